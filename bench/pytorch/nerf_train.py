"""The textbook NeRF trained in PyTorch on CPU from a NeRF-synthetic data set,
timed to a held-out PSNR: the peer of `sdfl` training on the same files.

The network is nerf_bench.py's (sdfl's `nerf()` defaults: harmonic
position 6, direction 2, 6 x 128 ReLU with the position again at layer 3,
64-wide view-dependent colour branch, softplus density as `nerf.sdfl`),
1024 random rays over all training views a step, 64 jittered samples
between `near` and `far`, compositing over a black background, MSE, Adam
5e-4. Every `--eval` seconds of training the clock stops and the held-out
PSNR (mean over the test views) is printed with the training seconds; the
run ends at `--target` dB or after `--minutes` of training.

    python bench/pytorch/nerf_train.py DATA_DIR [--threads 2] [--minutes 12]
        [--target 25] [--eval 60] [--near 2] [--far 5]

DATA_DIR holds transforms_train.json and transforms_test.json (OpenGL
camera-to-world poses, `camera_angle_x`) and RGBA PNGs (8-bit, as sdfl's
`dataset(...)` output writes them), composited over black.
"""
import argparse
import json
import math
import os
import struct
import time
import zlib

import numpy as np
import torch
import torch.nn.functional as F

from nerf_bench import Nerf


def read_png(path):
    """An 8-bit, non-interlaced RGB or RGBA PNG as float32 RGBA in [0, 1]."""
    with open(path, "rb") as f:
        data = f.read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", path
    pos, idat = 8, b""
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos : pos + 4])
        kind = data[pos + 4 : pos + 8]
        body = data[pos + 8 : pos + 8 + n]
        if kind == b"IHDR":
            w, h, depth, ctype, _, _, interlace = struct.unpack(">IIBBBBB", body)
            assert depth == 8 and ctype in (2, 6) and interlace == 0, (path, depth, ctype)
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    ch = 4 if ctype == 6 else 3
    raw = zlib.decompress(idat)
    stride = w * ch
    out = np.zeros((h, stride), dtype=np.uint8)
    prev = np.zeros(stride, dtype=np.int32)
    for y in range(h):
        ftype = raw[y * (stride + 1)]
        line = np.frombuffer(raw, np.uint8, stride, y * (stride + 1) + 1).astype(np.int32)
        cur = np.zeros(stride, dtype=np.int32)
        if ftype == 0:
            cur = line
        elif ftype == 2:
            cur = (line + prev) & 255
        else:
            for x in range(stride):
                a = cur[x - ch] if x >= ch else 0
                b = prev[x]
                c = prev[x - ch] if x >= ch else 0
                if ftype == 1:
                    p = a
                elif ftype == 3:
                    p = (a + b) // 2
                else:
                    pa, pb, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
                    p = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                cur[x] = (line[x] + p) & 255
        out[y] = cur
        prev = cur
    img = out.reshape(h, w, ch).astype(np.float32) / 255.0
    if ch == 3:
        img = np.concatenate([img, np.ones((h, w, 1), np.float32)], axis=-1)
    return img


def load_split(root, split, with_alpha=False):
    """A split's images (over black), poses and focal length in pixels; with
    `with_alpha`, each pixel's alpha too (sdfl's data sets: the hit mask)."""
    with open(os.path.join(root, f"transforms_{split}.json")) as f:
        meta = json.load(f)
    images, poses, alphas = [], [], []
    for frame in meta["frames"]:
        path = os.path.join(root, frame["file_path"])
        if not path.endswith(".png"):
            path += ".png"
        rgba = read_png(path)
        images.append(rgba[..., :3] * rgba[..., 3:])  # over black
        alphas.append(rgba[..., 3])
        poses.append(np.array(frame["transform_matrix"], np.float32))
    h, w = images[0].shape[:2]
    focal = 0.5 * w / math.tan(0.5 * meta["camera_angle_x"])
    if with_alpha:
        return np.stack(images), np.stack(poses), focal, np.stack(alphas)
    return np.stack(images), np.stack(poses), focal


def rays_of(poses, h, w, focal):
    """Ray origins and unit directions of every pixel (centres), OpenGL axes."""
    i, j = np.meshgrid(np.arange(w, dtype=np.float32) + 0.5, np.arange(h, dtype=np.float32) + 0.5)
    d = np.stack([(i - 0.5 * w) / focal, -(j - 0.5 * h) / focal, -np.ones_like(i)], -1)
    dirs = np.einsum("hwk,nck->nhwc", d, poses[:, :3, :3])
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    origins = np.broadcast_to(poses[:, None, None, :3, 3], dirs.shape)
    return origins.reshape(-1, 3).copy(), dirs.reshape(-1, 3).copy()


def render(net, origins, dirs, t):
    n, s = t.shape
    points = origins[:, None, :] + t[..., None] * dirs[:, None, :]
    d = dirs[:, None, :].expand(n, s, 3)
    sigma, rgb = net(points.reshape(-1, 3), d.reshape(-1, 3))
    sigma, rgb = sigma.reshape(n, s), rgb.reshape(n, s, 3)
    delta = torch.cat([t[..., 1:] - t[..., :-1], torch.zeros_like(t[..., :1])], dim=-1)
    tau = sigma * delta
    trans = torch.exp(-(torch.cumsum(tau, dim=-1) - tau))
    w = trans * (1.0 - torch.exp(-tau))
    return (w[..., None] * rgb).sum(dim=-2)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("data")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--minutes", type=float, default=12.0)
    ap.add_argument("--target", type=float, default=25.0)
    ap.add_argument("--eval", type=float, default=60.0)
    ap.add_argument("--near", type=float, default=2.0)
    ap.add_argument("--far", type=float, default=5.0)
    ap.add_argument("--rays", type=int, default=1024)
    ap.add_argument("--samples", type=int, default=64)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    rng = np.random.default_rng(0)

    train_img, train_pose, focal = load_split(args.data, "train")
    test_img, test_pose, _ = load_split(args.data, "test")
    _, h, w, _ = train_img.shape
    o, d = rays_of(train_pose, h, w, focal)
    o, d, target = torch.from_numpy(o), torch.from_numpy(d), torch.from_numpy(train_img.reshape(-1, 3))
    to, td = (torch.from_numpy(x) for x in rays_of(test_pose, h, w, focal))
    test_target = torch.from_numpy(test_img.reshape(len(test_img), -1, 3))
    print(f"{len(train_img)} training and {len(test_img)} held-out views of {w}x{h}, focal {focal:.1f}")

    net = Nerf(density=F.softplus)
    opt = torch.optim.Adam(net.parameters(), lr=5e-4)
    s = args.samples
    edges = torch.linspace(args.near, args.far, s + 1)

    def held_out_psnr():
        with torch.no_grad():
            t = (0.5 * (edges[:-1] + edges[1:])).expand(4096, s)
            psnrs = []
            for v in range(len(test_img)):
                px = h * w
                parts = []
                for a in range(v * px, (v + 1) * px, 4096):
                    b = min(a + 4096, (v + 1) * px)
                    parts.append(render(net, to[a:b], td[a:b], t[: b - a]))
                out = torch.cat(parts)
                mse = ((out - test_target[v]) ** 2).mean().item()
                psnrs.append(-10 * math.log10(max(mse, 1e-12)))
            return sum(psnrs) / len(psnrs)

    trained, step, next_eval = 0.0, 0, args.eval
    print("| training seconds | steps | held-out PSNR (dB) |")
    print("|---:|---:|---:|")
    while True:
        t0 = time.perf_counter()
        idx = torch.from_numpy(rng.integers(0, len(o), args.rays))
        t = edges[:-1] + (edges[1:] - edges[:-1]) * torch.rand(args.rays, s)
        opt.zero_grad(set_to_none=True)
        loss = ((render(net, o[idx], d[idx], t) - target[idx]) ** 2).mean()
        loss.backward()
        opt.step()
        trained += time.perf_counter() - t0
        step += 1
        if trained >= next_eval or trained >= args.minutes * 60:
            p = held_out_psnr()
            print(f"| {trained:.1f} | {step} | {p:.2f} |", flush=True)
            next_eval += args.eval
            if p >= args.target or trained >= args.minutes * 60:
                break


if __name__ == "__main__":
    main()
