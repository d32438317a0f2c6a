"""The simulator interface: controls in, vehicle states and events out.

Every backend (``builtin``, ``carla``) implements :class:`Simulator`. Positions are in the
workspace's world frame (x east, y north, metres); headings are radians counter-clockwise from
east; speeds are m/s; the wheel angle is the bicycle model's front wheel angle (radians,
positive = left).

The policy's steering command has its own unit (the recording's steering signal). It becomes a
wheel angle through a :class:`SteeringCalibration`: the path curvature per steering unit,
fitted from the recording by :func:`fit_steering_calibration`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt
import pydantic

from cam2sim.core.errors import ConfigError

if TYPE_CHECKING:
    from cam2sim.map.query import RoadMap
    from cam2sim.scenario.model import Scenario

__all__ = [
    "DEFAULT_CURVATURE_PER_UNIT",
    "Control",
    "EventKind",
    "Pose",
    "SimEvent",
    "Simulator",
    "SteeringCalibration",
    "VehicleState",
    "fit_steering_calibration",
]

EventKind = Literal["collision", "off_road", "route_completed", "stuck", "timeout"]

DEFAULT_CURVATURE_PER_UNIT = 0.022
"""Curvature per steering unit (1/m) fitted on the Munich reference drives."""


@dataclass(frozen=True, slots=True)
class Control:
    """One step's command.

    Attributes:
        steering: Steering command in the policy's unit (mapped by the calibration).
        target_speed: Speed to hold, m/s; None keeps the previous target.
        wheel_angle: Direct front wheel angle, radians (replay); overrides ``steering``.
    """

    steering: float = 0.0
    target_speed: float | None = None
    wheel_angle: float | None = None


@dataclass(frozen=True, slots=True)
class Pose:
    """A vehicle pose to reset to: centre on the road surface, heading and speed."""

    x: float
    y: float
    heading: float
    speed: float = 0.0


@dataclass(frozen=True, slots=True)
class VehicleState:
    """The ego vehicle after a step.

    Attributes:
        t: Simulated time since reset, seconds.
        x: Vehicle centre (footprint centre on the ground), world x.
        y: Vehicle centre, world y.
        z: Road surface height at the vehicle.
        heading: Radians counter-clockwise from east.
        speed: m/s (never negative).
        wheel_angle: Front wheel angle, radians, after the angle and rate limits.
        steering: The steering command applied, in the policy's unit (NaN for a direct angle).
        rear_axle: Rear axle centre ``(x, y)``, the bicycle model's reference point.
        progress_m: Arc length reached along the recorded centre trajectory.
    """

    t: float
    x: float
    y: float
    z: float
    heading: float
    speed: float
    wheel_angle: float
    steering: float
    rear_axle: tuple[float, float]
    progress_m: float = 0.0

    @property
    def center(self) -> tuple[float, float]:
        """Vehicle centre ``(x, y)``."""
        return (self.x, self.y)


@dataclass(frozen=True, slots=True)
class SimEvent:
    """Something that happened during a run: where, when and why."""

    kind: EventKind
    t: float
    x: float
    y: float
    reason: str


class SteeringCalibration(pydantic.BaseModel):
    """Maps the policy's steering unit to a wheel angle: ``kappa = k * command``.

    Attributes:
        curvature_per_unit: ``k``, path curvature (1/m) per steering unit.
        offset: Curvature (1/m) at zero command found by the fit (reported, not applied).
        source: ``default`` (the reference drives' value), ``fitted`` or ``config``.
        samples: Samples the fit used.
        rms_residual: RMS of the fit's curvature residuals (1/m).
    """

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    curvature_per_unit: float = DEFAULT_CURVATURE_PER_UNIT
    offset: float = 0.0
    source: Literal["default", "fitted", "config"] = "default"
    samples: int = 0
    rms_residual: float | None = None

    def wheel_angle(self, command: float, wheelbase: float) -> float:
        """Front wheel angle (radians) of a steering command: ``atan(L * k * command)``."""
        return math.atan(wheelbase * self.curvature_per_unit * command)


def _arc_length(xy: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    steps = np.hypot(*np.diff(xy, axis=0).T)
    return np.concatenate([[0.0], np.cumsum(steps)])


def _window_mean(values: npt.NDArray[np.float64], half: int) -> npt.NDArray[np.float64]:
    """Centred moving average over ``2 * half + 1`` samples (shrunk at the ends)."""
    c = np.concatenate([[0.0], np.cumsum(values)])
    idx = np.arange(values.shape[0])
    lo = np.clip(idx - half, 0, values.shape[0])
    hi = np.clip(idx + half + 1, 0, values.shape[0])
    out: npt.NDArray[np.float64] = (c[hi] - c[lo]) / (hi - lo)
    return out


_MIN_CALIBRATION_CORR = 0.5  # steering must explain the curvature to calibrate it
_MIN_RESIDUAL_SCALE = 1e-4  # 1/m: below any real curvature noise


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
    order = np.argsort(tp, kind="stable")
    tp, p, hd, sp = tp[order], p[order], np.unwrap(hd[order]), sp[order]
    so = np.argsort(ts, kind="stable")
    ts, st = ts[so], st[so]

    s = _arc_length(p)
    grid = np.arange(0.0, s[-1], spacing_m) if s[-1] > spacing_m else np.zeros(0)
    # Arc length only grows while moving; take the first pose reaching each grid station.
    keep = np.concatenate([[True], np.diff(s) > 0])
    s_k, t_k, h_k, v_k = s[keep], tp[keep], hd[keep], sp[keep]
    half = max(1, round(window_m / spacing_m))
    if grid.shape[0] < 2 * half + 3:
        msg = (
            f"the recording drives {s[-1]:.1f} m; fitting the steering calibration needs at "
            f"least {(2 * half + 3) * spacing_m:.0f} m of driving (or give curvature_per_unit)"
        )
        raise ConfigError(msg)
    t_g = np.interp(grid, s_k, t_k)
    h_g = np.interp(grid, s_k, h_k)
    v_g = np.interp(grid, s_k, v_k)
    idx = np.arange(grid.shape[0])
    lo = np.clip(idx - half, 0, grid.shape[0] - 1)
    hi = np.clip(idx + half, 0, grid.shape[0] - 1)
    kappa = (h_g[hi] - h_g[lo]) / (grid[hi] - grid[lo])
    steer_g = _window_mean(np.interp(t_g, ts, st), half)
    v_min = np.minimum(np.minimum(v_g[lo], v_g[hi]), v_g)
    ok = (hi - lo == 2 * half) & (v_min >= min_speed)
    ok &= (t_g >= ts[0]) & (t_g <= ts[-1])
    x, y = steer_g[ok], kappa[ok]
    if x.shape[0] < 10 or np.ptp(x) <= 0:
        msg = (
            f"only {x.shape[0]} samples above {min_speed} m/s with steering variation; the "
            "recording cannot calibrate steering (give curvature_per_unit instead)"
        )
        raise ConfigError(msg)
    a = np.stack([x, np.ones_like(x)], -1)
    coef = np.linalg.lstsq(a, y, rcond=None)[0]
    res = y - a @ coef
    centre = float(np.median(res))
    # Robust spread (MAD), floored: clean data can have almost every residual identical.
    scale = max(1.4826 * float(np.median(np.abs(res - centre))), _MIN_RESIDUAL_SCALE)
    inl = np.abs(res - centre) <= 3.0 * scale
    coef = np.linalg.lstsq(a[inl], y[inl], rcond=None)[0]
    res = y[inl] - a[inl] @ coef
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


@runtime_checkable
class Simulator(Protocol):
    """A driving simulator backend."""

    def load(self, scenario: Scenario, road_map: RoadMap) -> None:
        """Build the world of a scenario: roads, parked vehicles, the recorded route."""

    def reset(self, pose: Pose | None = None) -> VehicleState:
        """Place the ego vehicle at ``pose`` (default: the hero start) and clear the events."""

    def step(self, control: Control) -> VehicleState:
        """Advance one fixed time step under ``control``."""

    @property
    def events(self) -> tuple[SimEvent, ...]:
        """Events since the last reset, in order."""

    def close(self) -> None:
        """Release the backend's resources."""
