"""The ego route as seen by parked cars: which side of it they stand on, and how they face it."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Final

import numpy as np
import numpy.typing as npt

from cam2sim.core.polyline import ReferencePath, arc_length

if TYPE_CHECKING:
    from cam2sim.detect.vehicles import Orientation, Side

__all__ = ["MIN_ROUTE_M", "Route"]

MIN_ROUTE_M: Final = 5.0
"""A recording that drove less than this (metres) stood still: its route is its heading line."""


@dataclass(frozen=True)
class Route:
    """The driven path, resampled every ``spacing_m``, for side and orientation queries."""

    path: ReferencePath

    @classmethod
    def from_xy(
        cls,
        xy: npt.ArrayLike,
        *,
        heading: npt.ArrayLike | None = None,
        spacing_m: float = 0.5,
    ) -> Route:
        """Build from the ``(N, 2)`` driven positions (the dataset's trajectory).

        A car that barely moved (less than :data:`MIN_ROUTE_M` driven, e.g. one parked at the
        kerb) has no route to speak of: with ``heading`` (radians, one per position) the route
        is then a straight line through where it stood, along its mean heading, so that parked
        cars around it still get a side and an orientation.

        Raises:
            ValueError: Fewer than two distinct positions and no heading.
        """
        pts = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        if heading is not None and len(pts) and arc_length(pts)[-1] < MIN_ROUTE_M:
            yaw = np.asarray(heading, dtype=np.float64).ravel()
            mean = float(np.angle(np.exp(1j * yaw).mean()))
            along = np.array([math.cos(mean), math.sin(mean)])
            centre = np.median(pts, axis=0)
            pts = centre + np.outer([-MIN_ROUTE_M, MIN_ROUTE_M], along)
        return cls(ReferencePath.from_polyline(pts, spacing_m=spacing_m))

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
