"""A road built from the driven path: the map when no OSM can be had or the poses have no CRS.

:func:`trajectory_road` smooths the recorded path and writes one OpenDRIVE road along it:

- **Reference line**: the path resampled every ``step_m`` and smoothed with a Gaussian of
  ``smooth_m`` twiced (``2 G - G G``: bends keep their radius; odd reflection at the ends keeps
  the end points and their headings), then
  described as a chain of ``arc`` records every ``segment_m`` (``line`` where straight). Each
  arc's curvature is the smoothed heading change over its length, and its start point is
  integrated exactly from the previous arc (closed form, vectorised), so the line is
  continuous in position and heading (G1) as OpenDRIVE requires;
  :attr:`TrajectoryRoad.fit_m` is its largest distance from the smoothed path.
- **Lanes**: ``lanes`` driving lanes each way of ``lane_width_m``, a sidewalk of
  ``sidewalk_m`` on each side. The recorded car drove in the outermost lane of its direction
  (right-hand traffic: lane -``lanes``; left-hand: +``lanes``, with ``rule="LHT"``), so the
  reference line (the road's centre) lies that far to the left (right) of the smoothed path.
- **Elevation**: the road under the pose point, ``z - pose_height_m``, smoothed like the path,
  one linear ``elevation`` record an arc.
- **Ends**: ``extend_m`` of straight road before the first and after the last pose, so the
  car stands on the road there.
- **Header**: ``<geoReference>`` with the world frame's projection when there is one; else
  none, and the map is local (not geo-referenced).

Pure numpy; the text parses with :func:`cam2sim.map.opendrive.parse_opendrive` and CARLA's
``carla.Map``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal
from xml.sax.saxutils import escape

import numpy as np

from cam2sim.core.errors import ConfigError, StageError
from cam2sim.map.road_room import LaneWidening, RecordedBody, lane_widening

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = ["TrajectoryRoad", "TrajectoryRoadOptions", "smooth_path", "trajectory_road"]

_MIN_LENGTH_M = 10.0
_LINE_CURVATURE = 1e-7  # 1/m: below it an arc record is written as a line (radius > 10,000 km)


@dataclass(frozen=True)
class TrajectoryRoadOptions:
    """How the road along the driven path is laid out.

    Attributes:
        lanes: Driving lanes each way (the recorded car in the outermost of its direction).
        lane_width_m: Width of every driving lane.
        sidewalk_m: Sidewalk on each side (0: none).
        driving_side: ``right`` (right-hand traffic) or ``left``.
        smooth_m: Standard deviation of the Gaussian that smooths the path, metres.
        segment_m: Length of one arc record.
        pose_height_m: Height of the pose point above the road (``vehicle.reference`` z).
        extend_m: Straight road before the first and after the last pose.
        room_m: Where the recorded car's footprint (when given) came closer than this to the
            road's edge, the outermost lane there is widened to leave it this much
            (:mod:`cam2sim.map.road_room`).
    """

    lanes: int = 1
    lane_width_m: float = 3.35
    sidewalk_m: float = 2.0
    driving_side: Literal["right", "left"] = "right"
    smooth_m: float = 2.0
    segment_m: float = 2.0
    pose_height_m: float = 0.0
    extend_m: float = 10.0
    room_m: float = 0.5

    def __post_init__(self) -> None:
        problems = []
        if not 1 <= self.lanes <= 4:
            problems.append(f"lanes={self.lanes} (give 1-4 driving lanes each way)")
        if not (math.isfinite(self.lane_width_m) and 1.5 <= self.lane_width_m <= 6.0):
            problems.append(f"lane width {self.lane_width_m!r} m (give 1.5 to 6.0)")
        if not (math.isfinite(self.sidewalk_m) and 0.0 <= self.sidewalk_m <= 10.0):
            problems.append(f"sidewalk {self.sidewalk_m!r} m (give 0 to 10)")
        if self.driving_side not in ("right", "left"):
            problems.append(f"driving side {self.driving_side!r} (give right or left)")
        if not (0.0 <= self.room_m <= 5.0):
            problems.append(f"room_m={self.room_m} (give 0 to 5)")
        if not (0.0 <= self.extend_m <= 100.0):
            problems.append(f"extend_m={self.extend_m} (give 0 to 100)")
        if not (0.0 <= self.smooth_m <= 50.0 and 0.5 <= self.segment_m <= 50.0):
            problems.append(f"smooth_m={self.smooth_m}, segment_m={self.segment_m}")
        if problems:
            msg = "invalid trajectory road options: " + "; ".join(problems)
            raise ConfigError(msg)


@dataclass(frozen=True)
class TrajectoryRoad:
    """The road along the driven path.

    Attributes:
        xodr: The OpenDRIVE text.
        length_m: Length of the reference line.
        fit_m: Largest distance between the arc chain's nodes and the smoothed path (after
            the centre offset is taken off), metres.
        smoothing_m: Largest distance the smoothing moved a point of the path, metres.
        centre_xy: ``(N, 2)`` the reference line (road centre) at the arcs' starts and end.
        widened_m: The most an outermost lane was widened for the recorded car's sweep.
        widened_length_m: Length of road with a widened lane.
    """

    xodr: str
    length_m: float
    fit_m: float
    smoothing_m: float
    centre_xy: npt.NDArray[np.float64]
    widened_m: float = 0.0
    widened_length_m: float = 0.0


def smooth_path(
    xyz: npt.ArrayLike, *, step_m: float = 1.0, smooth_m: float = 2.0
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """The driven path resampled every ``step_m`` along its length and smoothed.

    Standstills (repeated positions) fall out in the resampling. Returns ``(s, xyz)``: the
    stations and the smoothed ``(M, 3)`` points.

    Raises:
        StageError: Fewer than 10 m driven.
    """
    pts = np.asarray(xyz, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] < 2 or not np.all(np.isfinite(pts[:, :2])):
        msg = "the trajectory holds no finite positions; re-import or re-extract the poses"
        raise StageError(msg)
    if pts.shape[1] == 2:
        pts = np.column_stack([pts, np.zeros(len(pts))])
    step = np.hypot(*np.diff(pts[:, :2], axis=0).T) if len(pts) > 1 else np.zeros(0)
    dist = np.concatenate([[0.0], np.cumsum(step)])
    _require_length(float(dist[-1]))
    moved = np.concatenate([[True], step > 1e-6])
    dist, pts = dist[moved], pts[moved]
    n = max(math.ceil(dist[-1] / step_m), 2)
    s = np.linspace(0.0, dist[-1], n + 1)
    res = np.column_stack([np.interp(s, dist, pts[:, k]) for k in range(3)])
    return (s, res) if smooth_m <= 0 else _smoothed(res, smooth_m / (s[1] - s[0]))


def _smoothed(
    res: npt.NDArray[np.float64], sigma: float
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Evenly resampled points smoothed by a Gaussian of ``sigma`` samples; new stations.

    A Gaussian alone pulls a bend towards its centre: a turn of radius ``R`` shrinks by about
    ``sigma**2 / (2 R)`` (0.33 m for a 6 m U-turn at 2 m), so the road would lie inside the
    path the car drove, its outer lane that much narrower where the car needs it most. The
    smoother is therefore Tukey's twicing, ``2 G(p) - G(G(p))``: the Gaussian's response
    ``H`` becomes ``1 - (1 - H)**2``, so the bend keeps its radius (0.02 m shrink for that
    U-turn) while position noise of a few metres' wavelength is removed as before.
    """
    half = math.ceil(3 * sigma)
    if half > len(res) - 1:  # a path shorter than the kernel: left as it is
        ds = np.hypot(*np.diff(res[:, :2], axis=0).T)
        return np.concatenate([[0.0], np.cumsum(ds)]), res
    kernel = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma) ** 2)
    kernel /= kernel.sum()
    once = _gaussian(res, kernel, half)
    out = 2.0 * once - _gaussian(once, kernel, half)
    # Re-measure the stations along the smoothed line.
    ds = np.hypot(*np.diff(out[:, :2], axis=0).T)
    return np.concatenate([[0.0], np.cumsum(ds)]), out


def _gaussian(
    res: npt.NDArray[np.float64], kernel: npt.NDArray[np.float64], half: int
) -> npt.NDArray[np.float64]:
    """``res`` convolved with ``kernel`` (``2 half + 1`` taps), oddly reflected at its ends.

    Odd reflection about the end points: a straight end stays straight and ends where it did.
    """
    head = 2 * res[0] - res[half:0:-1]
    tail = 2 * res[-1] - res[-2 : -half - 2 : -1]
    padded = np.concatenate([head, res, tail])
    return np.column_stack(
        [np.convolve(padded[:, k], kernel, mode="same")[half : half + len(res)] for k in range(3)]
    )


def _require_length(driven_m: float) -> None:
    if driven_m < _MIN_LENGTH_M:
        msg = (
            f"the recorded car drove only {driven_m:.1f} m; a road from the driven path needs "
            f"at least {_MIN_LENGTH_M:.0f} m (give an OSM file with --osm or a map with --xodr)"
        )
        raise StageError(msg)


def trajectory_road(
    xyz: npt.ArrayLike,
    options: TrajectoryRoadOptions | None = None,
    *,
    proj_string: str | None = None,
    name: str = "recorded route",
    body: RecordedBody | None = None,
) -> TrajectoryRoad:
    """One OpenDRIVE road along the driven path ``xyz`` (world frame, ``(N, 2|3)``).

    Args:
        xyz: The recorded positions in driving order.
        options: Lanes, widths, smoothing.
        body: The recorded car, placed at each position on the smoothed path (with its
            recorded heading, else along the path): the outermost lanes widen where it swept
            near the edge (``options.room_m``).
        proj_string: The world frame's projection, written as ``<geoReference>``; None for a
            local map.
        name: The road's name.

    Raises:
        StageError: The path is shorter than 10 m or not finite.
    """
    opts = options or TrajectoryRoadOptions()
    raw = np.asarray(xyz, dtype=np.float64)
    smooth_path(raw, smooth_m=0.0)  # the checks on the recorded path itself
    ds, unsmoothed = smooth_path(_extended(raw, opts.extend_m), smooth_m=0.0)
    s, path = (
        _smoothed(unsmoothed, opts.smooth_m / (ds[1] - ds[0]))
        if opts.smooth_m > 0
        else (ds, unsmoothed)
    )
    smoothing = float(np.max(np.hypot(*(unsmoothed[:, :2] - path[:, :2]).T)))
    tangent = np.gradient(path[:, :2], s, axis=0)
    heading = np.unwrap(np.arctan2(tangent[:, 1], tangent[:, 0]))
    # The arcs' nodes: every segment_m, and the end.
    count = max(round(s[-1] / opts.segment_m), 1)
    node_s = np.linspace(0.0, s[-1], count + 1)
    node_h = np.interp(node_s, s, heading)
    node_xy = np.column_stack([np.interp(node_s, s, path[:, k]) for k in range(2)])
    node_z = np.interp(node_s, s, path[:, 2]) - opts.pose_height_m
    length = np.diff(node_s)
    turn = np.diff(node_h)
    curvature = turn / length
    # Exact arc chain from the first node: chord = L sinc(turn / 2), along h + turn / 2.
    chord = length * np.sinc(turn / (2 * np.pi))
    mid = node_h[:-1] + turn / 2
    steps = np.column_stack([chord * np.cos(mid), chord * np.sin(mid)])
    chain = node_xy[0] + np.concatenate([[[0.0, 0.0]], np.cumsum(steps, axis=0)])
    # The road's centre: the car in the outermost lane of its direction.
    side = 1.0 if opts.driving_side == "right" else -1.0
    shift = side * opts.lane_width_m * (opts.lanes - 0.5)
    normal = np.column_stack([-np.sin(node_h), np.cos(node_h)])  # left of the heading
    centre = chain + shift * normal
    # An arc chain offset sideways by a constant stays an arc chain (radius r - shift).
    centre_curv = curvature / (1.0 - shift * curvature)
    centre_len = length * (1.0 - shift * curvature)
    if np.any(centre_len <= 0):
        msg = (
            f"the driven path turns tighter than the road is wide ({shift:.1f} m from the "
            "car to the road's centre); give fewer --lanes or a narrower lane width"
        )
        raise StageError(msg)
    fit = float(np.max(np.hypot(*(chain - node_xy).T)))
    widening = (
        None if body is None else _widening(raw, body, opts, (s, path, heading), node_s, ds[-1])
    )
    xodr = _xodr_text(
        name, _Chain(centre, node_h, centre_curv, centre_len, node_z), opts, proj_string, widening
    )
    widened = 0.0 if widening is None else widening.widest_m
    wide = (
        np.zeros(len(centre_len), dtype=bool)
        if widening is None
        else (np.maximum(widening.right_m, widening.left_m)[:-1] > 0.01)
    )
    return TrajectoryRoad(
        xodr=xodr,
        length_m=float(centre_len.sum()),
        fit_m=fit,
        smoothing_m=smoothing,
        centre_xy=centre,
        widened_m=widened,
        widened_length_m=float(centre_len[wide].sum()),
    )


def _widening(
    raw: npt.NDArray[np.float64],
    body: RecordedBody,
    opts: TrajectoryRoadOptions,
    smoothed: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]],
    node_s: npt.NDArray[np.float64],
    extended_m: float,
) -> LaneWidening:
    """How much the outermost lanes widen at the arcs' nodes for the recorded car's sweep.

    The car stands on the smoothed path at each pose's station (position noise is not a
    sweep), turned as recorded or along the path.
    """
    s, path, heading = smoothed
    # Each pose's station: along the recorded path, after the extension, scaled onto the
    # smoothed path.
    step = np.hypot(*np.diff(raw[:, :2], axis=0).T)
    station = np.concatenate([[0.0], np.cumsum(step)]) + (opts.extend_m if len(raw) > 1 else 0.0)
    station *= s[-1] / extended_m if extended_m > 0 else 1.0
    point = np.column_stack([np.interp(station, s, path[:, k]) for k in range(2)])
    turned = (
        np.interp(station, s, heading)
        if body.heading is None
        else np.asarray(body.heading, dtype=np.float64).reshape(-1)
    )
    corners = body.corners(point, turned)
    w, n = opts.lane_width_m, opts.lanes
    far = (2 * n - 0.5) * w  # the road's other edge, beyond the lanes of both directions
    band = (-w / 2, far) if opts.driving_side == "right" else (-far, w / 2)
    return lane_widening(
        s, path[:, :2], heading, corners.reshape(-1, 2),
        np.repeat(station, corners.shape[1]), band=band, stations=node_s, room_m=opts.room_m,
        hold_m=float(np.max(np.diff(node_s), initial=0.0)),
    )  # fmt: skip


def _extended(xyz: npt.NDArray[np.float64], extend_m: float) -> npt.NDArray[np.float64]:
    """The path with ``extend_m`` of straight road before its start and after its end.

    The directions are those of the first and last 10 m driven (their principal axes), so the
    car at the first and last pose stands on the road, not at its edge.
    """
    if extend_m <= 0 or len(xyz) < 2 or not np.all(np.isfinite(xyz[:, :2])):
        return xyz
    if xyz.shape[1] == 2:
        xyz = np.column_stack([xyz, np.zeros(len(xyz))])
    dist = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xyz[:, :2], axis=0).T))])
    if dist[-1] <= 0:
        return xyz
    reach = min(10.0, float(dist[-1]))
    first = _direction(xyz[dist <= reach, :2])
    last = _direction(xyz[dist >= dist[-1] - reach, :2])
    k = np.arange(1, math.ceil(extend_m) + 1)[:, None] * (extend_m / math.ceil(extend_m))
    before = xyz[0] - k[::-1] * np.append(first, 0.0)
    after = xyz[-1] + k * np.append(last, 0.0)
    return np.concatenate([before, xyz, after])


def _direction(xy: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Unit direction of travel along points (their principal axis, first to last)."""
    centred = xy - xy.mean(axis=0)
    axis: npt.NDArray[np.float64] = np.linalg.svd(centred, full_matrices=False)[2][0]
    return axis if float(np.dot(xy[-1] - xy[0], axis)) >= 0 else -axis


@dataclass(frozen=True, eq=False)
class _Chain:
    """The reference line's arcs.

    Start points and headings (K + 1), curvatures and lengths (K), and the ground's height at
    the nodes (K + 1).
    """

    centre: npt.NDArray[np.float64]
    heading: npt.NDArray[np.float64]
    curvature: npt.NDArray[np.float64]
    length: npt.NDArray[np.float64]
    ground_z: npt.NDArray[np.float64]


def _xodr_text(
    name: str,
    chain: _Chain,
    opts: TrajectoryRoadOptions,
    proj_string: str | None,
    widening: LaneWidening | None = None,
) -> str:
    centre, heading, curvature = chain.centre, chain.heading, chain.curvature
    length, ground_z = chain.length, chain.ground_z
    starts = np.concatenate([[0.0], np.cumsum(length)])
    total = float(starts[-1])
    # A straight stretch is a line: CARLA's arc divides by its curvature (NaN at zero).
    shapes = [
        "<line/>" if abs(k) < _LINE_CURVATURE else f'<arc curvature="{k:.9e}"/>' for k in curvature
    ]
    geometry = "\n".join(
        f'      <geometry s="{s0:.6f}" x="{x:.6f}" y="{y:.6f}" hdg="{h:.9f}" '
        f'length="{ln:.6f}">{shape}</geometry>'
        for s0, (x, y), h, ln, shape in zip(
            starts[:-1], centre[:-1], heading[:-1], length, shapes, strict=True
        )
    )
    grade = np.diff(ground_z) / length
    elevation = "\n".join(
        f'      <elevation s="{s0:.6f}" a="{z:.6f}" b="{g:.9f}" c="0" d="0"/>'
        for s0, z, g in zip(starts[:-1], ground_z[:-1], grade, strict=True)
    )
    lanes = _lane_section(opts, None if widening is None else (starts, widening))
    geo = f"    <geoReference><![CDATA[{proj_string}]]></geoReference>\n" if proj_string else ""
    xs, ys = centre[:, 0], centre[:, 1]
    rule = ' rule="LHT"' if opts.driving_side == "left" else ""
    return (
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        "<OpenDRIVE>\n"
        f'  <header revMajor="1" revMinor="4" name="{escape(name)}" version="1" '
        f'north="{ys.max():.3f}" south="{ys.min():.3f}" east="{xs.max():.3f}" '
        f'west="{xs.min():.3f}" vendor="cam2sim (from the driven path)">\n'
        f"{geo}"
        "  </header>\n"
        f'  <road name="{escape(name)}" length="{total:.6f}" id="1" junction="-1"{rule}>\n'
        "    <link/>\n"
        '    <type s="0" type="town"><speed max="50" unit="km/h"/></type>\n'
        f"    <planView>\n{geometry}\n    </planView>\n"
        f"    <elevationProfile>\n{elevation}\n    </elevationProfile>\n"
        "    <lateralProfile/>\n"
        "    <lanes>\n"
        '      <laneOffset s="0" a="0" b="0" c="0" d="0"/>\n'
        f"{lanes}"
        "    </lanes>\n"
        "  </road>\n"
        "</OpenDRIVE>\n"
    )


def _lane(lane_id: int, kind: str, width: float | str, mark: str) -> str:
    """A lane of constant ``width``, or of the ``<width>`` records ``width`` holds."""
    records = (
        f'            <width sOffset="0" a="{width:.3f}" b="0" c="0" d="0"/>\n'
        if isinstance(width, float)
        else width
    )
    return (
        f'          <lane id="{lane_id}" type="{kind}" level="false">\n'
        "            <link/>\n"
        f"{records}"
        f'            <roadMark sOffset="0" type="{mark}" weight="standard" color="standard" '
        'width="0.15"/>\n'
        "          </lane>\n"
    )


def _widened(base: float, starts: npt.NDArray[np.float64], extra: npt.NDArray[np.float64]) -> str:
    """``<width>`` records of a lane ``base`` wide plus ``extra`` at the nodes ``starts``.

    Linear from node to node; runs without widening merge into one constant record.
    """
    width = base + np.asarray(extra, dtype=np.float64)
    slope = np.diff(width) / np.diff(starts)
    out = []
    for k in range(len(starts) - 1):  # one record a changing arc; the lane section is short
        flat = abs(slope[k]) < 1e-9
        if k and flat and abs(slope[k - 1]) < 1e-9 and abs(width[k] - width[k - 1]) < 1e-9:
            continue
        out.append(
            f'            <width sOffset="{starts[k]:.6f}" a="{width[k]:.4f}" '
            f'b="{slope[k]:.9f}" c="0" d="0"/>\n'
        )
    return "".join(out)


def _lane_section(
    opts: TrajectoryRoadOptions,
    widening: tuple[npt.NDArray[np.float64], LaneWidening] | None = None,
) -> str:
    def width(lane_id: int) -> float | str:
        if widening is None or abs(lane_id) != opts.lanes:
            return opts.lane_width_m
        starts, extra = widening
        side = extra.left_m if lane_id > 0 else extra.right_m
        if not np.any(side > 0.0):
            return opts.lane_width_m
        return _widened(opts.lane_width_m, starts, side)

    def side(sign: int) -> str:
        ids = [sign * k for k in range(1, opts.lanes + 1)]
        body = [_lane(i, "driving", width(i), "broken") for i in ids]
        if opts.sidewalk_m > 0:
            body.append(_lane(sign * (opts.lanes + 1), "sidewalk", opts.sidewalk_m, "solid"))
        if sign > 0:
            body.reverse()  # left lanes are listed outermost first
        return "".join(body)

    centre = (
        '          <lane id="0" type="none" level="false">\n'
        '            <roadMark sOffset="0" type="solid" weight="standard" color="standard" '
        'width="0.15"/>\n'
        "          </lane>\n"
    )
    return (
        '      <laneSection s="0">\n'
        f"        <left>\n{side(1)}        </left>\n"
        f"        <center>\n{centre}        </center>\n"
        f"        <right>\n{side(-1)}        </right>\n"
        "      </laneSection>\n"
    )
