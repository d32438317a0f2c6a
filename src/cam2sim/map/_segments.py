"""Nearest point on many polylines for a batch of points: short segments in an STRtree."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import shapely

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    import numpy.typing as npt

__all__ = ["PolylineIndex", "SegmentHit"]

_MIN_SEGMENT_M = 1e-9


@dataclass(frozen=True, eq=False)
class SegmentHit:
    """The nearest segment of each query point.

    Attributes:
        owner: ``(N,)`` int64 polyline index, -1 where nothing lies within the search distance.
        foot: ``(N, 2)`` nearest point, metres (NaN where owner is -1).
        distance: ``(N,)`` distance to it, metres (inf where owner is -1).
        side: ``(N,)`` +1 left of the segment direction, -1 right, 0 on it.
        heading: ``(N,)`` segment direction, radians.
        values: Per-vertex values interpolated at the foot point, by name.
    """

    owner: npt.NDArray[np.int64]
    foot: npt.NDArray[np.float64]
    distance: npt.NDArray[np.float64]
    side: npt.NDArray[np.float64]
    heading: npt.NDArray[np.float64]
    values: Mapping[str, npt.NDArray[np.float64]]


@dataclass(frozen=True, eq=False)
class PolylineIndex:
    """Segments of many polylines, each tagged with the polyline it belongs to.

    Attributes:
        a: ``(M, 2)`` segment starts.
        b: ``(M, 2)`` segment ends.
        owner: ``(M,)`` polyline index of each segment.
        start_values: Per-vertex values at the segment starts, by name.
        end_values: The same at the segment ends.
    """

    a: npt.NDArray[np.float64]
    b: npt.NDArray[np.float64]
    owner: npt.NDArray[np.int64]
    start_values: Mapping[str, npt.NDArray[np.float64]]
    end_values: Mapping[str, npt.NDArray[np.float64]]

    @classmethod
    def build(
        cls,
        polylines: Sequence[npt.NDArray[np.float64]],
        owners: Sequence[int] | None = None,
        values: Mapping[str, Sequence[npt.NDArray[np.float64]]] | None = None,
    ) -> PolylineIndex:
        """Index ``(K_i, 2)`` polylines; ``values`` holds ``(K_i,)`` arrays per polyline."""
        values = values or {}
        ids = list(range(len(polylines))) if owners is None else list(owners)
        parts = [(i, p) for i, p in zip(ids, polylines, strict=True) if len(p) >= 2]
        if not parts:
            z = np.zeros((0, 2))
            e = {k: np.zeros(0) for k in values}
            return cls(z, z, np.zeros(0, dtype=np.int64), e, e)
        a = np.concatenate([p[:-1] for _, p in parts])
        b = np.concatenate([p[1:] for _, p in parts])
        owner = np.concatenate([np.full(len(p) - 1, i, dtype=np.int64) for i, p in parts])
        keep_poly = [j for j, p in enumerate(polylines) if len(p) >= 2]
        start = {k: np.concatenate([v[j][:-1] for j in keep_poly]) for k, v in values.items()}
        end = {k: np.concatenate([v[j][1:] for j in keep_poly]) for k, v in values.items()}
        keep = np.hypot(*(b - a).T) > _MIN_SEGMENT_M
        return cls(
            a[keep],
            b[keep],
            owner[keep],
            {k: v[keep] for k, v in start.items()},
            {k: v[keep] for k, v in end.items()},
        )

    @functools.cached_property
    def tree(self) -> shapely.STRtree:
        """STRtree of the segments as two-point line strings."""
        return shapely.STRtree(shapely.linestrings(np.stack([self.a, self.b], axis=1)))

    def nearest(self, xy: npt.NDArray[np.float64], max_distance: float | None = None) -> SegmentHit:
        """Find the nearest segment of each ``(N, 2)`` point (within ``max_distance``)."""
        n = xy.shape[0]
        if self.a.shape[0] == 0 or n == 0:
            return SegmentHit(
                owner=np.full(n, -1, dtype=np.int64),
                foot=np.full((n, 2), np.nan),
                distance=np.full(n, np.inf),
                side=np.full(n, np.nan),
                heading=np.full(n, np.nan),
                values={name: np.full(n, np.nan) for name in self.start_values},
            )
        q, hit = self.tree.query_nearest(
            shapely.points(xy), all_matches=False, max_distance=max_distance
        )
        k = np.zeros(n, dtype=np.int64)
        k[q] = hit
        owner = np.full(n, -1, dtype=np.int64)
        owner[q] = self.owner[hit]
        a, d = self.a[k], self.b[k] - self.a[k]
        t = np.clip(np.einsum("ij,ij->i", xy - a, d) / np.einsum("ij,ij->i", d, d), 0.0, 1.0)
        foot = a + t[:, None] * d
        rel = xy - foot
        dist = np.hypot(rel[:, 0], rel[:, 1])
        side = np.sign(d[:, 0] * rel[:, 1] - d[:, 1] * rel[:, 0])
        heading = np.arctan2(d[:, 1], d[:, 0])
        values = {
            name: start[k] + t * (self.end_values[name][k] - start[k])
            for name, start in self.start_values.items()
        }
        missing = owner < 0
        foot[missing] = np.nan
        dist[missing] = np.inf
        for arr in (side, heading, *values.values()):
            arr[missing] = np.nan
        return SegmentHit(owner, foot, dist, side, heading, values)
