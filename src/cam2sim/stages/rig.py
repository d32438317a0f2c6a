"""A camera rig imported beside the front camera: a stereo pair's other eye, surround cameras.

The splat trains on the front camera. The rig's other cameras saw the street from places the
front camera never was (a stereo pair's other eye is about half a metre to the side): their
frames are real-pixel ground truth off the recorded path, where the splat is scored
(:func:`cam2sim.splat.evaluate.evaluate_splat`'s ``rig``) beside the synthetic envelope.

A rig file (``cam2sim import WS --images DIR --rig rig.yaml``), paths relative to it::

    cameras:
      right:                       # a name: letters, digits, _
        images: image_1/           # one image per front image, in the same order
        calibration: K1.txt        # optional: the front camera's intrinsics by default
        offset_m: [0.0, -0.54, 0]  # from the front camera, vehicle axes (x forward, y left, z up)
        rpy_deg: [0, 0, 0]         # its turn from the front camera (roll, pitch, yaw)

Writes ``dataset/cameras/<name>/camera.json`` (:class:`~cam2sim.core.dataset.RigCamera`) and
``dataset/cameras/<name>/frames/NNNNNN`` numbered as the front frames they go with.
"""

from __future__ import annotations

import math
import re
import shutil
from dataclasses import dataclass
from pathlib import Path  # noqa: TC003 - dataclass field types
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from cam2sim.core.dataset import CameraIntrinsics, RigCamera
from cam2sim.core.errors import RecordingError
from cam2sim.core.frames.rotation import quat_from_euler, quat_to_matrix

if TYPE_CHECKING:
    from collections.abc import Callable

    import numpy.typing as npt

    from cam2sim.core.dataset import MountRecord
    from cam2sim.core.workspace import DatasetPaths

    #: Reads a calibration file for images of a size: (intrinsics, mount or None).
    IntrinsicsReader = Callable[
        [Path, tuple[int, int] | None, Path | None], tuple[CameraIntrinsics, MountRecord | None]
    ]

__all__ = ["RigSpec", "read_rig", "rig_offset", "write_rig"]

# Vehicle axes (x forward, y left, z up) of the optical axes (x right, y down, z forward).
_OPTICAL_IN_VEHICLE = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True)
class RigSpec:
    """One camera of a rig file (see the module doc)."""

    name: str
    images: Path
    calibration: Path | None
    offset_m: tuple[float, float, float]
    rpy_deg: tuple[float, float, float]

    def T_front_cam(self) -> npt.NDArray[np.float64]:
        """``(4, 4)``: this camera's optical axes -> the front camera's optical axes."""
        roll, pitch, yaw = (math.radians(a) for a in self.rpy_deg)
        turn = quat_to_matrix(quat_from_euler(roll, pitch, yaw))  # in vehicle axes
        B = _OPTICAL_IN_VEHICLE
        T = np.eye(4)
        T[:3, :3] = B.T @ turn @ B
        T[:3, 3] = B.T @ np.asarray(self.offset_m, dtype=np.float64)
        return T


def read_rig(path: Path) -> list[RigSpec]:
    """The cameras of a rig file.

    Raises:
        RecordingError: The file is missing or malformed (the message names the key).
    """
    import yaml  # noqa: PLC0415

    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        msg = f"--rig {path} does not exist"
        raise RecordingError(msg) from None
    except yaml.YAMLError as err:
        msg = f"{path} is not YAML ({err})"
        raise RecordingError(msg) from None
    cameras = data.get("cameras") if isinstance(data, dict) else None
    if not isinstance(cameras, dict) or not cameras:
        msg = f"{path}: needs a 'cameras:' mapping of name -> images, offset_m (module doc)"
        raise RecordingError(msg)
    return [_camera(path, str(name), entry) for name, entry in cameras.items()]


def _camera(path: Path, name: str, entry: Any) -> RigSpec:
    where = f"{path}: cameras.{name}"
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
        msg = f"{where}: a camera name is letters, digits and _"
        raise RecordingError(msg)
    if not isinstance(entry, dict) or "images" not in entry:
        msg = f"{where}: needs 'images: FOLDER' (and offset_m: [x, y, z])"
        raise RecordingError(msg)
    unknown = sorted(set(entry) - {"images", "calibration", "offset_m", "rpy_deg"})
    if unknown:
        msg = f"{where}: unknown keys {unknown}; use images, calibration, offset_m, rpy_deg"
        raise RecordingError(msg)

    def triple(key: str) -> tuple[float, float, float]:
        value = entry.get(key, [0.0, 0.0, 0.0])
        try:
            x, y, z = (float(v) for v in value)
        except (TypeError, ValueError):
            msg = f"{where}.{key}: give three numbers, e.g. [0, -0.54, 0]; got {value!r}"
            raise RecordingError(msg) from None
        return (x, y, z)

    calibration = entry.get("calibration")
    return RigSpec(
        name=name,
        images=path.parent / str(entry["images"]),
        calibration=None if calibration is None else path.parent / str(calibration),
        offset_m=triple("offset_m"),
        rpy_deg=triple("rpy_deg"),
    )


def rig_offset(camera: RigCamera) -> tuple[float, float]:
    """``(lateral_m, yaw_deg)`` of a rig camera from the front one (positive: right, left)."""
    T = camera.T()
    forward = T[:3, 2]  # its optical z in the front camera's optical axes
    yaw = math.degrees(math.atan2(-forward[0], forward[2]))
    return float(T[0, 3]), yaw


def write_rig(
    paths: DatasetPaths,
    specs: list[RigSpec],
    keep: npt.NDArray[np.bool_],
    front: CameraIntrinsics | None,
    *,
    source: Path,
    fmt: Literal["png", "jpeg"],
    list_images: Callable[[Path], list[Path]],
    intrinsics_from_file: IntrinsicsReader,
) -> tuple[str, ...]:
    """Write each rig camera's kept frames and record into the dataset ``paths``.

    ``keep`` says which of the front images were kept (numbered 0, 1, ... in order); each rig
    camera must have as many images as the front camera had before that. ``list_images`` and
    ``intrinsics_from_file`` are the import's own readers (:mod:`cam2sim.stages.image_import`,
    :func:`cam2sim.recording.intrinsics.intrinsics_from_file`).

    Raises:
        RecordingError: A folder with another image count, another image size than its
            calibration, or no intrinsics for a camera (neither its own nor the front's).
    """
    import cv2  # noqa: PLC0415

    from cam2sim.recording.image import encode_image_file  # noqa: PLC0415

    names = []
    for spec in specs:
        files = list_images(spec.images)
        if len(files) != keep.size:
            msg = (
                f"rig camera {spec.name}: {spec.images} holds {len(files)} images but the front "
                f"camera has {keep.size}; give one image per front image, in the same order"
            )
            raise RecordingError(msg)
        size = _size(files[0])
        if spec.calibration is not None:
            intr, _ = intrinsics_from_file(spec.calibration, size, spec.images)
        elif front is not None:
            intr = front
        else:
            msg = f"rig camera {spec.name}: no intrinsics; give calibration: FILE in {source}"
            raise RecordingError(msg)
        if (intr.width, intr.height) != size:
            msg = (
                f"rig camera {spec.name}: its calibration is for {intr.width}x{intr.height} but "
                f"its images are {size[0]}x{size[1]}"
            )
            raise RecordingError(msg)
        kept = [f for f, k in zip(files, keep, strict=True) if k]
        for i, f in enumerate(kept):
            target = paths.rig_frame_file(spec.name, i, fmt)
            target.parent.mkdir(parents=True, exist_ok=True)
            if f.suffix.lower().lstrip(".") in (("jpg", "jpeg") if fmt == "jpeg" else ("png",)):
                shutil.copyfile(f, target)
                continue
            image: Any = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
            if image is None:
                msg = f"{f} cannot be read as an image; remove or replace it"
                raise RecordingError(msg)
            if image.ndim == 3:
                image = cv2.cvtColor(image[..., :3], cv2.COLOR_BGR2RGB)
            target.write_bytes(encode_image_file(image, fmt))
        T = spec.T_front_cam()
        RigCamera(
            name=spec.name,
            intrinsics=intr,
            T_front_cam=tuple(tuple(float(v) for v in row) for row in T),
            source=str(source),
        ).save(paths.rig_camera_json(spec.name))
        names.append(spec.name)
    return tuple(names)


def _size(path: Path) -> tuple[int, int]:
    import cv2  # noqa: PLC0415

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        msg = f"{path} cannot be read as an image; remove or replace it"
        raise RecordingError(msg)
    return int(image.shape[1]), int(image.shape[0])
