"""``cam2sim import``: images (plus an optional pose table and calibration) into a dataset.

The minimum input without a bag. Images are a folder, taken in natural name order, their times
from the number in their file names (an epoch time by its size) or from the frame rate; or a
video file (a dash camera's), decoded at most ``video_fps`` frames a second, its times from the
video (:mod:`cam2sim.recording.video`). Times that count from zero meet dated poses (a GPS track) at
``--start``, else at the first pose. The poses are any file :mod:`cam2sim.recording.pose_file`
reads (a CSV of x, y or of GPS fixes, KITTI's poses.txt, KITTI raw's OXTS folder, a TUM
trajectory, GPX, NMEA); GPS fixes put the world frame at the first fix, and poses without an
orientation head where they travel. Without poses the dataset is marked pose-less (the splat
stage estimates poses itself).
"""

from __future__ import annotations

import csv
import logging
import re
import shutil
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Final, Literal

import numpy as np
import numpy.typing as npt

from cam2sim.core import frames
from cam2sim.core.config import (
    AXIS_CONVENTION_YAW_OFFSET,
    AxisConvention,
    Config,
    PoseConfig,
    SyncConfig,
    VehicleConfig,
    save_config,
)
from cam2sim.core.dataset import (
    POSE_PRECISION,
    Calibration,
    CameraIntrinsics,
    DatasetCounts,
    DatasetInfo,
    MountRecord,
    SourceRecord,
)
from cam2sim.core.errors import RecordingError
from cam2sim.core.files import atomic_folder, file_fingerprint, write_bytes_atomic
from cam2sim.core.images import frames_are_grey
from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.core.table import write_table
from cam2sim.core.trajectory import (
    Trajectory,
    densify_positions,
    gap_limit_s,
    heading_off_travel,
    orientation_from_motion,
    smooth_positions,
)
from cam2sim.core.workspace import DatasetPaths, Workspace, WorldFrameRecord, hash_inputs
from cam2sim.recording.comma2k19 import is_log_signal, read_log_signal
from cam2sim.recording.exif_gps import has_exif_gps
from cam2sim.recording.intrinsics import (
    IDENTITY_OPTICAL,
    intrinsics_from_file,
    intrinsics_from_fov,
)
from cam2sim.recording.pose import yaw_offset_quat
from cam2sim.recording.pose_file import (
    EXIF_POSES,
    PoseTable,
    first_column,
    read_exif_poses,
    read_pose_file,
    stamp_ns_from_text,
    table_stamps,
)
from cam2sim.recording.video import RAW_STREAM_SUFFIXES, decode_video, is_video
from cam2sim.scenario.calibration import PosePoint, fit_pose_point
from cam2sim.stages._runner import stage_run
from cam2sim.stages.rig import RigSpec, read_rig, write_rig

__all__ = [
    "ImportResult",
    "import_images",
    "intrinsics_from_file",
    "intrinsics_from_fov",
    "stamps_from_names",
]

logger = logging.getLogger(__name__)

STAGE = "extract"
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


@dataclass(frozen=True)
class ImportResult:
    """What :func:`import_images` did (``notes``: what it found or assumed, for the user)."""

    dataset_dir: Path
    info: DatasetInfo
    pose_point: PosePoint | None = None
    notes: tuple[str, ...] = ()


def _natural_key(path: Path) -> list[object]:
    return [int(p) if p.isdigit() else p for p in re.split(r"(\d+)", path.name)]


def _list_images(images: Path) -> list[Path]:
    if not images.is_dir():
        msg = f"--images {images} is not a folder; pass the folder holding the frames"
        raise RecordingError(msg)
    files = sorted(
        (p for p in images.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES), key=_natural_key
    )
    if not files:
        msg = f"{images} holds no .png/.jpg images; pass the folder holding the frames"
        raise RecordingError(msg)
    return files


_EPOCH_S: Final = 10**9
"""A whole number in a file name this large is a time (seconds since 1970 from 2001 on); a
smaller one counts frames (KITTI's ``000042.png``)."""
_NAME_UNITS: Final = ((10**17, "ns"), (10**14, "us"), (10**11, "ms"), (_EPOCH_S, "s"))
"""The unit of an epoch time by its size, as
:func:`~cam2sim.recording.timestamps.stamp_ns_from_text` reads it."""


def stamps_from_names(files: list[Path], *, fps: float) -> tuple[npt.NDArray[np.int64], str]:
    """Times of image files: the number in their names, else the frame index / fps.

    The number is an epoch time by its size (ns, us, ms, s) or, with a decimal point, seconds.
    It may stand alone (``1479425441182877835.jpg``) or inside a name the files share
    (``center_1479425441182877835.jpg``, ``left_1541178393.123456.png``): the one number that
    differs from file to file, the rest of every name the same.

    Returns:
        ``(N,)`` int64 nanoseconds and a word saying where they came from.
    """
    numbers = _name_numbers([p.stem for p in files])
    if numbers is not None:
        decimal = any("." in n for n in numbers)
        largest = max(int(n.partition(".")[0]) for n in numbers)
        if decimal or largest >= _EPOCH_S:  # times; smaller whole numbers count frames
            stamps = np.array([stamp_ns_from_text(n) for n in numbers], dtype=np.int64)
            unit = "s" if decimal else next(u for size, u in _NAME_UNITS if largest >= size)
            return stamps, f"file names ({unit})"
    stamps = np.round(np.arange(len(files)) * (1e9 / fps)).astype(np.int64)
    return stamps, f"frame index at {fps:g} fps"


def _name_numbers(stems: list[str]) -> list[str] | None:
    """The number that tells files apart, when the rest of their names is the same; else None."""
    split = [re.split(r"(\d+(?:\.\d+)?)", s) for s in stems]
    if not split or len({len(parts) for parts in split}) != 1 or len(split[0]) < 3:
        return None
    columns = list(zip(*split, strict=True))
    if any(len(set(columns[i])) != 1 for i in range(0, len(columns), 2)):
        return None  # the text around the numbers differs
    varying = [i for i in range(1, len(columns), 2) if len(set(columns[i])) > 1]
    if len(varying) != 1 and len(stems) > 1:
        return None  # two numbers change (seconds_microseconds, camera_frame): not one time
    return list(columns[varying[0] if varying else 1])


def _image_size(path: Path) -> tuple[int, int] | None:
    """``(width, height)`` of an image file, or None when it cannot be read."""
    import cv2  # noqa: PLC0415 -- lazy: cv2 is heavy

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    return None if image is None else (int(image.shape[1]), int(image.shape[0]))


_CREATED_COMMENT = "Created by cam2sim import."


def _open_workspace(root: Path, opts: ImportOptions) -> tuple[Workspace, Config, bool]:
    """The workspace at ``root``, its config and whether this import created it.

    A new one gets the import's pose settings (an offset whose X is to be fitted starts at the
    rear axle; :func:`_place_poses` sets it).
    """
    if (root / Workspace.MANIFEST).is_file():
        ws = Workspace.open(root)
        return ws, ws.load_config(), False
    config = Config(pose=PoseConfig(crs=opts.crs, axis_convention=opts.axis_convention))
    if opts.pose_offset_m is not None:  # where on the car the poses are (a camera, say)
        x, y, z = opts.pose_offset_m
        offset = (config.vehicle.rear_axle_x_m if x is None else x, y, z)
        vehicle = VehicleConfig(reference="offset", reference_offset_m=offset)
        config = config.model_copy(update={"vehicle": vehicle})
    return Workspace.create(root, config, comment=_CREATED_COMMENT), config, True


def _place_poses(
    ws: Workspace, config: Config, opts: ImportOptions, posed: _PosedImages, created: bool
) -> tuple[Config, PosePoint | None]:
    """Fit where the poses sit along the car (:func:`fit_pose_point`) and use or check it.

    A workspace this import created takes the fitted distance ahead of the rear axle when
    ``--pose-offset`` left X to be fitted (``fit,Y,Z``) or was not given (then only when the
    poses are clearly not at the rear axle, the default); the config is saved with it. A
    pose point given in numbers, or in an existing workspace's config, is kept, and a warning
    names the fitted one when they disagree. Poses without orientation (GPS fixes) are not
    fitted: their heading is their own direction of travel, so they never slip. Returns the
    config and the fit (None: the drive turns too little to tell, or the poses have no
    orientation).
    """
    given = opts.pose_offset_m
    wants_fit = created and (given is None or given[0] is None)
    if posed.heading_from_motion:
        # The heading is the poses' own direction of travel: they never slip, wherever they
        # sit on the car, so their turns cannot tell; taken as the rear axle's, the path is
        # driven as the recorded one moved.
        if wants_fit and given is not None:
            logger.warning(
                "--pose-offset fit: the poses have no orientation (their heading is their "
                "direction of travel), so their turns cannot tell where they sit along the car; "
                "they are taken to be over the rear axle (give X in metres if you know it)"
            )
        return config, None
    cols = posed.columns
    order = np.argsort(posed.stamps[posed.keep], kind="stable")
    fit = fit_pose_point(
        posed.stamps[posed.keep][order] / 1e9,
        np.stack([cols["x"], cols["y"]], -1)[order],
        np.asarray(cols["heading"])[order],
        np.asarray(cols["speed"])[order],
    )
    vehicle = config.vehicle
    ahead = vehicle.reference_ahead_of_rear_axle_m()
    if fit is None:
        if wants_fit and given is not None:
            logger.warning(
                "--pose-offset fit: the drive turns too little to tell where the poses sit "
                "along the car; they are taken to be over the rear axle (give X in metres)"
            )
        return config, None
    told = str(fit)
    off = fit.disagrees_with(ahead)
    if wants_fit and (given is not None or off):
        y, z = (0.0, 0.0) if given is None else (given[1], given[2])
        offset = (round(vehicle.rear_axle_x_m + fit.ahead_m, 3), y, z)
        config = config.model_copy(
            update={
                "vehicle": vehicle.model_copy(
                    update={"reference": "offset", "reference_offset_m": offset}
                )
            }
        )
        save_config(config, ws.config_path, comment=_CREATED_COMMENT)
        logger.info(
            "the poses turn like a point %s (%d samples in turns): vehicle.reference_offset_m "
            "set to [%.3f, %.2f, %.2f]", told, fit.turning, *offset,
        )  # fmt: skip
    elif off:
        logger.warning(
            "the poses turn like a point %s, but the vehicle config puts them %.2f m ahead: the "
            "simulated car will not turn as the recorded one did. Re-import with --pose-offset "
            "fit,Y,Z, or set vehicle.reference_offset_m in config.yaml to [%.2f, Y, Z]",
            told, ahead, vehicle.rear_axle_x_m + fit.ahead_m,
        )  # fmt: skip
    else:
        logger.info("the poses turn like a point %s, as configured", told)
    return config, fit


def _write_signals(
    paths: DatasetPaths,
    signals: dict[str, tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]],
) -> None:
    for name, (stamps, values) in signals.items():
        write_table(
            paths.signal_file(name),
            {"stamp_ns": stamps, "t": stamps / 1e9, "value": values},
            precision=POSE_PRECISION,
        )


def _read_signal(name: str, path: Path) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]:
    """A signal CSV (``--signal NAME=CSV``): a time column and a value column, in time order.

    Or a comma2k19 processed-log folder (``t`` and ``value`` numpy files, seconds).

    Time: ``stamp_ns``, ``timestamp``, ``t`` or ``time`` (seconds, on the images' time base);
    value: ``value``, a column named ``name``, or the only other column.
    """
    if not name.isidentifier():
        msg = f"--signal {name}={path}: the name must be a word (letters, digits, _), e.g. steering"
        raise RecordingError(msg)
    if is_log_signal(path):  # comma2k19's processed_log/<group>/<signal>/ (t, value)
        return read_log_signal(path)
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            rows = [
                {k.strip(): (v or "").strip() for k, v in r.items()} for r in csv.DictReader(handle)
            ]
    except FileNotFoundError:
        msg = f"--signal {name}={path}: no such file"
        raise RecordingError(msg) from None
    if not rows:
        msg = f"{path}: no rows; expected a header line (t,value) and one row per sample"
        raise RecordingError(msg)
    tcol = first_column(rows, "stamp_ns", "timestamp", "t", "time")
    others = [c for c in rows[0] if c != tcol]
    vcol = first_column(rows, "value", name) or (others[0] if len(others) == 1 else None)
    if tcol is None or vcol is None:
        msg = (
            f"{path}: needs a time column (stamp_ns, timestamp, t or time) and a value column "
            f"(value or {name}); found {', '.join(rows[0])}"
        )
        raise RecordingError(msg)
    try:
        stamps = table_stamps(rows, tcol)
        values = np.array([float(r[vcol]) for r in rows], dtype=np.float64)
    except ValueError as err:
        msg = f"{path}: a row is not a number ({err})"
        raise RecordingError(msg) from None
    order = np.argsort(stamps, kind="stable")
    return stamps[order], values[order]


def _world(
    table: PoseTable, crs: str | None, existing: WorldFrameRecord | None
) -> tuple[WorldFrameRecord, npt.NDArray[np.float64], npt.NDArray[np.float64] | None]:
    """The world frame of the poses, and the poses in it (orientation None where not given).

    GPS poses (latitude, longitude) fix the frame at their first fix, metric ones at their first
    position in ``crs``; without either the frame is local (not geo-referenced).
    """
    if table.geographic:
        if crs is not None and crs.upper() not in {"EPSG:4326", "WGS84"}:
            msg = (
                f"the poses are GPS fixes (latitude, longitude: WGS84), not {crs}; drop --crs "
                "(or give EPSG:4326)"
            )
            raise RecordingError(msg)
        crs = "EPSG:4326"
    if crs is None:
        return WorldFrameRecord(proj_string=None), table.xyz, table.quat
    if existing is not None and existing.source_crs == crs and existing.origin_lat_deg is not None:
        wf = frames.WorldFrame(
            existing.origin_lat_deg, existing.origin_lon_deg or 0.0, existing.origin_alt_m
        )
    elif table.geographic:
        lat, lon, alt = table.xyz[0]
        wf = frames.WorldFrame(float(lat), float(lon), float(alt))
    else:
        x, y, z = table.xyz[0]
        wf = frames.WorldFrame.at_crs_point(crs, float(x), float(y), float(z))
    record = WorldFrameRecord(
        proj_string=wf.proj_string,
        origin_lat_deg=wf.origin_lat_deg,
        origin_lon_deg=wf.origin_lon_deg,
        origin_alt_m=wf.origin_alt_m,
        source_crs=crs,
    )
    if table.geographic:  # east-north-up orientation: the world frame's axes at its origin
        xyz = wf.from_wgs84(table.xyz[:, 0], table.xyz[:, 1], table.xyz[:, 2])
        return record, xyz, table.quat
    xyz = wf.from_crs(crs, table.xyz)
    quat = None if table.quat is None else wf.quats_from_crs(crs, table.xyz[:, :2], table.quat)
    return record, xyz, quat


def _heading_quats(
    table: PoseTable,
    stamp_ns: npt.NDArray[np.int64],
    xyz: npt.NDArray[np.float64],
    sync: SyncConfig,
) -> npt.NDArray[np.float64]:
    """Orientation from the direction of travel, for poses that give none (GPS fixes)."""
    if table.by_index:
        msg = "the pose file gives no orientation and no times; add yaw or qx,qy,qz,qw"
        raise RecordingError(msg)
    order = np.argsort(stamp_ns, kind="stable")
    quat = np.empty((len(order), 4))
    quat[order] = orientation_from_motion(
        stamp_ns[order],
        xyz[order],
        window_s=sync.heading_window_s,
        min_speed_mps=sync.min_motion_speed_mps,
        pitch_window_m=sync.pitch_window_m,
    )
    pitch = frames.euler_from_quat(quat).pitch
    logger.info(
        "import: the poses give no orientation; heading from the direction of travel, pitch "
        "from the grade (%.1f to %.1f degrees)", np.degrees(pitch.min()), np.degrees(pitch.max())
    )  # fmt: skip
    return quat


ORIENTATION_OFF_TRAVEL_DEG: Final = 30.0
"""A pose file's headings this far (median over the samples driven) from the direction of
travel are a convention mistake, not a car: the import stops and says which."""


def _check_poses(
    table: PoseTable,
    stamp_ns: npt.NDArray[np.int64],
    xyz: npt.NDArray[np.float64],
    given: npt.NDArray[np.float64] | None,
    opts: ImportOptions,
) -> None:
    """Stop on poses whose times or orientation are in a convention the reader did not assume.

    ``given``: the orientation the file gave (world frame, body axes), None without one.
    """
    if not table.by_index:
        _check_speed(stamp_ns, xyz, opts)
    if given is not None:
        _check_orientation(table, xyz, given, opts)


MAX_MEDIAN_SPEED_MPS: Final = 70.0
"""Poses whose median speed is above this (250 km/h) have times in the wrong unit."""
MIN_MEDIAN_SPEED_MPS: Final = 0.05
"""Poses that cover 20 m at a median speed below this (milliseconds read as seconds: 8 m/s
becomes 0.008) have times in the wrong unit too."""


def _check_speed(
    stamp_ns: npt.NDArray[np.int64], xyz: npt.NDArray[np.float64], opts: ImportOptions
) -> None:
    """Stop when the poses move faster than a car: their times are not in seconds.

    Raises:
        RecordingError: The median speed between poses is above :data:`MAX_MEDIAN_SPEED_MPS`.
    """
    order = np.argsort(stamp_ns, kind="stable")
    dt = np.diff(stamp_ns[order]).astype(np.float64) / 1e9
    step = np.linalg.norm(np.diff(xyz[order][:, :2], axis=0), axis=1)
    moving = (dt > 0) & (step > 0)
    if moving.sum() < 3:
        return
    speed = float(np.median(step[moving] / dt[moving]))
    crawl = speed < MIN_MEDIAN_SPEED_MPS and float(step.sum()) > 20.0
    if speed <= MAX_MEDIAN_SPEED_MPS and not crawl:
        return
    than = "faster than a car" if not crawl else "slower than a car could cover them"
    msg = (
        f"{opts.poses}: the poses move at a median {speed:.3g} m/s between them, {than}: "
        "their times are likely not in seconds. Name the time column's unit (`time_ms`, "
        "`time [ms]`, `stamp_ns`) or write the times in seconds"
    )
    raise RecordingError(msg)


def _check_orientation(
    table: PoseTable,
    xyz: npt.NDArray[np.float64],
    quat: npt.NDArray[np.float64],
    opts: ImportOptions,
) -> None:
    """Stop when the poses' headings do not follow their own travel.

    Raises:
        RecordingError: The median heading is more than :data:`ORIENTATION_OFF_TRAVEL_DEG`
            from the direction of travel over the samples driven (at least 10).
    """
    order = np.argsort(table.stamp_ns, kind="stable")  # by_index: the rows' order
    off = heading_off_travel(xyz[order], frames.yaw_from_quat(quat[order]))
    driven = off[np.isfinite(off)]
    if len(driven) < 10:
        return
    median = float(np.degrees(np.median(np.abs(driven))))
    if median <= ORIENTATION_OFF_TRAVEL_DEG:
        return
    signed = float(np.degrees(np.median(driven)))
    turned = {90.0: "x_left", -90.0: "x_right", 180.0: "x_backward", -180.0: "x_backward"}
    near = [name for angle, name in turned.items() if abs(signed - angle) < 20.0]
    axes = f"--axis-convention {near[0]}" if near else "--axis-convention"
    geographic = (
        "in a lat/lon CSV `heading` is read as degrees clockwise from north (as GNSS/INS "
        "write it) and `yaw` as radians counter-clockwise from east"
        if table.geographic
        else "a CSV's `yaw`/`heading` is read as radians counter-clockwise from x"
    )
    msg = (
        f"{opts.poses}: the poses' headings are {median:.0f} degrees from their own direction "
        f"of travel (median over {len(driven)} samples driven; typically {signed:+.0f}): "
        f"{geographic}. Give {axes} when the body's forward axis is not the poses' x, fix the "
        "orientation's convention, or leave the orientation out to take the heading from the "
        "motion"
    )
    raise RecordingError(msg)


@dataclass(frozen=True)
class _PosedImages:
    world: WorldFrameRecord
    keep: npt.NDArray[np.bool_]
    stamps: npt.NDArray[np.int64]
    columns: dict[str, npt.NDArray[Any]]
    dropped: dict[str, int]
    heading_from_motion: bool
    notes: tuple[str, ...] = ()


def _poses_for_images(
    table: PoseTable,
    files: list[Path],
    stamps: npt.NDArray[np.int64],
    opts: ImportOptions,
    existing: WorldFrameRecord | None,
    time_source: str,
    sync: SyncConfig,
) -> _PosedImages:
    """Give every image its pose: by the table's image column, else by time."""
    dropped: dict[str, int] = {}
    world, xyz, given = _world(table, opts.crs, existing)
    stamp_ns = table.stamp_ns
    gap = gap_limit_s(stamp_ns, opts.max_pose_gap_s)  # a 1 Hz GPS: 2.5 s
    notes: tuple[str, ...] = ()
    if given is None and not (table.by_index or table.images is not None):
        # Fixes without orientation: their jitter smoothed away (else it reaches the heading,
        # the speed and the derived steering), then slow ones (1 Hz GPS) follow a cubic
        # through them, not straight chords.
        xyz, moved = smooth_positions(stamp_ns, xyz, max_gap_s=gap)
        if moved > 0:
            notes = (f"the position fixes were smoothed (they moved {moved:.3f} m RMS)",)
        stamp_ns, xyz = densify_positions(stamp_ns, xyz, max_gap_s=gap)
    quat = given if given is not None else _heading_quats(table, stamp_ns, xyz, sync)
    offset = AXIS_CONVENTION_YAW_OFFSET[opts.axis_convention]
    quat = frames.quat_normalize(frames.quat_multiply(quat, yaw_offset_quat(offset)))
    _check_poses(table, stamp_ns, xyz, quat if given is not None else None, opts)
    if table.images is not None or table.by_index:
        if table.by_index:  # row k belongs to the k-th image; the images give the times
            rows = np.where(np.arange(len(files)) < len(table.xyz), np.arange(len(files)), -1)
        else:
            index = {name: i for i, name in enumerate(table.images or [])}
            rows = np.array([index.get(f.name, -1) for f in files])
        keep = rows >= 0
        if (~keep).any():
            dropped["no_pose_row"] = int((~keep).sum())
        if not table.by_index:
            stamps = np.where(keep, table.stamp_ns[np.maximum(rows, 0)], stamps)
        sel = rows[keep]
        traj_pos, traj_q = xyz[sel], quat[sel]
        speed = np.zeros(int(keep.sum()))
        if keep.sum() >= 2:
            order = np.argsort(stamps[keep])
            traj = Trajectory(stamps[keep][order], traj_pos[order], traj_q[order])
            speed[order] = traj.speed_at(stamps[keep][order], window_s=0.2)
    else:
        traj = Trajectory(stamp_ns, xyz, quat)
        s = traj.sample(stamps, max_gap_s=gap)
        keep = s.valid
        for reason in np.unique(s.reason[~s.valid]):
            dropped[str(reason)] = int((s.reason == reason).sum())
        traj_pos, traj_q, speed = s.position, s.quat, s.speed
    if not keep.any():
        msg = (
            f"no image has a pose: images span {stamps.min() / 1e9:.3f}-"
            f"{stamps.max() / 1e9:.3f} s ({time_source}), poses span "
            f"{table.stamp_ns[0] / 1e9:.3f}-{table.stamp_ns[-1] / 1e9:.3f} s. Name the "
            "images by timestamp, add an image column to the pose table, or give --start "
            "(when the first frame was taken, on the poses' clock)"
        )
        raise RecordingError(msg)
    pose_cols = {
        "x": traj_pos[:, 0],
        "y": traj_pos[:, 1],
        "z": traj_pos[:, 2],
        "qx": traj_q[:, 0],
        "qy": traj_q[:, 1],
        "qz": traj_q[:, 2],
        "qw": traj_q[:, 3],
        "heading": frames.yaw_from_quat(traj_q),
        "speed": speed,
    }
    return _PosedImages(world, keep, stamps, pose_cols, dropped, given is None, notes)


@dataclass(frozen=True)
class ImportOptions:
    """Options of :func:`import_images`."""

    poses: Path | None = None
    calibration: Path | None = None
    crs: str | None = None
    axis_convention: AxisConvention = AxisConvention.X_FORWARD
    fps: float = 30.0
    max_pose_gap_s: float = 0.5
    signals: tuple[tuple[str, Path], ...] = ()
    pose_offset_m: tuple[float | None, float, float] | None = None
    rig: Path | None = None
    start: str | None = None
    video_fps: float = 10.0
    fov_deg: float | None = None

    @property
    def poses_file(self) -> Path | None:
        """The pose file given, or None (no poses, or ``exif``: the photos' own tags)."""
        return None if self.poses is None or self.exif_poses else self.poses

    @property
    def exif_poses(self) -> bool:
        """Whether the poses are the photos' own EXIF GPS tags (``--poses exif``)."""
        return self.poses is not None and str(self.poses).lower() == EXIF_POSES


def _fingerprint(path: Path) -> str:
    """A file's fingerprint; a folder's (KITTI's OXTS) from its files' names and fingerprints."""
    if not path.is_dir():
        return file_fingerprint(path)
    files = sorted(f for f in path.rglob("*") if f.is_file())
    return hash_inputs([(str(f.relative_to(path)), file_fingerprint(f)) for f in files])


def import_images(
    root: Path,
    images: Path,
    *,
    options: ImportOptions | None = None,
    progress: ProgressCallback | None = None,
) -> ImportResult:
    """Import an image folder (and optional poses and calibration) as the workspace dataset.

    Creates the workspace when it does not exist yet.

    Raises:
        RecordingError: No images, unreadable pose table or calibration, or no image with a pose.
    """
    opts = options or ImportOptions()
    progress = progress or no_progress
    if opts.calibration is not None and opts.fov_deg is not None:
        msg = "give --calibration or --fov, not both (the calibration says more)"
        raise RecordingError(msg)
    images = Path(images)
    video = is_video(images)
    files = [] if video else _list_images(images)
    signals = {name: _read_signal(name, path) for name, path in opts.signals}
    rig = read_rig(opts.rig) if opts.rig is not None else []
    exif = opts.exif_poses
    if exif and video:
        msg = "--poses exif reads the GPS tags of photos; a video has none: give its GPS track"
        raise RecordingError(msg)
    poses_file = opts.poses_file
    table = read_exif_poses(files) if exif else read_pose_file(poses_file) if poses_file else None
    ws, config, created = _open_workspace(Path(root), opts)
    scratch = ws.video_scratch_dir
    try:
        if video:
            shutil.rmtree(scratch, ignore_errors=True)
            bare = images.suffix.lower() in RAW_STREAM_SUFFIXES
            decoded = decode_video(
                images, scratch, max_fps=opts.video_fps, fmt=config.frames.format,
                jpeg_quality=config.frames.jpeg_quality, stream_fps=opts.fps if bare else None,
                progress=progress,
            )  # fmt: skip
            files, stamps = decoded.files, decoded.stamp_ns
            clock = f"--fps {opts.fps:g} (a bare stream has no times)" if bare else "frame times"
            time_source = (
                f"the video's {clock} ({len(files)} of its {decoded.decoded} frames, at most "
                f"{opts.video_fps:g} a second)"
            )
        elif exif:
            assert table is not None
            stamps, time_source = table.stamp_ns.copy(), "the photos' EXIF times"
        else:
            stamps, time_source = stamps_from_names(files, fps=opts.fps)
        stamps, notes = (
            (stamps, ()) if exif else _start_time(stamps, time_source, table, opts.start)
        )
        if table is None and files and has_exif_gps(files[0]):
            notes = (*notes, "the images carry EXIF GPS tags: import with --poses exif to use them")
        source = _Frames(images, files, stamps, time_source)
        inputs = _Inputs(table, signals, rig, (*(table.notes if table else ()), *notes))
        return _import(ws, config, created, source, inputs, opts, progress)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _start_time(
    stamps: npt.NDArray[np.int64], time_source: str, table: PoseTable | None, start: str | None
) -> tuple[npt.NDArray[np.int64], tuple[str, ...]]:
    """The images' times on the poses' clock: from ``--start``, or the first pose's time.

    Images whose times count from zero (a frame rate, a video) beside poses with dates (a GPS
    track), or on a clock the images' times never meet, take the first pose's time for the
    first frame, with a note saying so.

    Raises:
        RecordingError: ``start`` is neither seconds nor a date.
    """
    if start is not None:
        try:
            first = stamp_ns_from_text(start)
        except ValueError:
            msg = f"--start takes seconds or an ISO date (2026-05-01T09:30:00Z); got {start!r}"
            raise RecordingError(msg) from None
        return stamps - stamps[0] + first, ()
    relative = not time_source.startswith("file names")
    timed = table is not None and not table.by_index and table.images is None
    if not (relative and timed and table is not None):
        return stamps, ()
    # Dated poses (a GPS track), or poses on a clock of their own that the images' times never
    # meet (an NMEA log without dates counts from midnight): the first frame at the first pose.
    apart = stamps.max() < table.stamp_ns[0] or stamps.min() > table.stamp_ns[-1]
    if not (table.stamp_ns[0] > _DATED_NS or apart):
        return stamps, ()
    first = int(table.stamp_ns[0])
    when = datetime.fromtimestamp(first / 1e9, tz=UTC).isoformat(timespec="milliseconds")
    note = (
        f"the images have no dates ({time_source}): the first frame is taken at the first "
        f"pose's time, {when}; pass --start if the recording and the poses began apart"
    )
    return stamps - stamps[0] + first, (note,)


_DATED_NS = 10**17
"""Times past this (1973) are dates, not a recording's own clock from zero."""


@dataclass(frozen=True)
class _Frames:
    """The frames to import: the ``--images`` given, its image files and their times."""

    images: Path
    files: list[Path]
    stamps: npt.NDArray[np.int64]
    time_source: str


@dataclass(frozen=True)
class _Inputs:
    """What comes beside the frames: poses, signals, rig cameras, and notes for the user."""

    table: PoseTable | None
    signals: dict[str, tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]]
    rig: list[RigSpec]
    notes: tuple[str, ...]


def _import(
    ws: Workspace,
    config: Config,
    created: bool,
    source: _Frames,
    inputs: _Inputs,
    opts: ImportOptions,
    progress: ProgressCallback,
) -> ImportResult:
    """:func:`import_images` once its frames, times and poses are read."""
    images, files, stamps, time_source = (
        source.images, source.files, source.stamps, source.time_source
    )  # fmt: skip
    table, signals, rig, notes = inputs.table, inputs.signals, inputs.rig, inputs.notes
    intr, mount = (None, None)
    if opts.calibration:
        intr, mount = intrinsics_from_file(opts.calibration, _image_size(files[0]), images)
    elif opts.fov_deg is not None:
        intr = intrinsics_from_fov(opts.fov_deg, _image_size(files[0]) or (0, 0))
    extra_inputs = [
        *(p for p in (opts.poses_file, opts.calibration, opts.rig) if p is not None),
        *(path for _, path in opts.signals),
    ]
    sources = [SourceRecord(path=str(p), fingerprint=_fingerprint(p)) for p in extra_inputs]
    images_print = (
        file_fingerprint(images) if images.is_file() else hash_inputs([f.name for f in files])
    )
    inputs_hash = hash_inputs({"files": images_print, "opts": repr(opts)})
    with (
        stage_run(ws, STAGE, inputs_hash=inputs_hash, config=config) as run,
        atomic_folder(ws.dataset_dir) as tmp,
    ):
        paths = DatasetPaths(tmp)
        dropped: dict[str, int] = {}
        world = WorldFrameRecord(proj_string=None)
        keep = np.ones(len(files), dtype=bool)
        pose_cols: dict[str, npt.NDArray[Any]] | None = None
        pose_point: PosePoint | None = None
        motion = False
        if table is not None:
            posed = _poses_for_images(
                table, files, stamps, opts, ws.world_frame(), time_source, config.sync
            )
            config, pose_point = _place_poses(ws, config, opts, posed, created)
            run.config = config
            world, keep, stamps, pose_cols, dropped = (
                posed.world,
                posed.keep,
                posed.stamps,
                posed.columns,
                posed.dropped,
            )
            motion = posed.heading_from_motion
            notes = (*notes, *posed.notes)
            if dropped:
                why = ", ".join(f"{n} {reason.replace('_', ' ')}" for reason, n in dropped.items())
                left = f"{sum(dropped.values())} of {len(files)} frames have no pose ({why})"
                notes = (*notes, f"{left} and were left out")
        kept = [f for f, k in zip(files, keep, strict=True) if k]
        kept_stamps = stamps[keep]
        fmt = config.frames.format
        size = _write_frames(
            kept, paths, fmt, config.frames.jpeg_quality, progress, move=images.is_file()
        )
        _write_frame_tables(paths, kept_stamps, pose_cols)
        _write_signals(paths, signals)
        if intr is not None:  # a grey camera's simulated views are made grey too
            written = [paths.frame_file(i, fmt) for i in range(len(kept))]
            intr = intr.model_copy(update={"grey": frames_are_grey(written)})
        rig_names = write_rig(
            paths, rig, keep, intr, source=opts.rig or Path(), fmt=fmt,
            list_images=_list_images, intrinsics_from_file=intrinsics_from_file,
        )  # fmt: skip
        _save_calibration(paths, intr, mount, size)
        info = DatasetInfo(
            kind="images",
            pose_less=table is None,
            sources=(
                SourceRecord(path=str(images), fingerprint=images_print),
                *sources,
            ),
            time_base="file",
            counts=DatasetCounts(
                frames=len(kept),
                pose_samples=0 if table is None else len(table.stamp_ns),
                signals={name: len(v[0]) for name, v in signals.items()},
            ),
            start_ns=int(kept_stamps.min()),
            end_ns=int(kept_stamps.max()),
            duration_s=float(kept_stamps.max() - kept_stamps.min()) / 1e9,
            dropped={"camera": dropped} if dropped else {},
            frame_format=fmt,
            world=world,
            rig=rig_names,
            heading_from_motion=motion,
        )
        info.save(paths.dataset_json)
        run.world = world
    logger.info("import: %d frames (%s), pose-less: %s", len(kept), time_source, table is None)
    for note in notes:
        logger.info("import: %s", note)
    return ImportResult(ws.dataset_dir, info, pose_point, notes)


def _write_frame_tables(
    paths: DatasetPaths,
    stamps: npt.NDArray[np.int64],
    pose_cols: dict[str, npt.NDArray[Any]] | None,
) -> None:
    """The frames' table: with poses, ``poses.csv`` and the trajectory; else ``frames.csv``."""
    base = {"frame": np.arange(len(stamps), dtype=np.int64), "stamp_ns": stamps, "t": stamps / 1e9}
    if pose_cols is None:
        write_table(paths.frames_csv, base, precision=POSE_PRECISION)
        return
    write_table(paths.poses_csv, base | pose_cols, precision=POSE_PRECISION)
    # The trajectory the map, scenario and derived steering read: the images' poses in time
    # order (an extracted bag's holds every pose message).
    order = np.argsort(stamps, kind="stable")
    trajectory = {"stamp_ns": stamps[order], "t": stamps[order] / 1e9}
    trajectory |= {k: np.asarray(v)[order] for k, v in pose_cols.items()}
    write_table(paths.trajectory_csv, trajectory, precision=POSE_PRECISION)


def _save_calibration(
    paths: DatasetPaths,
    intr: CameraIntrinsics | None,
    mount: MountRecord | None,
    size: tuple[int, int],
) -> None:
    """The camera's calibration (the mount at the pose point when none is given).

    Raises:
        RecordingError: The calibration is for another image size.
    """
    if intr is not None and (intr.width, intr.height) != size:
        msg = f"calibration is for {intr.width}x{intr.height} but images are {size[0]}x{size[1]}"
        raise RecordingError(msg + "; pass the calibration of these images")
    default = MountRecord(
        translation_m=(0.0, 0.0, 0.0), quat_xyzw=IDENTITY_OPTICAL, axes="optical", source="default"
    )
    Calibration(camera=intr, camera_mount=mount or default).save(paths.calibration_json)


def _write_frames(
    files: list[Path],
    paths: DatasetPaths,
    fmt: Literal["png", "jpeg"],
    quality: int,
    progress: ProgressCallback,
    *,
    move: bool = False,
) -> tuple[int, int]:
    import cv2  # noqa: PLC0415

    from cam2sim.recording.image import encode_image_file  # noqa: PLC0415 -- lazy: imports cv2

    paths.frames_dir.mkdir(parents=True, exist_ok=True)
    if move:  # a video's frames, decoded into the workspace in this format: one size, renamed
        first = _image_size(files[0])
        assert first is not None  # decode_video wrote it
        for i, f in enumerate(files):
            f.replace(paths.frame_file(i, fmt))
        progress("images", len(files), len(files))
        return first
    size: tuple[int, int] | None = None
    want_suffix = (".jpg", ".jpeg") if fmt == "jpeg" else (".png",)
    for i, f in enumerate(files):
        # cv2 returns a MatLike whose dtype is only known at run time.
        image: Any = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        if image is None:
            msg = f"{f} cannot be read as an image; remove or replace it"
            raise RecordingError(msg)
        this = (int(image.shape[1]), int(image.shape[0]))
        if size is None:
            size = this
        elif this != size:
            msg = f"{f} is {this[0]}x{this[1]} but earlier images are {size[0]}x{size[1]}"
            raise RecordingError(msg)
        target = paths.frame_file(i, fmt)
        if f.suffix.lower() in want_suffix:
            shutil.copyfile(f, target)
        else:
            if image.ndim == 3:
                image = cv2.cvtColor(
                    image, cv2.COLOR_BGRA2RGB if image.shape[2] == 4 else cv2.COLOR_BGR2RGB
                )
            write_bytes_atomic(target, encode_image_file(image, fmt, jpeg_quality=quality))
        if i % 16 == 0:
            progress("images", i + 1, len(files))
    progress("images", len(files), len(files))
    assert size is not None
    return size
