"""Parked vehicles checked against the map and the recording before they are spawned.

A detected car can be wrong, and a wrong car spawned silently blocks the road the recording
drove through. Three checks, each giving a reason the vehicle is left out (the stage reports
them and marks them in ``scenario.png``):

- **on the recorded path**: the footprint intersects the swept path of the ego vehicle (its
  centre trajectory widened by half its width), i.e. the recording drove through where the car
  would stand;
- **in a driven lane**: the centre lies on a driving lane the recording used, near that lane's
  middle (within a quarter of its width), not at its kerb side where cars do park when a map
  has no separate parking lane;
- **overlap**: two footprints overlap by more than ``overlap_m2``; the less confident of the two
  is left out.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from cam2sim.core.footprint import footprint_corners

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy.typing as npt

    from cam2sim.map.query import RoadMap

__all__ = ["CheckOptions", "ParkedBox", "check_parked", "footprints"]


class ParkedBox(Protocol):
    """What the checks read of a parked vehicle (the detect stage's ``ParkedVehicle`` is one)."""

    @property
    def id(self) -> str:
        """Stable identifier."""
        ...

    @property
    def position(self) -> tuple[float, float, float]:
        """Centre, metres, world frame."""
        ...

    @property
    def yaw(self) -> float:
        """Heading of the length axis, radians."""
        ...

    @property
    def size(self) -> tuple[float, float, float]:
        """Length, width, height, metres."""
        ...


@dataclass(frozen=True)
class CheckOptions:
    """Thresholds of the parked-vehicle checks.

    Attributes:
        path_overlap_m2: Footprint area inside the ego's swept path that rejects a car.
        lane_centre_fraction: A car centre within this fraction of the lane width from a
            driven lane's centre line is "in" the lane.
        overlap_m2: Footprint overlap between two cars that rejects the less confident one.
    """

    path_overlap_m2: float = 0.2
    lane_centre_fraction: float = 0.25
    overlap_m2: float = 0.2


def footprints(vehicles: Sequence[ParkedBox]) -> npt.NDArray[np.object_]:
    """Shapely polygons of the vehicles' footprints."""
    import shapely  # noqa: PLC0415

    if not vehicles:
        return np.empty(0, dtype=object)
    corners = footprint_corners(
        [v.position[:2] for v in vehicles],
        [v.yaw for v in vehicles],
        [v.size[0] for v in vehicles],
        [v.size[1] for v in vehicles],
    )
    return np.asarray(shapely.polygons(corners), dtype=object)


def check_parked(
    vehicles: Sequence[ParkedBox],
    centre_path: npt.ArrayLike,
    ego_width_m: float,
    road_map: RoadMap | None,
    options: CheckOptions | None = None,
) -> dict[str, list[str]]:
    """Reasons to leave each vehicle out, by id (vehicles without a reason are absent).

    Args:
        vehicles: The parked vehicles.
        centre_path: ``(N, 2)`` the ego vehicle's centre along the recording, metres.
        ego_width_m: The ego vehicle's width.
        road_map: The map, for the driven-lane check (skipped when None).
        options: Thresholds.
    """
    import shapely  # noqa: PLC0415

    opts = options or CheckOptions()
    reasons: dict[str, list[str]] = {}
    if not vehicles:
        return reasons
    polys = footprints(vehicles)
    path_xy = np.asarray(centre_path, dtype=np.float64).reshape(-1, 2)
    swept = shapely.buffer(shapely.linestrings(path_xy), ego_width_m / 2.0, cap_style="flat")
    inside = shapely.area(shapely.intersection(polys, swept))
    for v, area in zip(vehicles, inside.tolist(), strict=True):
        if area > opts.path_overlap_m2:
            reasons.setdefault(v.id, []).append(
                f"stands on the recorded path ({area:.1f} m2 of its footprint inside the ego's "
                "swept path)"
            )
    if road_map is not None:
        driven = np.unique(road_map.lane_at(path_xy[:: max(1, len(path_xy) // 2000)], "driving"))
        driven = driven[driven >= 0]
        centres = np.array([v.position[:2] for v in vehicles])
        near = road_map.nearest_lane(centres, "driving", max_distance=10.0)
        hit = np.isin(near.lane, driven) & (
            np.abs(near.lateral) < opts.lane_centre_fraction * near.width
        )
        for i in np.flatnonzero(hit).tolist():
            lane = road_map.lanes[int(near.lane[i])]
            reasons.setdefault(vehicles[i].id, []).append(
                f"stands in the middle of driving lane {lane.lane_id} of road {lane.road_id}, "
                "which the recording drove through"
            )
    tree = shapely.STRtree(polys)
    a, b = tree.query(polys, predicate="intersects")
    pairs = a < b
    for i, j in zip(a[pairs].tolist(), b[pairs].tolist(), strict=True):
        area = float(shapely.area(shapely.intersection(polys[i], polys[j])))
        if area <= opts.overlap_m2:
            continue
        vi, vj = vehicles[i], vehicles[j]
        loser, winner = (vi, vj) if vi.confidence < vj.confidence else (vj, vi)
        reasons.setdefault(loser.id, []).append(
            f"overlaps {winner.id} by {area:.1f} m2 (less confident of the two)"
        )
    return reasons
