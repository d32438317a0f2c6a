"""Time ``cam2sim demo`` end to end and report the paper's experiment per seed.

Runs the demo as a user does (``python -m cam2sim demo -o OUT --runs N``: the recording, every
pipeline step, N closed-loop runs per camera with seeds 0..N-1), then reads what it wrote:
each step's seconds (``WS/runs/pipeline.json``), which device trained the splat and its
held-out and ground-truth scores (``WS/splat/eval.json``), the splat quality gate and every
run's outcome (``WS/report/drive/metrics.json``). Prints a per-seed table of Real / splat / Sim
completion and a summary for seed groups (``--groups 0-2,3-5``), and writes it all as JSON.

Usage:
    python benchmarks/demo.py OUT [--runs 6] [--groups 0-2,3-5] [--world paper] [--json result.json]
    python benchmarks/demo.py OUT --osm ../shared/data/osm/munich.osm [--route LAT,LON LAT,LON]

On a CUDA machine the demo trains the splat with gsplat (the GPU preset) automatically; the
recipe for the GPU machine is in docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from cam2sim.core.workspace import Workspace


def _groups(text: str) -> list[tuple[int, int]]:
    out = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out.append((int(lo), int(hi or lo)))
    return out


def _machine() -> str:
    gpu = ""
    try:
        import torch  # noqa: PLC0415

        if torch.cuda.is_available():
            gpu = f", {torch.cuda.get_device_name(0)}"
    except ImportError:
        pass
    return f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores{gpu}"


def _seed(run: dict[str, Any]) -> int | None:
    name = str(run.get("name", ""))
    if "-s" not in name:
        return None
    tail = name.rsplit("-s", 1)[1]
    return int(tail) if tail.isdigit() else None


def summarise(ws: Path, groups: list[tuple[int, int]]) -> dict[str, Any]:
    """What the demo wrote under ``ws``, per step, per seed and per seed group."""
    steps = {
        name: step.model_dump(mode="json")
        for name, step in Workspace.open(ws).read_manifest().steps.items()
    }
    metrics = json.loads((ws / "report" / "drive" / "metrics.json").read_text(encoding="utf-8"))
    splat_eval = ws / "splat" / "eval.json"
    ev = json.loads(splat_eval.read_text(encoding="utf-8")) if splat_eval.is_file() else {}
    per_seed: dict[int, dict[str, Any]] = {}
    for run in metrics["runs"]:
        seed = _seed(run)
        if seed is None:
            continue
        method = {"real": "Real", "drive-splat": "splat", "drive-raster": "Sim"}.get(
            str(run["method"]), str(run["method"])
        )
        per_seed.setdefault(seed, {})[method] = {
            "completion": run["completion"],
            "success": run["success"],
            "min_frechet_m": run["min_frechet_m"],
            "corridor_violation_pct": run["corridor_violation_pct"],
            "jitter": run["jitter"],
        }
    summary = []
    for lo, hi in groups:
        row: dict[str, Any] = {"seeds": f"{lo}-{hi}"}
        for method in ("Real", "splat", "Sim"):
            runs = [per_seed[s][method] for s in range(lo, hi + 1) if method in per_seed.get(s, {})]
            ok = [r for r in runs if r["success"]]
            row[method] = {
                "runs": len(runs),
                "failures": len(runs) - len(ok),
                "completion_mean": sum(r["completion"] for r in runs) / max(1, len(runs)),
                "min_frechet_m": _mean([r["min_frechet_m"] for r in ok]),
                "corridor_violation_pct": _mean([r["corridor_violation_pct"] for r in ok]),
                "jitter": _mean([r["jitter"] for r in runs]),
            }
        summary.append(row)
    truth = ev.get("truth") or {}
    return {
        "machine": _machine(),
        "steps": {k: {"state": v["state"], "seconds": v["seconds"]} for k, v in steps.items()},
        "splat_message": steps.get("splat", {}).get("message", ""),
        "splat_held_out": {k: (ev.get(k) or {}).get("mean") for k in ("psnr_db", "ssim", "lpips")},
        "splat_truth": truth.get("scores", []),
        "splat_gate": metrics.get("splat_gate"),
        "methods": metrics["methods"],
        "per_seed": per_seed,
        "groups": summary,
    }


def _mean(values: list[float | None]) -> float | None:
    kept = [v for v in values if v is not None]
    return sum(kept) / len(kept) if kept else None


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def main() -> int:
    """Run the demo, print the tables, write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--groups", default="0-2")
    parser.add_argument("--world", help="the demo street (cam2sim demo --world)")
    parser.add_argument("--osm", type=Path, help="a real OSM file (cam2sim demo --osm)")
    parser.add_argument("--route", nargs=2, metavar="LAT,LON", help="with --osm")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--no-run", action="store_true", help="only read an existing OUT")
    args = parser.parse_args()
    started = time.perf_counter()
    if not args.no_run:
        cmd = [
            sys.executable,
            "-m",
            "cam2sim",
            "demo",
            "-o",
            str(args.out),
            "--runs",
            str(args.runs),
        ]
        cmd += ["--world", args.world] if args.world else []
        cmd += ["--osm", str(args.osm)] if args.osm else []
        cmd += ["--route", *args.route] if args.route else []
        subprocess.run(cmd, check=True)
    wall = time.perf_counter() - started
    result = summarise(args.out / "ws", _groups(args.groups))
    result["wall_s"] = None if args.no_run else round(wall, 1)
    print(f"machine: {result['machine']}; demo wall {_fmt(result['wall_s'], '.0f')} s")
    print(" | ".join(f"{k} {v['seconds']:.1f} s" for k, v in result["steps"].items()))
    print(f"splat: {result['splat_message']}")
    for row in result["splat_truth"]:
        print(
            f"  vs truth lateral {row['lateral_m']:+.1f} m yaw {row['yaw_deg']:+.0f}: "
            f"PSNR {_fmt(row['psnr_db']['mean'], '.2f')} SSIM {_fmt(row['ssim']['mean'], '.3f')} "
            f"LPIPS {_fmt(row['lpips']['mean'], '.3f')}"
        )
    print("seed | " + " | ".join(f"{m} completion" for m in ("Real", "splat", "Sim")))
    for seed, row in sorted(result["per_seed"].items()):
        cells = [
            _fmt(row[m]["completion"], ".2f") if m in row else "-" for m in ("Real", "splat", "Sim")
        ]
        print(f"{seed} | " + " | ".join(cells))
    for g in result["groups"]:
        for m in ("Real", "splat", "Sim"):
            s = g[m]
            print(
                f"seeds {g['seeds']} {m}: {s['failures']}/{s['runs']} failures, completion "
                f"{s['completion_mean']:.2f}, Min-Fréchet {_fmt(s['min_frechet_m'], '.2f')} m, "
                f"corridor {_fmt(s['corridor_violation_pct'], '.1f')} %, "
                f"jitter {_fmt(s['jitter'], '.3f')}"
            )
    if args.json:
        args.json.write_text(json.dumps(result, indent=1, default=str) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
