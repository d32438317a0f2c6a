"""Shared fixtures: paths to the real data in ../shared/data and bags written on the fly."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from cam2sim.core import frames
from cam2sim.core.config import Config, RecordingConfig
from cam2sim.core.workspace import Workspace
from cam2sim.recording.bagwriter import BagFormat, BagWriter
from cam2sim.recording.image import image_message_fields
from cam2sim.scenario.synthetic import StreetSpec, synthetic_street

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
REFERENCE_DRIVES = SHARED_DATA / "reference-drives"


@pytest.fixture
def shared_data() -> Path:
    """The real data folder; skips the test when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not found at {SHARED_DATA}")
    return SHARED_DATA


def stamps_ns_from_text(column: list[str]) -> np.ndarray:
    """Parse decimal-second strings into exact int64 nanoseconds."""
    out = []
    for text in column:
        sec, _, frac = text.strip().partition(".")
        out.append(int(sec) * 1_000_000_000 + int((frac + "000000000")[:9]))
    return np.asarray(out, dtype=np.int64)


@dataclass(frozen=True)
class ReferenceDrive:
    """A real reference drive: exact ns stamps, UTM 32N positions, odometry-convention yaw."""

    stamp_ns: np.ndarray
    easting: np.ndarray
    northing: np.ndarray
    yaw_odom: np.ndarray


def load_reference_drive(path: Path) -> ReferenceDrive:
    lines = path.read_text().splitlines()[1:]
    cols = list(zip(*(line.split(",") for line in lines), strict=True))
    return ReferenceDrive(
        stamp_ns=stamps_ns_from_text(list(cols[0])),
        easting=np.asarray(cols[1], dtype=float),
        northing=np.asarray(cols[2], dtype=float),
        yaw_odom=np.asarray(cols[4], dtype=float),
    )


@pytest.fixture
def reference_drive(shared_data: Path) -> ReferenceDrive:
    return load_reference_drive(shared_data / "reference-drives" / "trajectory1.csv")


@dataclass(frozen=True)
class DriveBag:
    """A bag written by :func:`write_drive_bag` and what went into it."""

    path: Path
    camera_ns: np.ndarray
    images: list[np.ndarray]
    lidar_ns: np.ndarray
    steering_ns: np.ndarray
    steering: np.ndarray


def _image(i: int, width: int, height: int) -> np.ndarray:
    rng = np.random.default_rng(i)
    return rng.integers(0, 256, size=(height, width, 3), dtype=np.uint8)


def write_frames(
    folder: Path, n: int, size: tuple[int, int] = (16, 12), name: str = "{i:06d}.png"
) -> list[Path]:
    """``n`` random frames of ``size`` (width, height) in a new ``folder``, named by ``name``."""
    import cv2  # only the tests that write frames need it

    folder.mkdir(parents=True)
    files = [folder / name.format(i=i) for i in range(n)]
    for i, path in enumerate(files):
        assert cv2.imwrite(str(path), _image(i, *size))
    return files


def _cloud(i: int, n: int = 64) -> np.ndarray:
    rng = np.random.default_rng(1000 + i)
    pts = np.zeros(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])
    for name in ("x", "y", "z", "intensity"):
        pts[name] = rng.normal(size=n).astype(np.float32) * 10
    return pts


def write_drive_bag(
    path: Path,
    fmt: BagFormat,
    drive: ReferenceDrive,
    *,
    seconds: float | None = None,
    camera_hz: float = 30.0,
    size: tuple[int, int] = (16, 12),
    lidar_hz: float = 0.0,
    encoding: str = "rgb8",
    margin_s: float = 0.5,
) -> DriveBag:
    """Write a bag whose odometry carries a real drive's poses (UTM, x-left convention)."""
    n = len(drive.stamp_ns)
    if seconds is not None:
        n = int(np.searchsorted(drive.stamp_ns, drive.stamp_ns[0] + int(seconds * 1e9)))
    t0, t1 = int(drive.stamp_ns[0]), int(drive.stamp_ns[n - 1])
    step = int(1e9 / camera_hz)
    camera_ns = np.arange(t0 - int(margin_s * 1e9), t1 + int(margin_s * 1e9), step, dtype=np.int64)
    lidar_ns = (
        np.arange(t0, t1, int(1e9 / lidar_hz), dtype=np.int64)
        if lidar_hz
        else np.zeros(0, dtype=np.int64)
    )
    steering_ns = np.arange(t0, t1, 10_000_000, dtype=np.int64)
    steering = np.sin(np.arange(len(steering_ns)) / 50.0)
    quats = frames.quat_from_yaw(drive.yaw_odom[:n])
    events: list[tuple[int, str, int]] = [
        (int(s), "odom", i) for i, s in enumerate(drive.stamp_ns[:n])
    ]
    events += [(int(s), "cam", i) for i, s in enumerate(camera_ns)]
    events += [(int(s), "lidar", i) for i, s in enumerate(lidar_ns)]
    events += [(int(s), "steer", i) for i, s in enumerate(steering_ns)]
    events.sort()
    images = []
    with BagWriter(path, fmt) as w:
        for stamp, kind, i in events:
            receive = stamp + 1_000_000
            if kind == "odom":
                position = (drive.easting[i], drive.northing[i])
                w.write_odometry("/odom", stamp, position, quats[i], receive_ns=receive)
            elif kind == "cam":
                image = _image(i, *size)
                images.append(image)
                fields = dict(image_message_fields(image, encoding))
                w.write_fields(
                    "/camera/image_raw",
                    "sensor_msgs/msg/Image",
                    {"header": {"stamp": stamp, "frame_id": "camera"}, **fields},
                    receive_ns=receive,
                )
            elif kind == "lidar":
                w.write_point_cloud(
                    "/velodyne_points", stamp, _cloud(i), receive_ns=receive, frame_id="velodyne"
                )
            else:
                w.write_fields(
                    "/vehicle/steering_pct",
                    "std_msgs/msg/Float64",
                    {"data": float(steering[i])},
                    receive_ns=receive,
                )
    return DriveBag(path, camera_ns, images, lidar_ns, steering_ns, steering)


@pytest.fixture
def cloud_factory():
    return _cloud


def street_workspace(root: Path, spec: StreetSpec | None = None) -> Workspace:
    """A workspace holding a synthetic street's map and scenario (ready for drives)."""
    ws = Workspace.create(root, Config(recording=RecordingConfig(bags=[str(root / "none")])))
    scenario, xodr = synthetic_street(spec)
    ws.map_dir.mkdir(parents=True, exist_ok=True)
    (ws.map_dir / "map.xodr").write_text(xodr, encoding="utf-8")
    ws.scenario_dir.mkdir(parents=True, exist_ok=True)
    scenario.save(ws.scenario_dir / "scenario.json")
    return ws


def truth_workspace(
    root: Path, spec: StreetSpec, *, cars: bool = True, look: str = "photographic"
) -> Workspace:
    """A synthetic street workspace whose ground truth is the same street (cars optional)."""
    from cam2sim.render.truth import TruthCar, TruthLook, TruthWorld, truth_world_path
    from cam2sim.scenario.model import Scenario

    ws = street_workspace(root, spec)
    sc = Scenario.load(ws.scenario_dir / "scenario.json")
    _, xodr = synthetic_street(spec)
    truth_cars = tuple(
        TruthCar(
            x=v.position[0],
            y=v.position[1],
            yaw=v.heading,
            length=v.size[0],
            width=v.size[1],
            height=v.size[2],
        )
        for v in sc.parked
    )
    world = TruthWorld(
        crs="EPSG:32632",
        origin=(0.0, 0.0),
        xodr=xodr,
        cars=truth_cars if cars else (),
        look=TruthLook(kind=look),  # type: ignore[arg-type]
    )
    world.save(truth_world_path(ws.root))
    return ws


def has_egl() -> bool:
    """Whether a headless OpenGL context (EGL) can be made here (the raster renderer's)."""
    try:
        import moderngl

        moderngl.create_context(standalone=True, backend="egl").release()  # type: ignore[arg-type]
    except Exception:  # noqa: BLE001 - any failure means no headless GL here
        return False
    return True


@pytest.fixture(scope="module")
def one_torch_thread() -> Iterator[None]:
    """Run torch single-threaded in a module (and its spawned workers, which take the parent's
    count on CPU): on a shared 2-core machine, two threads run slower."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


CHROMIUM = Path("/usr/bin/chromium")
"""Debian's Chromium, which the browser tests drive through Playwright (`.ci/run` installs it)."""
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


def playwright_with_chromium():
    """``playwright.sync_api``; skips the test when it or Debian's Chromium is missing."""
    if not CHROMIUM.is_file():
        pytest.skip(f"{CHROMIUM} not installed")
    return pytest.importorskip("playwright.sync_api")


def launch_chromium(pw):
    """A headless, offline-quiet Chromium browser from a running ``sync_playwright()``."""
    return pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)


def _bicycle_drive(
    ahead_m: float, *, speed: float = 5.0, dt: float = 0.1, turns: tuple[float, ...] = (-0.1, 0.07)
) -> tuple[np.ndarray, ...]:
    """A kinematic-bicycle drive: straights and the given turns (curvature 1/m, 90 degrees each).

    Returns the times, the positions of a point ``ahead_m`` in front of the rear axle, the
    headings, the speeds of that point and the rear axle's curvature at each sample.
    """
    kappa: list[float] = [0.0] * 40
    for k in turns:
        kappa += [k] * round(abs(math.pi / 2 / k) / (speed * dt)) + [0.0] * 40
    kap = np.array(kappa)
    ds = speed * dt
    heading = np.concatenate([[0.0], np.cumsum(kap[:-1] * ds)])
    mid = heading + kap * ds / 2  # each step an arc: its chord points along the middle heading
    step = ds * np.stack([np.cos(mid), np.sin(mid)], -1)
    rear = np.concatenate([[[0.0, 0.0]], np.cumsum(step[:-1], axis=0)])
    point = rear + ahead_m * np.stack([np.cos(heading), np.sin(heading)], -1)
    t = np.arange(kap.shape[0]) * dt
    v = speed * np.hypot(1.0, ahead_m * kap)  # the point ahead travels further in a turn
    return t, point, heading, v, kap


@pytest.fixture
def bicycle_drive() -> Callable[..., tuple[np.ndarray, ...]]:
    """A kinematic-bicycle drive with turns, recorded at a point on the car (see its doc)."""
    return _bicycle_drive


def temporary_leftovers(folder: Path) -> list[str]:
    """Hidden files a failed or interrupted write left in ``folder`` (none should be).

    The workspace manifest's lock file (``Workspace.LOCK``) is meant to stay and is not one.
    """
    return sorted(
        p.name for p in folder.iterdir() if p.name.startswith(".") and p.name != Workspace.LOCK
    )
