"""The ``cam2sim`` command: thin wrappers that parse arguments and call one stage each."""

from __future__ import annotations

import errno
import select
import sys
from pathlib import Path
from typing import Annotated, Any

import typer
import typer.core

from cam2sim import __version__
from cam2sim.cli.ads_cmd import ads_app
from cam2sim.cli.bench_cmd import bench
from cam2sim.cli.campaign_cmd import campaign
from cam2sim.cli.demo_cmd import demo
from cam2sim.cli.detect_cmd import detect, refine
from cam2sim.cli.display import (
    StageErrorGroup,
    console,
    error_console,
    print_table,
    progress_bars,
    setup_logging,
    show_progress,
)
from cam2sim.cli.drive_cmd import drive, replay
from cam2sim.cli.evaluate import evaluate_app
from cam2sim.cli.map_cmd import map_
from cam2sim.cli.report_cmd import report
from cam2sim.cli.run_cmd import run
from cam2sim.cli.scenario_cmd import scenario
from cam2sim.cli.splat_cmd import splat
from cam2sim.core.config import AxisConvention
from cam2sim.core.errors import ConfigError
from cam2sim.core.workspace import Workspace

__all__ = ["app", "main"]

# Exit codes, usage errors and aborts: click's own ending of a command (typer vendors click, so
# the usage-error base class is found through typer's public BadParameter).
_CLICK_FLOW: tuple[type[BaseException], ...] = (
    typer.Exit,
    typer.Abort,
    *(c for c in typer.BadParameter.__mro__ if c.__name__ == "ClickException"),
)


COMMAND_ORDER = (
    "inspect", "init", "extract", "import", "map", "detect", "refine", "scenario", "splat",
    "ads", "replay", "drive", "evaluate", "report", "run", "demo", "campaign", "bench",
)  # fmt: skip
"""``cam2sim --help`` lists the commands in this order: as a user runs them."""


class _Guarded(StageErrorGroup):
    """The root command group: an error no stage anticipated ends in one line, not a traceback.

    Every command's stage errors (:class:`~cam2sim.core.errors.Cam2SimError`) end here, as one
    ``error: <message>`` line (:func:`~cam2sim.cli.display.error_exit`); so does the rest (a
    bug, a full disk, a permission denied), named with a hint. No command catches them itself.
    ``--debug`` shows the traceback instead.
    """

    def list_commands(self, ctx: Any) -> list[str]:
        """The commands in the order a user runs them (then any others)."""
        names = list(super().list_commands(ctx))
        first = [n for n in COMMAND_ORDER if n in names]
        return first + [n for n in names if n not in first]

    def invoke(self, ctx: Any) -> Any:
        try:
            return super().invoke(ctx)
        except _CLICK_FLOW:
            raise
        except KeyboardInterrupt:
            error_console.print("interrupted; re-run the same command to resume", highlight=False)
            raise typer.Exit(code=130) from None
        except Exception as err:
            if isinstance(err, BrokenPipeError) and _stdout_reader_gone():
                raise  # `cam2sim ... | head`: click's main ends quietly, as shell tools do
            if _state["debug"]:
                raise
            error_console.print(
                f"[bold red]error:[/] {unexpected_error(err)}", highlight=False, soft_wrap=True
            )
            raise typer.Exit(code=1) from None


def _stdout_reader_gone() -> bool:
    """Whether standard output is a pipe whose reader has gone (``cam2sim ... | head``)."""
    poll = getattr(select, "poll", None)
    if poll is None:  # no poll() (Windows): a broken pipe there is most likely stdout's
        return True
    try:
        poller = poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        return any(ev & (select.POLLERR | select.POLLHUP) for _, ev in poller.poll(0))
    except (OSError, ValueError, AttributeError):  # no real stdout (captured, closed)
        return False


def unexpected_error(err: BaseException) -> str:
    """One line for an error no stage anticipated: what happened and what to do."""
    text = str(err) or "no message"
    if isinstance(err, PermissionError):
        return f"permission denied: {err.filename or text}; check the folder's owner and mode"
    if isinstance(err, FileNotFoundError):
        return f"no such file: {err.filename or text}; check the path"
    if isinstance(err, OSError) and err.errno == errno.ENOSPC:
        return f"the disk is full ({err.filename or text}); free space and re-run to resume"
    if isinstance(err, MemoryError):
        return "out of memory; close other programs or use smaller options, then re-run"
    return (
        f"unexpected {type(err).__name__}: {text} (a cam2sim bug: re-run with --debug for the "
        "traceback and report it)"
    )


app = typer.Typer(
    name="cam2sim",
    cls=_Guarded,
    help="Turn a real driving recording into a closed-loop simulation of the same street.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,  # click's plain help: no cut flag names at 80 columns
)

_state: dict[str, int | bool] = {"verbose": 0, "progress": True, "debug": False}


def _register_subcommands() -> None:
    app.command("detect")(detect)
    app.command("refine")(refine)
    app.command("map")(map_)
    app.command("scenario")(scenario)
    app.command("replay")(replay)
    app.command("drive")(drive)
    app.command("report")(report)
    app.command("run")(run)
    app.command("demo")(demo)
    app.command("splat")(splat)
    app.command("campaign")(campaign)
    app.command("bench")(bench)
    app.add_typer(evaluate_app, name="evaluate")
    app.add_typer(ads_app, name="ads")


_register_subcommands()


def _version(value: bool) -> None:
    if value:
        console.print(f"cam2sim {__version__}")
        raise typer.Exit


@app.callback()
def _root(
    verbose: Annotated[
        int, typer.Option("--verbose", "-v", count=True, help="More log output (-vv for debug).")
    ] = 0,
    no_progress: Annotated[bool, typer.Option("--no-progress", help="Hide progress bars.")] = False,
    debug: Annotated[
        bool, typer.Option("--debug", help="Show the traceback of an unexpected error.")
    ] = False,
    version: Annotated[
        bool,
        typer.Option("--version", callback=_version, is_eager=True, help="Show the version."),
    ] = False,
) -> None:
    del version
    _state["verbose"] = verbose
    _state["debug"] = debug
    StageErrorGroup.debug = debug
    _state["progress"] = not no_progress
    show_progress(enabled=not no_progress)
    setup_logging(verbose=verbose)


@app.command()
def inspect(
    bags: Annotated[list[Path], typer.Argument(help="Bag files or folders of one recording.")],
) -> None:
    """Show the topics of a recording: types, counts, rates, time span and largest gaps.

    Example: cam2sim inspect drive.bag
    """
    from rich.table import Table  # noqa: PLC0415

    from cam2sim.recording.summary import summarize_recording  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    with progress_bars(enabled=bool(_state["progress"])) as sink:
        summary = summarize_recording(bags, progress=sink)
    table = Table(title=f"{', '.join(summary.paths)}  ({summary.duration_s:.2f} s)")
    for col, justify in (
        ("topic", "left"),
        ("type", "left"),
        ("count", "right"),
        ("rate Hz", "right"),
        ("span s", "right"),
        ("largest gap s", "right"),
        ("gap at s", "right"),
    ):
        table.add_column(col, justify=justify)  # type: ignore[arg-type]
    for t in summary.topics:
        table.add_row(
            t.name,
            t.msgtype,
            str(t.count),
            f"{t.rate_hz:.2f}",
            f"{(t.end_ns - t.start_ns) / 1e9:.2f}",
            f"{t.max_gap_s:.3f}",
            f"{t.max_gap_at_s:.2f}",
        )
    print_table(table)


@app.command()
def init(
    workspace: Annotated[Path, typer.Argument(help="Workspace folder to create.")],
    bag: Annotated[
        list[Path], typer.Option("--bag", "-b", help="A bag file or folder (repeatable).")
    ],
    force: Annotated[bool, typer.Option(help="Overwrite an existing workspace's config.")] = False,
) -> None:
    """Create a workspace and a starter config.yaml guessed from the recording's topics.

    Example: cam2sim init ws --bag drive.bag
    """
    from cam2sim.stages.init import init_workspace  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    result = init_workspace(workspace, bag, force=force)
    console.print(f"created workspace [bold]{result.workspace.root}[/]")
    for note in result.notes:
        console.print(f"  - {note}", highlight=False)
    console.print(f"edit {result.workspace.config_path}, then run: cam2sim extract {workspace}")


@app.command()
def extract(
    workspace: Annotated[Path, typer.Argument(help="The workspace folder.")],
    force: Annotated[bool, typer.Option(help="Re-extract even if up to date.")] = False,
) -> None:
    """Extract frames, poses, LiDAR scans and signals into WS/dataset/.

    Example: cam2sim extract ws
    """
    from cam2sim.stages.extract import extract as run_extract  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    ws = Workspace.open(workspace)
    with progress_bars(enabled=bool(_state["progress"])) as sink:
        result = run_extract(ws, force=force, progress=sink)
    info = result.info
    if result.skipped:
        console.print("dataset is up to date (use --force to re-extract)")
    dropped = ", ".join(
        f"{sensor} {reason}: {n}" for sensor, r in info.dropped.items() for reason, n in r.items()
    )
    console.print(
        f"{result.dataset_dir}: {info.counts.frames} frames, {info.counts.pose_samples} poses, "
        f"{info.counts.lidar_scans} LiDAR scans, {len(info.counts.signals)} signals over "
        f"{info.duration_s:.1f} s" + (f"; dropped {dropped}" if dropped else ""),
        highlight=False,
    )


@app.command("import")
def import_(
    workspace: Annotated[Path, typer.Argument(help="The workspace folder (created if new).")],
    *,
    images: Annotated[
        Path,
        typer.Option(
            help="Folder of .png/.jpg frames, or a video file (.mp4, .mov, .avi, .mkv; a bare "
            ".hevc/.h264 stream at --fps)."
        ),
    ],
    poses: Annotated[
        Path | None,
        typer.Option(
            help="CSV: timestamp,x,y[,z] or timestamp,lat,lon[,alt] (GPS), qx,qy,qz,qw or yaw "
            "(radians from x or east; a GPS CSV's heading: degrees from north; else the heading "
            "of travel)[, image]; KITTI's poses.txt; KITTI raw's oxts/ folder; a TUM trajectory "
            "(SLAM); a GPS track (GPX, NMEA log); a comma2k19 segment (its global_pose/); "
            "'exif': the photos' own EXIF GPS tags."
        ),
    ] = None,
    calibration: Annotated[
        Path | None,
        typer.Option(
            help="JSON with K, distortion, width, height (or a Cam2Sim camera.json), a K.txt, "
            "KITTI raw's calibration folder, or a tool's file as it is (ROS camera_info or "
            "OpenCV YAML/XML, Kalibr camchain, COLMAP cameras.txt, nerfstudio transforms.json)."
        ),
    ] = None,
    fov: Annotated[
        float | None,
        typer.Option(
            help="Without a calibration: the camera's horizontal field of view in degrees (its "
            "data sheet's), for a pinhole K."
        ),
    ] = None,
    crs: Annotated[
        str | None,
        typer.Option(help="CRS of x,y pose positions, e.g. EPSG:32632 (GPS lat,lon need none)."),
    ] = None,
    axis_convention: Annotated[
        AxisConvention, typer.Option(help="Where the pose frame's x axis points on the car.")
    ] = AxisConvention.X_FORWARD,
    fps: Annotated[
        float,
        typer.Option(help="Frame rate when file names carry no time, or of a bare video stream."),
    ] = 30.0,
    video_fps: Annotated[
        float, typer.Option(help="A video's frames kept a second (at most its own rate).")
    ] = 10.0,
    start: Annotated[
        str | None,
        typer.Option(
            help="When the first frame was taken, on the poses' clock (seconds, or an ISO date "
            "for a GPS track). Default: the file names' times, else the first pose's time."
        ),
    ] = None,
    signal: Annotated[
        list[str] | None,
        typer.Option(
            help="NAME=CSV: a signal (t,value) on the images' time base, e.g. "
            "steering=steer.csv (or a comma2k19 processed_log/CAN/steering_angle/ folder); "
            "repeatable."
        ),
    ] = None,
    rig: Annotated[
        Path | None,
        typer.Option(
            help="YAML of the rig's other cameras (images, offset_m from the front camera); "
            "the splat is scored at their real frames."
        ),
    ] = None,
    pose_offset: Annotated[
        str | None,
        typer.Option(
            help="X,Y,Z: where the poses sit on the car from its footprint centre (m, x forward, "
            "z up); X 'fit' measures it from the drive's turns, e.g. fit,0,1.65 for a camera "
            "1.65 m up. Not given: fitted, at ground height."
        ),
    ] = None,
) -> None:
    """Import images (and optional poses, calibration, signals) as the workspace dataset.

    Example: cam2sim import ws --images frames/ --poses poses.csv --crs EPSG:32632

    Example (a dash camera): cam2sim import ws --images drive.mp4 --poses track.gpx
    """
    from cam2sim.stages.image_import import ImportOptions, import_images  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    opts = ImportOptions(
        poses=poses,
        calibration=calibration,
        crs=crs,
        axis_convention=axis_convention,
        fps=fps,
        signals=tuple(_name_path(s) for s in signal or ()),
        pose_offset_m=_xyz(pose_offset) if pose_offset else None,
        rig=rig,
        start=start,
        video_fps=video_fps,
        fov_deg=fov,
    )
    with progress_bars(enabled=bool(_state["progress"])) as sink:
        result = import_images(workspace, images, options=opts, progress=sink)
    info = result.info
    kind = "pose-less " if info.pose_less else ""
    console.print(f"{result.dataset_dir}: {kind}dataset of {info.counts.frames} frames")
    for note in result.notes:
        console.print(f"  - {note}", highlight=False)
    if (point := result.pose_point) is not None:
        console.print(
            f"the poses sit {point.ahead_m:.2f} +- {point.stderr_m:.2f} m ahead of the rear axle "
            f"(fitted from {point.turning} samples in turns)"
        )


def _name_path(text: str) -> tuple[str, Path]:
    name, sep, path = text.partition("=")
    if not sep or not name or not path:
        msg = f"--signal takes NAME=CSV, e.g. steering=steer.csv; got {text!r}"
        raise ConfigError(msg)
    return name.strip(), Path(path)


def _xyz(text: str) -> tuple[float | None, float, float]:
    """``X,Y,Z`` in metres; X may be ``fit`` (None: fitted from the drive's turns)."""
    try:
        x, y, z = (v.strip() for v in text.split(","))
        return (None if x.lower() == "fit" else float(x), float(y), float(z))
    except ValueError:
        msg = f"--pose-offset takes X,Y,Z in metres (X may be 'fit'), e.g. fit,0,1.65; got {text!r}"
        raise ConfigError(msg) from None


def main() -> None:
    """Run the ``cam2sim`` command."""
    app()
