"""PyTorch CPU counterpart of `cargo run --release -p sdfl-bench -- nerf`.

One NeRF optimiser step with the network sdfl's `nerf()` builds by default
(harmonic position 6 -> 39, direction 2 -> 15, 6 x 128 ReLU trunk with the
position again at layer 3, density head, 128 feature layer, 64-wide colour
branch seeing the direction, sigmoid colour): 1024 rays x 64 samples,
compositing, MSE, backward, Adam. Also this machine's fp32 GEMM throughput
(a 65536 x 128 x 128 matmul), so both can be read as a fraction of it.

    python bench/pytorch/nerf_bench.py [reps] [threads]
"""
import sys
import time

import torch
import torch.nn as nn

RAYS, SAMPLES = 1024, 64
NEAR, FAR = 2.0, 6.0


def harmonic(x, freqs):
    f = 2.0 ** torch.arange(freqs, dtype=x.dtype)
    e = (x[..., None] * f).reshape(*x.shape[:-1], -1)
    return torch.cat([e.sin(), e.cos(), x], dim=-1)


class Nerf(nn.Module):
    def __init__(self, width=128, layers=6, skip=3, color=64, density=torch.relu):
        super().__init__()
        enc, denc = 39, 15
        self.skip = skip
        self.activation = density
        self.trunk = nn.ModuleList(
            [nn.Linear(enc if i == 0 else width + (enc if i == skip else 0), width) for i in range(layers)]
        )
        self.density = nn.Linear(width, 1)
        self.feature = nn.Linear(width, width)
        self.color_hidden = nn.Linear(width + denc, color)
        self.color_out = nn.Linear(color, 3)

    def forward(self, points, dirs):
        e = harmonic(points, 6)
        h = e
        for i, layer in enumerate(self.trunk):
            if i == self.skip:
                h = torch.cat([h, e], dim=-1)
            h = torch.relu(layer(h))
        sigma = self.activation(self.density(h))[..., 0]
        c = torch.relu(self.color_hidden(torch.cat([self.feature(h), harmonic(dirs, 2)], dim=-1)))
        return sigma, torch.sigmoid(self.color_out(c))


def composite(sigma, rgb, t):
    delta = torch.cat([t[..., 1:] - t[..., :-1], torch.zeros_like(t[..., :1])], dim=-1)
    tau = sigma * delta
    trans = torch.exp(-torch.cumsum(tau, dim=-1) + tau)  # exclusive
    w = trans * (1.0 - torch.exp(-tau))
    return (w[..., None] * rgb).sum(dim=-2)


def multiply_adds(net):
    return sum(m.in_features * m.out_features for m in net.modules() if isinstance(m, nn.Linear))


def main():
    reps = int(sys.argv[1]) if len(sys.argv) > 1 else 10
    threads = int(sys.argv[2]) if len(sys.argv) > 2 else 1
    torch.set_num_threads(threads)
    torch.manual_seed(0)

    a = torch.randn(65536, 128)
    b = torch.randn(128, 128)
    for _ in range(3):
        a @ b
    ts = []
    for _ in range(20):
        t0 = time.perf_counter()
        a @ b
        ts.append(time.perf_counter() - t0)
    gemm = 2 * 65536 * 128 * 128 / sorted(ts)[len(ts) // 2] / 1e9

    net = Nerf()
    opt = torch.optim.Adam(net.parameters(), lr=5e-4)
    origins = torch.randn(RAYS, 3) * 0.1 + torch.tensor([0.0, 0.0, -4.0])
    dirs = torch.nn.functional.normalize(torch.randn(RAYS, 3) * 0.2 + torch.tensor([0.0, 0.0, 1.0]), dim=-1)
    target = torch.rand(RAYS, 3)
    t = torch.linspace(NEAR, FAR, SAMPLES).expand(RAYS, SAMPLES)
    points = origins[:, None, :] + t[..., None] * dirs[:, None, :]
    d = dirs[:, None, :].expand(RAYS, SAMPLES, 3)

    def step():
        opt.zero_grad(set_to_none=True)
        sigma, rgb = net(points.reshape(-1, 3), d.reshape(-1, 3))
        colour = composite(sigma.reshape(RAYS, SAMPLES), rgb.reshape(RAYS, SAMPLES, 3), t)
        loss = ((colour - target) ** 2).mean()
        loss.backward()
        opt.step()

    for _ in range(2):
        step()
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        step()
        ts.append(time.perf_counter() - t0)
    ts.sort()
    med = ts[len(ts) // 2]
    flop = 3 * 2 * multiply_adds(net) * RAYS * SAMPLES
    print(
        f"| PyTorch {torch.__version__} | {threads} | {med * 1e3:.1f} | {ts[0] * 1e3:.1f} "
        f"| {flop / med / 1e9:.1f} | {gemm:.1f} | {flop / med / 1e9 / gemm * 100:.0f}% |"
    )


if __name__ == "__main__":
    main()
