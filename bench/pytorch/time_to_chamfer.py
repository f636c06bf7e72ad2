"""Time to Chamfer, sdfl's fast path against the textbook NeuS in PyTorch,
in one run on one machine, both at the same thread count (1 by default):
issue 25's "sdfl's fast path >= 10x shorter to the same Chamfer".

1. The data set: `sdfl run bench/pytorch/neus_data.sdfl`, the views that
   examples/neus_fast.sdfl trains on (same truth, cameras, size, material,
   tracing and held-out split), as NeRF-synthetic RGBA PNGs.
2. sdfl: examples/neus_fast.sdfl (`--volsdf`: volsdf_fast.sdfl) at each of
   `--steps` (`let steps = N`, which also sets its learning-rate decay, as
   `sdfl sweep --set steps=...` does), `sdfl run --threads T --json`, its
   GIFs left out (they are drawn after training and cost only wall time).
   Training seconds are the report's `train` stage (held-out evaluation
   excluded), the Chamfer distance its `mesh_fit` (the 96-cell mesh against
   the true surface).
3. PyTorch: bench/pytorch/neus_train.py on the data set with the same
   silhouette term (weight 0.1), `torch.set_num_threads(T)`, the Chamfer
   distance (computed as sdfl's `mesh_fit`) every `--eval` seconds of
   training (or at `--marks`), evaluation excluded, until `--torch-seconds`
   of training.
4. The ratio: PyTorch's first training time at or below sdfl's Chamfer
   over sdfl's training time, for each sdfl row; the headline is sdfl's
   last row. If PyTorch never gets there: its best Chamfer, the time sdfl
   takes to reach that, and the bound `--torch-seconds` / sdfl's time.

Everything goes into `--out DIR` (the data set, sdfl's outputs, logs,
results.md, results.json) and the text results into
DIR/time_to_chamfer.tar.gz for a remote run.

    python3 bench/pytorch/time_to_chamfer.py --out /tmp/ttc [--sdfl target/release/sdfl]
        [--torch-seconds 1200] [--eval 30 | --marks 15,30,60,...] [--steps 200,400,800] [--threads 1]
        [--volsdf] [--stop-when-reached] [--psnr]

Without `--sdfl` it builds the binary with `cargo build --release --bin
sdfl` in this repository. Needs numpy, torch, scipy and scikit-image.
"""
import argparse
import json
import math
import os
import platform
import re
import subprocess
import sys
import tarfile
import time
from datetime import datetime, timezone

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
ROW = re.compile(r"^\|\s*([0-9.]+)\s*\|\s*(\d+)\s*\|\s*([0-9.]+|inf)\s*\|\s*([0-9.]+|nan)\s*\|\s*$")


def say(line, log):
    print(line, flush=True)
    log.append(line)


def cpu_model():
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def load():
    try:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "?"


def run(cmd, log_path, env=None, echo=False):
    """Runs `cmd`, its stderr (and, with `echo`, its stdout as it comes) to
    the console and `log_path`; returns its stdout. Fails loudly."""
    with open(log_path, "w") as log:
        log.write("$ " + " ".join(cmd) + "\n")
        p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        out = []
        if echo:
            for line in p.stdout:
                print(line, end="", flush=True)
                log.write(line)
                out.append(line)
        else:
            out.append(p.stdout.read())
        err = p.stderr.read()
        log.write(err)
        p.wait()
    if p.returncode != 0:
        sys.stderr.write(err[-4000:])
        sys.exit(f"failed ({p.returncode}): {' '.join(cmd)} (log: {log_path})")
    return "".join(out)


def sdfl_binary(path):
    if path:
        return os.path.abspath(path)
    subprocess.run(["cargo", "build", "--release", "--bin", "sdfl"], cwd=ROOT, check=True)
    return os.path.join(ROOT, "target", "release", "sdfl")


def with_steps(source, steps):
    """The example at `steps` steps, without its GIFs."""
    text, n = re.subn(r"(?m)^let steps = \d+\s*$", f"let steps = {steps}", source)
    if n != 1:
        sys.exit("the example has no single `let steps = N` line to set")
    return "".join(line for line in text.splitlines(keepends=True) if "gif(" not in line)


def sdfl_rows(sdfl, example, steps, threads, out, log):
    source = open(example).read()
    rows = []
    os.makedirs(os.path.join(out, "sdfl"), exist_ok=True)
    for n in steps:
        name = f"steps{n}"
        scene = os.path.join(out, "sdfl", f"{name}.sdfl")
        with open(scene, "w") as f:
            f.write(with_steps(source, n))
        t0 = time.time()
        text = run(
            [sdfl, "run", "--threads", str(threads), "--json", "--restart", "--out", os.path.join(out, "sdfl", name), scene],
            os.path.join(out, "sdfl", f"{name}.log"),
        )
        with open(os.path.join(out, "sdfl", f"{name}.json"), "w") as f:
            f.write(text)
        report = next(j["report"] for j in json.loads(text)["jobs"] if j["kind"] == "train")
        stages = dict(report["stages"])
        fit = report.get("mesh_fit") or {}
        chamfer = fit.get("chamfer")
        held = report.get("held_out") or []
        row = {
            "steps": report["iterations"],
            "train_seconds": stages["train"],
            "ms_per_step": 1e3 * report["seconds_per_step"],
            "chamfer": math.inf if chamfer is None else chamfer,
            "held_out_psnr": held[-1]["psnr"] if held else None,
            "wall_seconds": time.time() - t0,
            "load": load(),
        }
        rows.append(row)
        say(
            f"sdfl {n} steps: {row['train_seconds']:.1f} s of training, Chamfer {row['chamfer']:.4f}"
            f" (run {row['wall_seconds']:.0f} s, load {row['load']})",
            log,
        )
        # The checkpoint (the grid and Adam's moments) is not needed here.
        for f in os.listdir(os.path.join(out, "sdfl", name)):
            if f.endswith(".ckpt"):
                os.remove(os.path.join(out, "sdfl", name, f))
    return rows


def torch_info(python, threads):
    code = (
        "import torch, numpy, scipy, skimage, sys; torch.set_num_threads(%d);"
        "print(torch.__version__); print(numpy.__version__, scipy.__version__, skimage.__version__);"
        "print(sys.version.split()[0]); print(torch.get_num_threads()); print(torch.__config__.parallel_info())" % threads
    )
    out = subprocess.run([python, "-c", code], capture_output=True, text=True, check=True).stdout.splitlines()
    return {
        "torch": out[0],
        "numpy_scipy_skimage": out[1],
        "python": out[2],
        "torch_threads": int(out[3]),
        "parallel_info": "\n".join(out[4:]),
    }


def torch_rows(python, data, args, target, out):
    env = dict(os.environ)
    for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        env[k] = str(args.threads)
    cmd = [
        python, os.path.join(HERE, "neus_train.py"), data,
        "--threads", str(args.threads),
        "--minutes", str(args.torch_seconds / 60.0),
        "--silhouette", str(args.silhouette),
    ]
    cmd += ["--marks", args.marks] if args.marks else ["--eval", str(args.eval)]
    if args.volsdf:
        cmd.append("--volsdf")
    if not args.psnr:
        cmd.append("--no-psnr")
    if args.stop_when_reached:
        cmd += ["--target", repr(target)]
    text = run(cmd, os.path.join(out, "pytorch.log"), env=env, echo=True)
    rows = []
    for line in text.splitlines():
        m = ROW.match(line.strip())
        if m:
            rows.append(
                {
                    "train_seconds": float(m.group(1)),
                    "steps": int(m.group(2)),
                    "chamfer": float(m.group(3)),
                    "held_out_psnr": None if m.group(4) == "nan" else float(m.group(4)),
                }
            )
    if not rows:
        sys.exit("no rows from neus_train.py (log: pytorch.log)")
    return rows


def first_at_or_below(rows, chamfer):
    return next((r for r in rows if r["chamfer"] <= chamfer), None)


def comparison(sdfl, torch_rows, limit):
    """Per sdfl row, PyTorch's first time at or below its Chamfer and the
    ratio; and the headline for sdfl's last row. PyTorch's untrained start
    (the initial sphere) does not count."""
    torch_rows = [r for r in torch_rows if r["steps"] > 0]
    per_row = []
    for s in sdfl:
        p = first_at_or_below(torch_rows, s["chamfer"])
        # From when on PyTorch stays at or below it (its curve swings).
        stays = None
        for k, r in enumerate(torch_rows):
            if all(q["chamfer"] <= s["chamfer"] for q in torch_rows[k:]):
                stays = r
                break
        per_row.append(
            {
                "sdfl_steps": s["steps"],
                "sdfl_seconds": s["train_seconds"],
                "chamfer": s["chamfer"],
                "torch_first_seconds": p["train_seconds"] if p else None,
                "torch_stays_seconds": stays["train_seconds"] if stays else None,
                "ratio": p["train_seconds"] / s["train_seconds"] if p else None,
                "ratio_at_least": None if p else limit / s["train_seconds"],
            }
        )
    final = sdfl[-1]
    best = min(torch_rows, key=lambda r: r["chamfer"])
    head = {"sdfl_final": final, "torch_best": best, **per_row[-1]}
    if per_row[-1]["ratio"] is None:
        s = first_at_or_below(sdfl, best["chamfer"])
        head["sdfl_to_torch_best"] = s
        head["ratio_at_torch_best"] = best["train_seconds"] / s["train_seconds"] if s else None
    return per_row, head


def fmt(x, spec):
    return "–" if x is None else format(x, spec)


def report(args, env, sdfl, torch_rows, per_row, head):
    model = "VolSDF" if args.volsdf else "NeuS"
    example = "volsdf_fast.sdfl" if args.volsdf else "neus_fast.sdfl"
    t = env["torch"]
    marks = f"at {args.marks} s of training" if args.marks else f"every {args.eval:g} s of training"
    lines = [
        f"## Time to Chamfer: sdfl `{example}` vs PyTorch {model} ({env['date']})",
        "",
        f"- Machine: {env['cpu']}, {env['cpus']} logical CPUs, load {env['load_start']} at the start,"
        f" {env['load_after_sdfl']} after sdfl, {env['load_end']} at the end.",
        f"- sdfl: `{env['sdfl_version']}`, commit {env['commit']}, `--threads {args.threads}`.",
        f"- PyTorch {t['torch']} (numpy, scipy, scikit-image {t['numpy_scipy_skimage']}; Python {t['python']}),"
        f" `torch.set_num_threads({args.threads})` (it reports {t['torch_threads']}), silhouette weight"
        f" {args.silhouette}, the textbook {model} MLP (4 × 64, 1024 rays × 48 samples, Adam 5e-4),"
        f" Chamfer {marks} (evaluation excluded), up to {args.torch_seconds:g} s.",
        "",
        "| side | steps | training s | Chamfer to the truth | held-out PSNR (dB) |",
        "|---|---:|---:|---:|---:|",
    ]
    for s in sdfl:
        lines.append(
            f"| sdfl | {s['steps']} | {s['train_seconds']:.1f} | {s['chamfer']:.4f} | {fmt(s['held_out_psnr'], '.2f')} |"
        )
    for r in torch_rows:
        lines.append(
            f"| PyTorch | {r['steps']} | {r['train_seconds']:.1f} | {r['chamfer']:.4f} | {fmt(r['held_out_psnr'], '.2f')} |"
        )
    lines += [
        "",
        "| sdfl steps | sdfl s | Chamfer | PyTorch first at or below (s) | stays below from (s) | PyTorch / sdfl |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for p in per_row:
        ratio = f"{p['ratio']:.1f}×" if p["ratio"] is not None else f"≥ {p['ratio_at_least']:.1f}× (not reached)"
        lines.append(
            f"| {p['sdfl_steps']} | {p['sdfl_seconds']:.1f} | {p['chamfer']:.4f} | {fmt(p['torch_first_seconds'], '.1f')}"
            f" | {fmt(p['torch_stays_seconds'], '.1f')} | {ratio} |"
        )
    lines.append("")
    f, b = head["sdfl_final"], head["torch_best"]
    if head["ratio"] is not None:
        lines.append(
            f"**Ratio {head['ratio']:.1f}×**: PyTorch first reached sdfl's final Chamfer {f['chamfer']:.4f}"
            f" after {head['torch_first_seconds']:.1f} s of training; sdfl took {f['train_seconds']:.1f} s ({f['steps']} steps)."
        )
    else:
        s = head.get("sdfl_to_torch_best")
        at_best = (
            f"sdfl reached that in {s['train_seconds']:.1f} s ({s['steps']} steps): {head['ratio_at_torch_best']:.1f}× at PyTorch's best"
            if s
            else "no sdfl row reached that"
        )
        lines.append(
            f"**PyTorch never reached sdfl's final Chamfer {f['chamfer']:.4f}** in {args.torch_seconds:g} s:"
            f" ratio ≥ {head['ratio_at_least']:.1f}×. Its best was {b['chamfer']:.4f} at {b['train_seconds']:.1f} s; {at_best}."
        )
    return "\n".join(lines) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True, help="directory for everything this run writes")
    ap.add_argument("--sdfl", default=None, help="the sdfl binary (default: cargo build --release here)")
    ap.add_argument("--python", default=sys.executable, help="the interpreter with torch (default: this one)")
    ap.add_argument("--torch-seconds", type=float, default=1200.0, help="PyTorch's training-time limit")
    ap.add_argument("--eval", type=float, default=30.0, help="seconds of PyTorch training between Chamfer evaluations")
    ap.add_argument("--marks", default=None, help="PyTorch's evaluation times (training s, comma-separated) instead of --eval")
    ap.add_argument("--steps", default="200,400,800", help="sdfl's step counts")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--silhouette", type=float, default=0.1, help="PyTorch's silhouette weight (the examples' 0.1)")
    ap.add_argument("--volsdf", action="store_true", help="volsdf_fast.sdfl against PyTorch's VolSDF")
    ap.add_argument("--stop-when-reached", action="store_true", help="end PyTorch at sdfl's final Chamfer")
    ap.add_argument("--psnr", action="store_true", help="PyTorch's held-out PSNR at each evaluation too (wall time)")
    args = ap.parse_args()
    steps = sorted(int(s) for s in args.steps.split(","))
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    log = []

    sdfl = sdfl_binary(args.sdfl)
    version = subprocess.run([sdfl, "--version"], capture_output=True, text=True).stdout.strip()
    commit = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    dirty = subprocess.run(["git", "-C", ROOT, "status", "--porcelain"], capture_output=True, text=True).stdout.strip()
    env = {
        "date": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "cpu": cpu_model(),
        "cpus": os.cpu_count(),
        "load_start": load(),
        "sdfl_version": version,
        "commit": (commit.stdout.strip() + (" (modified)" if dirty else "")) if commit.returncode == 0 else "?",
        "torch": torch_info(args.python, args.threads),
        "command": " ".join(sys.argv),
    }
    say(f"{env['cpu']}, {env['cpus']} CPUs, load {env['load_start']}; PyTorch {env['torch']['torch']}; {version}", log)

    run([sdfl, "run", "--threads", str(args.threads), "--out", os.path.join(out, "data"),
         os.path.join(HERE, "neus_data.sdfl")], os.path.join(out, "data.log"))
    data = os.path.join(out, "data", "neus_data")

    example = os.path.join(ROOT, "examples", "volsdf_fast.sdfl" if args.volsdf else "neus_fast.sdfl")
    sdfl_results = sdfl_rows(sdfl, example, steps, args.threads, out, log)
    env["load_after_sdfl"] = load()

    torch_results = torch_rows(args.python, data, args, sdfl_results[-1]["chamfer"], out)
    env["load_end"] = load()

    per_row, head = comparison(sdfl_results, torch_results, args.torch_seconds)
    text = report(args, env, sdfl_results, torch_results, per_row, head)
    print()
    print(text)
    with open(os.path.join(out, "results.md"), "w") as f:
        f.write(text)
    with open(os.path.join(out, "results.json"), "w") as f:
        json.dump({"env": env, "sdfl": sdfl_results, "pytorch": torch_results, "per_row": per_row, "headline": head},
                  f, indent=1, default=lambda x: None)
    tar = os.path.join(out, "time_to_chamfer.tar.gz")
    with tarfile.open(tar, "w:gz") as t:
        for name in ["results.md", "results.json", "pytorch.log", "data.log"]:
            t.add(os.path.join(out, name), arcname=name)
        for name in sorted(os.listdir(os.path.join(out, "sdfl"))):
            if name.endswith((".json", ".log", ".sdfl")):
                t.add(os.path.join(out, "sdfl", name), arcname=f"sdfl/{name}")
    print(f"results: {os.path.join(out, 'results.md')}; packed: {tar}")


if __name__ == "__main__":
    main()
