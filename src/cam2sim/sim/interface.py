"""The simulator interface: controls in, vehicle states and events out.

Every backend (``builtin``, ``carla``) implements :class:`Simulator`. Positions are in the
workspace's world frame (x east, y north, metres); headings are radians counter-clockwise from
east; speeds are m/s; the wheel angle is the bicycle model's front wheel angle (radians,
positive = left).

An episode starts at a :class:`PlanarPose` (2-D, with a speed), not at an SE(3)
:class:`cam2sim.core.frames.Pose`. The vehicle's vocabulary (controls, states, events, the
steering calibration) lives in :mod:`cam2sim.core.vehicle` and is re-exported here; the
calibration is fitted by the scenario
(:func:`cam2sim.scenario.calibration.fit_steering_calibration`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

from cam2sim.core.vehicle import (
    DEFAULT_CURVATURE_PER_UNIT,
    Control,
    EventKind,
    SimEvent,
    SteeringCalibration,
    VehicleState,
)

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from cam2sim.map.query import RoadMap
    from cam2sim.scenario.model import Scenario


__all__ = [
    "DEFAULT_CURVATURE_PER_UNIT",
    "Control",
    "EventKind",
    "Observation",
    "PlanarPose",
    "SimEvent",
    "Simulator",
    "SteeringCalibration",
    "SteeringPolicy",
    "VehicleState",
]


@dataclass(frozen=True, slots=True)
class PlanarPose:
    """Where an episode starts: a 2-D planar pose of the vehicle and the speed it starts at.

    This is not a rigid transform: the simulators place the vehicle on the road surface (the
    height and the roll and pitch come from the road), so only the planar part is given. The
    full SE(3) pose is :class:`cam2sim.core.frames.Pose`.

    Attributes:
        x: Vehicle centre east, metres, world frame.
        y: Vehicle centre north, metres, world frame.
        heading: Forward axis, radians counter-clockwise from east.
        speed: Speed at the start, m/s.
    """

    x: float
    y: float
    heading: float
    speed: float = 0.0


@runtime_checkable
class Simulator(Protocol):
    """A driving simulator backend."""

    def load(self, scenario: Scenario, road_map: RoadMap) -> None:
        """Build the world of a scenario: roads, parked vehicles, the recorded route."""

    def reset(self, pose: PlanarPose | None = None) -> VehicleState:
        """Place the ego vehicle at ``pose`` (default: the hero start) and clear the events."""

    def step(self, control: Control) -> VehicleState:
        """Advance one fixed time step under ``control``."""

    @property
    def events(self) -> tuple[SimEvent, ...]:
        """Events since the last reset, in order."""

    @property
    def done(self) -> bool:
        """Whether the episode has ended (an event that ends it, the route's end, a timeout)."""

    def close(self) -> None:
        """Release the backend's resources."""


@dataclass(frozen=True, slots=True)
class Observation:
    """What a policy sees at one decision.

    Attributes:
        t: Simulated time since reset, seconds.
        image: ``(H, W, 3)`` uint8 RGB frame of the run's camera; None when the run has none.
        state: The ego vehicle's state at ``t``.
    """

    t: float
    image: npt.NDArray[np.uint8] | None
    state: VehicleState


@runtime_checkable
class SteeringPolicy(Protocol):
    """Turns observations into steering commands (in the recording's steering unit)."""

    @property
    def name(self) -> str:
        """Short label for reports and logs."""
        ...

    @property
    def needs_image(self) -> bool:
        """Whether :meth:`predict` uses ``Observation.image`` (False: the run may skip it)."""
        ...

    def reset(self) -> None:
        """Forget any state: a new run starts."""
        ...

    def predict(self, obs: Observation) -> float:
        """The steering command for ``obs``, in the recording's steering unit."""
        ...

    def close(self) -> None:
        """Release models, sessions and connections."""
        ...
