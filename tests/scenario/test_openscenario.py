from __future__ import annotations

import math
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from cam2sim.core.dataset import MountRecord
from cam2sim.core.errors import BackendUnavailableError, ConfigError
from cam2sim.core.workspace import WorldFrameRecord
from cam2sim.scenario.model import (
    HeroStart,
    Scenario,
    ScenarioTrajectory,
    ScenarioVehicle,
    VehicleGeometry,
)
from cam2sim.scenario.openscenario import validate_openscenario, write_openscenario

pytest.importorskip("scenariogeneration", reason="needs the scenario extra")
pytest.importorskip("xmlschema", reason="needs the scenario extra")

MAP = "../map/map.xodr"
REAR_X = -1.393
RADIUS = 40.0
SPEED = 5.0  # m/s: 0.5 m between the 10 Hz samples


def _rotate(xy: tuple[float, float], heading: float) -> np.ndarray:
    c, s = math.cos(heading), math.sin(heading)
    return np.array([c * xy[0] - s * xy[1], s * xy[0] + c * xy[1]])


def _scenario() -> Scenario:
    """A 50 m left curve (radius 40 m) driven at 5 m/s, sampled at 10 Hz, on a gentle slope."""
    t = np.arange(101) / 10.0
    s = SPEED * t
    theta = s / RADIUS - math.pi / 2
    center = np.stack([RADIUS * np.cos(theta), RADIUS * np.sin(theta) + RADIUS, 0.02 * s], axis=1)
    heading = theta + math.pi / 2
    rear = center.copy()
    rear[:, 0] += REAR_X * np.cos(heading)
    rear[:, 1] += REAR_X * np.sin(heading)
    rows = [tuple(p) for p in rear.tolist()]
    trajectory = ScenarioTrajectory(
        heading_source="orientation",
        frame=tuple(range(len(t))),
        stamp_ns=tuple(1_700_000_000_000_000_000 + 100_000_000 * i for i in range(len(t))),
        t=tuple(t.tolist()),
        heading=tuple(heading.tolist()),
        speed=(SPEED,) * len(t),
        reference=rows,
        center=tuple(tuple(p) for p in center.tolist()),
        rear_axle=rows,
    )
    parked = (
        ScenarioVehicle(
            id="parked_001",
            position=(10.0, -4.0, 0.0),
            heading=0.1,
            size=(4.5, 1.8, 1.5),
            size_class="medium",
            side="right",
            orientation="parallel",
        ),
        ScenarioVehicle(
            id="parked_002",
            position=(30.0, 12.0, 0.2),
            heading=2.0,
            size=(5.4, 2.0, 2.3),
            size_class="van",
            side="left",
            orientation="parallel",
        ),
    )
    return Scenario(
        map_file="map/map.xodr",
        world=WorldFrameRecord(proj_string=None),
        vehicle=VehicleGeometry(
            length_m=4.79,
            width_m=2.16,
            height_m=1.49,
            wheelbase_m=2.875,
            reference_xyz=(REAR_X, 0.0, 0.0),
            rear_axle_xyz=(REAR_X, 0.0, 0.0),
        ),
        trajectory=trajectory,
        hero_start=HeroStart(position=(0.0, 0.0, 0.0), heading=0.0, speed=SPEED),
        parked=parked,
        camera_mount=MountRecord(
            translation_m=(1.5, 0.0, 1.4),
            quat_xyzw=(-0.5, 0.5, -0.5, 0.5),
            axes="optical",
            source="config",
        ),
    )


@pytest.fixture(scope="module")
def scenario() -> Scenario:
    return _scenario()


@pytest.fixture(scope="module")
def xosc_root(scenario: Scenario, tmp_path_factory: pytest.TempPathFactory) -> ET.Element:
    path = tmp_path_factory.mktemp("xosc") / "scenario.xosc"
    write_openscenario(scenario, path, map_path=MAP)
    return ET.parse(path).getroot()


def _world(element: ET.Element | None) -> tuple[float, float, float, float]:
    assert element is not None
    return tuple(float(element.attrib[k]) for k in ("x", "y", "z", "h"))  # type: ignore[return-value]


def _teleport(root: ET.Element, name: str) -> tuple[float, float, float, float]:
    private = root.find(f"Storyboard/Init/Actions/Private[@entityRef='{name}']")
    assert private is not None
    return _world(private.find(".//TeleportAction/Position/WorldPosition"))


def _vertices(root: ET.Element) -> tuple[np.ndarray, np.ndarray]:
    vertices = root.findall(".//FollowTrajectoryAction//Polyline/Vertex")
    times = np.array([float(v.attrib["time"]) for v in vertices])
    poses = np.array([_world(v.find("Position/WorldPosition")) for v in vertices])
    return times, poses


@pytest.mark.parametrize("minor", [0, 1, 2, 3])
def test_openscenario_validates_against_official_schema(
    scenario: Scenario, tmp_path: Path, minor: int
) -> None:
    path = tmp_path / "scenario.xosc"
    write_openscenario(scenario, path, map_path=MAP, version_minor=minor)
    header = ET.parse(path).getroot().find("FileHeader")
    assert header is not None
    assert (header.attrib["revMajor"], header.attrib["revMinor"]) == ("1", str(minor))
    assert validate_openscenario(path) == []


def test_openscenario_references_map_and_names_every_entity(xosc_root: ET.Element) -> None:
    logic = xosc_root.find("RoadNetwork/LogicFile")
    assert logic is not None
    assert logic.attrib["filepath"] == MAP
    names = [o.attrib["name"] for o in xosc_root.findall("Entities/ScenarioObject")]
    assert names == ["hero", "parked_001", "parked_002"]
    categories = [v.attrib["vehicleCategory"] for v in xosc_root.findall("Entities/*/Vehicle")]
    assert categories == ["car", "car", "van"]
    actors = xosc_root.findall(".//ManeuverGroup/Actors/EntityRef")
    assert [a.attrib["entityRef"] for a in actors] == ["hero"]


def test_route_follows_rear_axle_with_increasing_times(
    scenario: Scenario, xosc_root: ET.Element
) -> None:
    times, poses = _vertices(xosc_root)
    traj = scenario.trajectory
    np.testing.assert_allclose(poses[0], [*traj.rear_axle[0], traj.heading[0]], atol=1e-6)
    np.testing.assert_allclose(poses[-1], [*traj.rear_axle[-1], traj.heading[-1]], atol=1e-6)
    assert times[0] == 0.0
    assert times[-1] == pytest.approx(traj.t[-1])
    assert np.all(np.diff(times) > 0)
    # every vertex is a recorded sample, at its recorded time
    index = np.searchsorted(np.asarray(traj.t), times)
    np.testing.assert_allclose(poses[:, :3], np.asarray(traj.rear_axle)[index], atol=1e-9)
    timing = xosc_root.find(".//FollowTrajectoryAction/TimeReference/Timing")
    assert timing is not None
    assert timing.attrib == {"domainAbsoluteRelative": "absolute", "scale": "1.0", "offset": "0.0"}
    mode = xosc_root.find(".//FollowTrajectoryAction/TrajectoryFollowingMode")
    assert mode is not None
    assert mode.attrib["followingMode"] == "position"


@pytest.mark.parametrize(("spacing", "expected"), [(0.3, 101), (1.0, 101), (1.2, 51), (2.6, 21)])
def test_route_vertex_spacing_stays_within_option(
    scenario: Scenario, tmp_path: Path, spacing: float, expected: int
) -> None:
    path = tmp_path / "scenario.xosc"
    write_openscenario(scenario, path, map_path=MAP, max_vertex_spacing_m=spacing)
    _, poses = _vertices(ET.parse(path).getroot())
    gaps = np.linalg.norm(np.diff(poses[:, :3], axis=0), axis=1)
    raw_step = float(np.linalg.norm(np.diff(np.asarray(scenario.trajectory.rear_axle)[:2], axis=0)))
    assert gaps.max() <= max(spacing, raw_step) + 1e-9
    # the rear axle runs on a 40.02 m circle: its samples are 0.5003 m apart
    assert len(poses) == expected


def test_hero_starts_at_rear_axle_of_start_pose_with_recorded_speed(
    scenario: Scenario, xosc_root: ET.Element
) -> None:
    start = scenario.hero_start
    x, y, z, h = _teleport(xosc_root, "hero")
    expected_xy = np.array(start.position[:2]) + _rotate((REAR_X, 0.0), start.heading)
    np.testing.assert_allclose([x, y, z, h], [*expected_xy, start.position[2], start.heading])
    speed = xosc_root.find(
        "Storyboard/Init/Actions/Private[@entityRef='hero']//AbsoluteTargetSpeed"
    )
    assert speed is not None
    assert float(speed.attrib["value"]) == SPEED


def test_parked_vehicles_stand_at_their_scaled_rear_axle(
    scenario: Scenario, xosc_root: ET.Element
) -> None:
    for car in scenario.parked:
        x, y, z, h = _teleport(xosc_root, car.id)
        rear = REAR_X * car.size[0] / scenario.vehicle.length_m
        expected_xy = np.array(car.position[:2]) + _rotate((rear, 0.0), car.heading)
        np.testing.assert_allclose([x, y, z, h], [*expected_xy, car.position[2], car.heading])
        # stationary: the only story acts on the hero
        private = xosc_root.find(f"Storyboard/Init/Actions/Private[@entityRef='{car.id}']")
        assert private is not None
        assert len(private) == 1


def test_bounding_boxes_and_axles_match_geometry(scenario: Scenario, xosc_root: ET.Element) -> None:
    geometry = scenario.vehicle
    sizes = {"hero": (geometry.length_m, geometry.width_m, geometry.height_m)}
    sizes |= {car.id: car.size for car in scenario.parked}
    for obj in xosc_root.findall("Entities/ScenarioObject"):
        length, width, height = sizes[obj.attrib["name"]]
        scale = length / geometry.length_m
        dims = obj.find("Vehicle/BoundingBox/Dimensions")
        center = obj.find("Vehicle/BoundingBox/Center")
        rear = obj.find("Vehicle/Axles/RearAxle")
        front = obj.find("Vehicle/Axles/FrontAxle")
        assert dims is not None
        assert center is not None
        assert rear is not None
        assert front is not None
        got = [float(dims.attrib[k]) for k in ("length", "width", "height")]
        np.testing.assert_allclose(got, [length, width, height])
        got = [float(center.attrib[k]) for k in ("x", "y", "z")]
        np.testing.assert_allclose(got, [-REAR_X * scale, 0.0, height / 2])
        assert float(rear.attrib["positionX"]) == pytest.approx(0.0, abs=1e-12)
        assert float(front.attrib["positionX"]) == pytest.approx(geometry.wheelbase_m * scale)


def test_center_body_point_moves_every_position_to_the_centre(
    scenario: Scenario, tmp_path: Path
) -> None:
    path = tmp_path / "scenario.xosc"
    write_openscenario(scenario, path, map_path=MAP, body_point="center")
    root = ET.parse(path).getroot()
    _, poses = _vertices(root)
    np.testing.assert_allclose(poses[0, :3], scenario.trajectory.center[0], atol=1e-6)
    car = scenario.parked[0]
    np.testing.assert_allclose(_teleport(root, car.id), [*car.position, car.heading])
    center = root.find("Entities/ScenarioObject/Vehicle/BoundingBox/Center")
    assert center is not None
    assert float(center.attrib["x"]) == 0.0
    assert validate_openscenario(path) == []


def test_storyboard_stops_after_the_recorded_duration(
    scenario: Scenario, xosc_root: ET.Element
) -> None:
    stop = xosc_root.find("Storyboard/StopTrigger//SimulationTimeCondition")
    assert stop is not None
    assert float(stop.attrib["value"]) == pytest.approx(scenario.trajectory.t[-1] + 1.0)
    starts = xosc_root.findall("Storyboard/Story//StartTrigger//SimulationTimeCondition")
    assert [float(s.attrib["value"]) for s in starts] == [0.0, 0.0]


def test_validation_names_a_removed_element(scenario: Scenario, tmp_path: Path) -> None:
    path = tmp_path / "scenario.xosc"
    write_openscenario(scenario, path, map_path=MAP)
    tree = ET.parse(path)
    box = tree.getroot().find("Entities/ScenarioObject/Vehicle/BoundingBox")
    assert box is not None
    dims = box.find("Dimensions")
    assert dims is not None
    box.remove(dims)
    tree.write(path)
    errors = validate_openscenario(path)
    assert len(errors) == 1
    assert "BoundingBox" in errors[0]
    assert "Dimensions" in errors[0]


def test_validation_rejects_a_file_that_is_not_xml(tmp_path: Path) -> None:
    path = tmp_path / "scenario.xosc"
    path.write_text("not <xml", encoding="utf-8")
    with pytest.raises(ConfigError, match="not an XML file"):
        validate_openscenario(path)


def test_validation_rejects_an_unsupported_version(tmp_path: Path) -> None:
    path = tmp_path / "scenario.xosc"
    path.write_text('<OpenSCENARIO><FileHeader revMajor="1" revMinor="9"/></OpenSCENARIO>')
    with pytest.raises(ConfigError, match=r"declares OpenSCENARIO 1\.9"):
        validate_openscenario(path)


def test_write_failure_leaves_previous_file_intact(
    scenario: Scenario, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "scenario.xosc"
    write_openscenario(scenario, path, map_path=MAP)
    before = path.read_bytes()

    def fail(_fd: int) -> None:
        msg = "disk full"
        raise OSError(msg)

    monkeypatch.setattr("cam2sim.core.files.os.fsync", fail)
    with pytest.raises(OSError, match="disk full"):
        write_openscenario(scenario, path, map_path="../elsewhere.xodr")
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["scenario.xosc"]


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"version_minor": 4}, r"OpenSCENARIO 1\.4 is not supported"),
        ({"max_vertex_spacing_m": 0.0}, "max_vertex_spacing_m"),
        ({"body_point": "roof"}, "body_point"),
        ({"map_path": " "}, "map_path is empty"),
    ],
)
def test_write_rejects_bad_options(
    scenario: Scenario, tmp_path: Path, options: dict[str, object], match: str
) -> None:
    kwargs: dict[str, object] = {"map_path": MAP} | options
    with pytest.raises(ConfigError, match=match):
        write_openscenario(scenario, tmp_path / "scenario.xosc", **kwargs)  # type: ignore[arg-type]
    assert not (tmp_path / "scenario.xosc").exists()


def test_write_rejects_duplicate_vehicle_names(scenario: Scenario, tmp_path: Path) -> None:
    twin = scenario.parked[0].model_copy(update={"id": "hero"})
    clash = scenario.model_copy(update={"parked": (*scenario.parked, twin)})
    with pytest.raises(ConfigError, match="'hero'"):
        write_openscenario(clash, tmp_path / "scenario.xosc", map_path=MAP)


def test_write_without_scenariogeneration_names_the_extra(
    scenario: Scenario, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "scenariogeneration.xosc", None)
    with pytest.raises(BackendUnavailableError, match=r"pip install cam2sim\[scenario\]"):
        write_openscenario(scenario, tmp_path / "scenario.xosc", map_path=MAP)
