"""The recorded speed along the route, for a closed loop that drives at the driver's speeds.

A steering policy decides only where the car goes; how fast it goes is the test's choice. The
published tool holds one speed (10 km/h, its drives' pace). A real drive does not: KITTI 03
starts at 35 km/h and takes its sharp right turn at 9 km/h, and no steering takes that turn at
35. :class:`SpeedProfile` gives the recorded speed at the route point nearest to the car, so
the simulator's speed controller slows where the driver slowed. The nearest point is searched
in a window ahead of the last one (a route that crosses itself keeps its place), vectorised
over the window.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Final

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy.typing as npt

__all__ = ["MIN_PROFILE_SPEED", "SPEED_CHANGE_SHARE", "SpeedProfile"]

MIN_PROFILE_SPEED: Final = 1.5
"""m/s: the profile never asks for less, so that a stop in the recording (a red light, the
drive's end) does not halt the simulated car, which would end the run as stuck."""

SPEED_CHANGE_SHARE: Final = 0.25
"""A recording whose smoothed speed departs from its start speed by more than this share
somewhere along the route changes speed (:meth:`SpeedProfile.changes_speed`): ``cam2sim run``
then drives at the recorded speed by default. The synthetic drives hold one speed (their
smoothed speeds stay within a few per cent of it); KITTI 03 goes from 9.6 m/s to 2.4."""

_BEHIND: Final = 5
"""Route points behind the last nearest one that the search looks at."""


@dataclass(frozen=True)
class SpeedProfile:
    """Recorded speeds at the route's points.

    Attributes:
        xy: ``[N, 2]`` route points, world frame, metres (the vehicle centre's, as the
            simulator's state).
        speed: ``[N]`` speed there, m/s, smoothed, at least :data:`MIN_PROFILE_SPEED`.
        ahead: Route points ahead of the last nearest one that the search looks at.
    """

    xy: npt.NDArray[np.float64]
    speed: npt.NDArray[np.float64]
    ahead: int = 100

    @classmethod
    def recorded(
        cls,
        xy: Sequence[Sequence[float]],
        speed: Sequence[float],
        t: Sequence[float],
        *,
        smooth_s: float = 1.0,
    ) -> SpeedProfile:
        """The profile of a recorded drive: its speeds averaged over ``smooth_s`` seconds.

        Raises:
            ValueError: The columns differ in length, or hold fewer than two samples.
        """
        points = np.asarray(xy, dtype=np.float64)[:, :2]
        v = np.asarray(speed, dtype=np.float64)
        times = np.asarray(t, dtype=np.float64)
        if not (len(points) == len(v) == len(times)) or len(v) < 2:
            msg = f"a speed profile needs matching columns of 2+ samples, got {len(points)}, "
            msg += f"{len(v)}, {len(times)}"
            raise ValueError(msg)
        v = np.where(np.isfinite(v), v, 0.0)
        # Centred moving average over +-smooth_s/2, by cumulative sums (no loop).
        lo = np.searchsorted(times, times - smooth_s / 2, side="left")
        hi = np.searchsorted(times, times + smooth_s / 2, side="right")
        sums = np.concatenate([[0.0], np.cumsum(v)])
        smooth = (sums[hi] - sums[lo]) / np.maximum(hi - lo, 1)
        return cls(points, np.maximum(smooth, MIN_PROFILE_SPEED))

    def nearest(self, x: float, y: float, last: int | None = None) -> int:
        """The index of the route point nearest to ``(x, y)``, searched near ``last``.

        ``last`` None searches the whole route (the first call of an episode).
        """
        start = 0 if last is None else max(0, last - _BEHIND)
        stop = len(self.xy) if last is None else min(len(self.xy), last + self.ahead + 1)
        window = self.xy[start:stop]
        d2 = (window[:, 0] - x) ** 2 + (window[:, 1] - y) ** 2
        return start + int(np.argmin(d2))

    def changes_speed(self, held: float, share: float = SPEED_CHANGE_SHARE) -> bool:
        """Whether the recorded speed departs from ``held`` (m/s) by more than ``share`` of it.

        A stop or crawl below :data:`MIN_PROFILE_SPEED` counts at that speed (the profile
        never asks for less).
        """
        reference = max(float(held), MIN_PROFILE_SPEED)
        return bool(np.any(np.abs(self.speed - reference) > share * reference))

    def span_kmh(self) -> tuple[float, float]:
        """The slowest and fastest speed of the profile, km/h (for messages)."""
        return float(self.speed.min() * 3.6), float(self.speed.max() * 3.6)
