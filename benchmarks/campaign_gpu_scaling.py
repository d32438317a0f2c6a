"""Closed-loop campaigns across GPUs through Ray (issue 41): the same runs on 1 and 4 GPUs.

``cam2sim campaign PLAN --ray local`` runs every drive as a Ray task; a splat-camera run asks
for a GPU (``--gpus-per-run``: a share of one), a raster-camera run for one CPU. This script runs
one plan (the given workspaces x each one's own DAVE-2 x ``--cameras`` x ``--seeds``) once per
``--levels`` entry ``GxF`` (G GPUs, F of a GPU a splat run), each level in its own process with
``CUDA_VISIBLE_DEVICES`` set to its first G GPUs (its local Ray instance sees only those) and
its own campaign folder, while ``nvidia-smi`` samples every GPU's utilisation twice a second::

    python benchmarks/campaign_gpu_scaling.py WS1 WS2 WS3 WS4 --levels 1x1,4x1,4x0.5 \
        --seeds 0,1,2 --cameras splat,raster --out campaign_scaling.json

Writes the JSON after each level: the campaign's wall time (Ray's start included) and the
runs' wall time, runs/min, the speed-up over the first level, each GPU's mean utilisation
while the runs ran, the runs each GPU did, and per run its status and metrics and what its
``run.json`` says of its time (the loop's seconds, a frame's render and a policy call's
milliseconds: the rest of the run's seconds is its set-up); at the end how many runs' metrics
(status, completion, Min-Fréchet, corridor) are identical on every level.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

KEYS = ("status", "completion", "min_frechet_m", "corridor_violation_pct", "ended_by")


def _level(args: argparse.Namespace, gpus: int, share: float) -> dict[str, Any]:
    """One campaign on a local Ray instance with ``gpus`` GPUs, ``share`` of one a splat run."""
    from cam2sim.campaign.executors import RayCluster  # noqa: PLC0415 -- after the env is set
    from cam2sim.campaign.runner import run_campaign  # noqa: PLC0415

    folder = Path(args.work) / f"level-{gpus}x{share:g}"
    folder.mkdir(parents=True, exist_ok=True)
    plan = {
        "name": f"scaling-{gpus}x{share:g}",
        "output": str(folder / "campaign"),
        "workspaces": [str(Path(w).resolve()) for w in args.workspaces],
        "policies": ["workspace-model"],
        "cameras": args.cameras.split(","),
        "seeds": [int(s) for s in args.seeds.split(",")],
        "drive": {"steering_noise_std": args.noise},
        "timeout_s": 600,
    }
    path = folder / "plan.yaml"
    path.write_text(json.dumps(plan), encoding="utf-8")  # JSON is YAML
    started = time.perf_counter()
    result = run_campaign(path, executor=RayCluster("local", gpus_per_job=share))
    wall = time.perf_counter() - started
    return {
        "gpus": gpus,
        "gpus_per_run": share,
        "runs": result.ran,
        "failed": result.failed,
        "wall_s": wall,
        "runs_s": result.seconds,
        "runs_per_min": 60.0 * result.ran / result.seconds,
        "places": dict(Counter(r.place for r in result.rows if r.place)),
        "rows": [
            {"spec_id": r.spec_id, "camera": r.camera, "seconds": r.seconds}
            | {k: getattr(r, k) for k in KEYS}
            | _profile(r.workspace, r.run_id)
            for r in result.rows
        ],
    }


def _profile(workspace: str, run_id: str | None) -> dict[str, Any]:
    """What the run's own record says of its time: the loop's seconds and steps, and a
    frame's render and a policy call's milliseconds (the rest of a run's seconds is set-up)."""
    if run_id is None:
        return {}
    meta = json.loads((Path(workspace) / "runs" / run_id / "run.json").read_text())
    return {k: meta.get(k) for k in ("steps", "render_ms", "policy_ms")} | {
        "loop_s": meta.get("seconds")
    }


class _Sampler:
    """``nvidia-smi`` utilisation samples (every 0.5 s) of every GPU, in the background."""

    def __init__(self) -> None:
        self.samples: list[tuple[float, int, float]] = []
        try:
            self._proc: subprocess.Popen[str] | None = subprocess.Popen(
                ["nvidia-smi", "--query-gpu=index,utilization.gpu", "--format=csv,noheader,nounits",
                 "-lms", "500"],
                stdout=subprocess.PIPE, text=True,
            )  # fmt: skip
        except FileNotFoundError:  # no NVIDIA driver: no samples
            self._proc = None
            return
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        assert self._proc is not None
        assert self._proc.stdout is not None
        for line in self._proc.stdout:
            index, _, util = line.partition(",")
            if util.strip().isdigit():
                self.samples.append((time.time(), int(index), float(util)))

    def mean(self, since: float, until: float, gpus: int) -> list[float | None]:
        """Each of the first ``gpus`` GPUs' mean utilisation (%) between two times."""
        means: list[float | None] = []
        for gpu in range(gpus):
            values = [u for t, i, u in self.samples if i == gpu and since <= t <= until]
            means.append(sum(values) / len(values) if values else None)
        return means

    def stop(self) -> None:
        if self._proc is not None:
            self._proc.terminate()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("workspaces", nargs="+", help="workspaces with a splat and ads/dave2.onnx")
    parser.add_argument("--levels", default="1x1,4x1", help="GxF entries: G GPUs, F a run")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--cameras", default="splat,raster")
    parser.add_argument("--noise", type=float, default=0.05, help="steering noise (seeds differ)")
    parser.add_argument("--out", default="campaign_scaling.json")
    parser.add_argument("--level", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--work", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.level is not None:  # a child: one level, its row on the last line
        gpus, share = args.level.split("x")
        print(json.dumps(_level(args, int(gpus), float(share))))
        return 0
    work = Path(tempfile.mkdtemp(prefix="campaign-scaling-"))
    results: dict[str, Any] = {"args": {k: str(v) for k, v in vars(args).items()}, "levels": []}
    sampler = _Sampler()
    try:
        for level in args.levels.split(","):
            gpus = int(level.split("x")[0])
            env = dict(os.environ, CUDA_VISIBLE_DEVICES=",".join(str(i) for i in range(gpus)))
            cmd = [sys.executable, __file__, *args.workspaces, "--level", level,
                   "--work", str(work), "--seeds", args.seeds, "--cameras", args.cameras,
                   "--noise", str(args.noise)]  # fmt: skip
            since = time.time()
            done = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
            until = time.time()
            if done.returncode != 0:
                print(done.stdout[-3000:], done.stderr[-3000:], file=sys.stderr)
                return done.returncode
            row = json.loads(done.stdout.strip().splitlines()[-1])
            row["gpu_utilisation_pct"] = sampler.mean(since, until, gpus)
            first = results["levels"][0] if results["levels"] else row
            row["speedup"] = row["runs_per_min"] / first["runs_per_min"]
            results["levels"].append(row)
            util = ", ".join("-" if u is None else f"{u:.0f}" for u in row["gpu_utilisation_pct"])
            print(f"{level}: {row['runs']} runs in {row['runs_s']:.1f} s "
                  f"({row['runs_per_min']:.1f} runs/min, {row['speedup']:.2f}x; campaign "
                  f"{row['wall_s']:.1f} s), GPU use % {util}, {row['failed']} not done",
                  flush=True)  # fmt: skip
            splat = [r for r in row["rows"] if r["camera"] == "splat" and r.get("loop_s")]
            if splat:
                n = len(splat)
                print(f"  splat runs: {sum(r['seconds'] for r in splat) / n:.2f} s a run, of it "
                      f"the loop {sum(r['loop_s'] for r in splat) / n:.2f} s; a frame "
                      f"{sum(r['render_ms'] for r in splat) / n:.1f} ms, a policy call "
                      f"{sum(r['policy_ms'] for r in splat) / n:.2f} ms", flush=True)  # fmt: skip
            Path(args.out).write_text(json.dumps(results, indent=2) + "\n")
    finally:
        sampler.stop()
    per_level = [
        {r["spec_id"]: [r[k] for k in KEYS] for r in level["rows"]} for level in results["levels"]
    ]
    same = sum(all(p.get(i) == per_level[0][i] for p in per_level) for i in per_level[0])
    results["identical_runs"] = f"{same} of {len(per_level[0])}"
    Path(args.out).write_text(json.dumps(results, indent=2) + "\n")
    print(f"runs with identical metrics on every level: {results['identical_runs']} -> {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
