"""The textbook NeuS (`--volsdf`: VolSDF) trained in PyTorch on CPU from
the views examples/neus.sdfl and neus_fast.sdfl train on, timed to a
Chamfer distance to the true surface: the peer of sdfl's neural surfaces
on the same data.

The model and the step are neus_bench.py's (the network, density, batch,
losses and Adam of examples/neus.sdfl and volsdf.sdfl), with the
silhouette term of examples/neus_fast.sdfl (`silhouette(weight: 0.1)`:
each ray's opacity against its pixel's coverage, the PNGs' alpha) unless
`--silhouette 0`, so that both see the same supervision. Every `--eval`
seconds of training the clock stops and the run prints the Chamfer
distance of its mesh to the true surface and the held-out PSNR (mean over
the test views) with the training seconds and steps; it ends at
`--target` Chamfer or after `--minutes` of training.

The Chamfer distance is sdfl's (runtime/src/neural/distance.rs
`mesh_fit`): the field meshed over [-1.5, 1.5]^3 at 96 cells a side
(sdfl: surface nets; here marching cubes, scikit-image), the true surface
(the examples' smooth union of two spheres) meshed at 192 cells over its
bounds; 50 000 samples of each mesh against 1 000 000 of the other
(uniform by area), the mean of the two mean nearest distances.

    sdfl run bench/pytorch/neus_data.sdfl --out /tmp/neus
    python bench/pytorch/neus_train.py /tmp/neus/neus_data [--threads 2]
        [--minutes 10] [--eval 60 | --marks 15,30,60,...] [--target 0.019] [--volsdf]
        [--silhouette 0.1] [--no-psnr]

bench/pytorch/time_to_chamfer.py runs it against sdfl's fast path.

Needs numpy, torch, scipy and scikit-image.
"""
import argparse
import itertools
import math
import time

import numpy as np
import torch
from scipy.spatial import cKDTree
from skimage.measure import marching_cubes

from nerf_train import load_split, rays_of
from neus_bench import Trainer

BOUNDS = 1.5
MESH_RESOLUTION = 96
TRUE_RESOLUTION = 192
DENSE, QUERIES = 1_000_000, 50_000


def truth_sdf(p):
    """The examples' truth: smooth_union(sphere(0.55, [-0.35, 0, 0]),
    sphere(0.45, [0.4, 0.1, 0.1]), k: 0.2) with sdfl's polynomial smooth min."""
    a = np.linalg.norm(p - np.array([-0.35, 0.0, 0.0]), axis=-1) - 0.55
    b = np.linalg.norm(p - np.array([0.4, 0.1, 0.1]), axis=-1) - 0.45
    k = 0.2
    h = np.maximum(k - np.abs(a - b), 0.0) / k
    return np.minimum(a, b) - h * h * k * 0.25


def mesh_of(values, lo, step):
    verts, faces, _, _ = marching_cubes(values, level=0.0, spacing=(step,) * 3)
    return verts + lo, faces


def sample_surface(verts, faces, n, rng):
    """`n` points uniform by area over the triangles."""
    tri = verts[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=-1)
    pick = rng.choice(len(faces), size=n, p=area / area.sum())
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tri[pick]
    return t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])


def true_surface(rng):
    lo, hi = np.array([-0.95, -0.6, -0.6]), np.array([0.9, 0.6, 0.6])
    step = (hi - lo).max() / TRUE_RESOLUTION
    axes = [np.arange(lo[i], hi[i] + step, step) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1)
    verts, faces = mesh_of(truth_sdf(grid), lo, step)
    return sample_surface(verts, faces, QUERIES, rng), cKDTree(sample_surface(verts, faces, DENSE, rng))


@torch.no_grad()
def field_mesh(sdf):
    axis = torch.linspace(-BOUNDS, BOUNDS, MESH_RESOLUTION + 1)
    grid = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    values = torch.cat([sdf(grid[a : a + 65536]) for a in range(0, len(grid), 65536)])
    values = values.reshape((MESH_RESOLUTION + 1,) * 3).numpy()
    if values.min() > 0 or values.max() < 0:
        return None
    return mesh_of(values, np.full(3, -BOUNDS), 2 * BOUNDS / MESH_RESOLUTION)


def chamfer(sdf, truth_queries, truth_tree, rng, threads):
    mesh = field_mesh(sdf)
    if mesh is None:
        return math.inf
    verts, faces = mesh
    dense = cKDTree(sample_surface(verts, faces, DENSE, rng))
    samples = sample_surface(verts, faces, QUERIES, rng)
    to_mesh = dense.query(truth_queries, workers=threads)[0].mean()
    to_truth = truth_tree.query(samples, workers=threads)[0].mean()
    return 0.5 * (to_mesh + to_truth)


def held_out_psnr(trainer, o, d, target, views, step):
    """Mean PSNR over the test views, rendered at the sampler's even depths."""
    s = trainer.samples
    t = torch.linspace(trainer.near, trainer.far, s)
    px = len(o) // views
    psnrs = []
    for v in range(views):
        parts = []
        for a in range(v * px, (v + 1) * px, 4096):
            b = min(a + 4096, (v + 1) * px)
            colour, _, _ = trainer.model.render(o[a:b], d[a:b], t.expand(b - a, s), step, create_graph=False)
            parts.append(colour.detach())
        mse = ((torch.cat(parts) - target[v * px : (v + 1) * px]) ** 2).mean().item()
        psnrs.append(-10 * math.log10(max(mse, 1e-12)))
    return sum(psnrs) / len(psnrs)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("data")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--eval", type=float, default=60.0, help="seconds of training between evaluations")
    ap.add_argument(
        "--marks", default=None,
        help="training seconds to evaluate at, comma-separated, instead of --eval (the run ends at the last)",
    )
    ap.add_argument("--target", type=float, default=0.0)
    ap.add_argument("--volsdf", action="store_true")
    ap.add_argument(
        "--silhouette", type=float, default=0.1,
        help="weight of the silhouette term (examples/neus_fast.sdfl's 0.1; 0: none, as examples/neus.sdfl)",
    )
    ap.add_argument("--no-psnr", action="store_true", help="evaluate the Chamfer distance only")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    try:
        torch.set_num_interop_threads(args.threads)
    except RuntimeError:  # only before any parallel work; intra-op threads are what counts
        pass
    torch.manual_seed(0)
    rng = np.random.default_rng(0)

    train_img, train_pose, focal, train_alpha = load_split(args.data, "train", with_alpha=True)
    test_img, test_pose, _ = load_split(args.data, "test")
    _, h, w, _ = train_img.shape
    o, d = (torch.from_numpy(a) for a in rays_of(train_pose, h, w, focal))
    to, td = (torch.from_numpy(a) for a in rays_of(test_pose, h, w, focal))
    test_target = torch.from_numpy(test_img.reshape(-1, 3))
    coverage = torch.from_numpy(train_alpha.reshape(-1))
    trainer = Trainer(
        args.volsdf, o, d, torch.from_numpy(train_img.reshape(-1, 3)), coverage=coverage, silhouette=args.silhouette
    )
    truth_queries, truth_tree = true_surface(rng)
    model = "VolSDF" if args.volsdf else "NeuS"
    term = f"silhouette weight {args.silhouette}" if args.silhouette > 0 else "no silhouette term"
    print(
        f"{model}, PyTorch {torch.__version__}, {args.threads} threads, {term}: "
        f"{len(train_img)} training and {len(test_img)} held-out views of {w}x{h}"
    )

    def report(trained):
        c = chamfer(trainer.model.sdf, truth_queries, truth_tree, rng, args.threads)
        p = math.nan if args.no_psnr else held_out_psnr(trainer, to, td, test_target, len(test_img), trainer.step_count)
        print(f"| {trained:.1f} | {trainer.step_count} | {c:.4f} | {p:.2f} |", flush=True)
        return c

    print("| training seconds | steps | Chamfer to the true surface | held-out PSNR (dB) |")
    print("|---:|---:|---:|---:|")
    report(0.0)
    limit = args.minutes * 60
    if args.marks:
        marks = iter(sorted(float(m) for m in args.marks.split(",")))
        limit = min(limit, max(float(m) for m in args.marks.split(",")))
    else:
        marks = (args.eval * k for k in itertools.count(1))
    trained, next_eval = 0.0, next(marks)
    while True:
        t0 = time.perf_counter()
        trainer.step()
        trained += time.perf_counter() - t0
        if trained >= next_eval or trained >= limit:
            c = report(trained)
            # The next mark not yet passed (a step may outlast several).
            while trained >= next_eval:
                next_eval = next(marks, math.inf)
            if c <= args.target or trained >= limit:
                break


if __name__ == "__main__":
    main()
