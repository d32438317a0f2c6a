"""The ego route as seen by parked cars: which side of it they stand on, and how they face it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from cam2sim.metrics.path import ReferencePath

if TYPE_CHECKING:
    from cam2sim.detect.vehicles import Orientation, Side

__all__ = ["Route"]


@dataclass(frozen=True)
class Route:
    """The driven path, resampled every ``spacing_m``, for side and orientation queries."""

    path: ReferencePath

    @classmethod
    def from_xy(cls, xy: npt.ArrayLike, *, spacing_m: float = 0.5) -> Route:
        """Build from the ``(N, 2)`` driven positions (the dataset's trajectory)."""
        return cls(
            ReferencePath.from_polyline(np.asarray(xy, dtype=np.float64), spacing_m=spacing_m)
        )

    def nearest(self, xy: npt.ArrayLike) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Signed lateral offset (left positive) and route heading at the nearest vertex."""
        from scipy.spatial import cKDTree  # noqa: PLC0415

        pts = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        if pts.shape[0] == 0:
            return np.zeros(0), np.zeros(0)
        _, idx = cKDTree(self.path.xy).query(pts)
        heading = self.path.tangent_heading()[idx]
        d = pts - self.path.xy[idx]
        lateral = np.cos(heading) * d[:, 1] - np.sin(heading) * d[:, 0]
        return lateral, heading

    def side(self, xy: npt.ArrayLike) -> list[Side]:
        """``left`` or ``right`` of the driving direction, per point."""
        lateral, _ = self.nearest(xy)
        return ["left" if v > 0 else "right" for v in lateral]

    def orientation(self, xy: npt.ArrayLike, yaw: npt.ArrayLike) -> list[Orientation]:
        """``parallel`` when a box's length axis is within 45 degrees of the route, per box."""
        _, heading = self.nearest(xy)
        diff = np.abs(np.angle(np.exp(1j * (np.asarray(yaw, dtype=np.float64) - heading))))
        diff = np.minimum(diff, np.pi - diff)  # a box has no front: yaw and yaw + pi agree
        return ["parallel" if v < np.pi / 4 else "perpendicular" for v in diff]
