"""A road map you can query: lane polygons, drivable area, nearest lanes, road edges.

:class:`RoadMap` is built once from OpenDRIVE text (``RoadMap.from_xodr``): every lane of every
lane section is sampled along its road at a fixed station step (and at every geometry start), in
the map's own coordinates, which for cam2sim maps are world coordinates (x east, y north,
metres). Queries take whole ``(N, 2)`` point batches and run in shapely's C loops (STRtree) and
numpy, never a Python loop per point.

Lane direction follows OpenDRIVE right-hand traffic: lanes right of the reference line (negative
ids) run along increasing ``s``, left lanes against it. Every lane's centre line, boundaries and
heading are stored in its driving direction.
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
import shapely

from cam2sim.map._segments import PolylineIndex
from cam2sim.map.opendrive import (
    OpenDrive,
    Road,
    lane_borders,
    lane_offset,
    parse_opendrive,
    reference_line,
    road_half_width,
    station_grid,
)

if TYPE_CHECKING:
    from collections.abc import Iterable

    import numpy.typing as npt

__all__ = [
    "DRIVABLE_LANE_TYPES",
    "DRIVING",
    "Lane",
    "NearestLane",
    "ReferenceLine",
    "RoadEdge",
    "RoadMap",
]

logger = logging.getLogger(__name__)

DRIVING = "driving"
# Lane types a car may drive on (OpenDRIVE 1.4 names; CARLA treats them as road surface).
DRIVABLE_LANE_TYPES: tuple[str, ...] = (
    "driving",
    "entry",
    "exit",
    "onRamp",
    "offRamp",
    "bidirectional",
)
_KERB_SIDE_TYPES = ("driving", "parking", "shoulder", "bidirectional", "entry", "exit")
_DEFAULT_STEP_M = 0.5
_CHORD_TOLERANCE_M = 0.005  # curves are sampled so that no chord departs more than this


@dataclass(frozen=True, eq=False)
class Lane:
    """One lane of one lane section, sampled in its driving direction.

    Attributes:
        road_id: OpenDRIVE road id.
        section: Index of the lane section in the road.
        lane_id: OpenDRIVE lane id (< 0 right of the reference line, > 0 left).
        type: OpenDRIVE lane type (``driving``, ``parking``, ``sidewalk``, ``shoulder``, ...).
        junction_id: Id of the junction of a connecting road, else None.
        s: ``(K,)`` stations along the road, metres (decreasing for left lanes).
        centre: ``(K, 2)`` lane centre line, metres.
        left: ``(K, 2)`` left boundary (seen in the driving direction), metres.
        right: ``(K, 2)`` right boundary, metres.
        heading: ``(K,)`` driving direction of the centre line, radians CCW from +x.
        width: ``(K,)`` lane width, metres.
    """

    road_id: str
    section: int
    lane_id: int
    type: str
    junction_id: str | None
    s: npt.NDArray[np.float64]
    centre: npt.NDArray[np.float64]
    left: npt.NDArray[np.float64]
    right: npt.NDArray[np.float64]
    heading: npt.NDArray[np.float64]
    width: npt.NDArray[np.float64]

    @property
    def length(self) -> float:
        """Length of the centre line, metres."""
        return float(np.hypot(*np.diff(self.centre, axis=0).T).sum())


@dataclass(frozen=True, eq=False)
class ReferenceLine:
    """A road's reference line, sampled like its lanes.

    Attributes:
        road_id: OpenDRIVE road id.
        junction_id: Junction of a connecting road, else None.
        s: ``(K,)`` increasing stations, metres.
        xy: ``(K, 2)`` points, metres.
        heading: ``(K,)`` direction of increasing ``s``, radians.
    """

    road_id: str
    junction_id: str | None
    s: npt.NDArray[np.float64]
    xy: npt.NDArray[np.float64]
    heading: npt.NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class NearestLane:
    """The nearest lane centre line of each query point.

    Attributes:
        lane: ``(N,)`` int64 index into :attr:`RoadMap.lanes`, -1 where no lane qualified.
        centre: ``(N, 2)`` nearest point on that lane's centre line, metres.
        heading: ``(N,)`` driving direction of the lane there, radians: the reference line's
            heading (reversed for left lanes), interpolated between samples.
        distance: ``(N,)`` distance from the point to the centre line, metres (inf where lane
            is -1).
        lateral: ``(N,)`` signed offset from the centre line, metres, positive to the left of
            the driving direction.
        width: ``(N,)`` lane width there, metres.
        s: ``(N,)`` station along the road at the nearest point, metres.
    """

    lane: npt.NDArray[np.int64]
    centre: npt.NDArray[np.float64]
    heading: npt.NDArray[np.float64]
    distance: npt.NDArray[np.float64]
    lateral: npt.NDArray[np.float64]
    width: npt.NDArray[np.float64]
    s: npt.NDArray[np.float64]

    @property
    def inside(self) -> npt.NDArray[np.bool_]:
        """``(N,)`` whether the point lies within the lane's width."""
        return (self.lane >= 0) & (np.abs(self.lateral) <= self.width / 2.0)


@dataclass(frozen=True, eq=False)
class RoadEdge:
    """The outer edge of a road's carriageway on one side, where the kerb (or nothing) begins.

    Parked cars stand just inside it. Points run in the driving direction of the outermost
    lane on that side, so the carriageway lies to the left of a right edge and to the right of
    a left edge.

    Attributes:
        road_id: OpenDRIVE road id.
        section: Lane section index.
        side: ``"right"`` (negative lane ids) or ``"left"``.
        outer_lane_type: Type of the outermost carriageway lane (``driving``, ``parking``, ...).
        beyond_type: Type of the lane outside the edge (``sidewalk``, ...) or None.
        xy: ``(K, 2)`` the edge line, metres.
        heading: ``(K,)`` direction of travel along it, radians.
    """

    road_id: str
    section: int
    side: Literal["left", "right"]
    outer_lane_type: str
    beyond_type: str | None
    xy: npt.NDArray[np.float64]
    heading: npt.NDArray[np.float64]


def _type_key(lane_types: str | Iterable[str] | None) -> tuple[str, ...] | None:
    if lane_types is None:
        return None
    return tuple(sorted({lane_types} if isinstance(lane_types, str) else set(lane_types)))


def _as_xy(points: npt.ArrayLike) -> npt.NDArray[np.float64]:
    try:
        arr = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as err:
        msg = f"points must be a numeric (N, 2) or (N, 3) array, got {type(points).__name__}"
        raise TypeError(msg) from err
    if arr.ndim == 1 and arr.shape[0] in (2, 3):
        arr = arr[None]
    if arr.ndim != 2 or arr.shape[1] not in (2, 3):
        msg = f"points must have shape (N, 2) or (N, 3), got {arr.shape}; reshape the input"
        raise ValueError(msg)
    if not np.all(np.isfinite(arr[:, :2])):
        msg = "points hold NaN or inf; drop them before querying the map"
        raise ValueError(msg)
    return np.ascontiguousarray(arr[:, :2])


def _sample_road(road: Road, step_m: float) -> tuple[ReferenceLine, list[Lane]]:
    """Sample a road's reference line once, then every lane of every section along it."""
    s_all = station_grid(
        road,
        0.0,
        road.length,
        step_m,
        chord_tolerance_m=_CHORD_TOLERANCE_M,
        lateral_m=road_half_width(road),
    )
    cuts = np.array([min(max(sec.s, 0.0), road.length) for sec in road.sections])
    s_all = np.unique(np.concatenate([s_all, cuts]))
    x_all, y_all, hdg_all = reference_line(road, s_all)
    reference = ReferenceLine(
        road_id=road.id,
        junction_id=road.junction if road.in_junction else None,
        s=s_all,
        xy=np.stack([x_all, y_all], axis=-1),
        heading=hdg_all,
    )
    lanes: list[Lane] = []
    ends = [*cuts[1:], road.length]
    for k, (sec, start, end) in enumerate(zip(road.sections, cuts, ends, strict=True)):
        sel = (s_all >= start) & (s_all <= end)
        if end - start < 1e-6 or not sec.lanes or sel.sum() < 2:
            continue
        s, hdg, ref = s_all[sel], hdg_all[sel], reference.xy[sel]
        normal = np.stack([-np.sin(hdg), np.cos(hdg)], axis=-1)
        borders = lane_borders(sec, s - sec.s, lane_offset(road, s))
        for ln in sec.lanes:
            t_in, t_out = borders[ln.id]
            p_in = ref + t_in[:, None] * normal
            p_out = ref + t_out[:, None] * normal
            centre = (p_in + p_out) / 2.0
            width = np.abs(t_out - t_in)
            if ln.id < 0:  # along s: inner border is on the left
                left, right, head, ss = p_in, p_out, hdg, s
            else:  # against s: reverse, inner border is on the right
                left, right = p_out[::-1], p_in[::-1]
                centre, width, ss = centre[::-1], width[::-1], s[::-1]
                head = hdg[::-1] + math.pi
            lanes.append(
                Lane(
                    road_id=road.id,
                    section=k,
                    lane_id=ln.id,
                    type=ln.type,
                    junction_id=road.junction if road.in_junction else None,
                    s=ss,
                    centre=centre,
                    left=left,
                    right=right,
                    heading=np.arctan2(np.sin(head), np.cos(head)),
                    width=width,
                )
            )
    return reference, lanes


class RoadMap:
    """Lane geometry of an OpenDRIVE map, with vectorised queries.

    Build it with :meth:`from_xodr` or :meth:`from_opendrive`. Spatial indexes are built lazily
    on the first query that needs them and kept.

    Attributes:
        opendrive: The parsed document.
        lanes: Every lane of every lane section (centre lanes excluded).
        step_m: Station step the lanes were sampled at.
    """

    def __init__(self, opendrive: OpenDrive, *, step_m: float = _DEFAULT_STEP_M) -> None:
        if not (math.isfinite(step_m) and 0.01 <= step_m <= 10.0):
            msg = f"step_m={step_m!r}; give a station step between 0.01 and 10 metres"
            raise ValueError(msg)
        self.opendrive = opendrive
        self.step_m = step_m
        lanes: list[Lane] = []
        references: list[ReferenceLine] = []
        for road in opendrive.roads:
            reference, road_lanes = _sample_road(road, step_m)
            references.append(reference)
            lanes.extend(road_lanes)
        self.lanes: tuple[Lane, ...] = tuple(lanes)
        self.references: tuple[ReferenceLine, ...] = tuple(references)
        self._types = np.array([ln.type for ln in self.lanes], dtype=object)
        self._areas: dict[tuple[str, ...], shapely.Geometry] = {}
        self._segment_cache: dict[tuple[str, ...] | None, PolylineIndex] = {}
        self._quad_cache: dict[
            tuple[str, ...] | None, tuple[shapely.STRtree, npt.NDArray[np.int64]]
        ] = {}
        logger.debug(
            "road map: %d roads, %d junctions, %d lanes",
            len(opendrive.roads),
            len(opendrive.junctions),
            len(self.lanes),
        )

    @classmethod
    def from_opendrive(cls, opendrive: OpenDrive, *, step_m: float = _DEFAULT_STEP_M) -> RoadMap:
        """Build from a parsed document."""
        return cls(opendrive, step_m=step_m)

    @classmethod
    def from_xodr(cls, xodr: str | Path, *, step_m: float = _DEFAULT_STEP_M) -> RoadMap:
        """Build from OpenDRIVE text or a ``.xodr`` file.

        Raises:
            StageError: The OpenDRIVE is malformed.
        """
        if isinstance(xodr, Path):
            return cls(
                parse_opendrive(xodr.read_text(encoding="utf-8"), source=str(xodr)), step_m=step_m
            )
        return cls(parse_opendrive(xodr), step_m=step_m)

    # -- selection -------------------------------------------------------------------------
    def lane_indices(self, lane_types: str | Iterable[str] | None = None) -> npt.NDArray[np.int64]:
        """Indices into :attr:`lanes` of the lanes of the given types (all when None)."""
        if lane_types is None:
            return np.arange(len(self.lanes), dtype=np.int64)
        wanted = {lane_types} if isinstance(lane_types, str) else set(lane_types)
        return np.flatnonzero(np.isin(self._types, list(wanted))).astype(np.int64)

    @functools.cached_property
    def lane_in_junction(self) -> npt.NDArray[np.bool_]:
        """``(L,)`` whether each lane belongs to a connecting road inside a junction."""
        return np.array([ln.junction_id is not None for ln in self.lanes], dtype=bool)

    @property
    def lane_types(self) -> tuple[str, ...]:
        """The lane types present, sorted."""
        return tuple(sorted({ln.type for ln in self.lanes}))

    # -- polygons ---------------------------------------------------------------------------
    @functools.cached_property
    def _polygons(self) -> npt.NDArray[np.object_]:
        if not self.lanes:
            return np.empty(0, dtype=object)
        rings = [np.concatenate([ln.left, ln.right[::-1], ln.left[:1]]) for ln in self.lanes]
        counts = np.array([len(r) for r in rings])
        coords = np.concatenate(rings)
        indices = np.repeat(np.arange(len(rings)), counts)
        polys = shapely.polygons(shapely.linearrings(coords, indices=indices))
        bad = ~shapely.is_valid(polys)
        if bad.any():
            # Tight curves fold the inner border of wide lanes over itself; keep the covered area.
            polys[bad] = shapely.make_valid(polys[bad], method="structure", keep_collapsed=False)
        shapely.prepare(polys)
        return np.asarray(polys, dtype=object)

    def lane_polygons(
        self, lane_types: str | Iterable[str] | None = None
    ) -> npt.NDArray[np.object_]:
        """Return the shapely polygons of the lanes of the given types, in :attr:`lanes` order.

        Use :meth:`lane_indices` with the same argument for the matching lanes.
        """
        return self._polygons[self.lane_indices(lane_types)]

    def _area(self, types: tuple[str, ...]) -> shapely.Geometry:
        if types not in self._areas:
            polys = self.lane_polygons(types)
            area = shapely.union_all(polys) if len(polys) else shapely.Polygon()
            shapely.prepare(area)
            self._areas[types] = area
        return self._areas[types]

    def drivable_area(self, lane_types: Iterable[str] = DRIVABLE_LANE_TYPES) -> shapely.Geometry:
        """Return the union of the lanes of ``lane_types`` (default: the lanes cars drive on)."""
        key = _type_key(lane_types)
        assert key is not None
        return self._area(key)

    def _quads(
        self, types: tuple[str, ...] | None
    ) -> tuple[shapely.STRtree, npt.NDArray[np.int64]]:
        """One quadrilateral per lane and station step, in an STRtree (small, fast to test)."""
        if types not in self._quad_cache:
            idx = self.lane_indices(types)
            lanes = [self.lanes[i] for i in idx]
            if not lanes:
                empty = shapely.STRtree(np.empty(0, dtype=object))
                self._quad_cache[types] = (empty, np.zeros(0, dtype=np.int64))
                return self._quad_cache[types]
            a = np.concatenate([ln.left[:-1] for ln in lanes])
            b = np.concatenate([ln.left[1:] for ln in lanes])
            c = np.concatenate([ln.right[1:] for ln in lanes])
            d = np.concatenate([ln.right[:-1] for ln in lanes])
            owner = np.concatenate(
                [
                    np.full(len(ln.s) - 1, i, dtype=np.int64)
                    for i, ln in zip(idx, lanes, strict=True)
                ]
            )
            quads = shapely.polygons(np.stack([a, b, c, d, a], axis=1))
            self._quad_cache[types] = (shapely.STRtree(quads), owner)
        return self._quad_cache[types]

    def lane_at(
        self, points: npt.ArrayLike, lane_types: str | Iterable[str] | None = None
    ) -> npt.NDArray[np.int64]:
        """Return ``(N,)`` the index into :attr:`lanes` of the lane each point lies on, or -1.

        Where lanes of the requested types overlap (inside junctions), one of them is returned.
        """
        xy = _as_xy(points)
        out = np.full(xy.shape[0], -1, dtype=np.int64)
        tree, owner = self._quads(_type_key(lane_types))
        if owner.size == 0 or xy.shape[0] == 0:
            return out
        q, hit = tree.query(shapely.points(xy), predicate="intersects")
        out[q] = owner[hit]
        return out

    def on_lane(
        self, points: npt.ArrayLike, lane_types: str | Iterable[str] | None = DRIVABLE_LANE_TYPES
    ) -> npt.NDArray[np.bool_]:
        """Return ``(N,)`` whether each point lies on a lane of ``lane_types``."""
        return self.lane_at(points, lane_types) >= 0

    # -- nearest lane ------------------------------------------------------------------------
    def _segments(self, types: tuple[str, ...] | None) -> PolylineIndex:
        if types not in self._segment_cache:
            idx = self.lane_indices(types)
            lanes = [self.lanes[i] for i in idx]
            self._segment_cache[types] = PolylineIndex.build(
                [ln.centre for ln in lanes],
                owners=idx.tolist(),
                values={
                    "width": [ln.width for ln in lanes],
                    "s": [ln.s for ln in lanes],
                    "cos": [np.cos(ln.heading) for ln in lanes],
                    "sin": [np.sin(ln.heading) for ln in lanes],
                },
            )
        return self._segment_cache[types]

    def nearest_lane(
        self,
        points: npt.ArrayLike,
        lane_types: str | Iterable[str] | None = DRIVING,
        *,
        max_distance: float | None = None,
    ) -> NearestLane:
        """Find the nearest lane centre line of each point.

        Args:
            points: ``(N, 2)`` or ``(N, 3)`` world points, metres (z ignored).
            lane_types: Lane types to consider (default ``"driving"``; None for all).
            max_distance: Search radius, metres; farther points get lane -1 (faster on points
                far from any road). None searches without limit.

        Returns:
            The lane, nearest centre point, heading, distance, signed lateral offset, width and
            station of every point.
        """
        xy = _as_xy(points)
        hit = self._segments(_type_key(lane_types)).nearest(xy, max_distance)
        return NearestLane(
            lane=hit.owner,
            centre=hit.foot,
            heading=np.arctan2(hit.values["sin"], hit.values["cos"]),
            distance=hit.distance,
            lateral=hit.side * hit.distance,
            width=hit.values["width"],
            s=hit.values["s"],
        )

    # -- road edges --------------------------------------------------------------------------
    def road_edges(
        self, carriageway_types: Iterable[str] = _KERB_SIDE_TYPES
    ) -> tuple[RoadEdge, ...]:
        """Return the outer carriageway edge of every road side outside junctions.

        The carriageway is the run of lanes of ``carriageway_types`` next to the reference line;
        its outer boundary is the edge, and the lane beyond it (a sidewalk, say) is named.
        """
        wanted = set(carriageway_types)
        by_side: dict[tuple[str, int, int], list[Lane]] = {}
        for ln in self.lanes:
            if ln.junction_id is None:
                by_side.setdefault((ln.road_id, ln.section, int(np.sign(ln.lane_id))), []).append(
                    ln
                )
        edges: list[RoadEdge] = []
        for (road_id, section, side), lanes in by_side.items():
            lanes.sort(key=lambda ln: abs(ln.lane_id))
            outer: Lane | None = None
            beyond: str | None = None
            for ln in lanes:
                if ln.type in wanted:
                    outer = ln
                else:
                    beyond = ln.type
                    break
            if outer is None:
                continue
            edges.append(
                RoadEdge(
                    road_id=road_id,
                    section=section,
                    side="right" if side < 0 else "left",
                    outer_lane_type=outer.type,
                    beyond_type=beyond,
                    xy=outer.right if side < 0 else outer.left,
                    heading=outer.heading,
                )
            )
        return tuple(edges)

    # -- counts ------------------------------------------------------------------------------
    def lane_length_by_type(self) -> dict[str, float]:
        """Total centre-line length per lane type, metres."""
        out: dict[str, float] = {}
        for ln in self.lanes:
            out[ln.type] = out.get(ln.type, 0.0) + ln.length
        return dict(sorted(out.items()))
