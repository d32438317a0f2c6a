"""Demo worlds from real OpenStreetMap extracts (``cam2sim demo --osm FILE [--route A B]``).

:func:`osm_demo_world` turns an OSM file into the ground-truth world of a demo recording:

* **The route.** Given two points (``route``), the shortest drivable path between the road
  nodes nearest them (cut at 500 m); else the best path the file has (:func:`pick_route`):
  300-400 m (paths that run on are cut at 400 m: the demo's time grows with the route) on
  ``highway=residential|unclassified|tertiary`` ways (both directions open, no U-turns, no loop
  around a block narrower than 60 m), with at least two bends, preferring about 350 m near the
  middle of the extract; without such a path, the one with most bends and closest to that
  length, or without any of 300 m the longest, saying so in the world's notes. Where the
  extract has no such path of 100 m at all (an extract of main roads or of one junction),
  ``living_street``, ``secondary`` and ``primary`` ways are taken too (:data:`MAIN_ROADS`), the
  notes saying so; the street is still the demo's two-lane one. Every corner of
  the way geometry is rounded by the largest arc that fits
  (:meth:`~cam2sim.demo.route.PiecewiseRoute.from_polyline`, at least 26 m: a corner sharper
  than that is not drivable at the demo's speed and its paths are skipped).
* **The street** (:class:`~cam2sim.demo.world.DemoStreet`): the cross-section from the tags of
  the way the route follows longest (``width`` / ``lanes`` give the lane width, kept within
  3.0-4.0 m, else 3.5 m; lane markings when ``lanes`` is tagged or the road is tertiary or a
  main road and ``lane_markings`` is not ``no``); parked cars where ``parking:lane:*`` /
  ``parking:*`` allow them, nowhere where they forbid them, at the demo's seeded density where
  the tags say nothing, and never within 10 m of a junction; 25 km/h, or ``maxspeed`` when
  lower. The local frame is the UTM grid of the route's start
  (:class:`~cam2sim.core.frames.GridFrame`).
* **The buildings**: the extract's real footprints (``building=*``, heights from ``height`` or
  ``building:levels``) within 60 m of the street, except those the drawn street runs into; plain
  facades where the street has none within 25 m (as the built-in streets have).
* **The map stage's input** is the real extract around the route, not the drawn street: the
  reconstructed map differs from the truth as it does for a real recording.

The truth road is only the driven street (with straight 30 m leads at both ends): side streets
at its junctions are not drawn.
"""

from __future__ import annotations

import hashlib
import heapq
import itertools
import logging
import math
import re
from collections import Counter
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Final, TypeVar

import numpy as np

from cam2sim.core.errors import ConfigError, StageError
from cam2sim.core.frames import GridFrame
from cam2sim.demo.route import PiecewiseRoute
from cam2sim.demo.world import DemoBuilding, DemoStreet, DemoWorld, footprint_ring, parked_cars
from cam2sim.map.buildings import building_footprints
from cam2sim.map.osm import BBox, read_osm

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator, Mapping, Sequence

    import numpy.typing as npt

    from cam2sim.map.osm import OsmData

__all__ = [
    "DRIVABLE",
    "MAIN_ROADS",
    "OsmRoute",
    "OsmWorldPlan",
    "count_routes",
    "osm_demo_world",
    "pick_route",
    "pick_routes",
    "route_between",
]

logger = logging.getLogger(__name__)
_T = TypeVar("_T")

DRIVABLE: Final = ("residential", "unclassified", "tertiary")
"""The ``highway`` values a demo route uses."""
MAIN_ROADS: Final = ("living_street", "secondary", "primary")
"""Taken too where the extract has no path on :data:`DRIVABLE` roads alone (an extract of main
roads, or of a junction): the route then says so in its notes."""
ROUTE_MIN_M: Final = 300.0
ROUTE_SHORTEST_M: Final = 100.0
"""The shortest route taken when an extract has no path of :data:`ROUTE_MIN_M`."""
ROUTE_MAX_M: Final = 500.0
PICK_CUT_M: Final = 400.0
"""Picked paths that run on are cut here: the demo's time grows with the route."""
ROUTE_TARGET_M: Final = 350.0
"""The preferred length: long enough for three bends, short enough for 15 minutes on 2 cores."""
OSM_SPEED_MPS: Final = 25.0 / 3.6
COMFORT_ACCEL: Final = 2.0
"""Lateral acceleration (m/s^2) the recorded driver keeps to in bends, at constant speed."""
MIN_RADIUS_M: Final = 26.0
"""The tightest corner a route may have: OSM_SPEED_MPS^2 / COMFORT_ACCEL = 24 m for the right
lane, half a lane inside a right turn of the street's centre line."""
JUNCTION_RADIUS_M: Final = MIN_RADIUS_M
"""Corners at junctions are turns: rounded by at most this (a street's own curves by 60 m)."""
_MAX_DEFLECTION_RAD: Final = math.radians(100.0)
_SEARCH_BUDGET: Final = 40_000
"""Paths the route search extends before it settles for the best found."""
_ROUTE_SNAP_M: Final = 30.0
_BUILDING_REACH_M: Final = 60.0
_FACADE_GAP_M: Final = 25.0
_JUNCTION_CLEAR_M: Final = 10.0
_CROP_MARGIN_M: Final = 150.0
_DISTINCT_M: Final = 25.0
_MAX_OVERLAP: Final = 0.3
"""Routes of one extract share at most this much of their length (within 25 m)."""
_SELF_CLEAR_M: Final = 60.0
"""How close the route may come to itself further along (no loops around a small block)."""
_NO_PARKING: Final = frozenset(
    {"no", "no_parking", "no_stopping", "fire_lane", "separate", "none", "no_standing"}
)
_NUMBER = re.compile(r"^\s*([0-9]+(?:\.[0-9]+)?)")


@dataclass(frozen=True, eq=False)
class _Graph:
    """Drivable ways as a graph over their nodes (all of them, not only junctions)."""

    osm: OsmData
    frame: GridFrame
    kinds: tuple[str, ...]  # the highway values of its ways
    ways: tuple[int, ...]  # indices into osm.ways
    xy: npt.NDArray[np.float64]  # (N, 2) node positions, local frame
    node_ids: npt.NDArray[np.int64]  # (N,) OSM ids
    links: npt.NDArray[np.int64]  # (N,) distinct neighbours: 1 a dead end, 3+ a junction
    adjacency: tuple[tuple[tuple[int, int, bool], ...], ...]  # per node: (next, way, forward)


@dataclass(frozen=True)
class OsmRoute:
    """A drivable path through the extract.

    Attributes:
        nodes: Graph node indices along the path.
        xy: ``(K, 2)`` the path's polyline in the local frame (possibly cut inside its last
            segment, to stay within 500 m).
        ways: For each segment of ``xy``, the index of its OSM way in the file.
        forward: For each segment, whether it runs along its way's direction.
        route: The way's centre line with its corners rounded (the street's reference line;
            the car drives half a lane to its right).
        bends: Its bends (:meth:`~cam2sim.demo.route.PiecewiseRoute.bend_turns`).
    """

    nodes: tuple[int, ...]
    xy: npt.NDArray[np.float64]
    ways: tuple[int, ...]
    forward: tuple[bool, ...]
    route: PiecewiseRoute
    bends: int


@dataclass(frozen=True)
class OsmWorldPlan:
    """A demo world built from a real OSM file, and how it was chosen."""

    world: DemoWorld
    route: OsmRoute
    frame: GridFrame
    notes: tuple[str, ...]


def _number(text: str | None) -> float | None:
    m = _NUMBER.match(text or "")
    return float(m.group(1)) if m else None


def _oneway(tags: Mapping[str, str]) -> int:
    """1 forward only, -1 backward only, 0 both ways."""
    value = tags.get("oneway", "no")
    if value in {"yes", "true", "1"}:
        return 1
    if value == "-1":
        return -1
    return 0


def _graph(osm: OsmData, kinds: tuple[str, ...] = DRIVABLE) -> _Graph:
    ways = tuple(
        k
        for k, w in enumerate(osm.ways)
        if w.tags.get("highway") in kinds and w.tags.get("area") != "yes" and len(w.refs) > 1
    )
    if not ways:
        found = Counter(w.tags["highway"] for w in osm.ways if "highway" in w.tags)
        have = ", ".join(f"{k} ({n})" for k, n in found.most_common(8)) or "no highway at all"
        msg = (
            f"{osm.source} has no drivable road for the demo (highway={'/'.join(kinds)}); it "
            f"has: {have}. Export an area with residential streets"
        )
        raise StageError(msg)
    refs = np.concatenate([osm.ways[k].refs for k in ways])
    rows = osm.node_indices(refs)
    used = np.unique(rows[rows >= 0])
    if used.size < 2:
        msg = f"{osm.source}: the drivable ways' nodes are missing from the file; export it again"
        raise StageError(msg)
    lat, lon = osm.lat_deg[used], osm.lon_deg[used]
    frame = GridFrame.utm_at(float(lat.mean()), float(lon.mean()))
    xy = frame.from_wgs84(lat, lon)[:, :2]
    index = {int(r): i for i, r in enumerate(used)}
    neighbours: list[list[tuple[int, int, bool]]] = [[] for _ in used]
    linked: list[set[int]] = [set() for _ in used]
    for k in ways:
        way = osm.ways[k]
        seq = [index.get(int(r), -1) for r in osm.node_indices(way.refs)]
        one = _oneway(way.tags)
        for a, b in itertools.pairwise(seq):
            if a < 0 or b < 0 or a == b:
                continue
            linked[a].add(b)
            linked[b].add(a)
            if one >= 0:
                neighbours[a].append((b, k, True))
            if one <= 0:
                neighbours[b].append((a, k, False))
    return _Graph(
        osm=osm,
        frame=frame,
        kinds=kinds,
        ways=ways,
        xy=xy,
        node_ids=osm.node_id[used],
        links=np.array([len(s) for s in linked], dtype=np.int64),
        adjacency=tuple(tuple(n) for n in neighbours),
    )


def _route_of(
    graph: _Graph,
    nodes: Sequence[int],
    ways: Sequence[int],
    forward: Sequence[bool],
    cut_m: float = ROUTE_MAX_M,
) -> OsmRoute | None:
    """The path through ``nodes`` cut at ``cut_m``; None when not drivable."""
    xy = graph.xy[list(nodes)]
    seg = np.hypot(*np.diff(xy, axis=0).T)
    cum = np.r_[0.0, np.cumsum(seg)]
    if cum[-1] > cut_m:
        j = int(np.searchsorted(cum, cut_m))  # the segment (j-1, j) holds the cut
        f = (cut_m - cum[j - 1]) / seg[j - 1]
        end = xy[j - 1] + f * (xy[j] - xy[j - 1])
        xy = np.vstack([xy[:j], end])
        nodes, ways, forward = nodes[: j + 1], ways[:j], forward[:j]
    try:
        turns = np.array([graph.links[n] > 2 for n in nodes[: len(xy)]])
        cap = np.where(turns, JUNCTION_RADIUS_M, 60.0)
        route = PiecewiseRoute.from_polyline(xy, max_radius_m=cap, min_radius_m=MIN_RADIUS_M)
    except ValueError:
        return None
    if _loops_back(route):
        return None
    return OsmRoute(
        nodes=tuple(nodes),
        xy=xy,
        ways=tuple(ways),
        forward=tuple(forward),
        route=route,
        bends=len(route.bend_turns()),
    )


def _loops_back(route: PiecewiseRoute) -> bool:
    """Whether the route passes within :data:`_SELF_CLEAR_M` of itself 80 m further along."""
    s = np.arange(0.0, route.length_m, 5.0)
    xy, _ = route.points(s)
    near = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1)) < _SELF_CLEAR_M
    apart = np.abs(s[:, None] - s[None, :]) > 80.0
    return bool(np.any(near & apart))


def _paths(
    graph: _Graph, anchor: npt.NDArray[np.float64] | None = None, budget: int = _SEARCH_BUDGET
) -> Iterator[tuple[list[int], list[int], list[bool]]]:
    """Simple paths of 100-400 m ending at junctions or dead ends, or cut at 400 m.

    They start from the junctions and dead ends nearest ``anchor`` (default: the extract's
    middle); the search extends at most ``budget`` paths.
    """
    centre = graph.xy.mean(axis=0) if anchor is None else anchor
    ends = np.flatnonzero(graph.links != 2) if np.any(graph.links != 2) else np.arange(1)
    starts = ends[np.argsort(np.hypot(*(graph.xy[ends] - centre).T), kind="stable")]
    for start in starts.tolist():
        stack: list[tuple[list[int], list[int], list[bool], float]] = [([start], [], [], 0.0)]
        while stack and budget > 0:
            nodes, ways, fwd, length = stack.pop()
            here = nodes[-1]
            if length >= ROUTE_SHORTEST_M and (length >= PICK_CUT_M or graph.links[here] != 2):
                yield nodes, ways, fwd
            if length >= PICK_CUT_M:
                continue
            budget -= 1
            for nxt, way, forward in graph.adjacency[here]:
                if nxt in nodes:
                    continue
                if len(nodes) > 1:
                    a = graph.xy[here] - graph.xy[nodes[-2]]
                    b = graph.xy[nxt] - graph.xy[here]
                    cos = float(a @ b) / max(float(np.hypot(*a) * np.hypot(*b)), 1e-12)
                    if cos < math.cos(_MAX_DEFLECTION_RAD):
                        continue
                step = float(np.hypot(*(graph.xy[nxt] - graph.xy[here])))
                stack.append(([*nodes, nxt], [*ways, way], [*fwd, forward], length + step))
        if budget <= 0:
            return


def _best_route(
    graph: _Graph,
    anchor: npt.NDArray[np.float64],
    budget: int,
    avoid: Sequence[OsmRoute] = (),
) -> tuple[OsmRoute | None, int]:
    """The best path near ``anchor`` (see the module's description) and how many were tried.

    Paths that share more than :data:`_MAX_OVERLAP` of their length with a route of ``avoid``,
    or of whose length that much runs along the path, are passed over.
    """
    best: tuple[tuple[float, ...], OsmRoute] | None = None
    seen = 0
    for nodes, ways, fwd in _paths(graph, anchor, budget):
        seen += 1
        cand = _route_of(graph, nodes, ways, fwd, PICK_CUT_M)
        if cand is None or any(_shared(cand, other) > _MAX_OVERLAP for other in avoid):
            continue
        length = cand.route.length_m
        mid, _ = cand.route.points([length / 2.0])
        full = length >= ROUTE_MIN_M - 5.0  # rounding corners shortens a path a little
        key = (
            float(full),
            float(min(cand.bends, 2)) if full else 0.0,
            -round(abs(length - ROUTE_TARGET_M) / 25.0) if full else length,
            float(min(cand.bends, 3)),
            -float(np.hypot(*(mid[0] - anchor))),
        )
        if best is None or key > best[0]:
            best = (key, cand)
    return (None if best is None else best[1]), seen


def _route_notes(route: OsmRoute) -> list[str]:
    length = route.route.length_m
    span = f"{ROUTE_MIN_M:.0f}-{PICK_CUT_M:.0f} m"
    if length < ROUTE_MIN_M - 5.0:
        note = f"no drivable path of {span} here: took the longest, "
        return [note + f"{length:.0f} m with {route.bends} bends"]
    if route.bends < 2:
        return [f"no drivable path of {span} here has two bends; this one has {route.bends}"]
    return []


def _no_route(graph: _Graph, seen: int) -> StageError:
    msg = (
        f"{graph.osm.source} has no drivable path of {ROUTE_SHORTEST_M:.0f} m or more on "
        f"{'/'.join(graph.kinds)} roads with corners of {MIN_RADIUS_M:.0f} m radius or more "
        f"({seen} paths tried); give --route LAT,LON LAT,LON or a larger extract"
    )
    return StageError(msg)


def pick_route(graph: _Graph) -> tuple[OsmRoute, list[str]]:
    """The best demo route of the extract (see the module's description) and notes on it.

    Raises:
        StageError: No drivable path of 100 m or more.
    """
    route, seen = _best_route(graph, graph.xy.mean(axis=0), _SEARCH_BUDGET)
    if route is None:
        raise _no_route(graph, seen)
    return route, [f"route picked among {seen} drivable paths", *_route_notes(route)]


def _overlap(a: OsmRoute, b: OsmRoute) -> float:
    """The share of ``a``'s length within :data:`_DISTINCT_M` of ``b``."""
    pa, _ = a.route.points(np.arange(0.0, a.route.length_m, 5.0))
    pb, _ = b.route.points(np.arange(0.0, b.route.length_m, 5.0))
    near = np.hypot(*(pa[:, None, :] - pb[None, :, :]).transpose(2, 0, 1)).min(axis=1)
    return float(np.mean(near < _DISTINCT_M))


def _shared(a: OsmRoute, b: OsmRoute) -> float:
    """The larger share of either route's length that runs along the other."""
    return max(_overlap(a, b), _overlap(b, a))


def _anchors(graph: _Graph, n: int) -> npt.NDArray[np.float64]:
    """``n`` points spread over the drivable roads: the middle first, then farthest-point."""
    centre = graph.xy.mean(axis=0)
    chosen = [int(np.argmin(np.hypot(*(graph.xy - centre).T)))]
    far = np.hypot(*(graph.xy - graph.xy[chosen[0]]).T)
    for _ in range(n - 1):
        chosen.append(int(np.argmax(far)))
        far = np.minimum(far, np.hypot(*(graph.xy - graph.xy[chosen[-1]]).T))
    return graph.xy[chosen]


def pick_routes(graph: _Graph, count: int) -> list[tuple[OsmRoute, list[str]]]:
    """Up to ``count`` demo routes from different parts of the extract, the best first.

    The first is :func:`pick_route`'s. The others are the best paths near points spread over
    the drivable roads (farthest-point sampling from the middle, three points a route) among
    those with at most :data:`_MAX_OVERLAP` of their length within :data:`_DISTINCT_M` of a
    route already taken (different streets, not one street twice), and at least 150 m long.

    Raises:
        StageError: Not even one drivable path of 100 m or more.
    """
    first, notes = pick_route(graph)
    picked: list[tuple[OsmRoute, list[str]]] = [(first, notes)]
    if count <= 1:
        return picked
    budget = max(_SEARCH_BUDGET // 4, 2_000)
    for anchor in _anchors(graph, 3 * count)[1:]:
        if len(picked) >= count:
            break
        route, seen = _best_route(graph, anchor, budget, [r for r, _ in picked])
        if route is None or route.route.length_m < ROUTE_MIN_M / 2.0:
            continue
        where = graph.frame.to_wgs84(route.xy[:1])
        note = (
            f"route {len(picked) + 1} picked among {seen} drivable paths near "
            f"{float(where.lat_deg[0]):.5f},{float(where.lon_deg[0]):.5f}"
        )
        picked.append((route, [note, *_route_notes(route)]))
    return picked


def _on_roads(osm: OsmData, find: Callable[[_Graph], _T]) -> tuple[_Graph, _T, list[str]]:
    """``find`` on the graph of :data:`DRIVABLE` roads, else on one with :data:`MAIN_ROADS` too.

    The wider graph is tried only where the first has no road or ``find`` finds nothing on it
    (a :class:`StageError` or :class:`ConfigError`) and the extract has main roads; its error,
    which names every road kind tried, is the one raised when that fails too.

    Returns:
        The graph used, what ``find`` returned on it, and a note when it is the wider one.
    """
    try:
        graph = _graph(osm)
        return graph, find(graph), []
    except (StageError, ConfigError):
        if not any(w.tags.get("highway") in MAIN_ROADS for w in osm.ways):
            raise
    graph = _graph(osm, DRIVABLE + MAIN_ROADS)
    found = find(graph)
    note = (
        f"no route on {'/'.join(DRIVABLE)} roads alone: the route may use "
        f"{'/'.join(MAIN_ROADS)} roads too, drawn as the demo's two-lane street"
    )
    return graph, found, [note]


def count_routes(path: Path, wanted: int) -> list[str]:
    """The distinct demo routes of the OSM file ``path``, up to ``wanted``: one line each.

    Their indices are ``osm_demo_world``'s ``pick``.

    Raises:
        StageError: The file cannot be read or holds no drivable path.
    """
    graph, routes, _ = _on_roads(read_osm(Path(path)), lambda g: pick_routes(g, wanted))
    lines = []
    for route, _ in routes:
        ll = graph.frame.to_wgs84(route.xy[[0, -1]])
        lines.append(
            f"{route.route.length_m:.0f} m, {route.bends} bends, from "
            f"{float(ll.lat_deg[0]):.5f},{float(ll.lon_deg[0]):.5f} to "
            f"{float(ll.lat_deg[1]):.5f},{float(ll.lon_deg[1]):.5f}"
        )
    return lines


def _parse_point(text: str) -> tuple[float, float]:
    try:
        lat_s, lon_s = text.split(",")
        lat, lon = float(lat_s), float(lon_s)
    except ValueError:
        msg = f"--route point {text!r} is not LAT,LON (degrees, e.g. 48.1859,11.5510)"
        raise ConfigError(msg) from None
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        msg = f"--route point {text!r} is out of range; give LAT,LON in degrees, latitude first"
        raise ConfigError(msg)
    return lat, lon


def _snap(graph: _Graph, lat: float, lon: float, text: str) -> int:
    """The graph node nearest a point; the point must lie within 30 m of a drivable way."""
    p = graph.frame.from_wgs84([lat], [lon])[0, :2]
    a = np.array([graph.xy[i] for i, nb in enumerate(graph.adjacency) for _ in nb])
    b = np.array([graph.xy[j] for nb in graph.adjacency for j, _, _ in nb])
    if len(a):
        d = b - a
        t = np.clip(np.sum((p - a) * d, axis=1) / np.maximum(np.sum(d * d, axis=1), 1e-12), 0, 1)
        off = float(np.min(np.hypot(*(a + t[:, None] * d - p).T)))
    else:
        off = math.inf
    if off > _ROUTE_SNAP_M:
        msg = (
            f"--route point {text} is {off:.0f} m from the nearest drivable road of "
            f"{graph.osm.source} ({'/'.join(graph.kinds)}); give a point on such a road"
        )
        raise ConfigError(msg)
    return int(np.argmin(np.hypot(*(graph.xy - p).T)))


def route_between(graph: _Graph, first: str, second: str) -> tuple[OsmRoute, list[str]]:
    """The shortest drivable path between two ``LAT,LON`` points (cut at 500 m).

    Raises:
        ConfigError: A point is malformed or off the drivable roads, no path joins them, or the
            path has a corner too sharp to drive.
    """
    src = _snap(graph, *_parse_point(first), first)
    dst = _snap(graph, *_parse_point(second), second)
    dist = {src: 0.0}
    back: dict[int, tuple[int, int, bool]] = {}
    heap = [(0.0, src)]
    while heap:
        d, u = heapq.heappop(heap)
        if u == dst:
            break
        if d > dist.get(u, math.inf):
            continue
        for v, way, forward in graph.adjacency[u]:
            nd = d + float(np.hypot(*(graph.xy[v] - graph.xy[u])))
            if nd < dist.get(v, math.inf):
                dist[v], back[v] = nd, (u, way, forward)
                heapq.heappush(heap, (nd, v))
    if dst not in dist or src == dst:
        msg = f"no drivable path from {first} to {second} in {graph.osm.source}"
        raise ConfigError(msg)
    nodes, ways, fwd = [dst], [], []
    while nodes[-1] != src:
        u, way, forward = back[nodes[-1]]
        nodes.append(u)
        ways.append(way)
        fwd.append(forward)
    nodes.reverse()
    ways.reverse()
    fwd.reverse()
    route = _route_of(graph, nodes, ways, fwd)
    if route is None:
        msg = (
            f"the path from {first} to {second} turns a corner sharper than {MIN_RADIUS_M:.0f} m "
            "radius (not drivable at the demo's speed); choose points on one street"
        )
        raise ConfigError(msg)
    notes = [f"route from {first} to {second}: {dist[dst]:.0f} m of road"]
    if dist[dst] > ROUTE_MAX_M:
        notes.append(f"cut at {ROUTE_MAX_M:.0f} m")
    return route, notes


# -- the street --------------------------------------------------------------------------------


def _parking(tags: Mapping[str, str], side: str) -> bool | None:
    """Whether cars park on ``side`` (of the way's direction); None when the tags do not say."""
    for key in (
        f"parking:lane:{side}",
        "parking:lane:both",
        f"parking:{side}",
        "parking:both",
    ):
        if key in tags:
            return tags[key] not in _NO_PARKING
    return None


def _street(
    graph: _Graph, route: OsmRoute, name: str, title_source: str
) -> tuple[DemoStreet, list[str]]:
    """The demo street along ``route``: cross-section, speed, parking, in the local frame."""
    osm = graph.osm
    seg = np.hypot(*np.diff(route.xy, axis=0).T)
    on_way: dict[int, float] = {}
    for way, length in zip(route.ways, seg, strict=True):
        on_way[way] = on_way.get(way, 0.0) + float(length)
    main = osm.ways[max(on_way, key=on_way.__getitem__)].tags
    notes: list[str] = []
    lanes = _number(main.get("lanes"))
    width = _number(main.get("width"))
    lane_m = 3.5
    if width is not None:
        lane_m = float(np.clip(width / max(lanes or 2.0, 1.0), 3.0, 4.0))
        notes.append(f"lanes {lane_m:.2f} m from width={main['width']} of the main way")
    speed = OSM_SPEED_MPS
    limit = _number(main.get("maxspeed"))
    if limit is not None and "mph" in main.get("maxspeed", ""):
        limit *= 1.609344
    if limit is not None and limit / 3.6 < speed:
        speed = max(limit, 15.0) / 3.6
    markings = main.get("lane_markings") != "no" and (
        "lanes" in main or main.get("highway") in {"tertiary", "secondary", "primary"}
    )
    # Parking: per segment of the path, on the route's left and right.
    scale = route.route.length_m / max(float(seg.sum()), 1e-9)
    cum = np.r_[0.0, np.cumsum(seg)] * scale
    bans: list[tuple[str, float, float]] = []
    tagged = 0
    for j, (way, forward) in enumerate(zip(route.ways, route.forward, strict=True)):
        tags = osm.ways[way].tags
        for route_side in ("left", "right"):
            way_side = route_side if forward else ("right" if route_side == "left" else "left")
            allowed = _parking(tags, way_side)
            tagged += allowed is not None
            if allowed is False:
                bans.append((route_side, float(cum[j]), float(cum[j + 1])))
    for i, node in enumerate(route.nodes[: len(route.xy)]):
        if graph.links[node] > 2:
            s = float(cum[min(i, len(cum) - 1)])
            lo, hi = s - _JUNCTION_CLEAR_M, s + _JUNCTION_CLEAR_M
            bans += [("left", lo, hi), ("right", lo, hi)]
    if tagged:
        notes.append("parking from the ways' parking tags where they have them")
    road = main.get("name", "an unnamed street")
    street = DemoStreet(
        name=name,
        title=(
            f"{road} ({title_source}): {route.route.length_m:.0f} m, {route.bends} bends, "
            f"{speed * 3.6:.0f} km/h"
        ),
        route=route.route.offset(-lane_m / 2.0),  # the right lane's centre
        speed_mps=speed,
        lane_m=lane_m,
        lane_markings=markings,
        no_parking=tuple(_merge(bans)),
        crs=graph.frame.crs,
        origin=graph.frame.origin,
    )
    return street, notes


def _merge(bans: list[tuple[str, float, float]]) -> list[tuple[str, float, float]]:
    out: list[tuple[str, float, float]] = []
    for side in ("left", "right"):
        spans = sorted((lo, hi) for s, lo, hi in bans if s == side)
        for lo, hi in spans:
            if out and out[-1][0] == side and lo <= out[-1][2]:
                out[-1] = (side, out[-1][1], max(out[-1][2], hi))
            else:
                out.append((side, lo, hi))
    return out


def _centre_line(street: DemoStreet) -> npt.NDArray[np.float64]:
    """The street's reference line (between its driving lanes), leads included, every 1 m."""
    s = np.arange(-street.lead_m, street.length_m + street.lead_m + 1e-9, 1.0)
    xy, _ = street.route_points(s, street.lane_m / 2.0)
    return xy


def _buildings(
    graph: _Graph, street: DemoStreet, rng: np.random.Generator
) -> tuple[list[DemoBuilding], int, int]:
    """Real footprints near the street, kept clear of it, and facades where it has none.

    Returns the buildings, how many real ones were kept and how many dropped.
    """
    import shapely  # noqa: PLC0415

    line = shapely.LineString(_centre_line(street))
    half = street.lane_m + street.parking_m + street.sidewalk_m
    corridor = line.buffer(half + 0.5)
    reach = line.buffer(_BUILDING_REACH_M)
    kept: list[DemoBuilding] = []
    polys = []
    dropped = 0
    for b in building_footprints(graph.osm, graph.frame):
        ring = np.asarray(b.xy, dtype=np.float64)
        poly = shapely.make_valid(shapely.Polygon(ring))
        if not poly.intersects(reach):
            continue
        if poly.intersects(corridor):
            dropped += 1
            continue
        levels = max(round(b.height_m / 3.0), 1)
        kept.append(DemoBuilding(xy=tuple((float(x), float(y)) for x, y in ring), levels=levels))
        polys.append(poly)
    real = shapely.union_all(polys) if polys else None
    # Facades where a side of the street has no real building within reach.
    out = list(kept)
    length, depth, setback = 16.0, 10.0, 1.5
    lateral0 = street.lane_m / 2.0
    for sign in (1.0, -1.0):
        lateral = lateral0 + sign * (half + setback + depth / 2.0)
        for s in np.arange(-street.lead_m + 10.0, street.length_m + street.lead_m - 8.0, 21.0):
            if street.route.in_bend([s], 12.0)[0]:
                continue
            c, h = street.route_points([s], lateral)
            facade = footprint_ring(c[0], float(h[0]), length, depth)
            poly = shapely.Polygon(facade)
            near = poly.buffer(_FACADE_GAP_M - depth / 2.0)
            if poly.intersects(corridor) or (real is not None and near.intersects(real)):
                continue
            if any(poly.intersects(shapely.Polygon(o.xy)) for o in out[len(kept) :]):
                continue
            out.append(DemoBuilding(xy=facade, levels=int(rng.integers(2, 6))))
    return out, len(kept), dropped


def _world_name(path: Path, route: Sequence[str] | None, pick: int = 0) -> str:
    digest = hashlib.sha256(path.read_bytes())
    digest.update(repr(tuple(route or ())).encode())
    if pick:  # the first picked route keeps the name it had before routes were numbered
        digest.update(f"pick {pick}".encode())
    stem = path.name.split(".")[0]
    return f"osm-{stem}-{digest.hexdigest()[:8]}"


def osm_demo_world(
    path: Path, *, route: Sequence[str] | None = None, seed: int = 0, pick: int = 0
) -> OsmWorldPlan:
    """The demo world of the real OSM file ``path`` (see the module's description).

    ``route``: two ``"LAT,LON"`` points; None picks a route: the ``pick``-th (from 0) of
    :func:`pick_routes`, routes from different parts of the extract. ``seed`` places the
    parked cars and the plain facades.

    Raises:
        StageError: The file cannot be read, holds no drivable road or no drivable path (or
            fewer than ``pick + 1`` distinct ones).
        ConfigError: ``route`` is malformed, off the roads or not drivable.
    """
    path = Path(path)
    if route is not None and len(route) != 2:
        msg = f"--route takes two points LAT,LON LAT,LON, got {len(route)}"
        raise ConfigError(msg)
    osm = read_osm(path)
    if route:
        graph, (picked, notes), wider = _on_roads(osm, lambda g: route_between(g, *route))
    elif pick:
        graph, routes, wider = _on_roads(osm, lambda g: pick_routes(g, pick + 1))
        if len(routes) <= pick:
            msg = (
                f"{path} has {len(routes)} distinct drivable route(s) for the demo, not "
                f"{pick + 1}; ask for fewer routes of it (routes: {len(routes)})"
            )
            raise StageError(msg)
        picked, notes = routes[pick]
    else:
        graph, (picked, notes), wider = _on_roads(osm, pick_route)
    notes = [*wider, *notes]
    # The local frame: the UTM grid with its origin at the route's start.
    shift = np.round(picked.xy[0])
    frame = replace(
        graph.frame, origin=(graph.frame.origin[0] + shift[0], graph.frame.origin[1] + shift[1])
    )
    graph = replace(graph, frame=frame, xy=graph.xy - shift)
    # The same path moved, cut where it was picked (400 m; 500 between two given points): its
    # nodes run on to the end of the segment that holds the cut.
    kept_m = float(np.hypot(*np.diff(picked.xy, axis=0).T).sum())
    nodes, ways, forward = list(picked.nodes), list(picked.ways), list(picked.forward)
    moved = _route_of(graph, nodes, ways, forward, cut_m=kept_m + 1e-6)
    assert moved is not None  # the same path, moved
    picked = moved
    street, street_notes = _street(graph, picked, _world_name(path, route, pick), path.name)
    rng = np.random.default_rng(seed)
    cars = parked_cars(street, rng)
    buildings, real, dropped = _buildings(graph, street, rng)
    notes += street_notes
    notes.append(
        f"{real} real building footprints kept ({dropped} dropped: the drawn street runs into "
        f"them), {len(buildings) - real} plain facades added"
    )
    # The map stage reads the real extract around the street.
    ll = frame.to_wgs84(_centre_line(street))
    margin_lat = _CROP_MARGIN_M / 111_320.0
    margin_lon = margin_lat / max(math.cos(math.radians(float(ll.lat_deg.mean()))), 0.1)
    box = BBox(
        south=float(ll.lat_deg.min() - margin_lat),
        west=float(ll.lon_deg.min() - margin_lon),
        north=float(ll.lat_deg.max() + margin_lat),
        east=float(ll.lon_deg.max() + margin_lon),
    )
    # Ways run on past an extract's declared bounds with all their nodes; a route that follows
    # them there is mapped by them, so the written extract declares the box around the street.
    extract = replace(osm.crop(box), bounds=box)
    world = DemoWorld(street=street, cars=cars, buildings=tuple(buildings), osm=extract.to_xml())
    return OsmWorldPlan(world=world, route=picked, frame=frame, notes=tuple(notes))
