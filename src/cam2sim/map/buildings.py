"""Building footprints from the workspace's OpenStreetMap extract, in the world frame.

Closed ways tagged ``building=*`` (not ``building=no``) become outlines with a height: the
``height`` tag (metres; ``"12 m"`` and ``"12.5"`` both read), else ``building:levels`` times
3 m plus 1 m, else ``default_height_m``. Multipolygon relations are not assembled (their
outer ways are usually tagged too); building parts (``building:part``) are skipped.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Mapping

    import numpy.typing as npt

    from cam2sim.core.frames import GridFrame, WorldFrame
    from cam2sim.map.osm import OsmData

__all__ = ["Building", "building_footprints"]

_NUMBER = re.compile(r"^\s*([0-9]+(?:\.[0-9]+)?)\s*(m|metres|meters)?\s*$")


@dataclass(frozen=True, eq=False)
class Building:
    """A building outline and height.

    Attributes:
        osm_id: Id of the OSM way.
        xy: ``(K, 2)`` closed exterior ring in world metres.
        height_m: Height above the ground, metres.
    """

    osm_id: int
    xy: npt.NDArray[np.float64]
    height_m: float


def _height(tags: Mapping[str, str], default: float) -> float:
    m = _NUMBER.match(tags.get("height", ""))
    if m:
        return float(m.group(1))
    levels = _NUMBER.match(tags.get("building:levels", ""))
    if levels:
        return 3.0 * float(levels.group(1)) + 1.0
    return default


def building_footprints(
    osm: OsmData, world: WorldFrame | GridFrame, *, default_height_m: float = 10.0
) -> list[Building]:
    """Every closed ``building`` way of ``osm`` as an outline in the world frame."""
    ways = [
        w
        for w in osm.ways
        if w.tags.get("building", "no") != "no" and len(w.refs) >= 4 and w.refs[0] == w.refs[-1]
    ]
    if not ways:
        return []
    refs = np.concatenate([w.refs for w in ways])
    rows = osm.node_indices(refs)
    counts = np.array([len(w.refs) for w in ways])
    xyz = world.from_wgs84(osm.lat_deg[rows.clip(0)], osm.lon_deg[rows.clip(0)])
    bounds = np.concatenate([[0], np.cumsum(counts)])
    out = []
    for k, way in enumerate(ways):  # one outline per building
        lo, hi = bounds[k], bounds[k + 1]
        if np.any(rows[lo:hi] < 0):
            continue  # a node outside the extract
        out.append(Building(way.id, xyz[lo:hi, :2], _height(way.tags, default_height_m)))
    return out
