"""Pieces both simulator backends share: settings, the speed controller and route progress.

The builtin and the CARLA backend must steer, hold speed and judge route completion
identically, so that runs on either compare; the settings (:class:`VehicleControlOptions`,
:class:`EpisodeRuleOptions`, which both backends' options extend) and the code live here once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np
import pydantic

from cam2sim.core.errors import ConfigError
from cam2sim.core.polyline import ReferencePath
from cam2sim.sim.interface import SimEvent

if TYPE_CHECKING:
    import numpy.typing as npt

    from cam2sim.core.vehicle import Control, EventKind, SteeringCalibration

__all__ = [
    "EpisodeRuleOptions",
    "EpisodeRules",
    "EventLog",
    "RouteTracker",
    "SpeedGains",
    "SpeedPid",
    "VehicleControlOptions",
    "limit_wheel_angle",
    "wanted_wheel_angle",
]

_PROJECT_BACK = 4  # route segments searched behind the last foot point
_PROJECT_AHEAD = 40  # and ahead of it


class VehicleControlOptions(pydantic.BaseModel):
    """How the hero turns a control into motion, the same on every backend."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    dt: float = pydantic.Field(1.0 / 30.0, gt=0, description="fixed time step, s")
    max_wheel_angle_rad: float = pydantic.Field(0.61, gt=0, description="~35 degrees")
    max_steer_rate_rad_s: float = pydantic.Field(1.0, gt=0, description="wheel angle rate limit")
    max_accel: float = pydantic.Field(2.5, gt=0, description="m/s^2")
    max_decel: float = pydantic.Field(6.0, gt=0, description="braking limit, m/s^2")
    kp: float = pydantic.Field(1.5, ge=0, description="PID gain, (m/s^2) per (m/s)")
    ki: float = pydantic.Field(0.5, ge=0)
    kd: float = pydantic.Field(0.0, ge=0)
    integral_band: float = pydantic.Field(
        0.5, gt=0, description="the integral only runs this close to the target (m/s)"
    )
    target_speed: float | None = pydantic.Field(
        None, ge=0, description="initial target, m/s; None: the hero start's recorded speed"
    )


class EpisodeRuleOptions(pydantic.BaseModel):
    """When a run leaves the road, completes the route or is stuck, the same on every backend."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    offroad_margin_m: float = pydantic.Field(
        0.3, description="how far the footprint may leave the drivable area"
    )
    road_lane_types: tuple[str, ...] = pydantic.Field(
        (
            "driving", "parking", "shoulder", "bidirectional", "entry", "exit", "onRamp",
            "offRamp",
        ),
        description="lane types of the carriageway (kerb to kerb): leaving them is off-road; "
        "a parking lane or shoulder is road surface, a sidewalk is not",
    )  # fmt: skip
    route_end_tolerance_m: float = pydantic.Field(3.0, ge=0)
    route_max_lateral_m: float = pydantic.Field(
        4.0, gt=0, description="progress only counts this close to the recorded route"
    )
    stuck_speed: float = pydantic.Field(0.1, ge=0, description="m/s")
    stuck_after_s: float = pydantic.Field(5.0, gt=0)


class SpeedGains(Protocol):
    """The controller settings both backends' options carry."""

    @property
    def dt(self) -> float:
        """Fixed time step, s."""
        ...

    @property
    def kp(self) -> float:
        """Proportional gain, (m/s^2) per (m/s)."""
        ...

    @property
    def ki(self) -> float:
        """Integral gain."""
        ...

    @property
    def kd(self) -> float:
        """Derivative gain."""
        ...

    @property
    def max_accel(self) -> float:
        """Acceleration limit, m/s^2."""
        ...

    @property
    def max_decel(self) -> float:
        """Braking limit, m/s^2."""
        ...

    @property
    def integral_band(self) -> float:
        """Speed error below which the integral runs, m/s."""
        ...


@dataclass
class SpeedPid:
    """PID on the speed error, giving a limited longitudinal acceleration (m/s^2).

    Anti-windup: the integral runs only near the target (``integral_band``), not while the
    output is saturated in the error's direction, and not while braking at a standstill.
    """

    gains: SpeedGains
    integral: float = 0.0
    prev_speed: float = 0.0

    def reset(self, speed: float) -> None:
        """Start a new episode at ``speed``."""
        self.integral = 0.0
        self.prev_speed = speed

    def acceleration(self, target: float, speed: float) -> float:
        """The commanded acceleration for one step."""
        o = self.gains
        err = target - speed
        deriv = (speed - self.prev_speed) / o.dt
        self.prev_speed = speed
        acc = o.kp * err + o.ki * self.integral - o.kd * deriv
        sat = min(o.max_accel, max(-o.max_decel, acc))
        held = speed <= 0.0 and acc < 0.0  # standing still: brakes hold, no windup
        near = abs(err) < o.integral_band
        if near and (sat == acc or (acc > sat) != (err > 0)) and not held:
            self.integral += err * o.dt
        return sat


class RouteTracker:
    """Monotone progress (metres) of the vehicle centre along the recorded centre route."""

    def __init__(self, center_xy: npt.ArrayLike, *, max_lateral_m: float) -> None:
        self.route = ReferencePath.from_polyline(
            np.asarray(center_xy, dtype=np.float64)[:, :2], spacing_m=1.0
        )
        r = self.route.xy
        self._a = r[:-1]
        self._d = np.diff(r, axis=0)
        self._len2 = np.maximum((self._d**2).sum(axis=1), 1e-12)
        self.max_lateral_m = max_lateral_m
        self.seg = 0
        self.progress = 0.0

    @property
    def length_m(self) -> float:
        """Length of the recorded route."""
        return self.route.length_m

    def reset(self) -> None:
        """Back to the start of the route."""
        self.seg, self.progress = 0, 0.0

    def update(self, cx: float, cy: float) -> float:
        """Project the centre near the last foot point; progress never decreases."""
        lo = max(0, self.seg - _PROJECT_BACK)
        hi = min(self._a.shape[0], self.seg + _PROJECT_AHEAD)
        a, d = self._a[lo:hi], self._d[lo:hi]
        u = np.clip(((cx - a[:, 0]) * d[:, 0] + (cy - a[:, 1]) * d[:, 1]) / self._len2[lo:hi], 0, 1)
        dist2 = (a[:, 0] + u * d[:, 0] - cx) ** 2 + (a[:, 1] + u * d[:, 1] - cy) ** 2
        k = int(np.argmin(dist2))
        if dist2[k] <= self.max_lateral_m**2:
            seg = lo + k
            s = self.route.s
            prog = float(s[seg] + u[k] * (s[seg + 1] - s[seg]))
            if prog >= self.progress:
                self.seg, self.progress = seg, prog
        return self.progress


class EpisodeRules(Protocol):
    """The episode-ending settings both backends' options carry."""

    @property
    def route_end_tolerance_m(self) -> float:
        """Route completed this close to its end, metres."""
        ...

    @property
    def stuck_speed(self) -> float:
        """Below this speed the vehicle counts as standing, m/s."""
        ...

    @property
    def stuck_after_s(self) -> float:
        """Standing this long before the end is ``stuck``, s."""
        ...


@dataclass
class EventLog:
    """The episode's events, each kind reported once (at its first step), and the stuck clock."""

    events: list[SimEvent] = field(default_factory=list)
    seen: set[EventKind] = field(default_factory=set)
    slow_since: float | None = None

    def reset(self) -> None:
        """Forget every event of the last episode."""
        self.events, self.seen, self.slow_since = [], set(), None

    def emit(self, kind: EventKind, t: float, x: float, y: float, reason: str) -> None:
        """Record ``kind`` unless it was already reported this episode."""
        if kind not in self.seen:
            self.seen.add(kind)
            self.events.append(SimEvent(kind=kind, t=t, x=x, y=y, reason=reason))

    def judge_route(
        self,
        t: float,
        xy: tuple[float, float],
        speed: float,
        tracker: RouteTracker,
        rules: EpisodeRules,
        timeout_s: float,
    ) -> None:
        """Route completed, stuck and timeout, identically for every backend."""
        cx, cy = xy
        end = tracker.length_m - rules.route_end_tolerance_m
        if tracker.progress >= end:
            self.emit(
                "route_completed", t, cx, cy, f"reached {tracker.progress:.1f} m of the route"
            )
        if speed < rules.stuck_speed:
            if self.slow_since is None:
                self.slow_since = t
            if t - self.slow_since >= rules.stuck_after_s - 1e-9 and tracker.progress < end:
                reason = f"slower than {rules.stuck_speed} m/s for {rules.stuck_after_s} s"
                self.emit("stuck", t, cx, cy, reason)
        else:
            self.slow_since = None
        if t >= timeout_s - 1e-9:
            self.emit("timeout", t, cx, cy, f"ran {timeout_s:.1f} s without finishing")


def limit_wheel_angle(
    current: float, want: float, *, max_angle: float, max_rate: float, dt: float
) -> float:
    """Move the wheel angle from ``current`` toward ``want`` within the angle and rate limits."""
    want = min(max_angle, max(-max_angle, want))
    step = max_rate * dt
    return current + min(step, max(-step, want - current))


def wanted_wheel_angle(
    control: Control,
    calibration: SteeringCalibration,
    wheelbase: float,
    target_speed: float,
    *,
    noise: float = 0.0,
) -> tuple[float, float]:
    """The command as applied (NaN for a direct wheel angle) and the wheel angle it asks for.

    ``noise`` is added to a steering command (not to a direct wheel angle), in the command's
    unit, before the calibration maps it to a wheel angle.

    Raises:
        ConfigError: The command or the target speed is not finite.
    """
    if control.wheel_angle is not None:
        steer, want = math.nan, control.wheel_angle
    else:
        steer = control.steering + noise
        want = calibration.wheel_angle(steer, wheelbase)
    if not (math.isfinite(want) and math.isfinite(target_speed)):
        msg = f"control {control!r} is not finite; send finite steering and speed"
        raise ConfigError(msg)
    return steer, want
