"""Campaign throughput (issue 12): runs per minute on the local process pool and on Ray.

One synthetic curved street (``--length`` m, radius 80 m, 4 parked cars) is written into a
temporary workspace; a campaign of ``--runs`` closed-loop runs (pure pursuit, the ``--camera``
camera at ``--size``, seeds 0..runs-1 with steering noise so every run differs) is run

- on a local pool of 1 worker (the serial baseline) and of ``--workers`` workers,
- on a local Ray instance of ``--workers`` CPUs (started once; its start-up is reported apart),

each in a fresh campaign folder. Reported: wall time of the runs, runs per minute, and whether
the metrics of all three are identical. Then the fixed cost per task of each executor: the
wall time of ``--noop`` empty tasks through a warm ``ProcessPoolExecutor`` and through Ray.

Run from the repository root::

    python benchmarks/campaign.py [--runs 16] [--workers 2] [--camera raster] [--size 200x66]
"""

from __future__ import annotations

import argparse
import concurrent.futures
import multiprocessing
import os
import platform
import tempfile
import time
from pathlib import Path

import ray

from cam2sim.campaign.executors import LocalPool, RayCluster
from cam2sim.campaign.runner import CampaignResult, run_campaign
from cam2sim.core.config import Config, RecordingConfig
from cam2sim.core.workspace import Workspace
from cam2sim.scenario.synthetic import StreetSpec, synthetic_street

PLAN = """
workspaces: [ws]
policies: [pure-pursuit]
cameras: [{camera}]
seeds: {seeds}
drive: {{image_size: [{w}, {h}], steering_noise_std: 1.0}}
output: {output}
"""


def _noop(_: int = 0) -> int:
    return 0


def _workspace(root: Path, length: float) -> None:
    ws = Workspace.create(root, Config(recording=RecordingConfig(bags=[str(root / "none")])))
    spec = StreetSpec(
        length_m=length,
        radius_m=80.0,
        parked=tuple((20.0 + 40.0 * k, -4.75 if k % 2 else 4.75, 0.0) for k in range(4)),
    )
    scenario, xodr = synthetic_street(spec)
    ws.map_dir.mkdir(parents=True)
    (ws.map_dir / "map.xodr").write_text(xodr, encoding="utf-8")
    ws.scenario_dir.mkdir(parents=True)
    scenario.save(ws.scenario_dir / "scenario.json")


def _campaign(
    root: Path, args: argparse.Namespace, output: str, executor: LocalPool | RayCluster
) -> CampaignResult:
    w, h = (int(v) for v in args.size.split("x"))
    plan = root / f"{output}.yaml"
    seeds = list(range(args.runs))
    plan.write_text(PLAN.format(camera=args.camera, seeds=seeds, w=w, h=h, output=output))
    return run_campaign(plan, executor=executor)


def _report(name: str, result: CampaignResult) -> float:
    rate = 60.0 * result.ran / result.seconds
    busy = sum(r.seconds or 0.0 for r in result.rows)
    print(
        f"{name:<28} {result.ran} runs in {result.seconds:6.2f} s = {rate:6.1f} runs/min; "
        f"run time summed {busy:6.2f} s ({busy / result.ran:.2f} s per run in its worker)"
    )
    return rate


def _overhead(n: int, workers: int) -> tuple[float, float, float]:
    """Pool start-up (s), then milliseconds per empty task: a warm spawn pool, and Ray."""
    context = multiprocessing.get_context("spawn")
    t0 = time.perf_counter()
    with concurrent.futures.ProcessPoolExecutor(workers, mp_context=context) as pool:
        list(pool.map(_noop, range(workers * 2)))  # warm: workers started
        startup = time.perf_counter() - t0
        t0 = time.perf_counter()
        list(pool.map(_noop, range(n)))
        pool_ms = 1e3 * (time.perf_counter() - t0) / n
    task = ray.remote(num_cpus=1)(_noop)
    ray.get([task.remote() for _ in range(workers * 2)])
    t0 = time.perf_counter()
    ray.get([task.remote() for _ in range(n)])
    ray_ms = 1e3 * (time.perf_counter() - t0) / n
    return startup, pool_ms, ray_ms


def _metrics(result: CampaignResult) -> list[tuple[object, ...]]:
    return [(r.spec_id, r.status, r.completion, r.min_frechet_m) for r in result.rows]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=16)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--camera", default="raster", choices=["raster", "none"])
    parser.add_argument("--size", default="200x66")
    parser.add_argument("--length", type=float, default=160.0)
    parser.add_argument("--noop", type=int, default=500)
    args = parser.parse_args()
    print(
        f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
        f", ray {ray.__version__}; {args.runs} runs, camera {args.camera} {args.size}, "
        f"{args.length:.0f} m street"
    )
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        _workspace(root / "ws", args.length)
        serial = _campaign(root, args, "serial", LocalPool(1))
        base = _report("local pool, 1 worker", serial)
        pool = _campaign(root, args, "pool", LocalPool(args.workers))
        rate = _report(f"local pool, {args.workers} workers", pool)
        t0 = time.perf_counter()
        ray.init(num_cpus=args.workers, include_dashboard=False, log_to_driver=False)
        print(f"ray.init (local, {args.workers} CPUs): {time.perf_counter() - t0:.2f} s")
        on_ray = _campaign(root, args, "ray", RayCluster())
        ray_rate = _report(f"ray, {args.workers} CPUs", on_ray)
        print(
            f"speed-up over 1 worker: pool {rate / base:.2f}x, ray {ray_rate / base:.2f}x; "
            f"per-run mean (1 worker) {serial.seconds / serial.ran:.2f} s"
        )
        same = _metrics(serial) == _metrics(pool) == _metrics(on_ray)
        print(f"identical metrics on all three: {same}")
        startup, pool_ms, ray_ms = _overhead(args.noop, args.workers)
        print(f"fixed cost per empty task: spawn pool {pool_ms:.2f} ms, ray {ray_ms:.2f} ms")
        print(f"spawn pool start-up ({args.workers} workers, bare): {startup:.2f} s")
        ray.shutdown()


if __name__ == "__main__":
    main()
