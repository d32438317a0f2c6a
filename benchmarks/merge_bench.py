"""One benchmark report over the worlds of several benchmark folders (a suite run a world a call).

A one-GPU session that runs a suite one world per call (``ENTRY=i`` in ``gpu_bench.sh``) brings
back one folder per world (each ``bench.tgz`` unpacked). This moves their worlds into one folder
and writes the bench report over all of them (``summary.md``, ``tables/``, ``aggregate.json``;
the HTML report only with ``--html``), each world's log beside them as ``logs/LABEL.log``.

    PYTHONPATH=src python benchmarks/merge_bench.py /tmp/w0 /tmp/w1 -o docs/results/NAME --name N
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from cam2sim.metrics.benchmark import WorldResult, aggregate
from cam2sim.report.bench import write_bench_report


def write_report(out: Path, results: list[WorldResult], name: str, *, html: bool) -> str:
    """The bench report over ``results`` into ``out`` (the HTML page only with ``html``).

    Returns:
        The summary's headline (its text before the first section).
    """
    report = write_bench_report(out, results, aggregate(results), name=name)
    if not html:
        report.unlink()
    return (out / "summary.md").read_text().split("\n## ")[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", type=Path, nargs="+", help="benchmark folders (worlds/*/)")
    parser.add_argument("-o", "--out", type=Path, required=True)
    parser.add_argument("--name", required=True, help="the report's suite name")
    parser.add_argument("--html", action="store_true", help="keep the HTML report too")
    args = parser.parse_args()
    results: dict[str, WorldResult] = {}
    for folder in args.folders:
        for path in sorted(folder.glob("worlds/*/result.json")):
            result = WorldResult.load(path)
            if result.label in results:
                parser.error(f"{result.label} is in two folders; give each world once")
            results[result.label] = result
            target = args.out / "worlds" / result.label
            if target.exists():
                shutil.rmtree(target)
            shutil.copytree(path.parent, target)
            for log in folder.glob(f"logs/{result.label}*.log"):
                (args.out / "logs").mkdir(parents=True, exist_ok=True)
                shutil.copy(log, args.out / "logs" / log.name)
    if not results:
        parser.error("no worlds/*/result.json in the folders given")
    ordered = [results[label] for label in sorted(results)]
    print(write_report(args.out, ordered, args.name, html=args.html))


if __name__ == "__main__":
    main()
