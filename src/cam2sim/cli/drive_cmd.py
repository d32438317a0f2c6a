"""``cam2sim replay`` and ``cam2sim drive``: trajectory replay and closed-loop runs."""

from __future__ import annotations

import math
from enum import StrEnum
from pathlib import Path  # noqa: TC003 - typer reads annotations at run time
from typing import TYPE_CHECKING, Annotated, Any

import typer

from cam2sim.cli.display import console, progress_bars
from cam2sim.cli.options import (
    CarlaHostOption,
    CarlaPortOption,
    SimChoice,
    SimOption,
)
from cam2sim.core.errors import ConfigError
from cam2sim.core.schema import format_validation_error
from cam2sim.core.workspace import Workspace

if TYPE_CHECKING:
    from cam2sim.sim.carla_backend import CarlaOptions

__all__ = ["drive", "replay"]


class ReplayCamera(StrEnum):
    """Cameras a replay renders."""

    RASTER = "raster"
    SPLAT = "splat"
    BOTH = "both"
    TRUTH = "truth"
    CARLA = "carla"


class DriveCamera(StrEnum):
    """The camera a policy sees."""

    RASTER = "raster"
    SPLAT = "splat"
    TRUTH = "truth"
    CARLA = "carla"
    NONE = "none"


class Judge(StrEnum):
    """Where leaving the road and collisions are judged."""

    MAP = "map"
    TRUTH = "truth"


def _carla(ws: Path, sim: SimChoice, host: str | None, port: int | None) -> CarlaOptions | None:
    """CARLA options: config.yaml's ``carla`` block, with --carla-host/--carla-port on top."""
    if sim is not SimChoice.CARLA or (host is None and port is None):
        return None  # the run reads config.yaml's carla block
    import pydantic  # noqa: PLC0415

    from cam2sim.sim.carla_backend import CarlaOptions  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    raw = dict(Workspace.open(ws).load_config().carla)
    raw |= {k: v for k, v in (("host", host), ("port", port)) if v is not None}
    try:
        return CarlaOptions.model_validate(raw)
    except pydantic.ValidationError as err:
        raise ConfigError(format_validation_error(err, source="carla options")) from None


def _span(text: str | None) -> tuple[int | None, int | None]:
    if not text:
        return (None, None)
    first, sep, stop = text.partition(":")
    if not sep:
        msg = f"--frames takes A:B (either side may be empty), got {text!r}"
        raise typer.BadParameter(msg)
    try:
        return (int(first) if first else None, int(stop) if stop else None)
    except ValueError:
        msg = f"--frames takes integers A:B, got {text!r}"
        raise typer.BadParameter(msg) from None


def _size(text: str | None) -> tuple[int, int] | None:
    if not text:
        return None
    w, sep, h = text.lower().partition("x")
    if not sep or not w.isdigit() or not h.isdigit() or int(w) < 1 or int(h) < 1:
        msg = f"--size takes WIDTHxHEIGHT in pixels, e.g. 200x66, got {text!r}"
        raise typer.BadParameter(msg)
    return int(w), int(h)


def _variation(text: str | None) -> Any:
    """``--vary LATERAL_M,HEADING_DEG,SPEED`` as a RunVariation (None: no variation)."""
    if not text:
        return None
    from cam2sim.stages.variation import RunVariation  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    parts = text.split(",")
    try:
        lateral, heading, speed = (float(v) for v in parts)
        return RunVariation(start_lateral_m=lateral, start_heading_deg=heading, speed=speed)
    except ValueError:
        msg = (
            "--vary takes LATERAL_M,HEADING_DEG,SPEED standard deviations (>= 0; speed as a "
            f"fraction below 0.5), e.g. 0.1,0.5,0.03; got {text!r}"
        )
        raise typer.BadParameter(msg) from None


def replay(
    workspace: Annotated[Path, typer.Argument(help="The workspace folder.")],
    *,
    camera: Annotated[
        ReplayCamera, typer.Option(help="Camera(s) to render.")
    ] = ReplayCamera.RASTER,
    frames: Annotated[
        str | None, typer.Option(help="Samples A:B of the recorded trajectory (default: all).")
    ] = None,
    size: Annotated[
        str | None, typer.Option(help="Render size WIDTHxHEIGHT (default: the calibrated one).")
    ] = None,
    video: Annotated[bool, typer.Option("--video/--no-video", help="Write video.mp4.")] = True,
    sim: SimOption = SimChoice.BUILTIN,
    carla_host: CarlaHostOption = None,
    carla_port: CarlaPortOption = None,
) -> None:
    """Replay the recorded trajectory exactly: frames per camera, side by side with the real one.

    Example: cam2sim replay ws --camera both --frames 0:300
    """
    from cam2sim.stages.runs import ReplayOptions  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
    from cam2sim.stages.runs import replay as run_replay  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    cams = ("raster", "splat") if camera is ReplayCamera.BOTH else (camera.value,)
    if sim is SimChoice.CARLA and "carla" not in cams:
        cams = (*cams, "carla")
    opts = ReplayOptions(
        cameras=cams,  # type: ignore[arg-type]
        frames=_span(frames),
        image_size=_size(size),
        video=video,
        simulator=sim.value,
        carla=_carla(workspace, sim, carla_host, carla_port),
    )
    ws = Workspace.open(workspace)
    with progress_bars() as sink:
        result = run_replay(ws, options=opts, progress=sink)
    console.print(
        f"{result.folder}: {result.steps} frames replayed in {result.seconds:.1f} s",
        highlight=False,
    )


def _speed(text: str | None) -> float | None:
    """``--speed``: km/h, or None for 'recorded' and the default."""
    if text is None or text == "recorded":
        return None
    msg = f"--speed {text!r}: give km/h (a number >= 0) or 'recorded'"
    try:
        value = float(text)
    except ValueError:
        raise typer.BadParameter(msg) from None
    if not (math.isfinite(value) and value >= 0):
        raise typer.BadParameter(msg)
    return value


def drive(
    workspace: Annotated[Path, typer.Argument(help="The workspace folder.")],
    *,
    policy: Annotated[
        str,
        typer.Option(
            help="pure-pursuit, constant:VALUE, a .onnx/.pt steering model, or tcp://HOST:PORT."
        ),
    ] = "pure-pursuit",
    camera: Annotated[DriveCamera, typer.Option(help="What the policy sees.")] = DriveCamera.RASTER,
    runs: Annotated[int, typer.Option(min=1, help="Number of runs (seeds seed, seed+1, ...).")] = 1,
    speed: Annotated[
        str | None,
        typer.Option(
            help="Target speed in km/h, or 'recorded': the recorded speed along the route "
            "(default: the recorded start speed, held).",
        ),
    ] = None,
    seed: Annotated[int, typer.Option(help="Seed of the first run.")] = 0,
    every: Annotated[int, typer.Option(min=1, help="The policy answers every n-th step.")] = 3,
    size: Annotated[
        str | None, typer.Option(help="Camera size WIDTHxHEIGHT (default: the calibrated one).")
    ] = None,
    save_frames: Annotated[bool, typer.Option("--save-frames", help="Write the frames.")] = False,
    video: Annotated[bool, typer.Option("--video", help="Write video.mp4.")] = False,
    vary: Annotated[
        str | None,
        typer.Option(
            help="Seeded run-to-run variation: standard deviations LATERAL_M,HEADING_DEG,SPEED "
            "of the start offset and the speed factor, e.g. 0.1,0.5,0.03 (the demo's)."
        ),
    ] = None,
    sim: SimOption = SimChoice.BUILTIN,
    carla_host: CarlaHostOption = None,
    carla_port: CarlaPortOption = None,
    judge: Annotated[
        Judge,
        typer.Option(
            help="Where leaving the road and collisions are judged: map (the reconstructed "
            "map and parked vehicles) or truth (the workspace's ground-truth world).",
        ),
    ] = Judge.MAP,
) -> None:
    """Closed-loop runs in the builtin simulator (or CARLA); each run ends on an event.

    Example: cam2sim drive ws --policy pure-pursuit --camera raster --runs 3 --vary 0.1,0.5,0.03
    """
    from cam2sim.stages.runs import DriveOptions  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
    from cam2sim.stages.runs import drive as run_drive  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    opts = DriveOptions(
        policy=policy,
        camera=camera.value,
        runs=runs,
        speed_kmh=_speed(speed),
        recorded_speed=speed == "recorded",
        seed=seed,
        policy_every=every,
        image_size=_size(size),
        save_frames=save_frames,
        video=video,
        simulator=sim.value,
        carla=_carla(workspace, sim, carla_host, carla_port),
        variation=_variation(vary),
        judge="truth" if judge is Judge.TRUTH else "map",
    )
    ws = Workspace.open(workspace)
    with progress_bars() as sink:
        results = run_drive(ws, options=opts, progress=sink)
    for r in results:
        ends = ", ".join(f"{e['kind']} at {e['t']:.1f} s" for e in r.events) or "no event"
        console.print(f"{r.folder}: {r.steps} steps in {r.seconds:.1f} s ({ends})", highlight=False)
