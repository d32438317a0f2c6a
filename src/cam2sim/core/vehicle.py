"""The vehicle's vocabulary: controls, states, events and the steering calibration.

Shared by the simulators (:mod:`cam2sim.sim`), the policies (:mod:`cam2sim.ads`) and the
scenario (:mod:`cam2sim.scenario`, which fits the calibration). Positions are in the workspace's
world frame (x east, y north, metres); headings are radians counter-clockwise from east; speeds
are m/s; the wheel angle is the bicycle model's front wheel angle (radians, positive = left).

The policy's steering command has its own unit (the recording's steering signal). It becomes a
wheel angle through a :class:`SteeringCalibration`: the path curvature per steering unit, fitted
from the recording by :func:`cam2sim.scenario.calibration.fit_steering_calibration`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import pydantic

__all__ = [
    "DEFAULT_CURVATURE_PER_UNIT",
    "Control",
    "EventKind",
    "SimEvent",
    "SteeringCalibration",
    "VehicleState",
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
