"""run_episode: the closed loop on its own, with a scripted simulator and policies."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pytest

from cam2sim.core.errors import StageError
from cam2sim.sim.episode import ROW_KEYS, EpisodeOptions, run_episode
from cam2sim.sim.interface import (
    Control,
    Observation,
    PlanarPose,
    SimEvent,
    Simulator,
    SteeringPolicy,
    VehicleState,
)


def _state(t: float, x: float, y: float, heading: float, steering: float) -> VehicleState:
    return VehicleState(
        t=t, x=x, y=y, z=0.0, heading=heading, speed=10.0, wheel_angle=0.0,
        steering=steering, rear_axle=(x, y),
    )  # fmt: skip


@dataclass
class _Line:
    """A car on a straight line along its heading at 10 m/s, 0.1 s a step; ends after n steps."""

    end_after: int = 10
    controls: list[Control] = field(default_factory=list)
    state: VehicleState | None = None

    def load(self, scenario: object, road_map: object) -> None:
        del scenario, road_map

    def reset(self, pose: PlanarPose | None = None) -> VehicleState:
        p = pose or PlanarPose(0.0, 0.0, 0.0, 10.0)
        self.controls = []
        self.state = _state(0.0, p.x, p.y, p.heading, 0.0)
        return self.state

    def step(self, control: Control) -> VehicleState:
        assert self.state is not None
        s = self.state
        self.controls.append(control)
        x, y = s.x + math.cos(s.heading), s.y + math.sin(s.heading)
        self.state = _state(s.t + 0.1, x, y, s.heading, control.steering)
        return self.state

    @property
    def events(self) -> tuple[SimEvent, ...]:
        if len(self.controls) < self.end_after:
            return ()
        assert self.state is not None
        return (SimEvent("route_end", self.state.t, self.state.x, self.state.y, "the end"),)

    @property
    def done(self) -> bool:
        return len(self.controls) >= self.end_after

    def close(self) -> None:
        pass


class _Counting:
    """Answers the number of its calls; fails at call ``fail_at`` (1-based) when set."""

    name = "counting"
    needs_image = True

    def __init__(self, fail_at: int | None = None) -> None:
        self.calls: list[Observation] = []
        self.fail_at = fail_at

    def reset(self) -> None:
        self.calls = []

    def predict(self, obs: Observation) -> float:
        self.calls.append(obs)
        if self.fail_at is not None and len(self.calls) == self.fail_at:
            msg = "the policy server did not answer in 2 s"
            raise StageError(msg)
        return float(len(self.calls))

    def close(self) -> None:
        pass


def test_the_loop_asks_every_nth_step_and_hands_each_frame_on() -> None:
    sim, policy = _Line(end_after=10), _Counting()
    assert isinstance(sim, Simulator)
    assert isinstance(policy, SteeringPolicy)
    frames: list[int] = []

    def camera(state: VehicleState) -> np.ndarray:
        return np.full((2, 2, 3), int(state.x), np.uint8)

    episode = run_episode(
        sim, policy, camera, EpisodeOptions(policy_every=3, target_speed=5.0),
        on_frame=lambda image, step: frames.append(step),
    )  # fmt: skip
    assert episode.steps == 10  # the simulator ended it
    assert frames == [0, 3, 6, 9]
    assert [d[1] for d in episode.decisions] == [1.0, 2.0, 3.0, 4.0]
    # Each command holds until the next decision; the target speed goes with every step.
    assert [c.steering for c in sim.controls] == [1, 1, 1, 2, 2, 2, 3, 3, 3, 4]
    assert {c.target_speed for c in sim.controls} == {5.0}
    # The policy saw the frame of the state it decided on.
    assert [int(o.image[0, 0, 0]) for o in policy.calls if o.image is not None] == [0, 3, 6, 9]
    assert [e.kind for e in episode.events] == ["route_end"]
    assert set(episode.rows) == set(ROW_KEYS)


def test_rows_are_the_reference_point_and_a_failed_policy_ends_the_run() -> None:
    sim = _Line(end_after=100)
    start = PlanarPose(0.0, 0.0, math.pi / 2, 10.0)  # heading north
    options = EpisodeOptions(policy_every=2, reference_xyz=(1.5, 0.0, 0.3))
    episode = run_episode(sim, _Counting(fail_at=3), None, options, start)
    assert episode.failure is not None
    assert "did not answer" in episode.failure.reason
    assert episode.steps == 4  # two decisions, two steps each, then the failed third
    # 1.5 m ahead of the centre, heading north: x unchanged, y 1.5 m further, z 0.3 up.
    assert episode.rows["x"][0] == pytest.approx(0.0, abs=1e-9)
    assert episode.rows["y"][0] == pytest.approx(1.0 + 1.5)
    assert episode.rows["z"][0] == pytest.approx(0.3)


def test_the_step_cap_ends_a_run_the_simulator_does_not() -> None:
    episode = run_episode(_Line(end_after=10**6), _Counting(), None, EpisodeOptions(max_steps=7))
    assert episode.steps == 7
    assert episode.events == ()
    with pytest.raises(ValueError, match="policy_every"):
        EpisodeOptions(policy_every=0)


def test_the_car_is_asked_for_the_recorded_speed_where_it_is() -> None:
    from cam2sim.sim.speed import SpeedProfile

    # A route along x, 1 m a point; the driver slowed from 10 to 3 m/s between 4 and 7 m.
    xs = np.arange(0.0, 12.0)
    speeds = np.where((xs >= 4) & (xs <= 7), 3.0, 10.0)
    profile = SpeedProfile(np.stack([xs, np.zeros_like(xs)], axis=1), speeds)
    sim = _Line(end_after=10)
    options = EpisodeOptions(speed_profile=profile, speed_factor=0.5, target_speed=99.0)
    run_episode(sim, _Counting(), None, options)
    # The car moves 1 m a step: it is asked at x = 0, 1, ..., 9 (the profile, not 99), halved.
    assert [c.target_speed for c in sim.controls] == [5.0] * 4 + [1.5] * 4 + [5.0] * 2


def test_a_recorded_profile_is_smoothed_floored_and_keeps_its_place() -> None:
    from cam2sim.sim.speed import MIN_PROFILE_SPEED, SpeedProfile

    t = np.arange(0.0, 10.0, 0.1)
    speed = np.full_like(t, 8.0)
    speed[50] = 80.0  # a pose glitch: averaged over 1 s (11 samples)
    speed[90:] = 0.0  # the car stopped at the end
    xy = np.stack([np.cos(t), np.sin(t)], axis=1)  # a circle: the route passes 0 rad again
    profile = SpeedProfile.recorded(xy, speed, t)
    assert profile.speed[50] == pytest.approx(8.0 + 72.0 / 11)
    assert profile.speed[20] == pytest.approx(8.0)
    assert profile.speed[-1] == MIN_PROFILE_SPEED
    # At the start point again after a lap (6.3 rad): the search ahead of the last place
    # (6.0 rad) finds the lap's point, a search from nothing the start.
    assert profile.nearest(1.0, 0.0, last=60) == 63
    assert profile.nearest(1.0, 0.0) == 0
    with pytest.raises(ValueError, match="matching columns"):
        SpeedProfile.recorded(xy[:5], speed, t)


def test_a_drive_that_slows_for_a_turn_changes_speed_and_a_steady_one_does_not() -> None:
    from cam2sim.sim.speed import SpeedProfile

    t = np.arange(0.0, 20.0, 0.1)
    xy = np.stack([t * 8.0, np.zeros_like(t)], axis=1)
    rng = np.random.default_rng(0)
    # A synthetic drive: one speed, with the noise of speeds taken from pose differences.
    steady = SpeedProfile.recorded(xy, 8.0 + rng.normal(0.0, 0.3, t.size), t)
    assert not steady.changes_speed(8.0)
    # KITTI 03's shape: 35 km/h, down to 9 km/h for a sharp turn, back up.
    real = 9.6 - 7.0 * np.exp(-(((t - 9.0) / 1.5) ** 2))
    turn = SpeedProfile.recorded(xy, real, t)
    assert turn.changes_speed(9.6)
    slow, fast = turn.span_kmh()
    assert 9.0 < slow < 12.0
    assert fast == pytest.approx(9.6 * 3.6, rel=0.01)
    # A drive that ends in a stop changes speed too (the profile asks for its floor there).
    stop = SpeedProfile.recorded(xy, np.where(t < 18.0, 8.0, 0.0), t)
    assert stop.changes_speed(8.0)
