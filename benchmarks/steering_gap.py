"""Does the splat's steering gap predict its drive? One point a street, over benchmark results.

The steering gap is measured on the splat alone, before any drive: the drives' DAVE-2 on the
splat's view minus on the truth's view at the route profile's stations on the recorded path
(mean of the absolute values). This sets it against the splat runs' Min-Fréchet (and their
distance to their Real twins, where measured) for every street of the given result folders,
prints the table and the Spearman rank correlations, and draws the figure.

    PYTHONPATH=src python benchmarks/steering_gap.py docs/results/issue37-latest \\
        docs/results/issue37-cpu-suite-10 docs/results/issue37-piedmont-cpu-2 \\
        -o docs/results/issue37-latest/steering-gap.png

``--along BENCH/worlds/LABEL ...`` (worlds with their workspaces) asks the same along the route:
at each profile station, the gap against how far the splat runs drift from their Real twins
over the next ``--ahead`` metres (their lateral offsets on the recorded path, mean over seeds).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from cam2sim.core.workspace import Workspace
from cam2sim.metrics.behaviour import evaluate_with_real_runs, recorded_drive
from cam2sim.metrics.benchmark import WorldResult
from cam2sim.metrics.drive_io import load_run_dir
from cam2sim.metrics.drive_quality import DriveOptions
from cam2sim.report.bench import gap_figure, gap_prediction, rank_correlation, steering_gap_mean
from cam2sim.scenario.model import Scenario
from cam2sim.stages.evaluate import drive_run_ids, lane_margin


def _drift_along(world: Path, ahead_m: float) -> tuple[str, list[float], list[float]]:
    """The world's steering gap at each station and the splat runs' drift from their twins."""
    result = WorldResult.load(world / "result.json")
    ws = Workspace.open(world / "ws")
    runs = [load_run_dir(ws.runs_dir / r) for r in drive_run_ids(ws)]
    recorded = recorded_drive(Scenario.load(ws.scenario_path))
    options = DriveOptions(single_drive_half_width_m=lane_margin(ws))
    ev = evaluate_with_real_runs([recorded], runs, options=options)
    by_seed: dict[int, dict[str, str]] = {}
    for run in ev.runs:
        if run.seed is not None:
            by_seed.setdefault(run.seed, {})[run.method] = run.name
    pairs = [m for m in by_seed.values() if "drive-splat" in m and "real" in m]
    drift = np.mean([ev.lateral[m["drive-splat"]] - ev.lateral[m["real"]] for m in pairs], 0)
    s_path = ev.corridor_s - ev.metrics.segment.start_m
    profile = result.profile or {}
    stations = np.asarray(profile["s_m"], dtype=np.float64)
    gap = np.asarray(profile["steering_splat"][1], float) - np.asarray(  # type: ignore[index]
        profile["steering_truth"][1],
        float,  # type: ignore[index]
    )
    moved = np.interp(stations + ahead_m, s_path, drift) - np.interp(stations, s_path, drift)
    keep = np.isfinite(gap) & np.isfinite(moved) & (stations + ahead_m <= s_path[-1])
    return result.label, list(gap[keep]), list(moved[keep])


def along(worlds: list[Path], ahead_m: float) -> None:
    """Print, per world and pooled, how the gap at a station orders the drift after it."""
    every_gap: list[float] = []
    every_move: list[float] = []
    for world in worlds:
        label, gap, moved = _drift_along(world, ahead_m)
        every_gap += gap
        every_move += moved
        print(f"{label}: {len(gap)} stations, Spearman {rank_correlation(gap, moved):+.2f}")
    rho = rank_correlation(every_gap, every_move)
    print(f"pooled: {len(every_gap)} stations, Spearman {rho:+.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", type=Path, nargs="*", help="result folders (worlds/*/)")
    parser.add_argument("-o", "--out", type=Path, help="the figure (PNG)")
    parser.add_argument("--along", type=Path, nargs="+", help="worlds with workspaces")
    parser.add_argument("--ahead", type=float, default=15.0, help="metres after a station")
    args = parser.parse_args()
    if args.along:
        along(args.along, args.ahead)
        return
    if args.out is None or not args.folders:
        parser.error("give result folders and -o FIGURE (or --along WORLD...)")
    results = []
    heads = ["results", "street", "tuned", "mean steering gap", "splat Min-Fréchet m", "to twin m"]
    print("| " + " | ".join([*heads, "splat/Real"]) + " |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for folder in args.folders:
        for path in sorted(folder.glob("worlds/*/result.json")):
            world = WorldResult.load(path)
            splat, real = world.method("splat"), world.method("Real")
            gap = steering_gap_mean(world)
            if gap is None or splat is None or splat.min_frechet_m is None:
                continue
            twin = "-" if splat.twin_frechet_m is None else f"{splat.twin_frechet_m:.2f}"
            ratio = (
                f"{splat.min_frechet_m / real.min_frechet_m:.2f}"
                if real is not None and real.min_frechet_m
                else "-"
            )
            tuned = "yes" if world.tuned else "no"
            print(f"| {folder.name} | {world.label} | {tuned} | {gap:.3f} | "
                  f"{splat.min_frechet_m:.2f} | {twin} | {ratio} |")  # fmt: skip
            results.append((folder.name, world))
    worlds = [w for _, w in results]
    print(gap_prediction(worlds))
    for name in dict.fromkeys(n for n, _ in results):
        part = [w for n, w in results if n == name]
        print(f"{name}: {gap_prediction(part)}")
    untuned = [w for w in worlds if not w.tuned]
    print(f"streets not used while tuning: {gap_prediction(untuned)}")
    ratios = [
        (steering_gap_mean(w), s.min_frechet_m / r.min_frechet_m)
        for w in worlds
        if (s := w.method("splat"))
        and (r := w.method("Real"))
        and s.min_frechet_m
        and r.min_frechet_m
    ]
    rho = rank_correlation(
        [g for g, _ in ratios if g is not None], [q for g, q in ratios if g is not None]
    )
    print(f"against the ratio splat/Real instead: Spearman {rho:.2f}" if rho is not None else "")
    fig = gap_figure(worlds)
    if fig is not None:
        fig.savefig(args.out, dpi=120)
        print(f"figure: {args.out}")


if __name__ == "__main__":
    main()
