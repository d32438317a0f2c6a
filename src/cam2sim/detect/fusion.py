"""Fusion of per-frame boxes into parked vehicles in the world frame.

Every box is moved into the world frame with its sensor's pose at the frame's time
(:func:`boxes_to_world`). Association runs frame by frame: a frame's boxes are matched one to
one (Hungarian assignment, :func:`scipy.optimize.linear_sum_assignment`) to the clusters found
so far, with a gate on the distance normalised by both position uncertainties, so one frame
never puts two boxes into one cluster and two parked cars a few metres apart stay apart.
Parked cars do not move, so a cluster stays open for the whole drive: a car seen again after a
gap joins its cluster instead of starting a new one. Clusters whose centres end up closer than
``merge_m`` and which never shared a frame are merged afterwards (one car split by an early
poor box).

A cluster's position and size are the means of its boxes weighted by ``score / sigma**2``
(the inverse-variance weight, scaled by the detector's confidence); its yaw is the weighted
circular mean of the *axial* box directions (angles doubled, averaged, halved: a box has no
front, so 5 degrees and 185 degrees agree), then turned to face the route's direction of
travel. ``side`` and ``orientation`` are weighted majority votes of the per-box votes against
the route, not recomputed from the mean. Clusters with fewer than ``min_hits`` boxes are
dropped. ``confidence`` is the weight-averaged detector score.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from cam2sim.detect.vehicles import ParkedVehicle

if TYPE_CHECKING:
    from cam2sim.detect.boxes import Boxes
    from cam2sim.detect.route import Route
    from cam2sim.detect.vehicles import VehicleSource

__all__ = ["FusionOptions", "WorldBoxes", "boxes_to_world", "fuse"]


@dataclass(frozen=True)
class FusionOptions:
    """How boxes are associated and fused.

    Attributes:
        gate_sigma: Association gate in standard deviations of the combined position
            uncertainty (box and cluster).
        gate_max_m: Association gate ceiling in metres, whatever the uncertainty.
        gate_min_m: Association gate floor in metres (LiDAR boxes with a tiny sigma still
            match a few decimetres of fitting jitter).
        merge_m: Clusters closer than this that never shared a frame are merged.
        min_hits: Clusters with fewer boxes are dropped.
        max_range_m: Boxes farther than this from the sensor are ignored.
    """

    gate_sigma: float = 3.0
    gate_max_m: float = 2.0
    gate_min_m: float = 1.0
    merge_m: float = 1.2
    min_hits: int = 3
    max_range_m: float = 40.0

    def __post_init__(self) -> None:
        if self.min_hits < 1:
            msg = f"min_hits must be >= 1, got {self.min_hits}"
            raise ValueError(msg)
        if not 0 < self.gate_min_m <= self.gate_max_m:
            msg = f"need 0 < gate_min_m <= gate_max_m, got {self.gate_min_m}, {self.gate_max_m}"
            raise ValueError(msg)


@dataclass(frozen=True, eq=False)
class WorldBoxes:
    """Boxes of many frames in the world frame, one row per box.

    Attributes:
        frame: ``(N,)`` int64 frame (scan or image) index each box came from.
        bottom: ``(N, 3)`` bottom centre of each box, world metres.
        yaw: ``(N,)`` heading of each box's length axis, radians.
        size: ``(N, 3)`` length, width, height, metres.
        score: ``(N,)`` detector confidence.
        sigma_m: ``(N,)`` position standard deviation, metres.
        range_m: ``(N,)`` distance from the sensor, metres.
    """

    frame: npt.NDArray[np.int64]
    bottom: npt.NDArray[np.float64]
    yaw: npt.NDArray[np.float64]
    size: npt.NDArray[np.float64]
    score: npt.NDArray[np.float64]
    sigma_m: npt.NDArray[np.float64]
    range_m: npt.NDArray[np.float64]

    def __len__(self) -> int:
        return int(self.frame.shape[0])

    @classmethod
    def concatenate(cls, parts: list[WorldBoxes]) -> WorldBoxes:
        """All rows of ``parts`` in order."""
        if not parts:
            z = np.zeros(0)
            return cls(np.zeros(0, np.int64), np.zeros((0, 3)), z, np.zeros((0, 3)), z, z, z)
        return cls(
            *(np.concatenate([getattr(p, f) for p in parts]) for f in cls.__dataclass_fields__)
        )

    def select(self, keep: npt.NDArray[np.bool_]) -> WorldBoxes:
        """The rows picked by a boolean mask."""
        return WorldBoxes(*(getattr(self, f)[keep] for f in self.__dataclass_fields__))


def boxes_to_world(boxes: Boxes, T_world_sensor: npt.ArrayLike, frame: int) -> WorldBoxes:
    """Move one frame's boxes into the world frame.

    Args:
        boxes: Boxes in the sensor frame.
        T_world_sensor: ``(4, 4)`` sensor -> world transform at the frame's time.
        frame: Frame index recorded with each box.

    Returns:
        The boxes with world bottom centres and world yaws. A box is assumed upright in the
        world (parked cars stand on the road), so its bottom is its centre minus half its height.
    """
    T = np.asarray(T_world_sensor, dtype=np.float64).reshape(4, 4)
    R, t = T[:3, :3], T[:3, 3]
    center = boxes.center @ R.T + t
    d = boxes.direction() @ R.T
    yaw = np.arctan2(d[:, 1], d[:, 0])
    bottom = center.copy()
    bottom[:, 2] -= boxes.size[:, 2] / 2.0
    rng = np.linalg.norm(boxes.center, axis=1)
    n = len(boxes)
    return WorldBoxes(
        np.full(n, frame, dtype=np.int64),
        bottom,
        yaw,
        boxes.size.copy(),
        boxes.score.copy(),
        boxes.sigma_m.copy(),
        rng,
    )


def _associate(boxes: WorldBoxes, opts: FusionOptions) -> tuple[npt.NDArray[np.int64], int]:
    """Cluster label of every box (frame by frame Hungarian matching), and the cluster count."""
    from scipy.optimize import linear_sum_assignment  # noqa: PLC0415

    n = len(boxes)
    label = np.full(n, -1, dtype=np.int64)
    w = boxes.score / boxes.sigma_m**2
    # Running weighted sums per cluster: sum w, sum w*x, sum w*y, sum w*sigma^2 (for spread).
    cap = max(16, n)
    sw = np.zeros(cap)
    sx = np.zeros(cap)
    sy = np.zeros(cap)
    var = np.zeros(cap)
    count = 0
    order = np.argsort(boxes.frame, kind="stable")
    frames, starts = np.unique(boxes.frame[order], return_index=True)
    bounds = [*starts.tolist(), n]
    for k in range(frames.shape[0]):
        rows = order[bounds[k] : bounds[k + 1]]
        xy = boxes.bottom[rows, :2]
        if count:
            mean = np.stack([sx[:count], sy[:count]], 1) / sw[:count, None]
            d = np.linalg.norm(xy[:, None, :] - mean[None, :, :], axis=2)
            s = np.sqrt(boxes.sigma_m[rows, None] ** 2 + var[None, :count])
            gate = np.clip(opts.gate_sigma * s, opts.gate_min_m, opts.gate_max_m)
            cost = np.where(d <= gate, d / gate, 1e6)
            r_idx, c_idx = linear_sum_assignment(cost)
            ok = cost[r_idx, c_idx] < 1e6
            matched = np.full(rows.shape[0], -1, dtype=np.int64)
            matched[r_idx[ok]] = c_idx[ok]
        else:
            matched = np.full(rows.shape[0], -1, dtype=np.int64)
        new = matched < 0
        matched[new] = np.arange(count, count + int(new.sum()))
        count += int(new.sum())
        label[rows] = matched
        wk = w[rows]
        np.add.at(sw, matched, wk)
        np.add.at(sx, matched, wk * xy[:, 0])
        np.add.at(sy, matched, wk * xy[:, 1])
        # Uncertainty of a weighted mean: 1 / sum of inverse variances (score-free).
        inv = np.zeros(cap)
        np.add.at(inv, matched, 1.0 / boxes.sigma_m[rows] ** 2)
        touched = np.unique(matched)
        prev = np.where(var[touched] > 0, 1.0 / np.maximum(var[touched], 1e-12), 0.0)
        var[touched] = 1.0 / (prev + inv[touched])
    return label, count


def _merge(
    boxes: WorldBoxes, label: npt.NDArray[np.int64], count: int, opts: FusionOptions
) -> npt.NDArray[np.int64]:
    """Merge clusters closer than ``merge_m`` that never shared a frame; relabel 0..K-1."""
    from scipy.sparse import coo_matrix, csr_matrix  # noqa: PLC0415
    from scipy.sparse.csgraph import connected_components  # noqa: PLC0415
    from scipy.spatial import cKDTree  # noqa: PLC0415

    if count == 0:
        return label
    w = boxes.score / boxes.sigma_m**2
    sw = np.bincount(label, w, count)
    mean = np.stack(
        [np.bincount(label, w * boxes.bottom[:, i], count) / sw for i in (0, 1)], 1
    ).astype(np.float64)
    pairs = cKDTree(mean).query_pairs(opts.merge_m, output_type="ndarray")
    if pairs.shape[0]:
        # Clusters that shared a frame are different cars.
        _, frame_col = np.unique(boxes.frame, return_inverse=True)
        seen = csr_matrix(
            (np.ones(label.shape[0]), (label, frame_col.ravel())),
            shape=(count, int(frame_col.max()) + 1),
        )
        shared = np.asarray(seen[pairs[:, 0]].multiply(seen[pairs[:, 1]]).sum(axis=1)).ravel()
        keep = shared == 0
        pairs = pairs[keep]
    graph = coo_matrix(
        (np.ones(pairs.shape[0]), (pairs[:, 0], pairs[:, 1])) if pairs.shape[0] else ([], ([], [])),
        shape=(count, count),
    )
    _, comp = connected_components(graph, directed=False)
    return np.asarray(comp[label], dtype=np.int64)


def fuse(
    boxes: WorldBoxes,
    route: Route,
    *,
    source: VehicleSource,
    options: FusionOptions | None = None,
) -> tuple[list[ParkedVehicle], npt.NDArray[np.int64]]:
    """Fuse world boxes into parked vehicles.

    Args:
        boxes: Every frame's boxes in the world frame.
        route: The driven route (side and orientation votes, yaw direction).
        source: Detector source recorded on each vehicle.
        options: Association and fusion settings.

    Returns:
        The vehicles, ordered along the route (ids ``pv_000``, ``pv_001``, ...), and the
        vehicle index of every input box (-1 for boxes out of range or in dropped clusters).
    """
    opts = options or FusionOptions()
    n_in = len(boxes)
    member = np.full(n_in, -1, dtype=np.int64)
    in_range = boxes.range_m <= opts.max_range_m
    kept = boxes.select(in_range)
    if len(kept) == 0:
        return [], member
    label, count = _associate(kept, opts)
    label = _merge(kept, label, count, opts)
    k = int(label.max()) + 1
    hits = np.bincount(label, minlength=k)
    w = kept.score / kept.sigma_m**2
    sw = np.bincount(label, w, k)

    def wmean(v: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        return np.bincount(label, w * v, k) / sw

    bottom = np.stack([wmean(kept.bottom[:, i]) for i in range(3)], 1)
    size = np.stack([wmean(kept.size[:, i]) for i in range(3)], 1)
    conf = wmean(kept.score)
    # Axial circular mean of yaw.
    c2 = np.bincount(label, w * np.cos(2 * kept.yaw), k)
    s2 = np.bincount(label, w * np.sin(2 * kept.yaw), k)
    yaw = 0.5 * np.arctan2(s2, c2)
    # Votes of each box against the route.
    lateral, _ = route.nearest(kept.bottom[:, :2])
    left_votes = np.bincount(label, w * (lateral > 0), k)
    box_orient = np.asarray(route.orientation(kept.bottom[:, :2], kept.yaw))
    par_votes = np.bincount(label, w * (box_orient == "parallel"), k)
    side = np.where(left_votes > sw / 2, "left", "right")
    orient = np.where(par_votes >= sw / 2, "parallel", "perpendicular")
    # Face the direction of travel (yaw or yaw + pi, whichever is closer to the route heading).
    _, heading = route.nearest(bottom[:, :2])
    flip = np.cos(yaw - heading) < 0
    yaw = np.angle(np.exp(1j * (yaw + np.pi * flip)))
    good = np.flatnonzero(hits >= opts.min_hits)
    progress_order = _route_order(route, bottom[good, :2])
    good = good[progress_order]
    vehicles = []
    new_index = np.full(k, -1, dtype=np.int64)
    for i, c in enumerate(good.tolist()):
        new_index[c] = i
        vehicles.append(
            ParkedVehicle(
                id=f"pv_{i:03d}",
                position=(float(bottom[c, 0]), float(bottom[c, 1]), float(bottom[c, 2])),
                yaw=float(yaw[c]),
                size=(float(size[c, 0]), float(size[c, 1]), float(size[c, 2])),
                confidence=float(np.clip(conf[c], 0.0, 1.0)),
                hits=int(hits[c]),
                side=str(side[c]),
                orientation=str(orient[c]),
                source=source,
            )
        )
    member[np.flatnonzero(in_range)] = new_index[label]
    return vehicles, member


def _route_order(route: Route, xy: npt.NDArray[np.float64]) -> npt.NDArray[np.int64]:
    """Indices sorting points by the arc length of their nearest route vertex."""
    from scipy.spatial import cKDTree  # noqa: PLC0415

    if xy.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    _, idx = cKDTree(route.path.xy).query(xy)
    return np.argsort(route.path.s[idx], kind="stable").astype(np.int64)
