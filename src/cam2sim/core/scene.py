"""The ground-truth world's geometry: a road with kerbs, parked cars and buildings as boxes.

The vocabulary the demo's worlds (:mod:`cam2sim.demo.world`), the truth camera
(:mod:`cam2sim.render.truth`) and the synthetic LiDAR (:mod:`cam2sim.demo.lidar`) share. A
world frame: x, y horizontal, z up, metres; the street runs along world x.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = ["Ground", "SceneBox", "StreetScene", "car_on_ground"]


@dataclass(frozen=True)
class SceneBox:
    """An upright box in the world frame, turned about z only.

    Attributes:
        center: ``(3,)`` geometric centre, metres, world frame.
        size: ``(3,)`` length (along ``yaw``), width, height, metres.
        yaw: Angle of the length axis, radians CCW from world +x.
    """

    center: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw: float


@dataclass(frozen=True)
class Ground:
    """A road plane with kerbs: the road is ``|y| <= road_half_width_m``, sidewalks beyond.

    Heights follow ``z = height_m + slope[0] * x + slope[1] * y`` on the road and
    ``kerb_height_m`` more on the sidewalks; the kerbs are vertical faces at
    ``y = ±road_half_width_m`` (the street runs along world x).

    Attributes:
        height_m: Road height at the world origin, metres. Default 0.
        slope: ``(dz/dx, dz/dy)`` of the road, dimensionless. Default flat.
        road_half_width_m: Half the kerb-to-kerb width, metres. Default 5.0.
        kerb_height_m: Sidewalk height above the road, metres; 0 for no kerb. Default 0.12.
    """

    height_m: float = 0.0
    slope: tuple[float, float] = (0.0, 0.0)
    road_half_width_m: float = 5.0
    kerb_height_m: float = 0.12

    def height_at(self, xy: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Ground height, metres, under ``(..., 2)`` world positions (sidewalks included)."""
        p = np.asarray(xy, dtype=np.float64)
        road = self.height_m + self.slope[0] * p[..., 0] + self.slope[1] * p[..., 1]
        out: npt.NDArray[np.float64] = road + np.where(
            np.abs(p[..., 1]) > self.road_half_width_m, self.kerb_height_m, 0.0
        )
        return out


@dataclass(frozen=True)
class StreetScene:
    """A ground-truth world: what the truth camera draws and the synthetic LiDAR hits.

    Attributes:
        ground: The road and sidewalks.
        cars: Ground-truth boxes of the parked cars; a scan labels their returns by index.
        structures: Buildings and walls (boxes reaching below the ground, so slopes leave no
            gap under them).
    """

    ground: Ground = field(default_factory=Ground)
    cars: tuple[SceneBox, ...] = ()
    structures: tuple[SceneBox, ...] = ()


def car_on_ground(
    ground: Ground, xy: tuple[float, float], yaw: float, size: tuple[float, float, float]
) -> SceneBox:
    """Return the box of a car standing on ``ground`` at world ``xy`` (metres), turned ``yaw``."""
    z = float(ground.height_at(np.asarray(xy)))
    return SceneBox((xy[0], xy[1], z + size[2] / 2.0), size, yaw)
