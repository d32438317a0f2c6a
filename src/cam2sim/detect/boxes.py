"""Oriented 3D boxes in one sensor frame, as arrays (one row per box).

Two sensor-frame conventions exist, matching :class:`~cam2sim.core.dataset.MountRecord`:

- ``link`` (LiDAR; x forward, y left, z up): ``yaw`` turns the box's length axis from +x
  towards +y about +z, so its direction is ``(cos yaw, sin yaw, 0)``;
- ``optical`` (camera; x right, y down, z forward): ``yaw`` turns about the up axis (-y), the
  mmdetection3d camera-box convention, so the length axis is ``(cos yaw, 0, -sin yaw)``.

``center`` is the geometric centre of the box (not its bottom). ``sigma_m`` is each box
centre's standard deviation in metres (the detector's error model: LiDAR boxes a small
constant, monocular boxes growing with depth); fusion weights boxes by ``score / sigma_m**2``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

__all__ = ["Axes", "Boxes"]

Axes = Literal["link", "optical"]


@dataclass(frozen=True, eq=False)
class Boxes:
    """``N`` oriented boxes in one sensor frame.

    Attributes:
        center: ``(N, 3)`` box centres, metres.
        size: ``(N, 3)`` length (along the yaw direction), width, height, metres.
        yaw: ``(N,)`` radians, see the module doc for the axis.
        score: ``(N,)`` detector confidence in ``[0, 1]``.
        sigma_m: ``(N,)`` standard deviation of the centre position, metres (> 0).
        axes: Sensor-frame convention.
    """

    center: npt.NDArray[np.float64]
    size: npt.NDArray[np.float64]
    yaw: npt.NDArray[np.float64]
    score: npt.NDArray[np.float64]
    sigma_m: npt.NDArray[np.float64]
    axes: Axes = "link"

    def __post_init__(self) -> None:
        center = np.asarray(self.center, dtype=np.float64).reshape(-1, 3)
        n = center.shape[0]
        size = np.asarray(self.size, dtype=np.float64).reshape(-1, 3)
        yaw = np.asarray(self.yaw, dtype=np.float64).reshape(-1)
        score = np.asarray(self.score, dtype=np.float64).reshape(-1)
        sigma = np.broadcast_to(np.asarray(self.sigma_m, dtype=np.float64), (n,)).copy()
        if not (size.shape[0] == yaw.shape[0] == score.shape[0] == n):
            msg = (
                f"Boxes arrays disagree in length: center {n}, size {size.shape[0]}, "
                f"yaw {yaw.shape[0]}, score {score.shape[0]}"
            )
            raise ValueError(msg)
        if n and (not np.all(np.isfinite(center)) or not np.all(sigma > 0)):
            msg = "Boxes need finite centres and positive sigma_m"
            raise ValueError(msg)
        if self.axes not in ("link", "optical"):
            msg = f"Boxes.axes must be 'link' or 'optical', got {self.axes!r}"
            raise ValueError(msg)
        object.__setattr__(self, "center", center)
        object.__setattr__(self, "size", size)
        object.__setattr__(self, "yaw", yaw)
        object.__setattr__(self, "score", score)
        object.__setattr__(self, "sigma_m", sigma)

    def __len__(self) -> int:
        return int(self.center.shape[0])

    @classmethod
    def empty(cls, axes: Axes = "link") -> Boxes:
        """No boxes."""
        z = np.zeros((0, 3))
        return cls(z, z, np.zeros(0), np.zeros(0), np.zeros(0), axes)

    def direction(self) -> npt.NDArray[np.float64]:
        """``(N, 3)`` unit vectors along each box's length axis, in the sensor frame."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        z = np.zeros_like(c)
        if self.axes == "link":
            return np.stack([c, s, z], axis=-1)
        return np.stack([c, z, -s], axis=-1)

    def select(self, keep: npt.NDArray[np.bool_] | npt.NDArray[np.int64]) -> Boxes:
        """The boxes picked by a boolean mask or an index array."""
        return Boxes(
            self.center[keep],
            self.size[keep],
            self.yaw[keep],
            self.score[keep],
            self.sigma_m[keep],
            self.axes,
        )

    @classmethod
    def concatenate(cls, parts: list[Boxes], axes: Axes = "link") -> Boxes:
        """All boxes of ``parts`` (which must share ``axes``) in one set."""
        if not parts:
            return cls.empty(axes)
        if any(p.axes != parts[0].axes for p in parts):
            msg = "cannot concatenate boxes of different sensor-frame conventions"
            raise ValueError(msg)
        return cls(
            np.concatenate([p.center for p in parts]),
            np.concatenate([p.size for p in parts]),
            np.concatenate([p.yaw for p in parts]),
            np.concatenate([p.score for p in parts]),
            np.concatenate([p.sigma_m for p in parts]),
            parts[0].axes,
        )
