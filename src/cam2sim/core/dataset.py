"""The dataset format every later stage reads (``WS/dataset/``).

``dataset.json`` and ``calibration.json`` are schema-versioned artifacts; the tables
(``poses.csv``, ``trajectory.csv``, ``lidar.csv``, ``signals/<name>.csv``) are CSV with the
columns listed here. All positions are in the workspace world frame (metres, x east, y north,
z up), orientations are (x, y, z, w) quaternions of the vehicle body frame (x forward, y left,
z up) at the recording's pose reference point, heading is radians CCW from +x.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Final, Literal

import numpy as np
import pydantic

from cam2sim.core.camera import PinholeCamera
from cam2sim.core.schema import Artifact
from cam2sim.core.workspace import WorldFrameRecord

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = [
    "LIDAR_COLUMNS",
    "NO_INTRINSICS_HINT",
    "POSE_COLUMNS",
    "POSE_PRECISION",
    "SIGNAL_COLUMNS",
    "TRAJECTORY_COLUMNS",
    "Calibration",
    "CameraIntrinsics",
    "DatasetCounts",
    "DatasetInfo",
    "MountRecord",
    "SourceRecord",
]

NO_INTRINSICS_HINT: Final = (
    "import the images again with --calibration K.txt (or --fov DEG, the camera's horizontal "
    "field of view), or, for a bag, set camera.intrinsics in config.yaml"
)
"""What to do when a dataset has no camera intrinsics: an import names none, a bag's have
``topics.camera_info`` or ``camera.intrinsics``."""

POSE_COLUMNS = ("frame", "stamp_ns", "t", "x", "y", "z", "qx", "qy", "qz", "qw", "heading", "speed")
TRAJECTORY_COLUMNS = POSE_COLUMNS[1:]
LIDAR_COLUMNS = ("scan", "stamp_ns", "t", "x", "y", "z", "qx", "qy", "qz", "qw", "points")
SIGNAL_COLUMNS = ("stamp_ns", "t", "value")
POSE_PRECISION = {
    "t": 6,
    "x": 6,
    "y": 6,
    "z": 6,
    "qx": 9,
    "qy": 9,
    "qz": 9,
    "qw": 9,
    "heading": 9,
    "speed": 4,
    "value": 9,
}


class _Record(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)


class CameraIntrinsics(_Record):
    """Pinhole intrinsics of the recorded images (pixels) and lens distortion."""

    width: int
    height: int
    K: tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]
    distortion: tuple[float, ...] = ()
    distortion_model: Literal["plumb_bob", "equidistant"] = "plumb_bob"
    source: str = pydantic.Field(description="config, camera_info topic, or file")
    grey: bool = pydantic.Field(
        default=False,
        description="the recorded frames are grey (one channel, or three equal ones)",
    )

    @classmethod
    def from_camera(cls, camera: PinholeCamera, source: str) -> CameraIntrinsics:
        """The record of ``camera`` (where it came from: ``source``)."""
        K = camera.K()
        return cls(
            width=camera.width,
            height=camera.height,
            K=(
                (float(K[0, 0]), float(K[0, 1]), float(K[0, 2])),
                (float(K[1, 0]), float(K[1, 1]), float(K[1, 2])),
                (float(K[2, 0]), float(K[2, 1]), float(K[2, 2])),
            ),
            distortion=camera.distortion,
            distortion_model=camera.distortion_model,
            source=source,
        )

    def camera(self) -> PinholeCamera:
        """These intrinsics as the one camera type.

        Raises:
            ConfigError: ``K`` is not a pinhole matrix, or the size or a focal length is not
                positive.
        """
        return PinholeCamera.from_K(
            self.K,
            self.width,
            self.height,
            self.distortion,
            distortion_model=self.distortion_model,
        )


class MountRecord(_Record):
    """A sensor's pose in the vehicle body frame: ``T_body_sensor``.

    The sensor frame is a camera optical frame (x right, y down, z forward) for cameras and a
    link frame (x forward, y left, z up) for LiDARs.
    """

    translation_m: tuple[float, float, float]
    quat_xyzw: tuple[float, float, float, float]
    axes: Literal["optical", "link"]
    source: str = pydantic.Field(description="config or tf_static")


class Calibration(Artifact):
    """``calibration.json``: camera intrinsics and sensor mounts."""

    camera: CameraIntrinsics | None = None
    camera_mount: MountRecord
    lidar_mount: MountRecord | None = None


class RigCamera(Artifact):
    """``dataset/cameras/<name>/camera.json``: a rig camera beside the front one.

    Its frames (``frames/NNNNNN``) are taken at the front camera's frames of the same number;
    its pose is the front camera's times ``T_front_cam`` (optical axes both).
    """

    name: str
    intrinsics: CameraIntrinsics
    T_front_cam: tuple[tuple[float, float, float, float], ...] = pydantic.Field(
        description="4x4: this camera (optical axes) -> the front camera (optical axes)"
    )
    source: str = pydantic.Field(description="the rig file it came from")

    def T(self) -> npt.NDArray[np.float64]:
        """``T_front_cam`` as a ``(4, 4)`` array."""
        return np.asarray(self.T_front_cam, dtype=np.float64)


class SourceRecord(_Record):
    """One input file and its fingerprint."""

    path: str
    fingerprint: str


class DatasetCounts(_Record):
    """How many samples the dataset holds."""

    frames: int
    pose_samples: int
    lidar_scans: int = 0
    signals: dict[str, int] = pydantic.Field(default_factory=dict)


class DatasetInfo(Artifact):
    """``dataset.json``: what the dataset holds, where it came from, and what was dropped."""

    kind: Literal["bag", "images"]
    pose_less: bool = False
    sources: tuple[SourceRecord, ...]
    time_base: Literal["header", "receive", "file"]
    topics: dict[str, str] = pydantic.Field(
        default_factory=dict, description="role (camera, pose, lidar, signal:<name>) -> topic"
    )
    counts: DatasetCounts
    start_ns: int
    end_ns: int
    duration_s: float
    dropped: dict[str, dict[str, int]] = pydantic.Field(
        default_factory=dict, description="sensor -> reason -> count"
    )
    frame_format: Literal["png", "jpeg"]
    world: WorldFrameRecord
    rig: tuple[str, ...] = pydantic.Field(
        default=(), description="the rig's other cameras (dataset/cameras/<name>/)"
    )
    heading_from_motion: bool = pydantic.Field(
        default=False,
        description="the poses gave no orientation (GPS fixes): the heading is the direction "
        "of travel, the pitch the path's grade, roll zero; the splat's preparation then refines "
        "the poses",
    )
