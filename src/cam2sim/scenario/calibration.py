"""Fitting the steering calibration from a recording: curvature per steering unit.

The recorded path's curvature (from the poses, resampled by arc length and smoothed over a few
metres) is regressed on the recorded steering signal at the same times; the slope is the
:class:`~cam2sim.core.vehicle.SteeringCalibration`'s ``curvature_per_unit``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from cam2sim.core.errors import ConfigError
from cam2sim.core.polyline import arc_length
from cam2sim.core.vehicle import SteeringCalibration

__all__ = [
    "POSE_POINT_TOLERANCE_M",
    "PathCurvature",
    "PosePoint",
    "fit_pose_point",
    "fit_steering_calibration",
    "path_curvature",
    "steering_from_poses",
]


@dataclass(frozen=True)
class PathCurvature:
    """A driven path's curvature, sampled every ``spacing_m`` metres of arc length.

    Attributes:
        s: ``(K,)`` arc length of each sample, metres.
        t: ``(K,)`` when the vehicle reached it, seconds.
        kappa: ``(K,)`` curvature (1/m, positive turning left): the heading's change over a
            centred window of ``2 * half`` samples.
        speed: ``(K,)`` the slowest speed within that window, m/s.
        xy: ``(K, 2)`` the path's position at each sample.
        heading: ``(K,)`` its recorded heading there (unwrapped), radians.
        full: ``(K,)`` whether the window lies whole within the path (not cut at an end).
        half: Samples on each side of the window.
        length_m: The whole path's length.
    """

    s: npt.NDArray[np.float64]
    t: npt.NDArray[np.float64]
    kappa: npt.NDArray[np.float64]
    speed: npt.NDArray[np.float64]
    xy: npt.NDArray[np.float64]
    heading: npt.NDArray[np.float64]
    full: npt.NDArray[np.bool_]
    half: int
    length_m: float

    def valid_at(self, min_speed: float) -> npt.NDArray[np.bool_]:
        """Samples with a whole window, driven at ``min_speed`` or faster."""
        ok: npt.NDArray[np.bool_] = self.full & (self.speed >= min_speed)
        return ok


def path_curvature(
    t_pose: npt.ArrayLike,
    xy: npt.ArrayLike,
    heading: npt.ArrayLike,
    speed: npt.ArrayLike,
    *,
    spacing_m: float = 0.5,
    window_m: float = 3.0,
) -> PathCurvature:
    """The curvature of a driven path (see :func:`fit_steering_calibration`).

    The path is resampled by arc length, so bursty pose timestamps and standing still do not
    matter; the heading is unwrapped first.
    """
    tp = np.asarray(t_pose, dtype=np.float64).reshape(-1)
    p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    hd = np.asarray(heading, dtype=np.float64).reshape(-1)
    sp = np.asarray(speed, dtype=np.float64).reshape(-1)
    order = np.argsort(tp, kind="stable")
    tp, p, hd, sp = tp[order], p[order], np.unwrap(hd[order]), sp[order]
    s = arc_length(p)
    grid = np.arange(0.0, s[-1], spacing_m) if s[-1] > spacing_m else np.zeros(0)
    # Arc length only grows while moving; take the first pose reaching each grid station.
    keep = np.concatenate([[True], np.diff(s) > 0])
    s_k, t_k, h_k, v_k = s[keep], tp[keep], hd[keep], sp[keep]
    half = max(1, round(window_m / spacing_m))
    t_g = np.interp(grid, s_k, t_k)
    h_g = np.interp(grid, s_k, h_k)
    xy_g = np.stack([np.interp(grid, s_k, p[keep, 0]), np.interp(grid, s_k, p[keep, 1])], -1)
    v_g = np.interp(grid, s_k, v_k)
    idx = np.arange(grid.shape[0])
    lo = np.clip(idx - half, 0, max(grid.shape[0] - 1, 0))
    hi = np.clip(idx + half, 0, max(grid.shape[0] - 1, 0))
    with np.errstate(invalid="ignore", divide="ignore"):
        kappa = (h_g[hi] - h_g[lo]) / (grid[hi] - grid[lo])
    return PathCurvature(
        s=grid,
        t=t_g,
        kappa=np.nan_to_num(kappa),
        speed=np.minimum(np.minimum(v_g[lo], v_g[hi]), v_g) if grid.size else v_g,
        xy=xy_g,
        heading=h_g,
        full=(hi - lo) == 2 * half,
        half=half,
        length_m=float(s[-1]) if s.size else 0.0,
    )


def steering_from_poses(
    t_pose: npt.ArrayLike,
    xy: npt.ArrayLike,
    heading: npt.ArrayLike,
    speed: npt.ArrayLike,
    calibration: SteeringCalibration,
    *,
    min_speed: float = 2.0,
    spacing_m: float = 0.5,
    window_m: float = 1.0,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """A steering signal for a recording that has none: the path's curvature in steering units.

    The kinematic bicycle model turns a wheel angle ``delta`` into the curvature of the rear
    axle's path, ``tan(delta) / wheelbase``; :class:`~cam2sim.core.vehicle.SteeringCalibration`
    maps a steering command to that curvature (``kappa = k * command``). So the command that
    drives the recorded path is ``kappa / k`` with ``kappa`` from :func:`path_curvature` of the
    rear axle's positions (pass those, not a camera's: see :func:`fit_pose_point`). Samples
    slower than ``min_speed`` (and the first and last window) hold the nearest valid value:
    standing still, position jitter has no meaningful curvature. The heading's change is taken
    over a centred window of ``2 * window_m``: on the three reference drives 2 m correlates
    0.996 with the measured steering, 6 m 0.981 (it flattens a sharp turn's peak: 8 % of
    KITTI 03's 7 m-radius junction, enough for the simulated car to fall behind the turn).

    Returns:
        ``(t, steering)``: the times the path's arc-length samples were reached, seconds, and
        the steering command there.

    Raises:
        ConfigError: The path has no stretch driven at ``min_speed`` long enough for a window.
    """
    curve = path_curvature(t_pose, xy, heading, speed, spacing_m=spacing_m, window_m=window_m)
    ok = curve.valid_at(min_speed)
    if not np.any(ok):
        msg = (
            f"the poses drive {curve.length_m:.1f} m with no stretch of {2 * window_m:.0f} m at "
            f"{min_speed} m/s or faster: steering cannot be derived from them"
        )
        raise ConfigError(msg)
    idx = np.arange(curve.s.shape[0])
    nearest = np.interp(idx, idx[ok], idx[ok]).round().astype(np.int64)
    steering = curve.kappa[nearest] / calibration.curvature_per_unit
    return curve.t, steering


@dataclass(frozen=True)
class PosePoint:
    """Where on the car a recording's poses sit along its axis, as its turns show it.

    Attributes:
        ahead_m: Distance of the pose point ahead of the rear axle, metres.
        stderr_m: Standard error of :attr:`ahead_m`.
        yaw_offset_rad: The recorded heading's constant offset from the direction of travel
            on the straights (a sensor mounted askew), radians, positive left.
        samples: Samples the fit kept (0.5 m of path each by default).
        turning: Of those, samples in a turn (curvature at least ``min_curvature``).
    """

    ahead_m: float
    stderr_m: float
    yaw_offset_rad: float
    samples: int
    turning: int

    def __str__(self) -> str:
        return f"{self.ahead_m:.2f} +- {self.stderr_m:.2f} m ahead of the rear axle"

    def disagrees_with(self, ahead_m: float) -> bool:
        """Whether a configured pose point ``ahead_m`` ahead of the rear axle is off this fit.

        Off by more than :data:`POSE_POINT_TOLERANCE_M` or three standard errors.
        """
        return abs(self.ahead_m - ahead_m) > max(POSE_POINT_TOLERANCE_M, 3.0 * self.stderr_m)


POSE_POINT_TOLERANCE_M = 0.3
"""A configured pose point this much off the fitted one is reported (a car posed 0.3 m off
slips 2 degrees wrong at a 10 m radius)."""


def fit_pose_point(  # noqa: PLR0913
    t_pose: npt.ArrayLike,
    xy: npt.ArrayLike,
    heading: npt.ArrayLike,
    speed: npt.ArrayLike,
    *,
    min_speed: float = 2.0,
    min_curvature: float = 0.02,
    min_turning: int = 20,
    spacing_m: float = 0.5,
    window_m: float = 1.0,
) -> PosePoint | None:
    """How far ahead of the rear axle the poses sit, from the slip of the path in the turns.

    A car's rear axle moves along its heading (the kinematic bicycle model); a point ``a``
    metres ahead of it drifts towards the inside of a turn: its direction of travel leaves the
    heading by ``beta`` with ``sin(beta) = a * kappa``, ``kappa`` the heading's change per metre
    that point travels. A camera or GPS antenna ahead of the axle therefore shows the distance
    in every turn (KITTI 03's camera turns with ``beta`` up to 9.5 degrees at ``kappa`` 0.145
    1/m: 0.88 m ahead). ``sin(beta) = a * kappa + b`` is fitted by least squares over the path
    resampled every ``spacing_m`` and refitted without outliers; ``b`` takes a heading that is
    constantly askew of the travel.

    Returns:
        The fit, or None when the drive turns too little (fewer than ``min_turning`` samples
        at ``min_curvature`` or more, driven at ``min_speed`` or faster) to tell.
    """
    curve = path_curvature(t_pose, xy, heading, speed, spacing_m=spacing_m, window_m=window_m)
    n = curve.s.shape[0]
    if n < 2 * curve.half + 3:
        return None
    idx = np.arange(n)
    lo = np.clip(idx - curve.half, 0, n - 1)
    hi = np.clip(idx + curve.half, 0, n - 1)
    chord = curve.xy[hi] - curve.xy[lo]
    course = np.arctan2(chord[:, 1], chord[:, 0])  # a circle's chord is parallel to its middle
    beta = np.remainder(course - curve.heading + np.pi, 2.0 * np.pi) - np.pi
    ok = curve.valid_at(min_speed) & (np.hypot(chord[:, 0], chord[:, 1]) > 0)
    x, y = curve.kappa[ok], np.sin(beta[ok])
    if int(np.sum(np.abs(x) >= min_curvature)) < min_turning:
        return None
    coef, inl, res = _robust_line(x, y, _MIN_SLIP_SCALE)
    turning = int(np.sum(np.abs(x[inl]) >= min_curvature))
    spread = float(np.sum((x[inl] - x[inl].mean()) ** 2))
    if turning < min_turning or not spread > 0:
        return None
    dof = max(int(inl.sum()) - 2, 1)
    return PosePoint(
        ahead_m=float(coef[0]),
        stderr_m=float(np.sqrt(np.sum(res**2) / dof / spread)),
        yaw_offset_rad=float(np.arcsin(np.clip(coef[1], -1.0, 1.0))),
        samples=int(inl.sum()),
        turning=turning,
    )


def _window_mean(values: npt.NDArray[np.float64], half: int) -> npt.NDArray[np.float64]:
    """Centred moving average over ``2 * half + 1`` samples (shrunk at the ends)."""
    c = np.concatenate([[0.0], np.cumsum(values)])
    idx = np.arange(values.shape[0])
    lo = np.clip(idx - half, 0, values.shape[0])
    hi = np.clip(idx + half + 1, 0, values.shape[0])
    out: npt.NDArray[np.float64] = (c[hi] - c[lo]) / (hi - lo)
    return out


def _robust_line(
    x: npt.NDArray[np.float64], y: npt.NDArray[np.float64], floor: float
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_], npt.NDArray[np.float64]]:
    """``y = c[0] x + c[1]`` by least squares, refitted without outliers beyond 3 robust sigma.

    Returns the coefficients, the inliers and their residuals. The robust spread (MAD) is
    floored at ``floor``: clean data can have almost every residual identical.
    """
    a = np.stack([x, np.ones_like(x)], -1)
    coef = np.linalg.lstsq(a, y, rcond=None)[0]
    res = y - a @ coef
    centre = float(np.median(res))
    scale = max(1.4826 * float(np.median(np.abs(res - centre))), floor)
    inl: npt.NDArray[np.bool_] = np.abs(res - centre) <= 3.0 * scale
    fit = np.asarray(np.linalg.lstsq(a[inl], y[inl], rcond=None)[0], dtype=np.float64)
    left: npt.NDArray[np.float64] = y[inl] - a[inl] @ fit
    return fit, inl, left


_MIN_CALIBRATION_CORR = 0.5  # steering must explain the curvature to calibrate it
_MIN_RESIDUAL_SCALE = 1e-4  # 1/m: below any real curvature noise
_MIN_SLIP_SCALE = 1e-3  # sin(slip): 0.06 degrees, below any real heading noise


def fit_steering_calibration(  # noqa: PLR0913
    t_steer: npt.ArrayLike,
    steering: npt.ArrayLike,
    t_pose: npt.ArrayLike,
    xy: npt.ArrayLike,
    heading: npt.ArrayLike,
    speed: npt.ArrayLike,
    *,
    min_speed: float = 2.0,
    spacing_m: float = 0.5,
    window_m: float = 3.0,
) -> SteeringCalibration:
    """Fit the curvature per steering unit from a recording.

    The path is resampled by arc length (so bursty pose timestamps do not matter), its
    curvature is the change of the recorded heading over a centred window of ``2 * window_m``
    metres, and the steering signal, read at the time each arc-length sample was reached, is
    averaged over the same window. Samples below ``min_speed`` are dropped (standing still,
    position jitter makes curvature meaningless). ``kappa = k * steering + offset`` is fitted by
    least squares, then refitted without outliers beyond 3 robust standard deviations.

    Args:
        t_steer: ``(M,)`` steering timestamps, seconds.
        steering: ``(M,)`` steering signal in the policy's unit.
        t_pose: ``(N,)`` pose timestamps, seconds.
        xy: ``(N, 2)`` positions, metres.
        heading: ``(N,)`` headings, radians counter-clockwise from east.
        speed: ``(N,)`` speeds, m/s.
        min_speed: Slowest sample kept, m/s.
        spacing_m: Arc-length resampling step.
        window_m: Half window of the curvature estimate.

    Raises:
        ConfigError: Too little driving above ``min_speed`` or no steering variation to fit.
    """
    ts = np.asarray(t_steer, dtype=np.float64).reshape(-1)
    st = np.asarray(steering, dtype=np.float64).reshape(-1)
    tp = np.asarray(t_pose, dtype=np.float64).reshape(-1)
    p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    hd = np.asarray(heading, dtype=np.float64).reshape(-1)
    sp = np.asarray(speed, dtype=np.float64).reshape(-1)
    if not (ts.shape == st.shape and tp.shape[0] == p.shape[0] == hd.shape[0] == sp.shape[0]):
        msg = (
            f"steering has {ts.shape[0]} stamps for {st.shape[0]} values and the poses "
            f"{tp.shape[0]} stamps for {p.shape[0]} positions, {hd.shape[0]} headings and "
            f"{sp.shape[0]} speeds; pass matching arrays"
        )
        raise ConfigError(msg)
    so = np.argsort(ts, kind="stable")
    ts, st = ts[so], st[so]
    curve = path_curvature(tp, p, hd, sp, spacing_m=spacing_m, window_m=window_m)
    half = curve.half
    if curve.s.shape[0] < 2 * half + 3:
        msg = (
            f"the recording drives {curve.length_m:.1f} m; fitting the steering calibration needs "
            f"at least {(2 * half + 3) * spacing_m:.0f} m of driving (or give curvature_per_unit)"
        )
        raise ConfigError(msg)
    t_g, kappa = curve.t, curve.kappa
    steer_g = _window_mean(np.interp(t_g, ts, st), half)
    ok = curve.valid_at(min_speed) & (t_g >= ts[0]) & (t_g <= ts[-1])
    x, y = steer_g[ok], kappa[ok]
    if x.shape[0] < 10 or np.ptp(x) <= 0:
        msg = (
            f"only {x.shape[0]} samples above {min_speed} m/s with steering variation; the "
            "recording cannot calibrate steering (give curvature_per_unit instead)"
        )
        raise ConfigError(msg)
    coef, inl, res = _robust_line(x, y, _MIN_RESIDUAL_SCALE)
    corr = float(np.corrcoef(x[inl], y[inl])[0, 1]) if inl.sum() > 2 else 0.0
    if not (np.isfinite(coef[0]) and coef[0] > 0 and corr >= _MIN_CALIBRATION_CORR):
        msg = (
            f"the recorded steering does not explain the path's curvature (slope {coef[0]:.3g} "
            f"1/m per unit, correlation {corr:.2f}); it may be another signal or unsynchronised "
            "(give curvature_per_unit instead)"
        )
        raise ConfigError(msg)
    return SteeringCalibration(
        curvature_per_unit=float(coef[0]),
        offset=float(coef[1]),
        source="fitted",
        samples=int(inl.sum()),
        rms_residual=float(np.sqrt(np.mean(res**2))),
    )
