"""PyTorch CPU counterpart of `runtime/examples/box_volume_bench.rs`.

Same computation as sdfl's box volume (CONVENTIONS.md): assignment cameras,
4096 random rays x 64 samples on [0, 5], box SDF -> opacity alpha*Psi_beta(-sdf)
(stable log-keep form) -> weights -> rainbow colour -> MSE, backward and an
Adam step; plus a 256x256 forward render. Run by hand:

    pip install torch numpy
    python bench/pytorch/box_volume_bench.py [reps]
"""
import math
import sys
import time

import torch

torch.set_grad_enabled(True)
ALPHA, BETA = 1.0, 0.05
EYES = [(-2.5, 0.0, 0.0), (-1.0, 0.0, -2.2), (0.0, 0.0, -2.5), (1.0, 0.0, -2.2)]


def camera_rays(eye, res):
    eye = torch.tensor(eye, dtype=torch.float64)
    up = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
    z = -eye / eye.norm()
    x = torch.linalg.cross(up, z)
    x = x / x.norm()
    y = torch.linalg.cross(z, x)
    ndc = 1.0 - 2.0 * torch.arange(res, dtype=torch.float64) / (res - 1)
    yy, xx = torch.meshgrid(ndc, ndc, indexing="ij")  # rows top->bottom, cols left->right
    d = xx[..., None] * x + yy[..., None] * y + z
    d = d / d.norm(dim=-1, keepdim=True)
    o = eye.expand_as(d)
    return o.reshape(-1, 3).float(), d.reshape(-1, 3).float()


def box_volume(o, d, t, center, sides, with_grad_colour=True):
    p = o[:, None, :] + t[None, :, None] * d[:, None, :]  # [R, N, 3]
    diff = p - center
    q = diff.abs() - sides / 2
    sdf = q.clamp(min=0).pow(2).sum(-1).add(1e-30).sqrt() + q.max(-1).values.clamp(max=0)
    e = torch.exp(-sdf.abs() / BETA)
    opacity = torch.where(sdf >= 0, 0.5 * ALPHA * e, ALPHA * (1 - 0.5 * e))
    log_keep = torch.where(sdf >= 0, torch.log1p(-0.5 * ALPHA * e), math.log(0.5) - sdf.abs() / BETA)
    cum = torch.cumsum(log_keep, dim=1)
    trans = torch.exp(torch.cat([torch.zeros_like(cum[:, :1]), cum[:, :-1]], dim=1))
    w = trans * opacity
    col = diff.abs().clamp(0.02, 0.98)
    return (w[..., None] * col).sum(1), (w * t).sum(1)


def main():
    reps = int(sys.argv[1]) if len(sys.argv) > 1 else 10
    res, n_rays, n_samples = 256, 4096, 64
    t = torch.linspace(0.0, 5.0, n_samples)
    rays = [camera_rays(e, res) for e in EYES]
    all_o = torch.cat([r[0] for r in rays])
    all_d = torch.cat([r[1] for r in rays])
    g = torch.Generator().manual_seed(0)
    idx = torch.randperm(all_o.shape[0], generator=g)[:n_rays]
    o, d = all_o[idx], all_d[idx]
    with torch.no_grad():
        target, _ = box_volume(o, d, t, torch.tensor([0.25, 0.25, 0.0]), torch.tensor([2.0, 1.5, 1.5]))
    center = torch.zeros(3, requires_grad=True)
    sides = torch.full((3,), 1.5, requires_grad=True)
    opt = torch.optim.Adam([center, sides], lr=5e-4)

    def step():
        opt.zero_grad()
        rgb, _ = box_volume(o, d, t, center, sides)
        loss = ((rgb - target) ** 2).mean()
        loss.backward()
        opt.step()
        return loss.item()

    times = []
    for k in range(reps + 1):
        t0 = time.perf_counter()
        step()
        if k:
            times.append(time.perf_counter() - t0)
    step_ms = sorted(times)[len(times) // 2] * 1e3
    step_min = min(times) * 1e3

    o0, d0 = rays[0]
    times = []
    for k in range(reps + 1):
        t0 = time.perf_counter()
        with torch.no_grad():
            box_volume(o0, d0, t, torch.tensor([0.25, 0.25, 0.0]), torch.tensor([2.0, 1.5, 1.5]))
        if k:
            times.append(time.perf_counter() - t0)
    render_ms = sorted(times)[len(times) // 2] * 1e3
    render_min = min(times) * 1e3
    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}")
    print(f"train step (4096x64)   : {step_ms:8.2f} ms median {step_min:8.2f} ms min")
    print(f"render 256x256x64      : {render_ms:8.2f} ms median {render_min:8.2f} ms min")


if __name__ == "__main__":
    main()
