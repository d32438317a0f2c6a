"""A route made of straights and arcs, in a local metric frame.

:class:`PiecewiseRoute` starts at ``start`` (the origin heading east, +x, unless told) and chains
pieces ``(length_m, curvature)`` (curvature in 1/m, positive to the left; 0 for a straight).
Stations before 0 and past the end continue the first and last headings in straight lines, so a
street can extend beyond the driven route. Points are given ``lateral`` metres to the left of the
route. :meth:`PiecewiseRoute.from_polyline` fits one to a polyline (a street's OSM geometry) by
rounding each corner with the largest arc that fits, as road designers fillet a tangent line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Final

import numpy as np

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = ["BEND_MIN_TURN_RAD", "PiecewiseRoute"]

BEND_MIN_TURN_RAD: Final = math.radians(15.0)
"""A run of arcs turning less than this is a gentle curve, not a bend (cars park along it)."""


@dataclass(frozen=True)
class PiecewiseRoute:
    """Straights and arcs: ``pieces`` are ``(length_m, curvature_per_m)``, positive left.

    ``start`` is ``(x, y, heading)`` where the route begins (default: the origin, heading east).
    """

    pieces: tuple[tuple[float, float], ...]
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if not self.pieces or any(length <= 0 for length, _ in self.pieces):
            msg = f"a route needs pieces of positive length, got {self.pieces}"
            raise ValueError(msg)

    @classmethod
    def from_polyline(
        cls,
        xy: npt.ArrayLike,
        *,
        max_radius_m: float | npt.ArrayLike = 60.0,
        min_radius_m: float = 20.0,
    ) -> PiecewiseRoute:
        """The route along the polyline ``xy`` ``(N, 2)`` with each corner rounded by an arc.

        Each corner gets the largest radius up to ``max_radius_m`` (one for all, or one per
        point of ``xy``: the ends' are unused) whose tangent points fit on its two legs (a leg
        between two corners is shared in proportion to what each wants), so a curve drawn with
        many short segments keeps its own radius. Corners turning less than 0.1 degree are
        straightened out.

        Raises:
            ValueError: Fewer than two distinct points, or a corner that only fits a radius
                below ``min_radius_m`` (too sharp to drive through; the message says where).
        """
        pts = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        keep = np.r_[True, np.hypot(*np.diff(pts, axis=0).T) > 1e-6]
        pts = pts[keep]
        cap = np.broadcast_to(np.asarray(max_radius_m, dtype=np.float64), keep.shape)[keep]
        if len(pts) < 2:
            msg = f"a route needs two distinct points, got {len(pts)}"
            raise ValueError(msg)
        seg = np.diff(pts, axis=0)
        length = np.hypot(*seg.T)
        heading = np.arctan2(seg[:, 1], seg[:, 0])
        turn = np.remainder(np.diff(heading) + math.pi, 2.0 * math.pi) - math.pi
        turn = np.where(np.abs(turn) < math.radians(0.1), 0.0, turn)
        half = np.tan(np.abs(turn) / 2.0)
        want = cap[1:-1] * half  # tangent length each corner wants
        # Share every leg between its two corners in proportion to their wishes.
        before = np.r_[0.0, want[:-1]]  # the wish of the corner at the leg's other end
        after = np.r_[want[1:], 0.0]
        fit_in = length[:-1] * np.divide(
            want, want + before, out=np.ones_like(want), where=want > 0
        )
        fit_out = length[1:] * np.divide(want, want + after, out=np.ones_like(want), where=want > 0)
        tangent = np.minimum(want, np.minimum(fit_in, fit_out))
        radius = np.divide(tangent, half, out=np.full_like(want, np.inf), where=half > 0)
        sharp = np.flatnonzero(radius < min_radius_m * (1.0 - 1e-9))
        if sharp.size:
            i = int(sharp[0])
            msg = (
                f"the corner at ({pts[i + 1, 0]:.1f}, {pts[i + 1, 1]:.1f}) turns by "
                f"{math.degrees(abs(turn[i])):.0f} degrees and fits only a {radius[i]:.1f} m "
                f"radius on its legs (at least {min_radius_m:g} m is drivable)"
            )
            raise ValueError(msg)
        pieces: list[tuple[float, float]] = []
        t_in = np.r_[0.0, tangent]  # tangent taken at each leg's start
        t_out = np.r_[tangent, 0.0]  # and at its end
        for j in range(len(length)):
            straight = float(length[j] - t_in[j] - t_out[j])
            if straight > 1e-6:
                pieces.append((straight, 0.0))
            if j < len(turn) and turn[j] != 0.0:
                pieces.append(
                    (float(radius[j] * abs(turn[j])), float(np.sign(turn[j]) / radius[j]))
                )
        return cls(tuple(pieces), start=(float(pts[0, 0]), float(pts[0, 1]), float(heading[0])))

    @property
    def length_m(self) -> float:
        """Length of the route."""
        return float(sum(p[0] for p in self.pieces))

    @cached_property
    def starts(self) -> tuple[tuple[float, float, float, float], ...]:
        """``(s, x, y, heading)`` at the start of each piece."""
        out = []
        s = 0.0
        x, y, h = self.start
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

    def bend_turns(self) -> tuple[tuple[float, float, float], ...]:
        """``(start, end, turn_rad)`` of each bend (signed turn, positive left).

        A bend is a run of adjacent arcs turning the same way, by at least
        :data:`BEND_MIN_TURN_RAD` in all.
        """
        runs: list[list[float]] = []
        for (s0, _, _, _), (length, k) in zip(self.starts, self.pieces, strict=True):
            if k == 0.0:
                continue
            if runs and runs[-1][1] == s0 and runs[-1][2] * k > 0:
                runs[-1][1] = s0 + length
                runs[-1][2] += k * length
            else:
                runs.append([s0, s0 + length, k * length])
        return tuple((a, b, t) for a, b, t in runs if abs(t) >= BEND_MIN_TURN_RAD)

    def bends(self) -> tuple[tuple[float, float], ...]:
        """``(start, end)`` stations of the bends (:meth:`bend_turns`)."""
        return tuple((a, b) for a, b, _ in self.bend_turns())

    def in_bend(self, s: npt.ArrayLike, margin_m: float = 0.0) -> npt.NDArray[np.bool_]:
        """Whether stations ``s`` lie within ``margin_m`` of an arc."""
        st = np.atleast_1d(np.asarray(s, dtype=np.float64))
        out = np.zeros(st.shape, dtype=bool)
        for a, b in self.bends():
            out |= (st > a - margin_m) & (st < b + margin_m)
        return out

    def offset(self, lateral_m: float) -> PiecewiseRoute:
        """The route ``lateral_m`` to the left of this one (an arc keeps its centre).

        Raises:
            ValueError: The offset reaches an arc's centre.
        """
        pieces = []
        for length, k in self.pieces:
            scale = 1.0 - k * lateral_m
            if scale <= 0.0:
                msg = f"an offset of {lateral_m} m reaches the centre of an arc of radius {1 / k}"
                raise ValueError(msg)
            pieces.append((length * scale, k / scale))
        xy, h = self.points([0.0], lateral_m)
        return PiecewiseRoute(tuple(pieces), start=(float(xy[0, 0]), float(xy[0, 1]), float(h[0])))

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
