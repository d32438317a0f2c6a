"""Benchmark: every drive metric for 3 real and 6 simulated runs of ~10,000 points each.

Target (issue 3): under 2 s on the 2-core machine. Real runs are the reference drives in
../shared/data/reference-drives; simulated runs are written as our run folders (trajectory.csv,
steering.csv) from perturbed copies of the real ones, so loading is timed too.

    python benchmarks/drive_metrics.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from cam2sim.metrics.drive_io import load_runs
from cam2sim.metrics.drive_quality import evaluate_drives

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "reference-drives"


def _write_sim_runs(folder: Path, n_runs: int = 6) -> list[Path]:
    real = load_runs([DATA], real=True)
    rng = np.random.default_rng(0)
    out = []
    for k in range(n_runs):
        src = real[k % len(real)]
        n = len(src)
        xy = src.xy.copy()
        d = np.gradient(xy, axis=0)
        normal = np.stack([-d[:, 1], d[:, 0]], -1) / np.maximum(
            np.linalg.norm(d, axis=1, keepdims=True), 1e-9
        )
        drift = 0.6 * np.sin(np.linspace(0, 6 + k, n)) + rng.normal(0, 0.02, n)
        xy += normal * drift[:, None]
        t = src.t - src.t[0]
        run = folder / f"run-{k}"
        run.mkdir()
        lines = ["t,x,y,z,heading,speed,steering,wheel_angle"]
        lines += [f"{ti:.4f},{x:.4f},{y:.4f},0,0,0,0,0" for ti, (x, y) in zip(t, xy, strict=True)]
        (run / "trajectory.csv").write_text("\n".join(lines) + "\n")
        st = np.arange(0, t[-1], 0.1)
        sv = np.sin(st) + rng.normal(0, 0.05, st.size)
        (run / "steering.csv").write_text(
            "t,value\n" + "".join(f"{a:.4f},{b:.6f}\n" for a, b in zip(st, sv, strict=True))
        )
        (run / "run.json").write_text(f'{{"method": "sim{k % 2}", "proj_string": "EPSG:32632"}}')
        out.append(run)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    if not DATA.is_dir():
        msg = f"needs the real reference drives at {DATA}"
        raise SystemExit(msg)
    with tempfile.TemporaryDirectory() as tmp:
        runs = _write_sim_runs(Path(tmp))
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            real = load_runs([DATA], real=True)
            sim = load_runs(runs, real=False)
            t1 = time.perf_counter()
            ev = evaluate_drives(real, sim)
            t2 = time.perf_counter()
            times.append((t1 - t0, t2 - t1))
    points = [len(r) for r in real + sim]
    load, evaluate = np.median(np.array(times), axis=0)
    print(f"machine: {platform.processor() or platform.machine()}, {platform.python_version()}")
    print(f"runs: {len(real)} real + {len(sim)} simulated, {min(points)}-{max(points)} points each")
    print(f"load {load:.3f} s, evaluate {evaluate:.3f} s, total {load + evaluate:.3f} s")
    print(f"target < 2 s: {'met' if load + evaluate < 2.0 else 'NOT met'}")
    for s in ev.metrics.methods:
        print(f"  {s.method}: runs {s.runs}, avg Min-Frechet {s.avg_min_frechet_m}")


if __name__ == "__main__":
    main()
