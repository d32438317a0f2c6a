"""The geometric LiDAR detector: ground removal, clustering and oriented box fitting, no weights.

One scan in the LiDAR link frame becomes :class:`~cam2sim.detect.boxes.Boxes` of parked cars and
vans in five vectorised steps:

1. **Ground.** The lowest return of every ``ground_cell_m`` cell is ground when it lies close
   to the slope-limited lower envelope of all cells (a chamfer distance transform: no cell may
   rise more than ``ground_max_slope`` per metre from another), so sloped streets and kerbs stay
   ground while car roofs, walls and crowns, which rise steeply from the road beside them, do
   not. Other cells are filled from the ground cells around them. Each point's height above
   the ground is read bilinearly from this grid: there is no global height threshold.
2. **Clusters.** Returns ``band_m`` above the ground are binned into a ``cluster_cell_m``
   occupancy grid, dilated to bridge gaps up to ``cluster_gap_m`` and labelled into connected
   components (:func:`scipy.ndimage.label`). Only returns below ``cluster_top_m`` connect
   cells, so tree crowns above parked cars do not chain them together.
3. **Cheap rejections** over all clusters at once (few points, tiny footprint, top too low,
   no return near the ground as for crowns, cut by the range limit); clusters longer or wider
   than a car (a row of parked cars seen at a grazing angle) are cut at their widest gaps, and
   pieces without such a gap (walls) are dropped.
4. **Box fitting**, one cluster at a time over a voxel-thinned copy of its points: the L-shape
   closeness criterion of Zhang et al. (2017) is evaluated for every candidate angle at once.
   The sensor origin decides which faces were seen. A dimension measured on a seen face is
   kept; one that only a single face shows (a car seen from its side, or from its end) grows to
   the prior size *away* from the sensor, and so does a length too short for a car. A corner
   of a partly hidden car that fits either way round is dropped.
5. **Scoring and filters**: plausible length, width and top height (the top may lie one beam
   gap below the roof at long range); a score in ``[0, 1]`` from the share of the low returns
   that lie on the seen faces (squared), the plausibility of the size and the number of
   returns; overlapping boxes keep the best.

The detector assumes z up but nothing about the forward axis: it works the same for a LiDAR
with x forward (ROS) or y forward (nuScenes ``LIDAR_TOP``). On the nuScenes sweep in
``benchmarks/detect_nuscenes.py`` it finds the clearly visible cars with no false positive;
see that script for the protocol.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from cam2sim.detect.boxes import Boxes

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = ["GeometricDetector", "GeometricOptions"]

_EMPTY = np.inf


@dataclass(frozen=True)
class GeometricOptions:
    """Parameters of :class:`GeometricDetector` (lengths in metres, angles in degrees).

    Attributes:
        min_range_m: Returns closer than this (horizontal distance) are dropped: they are the
            ego vehicle's own body (nuScenes' ego returns lie within 2 m). Default 2.0.
        max_range_m: Returns farther than this are dropped, and clusters reaching it are not
            reported (their size is unknown); cars beyond have too few points. Default 40.
        ground_cell_m: Cell size of the ground height grid. Default 1.0.
        ground_max_slope: Steepest ground slope (rise over run) the ground may have between
            cells; steeper rises are objects. Default 0.12.
        ground_tolerance_m: A cell's lowest return may lie this far above the slope-limited
            envelope of its neighbours and still be ground (kerbs, noise). Default 0.15.
        ground_reach_m: How far the slope limit propagates; objects wider than twice this
            with no ground return around them are taken as ground. Default 20.
        band_m: ``(low, high)`` heights above the ground of the returns kept for clustering and
            measuring; ``low`` clears kerbs and road noise, ``high`` lets walls show they are
            too tall. Default (0.25, 3.0).
        cluster_top_m: Returns above this height are measured but do not join cells into
            clusters. Default 2.0.
        cluster_cell_m: Cell size of the clustering occupancy grid. Default 0.25.
        cluster_gap_m: Occupied cells closer than this join one cluster. Default 0.5.
        split_gap_m: Clusters longer than a car are cut at gaps at least this wide along
            their main axis. Default 0.3.
        fit_cell_m: Cluster points are thinned to one per cell of this size before fitting.
            Default 0.1.
        angle_step_deg: Step of the L-shape angle search over [0, 90). Default 1.0.
        min_points: Fewest returns in a cluster. Default 8.
        length_m: ``(min, max)`` box length. Default (2.6, 6.5).
        width_m: ``(min, max)`` box width. Default (1.3, 2.6).
        height_m: ``(min, max)`` top of the box above the ground. The highest return may lie
            up to one beam gap below the roof, so the minimum drops by the gap at the
            cluster's range. Default (1.3, 2.6).
        max_bottom_m: The lowest return of a cluster must be at most this high above the
            ground plus one beam gap (rejects tree crowns and overhangs). Default 0.7.
        beam_spacing_deg: Vertical angle between neighbouring beams near the horizon; the
            beam gap at range ``r`` is ``r * tan(beam_spacing_deg)``. Default 1.33 (Velodyne
            HDL-32E, as on nuScenes; a VLP-16 has 2.0, 64-beam sensors about 0.4).
        prior_size_m: ``(length, width)`` a partial view is extended to. Default (4.5, 1.8).
        typical_length_m: ``(low, high)`` lengths that score full marks. A length below
            ``low`` seen from beyond one end is taken as cut off (occluded or too sparse) and
            grows to the prior, away from the sensor. Default (3.5, 5.3).
        typical_width_m: ``(low, high)`` widths that score full marks. Default (1.6, 2.1).
        face_tolerance_m: A point within this distance of a visible face counts as on it.
            Default 0.15.
        min_view_angle_deg: A face counts as seen (and the box may be extended away from it)
            only when the line of sight meets it at least this far from grazing. Default 5.
        end_views: Also report clusters that only show a car's end (front or back): their
            length is then the prior, extended away from the sensor. Default True.
        min_score: Boxes scoring below this are dropped. Default 0.3.
        sigma_base_m: Centre standard deviation of a fully seen box near the sensor. Default
            0.1.
        sigma_per_m: Growth of the centre standard deviation per metre of range. Default 0.005.
        structure_slab_m: Height of the slab just above the clustering band searched for
            returns that continue upwards (walls, fences, poles, building fronts; no car
            reaches there). Default 1.5.
        structure_fraction: A cluster piece whose footprint has returns in that slab above more
            than this share of its points is a structure, not a car. Tree crowns lower than
            the slab top over a parked car can hide it. Default 0.3.
    """

    min_range_m: float = 2.0
    max_range_m: float = 40.0
    ground_cell_m: float = 1.0
    ground_max_slope: float = 0.12
    ground_tolerance_m: float = 0.15
    ground_reach_m: float = 20.0
    band_m: tuple[float, float] = (0.25, 3.0)
    cluster_top_m: float = 2.0
    cluster_cell_m: float = 0.25
    cluster_gap_m: float = 0.5
    split_gap_m: float = 0.3
    fit_cell_m: float = 0.1
    angle_step_deg: float = 1.0
    min_points: int = 8
    length_m: tuple[float, float] = (2.6, 6.5)
    width_m: tuple[float, float] = (1.3, 2.6)
    height_m: tuple[float, float] = (1.3, 2.6)
    max_bottom_m: float = 0.7
    beam_spacing_deg: float = 1.33
    prior_size_m: tuple[float, float] = (4.5, 1.8)
    typical_length_m: tuple[float, float] = (3.5, 5.3)
    typical_width_m: tuple[float, float] = (1.6, 2.1)
    face_tolerance_m: float = 0.15
    min_view_angle_deg: float = 5.0
    end_views: bool = True
    min_score: float = 0.3
    sigma_base_m: float = 0.1
    sigma_per_m: float = 0.005
    structure_slab_m: float = 1.5
    structure_fraction: float = 0.3


@dataclass(frozen=True)
class _Grid:
    """A square grid centred on the sensor: ``n x n`` cells of ``cell`` metres."""

    cell: float
    n: int

    @classmethod
    def covering(cls, radius: float, cell: float) -> _Grid:
        return cls(cell, 2 * math.ceil(radius / cell) + 2)

    @property
    def origin(self) -> float:
        """Coordinate of the lower edge of cell 0 (both axes), metres."""
        return -0.5 * self.n * self.cell

    def index(self, xy: npt.NDArray[np.float64]) -> npt.NDArray[np.int64]:
        """``(N, 2)`` cell indices of ``(N, 2)`` positions, clipped into the grid."""
        idx = np.floor((xy - self.origin) / self.cell).astype(np.int64)
        return np.clip(idx, 0, self.n - 1)

    def bilinear(
        self, values: npt.NDArray[np.float64], xy: npt.NDArray[np.float64]
    ) -> npt.NDArray[np.float64]:
        """Interpolate ``(n, n)`` cell-centre ``values`` at ``(N, 2)`` positions."""
        u = (xy - self.origin) / self.cell - 0.5
        i0 = np.clip(np.floor(u).astype(np.int64), 0, self.n - 2)
        f = np.clip(u - i0, 0.0, 1.0)
        flat = values.ravel()
        k = i0[:, 0] * self.n + i0[:, 1]
        fx, fy = f[:, 0], f[:, 1]
        low = flat[k] + fy * (flat[k + 1] - flat[k])
        high = flat[k + self.n] + fy * (flat[k + self.n + 1] - flat[k + self.n])
        out: npt.NDArray[np.float64] = low + fx * (high - low)
        return out


def _ground_heights(
    xy: npt.NDArray[np.float64], z: npt.NDArray[np.float64], grid: _Grid, opts: GeometricOptions
) -> npt.NDArray[np.float64]:
    """``(n, n)`` ground height per cell centre (metres) from the returns ``xy``, ``z``.

    The lowest return per cell is ground where it lies at most ``ground_tolerance_m`` above
    the slope-limited lower envelope ``min_c' low(c') + ground_max_slope * |c - c'|`` (a
    chamfer distance over ``ground_reach_m``): roofs, walls and crowns rise too steeply from
    the ground around them. Other cells take the mean of the ground cells within 3x3, else
    7x7, else the nearest one.
    """
    from scipy import ndimage  # noqa: PLC0415

    n, cell = grid.n, grid.cell
    idx = grid.index(xy)
    flat = np.full(n * n, _EMPTY)
    np.minimum.at(flat, idx[:, 0] * n + idx[:, 1], z)
    low = flat.reshape(n, n)
    has = np.isfinite(low)
    cross = np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]], dtype=bool)
    rise = opts.ground_max_slope * cell
    envelope = low.copy()
    for _ in range(math.ceil(opts.ground_reach_m / cell)):  # chamfer steps, each over the grid
        step = np.minimum(
            ndimage.minimum_filter(envelope, footprint=cross, mode="nearest") + rise,
            ndimage.minimum_filter(envelope, footprint=~cross, mode="nearest")
            + rise * math.sqrt(2),
        )
        if not np.any(step < envelope):
            break
        envelope = np.minimum(envelope, step)
    ground = has & (low <= envelope + opts.ground_tolerance_m)
    if not ground.any():
        return np.full((n, n), float(np.min(z)))
    weight = ground.astype(np.float64)
    value = np.where(ground, low, 0.0)
    out = np.where(ground, low, np.nan)
    for size in (3, 7):
        w = ndimage.uniform_filter(weight, size=size, mode="constant")
        v = ndimage.uniform_filter(value, size=size, mode="constant")
        fill = np.isnan(out) & (w > 1e-9)
        out[fill] = v[fill] / w[fill]
    missing = np.isnan(out)
    if missing.any():
        nearest = ndimage.distance_transform_edt(
            missing, return_distances=False, return_indices=True
        )
        out = out[tuple(nearest)]
    result: npt.NDArray[np.float64] = out
    return result


@dataclass(frozen=True, eq=False)
class _Clusters:
    """Band returns grouped by cluster, sorted by label.

    Attributes:
        xy: ``(M, 2)`` positions, metres, link frame.
        h: ``(M,)`` heights above the ground, metres.
        starts: ``(K + 1,)`` offsets of each cluster's rows in ``xy`` and ``h``.
    """

    xy: npt.NDArray[np.float64]
    h: npt.NDArray[np.float64]
    starts: npt.NDArray[np.int64]


def _clusters(
    xy: npt.NDArray[np.float64], h: npt.NDArray[np.float64], opts: GeometricOptions
) -> _Clusters:
    """Connected components of the occupied cells of the band returns (see the module doc)."""
    from scipy import ndimage  # noqa: PLC0415

    grid = _Grid.covering(opts.max_range_m, opts.cluster_cell_m)
    idx = grid.index(xy)
    occupied = np.zeros((grid.n, grid.n), dtype=bool)
    connect = h <= opts.cluster_top_m
    occupied[idx[connect, 0], idx[connect, 1]] = True
    reach = math.ceil(opts.cluster_gap_m / opts.cluster_cell_m / 2.0)
    if reach > 0:
        occupied = ndimage.binary_dilation(occupied, iterations=reach)
    labels, _ = ndimage.label(occupied, structure=np.ones((3, 3), dtype=bool))
    lab = labels[idx[:, 0], idx[:, 1]]
    order = np.argsort(lab, kind="stable")
    lab = lab[order]
    first = int(np.searchsorted(lab, 1))
    order, lab = order[first:], lab[first:]
    if lab.size == 0:
        return _Clusters(xy[:0], h[:0], np.zeros(1, dtype=np.int64))
    cuts = np.flatnonzero(np.diff(lab)) + 1
    starts = np.concatenate([[0], cuts, [lab.size]]).astype(np.int64)
    return _Clusters(xy[order], h[order], starts)


def _tall_cells(
    xy: npt.NDArray[np.float64], h: npt.NDArray[np.float64], opts: GeometricOptions
) -> npt.NDArray[np.bool_]:
    """Clustering-grid cells (grown by one cell) with returns in the slab above the band."""
    from scipy import ndimage  # noqa: PLC0415

    grid = _Grid.covering(opts.max_range_m, opts.cluster_cell_m)
    top = opts.band_m[1]
    slab = (h > top) & (h <= top + opts.structure_slab_m)
    idx = grid.index(xy[slab])
    tall = np.zeros((grid.n, grid.n), dtype=bool)
    tall[idx[:, 0], idx[:, 1]] = True
    grown: npt.NDArray[np.bool_] = ndimage.binary_dilation(tall, iterations=1)
    return grown


def _gap_per_m(opts: GeometricOptions) -> float:
    """Vertical gap between neighbouring beams per metre of range."""
    return math.tan(math.radians(opts.beam_spacing_deg))


def _prefilter(c: _Clusters, opts: GeometricOptions) -> npt.NDArray[np.int64]:
    """Indices of the clusters worth a box fit (cheap tests over all clusters at once)."""
    if c.starts.size < 2:
        return np.zeros(0, dtype=np.int64)
    s = c.starts[:-1]
    count = np.diff(c.starts)
    span_x = np.maximum.reduceat(c.xy[:, 0], s) - np.minimum.reduceat(c.xy[:, 0], s)
    span_y = np.maximum.reduceat(c.xy[:, 1], s) - np.minimum.reduceat(c.xy[:, 1], s)
    diagonal = np.hypot(span_x, span_y)  # long clusters are split later, not dropped
    top = np.maximum.reduceat(c.h, s)
    bottom = np.minimum.reduceat(c.h, s)
    r = np.hypot(c.xy[:, 0], c.xy[:, 1])
    gap = np.minimum.reduceat(r, s) * _gap_per_m(opts)
    cut_off = np.maximum.reduceat(r, s) > opts.max_range_m - opts.cluster_gap_m
    keep = (
        (count >= opts.min_points)
        & (diagonal >= 0.8 * opts.width_m[0])
        & (top >= opts.height_m[0] - gap)
        & (bottom <= opts.max_bottom_m + gap)
        & ~cut_off  # partly beyond the range limit: its size is unknown
    )
    return np.flatnonzero(keep)


@dataclass(frozen=True)
class _Fit:
    """One fitted box in the link frame (metres, radians)."""

    center_xy: tuple[float, float]
    length: float
    width: float
    yaw: float
    top: float
    score: float
    sigma: float


@dataclass(frozen=True)
class _Axis:
    """What the sensor saw along one box axis.

    Attributes:
        lo: Lowest projection of the points on the axis, metres from the sensor.
        hi: Highest projection, metres.
        ahead: ``+1`` when the sensor lies below ``lo`` (the box continues away from it
            towards ``+``), ``-1`` when above ``hi``, ``0`` when between.
        faced: The face across this axis that is nearer the sensor was seen at least
            ``min_view_angle_deg`` away from grazing.
    """

    lo: float
    hi: float
    ahead: int
    faced: bool

    @classmethod
    def of(cls, proj: npt.NDArray[np.float64], margin: float) -> _Axis:
        """Summarise the ``(M,)`` projections ``proj``; ``margin`` metres make a face seen."""
        lo, hi = float(proj.min()), float(proj.max())
        ahead = 1 if lo > 0 else (-1 if hi < 0 else 0)
        return cls(lo, hi, ahead, lo > margin or hi < -margin)

    @property
    def extent(self) -> float:
        return self.hi - self.lo

    def span(self, size: float) -> tuple[float, float]:
        """``(lo, hi)`` of a box ``size`` long along this axis, grown away from the sensor."""
        if size <= self.extent:
            return self.lo, self.hi
        if self.ahead > 0:
            return self.lo, self.lo + size
        return self.hi - size, self.hi


def _thin(xy: npt.NDArray[np.float64], cell: float) -> npt.NDArray[np.float64]:
    """One centroid per occupied ``cell``-metre square of ``(M, 2)`` positions."""
    key = np.floor((xy - xy.min(axis=0)) / cell).astype(np.int64)
    flat = key[:, 0] * (int(key[:, 1].max()) + 1) + key[:, 1]
    _, inverse, count = np.unique(flat, return_inverse=True, return_counts=True)
    sums = np.zeros((count.size, 2))
    np.add.at(sums, inverse, xy)
    out: npt.NDArray[np.float64] = sums / count[:, None]
    return out


def _contour(xy: npt.NDArray[np.float64], step: float) -> npt.NDArray[np.float64]:
    """The nearest of ``(M, 2)`` points in every bearing bin ``step`` metres wide.

    These are the outline the sensor sees first: a car's faces, not its hood or roof.
    """
    r = np.hypot(xy[:, 0], xy[:, 1])
    bearing = np.arctan2(xy[:, 1], xy[:, 0])
    bearing = np.angle(np.exp(1j * (bearing - bearing[0])))  # no wrap inside one cluster
    key = np.floor(bearing * float(np.mean(r)) / step).astype(np.int64)
    order = np.lexsort((r, key))
    first = np.concatenate([[True], np.diff(key[order]) != 0])
    out: npt.NDArray[np.float64] = xy[order[first]]
    return out


def _best_angle(xy: npt.NDArray[np.float64], angles: npt.NDArray[np.float64]) -> float:
    """Angle in ``angles`` (radians) with the best L-shape closeness score (Zhang et al. 2017).

    Every point counts ``1 / max(d, 0.05)`` where ``d`` is its distance to the nearest edge of
    the bounding rectangle at that angle; all angles are scored at once, ``(M, A)`` arrays.
    """
    p = xy - xy.mean(axis=0)
    c1 = p[:, :1] * np.cos(angles) + p[:, 1:] * np.sin(angles)
    c2 = -p[:, :1] * np.sin(angles) + p[:, 1:] * np.cos(angles)
    d1 = np.minimum(c1.max(axis=0) - c1, c1 - c1.min(axis=0))
    d2 = np.minimum(c2.max(axis=0) - c2, c2 - c2.min(axis=0))
    score = (1.0 / np.maximum(np.minimum(d1, d2), 0.05)).sum(axis=0)
    return float(angles[int(np.argmax(score))])


def _dimension(
    axis: _Axis, other: _Axis, limits: tuple[float, float], prior: float
) -> tuple[float, bool] | None:
    """Size of the box along ``axis`` (metres) and whether it was measured in full.

    The extent along ``axis`` is complete when a face parallel to it was seen, that is when
    ``other`` was faced; else it is only a lower bound (the far faces hide behind the near
    ones) and the box grows to ``prior`` away from the sensor. ``None`` when no car fits.
    """
    if axis.extent > limits[1]:
        return None
    if other.faced and axis.extent >= limits[0]:
        return axis.extent, True
    if axis.ahead == 0:
        return None  # the faces across this axis are not in view, yet its extent is unknown
    return max(prior, axis.extent), False


def _trapezoid(x: float, typical: tuple[float, float], limits: tuple[float, float]) -> float:
    """1 inside ``typical``, falling linearly to 0.2 at ``limits``."""
    if x < typical[0]:
        return 0.2 + 0.8 * max(0.0, (x - limits[0]) / max(typical[0] - limits[0], 1e-9))
    if x > typical[1]:
        return 0.2 + 0.8 * max(0.0, (limits[1] - x) / max(limits[1] - typical[1], 1e-9))
    return 1.0


def _face_fraction(
    pts: npt.NDArray[np.float64],
    axes: tuple[_Axis, _Axis],
    dirs: npt.NDArray[np.float64],
    tol: float,
) -> float:
    """Share of ``(M, 2)`` points within ``tol`` metres of a face turned towards the sensor."""
    near = np.zeros(pts.shape[0], dtype=bool)
    for axis, d in zip(axes, dirs, strict=True):
        if axis.ahead != 0:
            face = axis.lo if axis.ahead > 0 else axis.hi
            near |= np.abs(pts @ d - face) <= tol
    return float(near.mean())


@dataclass(frozen=True)
class _Choice:
    """Which fitted axis is the length, and the box it gives (link frame, metres)."""

    center: tuple[float, float]
    length: float
    width: float
    yaw: float
    extension: float
    measured: tuple[bool, bool]
    ambiguous: bool


def _choose(
    a: tuple[_Axis, _Axis], dirs: npt.NDArray[np.float64], opts: GeometricOptions
) -> _Choice | None:
    """Pick the length axis among the two fitted axes ``a`` (directions ``dirs``).

    Each way round must give a plausible length and width, one of them measured in full (seen
    on a face parallel to it); the other may be grown to the prior (a side or an end view), but
    not along the length when ``end_views`` is off. The way needing the least growth wins, then
    the one whose width is nearer the prior.
    """
    best: tuple[float, float, int] | None = None
    ways: dict[int, tuple[float, float, bool, bool]] = {}
    for k in (0, 1):
        along, across = a[k], a[1 - k]
        dl = _dimension(along, across, opts.length_m, opts.prior_size_m[0])
        dw = _dimension(across, along, opts.width_m, opts.prior_size_m[1])
        if dl is None or dw is None or not (dl[1] or dw[1]) or not (dl[1] or opts.end_views):
            continue
        (length, _), (width, _) = dl, dw
        if across.faced:  # a side face was seen, the far one hides: at least the prior
            width = max(width, opts.prior_size_m[1])
        if along.ahead != 0 and length < opts.typical_length_m[0]:  # short: likely cut off
            length = max(length, opts.prior_size_m[0])
        ways[k] = (length, width, dl[1], dw[1])
        rank = (float(not dl[1]) + float(not dw[1]), abs(width - opts.prior_size_m[1]), k)
        if best is None or rank < best:
            best = rank
    if best is None or (len(ways) > 1 and best[0] > 0):
        return None  # a corner of a partly hidden car: either way round might be right
    k = best[2]
    length, width, full_l, full_w = ways[k]
    along, across = a[k], a[1 - k]
    u, v = dirs[k], dirs[1 - k]
    l_lo, l_hi = along.span(length)
    w_lo, w_hi = across.span(width)
    centre = 0.5 * (l_lo + l_hi) * u + 0.5 * (w_lo + w_hi) * v
    return _Choice(
        center=(float(centre[0]), float(centre[1])),
        length=length,
        width=width,
        yaw=(math.atan2(u[1], u[0]) + math.pi / 2) % math.pi - math.pi / 2,
        extension=(length - along.extent) + (width - across.extent),
        measured=(full_l, full_w),
        ambiguous=len(ways) > 1,
    )


def _pieces(
    xy: npt.NDArray[np.float64], opts: GeometricOptions, angles: npt.NDArray[np.float64]
) -> list[tuple[npt.NDArray[np.int64], float | None]]:
    """Split a cluster longer than a car at its widest gaps along its main axis.

    A row of parked cars seen at a grazing angle forms one connected cluster (each car's end
    face bridges the gap to the next); along the row, the points still leave a gap between
    the cars. Clusters are cut at their widest gap (at least ``split_gap_m``) along the axis
    that is too long until every piece fits a ``length_m[1]`` by ``width_m[1]`` box; a piece
    with no such gap (a wall) is dropped.

    Returns:
        Row indices into ``xy`` of each piece, with the angle of its L-shape (radians, from a
        coarse fit) or ``None`` when the piece is too small to need one here.
    """
    todo = [np.arange(xy.shape[0])]
    done: list[tuple[npt.NDArray[np.int64], float | None]] = []
    while todo:  # one iteration per piece; few pieces per cluster
        idx = todo.pop()
        pts = xy[idx]
        if float(np.hypot(*np.ptp(pts, axis=0))) <= opts.width_m[1]:
            done.append((idx, None))  # fits a car however it is turned
            continue
        theta = _best_angle(_thin(pts, 2.0 * opts.fit_cell_m), angles)
        d1 = pts @ np.array([math.cos(theta), math.sin(theta)])
        d2 = pts @ np.array([-math.sin(theta), math.cos(theta)])
        major, minor = (d1, d2) if np.ptp(d1) >= np.ptp(d2) else (d2, d1)
        if np.ptp(major) > opts.length_m[1]:
            proj = major
        elif np.ptp(minor) > opts.width_m[1]:
            proj = minor  # e.g. the ends of cars parked side by side, seen end-on
        else:
            done.append((idx, theta))
            continue
        s = np.sort(proj)
        gaps = np.diff(s)
        inner = (s[:-1] - s[0] >= opts.width_m[0]) & (s[-1] - s[1:] >= opts.width_m[0])
        gaps = np.where(inner, gaps, 0.0)
        j = int(np.argmax(gaps))
        if gaps[j] < opts.split_gap_m:
            continue
        cut = 0.5 * (s[j] + s[j + 1])
        todo += [idx[proj < cut], idx[proj >= cut]]
    return done


def _fit_cluster(
    xy: npt.NDArray[np.float64],
    h: npt.NDArray[np.float64],
    opts: GeometricOptions,
    angles: npt.NDArray[np.float64],
    hint: float | None = None,
) -> _Fit | None:
    """Fit one cluster's box (link frame) or return ``None`` when it is no car.

    ``hint`` is a coarse L-shape angle (radians); the search then only refines it.
    """
    top = float(np.quantile(h, 0.98))
    gap = float(np.hypot(xy[:, 0], xy[:, 1]).min()) * _gap_per_m(opts)
    if not opts.height_m[0] - gap <= top <= opts.height_m[1]:
        return None
    low = xy[h <= opts.cluster_top_m]
    if low.shape[0] < 3:
        return None
    pts = _thin(low, opts.fit_cell_m)
    step = math.radians(opts.angle_step_deg)
    theta = _best_angle(pts, angles) if hint is None else hint
    theta = _best_angle(pts, theta + np.linspace(-3 * step, 3 * step, 31))
    dirs = np.array([[math.cos(theta), math.sin(theta)], [-math.sin(theta), math.cos(theta)]])
    margin = math.sin(math.radians(opts.min_view_angle_deg)) * float(np.hypot(*pts.mean(axis=0)))
    axes = (_Axis.of(pts @ dirs[0], margin), _Axis.of(pts @ dirs[1], margin))
    box = _choose(axes, dirs, opts)
    if box is None:
        return None
    body = xy[h <= 0.5 * top]  # below hoods and windows, where a car is its faces
    outline = _contour(_thin(body, opts.fit_cell_m) if body.shape[0] >= 5 else pts, 0.3)
    fit = _face_fraction(outline, axes, dirs, opts.face_tolerance_m)
    size = (
        _trapezoid(box.length, opts.typical_length_m, opts.length_m) if box.measured[0] else 0.8
    ) * (_trapezoid(box.width, opts.typical_width_m, opts.width_m) if box.measured[1] else 0.8)
    support = 1.0 - math.exp(-xy.shape[0] / 30.0)
    score = fit**2 * size * support * (0.7 if box.ambiguous else 1.0)
    distance = math.hypot(*box.center)
    sigma = opts.sigma_base_m + opts.sigma_per_m * distance + 0.25 * box.extension
    return _Fit(
        box.center,
        box.length,
        box.width,
        box.yaw,
        max(top, opts.height_m[0]),
        score,
        sigma,
    )


def _inside(xy: tuple[float, float], box: _Fit) -> bool:
    """Whether the point ``xy`` lies in the footprint of ``box`` (link frame, metres)."""
    dx, dy = xy[0] - box.center_xy[0], xy[1] - box.center_xy[1]
    c, s = math.cos(box.yaw), math.sin(box.yaw)
    return abs(c * dx + s * dy) <= box.length / 2 and abs(-s * dx + c * dy) <= box.width / 2


def _suppress(fits: list[_Fit]) -> list[_Fit]:
    """Keep the best-scoring box of boxes whose centres lie in one another (a car in pieces)."""
    kept: list[_Fit] = []
    for fit in sorted(fits, key=lambda f: -f.score):  # a handful of boxes
        if not any(_inside(fit.center_xy, k) or _inside(k.center_xy, fit) for k in kept):
            kept.append(fit)
    return kept


@dataclass(frozen=True)
class GeometricDetector:
    """Finds parked cars in one LiDAR scan without learned weights (see the module doc).

    Attributes:
        options: The parameters; the defaults suit a 32- to 128-beam roof LiDAR.
        name: ``"geometric"``, the name :func:`~cam2sim.detect.detector.load_detector` knows.
    """

    options: GeometricOptions = field(default_factory=GeometricOptions)
    name: str = field(default="geometric", init=False)

    def detect(self, points: npt.NDArray[np.float32]) -> Boxes:
        """Boxes (``axes="link"``) of the cars in one scan.

        Args:
            points: ``(N, 4)`` float32 x, y, z (metres, LiDAR link frame, z up) and intensity
                (unused); rows with a non-finite coordinate are ignored.

        Returns:
            One box per detected car: centre at the box's geometric middle, yaw of the length
            axis in ``[-pi/2, pi/2)`` (a box has no front), ``score`` in ``[0, 1]``,
            ``sigma_m`` growing with range and with the share of the box that was not seen.

        Raises:
            ValueError: ``points`` is not an ``(N, 4)`` (or ``(N, >=3)``) array.
        """
        arr = np.asarray(points)
        if arr.ndim != 2 or arr.shape[1] < 3:
            msg = (
                f"points must be an (N, 4) array of x, y, z, intensity, got shape {arr.shape}; "
                "reshape the scan to one row per return"
            )
            raise ValueError(msg)
        opts = self.options
        xyz = arr[:, :3].astype(np.float64)
        r = np.hypot(xyz[:, 0], xyz[:, 1])
        keep = np.isfinite(xyz).all(axis=1) & (r >= opts.min_range_m) & (r <= opts.max_range_m)
        xyz = xyz[keep]
        if xyz.shape[0] < opts.min_points:
            return Boxes.empty()
        grid = _Grid.covering(opts.max_range_m, opts.ground_cell_m)
        ground = _ground_heights(xyz[:, :2], xyz[:, 2], grid, opts)
        h = xyz[:, 2] - grid.bilinear(ground, xyz[:, :2])
        band = (h >= opts.band_m[0]) & (h <= opts.band_m[1])
        clusters = _clusters(xyz[band, :2], h[band], opts)
        tall = _tall_cells(xyz[:, :2], h, opts)
        cells = _Grid.covering(opts.max_range_m, opts.cluster_cell_m)
        angles = np.deg2rad(np.arange(0.0, 90.0, opts.angle_step_deg))
        fits = []
        for k in _prefilter(clusters, opts):  # one box fit per candidate cluster
            xy_k = clusters.xy[clusters.starts[k] : clusters.starts[k + 1]]
            h_k = clusters.h[clusters.starts[k] : clusters.starts[k + 1]]
            for piece, hint in _pieces(xy_k, opts, angles):
                if piece.size < opts.min_points:
                    continue
                hit = cells.index(xy_k[piece])
                if tall[hit[:, 0], hit[:, 1]].mean() > opts.structure_fraction:
                    continue  # returns continue above any car's roof: a wall or a front
                fit = _fit_cluster(xy_k[piece], h_k[piece], opts, angles, hint)
                if fit is not None and fit.score >= opts.min_score:
                    fits.append(fit)
        fits = _suppress(fits)
        if not fits:
            return Boxes.empty()
        centre_xy = np.array([f.center_xy for f in fits])
        top = np.array([f.top for f in fits])
        z = grid.bilinear(ground, centre_xy) + top / 2.0
        return Boxes(
            center=np.column_stack([centre_xy, z]),
            size=np.array([[f.length, f.width, f.top] for f in fits]),
            yaw=np.array([f.yaw for f in fits]),
            score=np.clip([f.score for f in fits], 0.0, 1.0),
            sigma_m=np.array([f.sigma for f in fits]),
            axes="link",
        )
