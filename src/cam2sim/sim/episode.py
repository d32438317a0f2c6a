"""One closed-loop episode: a policy steers a simulated car from what its camera shows.

:func:`run_episode` is the loop every drive runs (``cam2sim drive``, campaigns, the pipeline):
reset the simulator and the policy, then step the simulator at its fixed time step and ask the
policy for a new command every ``policy_every`` steps, from the camera's view of the car's
current state. It knows no workspace, no file and no renderer: the camera is a function of the
vehicle state (``stages`` builds it from a renderer, or from CARLA's own camera), and what the
caller keeps of each frame it is handed through ``on_frame``. A policy that fails (a remote
policy timed out: :class:`~cam2sim.core.errors.Cam2SimError`) ends the episode with a
``policy_error`` event instead of raising.

The recorded rows are the car at ``reference_xyz``, the point of the vehicle the recording's
poses describe (body frame: x forward, y left, z up, metres from the vehicle centre), so that a
run compares with the recorded trajectory directly.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Final

from cam2sim.core.errors import Cam2SimError
from cam2sim.scenario.body import body_point_positions
from cam2sim.sim.interface import Control, Observation

if TYPE_CHECKING:
    from collections.abc import Callable

    import numpy as np
    import numpy.typing as npt

    from cam2sim.sim.interface import PlanarPose, SimEvent, Simulator, SteeringPolicy, VehicleState
    from cam2sim.sim.speed import SpeedProfile

__all__ = ["ROW_KEYS", "Episode", "EpisodeOptions", "PolicyFailure", "run_episode"]

ROW_KEYS: Final = ("t", "x", "y", "z", "heading", "speed", "steering", "wheel_angle")
"""The columns of :attr:`Episode.rows`: time, the reference point, heading, speed, steering."""


@dataclass(frozen=True)
class EpisodeOptions:
    """How one episode runs.

    Attributes:
        max_steps: Step cap (the simulator's own end usually comes first).
        policy_every: The policy answers every n-th simulator step (3, as the published tool).
        target_speed: Speed the simulator's controller holds, m/s; None: the start speed.
        speed_profile: The recorded speeds along the route; when given, the controller
            follows the speed at the route point nearest to the car instead of
            ``target_speed``.
        speed_factor: Scales the profile's speeds (a run's seeded speed variation).
        reference_xyz: The point recorded in :attr:`Episode.rows`, body frame, metres from
            the vehicle centre.
        progress_every: Steps between ``progress`` calls.
    """

    max_steps: int = 100_000
    policy_every: int = 3
    target_speed: float | None = None
    speed_profile: SpeedProfile | None = None
    speed_factor: float = 1.0
    reference_xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    progress_every: int = 30

    def __post_init__(self) -> None:
        if self.max_steps < 1 or self.policy_every < 1 or self.progress_every < 1:
            msg = (
                "max_steps, policy_every and progress_every must be >= 1, got "
                f"{self.max_steps}, {self.policy_every}, {self.progress_every}"
            )
            raise ValueError(msg)


@dataclass(frozen=True)
class PolicyFailure:
    """The policy failed (a remote policy timed out): where and why the episode ended."""

    t: float
    x: float
    y: float
    reason: str


@dataclass(frozen=True)
class Episode:
    """What happened in one episode.

    Attributes:
        rows: One list per :data:`ROW_KEYS` column, one value per simulated step.
        decisions: ``(t, command)`` of every policy answer.
        events: The simulator's events (collisions, leaving the road, the route's end...).
        failure: The policy's failure, when it ended the episode.
        seconds: Wall time of the loop.
        render_s: Of it, the camera's.
        policy_s: Of it, the policy's.
    """

    rows: dict[str, list[float]]
    decisions: list[tuple[float, float]]
    events: tuple[SimEvent, ...]
    failure: PolicyFailure | None = None
    seconds: float = 0.0
    render_s: float = 0.0
    policy_s: float = 0.0

    @property
    def steps(self) -> int:
        """Simulated steps (a failed policy call simulates none)."""
        return len(self.rows["t"])


def run_episode(
    sim: Simulator,
    policy: SteeringPolicy,
    camera: Callable[[VehicleState], npt.NDArray[np.uint8]] | None,
    options: EpisodeOptions,
    start: PlanarPose | None = None,
    *,
    on_frame: Callable[[npt.NDArray[np.uint8], int], None] | None = None,
    progress: Callable[[int], None] | None = None,
) -> Episode:
    """Run one episode from ``start`` until the simulator ends it (or ``max_steps``).

    Args:
        sim: A loaded simulator.
        policy: The system under test.
        camera: The image the policy sees at a vehicle state; None: no image.
        options: Step cap, decision rate, target speed, recorded point.
        start: Where the car starts; None: the simulator's hero start.
        on_frame: Receives each camera frame and its simulator step index (0-based).
        progress: Receives the step count every ``progress_every`` steps.
    """
    state = sim.reset(start)
    policy.reset()
    rows: dict[str, list[float]] = {k: [] for k in ROW_KEYS}
    decisions: list[tuple[float, float]] = []
    command = 0.0
    render_s = policy_s = 0.0
    failure = None
    profile, cursor = options.speed_profile, None
    started = time.perf_counter()
    for step in range(options.max_steps):
        if step % options.policy_every == 0:
            image = None
            if camera is not None:
                t0 = time.perf_counter()
                image = camera(state)
                render_s += time.perf_counter() - t0
                if on_frame is not None:
                    on_frame(image, step)
            t0 = time.perf_counter()
            try:
                command = float(policy.predict(Observation(t=state.t, image=image, state=state)))
            except Cam2SimError as err:  # a remote policy timed out or failed: end the run
                failure = PolicyFailure(state.t, state.x, state.y, str(err))
                break
            policy_s += time.perf_counter() - t0
            decisions.append((state.t, command))
        target = options.target_speed
        if profile is not None:  # the recorded speed where the car is
            cursor = profile.nearest(state.x, state.y, cursor)
            target = float(profile.speed[cursor]) * options.speed_factor
        state = sim.step(Control(steering=command, target_speed=target))
        _record(rows, state, options.reference_xyz)
        if progress is not None and (step + 1) % options.progress_every == 0:
            progress(step + 1)
        if sim.done:
            break
    return Episode(
        rows,
        decisions,
        tuple(sim.events),
        failure,
        seconds=time.perf_counter() - started,
        render_s=render_s,
        policy_s=policy_s,
    )


def _record(
    rows: dict[str, list[float]], state: VehicleState, ref_xyz: tuple[float, float, float]
) -> None:
    """Append one state, with the position moved from the vehicle centre to ``ref_xyz``."""
    ref = body_point_positions(
        [[state.x, state.y, state.z]], [state.heading], (0.0, 0.0, 0.0), ref_xyz
    )[0]
    values = (
        state.t, ref[0], ref[1], ref[2], state.heading, state.speed, state.steering,
        state.wheel_angle,
    )  # fmt: skip
    for key, value in zip(ROW_KEYS, values, strict=True):
        rows[key].append(float(value))
