"""``map_report.json`` and ``map.png``: what the map holds and how well the route fits on it."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path  # noqa: TC003 - pydantic and dataclass field types
from typing import TYPE_CHECKING, Literal

import numpy as np
import pydantic

from cam2sim.core.schema import Artifact
from cam2sim.map.query import DRIVING

if TYPE_CHECKING:
    import numpy.typing as npt
    from matplotlib.artist import Artist

    from cam2sim.map.check import OsmAlignment
    from cam2sim.map.query import RoadMap

__all__ = [
    "ON_LANE_WARN_FRACTION",
    "AlignmentReport",
    "LateralOffset",
    "MapReport",
    "OffMapStretch",
    "RoadCounts",
    "RouteFit",
    "RouteReport",
    "SourceReport",
    "fit_route",
    "plot_map",
    "road_counts",
]

logger = logging.getLogger(__name__)

ON_LANE_WARN_FRACTION = 0.95
_MAX_STRETCHES = 100
_LANE_COLOURS = {
    "driving": "#9e9e9e",
    "parking": "#64b5f6",
    "sidewalk": "#e6cfa8",
    "shoulder": "#c5e1a5",
    "biking": "#ce93d8",
}
_OTHER_COLOUR = "#e0e0e0"


def _num(value: float) -> float | None:
    """JSON has no NaN: map NaN and inf to null."""
    return float(value) if math.isfinite(value) else None


class _Model(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)


class SourceReport(_Model):
    """Where the road data came from: an OSM file or Overpass, the driven path, a user's map."""

    kind: Literal["file", "overpass", "trajectory", "xodr"] = pydantic.Field(
        description="file: --osm; overpass: the Overpass API; trajectory: a road built from the "
        "driven path (dataset/trajectory.csv); xodr: the user's --xodr map"
    )
    path: str | None = pydantic.Field(None, description="the --osm, trajectory or --xodr file")
    url: str | None = pydantic.Field(None, description="the Overpass server")
    query: str | None = pydantic.Field(None, description="the Overpass QL sent")
    from_cache: bool = False
    sha256: str = pydantic.Field(description="of the OSM bytes read (file or answer)")
    nodes: int
    ways: int
    deleted_dropped: int = pydantic.Field(description="JOSM action=delete elements dropped")


class RoadCounts(_Model):
    """What the OpenDRIVE map holds."""

    roads: int = pydantic.Field(description="roads outside junctions")
    connecting_roads: int = pydantic.Field(description="roads inside junctions")
    junctions: int
    lanes_by_type: dict[str, int]
    lane_length_m_by_type: dict[str, float]


class LateralOffset(_Model):
    """Distance of the recorded poses from the nearest driving-lane centre line, metres."""

    mean_m: float | None
    p95_m: float | None
    max_m: float | None


class OffMapStretch(_Model):
    """A run of consecutive poses off every driving lane."""

    start_index: int
    end_index: int = pydantic.Field(description="inclusive")
    start_t_s: float
    end_t_s: float
    length_m: float
    max_offset_m: float | None = pydantic.Field(
        description="largest distance from the nearest driving-lane centre line"
    )


class RouteReport(_Model):
    """How the recorded route lies on the map."""

    poses: int
    length_m: float
    covered_length_m: float = pydantic.Field(
        description="route length between consecutive poses that are both on a driving lane"
    )
    covered_fraction: float | None = pydantic.Field(description="covered_length_m / length_m")
    on_lane_fraction: float | None = pydantic.Field(
        description="fraction of recorded poses on a driving lane"
    )
    against_lane_direction_fraction: float | None = pydantic.Field(
        description=(
            "fraction of on-lane poses outside junctions heading more than 90 degrees against "
            "the nearest driving lane"
        )
    )
    lateral_offset: LateralOffset
    off_map_stretch_count: int
    off_map_stretches: list[OffMapStretch] = pydantic.Field(
        description=f"the first {_MAX_STRETCHES} stretches, in route order"
    )


class AlignmentReport(_Model):
    """OSM nodes of converted roads against the OpenDRIVE lines (see cam2sim.map.check)."""

    nodes: int
    nodes_in_junctions: int
    unmatched: int
    median_m: float | None
    p95_m: float | None
    max_m: float | None
    within_0_5m: float | None
    straight_nodes: int
    straight_max_m: float | None
    rotation_deg: float | None
    scale_error: float | None
    shift_m: float | None

    @classmethod
    def from_alignment(cls, a: OsmAlignment) -> AlignmentReport:
        """Convert the measurement, NaN as null."""
        return cls(
            nodes=a.nodes,
            nodes_in_junctions=a.nodes_in_junctions,
            unmatched=a.unmatched,
            median_m=_num(a.median_m),
            p95_m=_num(a.p95_m),
            max_m=_num(a.max_m),
            within_0_5m=_num(a.within_0_5m),
            straight_nodes=a.straight_nodes,
            straight_max_m=_num(a.straight_max_m),
            rotation_deg=_num(a.rotation_deg),
            scale_error=_num(a.scale_error),
            shift_m=_num(a.shift_m),
        )


class MapReport(Artifact):
    """``WS/map/map_report.json``."""

    proj_string: str | None = pydantic.Field(
        description="the world frame; also the geoReference (null: not geo-referenced)"
    )
    georeferenced: bool = pydantic.Field(
        default=True, description="the map's coordinates can be placed on the Earth"
    )
    box: tuple[float, float, float, float] | None = pydantic.Field(
        description="south, west, north, east (degrees WGS84): route box plus margin; null "
        "when not geo-referenced"
    )
    margin_m: float
    options: dict[str, object] = pydantic.Field(description="conversion options")
    source: SourceReport
    roads: RoadCounts
    route: RouteReport
    osm_alignment: AlignmentReport | None = pydantic.Field(
        description="the map's roads against the OSM ways (null without OSM)"
    )
    warnings: list[str]


# -- route fit ----------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class RouteFit:
    """Per-pose results of fitting the route onto the map.

    Attributes:
        on_lane: ``(N,)`` pose lies on a driving lane.
        offset_m: ``(N,)`` distance to the nearest driving-lane centre line, metres.
        against: ``(N,)`` pose heads more than 90° against its lane.
        report: The summary.
    """

    on_lane: npt.NDArray[np.bool_]
    offset_m: npt.NDArray[np.float64]
    against: npt.NDArray[np.bool_]
    report: RouteReport


def _stretches(
    on_lane: npt.NDArray[np.bool_],
    t: npt.NDArray[np.float64],
    step: npt.NDArray[np.float64],
    offset: npt.NDArray[np.float64],
) -> list[OffMapStretch]:
    off = (~on_lane).astype(np.int8)
    edges = np.diff(np.concatenate([[0], off, [0]]))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1) - 1
    out = []
    for a, b in zip(starts, ends, strict=True):
        length = float(step[a:b].sum()) if b > a else 0.0
        worst = offset[a : b + 1]
        out.append(
            OffMapStretch(
                start_index=int(a),
                end_index=int(b),
                start_t_s=float(t[a]),
                end_t_s=float(t[b]),
                length_m=length,
                max_offset_m=_num(float(worst.max())) if worst.size else None,
            )
        )
    return out


def fit_route(
    road_map: RoadMap,
    xy: npt.ArrayLike,
    t: npt.ArrayLike,
    heading: npt.ArrayLike | None = None,
) -> RouteFit:
    """Fit recorded poses onto the map's driving lanes.

    Args:
        road_map: The map.
        xy: ``(N, 2)`` pose positions, world metres.
        t: ``(N,)`` pose times, seconds.
        heading: ``(N,)`` pose headings, radians (None skips the direction check).

    Returns:
        Per-pose flags and the route summary.
    """
    pts = np.asarray(xy, dtype=np.float64)[:, :2]
    times = np.asarray(t, dtype=np.float64)
    n = pts.shape[0]
    on_lane = road_map.on_lane(pts, DRIVING) if n else np.zeros(0, dtype=bool)
    near = road_map.nearest_lane(pts, DRIVING)
    offset = near.distance
    against = np.zeros(n, dtype=bool)
    if heading is not None and n:
        # Inside junctions the nearest centre line may belong to a crossing turn: skip those.
        off_junction = near.lane >= 0
        off_junction[off_junction] = ~road_map.lane_in_junction[near.lane[off_junction]]
        dh = np.asarray(heading, dtype=np.float64) - near.heading
        dh = np.abs((dh + np.pi) % (2 * np.pi) - np.pi)
        against = on_lane & off_junction & (dh > np.pi / 2)
    step = np.hypot(*np.diff(pts, axis=0).T) if n > 1 else np.zeros(0)
    both = on_lane[:-1] & on_lane[1:] if n > 1 else np.zeros(0, dtype=bool)
    length = float(step.sum())
    covered = float(step[both].sum())
    finite = offset[np.isfinite(offset)]
    stretches = _stretches(on_lane, times, step, offset)
    n_on = int(on_lane.sum())
    report = RouteReport(
        poses=n,
        length_m=length,
        covered_length_m=covered,
        covered_fraction=covered / length if length > 0 else None,
        on_lane_fraction=float(on_lane.mean()) if n else None,
        against_lane_direction_fraction=(
            float(against.sum() / n_on) if n_on and heading is not None else None
        ),
        lateral_offset=LateralOffset(
            mean_m=_num(float(finite.mean())) if finite.size else None,
            p95_m=_num(float(np.percentile(finite, 95))) if finite.size else None,
            max_m=_num(float(finite.max())) if finite.size else None,
        ),
        off_map_stretch_count=len(stretches),
        off_map_stretches=stretches[:_MAX_STRETCHES],
    )
    return RouteFit(on_lane=on_lane, offset_m=offset, against=against, report=report)


def route_warnings(route: RouteReport) -> list[str]:
    """Warnings worth showing for a route fit (empty when the route fits the map)."""
    out = []
    fraction = route.covered_fraction
    if fraction is None:
        fraction = route.on_lane_fraction
    if fraction is not None and fraction < ON_LANE_WARN_FRACTION:
        out.append(
            f"only {fraction:.1%} of the route lies on a driving lane of the map (expected at "
            f"least {ON_LANE_WARN_FRACTION:.0%}); {route.off_map_stretch_count} stretches leave "
            "it. Check map.png: add road types (--road-types, e.g. service,living_street), "
            "widen the lanes (--lane-width), or fix the OSM data"
        )
    against = route.against_lane_direction_fraction
    if against is not None and against > 1.0 - ON_LANE_WARN_FRACTION:
        out.append(
            f"{against:.1%} of the on-lane poses drive against the lane direction; check one-way "
            "tags in the OSM data and the recording's heading convention"
        )
    return out


def road_counts(road_map: RoadMap) -> RoadCounts:
    """Count roads, connecting roads, junctions and lanes by type."""
    roads = road_map.opendrive.roads
    lanes_by_type: dict[str, int] = {}
    for ln in road_map.lanes:
        lanes_by_type[ln.type] = lanes_by_type.get(ln.type, 0) + 1
    return RoadCounts(
        roads=sum(not r.in_junction for r in roads),
        connecting_roads=sum(r.in_junction for r in roads),
        junctions=len(road_map.opendrive.junctions),
        lanes_by_type=dict(sorted(lanes_by_type.items())),
        lane_length_m_by_type={k: round(v, 3) for k, v in road_map.lane_length_by_type().items()},
    )


__all__ += ["route_warnings"]


# -- picture ------------------------------------------------------------------------------------
def plot_map(
    road_map: RoadMap,
    route_xy: npt.ArrayLike,
    on_lane: npt.ArrayLike,
    path: Path,
    *,
    title: str = "",
    margin_m: float = 30.0,
) -> None:
    """Draw lanes by type and the route coloured by on/off lane into a PNG.

    Args:
        road_map: The map.
        route_xy: ``(N, 2)`` route positions, world metres.
        on_lane: ``(N,)`` whether each pose is on a driving lane.
        path: The PNG to write.
        title: Figure title.
        margin_m: View margin around the route, metres.
    """
    from matplotlib.collections import (  # noqa: PLC0415 - heavy, used here only
        LineCollection,
        PolyCollection,
    )
    from matplotlib.figure import Figure  # noqa: PLC0415
    from matplotlib.lines import Line2D  # noqa: PLC0415
    from matplotlib.patches import Patch  # noqa: PLC0415

    xy = np.asarray(route_xy, dtype=np.float64)[:, :2]
    flags = np.asarray(on_lane, dtype=bool)
    if xy.size:
        lo, hi = xy.min(axis=0) - margin_m, xy.max(axis=0) + margin_m
    else:
        pts = np.concatenate([ln.centre for ln in road_map.lanes] or [np.zeros((1, 2))])
        lo, hi = pts.min(axis=0), pts.max(axis=0)
    span = np.maximum(hi - lo, 1.0)
    width_in = 10.0
    height_in = float(np.clip(width_in * span[1] / span[0], 4.0, 16.0))
    fig = Figure(figsize=(width_in, height_in), dpi=110)
    ax = fig.add_subplot()
    handles: list[Artist] = []
    for lane_type in road_map.lane_types:
        polys = []
        for i in road_map.lane_indices(lane_type):
            ln = road_map.lanes[i]
            ring = np.concatenate([ln.left, ln.right[::-1]])
            if (ring.max(axis=0) >= lo).all() and (ring.min(axis=0) <= hi).all():
                polys.append(ring)
        colour = _LANE_COLOURS.get(lane_type, _OTHER_COLOUR)
        ax.add_collection(PolyCollection(polys, facecolors=colour, edgecolors="none", zorder=1))
        handles.append(Patch(color=colour, label=f"{lane_type} lane"))
    centres = [road_map.lanes[i].centre for i in road_map.lane_indices(DRIVING)]
    ax.add_collection(LineCollection(centres, colors="white", linewidths=0.4, zorder=2))
    ax.scatter(xy[flags, 0], xy[flags, 1], s=3, color="#2e7d32", zorder=3)
    ax.scatter(xy[~flags, 0], xy[~flags, 1], s=5, color="#c62828", zorder=4)
    handles += [
        Line2D([], [], color="#2e7d32", marker="o", ls="", label="route on a driving lane"),
        Line2D([], [], color="#c62828", marker="o", ls="", label="route off the map"),
    ]
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x east [m]")
    ax.set_ylabel("y north [m]")
    ax.legend(handles=handles, loc="upper right", fontsize="small")
    if title:
        ax.set_title(title, fontsize="medium")
    fig.tight_layout()
    fig.savefig(path, format="png")
