"""A finished benchmark's drives scored again by today's drive metrics, its report written again.

For a measure added after the suite ran (each run's distance to its Real twin): every world of
``BENCH/worlds/`` with a result and its workspace is rescored (``campaign.bench.rescore_world``);
the behaviour rows are replaced, checked first to keep every run's Min-Fréchet (the measure
itself did not change), then the bench report is written again over all worlds.

    PYTHONPATH=src python benchmarks/rescore_bench.py /tmp/cpu-suite10 --name streets-cpu \\
        [--copy docs/results/NAME]   # result.json, summary and tables also there
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
from pathlib import Path

from rich.progress import track

from cam2sim.campaign.bench import rescore_world
from cam2sim.core.errors import Cam2SimError
from cam2sim.metrics.benchmark import WorldResult, aggregate
from cam2sim.report.bench import write_bench_report


def _same(old: WorldResult, new: WorldResult) -> None:
    """Raise if a method's runs or their Min-Fréchet moved (beyond rounding)."""
    for row in old.methods:
        again = new.method(row.method)
        if again is None or (row.runs, row.failures) != (again.runs, again.failures):
            msg = f"{old.label} {row.method}: runs/failures changed on rescoring"
            raise Cam2SimError(msg)
        pairs = zip(row.min_frechet_runs_m, again.min_frechet_runs_m, strict=True)
        if any(not math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-9) for a, b in pairs):
            msg = f"{old.label} {row.method}: Min-Fréchet changed on rescoring"
            raise Cam2SimError(msg)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bench", type=Path, help="a benchmark folder (worlds/*/ws kept)")
    parser.add_argument("--name", required=True, help="the report's suite name")
    parser.add_argument("--copy", type=Path, help="also put result.json files and report here")
    args = parser.parse_args()
    worlds = sorted(p.parent for p in args.bench.glob("worlds/*/result.json"))
    agg_path = args.bench / "aggregate.json"
    if agg_path.is_file():  # the report's order as it was (the suite's)
        order = [p["label"] for p in json.loads(agg_path.read_text())["pairs"]]
        worlds.sort(key=lambda w: order.index(w.name) if w.name in order else len(order))
    if not worlds:
        parser.error(f"{args.bench} has no worlds/*/result.json")
    results = []
    for world in track(worlds, description="rescoring worlds"):
        old = WorldResult.load(world / "result.json")
        new = rescore_world(world)
        _same(old, new)
        new.save(world / "result.json")
        results.append(new)
        twins = {m.method: [round(t, 3) for t in m.twin_frechet_runs_m] for m in new.methods}
        print(f"{new.label}: to Real twin m {twins}")
    write_bench_report(args.bench, results, aggregate(results), name=args.name)
    if args.copy is not None:
        for world in worlds:
            dest = args.copy / "worlds" / world.name
            dest.mkdir(parents=True, exist_ok=True)
            shutil.copy2(world / "result.json", dest / "result.json")
        # the HTML page (its figures embedded, megabytes) stays in the benchmark folder
        write_bench_report(args.copy, results, aggregate(results), name=args.name).unlink()
    print((args.bench / "summary.md").read_text().split("\n## ")[0])


if __name__ == "__main__":
    main()
