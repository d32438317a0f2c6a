"""``cam2sim demo``: build a small synthetic recording and run the whole pipeline on it."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from cam2sim.cli.display import console, progress_bars
from cam2sim.cli.options import SkipOption, StepsOption, comma_list
from cam2sim.cli.run_cmd import _finish

__all__ = ["demo"]


def demo(
    *,
    out: Annotated[
        Path, typer.Option("--out", "-o", help="Folder for the recording and the workspace.")
    ] = Path("cam2sim-demo"),
    steps: StepsOption = None,
    skip: SkipOption = None,
    runs: Annotated[int, typer.Option(min=1, help="Drive runs per camera.")] = 3,
    seed: Annotated[int, typer.Option(help="Seed of the demo world and its noise.")] = 0,
    world: Annotated[
        str | None,
        typer.Option(
            help=(
                "The demo street: 'l-street' (the default: 183 m, one bend, 8 m/s) or 'paper' "
                "(the paper's street: 450 m, three bends, unmarked, parked cars narrowing the "
                "lane, 20 km/h)."
            )
        ),
    ] = None,
    osm: Annotated[
        Path | None,
        typer.Option(
            exists=True,
            dir_okay=False,
            help=(
                "Build the world from a real OpenStreetMap file (.osm, .osm.bz2, .osm.pbf): its "
                "street geometry, tags and building footprints; instead of --world."
            ),
        ),
    ] = None,
    route: Annotated[
        tuple[str, str] | None,
        typer.Option(
            metavar="LAT,LON LAT,LON",
            help=(
                "With --osm: drive the shortest road path between these two points (else a "
                "300-400 m route with two bends is picked)."
            ),
        ),
    ] = None,
) -> None:
    """Build a demo recording (a residential street near Munich) and run every stage on it.

    Needs no GPU, no CARLA server and no network. The recording (a ROS2 MCAP bag, an OSM file
    and a config) goes to OUT once; the workspace is OUT/ws, with the demo's ground-truth world
    in OUT/ws/truth/world.json: DAVE-2 drives RUNS times each in it (Real), with splat images
    and with simulator images. Re-run to resume.

    Example: cam2sim demo -o /tmp/demo   (or: cam2sim demo -o /tmp/paper --world paper, or
    cam2sim demo -o /tmp/munich --osm munich.osm)
    """
    from cam2sim.stages.experiment import (  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
        ExperimentOptions,
        WorldSource,
        run_experiment,
    )
    from cam2sim.stages.pipeline import STEPS  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    started = time.perf_counter()
    source = WorldSource(
        builtin=world, osm=osm, route=route if route is None else (route[0], route[1])
    )
    options = ExperimentOptions(
        runs=runs, seed=seed, steps=comma_list(steps) or STEPS, skip=comma_list(skip)
    )
    with progress_bars() as sink:
        done = run_experiment(
            out,
            source,
            options,
            progress=sink,
            say=lambda line: console.print(line, highlight=False),
        )
    ws, result = done.ws, done.result
    _finish(ws, result, time.perf_counter() - started)
