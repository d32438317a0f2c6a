"""The ``builtin`` simulator: an embedded, deterministic kinematic-bicycle world on CPU.

The ego vehicle is a kinematic bicycle about its rear axle, integrated exactly along a circular
arc each fixed step, with a front wheel angle limit and a steering-rate limit. A PID on
longitudinal acceleration (with acceleration and braking limits, anti-windup) holds the target
speed. The world is the OpenDRIVE map's drivable area and the scenario's parked vehicles as
static boxes. Each step checks, in this order: collision (footprint overlaps a parked box,
shapely STRtree built once), off-road (a footprint corner or edge midpoint leaves the drivable
area grown by ``offroad_margin_m``; prepared geometry), route completed (progress along the
recorded centre trajectory reaches its end), stuck and timeout. Each kind is reported once, at
the first step it happens.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt
import pydantic

from cam2sim.core.errors import StageError
from cam2sim.core.footprint import footprint_corners
from cam2sim.sim.control import (
    EpisodeRuleOptions,
    EventLog,
    RouteTracker,
    SpeedPid,
    VehicleControlOptions,
    limit_wheel_angle,
    wanted_wheel_angle,
)
from cam2sim.sim.interface import (
    Control,
    EventKind,
    PlanarPose,
    SimEvent,
    SteeringCalibration,
    VehicleState,
)

if TYPE_CHECKING:
    from cam2sim.map.query import RoadMap
    from cam2sim.scenario.model import Scenario

__all__ = ["BuiltinOptions", "BuiltinSimulator"]

_ALL_EVENTS: tuple[EventKind, ...] = (
    "collision",
    "off_road",
    "route_completed",
    "stuck",
    "timeout",
)


class BuiltinOptions(VehicleControlOptions, EpisodeRuleOptions):
    """Settings of the builtin simulator (defaults in the field descriptions).

    The control and episode settings are the ones every backend shares
    (:class:`~cam2sim.sim.control.VehicleControlOptions`,
    :class:`~cam2sim.sim.control.EpisodeRuleOptions`).
    """

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    calibration: SteeringCalibration = SteeringCalibration()
    timeout_s: float | None = pydantic.Field(
        None, gt=0, description="None: twice the recorded duration plus 10 s"
    )
    steering_noise_std: float = pydantic.Field(0.0, ge=0, description="steering units")
    seed: int = 0


class BuiltinSimulator:
    """The embedded simulator; see the module docstring.

    Use ``load`` once per scenario, then ``reset`` and ``step``::

        sim = BuiltinSimulator(BuiltinOptions())
        sim.load(scenario, road_map)
        state = sim.reset()
        while not sim.done:
            state = sim.step(Control(steering=policy(image)))
    """

    def __init__(self, options: BuiltinOptions | None = None) -> None:
        self.options = options or BuiltinOptions()
        self._loaded = False
        self._log = EventLog()
        self._rng = np.random.default_rng(self.options.seed)

    # -- world ---------------------------------------------------------------------------
    def load(self, scenario: Scenario, road_map: RoadMap) -> None:
        """Build the world: drivable area, parked boxes and the recorded route.

        Raises:
            StageError: The map has no drivable lanes.
        """
        import shapely  # noqa: PLC0415

        o = self.options
        area = road_map.drivable_area(o.road_lane_types)
        if area.is_empty:
            msg = "the road map has no drivable lanes; check the map stage's output (map.xodr)"
            raise StageError(msg)
        grown = shapely.buffer(area, o.offroad_margin_m) if o.offroad_margin_m else area
        shapely.prepare(grown)
        self._area = grown
        v = scenario.vehicle
        self._wheelbase = v.wheelbase_m
        self._rear_x = v.rear_axle_xyz[0]  # rear axle along x from the centre (negative)
        hl, hw = 0.5 * v.length_m, 0.5 * v.width_m
        corners = [[hl, hw], [hl, -hw], [-hl, -hw], [-hl, hw]]
        mids = [[hl, 0.0], [0.0, -hw], [-hl, 0.0], [0.0, hw]]
        self._local = np.array(corners + mids)  # footprint check points, vehicle frame
        self._parked = scenario.parked
        if scenario.parked:
            pc = np.array([p.position[:2] for p in scenario.parked])
            yaw = np.array([p.heading for p in scenario.parked])
            size = np.array([p.size for p in scenario.parked])
            boxes = shapely.polygons(footprint_corners(pc, yaw, size[:, 0], size[:, 1]))
            self._boxes: npt.NDArray[np.object_] = np.asarray(boxes, dtype=object)
            # a cheap distance test first: centres closer than the two half diagonals
            self._box_xy = pc
            reach = 0.5 * np.hypot(size[:, 0], size[:, 1]) + 0.5 * math.hypot(hl * 2, hw * 2)
            self._box_reach2 = reach**2
        else:
            self._boxes = np.empty(0, dtype=object)
        self._tree = shapely.STRtree(self._boxes)
        center = np.asarray(scenario.trajectory.center, dtype=np.float64)[:, :2]
        self._tracker = RouteTracker(center, max_lateral_m=self.options.route_max_lateral_m)
        self._pid = SpeedPid(self.options)
        self._start = scenario.hero_start
        self._z = scenario.hero_start.position[2]
        t = scenario.trajectory.t
        self._timeout = o.timeout_s if o.timeout_s is not None else 2.0 * (t[-1] - t[0]) + 10.0
        self._loaded = True
        self.reset()

    # -- episode ---------------------------------------------------------------------------
    def reset(self, pose: PlanarPose | None = None, *, seed: int | None = None) -> VehicleState:
        """Place the vehicle at ``pose`` (default: the hero start) and clear the events.

        Raises:
            StageError: ``load`` has not been called.
        """
        if not self._loaded:
            msg = "BuiltinSimulator.reset before load; call load(scenario, road_map) first"
            raise StageError(msg)
        if pose is None:
            s = self._start
            pose = PlanarPose(s.position[0], s.position[1], s.heading, s.speed)
        self._rng = np.random.default_rng(self.options.seed if seed is None else seed)
        self._t = 0.0
        self._heading = pose.heading
        self._rx = pose.x + self._rear_x * math.cos(pose.heading)
        self._ry = pose.y + self._rear_x * math.sin(pose.heading)
        self._speed = max(0.0, pose.speed)
        self._delta = 0.0
        self._steer = 0.0
        ts = self.options.target_speed
        self._target = ts if ts is not None else self._start.speed
        self._pid.reset(self._speed)
        self._log.reset()
        self._tracker.reset()
        self._update_progress()
        return self._state()

    @property
    def events(self) -> tuple[SimEvent, ...]:
        """Events since the last reset, in order."""
        return tuple(self._log.events)

    @property
    def done(self) -> bool:
        """Whether an event ended the episode (any event does)."""
        return bool(self._log.events)

    def close(self) -> None:
        """Drop the world (nothing external to release)."""
        self._loaded = False

    # -- dynamics --------------------------------------------------------------------------
    def step(self, control: Control) -> VehicleState:
        """Advance one fixed time step.

        Raises:
            StageError: ``load`` has not been called.
            ConfigError: A non-finite command.
        """
        if not self._loaded:
            msg = "BuiltinSimulator.step before load; call load(scenario, road_map) first"
            raise StageError(msg)
        dt = self.options.dt
        if control.target_speed is not None:
            self._target = max(0.0, control.target_speed)
        self._steer_toward(control)
        v0 = self._speed
        v1 = max(0.0, v0 + self._acceleration() * dt)
        dist = 0.5 * (v0 + v1) * dt
        self._speed = v1

        kappa = math.tan(self._delta) / self._wheelbase
        h0 = self._heading
        dh = kappa * dist
        if abs(dh) > 1e-9:
            h1 = h0 + dh
            self._rx += (math.sin(h1) - math.sin(h0)) / kappa
            self._ry += (math.cos(h0) - math.cos(h1)) / kappa
        else:
            h1 = h0 + dh
            hm = h0 + 0.5 * dh
            self._rx += dist * math.cos(hm)
            self._ry += dist * math.sin(hm)
        self._heading = math.remainder(h1, math.tau)
        self._t += dt
        self._update_progress()
        self._detect()
        return self._state()

    # -- helpers ---------------------------------------------------------------------------
    def _steer_toward(self, control: Control) -> None:
        """Move the wheel angle toward the command within the angle and rate limits."""
        o = self.options
        noise = 0.0
        if control.wheel_angle is None and o.steering_noise_std:
            noise = o.steering_noise_std * float(self._rng.standard_normal())
        self._steer, want = wanted_wheel_angle(
            control, o.calibration, self._wheelbase, self._target, noise=noise
        )
        self._delta = limit_wheel_angle(
            self._delta,
            want,
            max_angle=o.max_wheel_angle_rad,
            max_rate=o.max_steer_rate_rad_s,
            dt=o.dt,
        )

    def _acceleration(self) -> float:
        """PID on the speed error, limited.

        Anti-windup: the integral runs only near the target (``integral_band``), not while the
        output is saturated in the error's direction, and not while braking at a standstill.
        """
        return self._pid.acceleration(self._target, self._speed)

    def _center(self) -> tuple[float, float]:
        c, s = math.cos(self._heading), math.sin(self._heading)
        return (self._rx - self._rear_x * c, self._ry - self._rear_x * s)

    def _state(self) -> VehicleState:
        cx, cy = self._center()
        return VehicleState(
            t=self._t,
            x=cx,
            y=cy,
            z=self._z,
            heading=self._heading,
            speed=self._speed,
            wheel_angle=self._delta,
            steering=self._steer,
            rear_axle=(self._rx, self._ry),
            progress_m=self._tracker.progress,
        )

    def _corners(self) -> npt.NDArray[np.float64]:
        """``(8, 2)``: the footprint's corners (FL, FR, RR, RL) then its edge midpoints."""
        c, s = math.cos(self._heading), math.sin(self._heading)
        cx, cy = self._rx - self._rear_x * c, self._ry - self._rear_x * s
        out: npt.NDArray[np.float64] = self._local @ np.array([[c, s], [-s, c]]) + (cx, cy)
        return out

    def _update_progress(self) -> None:
        self._tracker.update(*self._center())

    def _near_a_box(self, cx: float, cy: float) -> bool:
        d = self._box_xy - (cx, cy)
        return bool(((d * d).sum(axis=1) <= self._box_reach2).any())

    def _emit(self, kind: EventKind, x: float, y: float, reason: str) -> None:
        self._log.emit(kind, self._t, x, y, reason)

    def _detect(self) -> None:
        import shapely  # noqa: PLC0415

        o = self.options
        cx, cy = self._center()
        pts = self._corners()
        if len(self._boxes) and "collision" not in self._log.seen and self._near_a_box(cx, cy):
            foot = shapely.Polygon(pts[:4])
            hit = self._tree.query(foot, predicate="intersects")
            if hit.size:
                i = int(hit[0])
                part = shapely.intersection(foot, self._boxes[i])
                p = shapely.centroid(part) if not part.is_empty else shapely.Point(cx, cy)
                self._emit("collision", p.x, p.y, f"hit parked vehicle {self._parked[i].id}")
        if "off_road" not in self._log.seen:
            inside = shapely.contains_xy(self._area, pts[:, 0], pts[:, 1])
            if not inside.all():
                out = pts[~inside]
                px, py = out.mean(axis=0)
                self._emit(
                    "off_road",
                    float(px),
                    float(py),
                    f"footprint left the drivable area by more than {o.offroad_margin_m} m",
                )
        self._log.judge_route(self._t, (cx, cy), self._speed, self._tracker, o, self._timeout)
