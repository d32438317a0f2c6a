"""Does the splat's steering gap predict its drive? One point a street, over benchmark results.

The steering gap is measured on the splat alone, before any drive: the drives' DAVE-2 on the
splat's view minus on the truth's view at the route profile's stations on the recorded path
(mean of the absolute values). This sets it against the splat runs' Min-Fréchet (and their
distance to their Real twins, where measured) for every street of the given result folders,
prints the table and the Spearman rank correlations, and draws the figure.

    PYTHONPATH=src python benchmarks/steering_gap.py docs/results/issue37-latest \\
        docs/results/issue37-cpu-suite-10 docs/results/issue37-piedmont-cpu-2 \\
        -o docs/results/issue37-latest/steering-gap.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

from cam2sim.metrics.benchmark import WorldResult
from cam2sim.report.bench import gap_figure, gap_prediction, rank_correlation, steering_gap_mean


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", type=Path, nargs="+", help="result folders (worlds/*/)")
    parser.add_argument("-o", "--out", type=Path, required=True, help="the figure (PNG)")
    args = parser.parse_args()
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
            twins = splat.twin_frechet_runs_m
            twin = f"{sum(twins) / len(twins):.2f}" if twins else "-"
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
