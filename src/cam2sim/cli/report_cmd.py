"""``cam2sim report``: the self-contained HTML report of a workspace."""

from __future__ import annotations

from pathlib import Path  # noqa: TC003 - typer reads annotations at run time
from typing import Annotated

import typer

from cam2sim.cli.display import console, progress_bars
from cam2sim.core.workspace import Workspace

__all__ = ["report"]


def report(
    workspace: Annotated[Path, typer.Argument(help="The workspace folder.")],
    *,
    real: Annotated[
        list[Path] | None,
        typer.Option(
            help="Real drives (trajectory*.csv files or folders): score the drives against them "
            "first (cam2sim evaluate workspace --real); without it the report reads the metrics "
            "the evaluate stage wrote."
        ),
    ] = None,
    real_crs: Annotated[
        str, typer.Option(help="CRS of the real drives' x, y (UTM 32N for the reference car).")
    ] = "EPSG:32632",
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="Output file (default: WS/report/report.html)."),
    ] = None,
) -> None:
    """Write one self-contained HTML page: summary, map, behaviour, runs, frames, metrics.

    Example: cam2sim report ws --real ../shared/data/reference-drives
    """
    from cam2sim.report.html import write_report  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
    from cam2sim.stages.evaluate import EvaluateOptions, evaluate_workspace  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    ws = Workspace.open(workspace)
    with progress_bars() as sink:
        if real:  # scored against these drives first; the report itself only reads
            options = EvaluateOptions(real=tuple(real), real_crs=real_crs)
            evaluate_workspace(ws, options=options, progress=sink)
        path = write_report(ws, out=out, progress=sink)
    console.print(str(path), highlight=False, soft_wrap=True)
