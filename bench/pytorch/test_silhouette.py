"""Checks of the silhouette term of neus_bench.py against its formula
(sdfl's runtime/src/neural/composite.rs `silhouette_backward`): the loss
in closed form, autograd's gradient against the closed form
∂L/∂τ_k = w/R · ((1 − a) − a·T/O) and against central differences, the
opacity floor's hard cases, and the term through the whole NeuS and VolSDF
model against finite differences of its parameters.

    python bench/pytorch/test_silhouette.py      (or pytest)
"""
import math
import os
import sys
import unittest

import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from neus_bench import OPACITY_FLOOR, Surface, silhouette, stratified  # noqa: E402

F64 = torch.float64


def reference(tau, a):
    """The term in plain float64 Python, one ray at a time (a list of
    per-sample absorptions per ray), and its gradient by the closed form."""
    loss, grads = 0.0, []
    for taus, cover in zip(tau, a):
        depth = sum(taus)
        opacity = -math.expm1(-depth)
        loss += (1 - cover) * depth - cover * math.log(max(opacity, OPACITY_FLOOR))
        covered = cover * math.exp(-depth) / opacity if opacity > OPACITY_FLOOR else 0.0
        grads.append([((1 - cover) - covered) / len(tau)] * len(taus))
    return loss / len(tau), grads


class SilhouetteTerm(unittest.TestCase):
    def setUp(self):
        g = torch.Generator().manual_seed(1)
        # Rays from nearly empty to opaque: absorptions per sample of 1e-4..1.
        scale = 10.0 ** torch.linspace(-4, 0, 12, dtype=F64)[:, None]
        self.tau = scale * torch.rand(12, 16, generator=g, dtype=F64)
        self.a = (torch.rand(12, generator=g) > 0.5).double()
        self.a[:4] = torch.tensor([0.0, 1.0, 0.25, 0.75], dtype=F64)  # partial coverage too

    def term(self, tau):
        return silhouette(tau.sum(-1), self.a)

    def test_loss_and_gradient_match_the_closed_form(self):
        tau = self.tau.clone().requires_grad_(True)
        loss = self.term(tau)
        loss.backward()
        want, want_grad = reference(self.tau.tolist(), self.a.tolist())
        self.assertAlmostEqual(loss.item(), want, delta=1e-12 * max(1.0, abs(want)))
        err = (tau.grad - torch.tensor(want_grad, dtype=F64)).abs().max().item()
        self.assertLess(err, 1e-12)

    def test_gradient_matches_central_differences(self):
        tau = self.tau.clone().requires_grad_(True)
        self.term(tau).backward()
        h = 1e-7
        for r, k in [(0, 3), (1, 0), (2, 15), (5, 7), (11, 2), (8, 8)]:
            up, down = self.tau.clone(), self.tau.clone()
            up[r, k] += h
            down[r, k] -= h
            fd = (self.term(up) - self.term(down)).item() / (2 * h)
            self.assertAlmostEqual(tau.grad[r, k].item(), fd, delta=1e-6 * max(1.0, abs(fd)))

    def test_hard_cases(self):
        # A covered ray that sees nothing: the floor's cost, no gradient; an
        # uncovered opaque ray: its depth, gradient 1/R per sample; a covered
        # opaque ray: ≈ 0; an empty uncovered ray: 0.
        tau = torch.tensor([[0.0, 0.0], [40.0, 40.0], [40.0, 40.0], [0.0, 0.0], [1e-8, 0.0]], dtype=F64, requires_grad=True)
        a = torch.tensor([1.0, 0.0, 1.0, 0.0, 1.0], dtype=F64)
        loss = silhouette(tau.sum(-1), a)
        loss.backward()
        self.assertTrue(torch.isfinite(loss) and torch.isfinite(tau.grad).all())
        want = (-math.log(OPACITY_FLOOR) + 80.0 + 0.0 + 0.0 - math.log(OPACITY_FLOOR)) / 5
        self.assertAlmostEqual(loss.item(), want, places=9)
        n = 5.0
        expected = torch.tensor([[0.0, 0.0], [1 / n, 1 / n], [0.0, 0.0], [1 / n, 1 / n], [0.0, 0.0]], dtype=F64)
        self.assertLess((tau.grad - expected).abs().max().item(), 1e-12)
        # Just above the floor the covered half's gradient is -T/O/R, large but finite.
        tau = torch.tensor([[2e-6]], dtype=F64, requires_grad=True)
        silhouette(tau.sum(-1), torch.tensor([1.0], dtype=F64)).backward()
        self.assertAlmostEqual(tau.grad.item(), -math.exp(-2e-6) / -math.expm1(-2e-6), delta=1.0)


class SilhouetteThroughTheModel(unittest.TestCase):
    """The term as the trainer adds it, through each density, against
    central differences of a few parameters (float64)."""

    def check(self, volsdf):
        torch.manual_seed(3)
        model = Surface(volsdf=volsdf).double()
        n = 24
        # Rays through the sphere of radius 0.6 and some past it.
        o = torch.tensor([[0.0, 0.0, 3.0]], dtype=F64).expand(n, 3).clone()
        lateral = torch.linspace(-0.9, 0.9, n, dtype=F64)
        target = torch.stack([lateral, 0.3 * torch.ones_like(lateral), -3.0 * torch.ones_like(lateral)], -1)
        d = target - o
        d = d / d.norm(dim=-1, keepdim=True)
        t = stratified(n, 32, 1.5, 4.5).double()
        a = (lateral.abs() < 0.55).double()
        a[0] = 1.0  # a covered ray that misses: the covered half at a faint ray

        def loss():
            _, _, depth = model.render(o, d, t, 0)
            return 0.1 * silhouette(depth, a)

        model.zero_grad()
        loss().backward()
        layer = model.sdf.hidden[1]
        picks = [(model.sdf.out.bias, (0,)), (layer.weight, (3, 5)), (layer.weight, (10, 2)), (layer.bias, (7,))]
        if not volsdf:
            picks.append((model.log_beta, ()))
        for p, at in picks:
            got = p.grad[at].item()
            h = 1e-6
            with torch.no_grad():
                p[at] += h
            up = loss().item()
            with torch.no_grad():
                p[at] -= 2 * h
            down = loss().item()
            with torch.no_grad():
                p[at] += h
            fd = (up - down) / (2 * h)
            self.assertAlmostEqual(got, fd, delta=1e-5 * max(1e-3, abs(fd)), msg=f"{p.shape} {at}")
        self.assertGreater(abs(model.sdf.out.bias.grad.item()), 1e-4)  # the term moves the surface

    def test_neus(self):
        self.check(False)

    def test_volsdf(self):
        self.check(True)


if __name__ == "__main__":
    unittest.main()
