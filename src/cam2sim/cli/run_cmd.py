"""``cam2sim run``: the whole pipeline, from bags to report, resuming where it stopped."""

from __future__ import annotations

import time
from pathlib import Path  # noqa: TC003 - typer reads annotations at run time
from typing import TYPE_CHECKING, Annotated

import typer
from rich.markup import escape
from rich.table import Table

from cam2sim.cli.display import (
    console,
    error_console,
    print_behaviour,
    print_steering_agreement,
    print_table,
    progress_bars,
)
from cam2sim.cli.options import SkipOption, StepsOption, comma_list
from cam2sim.core.config import load_config, save_config
from cam2sim.core.workspace import Workspace

if TYPE_CHECKING:
    from cam2sim.stages.pipeline import PipelineResult

__all__ = ["run"]

_STYLE = {
    "done": "green",
    "up_to_date": "cyan",
    "skipped": "dim",
    "not_applicable": "yellow",
    "failed": "bold red",
}


def _workspace(out: Path, bags: list[Path], config: Path | None) -> Workspace:
    """Open the workspace at ``out``, or create it from the bags (and a given config)."""
    from cam2sim.stages.init import init_workspace  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    cfg = None
    if config is not None:
        cfg = load_config(config)
        if bags:
            recording = cfg.recording.model_copy(update={"bags": [str(p.absolute()) for p in bags]})
            cfg = cfg.model_copy(update={"recording": recording})
    if (out / Workspace.MANIFEST).is_file():
        ws = Workspace.open(out)
        if cfg is not None:
            save_config(cfg, ws.config_path, comment=f"From {config} (cam2sim run --config)")
        return ws
    if cfg is not None:
        return Workspace.create(out, cfg, comment=f"From {config} (cam2sim run --config)")
    if not bags:
        msg = f"{out} is not a workspace yet; pass the recording's bags: cam2sim run BAG -o {out}"
        raise typer.BadParameter(msg)
    return init_workspace(out, bags).workspace


def _use_calibration(ws: Workspace, calibration: Path) -> None:
    """Keep ``calibration`` in the workspace's config.yaml (extract reads it; a resume too)."""
    cfg = ws.load_config()
    camera = cfg.camera.model_copy(update={"calibration": str(calibration.absolute())})
    save_config(
        cfg.model_copy(update={"camera": camera}),
        ws.config_path,
        comment=f"camera.calibration from cam2sim run --calibration {calibration}",
    )


def _summary(result: PipelineResult) -> Table:
    table = Table(title="cam2sim run")
    table.add_column("step")
    table.add_column("state")
    table.add_column("seconds", justify="right")
    table.add_column("message", overflow="fold")
    for o in result.outcomes:
        style = _STYLE.get(o.state, "")
        state = f"[{style}]{o.state.replace('_', ' ')}[/]" if style else o.state
        seconds = f"{o.seconds:.1f}" if o.seconds else "-"
        table.add_row(o.name, state, seconds, escape(o.message))
    return table


def run(
    bags: Annotated[
        list[Path] | None,
        typer.Argument(help="The recording's bag files or folders (not needed to resume)."),
    ] = None,
    *,
    out: Annotated[Path, typer.Option("--out", "-o", help="The workspace folder.")],
    config: Annotated[
        Path | None,
        typer.Option(help="A config.yaml to use instead of the guessed one."),
    ] = None,
    osm: Annotated[
        Path | None,
        typer.Option(help="OSM file for the map (default: download from the Overpass API)."),
    ] = None,
    calibration: Annotated[
        Path | None,
        typer.Option(
            exists=True,
            help="The camera's calibration file as a tool wrote it (ROS camera_info or OpenCV "
            "YAML, Kalibr, COLMAP cameras.txt, a K.txt...), for a bag without a camera_info "
            "topic; kept in config.yaml as camera.calibration.",
        ),
    ] = None,
    steps: StepsOption = None,
    skip: SkipOption = None,
    policy: Annotated[
        str | None,
        typer.Option(help="Drive policy (default: the trained DAVE-2, else pure-pursuit)."),
    ] = None,
    camera: Annotated[
        list[str] | None,
        typer.Option(
            help="Camera for replay and drive, repeatable: raster, splat, truth, none "
            "(default: raster, plus splat when splat models exist, plus truth for drives when "
            "the workspace has a ground-truth world)."
        ),
    ] = None,
    detect_model: Annotated[
        str | None,
        typer.Option(help="Camera detector for recordings without LiDAR (.onnx, .pt)."),
    ] = None,
    real: Annotated[
        list[Path] | None,
        typer.Option(
            help="Further recorded drives of the street (trajectory*.csv or folders): they join "
            "the recorded one as Real; repeatable."
        ),
    ] = None,
    real_crs: Annotated[str, typer.Option(help="CRS of the --real drives' x, y.")] = "EPSG:32632",
    runs: Annotated[int, typer.Option(min=1, help="Drive runs per camera.")] = 3,
    replay_every: Annotated[
        int | None,
        typer.Option(
            min=1,
            help="Replay every N-th recorded frame (default: every frame; with the splat "
            "camera on a CPU, at most 500 frames).",
        ),
    ] = None,
    vary: Annotated[
        bool,
        typer.Option(
            help="Make the runs differ as a driver's repeated drives do (seeded start pose, "
            "speed and steering noise, as the demo's); without it they are identical.",
        ),
    ] = True,
    recorded_speed: Annotated[
        bool | None,
        typer.Option(
            "--recorded-speed/--start-speed",
            help="Drive at the recorded speed along the route (slowing where the driver "
            "slowed), or hold the recorded start speed. Default: the recorded speed when the "
            "recording changes speed by more than 25 % (a real drive), else the start speed.",
            show_default=False,
        ),
    ] = None,
    splat_on_cpu: Annotated[
        bool, typer.Option(help="Train splats on the CPU (the CPU preset) when there is no GPU.")
    ] = True,
    bundle_adjust: Annotated[
        bool | None,
        typer.Option(
            "--bundle-adjust/--no-bundle-adjust",
            help="Adjust the recorded poses to the frames before the splat trains (held-out "
            "frames then aligned to their own images). Default: a real recording's poses "
            "(a demo world's exact ones are kept).",
            show_default=False,
        ),
    ] = None,
    continue_on_error: Annotated[
        bool, typer.Option(help="Go on with the next steps after a step failed.")
    ] = False,
) -> None:
    """Run every stage in order, skipping those up to date; re-run to resume.

    Steps: extract, map, detect, scenario, splat, ads, replay, drive, evaluate, report.

    Example: cam2sim run drive.mcap -o ws --osm area.osm --skip splat
    """
    from cam2sim.stages.experiment import DEMO_STEERING_NOISE  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
    from cam2sim.stages.pipeline import STEPS, PipelineOptions, remember_inputs, run_pipeline  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
    from cam2sim.stages.variation import DEMO_RUN_VARIATION  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    options = PipelineOptions(
        osm=osm,
        steps=comma_list(steps) or STEPS,
        skip=comma_list(skip),
        detect_model=detect_model,
        real=tuple(real or ()),
        real_crs=real_crs,
        policy=policy,
        cameras=tuple(camera) if camera else None,  # type: ignore[arg-type]
        runs=runs,
        replay_every=replay_every,
        steering_noise_std=DEMO_STEERING_NOISE if vary else 0.0,
        run_variation=DEMO_RUN_VARIATION if vary else None,
        recorded_speed=recorded_speed,
        splat_on_cpu=splat_on_cpu,
        bundle_adjust=bundle_adjust,
        continue_on_error=continue_on_error,
    )
    ws = _workspace(out, list(bags or []), config)
    if calibration is not None:
        _use_calibration(ws, calibration)
    options = remember_inputs(ws, options)  # a resume needs no --osm again
    started = time.perf_counter()  # wall time: on a GPU, DAVE-2 trains beside the splat
    with progress_bars() as sink:
        result = run_pipeline(ws, options=options, progress=sink)
    _finish(ws, result, time.perf_counter() - started)


def _finish(ws: Workspace, result: PipelineResult, total_s: float) -> None:
    """Print the summary table, the total and the report; exit 1 when a step failed."""
    print_table(_summary(result))
    metrics = ws.report_files.metrics_json
    if metrics.is_file() and result.outcome("evaluate").state in ("done", "up_to_date"):
        from cam2sim.metrics.drive_quality import DriveMetrics  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

        print_behaviour(DriveMetrics.load(metrics))
        print_steering_agreement(ws.report_files.images_dir)
    console.print(f"workspace {ws.root}; {total_s:.0f} s in all", highlight=False)
    if result.report is not None:
        console.print(f"report: {result.report}", highlight=False)
    if result.failed:
        error_console.print(
            "[bold red]a step failed[/]; fix what its message says, then run the same command "
            "again to resume",
            highlight=False,
        )
        raise typer.Exit(1)
