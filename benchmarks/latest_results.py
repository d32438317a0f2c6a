"""Each street's latest GPU result in one benchmark report: `docs/results/issue37-latest`.

The 14-street GPU suite has been run in parts over several one-GPU sessions since its third whole
run (the presets changed between them). This takes, for each street, the result of its latest
run (the runs named below, later ones overriding earlier), copies them into one benchmark folder
and writes the bench report over them (`summary.md`, `tables/`, `aggregate.json`; the HTML
report only with `--html`: its embedded figures weigh 1.5 MB), with `SOURCES.md` saying which
run each street's result comes from. The presets are mixed: the report says so in its title.

    PYTHONPATH=src python benchmarks/latest_results.py [--html]
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from cam2sim.metrics.benchmark import WorldResult
from merge_bench import write_report  # this folder's: one report over the results

RESULTS = Path(__file__).resolve().parents[1] / "docs" / "results"

#: (result files, which run), oldest first: a later run's street overrides an earlier one's.
RUNS = (
    ("issue37-gpu-suite-3/worlds/*/result.json", "third suite run, 2,500-step preset"),
    ("issue37-gpu-preset/worlds/*/result.json", "2,500-5,000-step preset, 4 worlds on an H100"),
    ("issue37-steps-check/result.json", "5,000 steps a chunk, alone on an H100"),
    ("issue37-preset-check/worlds/*/result.json", "the fixed preset, alone on an H100"),
    ("issue37-preset-alone/worlds/*/result.json", "the fixed preset and threads, alone on an H100"),
    ("issue37-preset-3/worlds/*/result.json", "the fixed preset, 5 worlds on an H100"),
    (
        "issue37-alone/worlds/*/result.json",
        "the fixed preset, detect and scenario beside the splat, alone on an H100",
    ),
    (
        "issue37-alone-thinned/worlds/*/result.json",
        "the fixed preset from 250,000 points a chunk, alone on an H100",
    ),
    (
        "issue37-capped/worlds/*/result.json",
        (
            "the fixed preset from 250,000 points a chunk, growth stopped at 400,000"
            " (the GPU preset since), alone on an H100"
        ),
    ),
    (
        "issue37-equal/worlds/*/result.json",
        "the GPU preset with splat chunks of equal length, a world a call, alone on an H100",
    ),
    (
        "issue37-picked/worlds/*/result.json",
        "the GPU preset, routes driven as picked (300-400 m), a world a call, alone on an H100",
    ),
    (
        "issue37-ownseeds/worlds/*/result.json",
        "the GPU preset, the street's own seeds, 2-3 worlds at a time sharing an H100",
    ),
)


def _seeds(result: WorldResult) -> str:
    """Which runs the street drew: its own seeds, or the ones every street shared before."""
    if result.run_seed is None:
        return "seeds 0-2, the same on every street (before commit e6e2692)"
    return f"its own seeds from {result.run_seed}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--html", action="store_true", help="keep the HTML report too")
    parser.add_argument("-o", "--out", type=Path, default=RESULTS / "issue37-latest")
    args = parser.parse_args()
    latest: dict[str, tuple[Path, WorldResult, str]] = {}
    for pattern, run in RUNS:
        for path in sorted(RESULTS.glob(pattern)):
            folder = path.relative_to(RESULTS).parts[0]
            result = WorldResult.load(path)
            latest[result.label] = (path, result, f"{run} (docs/results/{folder})")
    if args.out.exists():
        shutil.rmtree(args.out)
    for label, (path, _result, _run) in sorted(latest.items()):
        (args.out / "worlds" / label).mkdir(parents=True)
        shutil.copy(path, args.out / "worlds" / label / "result.json")
    results = [result for _label, (_path, result, _run) in sorted(latest.items())]
    name = "streets-gpu: each street's latest run (mixed presets)"
    headline = write_report(args.out, results, name, html=args.html)
    lines = [
        f"- {label}: {run}; {_seeds(result)}\n"
        for label, (_path, result, run) in sorted(latest.items())
    ]
    (args.out / "SOURCES.md").write_text(
        "# Which run each street's result comes from\n\n" + "".join(lines)
    )
    print(headline)


if __name__ == "__main__":
    main()
