"""``cam2sim scenario``: CARLA-ready assets and an OpenSCENARIO file of the recorded street."""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path  # noqa: TC003 - typer reads annotations at run time
from typing import Annotated

import typer

from cam2sim.cli.display import console, progress_bars
from cam2sim.core.workspace import Workspace

__all__ = ["HeadingChoice", "scenario"]


class HeadingChoice(StrEnum):
    """Where the trajectory's heading comes from."""

    ORIENTATION = "orientation"
    MOTION = "motion"


def scenario(
    workspace: Annotated[Path, typer.Argument(help="The workspace folder.")],
    *,
    heading: Annotated[
        HeadingChoice,
        typer.Option(help="Heading from the recorded orientation, or from the motion."),
    ] = HeadingChoice.ORIENTATION,
    keep_conflicts: Annotated[
        bool,
        typer.Option(
            "--keep-conflicts",
            help="Spawn parked vehicles that fail the map checks anyway (still reported).",
        ),
    ] = False,
    force: Annotated[bool, typer.Option(help="Rebuild even if up to date.")] = False,
) -> None:
    """Build WS/scenario/: scenario.json, carla/*.json, scenario.xosc and scenario.png.

    Needs the dataset (extract) and the map; parked vehicles come from `cam2sim detect` when it
    has run. The vehicle geometry is the `vehicle` block of config.yaml.

    Example: cam2sim scenario ws --heading motion
    """
    from cam2sim.stages.scenario import ScenarioOptions, run_scenario  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    ws = Workspace.open(workspace)
    with progress_bars() as sink:
        result = run_scenario(
            ws,
            options=ScenarioOptions(heading=heading.value, keep_conflicts=keep_conflicts),
            force=force,
            progress=sink,
        )
    doc = result.scenario
    if doc is None:
        console.print(f"{result.folder} is up to date (use --force to rebuild)")
        return
    tr = doc.trajectory
    console.print(
        f"{result.folder}: {len(tr.frame)} poses over {tr.t[-1]:.1f} s, "
        f"{len(doc.parked)} parked vehicles, {len(doc.rejected)} left out",
        highlight=False,
    )
    for r in doc.rejected:
        console.print(f"  left out {r.id}: {'; '.join(r.reasons)}", highlight=False)
