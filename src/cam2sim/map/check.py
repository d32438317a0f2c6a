"""Check a converted map against its OSM source: are the roads where OSM says they are?

Every node of an OSM way of a converted road type is projected into the world frame with
pyproj and compared with the OpenDRIVE lines the converter derives from the way. CARLA's
converter (SUMO netconvert) follows three conventions, and a node is matched to the nearest line
of any of them:

- a two-way street becomes two roads whose reference line is the OSM way;
- a one-way street's OSM way is the middle of its driving lanes;
- streets merged or widened by the converter put the way on a driving-lane boundary.

Nodes inside junction areas (the convex hull of a junction's connecting roads) are left out: the
converter cuts roads back there. Corners of the OSM polyline are rounded by the converter
(paramPoly3 curves about 14 m long), which moves a node at a sharp bend by up to about
``7 m * sin(bend / 2) / 2`` from the curve; nodes on straight stretches (bend under 5° at the node
and both neighbours) show the geo-referencing error alone. A least-squares similarity transform
between those nodes and their matched points (those within 0.25 m) gives the residual rotation,
scale and shift of the map against the world frame: a map made in the wrong projection (the
published tool's tmerc at longitude 0) shows 8.7° and 0.91 % at Munich.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import shapely

from cam2sim.map._segments import PolylineIndex

if TYPE_CHECKING:
    from collections.abc import Iterable

    import numpy.typing as npt

    from cam2sim.core.frames.projection import WorldFrame
    from cam2sim.map.osm import BBox, OsmData
    from cam2sim.map.query import Lane, RoadMap

__all__ = ["OsmAlignment", "osm_alignment"]

_STRAIGHT_DEG = 5.0


@dataclass(frozen=True)
class OsmAlignment:
    """How well the OpenDRIVE roads follow their OSM ways.

    Attributes:
        nodes: OSM nodes of converted road types outside junction areas.
        nodes_in_junctions: Nodes left out because they lie inside a junction area.
        unmatched: Nodes farther than 50 m from any road line (ways the converter dropped).
        median_m: Median node-to-line distance, metres.
        p95_m: 95th percentile, metres.
        max_m: Largest distance, metres (of matched nodes).
        within_0_5m: Fraction of nodes within 0.5 m.
        straight_nodes: Nodes on straight stretches.
        straight_max_m: Largest distance of those, metres.
        rotation_deg: Rotation of the map against the world frame, degrees (best fit).
        scale_error: Scale of the map minus 1 (best fit).
        shift_m: Translation of the map against the world frame, metres (best fit).
    """

    nodes: int
    nodes_in_junctions: int
    unmatched: int
    median_m: float
    p95_m: float
    max_m: float
    within_0_5m: float
    straight_nodes: int
    straight_max_m: float
    rotation_deg: float
    scale_error: float
    shift_m: float


_UNMATCHED_M = 50.0
_FIT_MATCH_M = 0.25


def _candidate_lines(road_map: RoadMap) -> PolylineIndex:
    """Reference lines, driving-lane boundaries and driving-carriageway middles off junctions."""
    lines = [ref.xy for ref in road_map.references if ref.junction_id is None]
    sides: dict[tuple[str, int, int], list[Lane]] = {}
    for ln in road_map.lanes:
        if ln.junction_id is None and ln.type == "driving":
            sides.setdefault((ln.road_id, ln.section, int(np.sign(ln.lane_id))), []).append(ln)
    for lanes in sides.values():
        lanes.sort(key=lambda ln: abs(ln.lane_id))
        lines.extend(p for ln in lanes for p in (ln.left, ln.right))
        inner = lanes[0].left if lanes[0].lane_id < 0 else lanes[0].right
        outer = lanes[-1].right if lanes[-1].lane_id < 0 else lanes[-1].left
        lines.append((inner + outer) / 2.0)
    return PolylineIndex.build(lines)


def _junction_area(road_map: RoadMap) -> shapely.Geometry:
    """Union of the convex hulls of each junction's connecting-road lanes."""
    coords: dict[str, list[npt.NDArray[np.float64]]] = {}
    for ln in road_map.lanes:
        if ln.junction_id is not None:
            coords.setdefault(ln.junction_id, []).extend((ln.left, ln.right))
    hulls = [shapely.convex_hull(shapely.multipoints(np.concatenate(c))) for c in coords.values()]
    area = shapely.union_all(hulls) if hulls else shapely.Polygon()
    shapely.prepare(area)
    return area


def _bend_deg(xy: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Deflection angle at every vertex of a polyline, degrees (inf at both ends)."""
    out = np.full(len(xy), np.inf)
    if len(xy) > 2:
        v1 = xy[1:-1] - xy[:-2]
        v2 = xy[2:] - xy[1:-1]
        a = np.arctan2(v2[:, 1], v2[:, 0]) - np.arctan2(v1[:, 1], v1[:, 0])
        out[1:-1] = np.degrees(np.abs((a + np.pi) % (2 * np.pi) - np.pi))
    return out


def _similarity(
    src: npt.NDArray[np.float64], dst: npt.NDArray[np.float64]
) -> tuple[float, float, float]:
    """Best-fit rotation (degrees), scale - 1 and shift (metres) mapping ``src`` onto ``dst``."""
    if len(src) < 3:
        return math.nan, math.nan, math.nan
    ca, cb = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - ca, dst - cb
    u, sv, vt = np.linalg.svd(a.T @ b)
    sign = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    d = np.diag([1.0, sign])
    rot = vt.T @ d @ u.T
    var = float((a**2).sum())
    scale = float((sv * np.diag(d)).sum() / var) if var > 0 else math.nan
    shift = cb - scale * (rot @ ca)
    return math.degrees(math.atan2(rot[1, 0], rot[0, 0])), scale - 1.0, float(np.hypot(*shift))


def osm_alignment(
    osm: OsmData,
    road_map: RoadMap,
    frame: WorldFrame,
    road_types: Iterable[str],
    *,
    within: BBox | None = None,
) -> OsmAlignment:
    """Measure how far the OSM nodes of converted roads lie from the map's road lines.

    Args:
        osm: The OSM data the map was converted from.
        road_map: The converted map.
        frame: The world frame (the map's projection).
        road_types: The ``highway`` values that were converted.
        within: Count only the nodes inside this box (for data cut out of a larger extract,
            whose roads the converter ends differently near the cut).

    Returns:
        Distances, the share within 0.5 m, and the best-fit residual transform.
    """
    xy_parts: list[npt.NDArray[np.float64]] = []
    straight_parts: list[npt.NDArray[np.bool_]] = []
    for way in osm.highways(road_types):
        lat, lon = osm.way_coords(way)
        xy = frame.from_wgs84(lat, lon)[:, :2]
        bend = _bend_deg(xy)
        straight = bend < _STRAIGHT_DEG
        straight[1:-1] &= (bend[:-2] < _STRAIGHT_DEG) | ~np.isfinite(bend[:-2])
        straight[1:-1] &= (bend[2:] < _STRAIGHT_DEG) | ~np.isfinite(bend[2:])
        if within is not None:
            inside = within.contains(lat, lon)
            xy, straight = xy[inside], straight[inside]
        xy_parts.append(xy)
        straight_parts.append(straight)
    nan = math.nan
    if not xy_parts or not sum(len(p) for p in xy_parts):
        return OsmAlignment(0, 0, 0, nan, nan, nan, nan, 0, nan, nan, nan, nan)
    xy_all = np.concatenate(xy_parts)
    straight_all = np.concatenate(straight_parts)
    in_junction = shapely.intersects_xy(_junction_area(road_map), xy_all[:, 0], xy_all[:, 1])
    hit = _candidate_lines(road_map).nearest(xy_all, max_distance=_UNMATCHED_M)
    dist, foot = hit.distance, hit.foot
    keep = ~in_junction & np.isfinite(dist)
    d = dist[keep]
    if d.size == 0:
        return OsmAlignment(0, int(in_junction.sum()), 0, nan, nan, nan, nan, 0, nan, nan, nan, nan)
    straight = keep & straight_all
    # Fit on the well-matched straight nodes: a node the converter moved (a merged lane, a
    # junction just outside its area) would tilt a least-squares fit over a small area.
    fit = straight & (dist <= _FIT_MATCH_M)
    rotation, scale, shift = _similarity(xy_all[fit], foot[fit])
    return OsmAlignment(
        nodes=int(keep.sum()),
        nodes_in_junctions=int(in_junction.sum()),
        unmatched=int((~in_junction & ~np.isfinite(dist)).sum()),
        median_m=float(np.median(d)),
        p95_m=float(np.percentile(d, 95)),
        max_m=float(d.max()),
        within_0_5m=float((d <= 0.5).mean()),
        straight_nodes=int(straight.sum()),
        straight_max_m=float(dist[straight].max()) if straight.any() else nan,
        rotation_deg=rotation,
        scale_error=scale,
        shift_m=shift,
    )
