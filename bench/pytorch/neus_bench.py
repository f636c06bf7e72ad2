"""PyTorch CPU counterpart of one training step of examples/neus.sdfl
(`--volsdf`: examples/volsdf.sdfl): the textbook neural surface, the
network sdfl trains there (runtime/src/neural/surface/, sdf_net/).

- Distance network (`neural_sdf(layers: 4, width: 64, radius: 0.6)`): the
  harmonic encoding of the point (4 octaves, sines, cosines, the point:
  27 features), 4 softplus(beta=100) layers of 64, the encoding again at
  layer 3, a linear distance; geometric initialisation to a sphere of
  radius 0.6, its output line fitted to |x| as sdfl calibrates it.
- Colour network: the point's harmonic encoding (4 octaves), the SDF's
  gradient (the normal, unnormalised) and the view direction's encoding
  (2 octaves): 45 inputs, 2 ReLU layers of 64, sigmoid RGB. No feature
  vector: sdfl's colour network takes none.
- NeuS: each interval absorbs `max(0, ln Phi(f_k) - ln Phi(f_k+1))`,
  `Phi = sigmoid(f/beta)`, the last sample nothing; beta trained from 0.05
  as `ln(beta)/20` (sdfl's BETA_RATE), clamped to 1e-4..10.
  VolSDF: `sigma = 20 Psi_beta(-f)` (Laplace CDF) times the interval, the
  last interval 0; beta falls geometrically from 0.1 to 0.005 over 3000
  steps (not trained).
- 1024 rays drawn without replacement over the 36 training views of 64^2
  (orbit of 40 at radius 3, focal 1.2), 48 jittered stratified depths in
  [1.5, 4.5], compositing over black, MSE (mean over rays and channels)
  + 0.02 x mean (|grad f| - 1)^2 over every sample, the gradient from
  torch.autograd.grad(create_graph=True) (double backward), Adam 5e-4
  (beta 0.9, 0.999, eps 1e-8), halved every 1500 steps.
- Optionally (`silhouette` > 0, as examples/neus_fast.sdfl's
  `silhouette(weight: 0.1)`; off here, as in neus.sdfl): NeuS's mask loss,
  each ray's binary cross-entropy of its opacity O = 1 - exp(-tau) against
  its pixel's coverage a (the data set's alpha, sdfl's hit mask), tau the
  ray's total optical depth: weight x mean over rays of
  (1 - a) tau - a ln max(O, 1e-6) (runtime/src/neural/composite.rs
  `silhouette_backward`; below the floor the covered half has no gradient).

A step is the batch's rays and depths, forward, backward and Adam, as
sdfl's `Run::advance` times it. The targets are the data set's when
`--data DIR` names one (bench/pytorch/neus_data.sdfl writes it), grey
otherwise (the work is the same).

    python bench/pytorch/neus_bench.py [reps] [threads] [--volsdf] [--data DIR [--silhouette 0.1]]
    python bench/pytorch/neus_bench.py --check DIR/neus.txt     # same step as sdfl?
    python bench/pytorch/neus_bench.py --check DIR/volsdf.txt --volsdf

    python bench/pytorch/neus_bench.py --views DIR/views.txt --data DATA   # same pixels?

(`cargo run --release -p sdfl-bench -- surface check DIR` writes DIR/*.txt;
where a file also holds `coverage` and `silhouette` lines, the check
includes the silhouette term, and `views.txt`, where it is written, holds
every training pixel of the examples' views.)

Prints one Markdown row: implementation, model, threads, median and
minimum step ms.
"""
import argparse
import math
import time

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

# sdfl's BETA_RATE: a trained beta is kept as ln(beta) / BETA_RATE.
BETA_RATE = 20.0


def harmonic(x, freqs):
    """sin(2^k x_i) (i outer, k inner), then the cosines, then x: sdfl's layout."""
    f = 2.0 ** torch.arange(freqs, dtype=x.dtype)
    e = (x[..., None] * f).reshape(*x.shape[:-1], -1)
    return torch.cat([e.sin(), e.cos(), x], dim=-1)


class SdfNet(nn.Module):
    """IGR's distance network as `neural_sdf(...)` builds it."""

    def __init__(self, layers=4, width=64, skips=(3,), freqs=4, beta=100.0):
        super().__init__()
        self.freqs, self.skips = freqs, set(s for s in skips if 0 < s < layers)
        enc = 3 * (2 * freqs + 1)
        self.hidden = nn.ModuleList(
            [nn.Linear(enc if i == 0 else width + (enc if i in self.skips else 0), width) for i in range(layers)]
        )
        self.out = nn.Linear(width, 1)
        self.beta = beta

    def forward(self, x):
        e = harmonic(x, self.freqs)
        h = e
        for i, layer in enumerate(self.hidden):
            if i in self.skips:
                h = torch.cat([h, e], dim=-1)
            h = F.softplus(layer(h), beta=self.beta)
        return self.out(h)[..., 0]

    @torch.no_grad()
    def geometric_init(self, radius, seed=0):
        """SAL's initialisation as sdf_net's `init_geometric` does it: hidden
        weights N(0, 2/width) with layer 0's sines and cosines and a skip's
        encoding part zero, biases 0; output weights sqrt(pi/width); then the
        output's scale and bias fitted so that f ~ |x| - radius on 512
        Fibonacci points at radii 0.5r..1.5r."""
        g = torch.Generator().manual_seed(seed)
        raw = 6 * self.freqs
        for i, layer in enumerate(self.hidden):
            n = layer.out_features
            w = torch.randn(layer.weight.shape, generator=g) * math.sqrt(2.0 / n)
            if i == 0:
                w[:, :raw] = 0.0
            elif i in self.skips:
                w[:, n:] = 0.0
            layer.weight.copy_(w)
            layer.bias.zero_()
        fan_in = self.out.in_features
        self.out.weight.copy_(math.sqrt(math.pi / fan_in) + 1e-5 * torch.randn(self.out.weight.shape, generator=g))
        self.out.bias.zero_()
        n = 512
        golden = math.pi * (3.0 - math.sqrt(5.0))
        k = torch.arange(n, dtype=torch.float64)
        z = 1.0 - (2 * k + 1) / n
        rho, phi = (1 - z * z).sqrt(), golden * k
        r = radius * (0.5 + (k % 8) / 7.0)
        pts = torch.stack([r * rho * phi.cos(), r * rho * phi.sin(), r * z], -1).float()
        u = self(pts).double()
        t = r
        b = ((t - t.mean()) * (u - u.mean())).sum() / ((t - t.mean()) ** 2).sum()
        a = u.mean() - b * t.mean()
        if b > 0 and torch.isfinite(a) and torch.isfinite(b):
            self.out.weight.div_(float(b))
            self.out.bias.fill_(float(-a / b - radius))
        else:
            self.out.bias.fill_(-radius)


class ColorNet(nn.Module):
    """The colour of a sample from its encoded point, its normal and its
    encoded view direction (PyTorch's default initialisation, as sdfl's)."""

    def __init__(self, layers=2, width=64, freqs=4, dir_freqs=2):
        super().__init__()
        self.freqs, self.dir_freqs = freqs, dir_freqs
        inp = 3 * (2 * freqs + 1) + 3 + 3 * (2 * dir_freqs + 1)
        self.hidden = nn.ModuleList([nn.Linear(inp if i == 0 else width, width) for i in range(layers)])
        self.out = nn.Linear(width, 3)

    def forward(self, x, normal, d):
        h = torch.cat([harmonic(x, self.freqs), normal, harmonic(d, self.dir_freqs)], dim=-1)
        for layer in self.hidden:
            h = F.relu(layer(h))
        return torch.sigmoid(self.out(h))


class Surface(nn.Module):
    """A neural SDF with a colour network, seen through NeuS's or VolSDF's density."""

    def __init__(self, volsdf=False, steps=3000):
        super().__init__()
        self.sdf = SdfNet()
        self.sdf.geometric_init(0.6)
        self.color = ColorNet()
        self.volsdf, self.steps = volsdf, steps
        # NeuS: beta trained from 0.05 as ln(beta)/BETA_RATE; VolSDF: scheduled.
        self.log_beta = nn.Parameter(torch.tensor(math.log(0.05) / BETA_RATE), requires_grad=not volsdf)
        self.alpha, self.beta0, self.beta_end = 20.0, 0.1, 0.005

    def beta(self, step):
        if self.volsdf:
            s = min(step / max(self.steps - 1, 1), 1.0)
            return self.beta0 * (self.beta_end / self.beta0) ** s
        return torch.exp(BETA_RATE * self.log_beta)

    @torch.no_grad()
    def project(self):
        self.log_beta.clamp_(math.log(1e-4) / BETA_RATE, math.log(10.0) / BETA_RATE)

    def render(self, origins, dirs, t, step, create_graph=True):
        """Colour of each ray, the eikonal term over every sample and each
        ray's total optical depth (the sum of its samples' absorptions)."""
        n, s = t.shape
        x = (origins[:, None, :] + t[..., None] * dirs[:, None, :]).reshape(-1, 3)
        x.requires_grad_(True)
        f = self.sdf(x)
        (g,) = torch.autograd.grad(f, x, torch.ones_like(f), create_graph=create_graph)
        d = dirs[:, None, :].expand(n, s, 3).reshape(-1, 3)
        rgb = self.color(x, g, d).reshape(n, s, 3)
        f = f.reshape(n, s)
        beta = self.beta(step)
        if self.volsdf:
            e = torch.exp(-f.abs() / beta)
            sigma = self.alpha * torch.where(f > 0, 0.5 * e, 1.0 - 0.5 * e)
            delta = torch.cat([t[:, 1:] - t[:, :-1], torch.zeros_like(t[:, :1])], dim=-1)
            tau = sigma * delta
        else:
            x_ = f / beta
            tau = F.relu(F.softplus(-x_[:, 1:]) - F.softplus(-x_[:, :-1]))
            tau = torch.cat([tau, torch.zeros_like(tau[:, :1])], dim=-1)
        trans = torch.exp(-(torch.cumsum(tau, dim=-1) - tau))
        w = trans * -torch.expm1(-tau)
        colour = (w[..., None] * rgb).sum(dim=1)
        eikonal = ((g.norm(dim=-1) - 1.0) ** 2).mean()
        return colour, eikonal, tau.sum(dim=-1)


# sdfl's OPACITY_FLOOR: a covered ray's opacity is taken as at least this.
OPACITY_FLOOR = 1e-6


def silhouette(depth, coverage):
    """Mean over rays of the binary cross-entropy of each ray's opacity
    O = 1 - exp(-depth) against its pixel's coverage, written as sdfl's
    `silhouette_backward` does: (1 - a) depth - a ln max(O, 1e-6). Below
    the floor the covered half is constant (no gradient), as sdfl's."""
    opacity = -torch.expm1(-depth)
    kept = torch.where(opacity > OPACITY_FLOOR, opacity, torch.full_like(opacity, OPACITY_FLOOR))
    return ((1.0 - coverage) * depth - coverage * kept.log()).mean()


def orbit_rays(views=40, radius=3.0, focal=1.2, size=64):
    """Every pixel's ray of an orbit like sdfl's `orbit(radius, up: [0, 1, 0],
    focal, views)` (pixel centres spanning NDC [-1, 1]); for timing only,
    where the step's work does not depend on which pixels are which."""
    origins, dirs = [], []
    ndc = 1.0 - 2.0 * np.arange(size) / (size - 1)
    for k in range(views):
        a = 2 * math.pi * k / views + math.pi / 2
        eye = np.array([radius * math.cos(a), 0.0, -radius * math.sin(a)])
        fwd = -eye / np.linalg.norm(eye)
        right = np.cross(np.array([0.0, 1.0, 0.0]), fwd)
        right /= np.linalg.norm(right)
        up = np.cross(fwd, right)
        xs, ys = np.meshgrid(ndc, ndc)
        d = fwd + (xs[..., None] * right + ys[..., None] * up) / focal
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        dirs.append(d.reshape(-1, 3))
        origins.append(np.broadcast_to(eye, (size * size, 3)))
    return (torch.from_numpy(np.concatenate(a).astype(np.float32)) for a in (origins, dirs))


def stratified(rays, samples, near, far):
    """sdfl's jittered depths: each drawn uniformly in its stratum between
    the midpoints of linspace(near, far, samples), the ends at near and far."""
    t = torch.linspace(near, far, samples)
    mid = 0.5 * (t[1:] + t[:-1])
    lo = torch.cat([t[:1], mid])
    hi = torch.cat([mid, t[-1:]])
    return lo + (hi - lo) * torch.rand(rays, samples)


class Trainer:
    """sdfl's training loop for a neural surface: the model, Adam, the step;
    with `silhouette` > 0 (and each pixel's `coverage`) the mask loss too."""

    def __init__(
        self, volsdf, origins, dirs, targets, rays=1024, samples=48, near=1.5, far=4.5, steps=3000,
        coverage=None, silhouette=0.0,
    ):
        if silhouette > 0 and coverage is None:
            raise ValueError("the silhouette term needs each pixel's coverage")
        self.model = Surface(volsdf=volsdf, steps=steps)
        self.opt = torch.optim.Adam([p for p in self.model.parameters() if p.requires_grad], lr=5e-4)
        self.sched = torch.optim.lr_scheduler.StepLR(self.opt, step_size=1500, gamma=0.5)
        self.o, self.d, self.target = origins, dirs, targets
        self.coverage, self.silhouette = coverage, silhouette
        self.rays, self.samples, self.near, self.far = rays, samples, near, far
        self.step_count = 0

    def step(self):
        idx = torch.randperm(len(self.o))[: self.rays]
        t = stratified(self.rays, self.samples, self.near, self.far)
        self.opt.zero_grad(set_to_none=True)
        colour, eikonal, depth = self.model.render(self.o[idx], self.d[idx], t, self.step_count)
        loss = ((colour - self.target[idx]) ** 2).mean() + 0.02 * eikonal
        if self.silhouette > 0:
            loss = loss + self.silhouette * silhouette(depth, self.coverage[idx])
        loss.backward()
        self.opt.step()
        self.sched.step()
        self.model.project()
        self.step_count += 1
        return loss.item()


def check(path, volsdf):
    """Compares this model's loss and gradient, in float64, with sdfl's on
    the same parameters and batch (`sdfl-bench surface check DIR` writes
    them): prints the relative difference of the loss and, per tensor, the
    largest gradient difference over the tensor's largest gradient."""
    rows = {}
    for line in open(path):
        words = line.split()
        key, vals = (" ".join(words[:2]), words[2:]) if words[0] in ("param", "grad") else (words[0], words[1:])
        rows[key] = torch.tensor([float(v) for v in vals], dtype=torch.float64)
    model = Surface(volsdf=volsdf).double()

    def tensor_of(name):
        if name == "log_beta":
            return model.log_beta, None
        net, *rest = name.split(".")
        if net == "sdf":
            layer = model.sdf.out if rest[0] == "output" else model.sdf.hidden[int(rest[1])]
        else:
            layer = model.color.out if rest[0] == "out" else model.color.hidden[int(rest[0])]
        p = layer.weight if rest[-1] == "weight" else layer.bias
        # sdfl keeps a layer's weights input-major: (fan_in, out).
        shape = (p.shape[1], p.shape[0]) if rest[-1] == "weight" else None
        return p, shape

    def as_torch(v, shape):
        return v.reshape(shape).T if shape else v.reshape(-1)

    names = [k[6:] for k in rows if k.startswith("param ")]
    with torch.no_grad():
        for name in names:
            p, shape = tensor_of(name)
            p.copy_(as_torch(rows["param " + name], shape).reshape(p.shape))
    n = int(rows["samples"][0])
    o, d = rows["origins"].reshape(-1, 3), rows["dirs"].reshape(-1, 3)
    t, target = rows["depths"].reshape(-1, n), rows["targets"].reshape(-1, 3)
    colour, eikonal, depth = model.render(o, d, t, 0)
    loss = ((colour - target) ** 2).mean() + 0.02 * eikonal
    weight = rows["silhouette"][0].item() if "silhouette" in rows else 0.0
    if weight > 0:
        loss = loss + weight * silhouette(depth, rows["coverage"])
        covered = int((rows["coverage"] > 0.5).sum())
        print(f"silhouette term, weight {weight}: {covered} of {len(o)} rays covered")
    loss.backward()
    ref = rows["loss"][0].item()
    print(f"loss: PyTorch {loss.item():.6e}, sdfl {ref:.6e}, relative difference {abs(loss.item() - ref) / abs(ref):.1e}")
    print("| tensor | max abs gradient (sdfl) | max abs difference / max abs gradient |")
    print("|---|---:|---:|")
    for name in names:
        p, shape = tensor_of(name)
        g = p.grad.reshape(-1) if p.grad is not None else torch.zeros(p.numel(), dtype=torch.float64)
        want = as_torch(rows["grad " + name], shape).reshape(-1)
        scale = want.abs().max().item()
        err = (g - want).abs().max().item()
        print(f"| {name} | {scale:.3e} | {err / scale if scale > 0 else err:.1e} |")


def check_views(path, data):
    """Compares every training pixel sdfl trains on (`views.txt`: per ray its
    view among the training views, pixel, origin, direction, target colour
    and coverage) with the data set's: the same rays, colours and alpha.
    Prints the largest differences; the views are the same when the rays
    agree to float rounding and colours and coverage exactly."""
    from nerf_train import load_split, rays_of

    rows = np.loadtxt(path)
    img, pose, focal, alpha = load_split(data, "train", with_alpha=True)
    n, h, w, _ = img.shape
    o, d = rays_of(pose, h, w, focal)
    at = rows[:, 0].astype(np.int64) * h * w + rows[:, 1].astype(np.int64)
    print(f"{len(rows)} rays from sdfl over {n} training views of {w}x{h} ({n * h * w} pixels, {len(np.unique(at))} distinct)")
    print(f"largest difference: origin {np.abs(rows[:, 2:5] - o[at]).max():.1e}, direction {np.abs(rows[:, 5:8] - d[at]).max():.1e}, "
          f"colour {np.abs(rows[:, 8:11] - img.reshape(-1, 3)[at]).max():.1e}, coverage {np.abs(rows[:, 11] - alpha.reshape(-1)[at]).max():.1e}")
    print(f"covered pixels: sdfl {int(rows[:, 11].sum())}, data set {int(alpha.sum())}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("reps", nargs="?", type=int, default=10)
    ap.add_argument("threads", nargs="?", type=int, default=1)
    ap.add_argument("--volsdf", action="store_true")
    ap.add_argument("--data", default=None)
    ap.add_argument("--check", default=None, help="compare with sdfl's step written by `sdfl-bench surface check`")
    ap.add_argument(
        "--silhouette", type=float, default=0.0,
        help="weight of the silhouette term (needs --data; 0, as examples/neus.sdfl, which `sdfl-bench surface` times)",
    )
    ap.add_argument("--views", default=None, help="with --data: compare sdfl's training pixels (views.txt) with the data set")
    args = ap.parse_args()
    if args.views:
        return check_views(args.views, args.data)
    if args.check:
        return check(args.check, args.volsdf)
    if args.silhouette > 0 and not args.data:
        ap.error("--silhouette needs --data (each pixel's coverage is its alpha)")
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    coverage = None
    if args.data:
        from nerf_train import load_split, rays_of

        img, pose, focal, alpha = load_split(args.data, "train", with_alpha=True)
        _, h, w, _ = img.shape
        o, d = (torch.from_numpy(a) for a in rays_of(pose, h, w, focal))
        target = torch.from_numpy(img.reshape(-1, 3))
        coverage = torch.from_numpy(alpha.reshape(-1))
    else:
        o, d = orbit_rays(views=36)
        target = torch.full((len(o), 3), 0.5)
    trainer = Trainer(args.volsdf, o, d, target, coverage=coverage, silhouette=args.silhouette)
    for _ in range(2):
        trainer.step()
    ts = []
    for _ in range(args.reps):
        t0 = time.perf_counter()
        trainer.step()
        ts.append(time.perf_counter() - t0)
    ts.sort()
    model = "VolSDF" if args.volsdf else "NeuS"
    print(f"| PyTorch {torch.__version__} (double backward) | {model} | {args.threads} | {ts[len(ts) // 2] * 1e3:.1f} | {ts[0] * 1e3:.1f} |")


if __name__ == "__main__":
    main()
