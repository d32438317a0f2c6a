"""A camera's intrinsics (and its pose on the car) from whatever calibration a user has.

:func:`intrinsics_from_file` takes our ``calibration.json``, a Cam2Sim ``camera.json``, a bare
3x3 K (KITTI's ``K.txt`` or the ``P0:`` line of its ``calib.txt``), KITTI raw's calibration
folder (:mod:`cam2sim.recording.kitti_calibration`) and the files calibration tools write
(:mod:`cam2sim.recording.calibration_file`), fitted to the images' size;
:func:`intrinsics_from_fov` makes a pinhole camera of a data sheet's field of view. Both
return the dataset's :class:`~cam2sim.core.dataset.CameraIntrinsics`.
"""

from __future__ import annotations

import json
import logging
import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from cam2sim.core import frames
from cam2sim.core.camera import PinholeCamera
from cam2sim.core.dataset import Calibration, CameraIntrinsics, MountRecord
from cam2sim.core.errors import ConfigError, RecordingError
from cam2sim.recording.calibration_file import CameraFile, camera_from_mapping, read_camera_text
from cam2sim.recording.kitti_calibration import (
    KITTI_RAW_FILES,
    is_kitti_raw_calibration,
    read_kitti_raw_calibration,
)

__all__ = ["IDENTITY_OPTICAL", "intrinsics_from_file", "intrinsics_from_fov"]

logger = logging.getLogger(__name__)

IDENTITY_OPTICAL = (-0.5, 0.5, -0.5, 0.5)
"""The optical camera (x right, y down, z forward) looking along the body's +x: a mount's
orientation when nothing else is known."""


def _text_K(path: Path, text: str, size: tuple[int, int] | None) -> CameraIntrinsics | None:
    """Intrinsics from a plain-text K (3x3, 9 numbers) or a KITTI ``P0:`` line; else None."""
    first = next((ln for ln in text.splitlines() if ln.strip()), "")
    tokens = first.split(":", 1)[1].split() if first.startswith("P0:") else text.split()
    try:
        values = [float(v) for v in tokens]
    except ValueError:
        return None
    if len(values) == 12:  # a KITTI projection matrix P0 = K [I | 0]
        values = [values[i] for i in (0, 1, 2, 4, 5, 6, 8, 9, 10)]
    if len(values) != 9:
        return None
    if size is None:
        msg = f"--calibration {path} is a bare K matrix; the image size must come from the images"
        raise RecordingError(msg)
    camera = PinholeCamera.from_K(np.asarray(values).reshape(3, 3), size[0], size[1], [])
    return CameraIntrinsics.from_camera(camera, f"file {path} (K; size from the images)")


def _kitti_raw(folder: Path, images: Path | None) -> tuple[CameraIntrinsics, MountRecord]:
    """KITTI raw's calibration folder: the camera of ``images`` (``image_0N``; else 00)."""
    found = re.findall(r"image_0([0-3])", str(images)) if images is not None else []
    cam = read_kitti_raw_calibration(folder, f"0{found[-1]}" if found else "00")
    camera = PinholeCamera.from_K(cam.K, cam.width, cam.height, [])
    source = f"file {folder} (KITTI raw, rectified camera {cam.camera})"
    intr = CameraIntrinsics.from_camera(camera, source)
    rot = cam.T_imu_cam[:3, :3]
    u, _, vt = np.linalg.svd(rot)  # R_rect is orthonormal to 1e-6 only
    mount = MountRecord(
        translation_m=tuple(float(v) for v in cam.T_imu_cam[:3, 3]),
        quat_xyzw=tuple(float(v) for v in frames.quat_from_matrix(u @ vt)),
        axes="optical",
        source=source,
    )
    return intr, mount


def intrinsics_from_fov(fov_deg: float, size: tuple[int, int]) -> CameraIntrinsics:
    """A pinhole camera of ``size`` (width, height) with a horizontal field of view ``fov_deg``.

    For a camera known only by its data sheet (a dash camera's "120 degrees"): square pixels,
    the principal point at the image centre, no distortion (a fisheye's wide angle is not a
    pinhole's: calibrate such a lens, ``docs/commands/import.md``).

    Raises:
        RecordingError: The angle is not within (10, 170) degrees, or the size is unknown.
    """
    if not 10.0 < fov_deg < 170.0:
        msg = f"--fov {fov_deg:g}: give the horizontal field of view in degrees, 10 to 170"
        raise RecordingError(msg)
    width, height = size
    if width <= 0 or height <= 0:
        msg = "--fov needs the images' size, and the first image cannot be read"
        raise RecordingError(msg)
    f = 0.5 * width / math.tan(math.radians(fov_deg) / 2.0)
    camera = PinholeCamera(f, f, (width - 1) / 2.0, (height - 1) / 2.0, width, height, ())
    return CameraIntrinsics.from_camera(camera, f"--fov {fov_deg:g} (pinhole, no distortion)")


def intrinsics_from_file(
    path: Path, size: tuple[int, int] | None = None, images: Path | None = None
) -> tuple[CameraIntrinsics, MountRecord | None]:
    """Read camera intrinsics (and a mount, when the file has one).

    Accepts our ``calibration.json``, a Cam2Sim ``camera.json``, a plain-text K (3x3: KITTI's
    ``K.txt``, or the ``P0:`` line of its ``calib.txt``), KITTI raw's calibration folder (K,
    size and the camera's mount on the GPS/IMU unit, the camera named by ``images``'
    ``image_0N`` folder), and the files calibration tools write
    (:mod:`cam2sim.recording.calibration_file`: ROS ``camera_info`` YAML, OpenCV YAML/XML,
    Kalibr, COLMAP ``cameras.txt``, nerfstudio ``transforms.json``, JSON or YAML of ``K`` or
    ``fx, fy, cx, cy``). A file without a size takes the images' ``size``; one for a larger
    or smaller image of the same shape is scaled to it (the images were resized), one of
    another shape is refused when the dataset is written.
    """
    path = Path(path)
    if is_kitti_raw_calibration(path):
        return _kitti_raw(path, images)
    if path.is_dir():
        msg = (
            f"--calibration {path} is a folder without KITTI raw's "
            f"{', '.join(KITTI_RAW_FILES)}; give a calibration file or that folder"
        )
        raise RecordingError(msg)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        msg = f"--calibration {path}: cannot read it as text ({err})"
        raise RecordingError(msg) from None
    try:
        raw: Any = json.loads(text)
    except json.JSONDecodeError as err:
        intr = _text_K(path, text, size)
        if intr is not None:
            return intr, None
        found = read_camera_text(path, text)
        if found is None:
            msg = (
                f"--calibration {path}: neither JSON ({err}) nor a plain 3x3 K matrix nor a "
                "calibration YAML, OpenCV XML or COLMAP cameras.txt; pass a calibration.json, "
                "a camera.json, a K.txt or a tool's calibration file (docs/commands/import.md)"
            )
            raise RecordingError(msg) from None
        return _from_camera_file(path, found, size), None
    if isinstance(raw, dict) and "camera_mount" in raw:
        calib = Calibration.model_validate(raw)
        if calib.camera is None:
            msg = f"{path}: calibration.json has no camera intrinsics"
            raise RecordingError(msg)
        return calib.camera, calib.camera_mount
    if isinstance(raw, dict) and isinstance(raw.get("camera"), dict):
        return _cam2sim_camera(path, raw["camera"])
    found = camera_from_mapping(path, raw, "JSON") if isinstance(raw, dict) else None
    if found is None:
        msg = (
            f"{path}: expected K (3x3), width, height[, distortion] (or fx, fy, cx, cy, or a "
            "tool's calibration: docs/commands/import.md)"
        )
        raise RecordingError(msg)
    return _from_camera_file(path, found, size), None


def _cam2sim_camera(path: Path, cam: dict[str, Any]) -> tuple[CameraIntrinsics, MountRecord | None]:
    """A Cam2Sim ``camera.json``'s camera: intrinsics and its pose on the car."""
    cal = cam.get("calibration", {})
    original = cam.get("original_size", {})
    mount = None
    if isinstance(cam.get("position"), dict):
        pos = cam["position"]
        # Cam2Sim's camera.json uses CARLA's vehicle frame: x forward, y right, z up.
        pitch = math.radians(float(cam.get("pitch", 0.0)))
        q = frames.quat_multiply(
            frames.quat_from_euler(0.0, -pitch, 0.0), np.asarray(IDENTITY_OPTICAL)
        )
        mount = MountRecord(
            translation_m=(float(pos["x"]), -float(pos["y"]), float(pos["z"])),
            quat_xyzw=tuple(float(v) for v in q),
            axes="optical",
            source=f"file {path}",
        )
    try:
        K = np.asarray(cal.get("K"), dtype=float).reshape(3, 3)
        camera = PinholeCamera.from_K(
            K,
            int(original.get("x")),
            int(original.get("y")),
            [float(v) for v in cal.get("distortion", [])],
        )
    except (KeyError, TypeError, ValueError) as err:
        msg = f"{path}: expected camera.calibration.K (3x3) and camera.original_size; {err!r}"
        raise RecordingError(msg) from None
    return CameraIntrinsics.from_camera(camera, f"file {path}"), mount


def _from_camera_file(
    path: Path, found: CameraFile, size: tuple[int, int] | None
) -> CameraIntrinsics:
    """The intrinsics of a tool's calibration file, fitted to the images' ``size``."""
    source = f"file {path} ({found.form})"
    width, height = found.width, found.height
    if width is None or height is None:
        if size is None:
            msg = f"--calibration {path} gives no image size; the size must come from the images"
            raise RecordingError(msg)
        width, height = size
        source += "; size from the images"
    try:
        camera = PinholeCamera.from_K(
            found.K, width, height, found.distortion, distortion_model=found.model
        )
    except ConfigError as err:
        msg = f"--calibration {path}: {err}"
        raise RecordingError(msg) from None
    for note in found.notes:
        logger.warning("calibration: %s", note)
    if size is not None and (width, height) != tuple(size) and _same_shape((width, height), size):
        logger.warning(
            "calibration: %s is for %dx%d images; scaled to the images' %dx%d (resized, "
            "not cropped: give the calibration of these images if they were cropped)",
            path, width, height, size[0], size[1],
        )  # fmt: skip
        camera = camera.scaled(size[0], size[1])
        source += f"; scaled from {width}x{height}"
    return CameraIntrinsics.from_camera(camera, source)


def _same_shape(a: tuple[int, int], b: tuple[int, int]) -> bool:
    """Whether two image sizes have one aspect ratio (to half a pixel of the smaller)."""
    small, large = sorted((a, b), key=lambda s: s[0])
    scale = large[0] / small[0]
    return abs(large[1] / scale - small[1]) <= 0.5
