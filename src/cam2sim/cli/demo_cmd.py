"""``cam2sim demo``: build a small synthetic recording and run the whole pipeline on it."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from cam2sim.cli.display import console, error_console, progress_bars
from cam2sim.cli.options import SkipOption, StepsOption, comma_list
from cam2sim.cli.run_pipeline_cmd import _finish, _workspace
from cam2sim.core.errors import Cam2SimError, ConfigError
from cam2sim.core.files import write_bytes_atomic

__all__ = ["DEMO_STEERING_NOISE", "demo"]

DEMO_STEERING_NOISE = 0.05
"""Steering noise of the demo's drives (steering units, each simulator step, seeded per run)."""


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
                "300-500 m route with two bends is picked)."
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
    from cam2sim.ads.train import TrainOptions  # noqa: PLC0415 -- lazy: imports torch, cv2
    from cam2sim.demo.recording import (  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
        build_demo_recording,
        load_demo_recording,
        recorded_street,
    )
    from cam2sim.demo.world import demo_street  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
    from cam2sim.render.truth import truth_world_path  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
    from cam2sim.stages.pipeline import (  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
        STEPS,
        PipelineOptions,
        demo_splat_options,
        run_pipeline,
    )
    from cam2sim.stages.variation import DEMO_RUN_VARIATION  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    started = time.perf_counter()
    try:
        plan = None
        if osm is not None:
            if world is not None:
                msg = "give --world or --osm, not both"
                raise ConfigError(msg)
            from cam2sim.demo.osm_world import osm_demo_world  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

            plan = osm_demo_world(osm, route=route, seed=seed)
            street = plan.world.street
            console.print(f"demo world: {street.title}", highlight=False)
            for note in plan.notes:
                console.print(f"  {note}", highlight=False)
        elif route is not None:
            msg = "--route needs --osm (the OSM file the route runs on)"
            raise ConfigError(msg)
        else:
            street = demo_street(world or "l-street")
        there = recorded_street(out)
        if there is not None and there != street.name:
            msg = (
                f"{out} holds the demo of world '{there}'; give another --out for "
                f"'{street.name}' (or the same --world/--osm as before to resume it)"
            )
            raise ConfigError(msg)
        options = PipelineOptions(
            steps=comma_list(steps) or STEPS, skip=comma_list(skip), runs=runs
        )
        with progress_bars(enabled=sys.stderr.isatty()) as sink:
            recording = load_demo_recording(out, street)
            if recording is None:
                recording = build_demo_recording(
                    out,
                    seed=seed,
                    street=street,
                    world=plan.world if plan is not None else None,
                    progress=sink,
                )
                built = time.perf_counter() - started
                console.print(
                    f"demo recording: {recording.bag} ({recording.camera_frames} frames, "
                    f"{recording.duration_s:.0f} s) in {built:.0f} s",
                    highlight=False,
                )
            else:
                console.print(f"demo recording: {recording.bag} (already built)", highlight=False)
            options = PipelineOptions(
                osm=recording.osm,
                steps=options.steps,
                skip=options.skip,
                runs=runs,
                replay_every=6,  # 20 Hz camera: 76 replayed frames
                steering_noise_std=DEMO_STEERING_NOISE,
                # Runs differ as a driver's repeated drives do: start pose and speed.
                run_variation=DEMO_RUN_VARIATION,
                splat=demo_splat_options(cuda=_cuda()),
                splat_on_cpu=True,
                # 23 s of driving (81 s on the paper's street): the held-out tail (the last
                # straight) cannot choose the
                # epoch, so all 30 are trained and the last is kept (docs/benchmarks.md).
                # On the CPU everywhere: the same seeded model on a laptop and a GPU machine (a
                # CUDA-trained one left the road in the ground-truth world; docs/benchmarks.md).
                ads=TrainOptions(epochs=30, batch_size=32, keep="last", device="cpu"),
            )
            ws = _workspace(out / "ws", [], recording.config)
            truth = recording.truth_world.read_bytes()
            target = truth_world_path(ws.root)
            if not target.is_file() or target.read_bytes() != truth:
                write_bytes_atomic(target, truth)
            result = run_pipeline(ws, options=options, progress=sink)
    except Cam2SimError as err:
        error_console.print(f"[bold red]error:[/] {escape(str(err))}", highlight=False)
        raise typer.Exit(1) from None
    _finish(ws, result, time.perf_counter() - started)


def _cuda() -> bool:
    """Whether a CUDA GPU is there for the splat (torch is imported by the pipeline anyway)."""
    import torch  # noqa: PLC0415

    return bool(torch.cuda.is_available())
