"""comma2k19 segments: the fused global pose of every video frame, and the processed logs.

A comma2k19 segment (one minute of driving, ``Chunk_N/<route>/<segment>/``) holds the front
camera as ``video.hevc`` (1164x874, 20 Hz), ``global_pose/`` and ``processed_log/``, every
array a numpy ``.npy`` file without its extension:

- ``global_pose/frame_times``: ``(N,)`` seconds on the device's boot clock, one per video frame;
  ``frame_positions``: ``(N, 3)`` ECEF metres (GNSS, IMU and vision fused: smooth);
  ``frame_orientations``: ``(N, 4)`` quaternions ``(w, x, y, z)`` of the rotation from the
  device frame (x forward, y right, z down) into ECEF;
- ``processed_log/<group>/<signal>/t`` and ``.../value``: a signal on the same clock (CAN
  ``steering_angle`` in degrees, ``speed`` in m/s).

:func:`read_global_pose` reads the poses as a geographic pose table (latitude, longitude,
height; the body x forward, y left, z up in east-north-up), :func:`read_log_signal` a signal.
The frame conventions are those of the dataset's own ``utils/camera.py`` and
``utils/orientation.py``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from cam2sim.core import frames
from cam2sim.core.errors import RecordingError

if TYPE_CHECKING:
    from pathlib import Path

    import numpy.typing as npt

__all__ = [
    "GLOBAL_POSE_FILES",
    "CommaPoses",
    "global_pose_folder",
    "is_log_signal",
    "read_global_pose",
    "read_log_signal",
]

GLOBAL_POSE_FILES = ("frame_times", "frame_positions")
"""The files a ``global_pose`` folder must hold (``frame_orientations`` is read when there)."""

_BODY_FROM_DEVICE = np.diag([1.0, -1.0, -1.0])
"""comma's device frame (x forward, y right, z down) to the body's (x forward, y left, z up)."""


def global_pose_folder(path: Path) -> Path | None:
    """The ``global_pose`` folder ``path`` is, or holds (a segment folder); else None."""
    for folder in (path, path / "global_pose"):
        if folder.is_dir() and all((folder / name).is_file() for name in GLOBAL_POSE_FILES):
            return folder
    return None


@dataclass(frozen=True, eq=False)
class CommaPoses:
    """The global pose of a segment's video frames.

    Attributes:
        stamp_ns: ``(N,)`` int64 times on the device's boot clock.
        lat_lon_alt: ``(N, 3)`` WGS84 latitude, longitude (degrees) and height (metres).
        quat: ``(N, 4)`` orientation ``(x, y, z, w)`` of the body (x forward, y left, z up) in
            east-north-up, or None without ``frame_orientations``.
    """

    stamp_ns: npt.NDArray[np.int64]
    lat_lon_alt: npt.NDArray[np.float64]
    quat: npt.NDArray[np.float64] | None


def read_global_pose(folder: Path) -> CommaPoses:
    """The poses of a ``global_pose`` folder (see :func:`global_pose_folder`).

    Raises:
        RecordingError: A file is not a numpy array of the expected shape, or the arrays
            disagree in length; the message names the file.
    """
    times = _array(folder / "frame_times", (-1,))
    positions = _array(folder / "frame_positions", (len(times), 3))
    try:
        geo = frames.wgs84_from_ecef(positions)
    except ValueError as err:
        msg = f"{folder / 'frame_positions'}: {err}"
        raise RecordingError(msg) from None
    lat_lon_alt = np.column_stack([geo.lat_deg, geo.lon_deg, geo.alt_m])
    quat = None
    if (folder / "frame_orientations").is_file():
        wxyz = _array(folder / "frame_orientations", (len(times), 4))
        ecef_from_device = frames.quat_to_matrix(np.roll(wxyz, -1, axis=1))
        enu_from_ecef = frames.enu_from_ecef_rotation(geo.lat_deg, geo.lon_deg)
        quat = frames.quat_from_matrix(enu_from_ecef @ ecef_from_device @ _BODY_FROM_DEVICE)
    stamps = np.round(times * 1e9).astype(np.int64)
    return CommaPoses(stamps, lat_lon_alt, quat)


def is_log_signal(path: Path) -> bool:
    """Whether ``path`` is a processed-log signal folder (``t`` and ``value``)."""
    return path.is_dir() and (path / "t").is_file() and (path / "value").is_file()


def read_log_signal(path: Path) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]:
    """A processed-log signal: nanosecond times and values, in time order.

    Raises:
        RecordingError: ``t`` and ``value`` are not numpy arrays of one length (``value`` of
            one number a sample).
    """
    t = _array(path / "t", (-1,))
    value = _array(path / "value", (len(t), -1))
    if value.shape[1] != 1:
        msg = f"{path / 'value'}: {value.shape[1]} numbers a sample; a signal has one"
        raise RecordingError(msg)
    order = np.argsort(t, kind="stable")
    return np.round(t[order] * 1e9).astype(np.int64), value[order, 0]


def _array(path: Path, shape: tuple[int, ...]) -> npt.NDArray[np.float64]:
    """A numpy file (comma's have no ``.npy`` suffix) as float64 of ``shape`` (-1: any)."""
    try:
        raw: Any = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as err:
        msg = f"{path}: not a numpy array file ({err}); give the segment's files as comma ships"
        raise RecordingError(msg) from None
    array = np.asarray(raw, dtype=np.float64)
    try:
        array = array.reshape(shape)
    except ValueError:
        want = "x".join("N" if s == -1 else str(s) for s in shape)
        msg = f"{path}: an array of shape {array.shape}, expected {want}"
        raise RecordingError(msg) from None
    if not np.all(np.isfinite(array)):
        msg = f"{path}: NaN or inf values; remove those samples"
        raise RecordingError(msg)
    return array
