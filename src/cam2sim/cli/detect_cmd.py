"""``cam2sim detect`` and ``cam2sim refine``: parked vehicles, found and then fixed by hand."""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path  # noqa: TC003 - typer reads annotations at run time
from typing import Annotated

import typer

from cam2sim.cli.display import console, print_table, progress_bars
from cam2sim.core.workspace import Workspace

__all__ = ["SourceChoice", "detect", "refine"]


class SourceChoice(StrEnum):
    """Which sensor the detector reads."""

    LIDAR = "lidar"
    CAMERA = "camera"


def detect(
    workspace: Annotated[Path, typer.Argument(help="The workspace folder.")],
    *,
    source: Annotated[
        SourceChoice | None,
        typer.Option(help="Sensor to detect in (default: lidar when the dataset has scans)."),
    ] = None,
    model: Annotated[
        str | None,
        typer.Option(
            help="Detector: 'geometric' (LiDAR, default), a .onnx / .pt model path, "
            "'pointpillars:CONFIG:CKPT' or 'fcos3d:CONFIG:CKPT' (mmdet3d)."
        ),
    ] = None,
    every: Annotated[int, typer.Option(min=1, help="Use every n-th scan or frame.")] = 1,
    min_hits: Annotated[
        int, typer.Option("--min-hits", min=1, help="Drop vehicles seen fewer times.")
    ] = 3,
    max_range: Annotated[
        float, typer.Option("--max-range", min=1.0, help="Ignore boxes farther away, metres.")
    ] = 40.0,
    snap: Annotated[
        bool, typer.Option(help="Snap vehicles to the map's road edge (run `cam2sim map` first).")
    ] = False,
    workers: Annotated[int, typer.Option(min=1, help="Detector threads.")] = 2,
    force: Annotated[bool, typer.Option(help="Run again even if up to date.")] = False,
) -> None:
    """Find parked vehicles and write WS/detections/parked_vehicles.json (+ a bird's-eye PNG).

    Example: cam2sim detect ws --source lidar --snap
    """
    from cam2sim.detect.fusion import FusionOptions  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
    from cam2sim.stages.detect import DetectOptions, run_detect  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    options = DetectOptions(
        source=None if source is None else source.value,
        model=model,
        every=every,
        fusion=FusionOptions(min_hits=min_hits, max_range_m=max_range),
        snap=snap,
        workers=workers,
    )
    ws = Workspace.open(workspace)
    with progress_bars() as sink:
        result = run_detect(ws, options=options, force=force, progress=sink)
    doc = result.vehicles
    if doc is None:
        console.print(f"{result.path} is up to date (use --force to run again)")
        return
    rows = [
        [
            v.id,
            f"{v.position[0]:.1f}, {v.position[1]:.1f}",
            f"{v.size[0]:.1f} x {v.size[1]:.1f}",
            v.side,
            v.orientation,
            str(v.hits),
            f"{v.confidence:.2f}",
        ]
        for v in doc.vehicles
    ]
    from rich.table import Table  # noqa: PLC0415

    table = Table(title=f"{len(doc.vehicles)} parked vehicles")
    for name in ("id", "x, y (m)", "size (m)", "side", "orientation", "hits", "conf"):
        table.add_column(name)
    for row in rows:
        table.add_row(*row)
    print_table(table)
    console.print(
        f"{result.path}: {len(doc.vehicles)} vehicles from {doc.detections} boxes in "
        f"{doc.frames_used} {doc.source} frames; picture {result.figure}",
        highlight=False,
    )


def refine(
    workspace: Annotated[Path, typer.Argument(help="The workspace folder.")],
    *,
    port: Annotated[int, typer.Option(min=0, max=65535, help="Port (0 = any free one).")] = 0,
    open_browser: Annotated[
        bool, typer.Option("--open/--no-open", help="Open the page in the default browser.")
    ] = True,
) -> None:
    """Edit WS/detections/parked_vehicles.json by hand in a local web page (127.0.0.1 only).

    Select, drag, rotate, resize, insert, delete, undo, save. Every save keeps the previous
    version under WS/detections/history/. Stop with Ctrl-C.

    Example: cam2sim refine ws --port 8765
    """
    from cam2sim.detect.editor import serve_editor  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    def ready(url: str) -> None:
        console.print(f"editor at {url} (Ctrl-C to stop)", highlight=False)

    try:
        ws = Workspace.open(workspace)
        serve_editor(ws, port=port, open_browser=open_browser, on_ready=ready)
    except KeyboardInterrupt:
        console.print("editor stopped")
