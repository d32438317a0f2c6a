"""Polylines and reference paths: arc length, resampling, robust projection, lateral offsets.

The shared path geometry: the metrics measure runs along it, the simulator tracks route
progress with it, detection places parked cars beside the driven route with it.

A run is projected onto a reference polyline by a monotone alignment: each point is assigned to a
reference segment so that progress never decreases along the run and the summed distance is
minimal (distances capped at ``max_lateral_m``, so points far off the route neither pull the
alignment nor earn progress). This is what makes completion robust to a run that wanders off
near the end: a point only earns progress where it is on the route.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = [
    "PathProjection",
    "ReferencePath",
    "arc_length",
    "resample_by_arc_length",
    "resample_indices",
]


def arc_length(xy: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Cumulative arc length ``(N,)`` of an ``(N, 2)`` polyline, starting at 0."""
    if xy.shape[0] == 0:
        return np.zeros(0)
    steps = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def _resample(
    xy: npt.NDArray[np.float64], spacing_m: float
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    s = arc_length(xy)
    if s.shape[0] < 2 or s[-1] <= 0:
        return xy[:1].copy(), np.zeros(1)
    q = np.arange(0.0, s[-1], spacing_m)
    q = np.append(q, s[-1]) if s[-1] - q[-1] > 1e-9 else q
    keep = np.concatenate([[True], np.diff(s) > 0])
    out = np.stack([np.interp(q, s[keep], xy[keep, 0]), np.interp(q, s[keep], xy[keep, 1])], -1)
    return out, q


def resample_by_arc_length(
    xy: npt.NDArray[np.float64], spacing_m: float
) -> npt.NDArray[np.float64]:
    """Resample an ``(N, 2)`` polyline at uniform arc-length spacing (last point kept)."""
    return _resample(xy, spacing_m)[0]


def resample_indices(xy: npt.NDArray[np.float64], spacing_m: float) -> npt.NDArray[np.int64]:
    """Indices of points at least ``spacing_m`` of arc length apart (first and last kept)."""
    s = arc_length(xy)
    if s.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    marks = np.arange(0.0, s[-1] + spacing_m, spacing_m)
    idx = np.unique(np.searchsorted(s, marks, side="left").clip(0, s.shape[0] - 1))
    if idx[-1] != s.shape[0] - 1:
        idx = np.append(idx, s.shape[0] - 1)
    return idx.astype(np.int64)


@dataclass(frozen=True)
class PathProjection:
    """A run projected onto a reference path.

    Attributes:
        progress_m: ``(N,)`` arc length of each point's foot point on the reference; monotone
            non-decreasing along the run.
        lateral_m: ``(N,)`` signed distance to the reference, positive to the left of its
            direction of travel.
        on_route: ``(N,)`` whether the point lies within ``max_lateral_m`` of the reference.
    """

    progress_m: npt.NDArray[np.float64]
    lateral_m: npt.NDArray[np.float64]
    on_route: npt.NDArray[np.bool_]


@dataclass(frozen=True)
class ReferencePath:
    """A reference polyline resampled every ``spacing_m`` metres.

    Attributes:
        xy: ``(M, 2)`` vertices, metres.
        s: ``(M,)`` arc length of each vertex along the original (densely sampled) polyline,
            metres. Chords of the resampled polyline cut corners, so its own length would be
            short by about 0.25 % on the reference drive's bends; progress uses the true length.
        spacing_m: Resampling step.
    """

    xy: npt.NDArray[np.float64]
    s: npt.NDArray[np.float64]
    spacing_m: float

    @classmethod
    def from_polyline(cls, xy: npt.NDArray[np.float64], *, spacing_m: float = 0.5) -> ReferencePath:
        """Resample a driven polyline into a reference path."""
        ref, s = _resample(np.asarray(xy, dtype=np.float64), spacing_m)
        if ref.shape[0] < 2:
            msg = "the reference run has no length; it needs at least two distinct positions"
            raise ValueError(msg)
        return cls(xy=ref, s=s, spacing_m=spacing_m)

    @property
    def length_m(self) -> float:
        """Total length of the reference."""
        return float(self.s[-1])

    def tangent_heading(self) -> npt.NDArray[np.float64]:
        """``(M,)`` heading of each vertex (forward difference; backward at the end)."""
        d = np.diff(self.xy, axis=0)
        d = np.vstack([d, d[-1:]])
        return np.unwrap(np.arctan2(d[:, 1], d[:, 0]))

    def curvature(self, *, window_m: float = 5.0) -> npt.NDArray[np.float64]:
        """``(M,)`` signed curvature (1/m, positive = left turn) over a centred window."""
        h = self.tangent_heading()
        k = max(1, round(window_m / self.spacing_m))
        lo = np.clip(np.arange(h.shape[0]) - k, 0, h.shape[0] - 1)
        hi = np.clip(np.arange(h.shape[0]) + k, 0, h.shape[0] - 1)
        ds = self.s[hi] - self.s[lo]
        out = np.zeros_like(h)
        np.divide(h[hi] - h[lo], ds, out=out, where=ds > 0)
        return out

    def point_at(self, s: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """``(K, 2)`` points on the reference at arc lengths ``s``."""
        return np.stack(
            [np.interp(s, self.s, self.xy[:, 0]), np.interp(s, self.s, self.xy[:, 1])], -1
        )

    def normal_at(self, s: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """``(K, 2)`` unit left normals at arc lengths ``s``."""
        h = np.interp(s, self.s, self.tangent_heading())
        return np.stack([-np.sin(h), np.cos(h)], -1)

    def project(self, xy: npt.NDArray[np.float64], *, max_lateral_m: float = 4.0) -> PathProjection:
        """Project an ``(N, 2)`` run onto the path with a monotone alignment (see module doc)."""
        xy = np.asarray(xy, dtype=np.float64)
        n = xy.shape[0]
        if n == 0:
            return PathProjection(np.zeros(0), np.zeros(0), np.zeros(0, dtype=bool))
        p0, d = self.xy[:-1], np.diff(self.xy, axis=0)
        len2 = np.maximum((d * d).sum(axis=1), 1e-12)
        m = p0.shape[0]
        back = np.empty((n, m), dtype=np.int32)
        cost = np.zeros(m)
        arange = np.arange(m)
        # (n, m) foot-point parameters and distances, without (n, m, 2) temporaries.
        rx = xy[:, 0:1] - p0[None, :, 0]
        ry = xy[:, 1:2] - p0[None, :, 1]
        t_all = np.clip((rx * d[None, :, 0] + ry * d[None, :, 1]) / len2[None], 0.0, 1.0)
        rx -= t_all * d[None, :, 0]
        ry -= t_all * d[None, :, 1]
        dist_all = np.hypot(rx, ry)
        del rx, ry
        capped = np.minimum(dist_all, max_lateral_m)
        for i in range(n):
            if i == 0:
                back[i] = arange
                cost = capped[0].astype(np.float64)
                continue
            pm = np.minimum.accumulate(cost)
            record = np.concatenate([[True], cost[1:] < pm[:-1]])
            back[i] = np.maximum.accumulate(np.where(record, arange, 0))
            cost = pm + capped[i]
        j = np.empty(n, dtype=np.int64)
        j[-1] = int(np.argmin(cost))
        for i in range(n - 1, 0, -1):
            j[i - 1] = back[i, j[i]]
        rows = np.arange(n)
        t = t_all[rows, j].astype(np.float64)
        foot = p0[j] + t[:, None] * d[j]
        offset = xy - foot
        cross = d[j, 0] * offset[:, 1] - d[j, 1] * offset[:, 0]
        seg_len = np.sqrt(len2[j])
        lateral = cross / seg_len
        progress = self.s[j] + t * (self.s[j + 1] - self.s[j])
        on_route = dist_all[rows, j] <= max_lateral_m
        return PathProjection(progress_m=progress, lateral_m=lateral, on_route=on_route)
