"""An ego trajectory in the world frame, and sampling it at sensor times.

:class:`Trajectory` holds time-stamped body poses (position of the reference point and body
orientation, x forward, y left, z up). :meth:`Trajectory.sample` interpolates it at arbitrary
times (linear positions, slerp orientations) and says which times could not be served and why:
outside the pose coverage, or inside a gap longer than the allowed maximum.

A slow position source (a GPS receiver at 1 Hz: 8 m between fixes at 30 km/h) is no gap: the
allowed gap grows with the source's own interval (:func:`gap_limit_s`), and positions without
an orientation are first resampled along a cubic through the fixes (:func:`densify_positions`),
so a 10 m-radius turn between 1 Hz fixes is not cut short by up to 0.8 m of straight chords.
Before that their jitter is smoothed away (:func:`smooth_positions`): a heading, a speed and a
path curvature taken from 10 Hz fixes carry it otherwise (0.1 m of jitter is 0.7 m/s of speed
over 0.2 s).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from cam2sim.core import frames
from cam2sim.core.polyline import arc_length

__all__ = [
    "DropReason",
    "Trajectory",
    "TrajectorySample",
    "densify_positions",
    "gap_limit_s",
    "heading_from_motion",
    "heading_off_travel",
    "orientation_from_motion",
    "pitch_from_motion",
    "smooth_positions",
]


GAP_INTERVALS: Final = 2.5
"""A pose gap is longer than this many of the source's median intervals (and than the configured
limit): one missing fix of a 1 Hz GPS is bridged, a dropout of several seconds is not."""


def gap_limit_s(stamp_ns: npt.ArrayLike, configured_s: float) -> float:
    """The longest pose gap to interpolate across.

    ``configured_s``, or :data:`GAP_INTERVALS` of the source's median interval where the source
    is slower.
    """
    t = np.asarray(stamp_ns, dtype=np.int64)
    if t.shape[0] < 2:
        return configured_s
    median = float(np.median(np.diff(np.sort(t)))) / 1e9
    return max(configured_s, GAP_INTERVALS * median)


def densify_positions(
    stamp_ns: npt.ArrayLike,
    position: npt.ArrayLike,
    *,
    max_gap_s: float,
    rate_hz: float = 10.0,
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]:
    """Positions slower than ``rate_hz`` resampled at ``rate_hz`` along a cubic through them.

    Each interval of at most ``max_gap_s`` gets points every ``1 / rate_hz`` seconds on the
    cubic Hermite curve whose tangents are the neighbours' central differences in time
    (Catmull-Rom for uneven times): it passes through every fix and follows a turn between
    them. Longer intervals (gaps) are left alone. The fixes themselves are kept.

    Returns:
        ``(stamps, positions)``, sorted; the input when it is already at ``rate_hz`` or
        faster, or has fewer than 3 fixes.
    """
    t = np.asarray(stamp_ns, dtype=np.int64)
    p = np.asarray(position, dtype=np.float64).reshape(len(t), -1)
    order = np.argsort(t, kind="stable")
    t, p = t[order], p[order]
    dt = np.diff(t).astype(np.float64) / 1e9
    if len(t) < 3 or float(np.median(dt)) <= 1.5 / rate_hz:
        return t, p
    tangent = _velocities(t.astype(np.float64) / 1e9, p, dt > max_gap_s)
    per = np.where(dt <= max_gap_s, np.floor(dt * rate_hz - 1e-9).astype(np.int64), 0)
    k = np.repeat(np.arange(len(dt)), per)  # the interval of each new point
    first = np.cumsum(per) - per
    u = (np.arange(int(per.sum())) - first[k] + 1) / (per[k] + 1.0)  # in (0, 1)
    h00, h10 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u
    h01, h11 = -2 * u**3 + 3 * u**2, u**3 - u**2
    span = dt[k][:, None]
    new = (
        h00[:, None] * p[k] + h10[:, None] * span * tangent[k]
        + h01[:, None] * p[k + 1] + h11[:, None] * span * tangent[k + 1]
    )  # fmt: skip
    new_t = t[k] + np.round(u * dt[k] * 1e9).astype(np.int64)
    stamps = np.concatenate([t, new_t])
    merged = np.argsort(stamps, kind="stable")
    return stamps[merged], np.concatenate([p, new])[merged]


MIN_SMOOTHED_FIXES: Final = 5
"""A run of fixes between gaps shorter than this is left as it is (too few to tell noise)."""


def smooth_positions(
    stamp_ns: npt.ArrayLike, position: npt.ArrayLike, *, max_gap_s: float
) -> tuple[npt.NDArray[np.float64], float]:
    """Positions without orientation (GPS fixes) with their jitter smoothed away.

    Each coordinate of each run of fixes between gaps (intervals longer than ``max_gap_s``) is
    replaced by a cubic smoothing spline in time whose smoothness generalised cross-validation
    picks from the fixes themselves (``scipy.interpolate.make_smoothing_spline``): white jitter
    goes, the path's turns and a slow drift (which no filter can tell from the road) stay. On
    KITTI 03 written as 10 Hz fixes with 0.1 m jitter: 0.098 m of jitter -> 0.018 m, speed error
    0.73 -> 0.17 m/s. Fixes sharing a stamp are averaged first; a run of fewer than
    :data:`MIN_SMOOTHED_FIXES` stamps is left alone.

    Returns:
        ``(positions, change_rms_m)``: ``(N, D)`` positions in the input's order, and the RMS
        distance they moved (a measure of the jitter removed).
    """
    from scipy.interpolate import make_smoothing_spline  # noqa: PLC0415 -- lazy: heavy

    t = np.asarray(stamp_ns, dtype=np.int64).reshape(-1)
    p = np.asarray(position, dtype=np.float64).reshape(len(t), -1)
    if len(t) < MIN_SMOOTHED_FIXES:
        return p.copy(), 0.0
    unique, inverse, count = np.unique(t, return_inverse=True, return_counts=True)
    mean = np.zeros((len(unique), p.shape[1]))
    np.add.at(mean, inverse, p)
    mean /= count[:, None]
    sec = (unique - unique[0]).astype(np.float64) / 1e9
    fitted = mean.copy()
    for lo, hi in _runs(np.diff(sec) > max_gap_s):  # one fit a run of fixes, not one a point
        if hi - lo < MIN_SMOOTHED_FIXES:
            continue
        x = sec[lo:hi] - sec[lo]
        try:
            fitted[lo:hi] = np.stack(
                [make_smoothing_spline(x, mean[lo:hi, k])(x) for k in range(p.shape[1])], -1
            )
        except (ValueError, np.linalg.LinAlgError):  # degenerate run: keep the fixes
            continue
    out = fitted[inverse]
    change = np.linalg.norm(out - p, axis=1)
    return out, float(np.sqrt(np.mean(change**2)))


def _runs(gap: npt.NDArray[np.bool_]) -> list[tuple[int, int]]:
    """``(start, stop)`` of each run of samples between the intervals marked ``gap``."""
    bounds = np.concatenate([[0], np.flatnonzero(gap) + 1, [len(gap) + 1]])
    return [(int(lo), int(hi)) for lo, hi in itertools.pairwise(bounds)]


def _velocities(
    t: npt.NDArray[np.float64], p: npt.NDArray[np.float64], gap: npt.NDArray[np.bool_]
) -> npt.NDArray[np.float64]:
    """``(N, D)`` velocities at the fixes.

    Second-order differences within each run of fixes between gaps, one-sided at a run's ends,
    so that no tangent spans a gap.
    """
    out = np.zeros_like(p)
    for lo, hi in _runs(gap):  # one call a run of fixes, not one a point
        if hi - lo >= 3:
            out[lo:hi] = np.gradient(p[lo:hi], t[lo:hi], axis=0, edge_order=2)
        elif hi - lo == 2:
            out[lo:hi] = (p[lo + 1] - p[lo]) / (t[lo + 1] - t[lo])
    return out


class DropReason:
    """Why a sensor sample got no pose (names used in ``dataset.json``)."""

    OUTSIDE = "outside_pose_coverage"
    GAP = "pose_gap"


@dataclass(frozen=True)
class TrajectorySample:
    """Poses interpolated at query times.

    Attributes:
        valid: ``(M,)`` bool, whether the query time got a pose.
        reason: ``(M,)`` str, empty for valid queries, else a :class:`DropReason` value.
        position: ``(K, 3)`` world metres for the K valid queries.
        quat: ``(K, 4)`` body orientation (x, y, z, w) in the world frame.
        heading: ``(K,)`` radians CCW from +x (east).
        speed: ``(K,)`` m/s.
    """

    valid: npt.NDArray[np.bool_]
    reason: npt.NDArray[np.str_]
    position: npt.NDArray[np.float64]
    quat: npt.NDArray[np.float64]
    heading: npt.NDArray[np.float64]
    speed: npt.NDArray[np.float64]


@dataclass(frozen=True)
class Trajectory:
    """Time-stamped body poses in the world frame.

    Attributes:
        stamp_ns: ``(N,)`` int64, strictly increasing, N >= 2.
        position: ``(N, 3)`` float64 world metres of the vehicle reference point.
        quat: ``(N, 4)`` float64 (x, y, z, w) body orientation (x forward, y left, z up).
    """

    stamp_ns: npt.NDArray[np.int64]
    position: npt.NDArray[np.float64]
    quat: npt.NDArray[np.float64]

    def __post_init__(self) -> None:
        n = self.stamp_ns.shape[0]
        if n < 2 or self.position.shape != (n, 3) or self.quat.shape != (n, 4):
            msg = (
                f"trajectory needs N >= 2 samples with positions (N, 3) and quats (N, 4); got "
                f"{self.stamp_ns.shape}, {self.position.shape}, {self.quat.shape}"
            )
            raise ValueError(msg)

    @property
    def heading(self) -> npt.NDArray[np.float64]:
        """``(N,)`` heading of every sample, radians."""
        return frames.yaw_from_quat(self.quat)

    def speed_at(
        self, query_ns: npt.NDArray[np.int64], *, window_s: float
    ) -> npt.NDArray[np.float64]:
        """Speed (m/s) at query times: distance over a centred window, clipped to the coverage."""
        half = int(window_s * 5e8)
        t0 = np.clip(query_ns - half, self.stamp_ns[0], self.stamp_ns[-1])
        t1 = np.clip(query_ns + half, self.stamp_ns[0], self.stamp_ns[-1])
        rel = (self.stamp_ns - self.stamp_ns[0]).astype(np.float64)
        a = np.stack([np.interp(t0 - self.stamp_ns[0], rel, c) for c in self.position.T], -1)
        b = np.stack([np.interp(t1 - self.stamp_ns[0], rel, c) for c in self.position.T], -1)
        dt = (t1 - t0).astype(np.float64) / 1e9
        dist = np.linalg.norm((b - a)[:, :2], axis=1)
        speed: npt.NDArray[np.float64] = np.divide(dist, dt, out=np.zeros_like(dist), where=dt > 0)
        return speed

    def sample(
        self, query_ns: npt.NDArray[np.int64], *, max_gap_s: float, speed_window_s: float = 0.2
    ) -> TrajectorySample:
        """Interpolate the trajectory at ``query_ns`` (int64 nanoseconds).

        Queries outside ``[stamp_ns[0], stamp_ns[-1]]`` or between two samples further apart than
        ``max_gap_s`` are marked invalid with their reason.
        """
        query_ns = np.asarray(query_ns, dtype=np.int64)
        reason = np.full(query_ns.shape[0], "", dtype=object)
        outside = (query_ns < self.stamp_ns[0]) | (query_ns > self.stamp_ns[-1])
        reason[outside] = DropReason.OUTSIDE
        idx = np.clip(np.searchsorted(self.stamp_ns, query_ns, side="right"), 1, len(self) - 1)
        max_gap_ns = int(max_gap_s * 1e9) if np.isfinite(max_gap_s) else np.iinfo(np.int64).max
        gap = (self.stamp_ns[idx] - self.stamp_ns[idx - 1]) > max_gap_ns
        below = np.clip(np.searchsorted(self.stamp_ns, query_ns, side="left"), 0, len(self) - 1)
        exact = self.stamp_ns[below] == query_ns
        gap &= ~outside & ~exact
        reason[gap] = DropReason.GAP
        valid = ~outside & ~gap
        q = query_ns[valid]
        if q.size:
            s = frames.interpolate_poses(self.stamp_ns, self.position, self.quat, q)
            pos, quat = s.positions, s.quats
        else:
            pos, quat = np.zeros((0, 3)), np.zeros((0, 4))
        return TrajectorySample(
            valid=valid,
            reason=reason.astype(str),
            position=pos,
            quat=quat,
            heading=frames.yaw_from_quat(quat) if q.size else np.zeros(0),
            speed=self.speed_at(q, window_s=speed_window_s),
        )

    def __len__(self) -> int:
        return int(self.stamp_ns.shape[0])


def heading_from_motion(
    stamp_ns: npt.NDArray[np.int64],
    position: npt.NDArray[np.float64],
    *,
    window_s: float,
    min_speed_mps: float,
) -> npt.NDArray[np.float64]:
    """Heading (radians) from the direction of travel over a centred time window.

    Below ``min_speed_mps`` the heading of the nearest moving sample is held (forward, then
    backward fill). If the vehicle never moves, the heading is 0 everywhere.
    """
    traj = Trajectory(stamp_ns, position, np.tile([0.0, 0.0, 0.0, 1.0], (len(stamp_ns), 1)))
    half = int(window_s * 5e8)
    t0 = np.clip(stamp_ns - half, stamp_ns[0], stamp_ns[-1])
    t1 = np.clip(stamp_ns + half, stamp_ns[0], stamp_ns[-1])
    rel = (stamp_ns - stamp_ns[0]).astype(np.float64)
    a = np.stack([np.interp(t0 - stamp_ns[0], rel, c) for c in position[:, :2].T], -1)
    b = np.stack([np.interp(t1 - stamp_ns[0], rel, c) for c in position[:, :2].T], -1)
    d = b - a
    heading = np.arctan2(d[:, 1], d[:, 0])
    moving = traj.speed_at(stamp_ns, window_s=window_s) >= max(min_speed_mps, 1e-6)
    if not moving.any():
        return np.zeros(len(stamp_ns))
    idx = np.where(moving, np.arange(len(stamp_ns)), -1)
    idx = np.maximum.accumulate(idx)
    first = int(np.flatnonzero(moving)[0])
    idx[idx < 0] = first
    return frames.unwrap_angles(heading[idx])


def heading_off_travel(
    position: npt.ArrayLike, heading: npt.ArrayLike, *, chord_m: float = 4.0
) -> npt.NDArray[np.float64]:
    """``(N,)`` how far each given heading is from the direction of travel, radians.

    The direction of travel at a sample is the chord from the path ``chord_m / 2`` behind it
    to ``chord_m / 2`` ahead (by arc length, so standing still and odd timing do not matter);
    samples whose chord is shorter than half ``chord_m`` (the path's ends, a car standing
    still) are NaN. A recorded orientation follows the travel within a few degrees (a sensor
    mounted askew, a pose point's slip in a turn); tens of degrees on most samples are a
    convention mistake (degrees read as radians, compass headings read as ENU yaw).

    Args:
        position: ``(N, 2+)`` positions in path order, metres.
        heading: ``(N,)`` the recorded headings, radians counter-clockwise from +x.
        chord_m: Length of the chord that gives the direction of travel, metres.
    """
    p = np.asarray(position, dtype=np.float64)
    p = p.reshape(len(p), -1)[:, :2]
    h = np.asarray(heading, dtype=np.float64).reshape(-1)
    out = np.full(len(p), np.nan)
    if len(p) < 2:
        return out
    s = arc_length(p)
    lo = np.clip(np.searchsorted(s, s - 0.5 * chord_m, side="left"), 0, len(p) - 1)
    hi = np.clip(np.searchsorted(s, s + 0.5 * chord_m, side="right") - 1, 0, len(p) - 1)
    d = p[hi] - p[lo]
    ok = np.hypot(d[:, 0], d[:, 1]) >= 0.5 * chord_m
    travel = np.arctan2(d[:, 1], d[:, 0])
    out[ok] = frames.angle_difference(h[ok], travel[ok])
    return out


def pitch_from_motion(
    position: npt.NDArray[np.float64], *, window_m: float
) -> npt.NDArray[np.float64]:
    """Pitch (radians, ROS: positive nose down) from the grade of the path over a centred window.

    A car pitches with its road: the grade is the height gained over a chord of ``window_m``
    metres of horizontal travel centred on each pose (shrunk at the ends of the path). Counted
    in metres, not seconds, so slow driving and standing still do not amplify the height's
    noise (0.1 m of GPS noise over 15 m: 0.5 degrees). Positions without heights give 0.

    Args:
        position: ``(N, 3)`` positions in time order, metres (z up).
        window_m: Chord length, metres.
    """
    p = np.asarray(position, dtype=np.float64).reshape(-1, 3)
    if len(p) < 2:
        return np.zeros(len(p))
    s = arc_length(p[:, :2])
    if not s[-1] > 0:
        return np.zeros(len(p))
    # Heights at equal arc lengths: repeated s (standing still) keeps the first sample's height.
    s_unique, first = np.unique(s, return_index=True)
    z = p[first, 2]
    s0 = np.clip(s - 0.5 * window_m, 0.0, s[-1])
    s1 = np.clip(s + 0.5 * window_m, 0.0, s[-1])
    rise = np.interp(s1, s_unique, z) - np.interp(s0, s_unique, z)
    run = s1 - s0
    pitch = np.where(run > 0, -np.arctan2(rise, np.maximum(run, 1e-9)), 0.0)
    return np.asarray(pitch, dtype=np.float64)


def orientation_from_motion(
    stamp_ns: npt.NDArray[np.int64],
    position: npt.NDArray[np.float64],
    *,
    window_s: float,
    min_speed_mps: float,
    pitch_window_m: float,
) -> npt.NDArray[np.float64]:
    """``(N, 4)`` quaternions for poses that give none (GPS fixes), in time order.

    The heading is :func:`heading_from_motion`'s, the pitch :func:`pitch_from_motion`'s, the
    roll zero.
    """
    heading = heading_from_motion(
        stamp_ns, position, window_s=window_s, min_speed_mps=min_speed_mps
    )
    pitch = pitch_from_motion(position, window_m=pitch_window_m)
    return frames.quat_from_euler(0.0, pitch, heading)
