"""Room on the road for the car that drove it: lanes widened where the recorded car's body swept.

A road built from the driven path (:mod:`cam2sim.map.trajectory_road`) puts the recorded car in
the middle of a lane of fixed width. Where the car turned tightly (a junction, a U-turn) its body
swept wider than the path of its pose point: the front corner outside the turn, the rear corner
inside it (a 4.5 m car on a 7 m turn: 0.9 m beyond its half width). A real junction has that
room; a lane of 3.35 m does not, so the recorded drive itself would leave such a road, and every
closed-loop run that follows it a little wider is called off the road for the map's sake.

:func:`lane_widening` measures, along the path, how far the recorded footprint's corners came
beyond the lanes' outer edges, with ``room_m`` to spare, and returns how much wider the
outermost lane on each side must be there (tapered in and out over ``taper_m``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = ["LaneWidening", "RecordedBody", "lane_widening"]


@dataclass(frozen=True, eq=False)
class RecordedBody:
    """The recorded car's footprint, to place along the road's path.

    Attributes:
        length_m: Footprint length.
        width_m: Footprint width.
        reference_xy: Where the poses sit on the car, from the footprint's centre (x forward,
            y left), metres.
        heading: ``(N,)`` the recorded headings, one a pose (unwrapped or not), when the poses
            had an orientation; None: the car points along the path (a GPS drive, whose
            heading is its noisy direction of travel).
    """

    length_m: float
    width_m: float
    reference_xy: tuple[float, float]
    heading: npt.NDArray[np.float64] | None = None

    def corners(
        self, point: npt.NDArray[np.float64], heading: npt.NDArray[np.float64]
    ) -> npt.NDArray[np.float64]:
        """``(N, 4, 2)``: the footprint with its pose point at ``point``, headed ``heading``."""
        c, s = np.cos(heading), np.sin(heading)
        rx, ry = self.reference_xy
        centre = point - np.column_stack([c * rx - s * ry, s * rx + c * ry])
        hl, hw = self.length_m / 2, self.width_m / 2
        signs = np.array([[1.0, 1.0], [1.0, -1.0], [-1.0, -1.0], [-1.0, 1.0]])
        fwd = np.column_stack([c, s])[:, None, :]
        left = np.column_stack([-s, c])[:, None, :]
        out: npt.NDArray[np.float64] = (
            centre[:, None, :] + signs[None, :, :1] * hl * fwd + signs[None, :, 1:] * hw * left
        )
        return out


@dataclass(frozen=True)
class LaneWidening:
    """How much wider the outermost driving lane on each side must be, at given stations.

    Attributes:
        right_m: ``(K,)`` extra width of the outermost right lane (lane ``-lanes``), metres.
        left_m: ``(K,)`` extra width of the outermost left lane (lane ``+lanes``), metres.
    """

    right_m: npt.NDArray[np.float64]
    left_m: npt.NDArray[np.float64]

    @property
    def widest_m(self) -> float:
        """The largest widening on either side."""
        return float(max(self.right_m.max(initial=0.0), self.left_m.max(initial=0.0)))


def _frame_at(
    s: npt.NDArray[np.float64],
    path_s: npt.NDArray[np.float64],
    path_xy: npt.NDArray[np.float64],
    heading: npt.NDArray[np.float64],
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """The path's point and unit tangent at stations ``s`` (clamped to the path)."""
    point = np.column_stack([np.interp(s, path_s, path_xy[:, k]) for k in range(2)])
    h = np.interp(s, path_s, heading)
    return point, np.column_stack([np.cos(h), np.sin(h)])


def lane_widening(  # noqa: PLR0913
    path_s: npt.ArrayLike,
    path_xy: npt.ArrayLike,
    heading: npt.ArrayLike,
    corners_xy: npt.ArrayLike,
    corners_s: npt.ArrayLike,
    *,
    band: tuple[float, float],
    stations: npt.ArrayLike,
    room_m: float = 0.5,
    taper_m: float = 10.0,
    hold_m: float = 2.0,
) -> LaneWidening:
    """The widening of the outermost lanes that gives the recorded footprint ``room_m``.

    Args:
        path_s: ``(P,)`` stations of the car's path (the line its lane is centred on), rising.
        path_xy: ``(P, 2)`` the path.
        heading: ``(P,)`` its unwrapped heading, radians.
        corners_xy: ``(M, 2)`` the recorded footprint's corners (all samples).
        corners_s: ``(M,)`` each corner's station, roughly (its sample's station): refined here
            by projecting onto the path's tangent near it, so a path that comes back along
            itself never takes a corner for the other pass.
        band: The drivable road's lateral extent from the path, ``(right, left)`` metres
            (right negative), before any widening.
        stations: ``(K,)`` path stations to give the widening at.
        room_m: Space to keep between a corner and the road's edge.
        taper_m: A widening grows in and out linearly over this length.
        hold_m: Each need holds for this far either side of its station (the spacing of
            ``stations``: a width linear between them then never dips below a need).

    Returns:
        The extra width of the right and left outermost lanes at ``stations``.
    """
    ps = np.asarray(path_s, dtype=np.float64)
    pxy = np.asarray(path_xy, dtype=np.float64).reshape(-1, 2)
    hd = np.asarray(heading, dtype=np.float64)
    cxy = np.asarray(corners_xy, dtype=np.float64).reshape(-1, 2)
    cs = np.clip(np.asarray(corners_s, dtype=np.float64).reshape(-1), ps[0], ps[-1])
    for _ in range(3):  # Newton steps along the tangent: the corner's own station
        point, tangent = _frame_at(cs, ps, pxy, hd)
        cs = np.clip(cs + np.einsum("ij,ij->i", cxy - point, tangent), ps[0], ps[-1])
    point, tangent = _frame_at(cs, ps, pxy, hd)
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])  # left of the path
    lateral = np.einsum("ij,ij->i", cxy - point, normal)
    need_right = np.maximum(band[0] + room_m - lateral, 0.0)  # past the right edge (negative)
    need_left = np.maximum(lateral - (band[1] - room_m), 0.0)
    at = np.asarray(stations, dtype=np.float64).reshape(-1)
    return LaneWidening(
        _profile(cs, need_right, at, taper_m, hold_m), _profile(cs, need_left, at, taper_m, hold_m)
    )


def _profile(
    s: npt.NDArray[np.float64],
    need: npt.NDArray[np.float64],
    at: npt.NDArray[np.float64],
    taper_m: float,
    hold_m: float,
    step_m: float = 0.25,
) -> npt.NDArray[np.float64]:
    """The lowest profile over ``at`` that covers each ``need`` at its station ``s``.

    It falls by the largest need over ``taper_m`` a metre. The needs are binned on a
    ``step_m`` grid (their maximum a bin); the maximum of the tents is then two running maxima:
    ``max_j (g_j - fall |i - j|)`` is ``cummax(g + fall j) - fall i`` from the left and the
    mirror image from the right. Each need first spreads flat over ``hold_m`` either side (a
    running maximum over that window).
    """
    if at.size == 0 or not np.any(need > 0):
        return np.zeros(at.shape[0])
    lo = float(min(s.min(), at.min()))
    n = int(np.ceil((max(s.max(), at.max()) - lo) / step_m)) + 1
    grid = np.zeros(n)
    np.maximum.at(grid, np.clip(np.round((s - lo) / step_m).astype(np.int64), 0, n - 1), need)
    half = int(np.ceil(hold_m / step_m))
    if half > 0:
        padded = np.pad(grid, half)
        grid = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1).max(axis=1)
    fall = float(need.max()) / max(taper_m, 1e-6) * step_m
    idx = np.arange(n, dtype=np.float64)
    ahead = np.maximum.accumulate(grid + fall * idx) - fall * idx
    behind = (np.maximum.accumulate((grid - fall * idx)[::-1]))[::-1] + fall * idx
    tents = np.maximum(np.maximum(ahead, behind), 0.0)
    return np.interp(at, lo + step_m * idx, tents)
