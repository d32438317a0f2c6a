"""The ``carla`` simulator: the scenario replayed in a running CARLA server (0.9.16).

``load`` connects, builds the world from the scenario's OpenDRIVE map with
``generate_opendrive_world`` (mesh parameters in :class:`CarlaOptions`), switches to synchronous
mode at ``dt``, spawns the parked vehicles frozen (physics off; blueprints chosen
deterministically by size class, :func:`select_blueprint`), the hero at its start pose on the road
surface, and an RGB and a semantic camera at the calibrated mount and field of view, plus
collision and lane-invasion sensors. A calibration with lens distortion gets the pinhole
sensors of :meth:`~cam2sim.core.camera.PinholeCamera.pinhole_remap` (``centred``: CARLA's
principal point is the image centre), and :meth:`CarlaSimulator.camera_images` remaps their
images into the lens's pixels, as the other cameras of runs do. Every transform crosses the
boundary through :mod:`cam2sim.core.frames.carla`.

Steering goes through ``carla.VehicleAckermannControl``: the policy's command becomes a front
wheel angle with the steering calibration (the builtin backend's angle and rate limits apply);
CARLA's steer is that angle negated (positive steer = right in CARLA's left-handed frame). Speed
is held by a PID with the builtin backend's gains and limits (``speed_control="pid"``: the
Ackermann target speed is the PID's next-step speed) or by CARLA's own Ackermann controller
(``"carla"``: the target speed with ``max_accel``).

Events, each reported once at the first step it happens, like the builtin backend:

- ``collision``: the collision sensor fired (any actor, or static geometry).
- ``off_road``: the lane-invasion sensor reported crossing a marking in ``offroad_markings``
  (kerb, grass), or a footprint check point left the road surface: the footprint corners and
  edge midpoints, pulled in by ``offroad_margin_m``, are looked up with
  ``map.get_waypoint(project_to_road=False, lane_type=road lanes)``. A solid painted line alone
  is not off-road (generated maps paint the centre line solid); leaving the carriageway over a
  solid boundary is caught by the footprint check.
- ``route_completed``, ``stuck``, ``timeout``: from the progress along the recorded centre
  trajectory, as in the builtin backend.

Assumption: the hero actor's origin is the vehicle frame origin (footprint centre on the
ground); CARLA's vehicle blueprints put their origin there up to a few centimetres.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Self

import numpy as np
import numpy.typing as npt

from cam2sim.core.dataset import NO_INTRINSICS_HINT
from cam2sim.core.errors import BackendUnavailableError, ConfigError, StageError
from cam2sim.core.frames.carla import (
    CarlaTransform,
    carla_to_world,
    pose_from_carla,
    pose_to_carla,
    world_to_carla,
)
from cam2sim.core.frames.pose import Pose
from cam2sim.core.frames.rotation import (
    quat_from_matrix,
    quat_from_yaw,
    quat_to_matrix,
    yaw_from_quat,
)
from cam2sim.sim.carla_options import DEFAULT_BLUEPRINTS, CarlaOptions, select_blueprint
from cam2sim.sim.control import (
    EventLog,
    RouteTracker,
    SpeedPid,
    limit_wheel_angle,
    wanted_wheel_angle,
)
from cam2sim.sim.interface import (
    Control,
    EventKind,
    PlanarPose,
    SimEvent,
    VehicleState,
)

if TYPE_CHECKING:
    from types import TracebackType

    from cam2sim.map.query import RoadMap
    from cam2sim.scenario.model import Scenario

__all__ = [
    "DEFAULT_BLUEPRINTS",
    "CameraFrames",
    "CarlaOptions",
    "CarlaSimulator",
    "ClientFactory",
    "camera_link_pose",
    "horizontal_fov_deg",
    "select_blueprint",
]

logger = logging.getLogger(__name__)

ClientFactory = Callable[[str, int, float], Any]
"""``(host, port, timeout_s) -> client``: a ``carla.Client`` or a stand-in with its methods."""

_START_HINT = (
    "start CARLA 0.9.16 first (`./CarlaUE4.sh -RenderOffScreen` in the CARLA folder) or set "
    "sim.carla.host / sim.carla.port in config.yaml"
)
_INSTALL_HINT = "install the CARLA client with: pip install cam2sim[map] (carla==0.9.16)"
_PARKED_SPAWN_LIFT_M = 0.25  # spawned this high (clear of the road mesh), then set down frozen


@dataclass(frozen=True, slots=True)
class CameraFrames:
    """The latest images of the attached cameras.

    Attributes:
        frame: CARLA frame number both images belong to.
        rgb: ``(H, W, 3)`` uint8 RGB.
        semantic: ``(H, W)`` uint8 CARLA semantic tags (the red channel of the raw image).
    """

    frame: int
    rgb: npt.NDArray[np.uint8]
    semantic: npt.NDArray[np.uint8]


def _import_carla() -> Any:
    """Import ``carla`` (PROJ data set for its bundled PROJ), or say how to install it."""
    try:
        import pyproj.datadir  # noqa: PLC0415

        data_dir = str(pyproj.datadir.get_data_dir())
        os.environ.setdefault("PROJ_LIB", data_dir)
        os.environ.setdefault("PROJ_DATA", data_dir)
    except ImportError:  # pragma: no cover - pyproj is a core dependency
        pass
    try:
        import carla  # noqa: PLC0415
    except ImportError as exc:
        msg = f"the carla backend needs the carla package; {_INSTALL_HINT}"
        raise BackendUnavailableError(msg) from exc
    return carla


def _default_client_factory(host: str, port: int, timeout_s: float) -> Any:
    carla = _import_carla()
    client = carla.Client(host, port)
    client.set_timeout(timeout_s)
    return client


def _to_carla_transform(carla: Any, pose: Pose) -> Any:
    t = pose_to_carla(pose)
    loc = t.location
    return carla.Transform(
        carla.Location(x=float(loc[0]), y=float(loc[1]), z=float(loc[2])),
        carla.Rotation(pitch=t.pitch_deg, yaw=t.yaw_deg, roll=t.roll_deg),
    )


def _location(carla: Any, x: float, y: float, z: float) -> Any:
    """A ``carla.Location`` of a world point."""
    c = world_to_carla([x, y, z])
    return carla.Location(x=float(c[0]), y=float(c[1]), z=float(c[2]))


def _from_carla_transform(tf: Any) -> Pose:
    loc, rot = tf.location, tf.rotation
    ct = CarlaTransform(
        location=np.array([loc.x, loc.y, loc.z], dtype=np.float64),
        pitch_deg=float(rot.pitch),
        yaw_deg=float(rot.yaw),
        roll_deg=float(rot.roll),
    )
    return pose_from_carla(ct)


def _ground_pose(x: float, y: float, z: float, heading: float) -> Pose:
    return Pose(np.array([x, y, z], dtype=np.float64), quat_from_yaw(heading))


# Camera optical axes (x right, y down, z forward) -> link axes (x forward, y left, z up).
_OPTICAL_TO_LINK = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def camera_link_pose(scenario: Scenario) -> Pose:
    """The camera's link-axes pose (x forward, y left, z up) in the vehicle frame."""
    m = scenario.camera_mount
    rot = quat_to_matrix(np.asarray(m.quat_xyzw, dtype=np.float64))
    if m.axes == "optical":
        rot = rot @ _OPTICAL_TO_LINK
    t = np.asarray(m.translation_m, dtype=np.float64) + np.asarray(scenario.vehicle.reference_xyz)
    return Pose(t, quat_from_matrix(rot))


def horizontal_fov_deg(scenario: Scenario) -> float:
    """The scenario camera's horizontal field of view, degrees (``2 atan(w / 2 fx)``).

    Raises:
        StageError: The scenario has no camera intrinsics.
    """
    cam = scenario.camera
    if cam is None:
        msg = f"the scenario has no camera intrinsics; {NO_INTRINSICS_HINT}"
        raise StageError(msg)
    return math.degrees(2.0 * math.atan(0.5 * cam.width / cam.K[0][0]))


class CarlaSimulator:
    """The CARLA backend; see the module docstring.

    Use it as a context manager so that every spawned actor is destroyed and the world's
    settings are restored, also on an error or Ctrl-C::

        with CarlaSimulator(CarlaOptions(), xodr=path) as sim:
            sim.load(scenario, road_map)
            state = sim.reset()
            while not sim.done:
                state = sim.step(Control(steering=policy(sim.camera_images().rgb)))

    Args:
        options: Settings.
        xodr: The OpenDRIVE map, as a file or its text; None: ``scenario.map_file`` resolved
            against ``workspace_root``.
        workspace_root: Where ``scenario.map_file`` is relative to.
        client_factory: Builds the client (tests pass a stand-in).
    """

    def __init__(
        self,
        options: CarlaOptions | None = None,
        *,
        xodr: str | Path | None = None,
        workspace_root: Path | None = None,
        client_factory: ClientFactory | None = None,
    ) -> None:
        self.options = options or CarlaOptions()
        self._xodr = xodr
        self._workspace_root = workspace_root
        self._client_factory = client_factory or _default_client_factory
        self._loaded = False
        self._world: Any = None
        self._original_settings: Any = None
        self._sensors: list[Any] = []
        self._actors: list[Any] = []  # vehicles, spawn order
        self._hero: Any = None
        self._log = EventLog()
        self._lock = threading.Lock()
        self._pending: list[tuple[EventKind, str]] = []
        self._images: dict[str, Any] = {}
        self._lens: Any = None  # (map_x, map_y) into the lens's pixels; None: pinhole camera
        self._frame = -1

    # -- context ---------------------------------------------------------------------------
    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- world -----------------------------------------------------------------------------
    def load(self, scenario: Scenario, road_map: RoadMap) -> None:  # noqa: ARG002
        """Connect, build the world and spawn everything; on any failure tear it down again.

        ``road_map`` is not needed (CARLA builds its own from the same OpenDRIVE); it is taken
        for the :class:`~cam2sim.sim.interface.Simulator` protocol.

        Raises:
            BackendUnavailableError: carla is not installed or no server answers.
            StageError: A spawn failed, or the map is missing.
            ConfigError: No allowed blueprint for a parked vehicle's size class.
        """
        self.close()
        try:
            self._load(scenario)
            self._loaded = True
            self.reset()
        except BaseException:
            self.close()
            raise

    def _map_text(self, scenario: Scenario) -> str:
        src = self._xodr
        if isinstance(src, Path):
            return src.read_text(encoding="utf-8")
        if isinstance(src, str):
            return src
        if scenario.map_file is None or self._workspace_root is None:
            msg = (
                "the carla backend needs the OpenDRIVE map: pass xodr= or workspace_root= (the "
                "scenario's map_file is "
                f"{scenario.map_file!r}); run `cam2sim map WS` if the workspace has none"
            )
            raise StageError(msg)
        return (self._workspace_root / scenario.map_file).read_text(encoding="utf-8")

    def _connect(self) -> Any:
        o = self.options
        where = f"{o.host}:{o.port}"
        try:
            client = self._client_factory(o.host, o.port, o.timeout_s)
            version = client.get_server_version()
        except BackendUnavailableError:
            raise
        except RuntimeError as exc:
            msg = (
                f"no CARLA server answered at {where} within {o.timeout_s} s ({exc}); {_START_HINT}"
            )
            raise BackendUnavailableError(msg) from exc
        logger.info("connected to CARLA %s at %s", version, where)
        return client

    def _load(self, scenario: Scenario) -> None:
        carla = _import_carla()
        o = self.options
        xodr = self._map_text(scenario)
        client = self._connect()
        params = carla.OpendriveGenerationParameters(
            vertex_distance=o.vertex_distance,
            max_road_length=o.max_road_length,
            wall_height=o.wall_height,
            additional_width=o.additional_width,
            smooth_junctions=o.smooth_junctions,
            enable_mesh_visibility=o.enable_mesh_visibility,
        )
        world = client.generate_opendrive_world(xodr, params)
        self._world = world
        self._original_settings = world.get_settings()
        settings = world.get_settings()
        settings.synchronous_mode = True
        settings.fixed_delta_seconds = o.dt
        world.apply_settings(settings)
        self._map = world.get_map()
        self._carla = carla
        self._lane_mask = self._lane_type_mask(carla)
        library = world.get_blueprint_library()
        self._spawn_parked(carla, world, library, scenario)

        v = scenario.vehicle
        self._wheelbase = v.wheelbase_m
        self._rear_x = v.rear_axle_xyz[0]
        self._half = (0.5 * v.length_m, 0.5 * v.width_m)
        self._calibration = o.calibration or scenario.steering_calibration
        self._start = scenario.hero_start
        hx, hy, hz = scenario.hero_start.position
        if not list(library.filter(o.hero_blueprint)):
            msg = (
                f"the server has no hero blueprint {o.hero_blueprint!r}; set "
                "sim.carla.hero_blueprint to one of its vehicle.* blueprints"
            )
            raise ConfigError(msg)
        bp = library.find(o.hero_blueprint)
        if bp.has_attribute("role_name"):
            bp.set_attribute("role_name", "hero")
        z0 = self._surface_z(hx, hy, hz) + o.spawn_lift_m
        tf = _to_carla_transform(carla, _ground_pose(hx, hy, z0, scenario.hero_start.heading))
        try:
            hero = world.spawn_actor(bp, tf)
        except RuntimeError as exc:
            msg = f"CARLA refused the hero ({o.hero_blueprint}) at ({hx:.2f}, {hy:.2f}): {exc}"
            raise StageError(msg) from exc
        self._actors.append(hero)
        self._hero = hero
        self._attach_sensors(carla, world, library, scenario, hero)
        self._setup_route(scenario)

    def _spawn_parked(self, carla: Any, world: Any, library: Any, scenario: Scenario) -> None:
        """Spawn the parked vehicles frozen (physics off), blueprints by size class."""
        o = self.options
        available = [bp.id for bp in library.filter("vehicle.*")]
        for pv in scenario.parked:
            name = select_blueprint(pv.size_class, pv.id, available, o.blueprints)
            bp = library.find(name)
            if bp.has_attribute("role_name"):
                bp.set_attribute("role_name", f"parked_{pv.id}")
            x, y, z = pv.position
            ground = self._surface_z(x, y, z)
            lifted = _ground_pose(x, y, ground + _PARKED_SPAWN_LIFT_M, pv.heading)
            try:
                actor = world.spawn_actor(bp, _to_carla_transform(carla, lifted))
            except RuntimeError as exc:
                msg = (
                    f"CARLA refused parked vehicle {pv.id} ({name}) at ({x:.2f}, {y:.2f}): "
                    f"{exc}; check the scenario's parked vehicles for overlaps"
                )
                raise StageError(msg) from exc
            self._actors.append(actor)
            actor.set_simulate_physics(False)  # frozen: a static obstacle, then set down
            actor.set_transform(_to_carla_transform(carla, _ground_pose(x, y, ground, pv.heading)))

    def _lane_type_mask(self, carla: Any) -> Any:
        mask: Any = None
        for name in self.options.road_lane_types:
            lt = getattr(carla.LaneType, name[:1].upper() + name[1:], None)
            if lt is None:
                msg = f"road_lane_types has {name!r}, which carla.LaneType does not know"
                raise ConfigError(msg)
            mask = lt if mask is None else mask | lt
        return mask

    def _surface_z(self, x: float, y: float, z: float) -> float:
        """Road surface height near a world point (``z`` when no lane is near)."""
        c = self._carla
        loc = _location(c, x, y, z)
        wp = self._map.get_waypoint(loc, project_to_road=True, lane_type=c.LaneType.Any)
        return float(wp.transform.location.z) if wp is not None else z

    def _attach_sensors(
        self, carla: Any, world: Any, library: Any, scenario: Scenario, hero: Any
    ) -> None:
        o = self.options
        cam = scenario.camera
        fov = horizontal_fov_deg(scenario)
        assert cam is not None
        w, h = o.image_size or (cam.width, cam.height)
        lens = cam.camera().scaled(w, h).pinhole_remap(centred=True)
        self._lens = None if lens is None else lens[1:]
        if lens is not None:  # the sensors see the lens's pinhole camera; images are remapped
            pinhole = lens[0]
            w, h = pinhole.width, pinhole.height
            fov = math.degrees(2.0 * math.atan(0.5 * w / pinhole.fx))
        mount = _to_carla_transform(carla, camera_link_pose(scenario))
        for kind, bp_name in (
            ("rgb", "sensor.camera.rgb"),
            ("semantic", "sensor.camera.semantic_segmentation"),
        ):
            bp = library.find(bp_name)
            bp.set_attribute("image_size_x", str(w))
            bp.set_attribute("image_size_y", str(h))
            bp.set_attribute("fov", f"{fov:.6f}")
            sensor = world.spawn_actor(bp, mount, attach_to=hero)
            self._sensors.append(sensor)
            sensor.listen(self._image_callback(kind))
        ident = carla.Transform()
        collision = world.spawn_actor(library.find("sensor.other.collision"), ident, attach_to=hero)
        self._sensors.append(collision)
        collision.listen(self._on_collision)
        invasion = world.spawn_actor(
            library.find("sensor.other.lane_invasion"), ident, attach_to=hero
        )
        self._sensors.append(invasion)
        invasion.listen(self._on_lane_invasion)

    def _setup_route(self, scenario: Scenario) -> None:

        o = self.options
        center = np.asarray(scenario.trajectory.center, dtype=np.float64)[:, :2]
        self._tracker = RouteTracker(center, max_lateral_m=self.options.route_max_lateral_m)
        self._pid = SpeedPid(self.options)
        t = scenario.trajectory.t
        self._timeout = (
            o.episode_timeout_s if o.episode_timeout_s is not None else 2.0 * (t[-1] - t[0]) + 10.0
        )
        hl, hw = self._half
        m = o.offroad_margin_m
        hl, hw = max(0.0, hl - m), max(0.0, hw - m)
        corners = [[hl, hw], [hl, -hw], [-hl, -hw], [-hl, hw]]
        mids = [[hl, 0.0], [0.0, -hw], [-hl, 0.0], [0.0, hw]]
        self._local = np.array(corners + mids)

    # -- sensor callbacks (CARLA's threads) ------------------------------------------------
    def _image_callback(self, kind: str) -> Callable[[Any], None]:
        def store(image: Any) -> None:
            with self._lock:
                self._images[kind] = image

        return store

    def _on_collision(self, event: Any) -> None:
        other = getattr(event.other_actor, "type_id", "static geometry")
        with self._lock:
            self._pending.append(("collision", f"hit {other}"))

    def _on_lane_invasion(self, event: Any) -> None:
        names = [str(m.type).rsplit(".", 1)[-1] for m in event.crossed_lane_markings]
        bad = [n for n in names if n in self.options.offroad_markings]
        if bad:
            with self._lock:
                self._pending.append(("off_road", f"crossed a {bad[0].lower()} marking"))

    # -- episode ---------------------------------------------------------------------------
    def reset(self, pose: PlanarPose | None = None) -> VehicleState:
        """Place the hero at ``pose`` (default: the hero start), tick once, clear the events.

        Raises:
            StageError: ``load`` has not been called.
        """
        if not self._loaded:
            msg = "CarlaSimulator.reset before load; call load(scenario, road_map) first"
            raise StageError(msg)
        c = self._carla
        if pose is None:
            s = self._start
            pose = PlanarPose(s.position[0], s.position[1], s.heading, s.speed)
        z = self._surface_z(pose.x, pose.y, self._start.position[2]) + self.options.spawn_lift_m
        hero = self._hero
        hero.set_transform(_to_carla_transform(c, _ground_pose(pose.x, pose.y, z, pose.heading)))
        v = max(0.0, pose.speed)
        vel = world_to_carla([v * math.cos(pose.heading), v * math.sin(pose.heading), 0.0])
        hero.set_target_velocity(c.Vector3D(x=float(vel[0]), y=float(vel[1]), z=float(vel[2])))
        hero.set_target_angular_velocity(c.Vector3D())
        hero.apply_ackermann_control(c.VehicleAckermannControl())
        ts = self.options.target_speed
        self._target = ts if ts is not None else self._start.speed
        self._delta = 0.0
        self._steer = 0.0
        self._t = 0.0
        self._frame = int(self._world.tick())
        self._speed = v
        self._pid.reset(v)
        with self._lock:
            self._pending.clear()
        self._log.reset()
        self._tracker.reset()
        state = self._read_state()
        self._update_progress(state.x, state.y)
        return self._with_progress(state)

    @property
    def events(self) -> tuple[SimEvent, ...]:
        """Events since the last reset, in order."""
        return tuple(self._log.events)

    @property
    def done(self) -> bool:
        """Whether an event ended the episode (any event does)."""
        return bool(self._log.events)

    def step(self, control: Control) -> VehicleState:
        """Apply ``control`` through Ackermann control and tick the world once.

        Raises:
            StageError: ``load`` has not been called.
            ConfigError: A non-finite command.
        """
        if not self._loaded:
            msg = "CarlaSimulator.step before load; call load(scenario, road_map) first"
            raise StageError(msg)
        o = self.options
        c = self._carla
        if control.target_speed is not None:
            self._target = max(0.0, control.target_speed)
        self._steer_toward(control)
        if o.speed_control == "pid":
            acc = self._acceleration()
            speed = max(0.0, self._speed + acc * o.dt)
            ctl = c.VehicleAckermannControl(
                steer=-self._delta,
                steer_speed=o.max_steer_rate_rad_s,
                speed=speed,
                acceleration=abs(acc),
                jerk=0.0,
            )
        else:
            ctl = c.VehicleAckermannControl(
                steer=-self._delta,
                steer_speed=o.max_steer_rate_rad_s,
                speed=self._target,
                acceleration=o.max_accel,
                jerk=0.0,
            )
        self._hero.apply_ackermann_control(ctl)
        self._frame = int(self._world.tick())
        self._t += o.dt
        state = self._read_state()
        self._speed = state.speed
        self._update_progress(state.x, state.y)
        self._detect(state)
        return self._with_progress(state)

    def camera_images(self, timeout_s: float | None = None) -> CameraFrames:
        """The RGB and semantic images of the last tick.

        Raises:
            StageError: Not loaded, or the images did not arrive within ``timeout_s``.
        """
        if not self._loaded:
            msg = "CarlaSimulator.camera_images before load; call load(scenario, road_map) first"
            raise StageError(msg)
        wait = self.options.image_timeout_s if timeout_s is None else timeout_s
        deadline = time.monotonic() + wait
        while True:
            with self._lock:
                rgb, sem = self._images.get("rgb"), self._images.get("semantic")
            if (
                rgb is not None
                and sem is not None
                and rgb.frame >= self._frame
                and sem.frame >= self._frame
            ):
                break
            if time.monotonic() >= deadline:
                msg = (
                    f"the cameras sent no image of frame {self._frame} within {wait} s; the "
                    "server may be overloaded (raise sim.carla.image_timeout_s)"
                )
                raise StageError(msg)
            time.sleep(0.002)
        colour, labels = _bgra(rgb)[..., 2::-1].copy(), _bgra(sem)[..., 2].copy()
        if self._lens is not None:
            import cv2  # noqa: PLC0415 -- lazy: imports cv2

            map_x, map_y = self._lens
            colour = np.asarray(cv2.remap(colour, map_x, map_y, cv2.INTER_LINEAR), np.uint8)
            labels = np.asarray(cv2.remap(labels, map_x, map_y, cv2.INTER_NEAREST), np.uint8)
        return CameraFrames(frame=int(rgb.frame), rgb=colour, semantic=labels)

    def close(self) -> None:
        """Destroy every spawned actor (sensors first) and restore the world's settings.

        Idempotent, and safe after a partial ``load``: each step is attempted and a failure is
        logged, not raised, so the rest is still cleaned up.
        """
        self._loaded = False
        for sensor in reversed(self._sensors):
            _quietly(sensor.stop, "stop sensor")
        for actor in [*reversed(self._sensors), *reversed(self._actors)]:
            _quietly(actor.destroy, "destroy actor")
        self._sensors.clear()
        self._actors.clear()
        self._hero = None
        if self._world is not None and self._original_settings is not None:
            _quietly(
                lambda: self._world.apply_settings(self._original_settings), "restore settings"
            )
        self._original_settings = None
        self._world = None
        with self._lock:
            self._images.clear()
            self._pending.clear()

    # -- helpers ---------------------------------------------------------------------------
    def _steer_toward(self, control: Control) -> None:
        """Move the wheel angle toward the command within the angle and rate limits."""
        o = self.options
        self._steer, want = wanted_wheel_angle(
            control, self._calibration, self._wheelbase, self._target
        )
        self._delta = limit_wheel_angle(
            self._delta,
            want,
            max_angle=o.max_wheel_angle_rad,
            max_rate=o.max_steer_rate_rad_s,
            dt=o.dt,
        )

    def _acceleration(self) -> float:
        """The builtin backend's PID on the speed error (same gains, limits and anti-windup)."""
        return self._pid.acceleration(self._target, self._speed)

    def _read_state(self) -> VehicleState:
        pose = _from_carla_transform(self._hero.get_transform())
        x, y, z = (float(v) for v in pose.position)
        heading = float(yaw_from_quat(pose.quat))
        v = self._hero.get_velocity()
        vel = carla_to_world([v.x, v.y, v.z])
        speed = math.hypot(float(vel[0]), float(vel[1]))
        c, s = math.cos(heading), math.sin(heading)
        return VehicleState(
            t=self._t,
            x=x,
            y=y,
            z=z,
            heading=heading,
            speed=speed,
            wheel_angle=self._delta,
            steering=self._steer,
            rear_axle=(x + self._rear_x * c, y + self._rear_x * s),
        )

    def _with_progress(self, state: VehicleState) -> VehicleState:
        return dataclasses.replace(state, progress_m=self._tracker.progress)

    def _update_progress(self, cx: float, cy: float) -> None:
        self._tracker.update(cx, cy)

    def _emit(self, kind: EventKind, x: float, y: float, reason: str) -> None:
        self._log.emit(kind, self._t, x, y, reason)

    def _off_road_point(self, state: VehicleState) -> tuple[float, float] | None:
        """The first footprint check point off the road surface, or None."""
        c = self._carla
        cs, sn = math.cos(state.heading), math.sin(state.heading)
        pts = self._local @ np.array([[cs, sn], [-sn, cs]]) + (state.x, state.y)
        for px, py in pts:
            loc = _location(c, float(px), float(py), state.z)
            wp = self._map.get_waypoint(loc, project_to_road=False, lane_type=self._lane_mask)
            if wp is None:
                return (float(px), float(py))
        return None

    def _detect(self, state: VehicleState) -> None:
        o = self.options
        cx, cy = state.x, state.y
        with self._lock:
            pending, self._pending = self._pending, []
        for kind, reason in pending:
            self._emit(kind, cx, cy, reason)
        if "off_road" not in self._log.seen:
            out = self._off_road_point(state)
            if out is not None:
                self._emit(
                    "off_road",
                    out[0],
                    out[1],
                    f"footprint left the road surface by more than {o.offroad_margin_m} m",
                )
        self._log.judge_route(self._t, (cx, cy), state.speed, self._tracker, o, self._timeout)


def _bgra(image: Any) -> npt.NDArray[np.uint8]:
    """A CARLA image's ``raw_data`` as ``(H, W, 4)`` uint8 BGRA."""
    buf = np.frombuffer(bytes(image.raw_data), dtype=np.uint8)
    return buf.reshape(int(image.height), int(image.width), 4)


def _quietly(action: Callable[[], object], what: str) -> None:
    """Run one teardown action; log (not raise) a failure so the rest still runs."""
    try:
        action()
    except Exception:
        logger.warning("carla teardown: %s failed", what, exc_info=True)
