"""Pose files that come beside an image folder: the poses of ``cam2sim import``.

Seven layouts are read, each into one :class:`PoseTable`:

- a CSV in a metric frame: ``timestamp|t|stamp_ns, x, y[, z]`` (the frame's CRS is the
  import's ``--crs``, or none: a local frame);
- a CSV of GPS fixes: ``timestamp, lat, lon[, alt]`` (WGS84 degrees and metres): geo-referenced
  without ``--crs``;
- KITTI odometry's ``poses.txt``: a 3x4 camera-to-world matrix a line, line k for image k;
- KITTI raw's ``oxts/`` folder (or its ``data/``): one text file a frame, file k for image k,
  whose first six numbers are latitude, longitude, altitude, roll, pitch and yaw (the GPS/IMU
  unit's axes x forward, y left, z up; yaw 0 east, counter-clockwise; ``R = Rz Ry Rx``);
- the TUM trajectory format SLAM systems and ``evo`` write (``timestamp tx ty tz qx qy qz qw`` a
  line, ``#`` comments): a camera's optical axes (z forward, as visual SLAM writes them) or a
  body's (x forward), told apart by the direction the poses travel in;
- a GPS track: GPX, or an NMEA 0183 log (:mod:`cam2sim.recording.gps_track`).

A CSV's orientation is ``qx, qy, qz, qw``, ``yaw`` (radians, counter-clockwise from the frame's
x axis; east for GPS) or ``heading`` (the same in a metric CSV; in a GPS CSV what a GNSS/INS
writes: degrees clockwise from north). A GPS receiver's ``course`` or ``bearing`` (the
direction of travel, undefined standing still) is not an orientation and is not read. Without
one the caller takes the heading from the direction of travel (:attr:`PoseTable.quat` is
None). An ``image`` column names the file each row belongs to. Column names are matched
trimmed, in any case and without a unit (``Latitude (deg)``, ``time [s]``).
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Final

import numpy as np
import numpy.typing as npt

from cam2sim.core import frames
from cam2sim.core.errors import RecordingError
from cam2sim.recording.comma2k19 import global_pose_folder, read_global_pose
from cam2sim.recording.exif_gps import read_exif_track
from cam2sim.recording.gps_track import GpsTrack, is_nmea, read_gpx, read_nmea
from cam2sim.recording.timestamps import UNIT_NS, is_time_of_day, iso_ns, stamp_ns_from_text

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

__all__ = [
    "EXIF_POSES",
    "PoseTable",
    "first_column",
    "read_exif_poses",
    "read_pose_file",
    "stamp_ns_from_text",
    "table_stamps",
]

_LAT = ("lat", "latitude", "lat_deg", "latitude_deg", "gps_lat", "gps_latitude")
_LON = ("lon", "lng", "long", "longitude", "lon_deg", "longitude_deg", "gps_lon", "gps_lng",
        "gps_longitude")  # fmt: skip
_ALT = ("alt", "altitude", "alt_m", "altitude_m", "elevation", "ele", "height", "gps_alt")
_TIME = (
    *(
        f"{name}{unit}"
        for name in ("stamp", "timestamp", "t", "time")
        for unit in ("", "_s", "_sec", "_ms", "_us", "_ns")
        if f"{name}{unit}" != "stamp"
    ),
    *("datetime", "date_time", "utc", "time_utc", "utc_time", "gps_time", "unix_time", "epoch"),
)
_UNIT = re.compile(r"\s*[(\[]([^)\]]*)[)\]]\s*$")
"""A unit after a column name: ``Latitude (deg)``, ``time [s]``."""


def _column_name(name: str | None) -> str:
    """A CSV header cell as the reader looks it up: trimmed, lower case, without a unit."""
    return _UNIT.sub("", (name or "").strip()).lower()


def _column_units(header: Sequence[str] | None) -> dict[str, str]:
    """The unit each header cell names in brackets, by its looked-up name (``time [ms]``)."""
    units = {}
    for cell in header or []:
        found = _UNIT.search((cell or "").strip())
        if found:
            units[_column_name(cell)] = found.group(1).strip().lower()
    return units


@dataclass(frozen=True)
class PoseTable:
    """The poses of a pose file, in file order (CSV rows by time unless they name images).

    Attributes:
        stamp_ns: ``(N,)`` int64 times; row indices where ``by_index`` (the images give times).
        xyz: ``(N, 3)`` positions: metres in the file's frame, or latitude, longitude (degrees)
            and altitude (metres) where ``geographic``.
        quat: ``(N, 4)`` orientation (x, y, z, w) of the pose frame (x forward, y left, z up) in
            the file's frame (east-north-up where ``geographic``), or None: none was given.
        images: The image file each row belongs to, or None.
        by_index: Row k belongs to the k-th image (KITTI's poses.txt and OXTS folders).
        geographic: ``xyz`` holds WGS84 latitude, longitude, altitude.
        kind: What was read (``csv``, ``gps csv``, ``kitti poses``, ``kitti oxts``, ``tum``,
            ``tum camera``, ``gpx``, ``nmea``).
        notes: What the reader found or assumed that the user should know.
    """

    stamp_ns: npt.NDArray[np.int64]
    xyz: npt.NDArray[np.float64]
    quat: npt.NDArray[np.float64] | None
    images: list[str] | None
    by_index: bool = False
    geographic: bool = False
    kind: str = "csv"
    notes: tuple[str, ...] = ()


def first_column(rows: list[dict[str, str]], *names: str) -> str | None:
    """The first of ``names`` that is a column of ``rows`` (None: none is)."""
    for name in names:
        if name in rows[0]:
            return name
    return None


def table_stamps(
    rows: list[dict[str, str]], column: str, unit: str | None = None
) -> npt.NDArray[np.int64]:
    """Nanosecond stamps of a table's time column.

    The unit is ``unit`` (a header's ``time [ms]``), else the column name's (``stamp_ns``,
    ``time_ms``), else seconds, dates or times of day (:func:`stamp_ns_from_text`, which also
    tells epoch milliseconds, microseconds and nanoseconds by their size). Times of day that
    run past midnight go on into the next day.

    Raises:
        ValueError: A cell is not a number, a date or a time of day.
    """
    suffix = column.rpartition("_")[2]
    if unit is None and "_" in column and suffix in (*UNIT_NS, "sec"):
        unit = "s" if suffix == "sec" else suffix
    stamps = np.array([stamp_ns_from_text(r[column], unit) for r in rows], dtype=np.int64)
    if len(stamps) > 1 and is_time_of_day(rows[0][column]):
        day = 86_400 * 1_000_000_000
        stamps = stamps + day * np.cumsum(np.r_[0, np.diff(stamps) < -day // 2])
    return stamps


# KITTI's camera-to-world poses: camera axes x right, y down, z forward, in the first camera's
# frame. The vehicle frame is x forward, y left, z up; its columns in camera axes:
_VEHICLE_IN_OPTICAL = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
# The world: the first camera's frame turned z up (x forward, y left at the start).
_WORLD_FROM_FIRST_CAMERA = _VEHICLE_IN_OPTICAL.T


def _numbers(line: str, count: int) -> bool:
    """Whether a line is ``count`` whitespace-separated numbers (no commas, no header).

    KITTI's poses are 12 (a 3x4 matrix), TUM's 8 (time, position, quaternion).
    """
    parts = line.split()
    if len(parts) != count or "," in line:
        return False
    try:
        [float(p) for p in parts]
    except ValueError:
        return False
    return True


def _read_kitti_poses(path: Path, lines: list[str]) -> PoseTable:
    """KITTI odometry poses (one 3x4 camera-to-world matrix a line, row k = image k).

    The vehicle pose is the camera's position with the vehicle's axes (x forward, y left,
    z up), in the first camera's frame turned z up; the camera's mount is then the identity
    optical mount at the pose point (the pose point is the camera, above the road).
    """
    try:
        m = np.array([[float(v) for v in ln.split()] for ln in lines]).reshape(-1, 3, 4)
    except ValueError as err:
        msg = f"{path}: a KITTI pose line is not 12 numbers ({err}); fix that line"
        raise RecordingError(msg) from None
    rot = _WORLD_FROM_FIRST_CAMERA @ m[:, :, :3] @ _VEHICLE_IN_OPTICAL
    xyz = (_WORLD_FROM_FIRST_CAMERA @ m[:, :, 3:]).reshape(-1, 3)
    if not (np.isfinite(xyz).all() and np.isfinite(rot).all()):
        msg = f"{path}: NaN/inf in the poses; remove those lines"
        raise RecordingError(msg)
    quat = frames.quat_normalize(frames.quat_from_matrix(rot))
    stamps = np.arange(len(m), dtype=np.int64)  # placeholders: the images give the times
    return PoseTable(stamps, xyz, quat, None, by_index=True, kind="kitti poses")


def _optical_axes(rot: npt.NDArray[np.float64], xyz: npt.NDArray[np.float64]) -> bool | None:
    """Whether poses travel along their z axis (a camera's optical frame) or their x axis.

    Returns:
        True: along z; False: along x (a body frame); None: they do not move, or neither.
    """
    step = np.diff(xyz, axis=0)
    moving = np.linalg.norm(step, axis=1) > 0.01
    if moving.sum() < 2:
        return None
    local = np.einsum("nji,nj->ni", rot[:-1][moving], step[moving])  # R^T d
    mean = (local / np.linalg.norm(local, axis=1, keepdims=True)).mean(axis=0)
    if mean[2] > 0.7:
        return True
    if abs(mean[0]) > 0.7:
        return False
    return None


def _read_tum(path: Path, lines: list[str]) -> PoseTable:
    """A TUM trajectory (``timestamp tx ty tz qx qy qz qw`` a line).

    Poses that travel along their own z axis are a camera's (visual SLAM, COLMAP): they become
    the vehicle's axes at the camera, as KITTI's, and a world whose up is not +z (SLAM's first
    camera frame, y down) is turned z up from the first pose. Others are a body's (x forward):
    as given, ``--axis-convention`` saying where their x points.
    """
    rows = [ln.split() for ln in lines if not ln.lstrip().startswith("#")]
    try:
        stamps = np.array([stamp_ns_from_text(r[0]) for r in rows], dtype=np.int64)
        values = np.array([[float(v) for v in r[1:]] for r in rows], dtype=np.float64)
    except (ValueError, IndexError) as err:
        msg = f"{path}: a TUM line is not 'timestamp tx ty tz qx qy qz qw' ({err}); fix it"
        raise RecordingError(msg) from None
    if values.shape[1:] != (7,) or not np.isfinite(values).all():
        msg = f"{path}: every TUM line needs 8 finite numbers; fix the lines that do not"
        raise RecordingError(msg)
    order = np.argsort(stamps, kind="stable")
    stamps, values = stamps[order], values[order]
    if (np.diff(stamps) == 0).any():
        msg = f"{path}: two poses share a timestamp; remove duplicates"
        raise RecordingError(msg)
    xyz, quat = values[:, :3], frames.quat_normalize(values[:, 3:])
    rot = frames.quat_to_matrix(quat)
    optical = _optical_axes(rot, xyz)
    if optical is None:
        msg = (
            f"{path}: the poses travel along neither their x axis (a vehicle's) nor their z "
            "axis (a camera's); give poses of a moving car or camera"
        )
        raise RecordingError(msg)
    if not optical:
        note = "TUM poses of a body (x forward)"
        return PoseTable(stamps, xyz, quat, None, kind="tum", notes=(note,))
    up = np.einsum("nij,j->ni", rot, [0.0, -1.0, 0.0]).mean(axis=0)  # the camera's up, in world
    z_up = bool(up[2] > 0.9 * np.linalg.norm(up))
    turn = np.eye(3) if z_up else _WORLD_FROM_FIRST_CAMERA @ rot[0].T
    rot_v = turn @ rot @ _VEHICLE_IN_OPTICAL
    note = "TUM poses of a camera (optical axes: z forward), placed as the vehicle's"
    if not z_up:
        note += "; the world turned z up from the first camera"
    return PoseTable(
        stamps,
        (turn @ xyz.T).T,
        frames.quat_normalize(frames.quat_from_matrix(rot_v)),
        None,
        kind="tum camera",
        notes=(note,),
    )


def _oxts_stamps(path: Path, count: int) -> npt.NDArray[np.int64]:
    """Times of an OXTS folder's ``timestamps.txt`` (KITTI's local date and time), else indices."""
    stamps_file = path / "timestamps.txt"
    if not stamps_file.is_file():
        return np.arange(count, dtype=np.int64)
    lines = [ln.strip() for ln in stamps_file.read_text(encoding="utf-8").splitlines()]
    lines = [ln for ln in lines if ln]
    if len(lines) != count:
        msg = (
            f"{stamps_file}: {len(lines)} times for {count} OXTS files; give the folder as "
            "KITTI ships it (one time a file)"
        )
        raise RecordingError(msg)
    try:
        ns = np.array([iso_ns(ln) for ln in lines], dtype=np.int64)
    except ValueError as err:
        msg = f"{stamps_file}: not KITTI's 'YYYY-MM-DD hh:mm:ss.fffffffff' times ({err})"
        raise RecordingError(msg) from None
    return np.asarray(ns - ns[0], dtype=np.int64)


def _read_oxts(path: Path) -> PoseTable:
    """KITTI raw's OXTS folder: file k (lat, lon, alt, roll, pitch, yaw, ...) for image k."""
    data = path / "data" if (path / "data").is_dir() else path
    files = sorted(data.glob("*.txt"))
    files = [f for f in files if f.name != "timestamps.txt"]
    if not files:
        msg = (
            f"--poses {path} is a folder without OXTS files (data/*.txt); give KITTI raw's "
            "oxts/ folder, a pose CSV or KITTI's poses.txt"
        )
        raise RecordingError(msg)
    rows = []
    for f in files:
        parts = f.read_text(encoding="utf-8").split()
        try:
            values = [float(v) for v in parts[:6]]
        except ValueError as err:
            msg = f"{f}: not an OXTS record ({err}); it starts lat lon alt roll pitch yaw"
            raise RecordingError(msg) from None
        if len(values) < 6:
            msg = f"{f}: {len(values)} numbers; an OXTS record starts lat lon alt roll pitch yaw"
            raise RecordingError(msg)
        rows.append(values)
    table = np.asarray(rows, dtype=np.float64)
    if not np.isfinite(table).all():
        bad = files[int(np.flatnonzero(~np.isfinite(table).all(axis=1))[0])]
        msg = f"{bad}: NaN/inf in an OXTS record; remove that frame"
        raise RecordingError(msg)
    quat = frames.quat_from_euler(table[:, 3], table[:, 4], table[:, 5])  # R = Rz Ry Rx
    stamps = _oxts_stamps(data.parent if data.name == "data" else data, len(files))
    return PoseTable(
        stamps, table[:, :3], quat, None, by_index=True, geographic=True, kind="kitti oxts"
    )


def _in_time_order(
    path: Path,
    stamps: npt.NDArray[np.int64],
    xyz: npt.NDArray[np.float64],
    quat: npt.NDArray[np.float64] | None,
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64], npt.NDArray[np.float64] | None]:
    """A table's rows sorted by time, a repeated row (a logger repeating its last fix) once.

    Raises:
        RecordingError: Two different poses share a time.
    """
    order = np.argsort(stamps, kind="stable")
    stamps, xyz = stamps[order], xyz[order]
    quat = quat[order] if quat is not None else None
    same = np.diff(stamps) == 0
    values = xyz if quat is None else np.concatenate([xyz, quat], axis=1)
    repeat = same & (np.diff(values, axis=0) == 0).all(axis=1)
    if (same & ~repeat).any():
        k = int(np.flatnonzero(same & ~repeat)[0])
        msg = (
            f"{path}: two different poses share the timestamp {stamps[k] / 1e9:.9f}; a time "
            "column of whole seconds at a faster rate? Give the times with their fraction"
        )
        raise RecordingError(msg)
    keep = np.concatenate([[True], ~repeat])
    return stamps[keep], xyz[keep], quat[keep] if quat is not None else None


def _csv_orientation(
    rows: list[dict[str, str]], *, geographic: bool
) -> npt.NDArray[np.float64] | None:
    """A CSV's orientation column(s) as quaternions (None: it has none).

    Raises:
        ValueError: A cell is not a number.
    """
    if all(c in rows[0] for c in ("qx", "qy", "qz", "qw")):
        return np.array([[float(r[c]) for c in ("qx", "qy", "qz", "qw")] for r in rows])
    if "yaw" in rows[0]:
        return frames.quat_from_yaw(np.array([float(r["yaw"]) for r in rows]))
    if "heading" in rows[0]:
        heading = np.array([float(r["heading"]) for r in rows])
        # With lat/lon a heading is a GNSS/INS one: degrees clockwise from north.
        return frames.quat_from_yaw(np.radians(90.0 - heading) if geographic else heading)
    return None


def _read_csv(path: Path, lines: list[str]) -> PoseTable:
    if lines and lines[0].startswith("#"):
        lines[0] = lines[0].lstrip("#")
    reader = csv.DictReader(lines)
    rows = [{_column_name(k): (v or "").strip() for k, v in r.items()} for r in reader]
    units = _column_units(reader.fieldnames)
    if not rows:
        msg = f"{path}: no pose rows; expected a header line and one row per pose"
        raise RecordingError(msg)
    tcol = first_column(rows, *_TIME)
    lat, lon = first_column(rows, *_LAT), first_column(rows, *_LON)
    geographic = lat is not None and lon is not None and "x" not in rows[0]
    missing = [] if geographic else [c for c in ("x", "y") if c not in rows[0]]
    if tcol is None or missing:
        msg = (
            f"{path}: needs columns timestamp (or t/stamp_ns) and x, y[, z] (metres) or lat, "
            f"lon[, alt] (GPS), optionally qx,qy,qz,qw or yaw; found {', '.join(rows[0])}"
        )
        raise RecordingError(msg)
    try:
        stamps = table_stamps(rows, tcol, units.get(tcol))
        if geographic:
            assert lat is not None
            assert lon is not None
            alt = first_column(rows, *_ALT)
            xyz = np.array(
                [[float(r[lat]), float(r[lon]), float(r[alt] or 0.0) if alt else 0.0] for r in rows]
            )
        else:
            xyz = np.array([[float(r["x"]), float(r["y"]), float(r.get("z") or 0.0)] for r in rows])
        quat = _csv_orientation(rows, geographic=geographic)
    except ValueError as err:
        msg = f"{path}: a value is not a number ({err}); fix that row"
        raise RecordingError(msg) from None
    if not (np.isfinite(xyz).all() and (quat is None or np.isfinite(quat).all())):
        msg = f"{path}: NaN/inf in the poses; remove those rows"
        raise RecordingError(msg)
    if geographic and not ((np.abs(xyz[:, 0]) < 90).all() and (np.abs(xyz[:, 1]) <= 180).all()):
        msg = f"{path}: latitudes must lie within +-90 and longitudes within +-180 degrees"
        raise RecordingError(msg)
    icol = first_column(rows, "image", "file", "imagefile")
    images = [r[icol].replace("\\", "/").rsplit("/", 1)[-1] for r in rows] if icol else None
    if images is None:
        stamps, xyz, quat = _in_time_order(path, stamps, xyz, quat)
    quat = frames.quat_normalize(quat) if quat is not None else None
    return PoseTable(
        stamps, xyz, quat, images, geographic=geographic, kind="gps csv" if geographic else "csv"
    )


def read_pose_file(path: Path) -> PoseTable:
    """Read a pose CSV (metric or GPS), KITTI's poses.txt or OXTS folder, TUM, GPX or NMEA.

    Raises:
        RecordingError: The file does not exist or is not one of these layouts (the message
            names the file, the row or the columns found).
    """
    if path.is_dir():
        comma = global_pose_folder(path)
        return _read_oxts(path) if comma is None else _from_comma(comma)
    if path.suffix.lower() == ".gpx":
        return _from_track(read_gpx(path), "gpx")
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            lines = [ln for ln in handle if ln.strip()]
    except FileNotFoundError:
        msg = f"--poses {path} does not exist"
        raise RecordingError(msg) from None
    data = [ln for ln in lines if not ln.lstrip().startswith("#")]
    if data and _numbers(data[0], 12):
        return _read_kitti_poses(path, data)
    if data and _numbers(data[0], 8):
        return _read_tum(path, lines)
    track = (
        read_gpx(path) if lines and lines[0].lstrip().startswith("<")
        else read_nmea(path, lines) if is_nmea(lines)
        else None
    )  # fmt: skip
    if track is not None:
        return _from_track(track, "gpx" if lines[0].lstrip().startswith("<") else "nmea")
    return _read_csv(path, lines)


def _from_comma(folder: Path) -> PoseTable:
    """A comma2k19 segment's global pose: a geographic table with orientation, by time."""
    poses = read_global_pose(folder)
    notes = [f"comma2k19 global pose: {len(poses.stamp_ns)} frames (GNSS, IMU and vision fused)"]
    if poses.quat is None:
        notes.append("no frame_orientations: the heading comes from the motion")
    return PoseTable(
        poses.stamp_ns, poses.lat_lon_alt, poses.quat, None, geographic=True, kind="comma2k19",
        notes=tuple(notes),
    )  # fmt: skip


EXIF_POSES: Final = "exif"
"""``--poses exif``: every photo's own EXIF GPS fix (:mod:`cam2sim.recording.exif_gps`)."""


def read_exif_poses(files: list[Path]) -> PoseTable:
    """The photos' EXIF fixes as a geographic pose table, row k the fix of photo k.

    Raises:
        RecordingError: A photo has no fix or time, or two photos share a time.
    """
    track = read_exif_track(files)
    stamps = track.stamp_ns
    shared = np.unique(stamps, return_counts=True)
    if (shared[1] > 1).any():
        first = int(shared[0][np.argmax(shared[1] > 1)])
        when = datetime.fromtimestamp(first / 1e9, tz=UTC).isoformat()
        msg = (
            f"{int((stamps == first).sum())} photos share an EXIF time (first {when}): their "
            "times are whole seconds; give the poses in a file (--poses), or name the photos by "
            "their times"
        )
        raise RecordingError(msg)
    return _from_track(track, "exif")


def _from_track(track: GpsTrack, kind: str) -> PoseTable:
    """A GPS track's fixes as a geographic pose table (no orientation)."""
    notes = [f"{kind.upper()}: {len(track.stamp_ns)} fixes"]
    if track.skipped:
        notes.append("skipped " + ", ".join(f"{v} ({k})" for k, v in track.skipped.items()))
    if not track.dated:
        notes.append("no RMC sentence gives the date: the times count from 1970-01-01")
    return PoseTable(
        track.stamp_ns, track.lat_lon_alt, None, None, geographic=True, kind=kind,
        notes=tuple(notes),
    )  # fmt: skip
