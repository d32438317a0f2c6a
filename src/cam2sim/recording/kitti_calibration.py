"""KITTI raw's calibration folder: a rectified camera's K, image size and pose on the GPS/IMU unit.

A KITTI raw drive's date folder (``2011_09_26/``) holds three text files of ``key: numbers``
lines: ``calib_cam_to_cam.txt`` (per camera ``S_rect_0N`` size, ``P_rect_0N`` 3x4 projection
of the rectified image, ``R_rect_00`` the rectifying rotation), ``calib_velo_to_cam.txt``
(``R``, ``T``: Velodyne to camera 0) and ``calib_imu_to_velo.txt`` (``R``, ``T``: GPS/IMU to
Velodyne). A point in the IMU frame reaches rectified camera N's frame by
``[I | b_N] R_rect_00 T_cam0_velo T_velo_imu`` (``b_N`` from ``P_rect_0N``'s last column: the
stereo baseline), the chain of the KITTI devkit. The OXTS poses are the IMU's, so the camera's
pose on it is the mount :func:`read_kitti_raw_calibration` returns.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from cam2sim.core.errors import RecordingError

if TYPE_CHECKING:
    from pathlib import Path

__all__ = [
    "KITTI_RAW_FILES",
    "KittiRawCamera",
    "is_kitti_raw_calibration",
    "read_kitti_raw_calibration",
]

KITTI_RAW_FILES = ("calib_cam_to_cam.txt", "calib_velo_to_cam.txt", "calib_imu_to_velo.txt")
"""The files of a KITTI raw calibration folder."""


@dataclass(frozen=True)
class KittiRawCamera:
    """One rectified camera of a KITTI raw drive.

    Attributes:
        camera: Its number (``00`` grey left ... ``03`` colour right).
        K: ``(3, 3)`` intrinsics of the rectified images.
        width: Rectified image width, pixels.
        height: Rectified image height, pixels.
        T_imu_cam: ``(4, 4)`` the camera's optical frame (x right, y down, z forward) in the
            GPS/IMU frame (x forward, y left, z up), metres.
    """

    camera: str
    K: npt.NDArray[np.float64]
    width: int
    height: int
    T_imu_cam: npt.NDArray[np.float64]


def is_kitti_raw_calibration(path: Path) -> bool:
    """Whether ``path`` is a folder holding KITTI raw's three calibration files."""
    return path.is_dir() and all((path / name).is_file() for name in KITTI_RAW_FILES)


def _fields(path: Path) -> dict[str, npt.NDArray[np.float64]]:
    """The numeric ``key: numbers`` lines of a KITTI calibration file (others skipped)."""
    out: dict[str, npt.NDArray[np.float64]] = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        key, sep, rest = line.partition(":")
        if not sep:
            continue
        try:
            out[key.strip()] = np.array([float(v) for v in rest.split()], dtype=np.float64)
        except ValueError:
            continue  # calib_time: 09-Jan-2012 13:57:47
    return out


def _need(
    fields: dict[str, npt.NDArray[np.float64]], key: str, size: int, path: Path
) -> npt.NDArray[np.float64]:
    value = fields.get(key)
    if value is None or value.size != size:
        found = "missing" if value is None else f"{value.size} numbers"
        msg = f"{path}: {key} must be {size} numbers ({found}); is it KITTI raw's calibration?"
        raise RecordingError(msg)
    return value


def _rigid(
    rotation: npt.NDArray[np.float64], translation: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    T = np.eye(4)
    T[:3, :3] = rotation.reshape(3, 3)
    T[:3, 3] = translation
    return T


def read_kitti_raw_calibration(folder: Path, camera: str = "00") -> KittiRawCamera:
    """Read rectified camera ``camera``'s K, size and pose on the GPS/IMU unit.

    Raises:
        RecordingError: A file or a key is missing or malformed (the message names which).
    """
    cam_file, velo_file, imu_file = (folder / name for name in KITTI_RAW_FILES)
    missing = [p.name for p in (cam_file, velo_file, imu_file) if not p.is_file()]
    if missing:
        msg = f"--calibration {folder}: no {', '.join(missing)}; give KITTI raw's date folder"
        raise RecordingError(msg)
    cams = _fields(cam_file)
    P = _need(cams, f"P_rect_{camera}", 12, cam_file).reshape(3, 4)
    width, height = _need(cams, f"S_rect_{camera}", 2, cam_file)
    rect = np.eye(4)
    rect[:3, :3] = _need(cams, "R_rect_00", 9, cam_file).reshape(3, 3)
    velo = _fields(velo_file)
    cam0_velo = _rigid(_need(velo, "R", 9, velo_file), _need(velo, "T", 3, velo_file))
    imu = _fields(imu_file)
    velo_imu = _rigid(_need(imu, "R", 9, imu_file), _need(imu, "T", 3, imu_file))
    K = P[:, :3]
    baseline = np.eye(4)
    baseline[:3, 3] = np.linalg.solve(K, P[:, 3])  # P = K [I | b]
    cam_imu = baseline @ rect @ cam0_velo @ velo_imu
    return KittiRawCamera(
        camera=camera,
        K=K.copy(),
        width=round(float(width)),
        height=round(float(height)),
        T_imu_cam=np.asarray(np.linalg.inv(cam_imu), dtype=np.float64),
    )
