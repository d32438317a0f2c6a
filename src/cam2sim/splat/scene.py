"""The contract between splat preparation and training: a prepared scene on disk.

``WS/splat/prep/`` (written by :mod:`cam2sim.splat.prepare`, read by :mod:`cam2sim.splat.train`):

- ``scene.json``: a :class:`SceneRecord` (frames with camera poses and intrinsics, chunks);
- ``images/NNNNNN.png``: undistorted RGB frames (what training sees);
- ``masks/NNNNNN.png``: uint8 masks, 255 = pixel used for training, 0 = excluded (ego hood);
- ``sky/NNNNNN.png``: uint8, 255 = sky (optional; used for the sky/background model);
- ``points.npz``: initial points ``xyz`` (N, 3) float32 world metres, ``rgb`` (N, 3) uint8,
  ``source`` (N,) uint8 (0 = triangulated, 1 = LiDAR).

Cameras are pinhole (after undistortion), OpenCV optical axes (x right, y down, z forward);
``T_world_cam`` maps camera coordinates to world coordinates. World = the workspace world frame
(metres), or an arbitrary SfM frame when ``scale_ambiguous`` is set (images-only recordings).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt
import pydantic

from cam2sim.core.camera import PinholeCamera
from cam2sim.core.files import write_bytes_atomic
from cam2sim.core.schema import Artifact

__all__ = ["ChunkRecord", "FrameRecord", "SceneRecord", "load_points", "save_points"]


class FrameRecord(pydantic.BaseModel):
    """One training/evaluation view."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    index: int = pydantic.Field(description="Index in the prepared scene (file stem NNNNNN)")
    dataset_frame: int = pydantic.Field(description="Frame number in WS/dataset/")
    stamp_ns: int
    T_world_cam: list[list[float]] = pydantic.Field(description="4x4, camera (optical) -> world")
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    held_out: bool = pydantic.Field(
        default=False, description="Evaluation view (every 8th by default)"
    )
    chunks: list[int] = pydantic.Field(default_factory=list, description="Chunks it belongs to")
    progress_m: float = pydantic.Field(0.0, description="Distance travelled at this frame")
    from_recorded: list[float] | None = pydantic.Field(
        None,
        description="Where the preparation adjusted the recorded poses (bundle adjustment): "
        "the correction from the recorded pose near this frame to the model's, (rotation "
        "vector, translation m) in the camera frame, smoothed along the route "
        "(cam2sim.splat.geometry.smoothed_corrections); the closed loop renders at recorded "
        "poses and the renderer applies it",
    )

    def T(self) -> npt.NDArray[np.float64]:
        """``T_world_cam`` as a (4, 4) array."""
        return np.asarray(self.T_world_cam, dtype=np.float64)

    def camera(self) -> PinholeCamera:
        """The (undistorted, pinhole) camera of this view."""
        return PinholeCamera(self.fx, self.fy, self.cx, self.cy, self.width, self.height)

    def K(self) -> npt.NDArray[np.float64]:
        """(3, 3) intrinsics of the undistorted image."""
        return self.camera().K()


class ChunkRecord(pydantic.BaseModel):
    """A stretch of the route trained as one model."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    id: int
    start_m: float
    end_m: float
    frames: list[int]
    center: list[float] = pydantic.Field(description="Mean camera position, world metres")


class SceneRecord(Artifact):
    """``scene.json``."""

    frames: list[FrameRecord]
    chunks: list[ChunkRecord]
    scale_ambiguous: bool = False
    pose_source: str = pydantic.Field(description="recording, refined, or sfm")
    notes: list[str] = pydantic.Field(default_factory=list)


def save_points(
    path: Path,
    xyz: npt.NDArray[np.float32],
    rgb: npt.NDArray[np.uint8],
    source: npt.NDArray[np.uint8],
) -> None:
    """Write ``points.npz`` (see module doc)."""
    import io  # noqa: PLC0415

    buffer = io.BytesIO()
    np.savez(
        buffer, xyz=xyz.astype(np.float32), rgb=rgb.astype(np.uint8), source=source.astype(np.uint8)
    )
    write_bytes_atomic(Path(path), buffer.getvalue())


def load_points(
    path: Path,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8], npt.NDArray[np.uint8]]:
    """Read ``points.npz``: (xyz, rgb, source)."""
    with np.load(Path(path)) as data:
        return data["xyz"], data["rgb"], data["source"]
