"""The CARLA backend without a server: offline map agreement, blueprints, a fake client.

The fake client, world and actors below record every call; the world's map is CARLA's own
offline ``carla.Map(name, xodr)``. The live test runs only with ``CAM2SIM_CARLA_HOST`` set.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from carla_fakes import FakeClient, FakeWorld

from cam2sim.core.errors import BackendUnavailableError, ConfigError, StageError
from cam2sim.core.frames import angle_difference, yaw_from_quat
from cam2sim.core.frames.carla import CarlaTransform, pose_from_carla
from cam2sim.map.query import RoadMap
from cam2sim.scenario.synthetic import StreetSpec, synthetic_street
from cam2sim.sim.carla_backend import (
    DEFAULT_BLUEPRINTS,
    CarlaOptions,
    CarlaSimulator,
    select_blueprint,
)
from cam2sim.sim.interface import Control, PlanarPose, Simulator

if TYPE_CHECKING:
    from cam2sim.scenario.model import Scenario

PARKED = ((20.0, -4.75, 0.0), (30.0, -4.75, 0.0), (40.0, -4.75, 0.0), (50.0, -4.75, 0.0))


@pytest.fixture(scope="module")
def street() -> tuple[Scenario, str]:
    return synthetic_street(StreetSpec(length_m=60.0, radius_m=40.0, parked=PARKED))


# -- (a) offline map agreement ------------------------------------------------------------------
def test_carla_waypoints_lie_on_our_lane_centres(street: tuple[Scenario, str]) -> None:
    carla = pytest.importorskip("carla")
    _, xodr = street
    cmap = carla.Map("t", xodr)
    ours = RoadMap.from_xodr(xodr)
    wps = [w for w in cmap.generate_waypoints(2.0) if w.lane_type == carla.LaneType.Driving]
    assert len(wps) > 20
    xyz, heading = [], []
    for w in wps:
        loc, rot = w.transform.location, w.transform.rotation
        pose = pose_from_carla(
            CarlaTransform(np.array([loc.x, loc.y, loc.z]), rot.pitch, rot.yaw, rot.roll)
        )
        xyz.append(pose.position)
        heading.append(yaw_from_quat(pose.quat))
    hit = ours.nearest_lane(np.array(xyz), "driving")
    assert (hit.lane >= 0).all()
    assert float(hit.distance.max()) < 0.05
    dh = np.abs(angle_difference(np.array(heading), hit.heading))
    assert math.degrees(float(dh.max())) < 0.5
    # both a straight and a curved stretch were checked
    assert np.ptp(np.unwrap(np.array(heading))) > 0.5


# -- (b) blueprint selection --------------------------------------------------------------------
AVAILABLE = (
    "vehicle.citroen.c3",
    "vehicle.mini.cooper_s",
    "vehicle.seat.leon",
    "vehicle.toyota.prius",
    "vehicle.tesla.model3",
    "vehicle.mercedes.sprinter",
)


def test_blueprint_choice_is_deterministic_and_allowed() -> None:
    picks = [
        select_blueprint("small", f"pv_{i:03d}", AVAILABLE, DEFAULT_BLUEPRINTS) for i in range(40)
    ]
    again = [
        select_blueprint("small", f"pv_{i:03d}", list(reversed(AVAILABLE)), DEFAULT_BLUEPRINTS)
        for i in range(40)
    ]
    assert picks == again  # order of the server's list does not matter
    assert set(picks) == {"vehicle.citroen.c3", "vehicle.mini.cooper_s"}  # both get used
    assert (
        select_blueprint("van", "pv_1", AVAILABLE, DEFAULT_BLUEPRINTS)
        == "vehicle.mercedes.sprinter"
    )
    medium = {select_blueprint("medium", f"m{i}", AVAILABLE, DEFAULT_BLUEPRINTS) for i in range(30)}
    assert medium <= {"vehicle.seat.leon", "vehicle.toyota.prius"}


def test_blueprint_choice_fails_clearly_when_nothing_matches() -> None:
    with pytest.raises(ConfigError, match=r"size class 'large'.*sim\.carla\.blueprints\.large"):
        select_blueprint("large", "pv_9", AVAILABLE, DEFAULT_BLUEPRINTS)
    with pytest.raises(ConfigError, match="'small'"):
        select_blueprint("small", "pv_9", AVAILABLE, {"small": ("vehicle.nope",)})


# -- (c) a fake client --------------------------------------------------------------------------
def _sim(
    xodr: str,
    *,
    fail_vehicle_spawn: int | None = None,
    interrupt_sensor: bool = False,
    speed_control: str = "pid",
) -> tuple[CarlaSimulator, FakeClient]:
    client = FakeClient(
        fail_vehicle_spawn=fail_vehicle_spawn,
        interrupt_sensor=interrupt_sensor,
        available=(*AVAILABLE, "vehicle.nissan.patrol"),
    )
    opts = CarlaOptions.model_validate({"image_size": (8, 5), "speed_control": speed_control})
    return CarlaSimulator(opts, xodr=xodr, client_factory=lambda *_: client), client


def _assert_torn_down(world: FakeWorld) -> None:
    assert world.actors, "nothing was spawned"
    assert {id(a) for a in world.destroyed} == {id(a) for a in world.actors}
    kinds = [a.type_id.split(".")[0] for a in world.destroyed]
    assert kinds == sorted(kinds, key=lambda k: k != "sensor")  # sensors first
    assert all(a.stopped for a in world.actors if a.type_id.startswith("sensor."))
    assert world.current.synchronous_mode is False
    assert world.current.fixed_delta_seconds is None


def test_load_step_close_with_a_fake_client(street: tuple[Scenario, str]) -> None:
    pytest.importorskip("carla")
    scenario, xodr = street
    sim, client = _sim(xodr)
    assert isinstance(sim, Simulator)
    with sim:
        sim.load(scenario, RoadMap.from_xodr(xodr))
        world = client.world
        assert world is not None
        assert client.params.vertex_distance == pytest.approx(0.1)
        assert client.params.additional_width == pytest.approx(0.6)
        assert world.applied[0].synchronous_mode
        assert world.applied[0].fixed_delta_seconds == pytest.approx(1 / 30)
        vehicles = [a for a in world.actors if a.type_id.startswith("vehicle.")]
        parked = [a for a in vehicles if a.attributes["role_name"].startswith("parked_")]
        (hero,) = [a for a in vehicles if a.attributes["role_name"] == "hero"]
        assert hero.type_id == "vehicle.tesla.model3"
        assert len(parked) == len(PARKED)
        assert not any(a.physics for a in parked)
        for a, pv in zip(parked, scenario.parked, strict=True):
            loc = a.transform.location
            assert (loc.x, -loc.y) == pytest.approx(pv.position[:2], abs=1e-4)
            assert loc.z == pytest.approx(0.0, abs=1e-4)  # set down on the road surface
        cams = [a for a in world.actors if a.type_id.startswith("sensor.camera")]
        assert {c.type_id for c in cams} == {
            "sensor.camera.rgb",
            "sensor.camera.semantic_segmentation",
        }
        for cam in cams:
            assert cam.parent is hero
            t = cam.transform
            # mount: 1.6 m ahead of the rear axle, 1.4 m up, looking forward
            ref_x = scenario.vehicle.reference_xyz[0]
            assert (t.location.x, t.location.y, t.location.z) == pytest.approx(
                (ref_x + 1.6, 0.0, 1.4), abs=1e-4
            )
            assert (t.rotation.pitch, t.rotation.yaw, t.rotation.roll) == pytest.approx(
                (0.0, 0.0, 0.0), abs=1e-4
            )
            assert float(cam.attributes["fov"]) == pytest.approx(
                math.degrees(2 * math.atan(400 / 640)), abs=1e-4
            )
        others = {a.type_id for a in world.actors if a.parent is hero} - {c.type_id for c in cams}
        assert others == {"sensor.other.collision", "sensor.other.lane_invasion"}

        state = sim.reset()
        start = scenario.hero_start
        assert (state.x, state.y) == pytest.approx(start.position[:2], abs=1e-4)
        assert state.heading == pytest.approx(start.heading, abs=1e-5)
        for _ in range(5):
            state = sim.step(Control(steering=1.0, target_speed=8.0))
        # a left command is a negative CARLA steer
        assert hero.controls[-1].steer < 0
        assert hero.controls[-1].steer == pytest.approx(-state.wheel_angle)
        assert state.progress_m > 0.5
        assert sim.events == ()
        frames = sim.camera_images()
        assert frames.frame == world.frame
        assert frames.rgb.shape == (5, 8, 3)
        assert (frames.rgb[0, 0] == (7, 0, 10)).all()
        assert frames.semantic.shape == (5, 8)
        assert (frames.semantic == 7).all()
    _assert_torn_down(world)
    sim.close()  # twice: nothing more happens
    assert len(world.destroyed) == len(world.actors)


def test_a_calibration_with_a_lens_gets_pinhole_sensors_and_remapped_images(
    street: tuple[Scenario, str],
) -> None:
    pytest.importorskip("carla")
    scenario, xodr = street
    assert scenario.camera is not None
    lens = scenario.camera.model_copy(update={"distortion": (-0.27, 0.035, 0.002, -0.001, 0.0)})
    scenario = scenario.model_copy(update={"camera": lens})
    client = FakeClient(available=(*AVAILABLE, "vehicle.nissan.patrol"))
    opts = CarlaOptions.model_validate({"image_size": (64, 40)})
    with CarlaSimulator(opts, xodr=xodr, client_factory=lambda *_: client) as sim:
        sim.load(scenario, RoadMap.from_xodr(xodr))
        world = client.world
        assert world is not None
        expected = lens.camera().scaled(64, 40).pinhole_remap(centred=True)
        assert expected is not None
        pinhole = expected[0]
        for cam in (a for a in world.actors if a.type_id.startswith("sensor.camera")):
            # The sensors are the lens's pinhole camera (larger: barrel distortion) ...
            size = (int(cam.attributes["image_size_x"]), int(cam.attributes["image_size_y"]))
            assert size == pinhole.size
            assert size[0] > 64
            assert float(cam.attributes["fov"]) == pytest.approx(
                math.degrees(2 * math.atan(pinhole.width / (2 * pinhole.fx))), abs=1e-4
            )
        sim.reset()
        sim.step(Control(steering=0.0))
        frames = sim.camera_images()
    # ... and the images come back in the lens's pixels.
    assert frames.rgb.shape == (40, 64, 3)
    assert frames.semantic.shape == (40, 64)
    assert (frames.semantic == 7).all()
    assert frames.rgb[37, 32, 1] == 200  # the lower half stays down
    assert frames.rgb[2, 32, 1] == 0


def test_collision_sensor_and_leaving_the_road_are_events(street: tuple[Scenario, str]) -> None:
    carla = pytest.importorskip("carla")
    scenario, xodr = street
    sim, client = _sim(xodr)
    with sim:
        sim.load(scenario, RoadMap.from_xodr(xodr))
        assert client.world is not None
        (col,) = [a for a in client.world.actors if a.type_id == "sensor.other.collision"]
        sim.reset()

        @dataclass
        class Other:
            type_id: str

        @dataclass
        class Hit:
            other_actor: Other

        col.callback(Hit(Other("vehicle.seat.leon")))
        sim.step(Control())
        (ev,) = sim.events
        assert ev.kind == "collision"
        assert "vehicle.seat.leon" in ev.reason
        start = scenario.hero_start
        sim.reset(PlanarPose(start.position[0], start.position[1] + 30.0, start.heading))
        sim.step(Control())
        assert [e.kind for e in sim.events] == ["off_road"]

        # lane invasion: a solid line is not off-road, a kerb is
        (inv,) = [a for a in client.world.actors if a.type_id == "sensor.other.lane_invasion"]

        @dataclass
        class Marking:
            type: Any

        @dataclass
        class Invasion:
            crossed_lane_markings: list[Marking]

        sim.reset()
        inv.callback(Invasion([Marking(carla.LaneMarkingType.SolidSolid)]))
        sim.step(Control())
        assert not sim.events
        inv.callback(Invasion([Marking(carla.LaneMarkingType.Curb)]))
        sim.step(Control())
        (ev,) = sim.events
        assert (ev.kind, ev.reason) == ("off_road", "crossed a curb marking")


@pytest.mark.parametrize("mode", ["pid", "carla"])
def test_speed_control_modes(street: tuple[Scenario, str], mode: str) -> None:
    pytest.importorskip("carla")
    scenario, xodr = street
    sim, client = _sim(xodr, speed_control=mode)
    with sim:
        sim.load(scenario, RoadMap.from_xodr(xodr))
        state = sim.reset(
            PlanarPose(*scenario.hero_start.position[:2], scenario.hero_start.heading)
        )
        assert state.speed == pytest.approx(0.0)
        state = sim.step(Control(target_speed=5.0))
        assert client.world is not None
        (hero,) = [a for a in client.world.actors if a.attributes.get("role_name") == "hero"]
        ctl = hero.controls[-1]
        if mode == "carla":  # CARLA's controller gets the target itself
            assert (ctl.speed, ctl.acceleration) == pytest.approx((5.0, 2.5))
        else:  # the builtin PID: one step of saturated acceleration
            assert (ctl.speed, ctl.acceleration) == pytest.approx((2.5 / 30, 2.5))
        assert state.speed == pytest.approx(ctl.speed, abs=1e-4)


def test_teardown_after_a_failed_parked_spawn(street: tuple[Scenario, str]) -> None:
    pytest.importorskip("carla")
    scenario, xodr = street
    sim, client = _sim(xodr, fail_vehicle_spawn=3)
    with pytest.raises(StageError, match=r"parked vehicle .*check the scenario"):
        sim.load(scenario, RoadMap.from_xodr(xodr))
    assert client.world is not None
    assert len(client.world.actors) == 2
    _assert_torn_down(client.world)
    sim.close()
    with pytest.raises(StageError, match="before load"):
        sim.step(Control())


def test_teardown_on_ctrl_c(street: tuple[Scenario, str]) -> None:
    pytest.importorskip("carla")
    scenario, xodr = street
    sim, client = _sim(xodr, interrupt_sensor=True)
    with pytest.raises(KeyboardInterrupt):
        sim.load(scenario, RoadMap.from_xodr(xodr))
    assert client.world is not None
    _assert_torn_down(client.world)  # parked cars and the hero


def test_no_server_names_host_and_port(street: tuple[Scenario, str]) -> None:
    pytest.importorskip("carla")
    scenario, xodr = street

    def refuse(host: str, port: int, timeout: float) -> Any:
        msg = f"time-out of {timeout}s while waiting for the simulator at {host}:{port}"
        raise RuntimeError(msg)

    sim = CarlaSimulator(CarlaOptions(host="simhost", port=2042), xodr=xodr, client_factory=refuse)
    with pytest.raises(
        BackendUnavailableError, match=r"simhost:2042.*CarlaUE4\.sh -RenderOffScreen"
    ):
        sim.load(scenario, RoadMap.from_xodr(xodr))
    sim.close()


# -- (d) a live server --------------------------------------------------------------------------
@pytest.mark.requires_carla
@pytest.mark.skipif(not os.environ.get("CAM2SIM_CARLA_HOST"), reason="CAM2SIM_CARLA_HOST unset")
def test_live_server_drive(street: tuple[Scenario, str]) -> None:
    pytest.importorskip("carla")
    scenario, xodr = street
    opts = CarlaOptions(
        host=os.environ["CAM2SIM_CARLA_HOST"],
        port=int(os.environ.get("CAM2SIM_CARLA_PORT", "2000")),
        image_size=(200, 126),
    )
    with CarlaSimulator(opts, xodr=xodr) as sim:
        sim.load(scenario, RoadMap.from_xodr(xodr))
        state = sim.reset()
        for _ in range(50):
            state = sim.step(Control(steering=0.0))
        frames = sim.camera_images()
    assert frames.rgb.shape == (126, 200, 3)
    assert state.progress_m > 1.0
    assert not [e for e in sim.events if e.kind in {"collision", "off_road"}]
