"""A route made of straights and arcs, in a local metric frame.

:class:`PiecewiseRoute` starts at the origin heading east (+x) and chains pieces ``(length_m,
curvature)`` (curvature in 1/m, positive to the left; 0 for a straight). Stations before 0 and
past the end continue the first and last headings in straight lines, so a street can extend
beyond the driven route. Points are given ``lateral`` metres to the left of the route.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = ["PiecewiseRoute"]


@dataclass(frozen=True)
class PiecewiseRoute:
    """Straights and arcs: ``pieces`` are ``(length_m, curvature_per_m)``, positive left."""

    pieces: tuple[tuple[float, float], ...]

    def __post_init__(self) -> None:
        if not self.pieces or any(length <= 0 for length, _ in self.pieces):
            msg = f"a route needs pieces of positive length, got {self.pieces}"
            raise ValueError(msg)

    @property
    def length_m(self) -> float:
        """Length of the route."""
        return float(sum(p[0] for p in self.pieces))

    @cached_property
    def starts(self) -> tuple[tuple[float, float, float, float], ...]:
        """``(s, x, y, heading)`` at the start of each piece."""
        out = []
        s = x = y = h = 0.0
        for length, k in self.pieces:
            out.append((s, x, y, h))
            if k == 0.0:
                x, y = x + length * math.cos(h), y + length * math.sin(h)
            else:
                h1 = h + k * length
                x, y = x + (math.sin(h1) - math.sin(h)) / k, y - (math.cos(h1) - math.cos(h)) / k
                h = h1
            s += length
        return tuple(out)

    @property
    def end_heading(self) -> float:
        """Heading at the end of the route."""
        h0 = self.starts[-1][3]
        length, k = self.pieces[-1]
        return h0 + k * length

    def points(
        self, s: npt.ArrayLike, lateral: float | npt.ArrayLike = 0.0
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Positions ``(N, 2)`` and headings ``(N,)`` at stations ``s``, ``lateral`` to the left."""
        st = np.atleast_1d(np.asarray(s, dtype=np.float64))
        s0, x0, y0, h0 = (np.array(c) for c in zip(*self.starts, strict=True))
        k = np.array([p[1] for p in self.pieces])
        idx = np.clip(np.searchsorted(s0, st, side="right") - 1, 0, len(s0) - 1)
        ds = st - s0[idx]
        kk = np.where(st < 0.0, 0.0, k[idx])  # before the start: the first heading, straight
        end = st > self.length_m
        ds = np.where(end, st - self.length_m, ds)
        xs, ys, hs = x0[idx], y0[idx], h0[idx]
        if end.any():  # past the end: the last heading, straight from the end point
            last_xy, _ = self.points([self.length_m])
            xs = np.where(end, last_xy[0, 0], xs)
            ys = np.where(end, last_xy[0, 1], ys)
            hs = np.where(end, self.end_heading, hs)
            kk = np.where(end, 0.0, kk)
        h = hs + kk * ds
        safe = np.where(kk == 0.0, 1.0, kk)
        straight = kk == 0.0
        x = np.where(straight, xs + ds * np.cos(hs), xs + (np.sin(h) - np.sin(hs)) / safe)
        y = np.where(straight, ys + ds * np.sin(hs), ys - (np.cos(h) - np.cos(hs)) / safe)
        lat = np.broadcast_to(np.asarray(lateral, dtype=np.float64), st.shape)
        xy = np.column_stack([x - lat * np.sin(h), y + lat * np.cos(h)])
        return xy, h

    def curvature(self, s: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Curvature (1/m, positive left) at stations ``s`` (0 beyond the ends)."""
        st = np.atleast_1d(np.asarray(s, dtype=np.float64))
        s0 = np.array([c[0] for c in self.starts])
        k = np.array([p[1] for p in self.pieces])
        idx = np.clip(np.searchsorted(s0, st, side="right") - 1, 0, len(s0) - 1)
        out: npt.NDArray[np.float64] = np.where((st < 0) | (st > self.length_m), 0.0, k[idx])
        return out

    def bends(self) -> tuple[tuple[float, float], ...]:
        """``(start, end)`` stations of the arcs."""
        return tuple(
            (s0, s0 + length)
            for (s0, _, _, _), (length, k) in zip(self.starts, self.pieces, strict=True)
            if k != 0.0
        )

    def in_bend(self, s: npt.ArrayLike, margin_m: float = 0.0) -> npt.NDArray[np.bool_]:
        """Whether stations ``s`` lie within ``margin_m`` of an arc."""
        st = np.atleast_1d(np.asarray(s, dtype=np.float64))
        out = np.zeros(st.shape, dtype=bool)
        for a, b in self.bends():
            out |= (st > a - margin_m) & (st < b + margin_m)
        return out

    def offset_plan_view(self, lateral_m: float, lead_m: float) -> tuple[str, float]:
        """OpenDRIVE ``<geometry>`` elements of the line ``lateral_m`` left of the route.

        Returns:
            The elements and the line's length (the OpenDRIVE road's ``length``).

        The line runs from ``-lead_m`` to ``length_m + lead_m`` (straight leads); an arc of
        curvature ``k`` offset by ``d`` keeps its centre, so its curvature becomes ``k/(1-kd)``.

        Raises:
            ValueError: The offset reaches an arc's centre.
        """
        parts: list[str] = []
        s_ref = 0.0

        def line(s: float, length: float, curvature: float) -> None:
            nonlocal s_ref
            xy, h = self.points([s], lateral_m)
            x, y, hdg = float(xy[0, 0]), float(xy[0, 1]), float(h[0])
            shape = "<line/>" if curvature == 0.0 else f'<arc curvature="{curvature!r}"/>'
            parts.append(
                f'<geometry s="{s_ref!r}" x="{x!r}" y="{y!r}" hdg="{hdg!r}" '
                f'length="{length!r}">{shape}</geometry>'
            )
            s_ref += length

        pieces = [(lead_m, 0.0), *self.pieces, (lead_m, 0.0)]
        s = -lead_m
        for length, k in pieces:
            if k != 0.0 and k * lateral_m >= 1.0:
                msg = f"an offset of {lateral_m} m reaches the centre of an arc of radius {1 / k}"
                raise ValueError(msg)
            scale = 1.0 - k * lateral_m
            line(s, float(length * scale), float(k / scale))
            s += length
        return "".join(parts), s_ref
