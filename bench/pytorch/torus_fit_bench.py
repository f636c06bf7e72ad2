"""PyTorch CPU counterpart of `cargo run --release -p sdfl-bench -- train` (torus rows).

One optimiser step of the torus fit: six cameras at 96x96, 4096 random rays x
64 samples on [0, 6], torus SDF (centre, major and minor radius trainable) ->
opacity alpha*Psi_beta(-sdf) in the stable log-keep form -> weights ->
constant colour -> MSE, backward and an Adam step. Run by hand:

    pip install torch numpy
    python bench/pytorch/torus_fit_bench.py [reps] [threads]
"""
import math
import sys
import time

import torch

ALPHA, BETA = 1.0, 0.05
EYES = [(0, 0, -3), (2.6, 0, -1.5), (0, 2.6, -1.5), (-2.6, 0, 1.5), (0, -2.6, 1.5), (0, 0, 3)]
COLOUR = torch.tensor([0.9, 0.5, 0.2])


def camera_rays(eye, res):
    eye = torch.tensor(eye, dtype=torch.float64)
    up = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
    z = -eye / eye.norm()
    x = torch.linalg.cross(up, z)
    x = x / x.norm()
    y = torch.linalg.cross(z, x)
    ndc = 1.0 - 2.0 * torch.arange(res, dtype=torch.float64) / (res - 1)
    yy, xx = torch.meshgrid(ndc, ndc, indexing="ij")
    d = xx[..., None] * x + yy[..., None] * y + z
    d = d / d.norm(dim=-1, keepdim=True)
    return eye.expand_as(d).reshape(-1, 3).float(), d.reshape(-1, 3).float()


def torus_volume(o, d, t, center, major, minor):
    p = o[:, None, :] + t[None, :, None] * d[:, None, :]  # [R, N, 3]
    q = p - center
    a = (q[..., 0] ** 2 + q[..., 1] ** 2).sqrt() - major
    sdf = (a * a + q[..., 2] ** 2).sqrt() - minor
    e = torch.exp(-sdf.abs() / BETA)
    opacity = torch.where(sdf >= 0, 0.5 * ALPHA * e, ALPHA * (1 - 0.5 * e))
    log_keep = torch.where(sdf >= 0, torch.log1p(-0.5 * ALPHA * e), math.log(0.5) - sdf.abs() / BETA)
    cum = torch.cumsum(log_keep, dim=1)
    trans = torch.exp(torch.cat([torch.zeros_like(cum[:, :1]), cum[:, :-1]], dim=1))
    w = trans * opacity
    return w.sum(1, keepdim=True) * COLOUR


def main():
    reps = int(sys.argv[1]) if len(sys.argv) > 1 else 20
    if len(sys.argv) > 2:
        torch.set_num_threads(int(sys.argv[2]))
    res, n_rays, n_samples = 96, 4096, 64
    t = torch.linspace(0.0, 6.0, n_samples)
    rays = [camera_rays(e, res) for e in EYES]
    all_o = torch.cat([r[0] for r in rays])
    all_d = torch.cat([r[1] for r in rays])
    g = torch.Generator().manual_seed(0)
    idx = torch.randperm(all_o.shape[0], generator=g)[:n_rays]
    o, d = all_o[idx], all_d[idx]
    with torch.no_grad():
        target = torus_volume(o, d, t, torch.tensor([0.0, 0.1, -0.1]), torch.tensor(1.0), torch.tensor(0.25))
    center = torch.tensor([0.1, 0.0, 0.0], requires_grad=True)
    major = torch.tensor(0.8, requires_grad=True)
    minor = torch.tensor(0.35, requires_grad=True)
    opt = torch.optim.Adam([center, major, minor], lr=5e-3)

    def step():
        opt.zero_grad()
        loss = ((torus_volume(o, d, t, center, major, minor) - target) ** 2).mean()
        loss.backward()
        opt.step()

    for _ in range(2):
        step()
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        step()
        times.append((time.perf_counter() - t0) * 1e3)
    times.sort()
    print(f"| torus | PyTorch {torch.__version__} | {torch.get_num_threads()} | {times[len(times) // 2]:.2f} | {times[0]:.2f} |")


if __name__ == "__main__":
    main()
