"""The README's headline picture: each method's failure rate on the GPU street suite.

    python benchmarks/headline_figure.py [AGGREGATE_JSON] [OUT_PNG]

Reads a benchmark's ``aggregate.json`` (default: the GPU suite's, docs/results/) and draws the
rates with their 95 % Wilson intervals (``cam2sim.report.bench.rates_figure``).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from cam2sim.metrics.benchmark import Aggregate
from cam2sim.report.bench import rates_figure

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    """Write the picture."""
    src = (
        Path(sys.argv[1])
        if len(sys.argv) > 1
        else ROOT / "docs/results/issue37-gpu-suite-3/aggregate.json"
    )
    out = Path(sys.argv[2]) if len(sys.argv) > 2 else ROOT / "docs/results/headline.png"
    agg = Aggregate.model_validate(json.loads(src.read_text(encoding="utf-8")))
    title = f"DAVE-2 closed loop on {agg.streets} streets, 3 seeds each"
    rates_figure(agg, title=title).savefig(out, dpi=120, bbox_inches="tight")
    print(out)


if __name__ == "__main__":
    main()
