"""The ``cam2sim`` command: thin wrappers around the stages, errors as ``error: ...``."""

from __future__ import annotations

import logging
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner, Result

from cam2sim import __version__
from cam2sim.cli.main import app
from cam2sim.core.dataset import Calibration
from cam2sim.core.workspace import Workspace
from cam2sim.recording.bagwriter import BagWriter
from cam2sim.recording.image import image_message_fields

T0 = 1_700_000_000_000_000_000
HEAVY_MODULES = (
    "torch",
    "cv2",
    "rosbags",
    "pyproj",
    "moderngl",
    "carla",
    "gsplat",
    "transformers",
    "onnxruntime",
    "pycolmap",
    "numpy",  # what the CLI's lazy imports keep --help from loading
    "shapely",
)
COMMANDS = ("inspect", "init", "extract", "import")


@pytest.fixture(autouse=True)
def _restore_logging() -> Iterator[None]:
    """The CLI configures the root logger; give the other tests theirs back."""
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    yield
    root.handlers[:] = handlers
    root.setLevel(level)


def invoke(*args: str, columns: int = 200) -> Result:
    """Run the CLI in-process on a terminal ``columns`` wide."""
    return CliRunner().invoke(app, ["--no-progress", *args], env={"COLUMNS": str(columns)})


def write_bag(path: Path) -> Path:
    """1.5 s of a 16x12 camera with camera_info, local odometry and a steering signal."""
    rng = np.random.default_rng(0)
    with BagWriter(path, "mcap") as w:
        for i in range(31):
            stamp = T0 + i * 50_000_000
            w.write_fields(
                "/odom",
                "nav_msgs/msg/Odometry",
                {
                    "header": {"stamp": stamp, "frame_id": "odom"},
                    "child_frame_id": "base_link",
                    "pose": {"pose": {"position": {"x": 0.25 * i}, "orientation": {"w": 1.0}}},
                },
                receive_ns=stamp,
            )
            w.write_fields(
                "/vehicle/steering_pct", "std_msgs/msg/Float64", {"data": 0.1 * i}, receive_ns=stamp
            )
            if i % 2 or i == 30:
                continue
            image = rng.integers(0, 256, size=(12, 16, 3), dtype=np.uint8)
            fields = dict(image_message_fields(image, "rgb8"))
            header = {"stamp": stamp + 25_000_000, "frame_id": "camera"}
            w.write_fields(
                "/camera/image_raw",
                "sensor_msgs/msg/Image",
                {"header": header, **fields},
                receive_ns=stamp + 25_000_000,
            )
            w.write_fields(
                "/camera/camera_info",
                "sensor_msgs/msg/CameraInfo",
                {
                    "header": header,
                    "width": 16,
                    "height": 12,
                    "distortion_model": "plumb_bob",
                    "d": [0.0] * 5,
                    "k": [20.0, 0.0, 8.0, 0.0, 20.0, 6.0, 0.0, 0.0, 1.0],
                },
                receive_ns=stamp + 25_000_000,
            )
    return path


def test_inspect_prints_every_topic_and_type(tmp_path: Path) -> None:
    result = invoke("inspect", str(write_bag(tmp_path / "bag")))
    assert result.exit_code == 0, result.output
    for topic, msgtype in (
        ("/camera/image_raw", "sensor_msgs/msg/Image"),
        ("/camera/camera_info", "sensor_msgs/msg/CameraInfo"),
        ("/odom", "nav_msgs/msg/Odometry"),
        ("/vehicle/steering_pct", "std_msgs/msg/Float64"),
    ):
        row = next(line for line in result.stdout.splitlines() if f" {topic} " in line)
        assert msgtype in row
    assert "(1.50 s)" in result.stdout


def test_inspect_keeps_topic_names_whole_on_a_narrow_console(tmp_path: Path) -> None:
    result = invoke("inspect", str(write_bag(tmp_path / "bag")), columns=80)
    assert result.exit_code == 0
    assert "…" not in result.stdout


def test_inspect_reports_a_missing_bag(tmp_path: Path) -> None:
    result = invoke("inspect", str(tmp_path / "missing.bag"))
    assert result.exit_code == 1
    assert result.stderr.startswith("error:")
    assert "does not exist" in result.stderr


def test_init_then_extract_write_a_dataset(tmp_path: Path) -> None:
    bag = write_bag(tmp_path / "bag")
    ws = tmp_path / "ws"
    result = invoke("init", str(ws), "--bag", str(bag))
    assert result.exit_code == 0, result.output
    text = " ".join(result.stdout.split())  # rich wraps long paths at the terminal width
    assert f"created workspace {ws}" in text
    assert "camera: chose" not in text  # one camera: nothing to choose between
    assert "signals: steering_pct" in text
    assert f"cam2sim extract {ws}" in text
    result = invoke("extract", str(ws))
    assert result.exit_code == 0, result.output
    out = " ".join(result.stdout.split())
    assert "15 frames, 31 poses, 0 LiDAR scans, 1 signals over 1.4 s" in out
    assert (ws / "dataset" / "frames" / "000014.png").is_file()
    again = invoke("extract", str(ws))
    assert again.exit_code == 0
    assert "dataset is up to date" in " ".join(again.stdout.split())


def test_extract_with_a_wrong_topic_fails_with_an_error_line(tmp_path: Path) -> None:
    ws = tmp_path / "ws"
    assert invoke("init", str(ws), "--bag", str(write_bag(tmp_path / "bag"))).exit_code == 0
    config = ws / "config.yaml"
    config.write_text(config.read_text().replace("camera: /camera/image_raw", "camera: /cam/img"))
    result = invoke("extract", str(ws))
    assert result.exit_code == 1
    assert result.stderr.startswith("error: topic '/cam/img' (topics.camera in config.yaml)")
    assert "Topics present: /camera/camera_info (sensor_msgs/msg/CameraInfo)" in result.stderr
    assert "/odom (nav_msgs/msg/Odometry)" in result.stderr
    assert "Traceback" not in result.output


def test_errors_are_one_line_on_a_narrow_console(tmp_path: Path) -> None:
    result = invoke("extract", str(tmp_path / "not-a-workspace"), columns=80)
    assert result.exit_code == 1
    assert result.stderr.startswith("error:")
    assert result.stderr.count("\n") == 1


def test_import_images_writes_a_pose_less_dataset(tmp_path: Path) -> None:
    folder = tmp_path / "images"
    folder.mkdir()
    for i in range(3):
        assert cv2.imwrite(str(folder / f"{T0 + i * 10**8}.png"), np.full((12, 16, 3), i, np.uint8))
    result = invoke("import", str(tmp_path / "ws"), "--images", str(folder))
    assert result.exit_code == 0, result.output
    assert "pose-less dataset of 3 frames" in result.stdout
    assert (tmp_path / "ws" / "dataset" / "frames.csv").is_file()


def test_import_of_an_empty_folder_fails_with_an_error_line(tmp_path: Path) -> None:
    (tmp_path / "images").mkdir()
    result = invoke("import", str(tmp_path / "ws"), "--images", str(tmp_path / "images"))
    assert result.exit_code == 1
    assert result.stderr.startswith("error:")
    assert "holds no .png/.jpg images" in result.stderr


def test_version_prints_the_package_version() -> None:
    result = invoke("--version")
    assert result.exit_code == 0
    assert result.stdout.strip() == f"cam2sim {__version__}"


@pytest.mark.parametrize(
    ("command", "example"),
    [
        ("inspect", "Example: cam2sim inspect drive.bag"),
        ("init", "Example: cam2sim init ws --bag drive.bag"),
        ("extract", "Example: cam2sim extract ws"),
        ("import", "Example: cam2sim import ws --images frames/"),
    ],
)
def test_help_of_every_command_shows_an_example(command: str, example: str) -> None:
    result = invoke(command, "--help")
    assert result.exit_code == 0
    assert example in result.stdout


def test_help_lists_every_command() -> None:
    result = invoke("--help")
    assert result.exit_code == 0
    for command in COMMANDS:
        assert f" {command} " in result.stdout


def test_python_dash_m_cam2sim_runs_the_cli() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "cam2sim", "--help"],
        capture_output=True,
        text=True,
        check=False,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    assert "Usage" in proc.stdout
    assert "extract" in proc.stdout


def test_importing_the_cli_loads_no_heavy_dependency() -> None:
    code = (
        "import sys, cam2sim, cam2sim.cli.main\n"
        f"print(','.join(m for m in {HEAVY_MODULES!r} if m in sys.modules))\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=False, timeout=60
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == ""


@pytest.mark.parametrize(("flags", "antialiased"), [([], True), (["--classic"], False)])
def test_splat_trains_antialiased_unless_told_classic(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, flags: list[str], antialiased: bool
) -> None:
    from cam2sim.core.workspace import Workspace
    from cam2sim.stages import splat as stage

    monkeypatch.setattr(Workspace, "open", classmethod(lambda cls, root: root))
    seen = []

    def fake_run_splat(ws: object, *, options: stage.SplatStageOptions, **_: object) -> None:
        seen.append(options.train.antialiased)
        msg = "stopped here"
        raise stage.StageError(msg)

    monkeypatch.setattr(stage, "run_splat", fake_run_splat)
    result = CliRunner().invoke(app, ["splat", str(tmp_path / "ws"), *flags])
    assert seen == [antialiased], result.output
    assert "stopped here" in result.output


def test_progress_off_a_terminal_is_plain_lines() -> None:
    """`cam2sim demo > log 2>&1`: a line per task start and end, one every 30 s in between."""
    import io

    from cam2sim.cli.display import LineProgress, ProgressSink, progress_bars

    out = io.StringIO()
    lines = LineProgress(out, every_s=0.0)
    lines("splat training", 0, 700)
    lines("splat training", 350, 700)
    lines("splat training", 700, 700)
    lines("splat training", 700, 700)  # the end is said once
    lines("drive", 0, None)
    text = out.getvalue().splitlines()
    assert [t.split("] ", 1)[1] for t in text] == [
        "splat training: started (0/700)",
        "splat training: 350/700",
        "splat training: done (700/700)",
        "drive: started (0)",
    ]
    assert all(t.startswith("[") and " s] " in t for t in text)
    quiet = LineProgress(io.StringIO(), every_s=30.0)
    quiet("t", 0, 10)
    quiet("t", 5, 10)  # within 30 s of the last line: nothing
    assert quiet._stream.getvalue().count("\n") == 1  # type: ignore[attr-defined]
    with progress_bars() as sink:  # pytest's stderr is no terminal
        assert isinstance(sink, LineProgress)
    with progress_bars(enabled=False) as sink:  # --no-progress
        assert isinstance(sink, ProgressSink)


def _commands(group: Any, prefix: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], Any]]:
    out = []
    for name, cmd in group.commands.items():
        out.append(((*prefix, name), cmd))
        if hasattr(cmd, "commands"):  # a group (typer's own click types)
            out += _commands(cmd, (*prefix, name))
    return out


def test_every_commands_help_reads_at_80_columns() -> None:
    import typer.main

    root = typer.main.get_command(app)
    commands = _commands(root)
    assert len(commands) >= 25  # the commands and the subcommands of evaluate and ads
    for path, cmd in commands:
        result = invoke(*path, "--help", columns=80)
        assert result.exit_code == 0, (path, result.output)
        text = result.output
        assert "<bool>" not in text, path  # switches take no value
        assert "…" not in text, path  # nothing cut
        assert max(len(line) for line in text.splitlines()) <= 80, path
        for param in cmd.params:
            if getattr(param, "hidden", False):
                continue
            for flag in [*param.opts, *param.secondary_opts]:
                if flag.startswith("-"):
                    assert flag in text, (path, flag)  # every flag name whole


def test_the_commands_are_listed_in_the_order_a_user_runs_them() -> None:
    text = invoke("--help", columns=80).output
    listed = [line.split()[0] for line in text.split("Commands:")[1].splitlines() if line.strip()]
    assert listed[:4] == ["inspect", "init", "extract", "import"]
    assert listed.index("map") < listed.index("detect") < listed.index("scenario")
    assert listed.index("report") < listed.index("run") < listed.index("demo")


def test_run_keeps_a_calibration_file_and_extract_uses_it(tmp_path: Path) -> None:
    """`run --calibration` over the bag's camera_info (K 20 px): a 32x24 ROS camera_info YAML
    of 60 px, scaled to the 16x12 frames, is what the dataset gets, and config.yaml keeps it."""
    bag = write_bag(tmp_path / "bag")
    calib = tmp_path / "ost.yaml"
    calib.write_text(
        "image_width: 32\nimage_height: 24\ncamera_matrix: {rows: 3, cols: 3, "
        "data: [60.0, 0, 15.5, 0, 60.0, 11.5, 0, 0, 1]}\n"
    )
    ws = tmp_path / "ws"
    result = invoke(
        "run", str(bag), "-o", str(ws), "--calibration", str(calib), "--steps", "extract"
    )
    assert result.exit_code == 0, result.output
    assert Workspace.open(ws).load_config().camera.calibration == str(calib.absolute())
    camera = Calibration.load(ws / "dataset" / "calibration.json").camera
    assert camera is not None
    assert camera.K[0][0] == pytest.approx(30.0)
