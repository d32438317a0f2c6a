"""Snapping parked vehicles to the map's road edge (the kerb line of the carriageway).

A parallel-parked car stands with its outer side a kerb gap inside the road edge and its length
along it; a perpendicular one stands with its near end at the edge. Snapping moves each vehicle
to the nearest road edge point on its side of the road (when one lies within ``max_move_m``) and
turns it to the edge's direction (or across it); vehicles edited by hand are left alone, and so
are vehicles with no edge in reach.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from cam2sim.detect.vehicles import ParkedVehicle
    from cam2sim.map.query import RoadMap

__all__ = ["SnapOptions", "snap_to_road_edges"]


@dataclass(frozen=True)
class SnapOptions:
    """How far and how vehicles are snapped.

    Attributes:
        max_move_m: Vehicles farther than this from any road edge stay where they are.
        kerb_gap_m: Gap between a parallel car's outer side and the edge.
    """

    max_move_m: float = 2.5
    kerb_gap_m: float = 0.2


def snap_to_road_edges(
    vehicles: list[ParkedVehicle], road_map: RoadMap, options: SnapOptions | None = None
) -> tuple[list[ParkedVehicle], int]:
    """Return the vehicles snapped to the nearest road edge, and how many moved."""
    from scipy.spatial import cKDTree  # noqa: PLC0415

    opts = options or SnapOptions()
    edges = road_map.road_edges()
    if not edges or not vehicles:
        return list(vehicles), 0
    xy = np.concatenate([e.xy for e in edges])
    heading = np.concatenate([e.heading for e in edges])
    # Inward normal: the carriageway lies left of a right edge and right of a left edge.
    sign = np.concatenate(
        [np.full(e.xy.shape[0], 1.0 if e.side == "right" else -1.0) for e in edges]
    )
    inward = np.stack([-np.sin(heading), np.cos(heading)], 1) * sign[:, None]
    tree = cKDTree(xy)
    out: list[ParkedVehicle] = []
    moved = 0
    for v in vehicles:
        p = np.asarray(v.position[:2])
        dist, i = tree.query(p)
        if v.edited or dist > opts.max_move_m + v.size[1]:
            out.append(v)
            continue
        length, width = v.size[0], v.size[1]
        if v.orientation == "parallel":
            offset = width / 2.0 + opts.kerb_gap_m
            yaw = float(heading[i])
        else:
            offset = length / 2.0
            yaw = float(heading[i] + np.pi / 2.0)
        target = xy[i] + inward[i] * offset
        # The vehicle may stand outside the carriageway (on a parking bay beyond the kerb):
        # keep it on the side of the edge it was detected on.
        if float(np.dot(p - xy[i], inward[i])) < 0:
            target = xy[i] - inward[i] * offset
        if float(np.linalg.norm(target - p)) > opts.max_move_m:
            out.append(v)
            continue
        # Keep the direction (yaw or yaw + pi) closest to the detected one.
        if np.cos(yaw - v.yaw) < 0:
            yaw += np.pi
        yaw = float(np.angle(np.exp(1j * yaw)))
        out.append(
            v.model_copy(
                update={"position": (float(target[0]), float(target[1]), v.position[2]), "yaw": yaw}
            )
        )
        moved += 1
    return out, moved
