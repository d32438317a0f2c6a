"""Pose files that come beside an image folder: the poses of ``cam2sim import``.

Four layouts are read, each into one :class:`PoseTable`:

- a CSV in a metric frame: ``timestamp|t|stamp_ns, x, y[, z]`` (the frame's CRS is the
  import's ``--crs``, or none: a local frame);
- a CSV of GPS fixes: ``timestamp, lat, lon[, alt]`` (WGS84 degrees and metres): geo-referenced
  without ``--crs``;
- KITTI odometry's ``poses.txt``: a 3x4 camera-to-world matrix a line, line k for image k;
- KITTI raw's ``oxts/`` folder (or its ``data/``): one text file a frame, file k for image k,
  whose first six numbers are latitude, longitude, altitude, roll, pitch and yaw (the GPS/IMU
  unit's axes x forward, y left, z up; yaw 0 east, counter-clockwise; ``R = Rz Ry Rx``).

A CSV's orientation is ``qx, qy, qz, qw`` or ``yaw``/``heading`` (radians, counter-clockwise from
the frame's x axis; east for GPS); without either it is left to the caller to take from the
direction of travel (:attr:`PoseTable.quat` is None). An ``image`` column names the file each
row belongs to.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from cam2sim.core import frames
from cam2sim.core.errors import RecordingError

if TYPE_CHECKING:
    from pathlib import Path

__all__ = ["PoseTable", "first_column", "read_pose_file", "stamp_ns_from_text", "table_stamps"]

_LAT = ("lat", "latitude", "lat_deg")
_LON = ("lon", "lng", "longitude", "lon_deg")
_ALT = ("alt", "altitude", "alt_m")
_TIME = ("stamp_ns", "timestamp", "t", "time", "Timestamp_Sec")


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
        kind: What was read (``csv``, ``gps csv``, ``kitti poses``, ``kitti oxts``).
    """

    stamp_ns: npt.NDArray[np.int64]
    xyz: npt.NDArray[np.float64]
    quat: npt.NDArray[np.float64] | None
    images: list[str] | None
    by_index: bool = False
    geographic: bool = False
    kind: str = "csv"


def first_column(rows: list[dict[str, str]], *names: str) -> str | None:
    """The first of ``names`` that is a column of ``rows`` (None: none is)."""
    for name in names:
        if name in rows[0]:
            return name
    return None


def stamp_ns_from_text(text: str) -> int:
    """Nanoseconds of a time in seconds, or of an ISO 8601 date and time.

    A 16+ digit integer is taken as nanoseconds; a date and time (``2011-09-26 13:02:25.964``,
    ``...T...Z``) without a zone as UTC, every fractional digit kept.

    Raises:
        ValueError: The text is neither.
    """
    text = text.strip()
    if len(text) >= 19 and text[4] == "-" and text[10] in " T":
        return _iso_ns(text)
    sec, _, frac = text.partition(".")
    if not frac and abs(int(sec)) > 10**15:
        return int(sec)
    return int(sec) * 1_000_000_000 + int((frac + "000000000")[:9]) * (
        -1 if sec.startswith("-") else 1
    )


def _iso_ns(text: str) -> int:
    """Nanoseconds since the epoch of an ISO 8601 date and time (UTC when it names no zone)."""
    head, frac, tail = text[:19], "", text[19:]
    if tail.startswith("."):
        digits = len(tail) - len(tail[1:].lstrip("0123456789"))
        frac, tail = tail[1:digits], tail[digits:]
    moment = datetime.fromisoformat(head.replace(" ", "T") + tail)
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    seconds = int(moment.timestamp())
    return seconds * 1_000_000_000 + int((frac + "000000000")[:9])


def table_stamps(rows: list[dict[str, str]], column: str) -> npt.NDArray[np.int64]:
    """Nanosecond stamps of a table's time column (``stamp_ns`` as is, else seconds).

    Raises:
        ValueError: A cell is not a number.
    """
    parse = int if column == "stamp_ns" else stamp_ns_from_text
    return np.array([parse(r[column]) for r in rows], dtype=np.int64)


# KITTI's camera-to-world poses: camera axes x right, y down, z forward, in the first camera's
# frame. The vehicle frame is x forward, y left, z up; its columns in camera axes:
_VEHICLE_IN_OPTICAL = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
# The world: the first camera's frame turned z up (x forward, y left at the start).
_WORLD_FROM_FIRST_CAMERA = _VEHICLE_IN_OPTICAL.T


def _is_kitti(line: str) -> bool:
    """Whether a line is a KITTI pose: 12 numbers, whitespace-separated, no header."""
    parts = line.split()
    if len(parts) != 12 or "," in line:
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
        ns = np.array([_iso_ns(ln) for ln in lines], dtype=np.int64)
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


def _read_csv(path: Path, lines: list[str]) -> PoseTable:
    if lines and lines[0].startswith("#"):
        lines[0] = lines[0].lstrip("#")
    rows = [{k.strip(): (v or "").strip() for k, v in r.items()} for r in csv.DictReader(lines)]
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
        stamps = table_stamps(rows, tcol)
        if geographic:
            assert lat is not None
            assert lon is not None
            alt = first_column(rows, *_ALT)
            xyz = np.array(
                [[float(r[lat]), float(r[lon]), float(r[alt] or 0.0) if alt else 0.0] for r in rows]
            )
        else:
            xyz = np.array([[float(r["x"]), float(r["y"]), float(r.get("z") or 0.0)] for r in rows])
        quat: npt.NDArray[np.float64] | None = None
        if all(c in rows[0] for c in ("qx", "qy", "qz", "qw")):
            quat = np.array([[float(r[c]) for c in ("qx", "qy", "qz", "qw")] for r in rows])
        elif (ycol := first_column(rows, "yaw", "heading")) is not None:
            quat = frames.quat_from_yaw(np.array([float(r[ycol]) for r in rows]))
    except ValueError as err:
        msg = f"{path}: a value is not a number ({err}); fix that row"
        raise RecordingError(msg) from None
    if not (np.isfinite(xyz).all() and (quat is None or np.isfinite(quat).all())):
        msg = f"{path}: NaN/inf in the poses; remove those rows"
        raise RecordingError(msg)
    if geographic and not ((np.abs(xyz[:, 0]) < 90).all() and (np.abs(xyz[:, 1]) <= 180).all()):
        msg = f"{path}: latitudes must lie within +-90 and longitudes within +-180 degrees"
        raise RecordingError(msg)
    icol = first_column(rows, "image", "file", "ImageFile")
    images = [r[icol].replace("\\", "/").rsplit("/", 1)[-1] for r in rows] if icol else None
    if images is None:
        order = np.argsort(stamps, kind="stable")
        if (np.diff(stamps[order]) == 0).any():
            msg = f"{path}: two poses share a timestamp; remove duplicates"
            raise RecordingError(msg)
        stamps, xyz = stamps[order], xyz[order]
        quat = quat[order] if quat is not None else None
    quat = frames.quat_normalize(quat) if quat is not None else None
    return PoseTable(
        stamps, xyz, quat, images, geographic=geographic, kind="gps csv" if geographic else "csv"
    )


def read_pose_file(path: Path) -> PoseTable:
    """Read a pose CSV (metric or GPS), KITTI's poses.txt or KITTI raw's OXTS folder.

    Raises:
        RecordingError: The file does not exist or is not one of these layouts (the message
            names the file, the row or the columns found).
    """
    if path.is_dir():
        return _read_oxts(path)
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            lines = [ln for ln in handle if ln.strip()]
    except FileNotFoundError:
        msg = f"--poses {path} does not exist"
        raise RecordingError(msg) from None
    if lines and _is_kitti(lines[0]):
        return _read_kitti_poses(path, lines)
    return _read_csv(path, lines)
