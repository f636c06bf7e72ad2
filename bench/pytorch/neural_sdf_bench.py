"""PyTorch CPU counterpart of the neural SDF step (runtime/src/neural/sdf_net.rs).

The assignment's neural SDF (harmonic 4 frequencies with the input, 6 x 128
softplus(beta=100) layers, the encoding again at layer 3, a linear distance)
on 4096 surface points and 4096 random points in [-4, 4]^3: mean |f| at the
surface, 0.02 x eikonal (|grad f| - 1)^2 at both sets with the gradient from
torch.autograd.grad(create_graph=True), 0.1 x exp(-100|f|) at the random
points, backward, Adam.

    python bench/pytorch/neural_sdf_bench.py [reps] [threads]
"""
import sys
import time

import torch
import torch.nn as nn


def harmonic(x, freqs=4):
    f = 2.0 ** torch.arange(freqs, dtype=x.dtype)
    e = (x[..., None] * f).reshape(*x.shape[:-1], -1)
    return torch.cat([e.sin(), e.cos(), x], dim=-1)


class NeuralSdf(nn.Module):
    def __init__(self, width=128, layers=6, skip=3):
        super().__init__()
        enc = 27
        self.skip = skip
        self.hidden = nn.ModuleList(
            [nn.Linear(enc if i == 0 else width + (enc if i == skip else 0), width) for i in range(layers)]
        )
        self.out = nn.Linear(width, 1)
        self.act = nn.Softplus(beta=100)

    def forward(self, x):
        e = harmonic(x)
        h = e
        for i, layer in enumerate(self.hidden):
            if i == self.skip:
                h = torch.cat([h, e], dim=-1)
            h = self.act(layer(h))
        return self.out(h)[..., 0]


def main():
    reps = int(sys.argv[1]) if len(sys.argv) > 1 else 10
    threads = int(sys.argv[2]) if len(sys.argv) > 2 else 1
    torch.set_num_threads(threads)
    torch.manual_seed(0)
    net = NeuralSdf()
    opt = torch.optim.Adam(net.parameters(), lr=1e-4)
    surface = torch.randn(4096, 3) * 0.5

    def step():
        opt.zero_grad(set_to_none=True)
        random = (torch.rand(4096, 3) * 2 - 1) * 4
        pts = torch.cat([surface, random]).requires_grad_(True)
        f = net(pts)
        (g,) = torch.autograd.grad(f.sum(), pts, create_graph=True)
        eik = ((g.norm(dim=-1) - 1) ** 2).mean()
        loss = f[:4096].abs().mean() + 0.02 * eik + 0.1 * torch.exp(-100 * f[4096:].abs()).mean()
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
    print(f"| PyTorch {torch.__version__} | {threads} | {ts[len(ts) // 2] * 1e3:.1f} | {ts[0] * 1e3:.1f} |")


if __name__ == "__main__":
    main()
