"""``WS/scenario/scenario.xosc``: the scenario as an OpenSCENARIO 1.x file, and its validation.

The file references the OpenDRIVE map (``RoadNetwork/LogicFile``), places the hero at its start
pose with its recorded start speed, replays the recorded route with a ``FollowTrajectoryAction``
(a timed polyline), and spawns every parked vehicle as a stationary ``Vehicle``. It uses only
standard constructs, so esmini and CARLA's ScenarioRunner can read it.

Frames. Positions are ``WorldPosition`` in the world frame, which is the OpenDRIVE map's
inertial frame (x east, y north, z up; ``h`` in radians CCW from east), so world coordinates go
in unchanged.

Reference point. OpenSCENARIO places an entity by its reference point; for a vehicle that is the
centre of the rear axle projected onto the ground, and the ``BoundingBox/Center`` and the axles'
``positionX`` are given relative to it (esmini's catalogs do the same). With the default
``body_point="rear_axle"`` every position in the file is that point: the trajectory's
``rear_axle`` column and, for the hero start and parked vehicles (given at their centre), the
centre moved along the heading by the rear axle's offset in the vehicle frame
(``VehicleGeometry.rear_axle_xyz``). The bounding box centre then sits at
``(-rear_axle_x, -rear_axle_y, height / 2)``. Another ``body_point`` moves the reference point
(e.g. ``"center"`` for tools that place vehicles by their centre, such as CARLA actors); the
boxes and axles move with it, so the file stays self-consistent. A body point's height above the
ground (its vehicle-frame z) is removed from the trajectory's z: the reference point lies on the
ground. Parked vehicles have no measured axles: their body point and wheelbase are the hero's,
scaled by their length (x) and width (y).
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import functools
import importlib
import importlib.metadata
import importlib.resources
import logging
import math
import typing
import xml.etree.ElementTree as ET
from collections import Counter
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from cam2sim import __version__
from cam2sim.core.backends import require_module
from cam2sim.core.errors import BackendUnavailableError, ConfigError
from cam2sim.core.files import write_bytes_atomic
from cam2sim.scenario.model import BodyPoint

if TYPE_CHECKING:
    from collections.abc import Mapping
    from types import ModuleType

    import xmlschema

    from cam2sim.scenario.model import Scenario, ScenarioVehicle, VehicleGeometry

__all__ = ["SCHEMA_FILES", "validate_openscenario", "write_openscenario"]

logger = logging.getLogger(__name__)

# scenariogeneration ships no type information: its objects are Any to mypy.
_Xosc = Any

SCHEMA_FILES: Mapping[int, str] = MappingProxyType(
    {
        0: "OpenSCENARIO_1_0.xsd",
        1: "OpenSCENARIO_1_1.xsd",
        2: "OpenSCENARIO_1_2.xsd",
        3: "OpenSCENARIO_1_3_1.xsd",
    }
)
"""The official XSD per OpenSCENARIO 1.x minor version (bundled with scenariogeneration)."""

_INSTALL_HINT = "install it with `pip install cam2sim[scenario]`"
_HERO = "hero"
_BODY_POINTS: tuple[str, ...] = typing.get_args(BodyPoint)

# Nominal values for what a recording does not measure (documented, not fitted).
_WHEEL_DIAMETER_M = 0.7
_TRACK_WIDTH_FRACTION = 0.85  # track width / overall width
_MAX_STEERING_RAD = 0.6
_MAX_SPEED_MPS = 70.0
_MAX_ACCELERATION_MPS2 = 10.0
_MAX_DECELERATION_MPS2 = 10.0


@dataclasses.dataclass(frozen=True)
class _Body:
    """One vehicle's geometry in its OpenSCENARIO entity frame.

    The origin is the entity reference point on the ground; x forward, y left, z up, metres.
    """

    size: tuple[float, float, float]  # length, width, height
    center: tuple[float, float, float]  # bounding-box centre
    rear_axle_x: float
    front_axle_x: float


def write_openscenario(
    scenario: Scenario,
    path: Path,
    *,
    map_path: str,
    body_point: BodyPoint = "rear_axle",
    version_minor: int = 2,
    name: str = "cam2sim",
    max_vertex_spacing_m: float = 1.0,
    stop_margin_s: float = 1.0,
) -> None:
    """Write ``scenario`` as an OpenSCENARIO 1.x file, atomically.

    Args:
        scenario: The scenario (world frame = the OpenDRIVE map's inertial frame).
        path: Destination ``.xosc`` file. Its folder is created when missing.
        map_path: The OpenDRIVE map as written into ``RoadNetwork/LogicFile``, relative to the
            ``.xosc`` file (e.g. ``../map/map.xodr``).
        body_point: The vehicle point every position refers to (see the module docstring);
            ``"rear_axle"`` is OpenSCENARIO's own reference point.
        version_minor: OpenSCENARIO minor version, 0 to 3 (1.0 to 1.3).
        name: The scenario's description in the file header.
        max_vertex_spacing_m: Largest distance between consecutive route vertices; recorded
            samples closer than that are dropped (first and last kept). Two recorded samples
            farther apart stay consecutive vertices.
        stop_margin_s: The scenario stops this long after the last recorded sample.

    Raises:
        ConfigError: An option is out of range, the trajectory times do not increase, or two
            vehicles share a name.
        BackendUnavailableError: scenariogeneration is not installed.
    """
    _check_options(body_point, version_minor, max_vertex_spacing_m, stop_margin_s, map_path)
    _check_scenario(scenario)
    xosc = require_module("scenariogeneration.xosc", _INSTALL_HINT, "OpenSCENARIO support")
    previous = (xosc.VersionBase.version_major, xosc.VersionBase.version_minor)
    # scenariogeneration keeps the target version in a class attribute; restore it afterwards.
    xosc.VersionBase().setVersion(major=1, minor=version_minor)
    try:
        element, n_vertices = _document(
            xosc,
            scenario,
            map_path=map_path,
            body_point=body_point,
            version_minor=version_minor,
            name=name,
            max_vertex_spacing_m=max_vertex_spacing_m,
            stop_margin_s=stop_margin_s,
        )
    finally:
        xosc.VersionBase().setVersion(major=previous[0], minor=previous[1])
    write_bytes_atomic(Path(path), _to_bytes(element))
    logger.info(
        "wrote %s: OpenSCENARIO 1.%d, hero route of %d vertices from %d samples, "
        "%d parked vehicles",
        path,
        version_minor,
        n_vertices,
        len(scenario.trajectory.t),
        len(scenario.parked),
    )


def validate_openscenario(path: Path) -> list[str]:
    """Validate an OpenSCENARIO file against the official XSD of its version.

    The version is the file's ``FileHeader`` ``revMajor``/``revMinor``; the XSDs are those that
    scenariogeneration bundles.

    Args:
        path: The ``.xosc`` file.

    Returns:
        One message per schema violation, ``"<element path>: <reason>"``; empty when valid.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ConfigError: The file is not XML, not OpenSCENARIO, or of an unsupported version.
        BackendUnavailableError: xmlschema or scenariogeneration is not installed.
    """
    path = Path(path)
    if not path.is_file():
        msg = f"{str(path)!r} does not exist; write it first (cam2sim scenario)"
        raise FileNotFoundError(msg)
    require_module("xmlschema", _INSTALL_HINT, "OpenSCENARIO support")
    import xmlschema  # noqa: PLC0415 - optional (scenario extra); _require said how to install

    try:
        resource = xmlschema.XMLResource(str(path), defuse="always")
    except ET.ParseError as err:  # xmlschema's parse errors subclass it
        msg = f"{path} is not an XML file ({err}); re-write it with cam2sim scenario"
        raise ConfigError(msg) from None
    minor = _version_minor(resource.root, path)
    schema = _schema(minor)
    return [f"{err.path}: {err.reason}" for err in schema.iter_errors(resource)]


def _check_options(
    body_point: str,
    version_minor: int,
    max_vertex_spacing_m: float,
    stop_margin_s: float,
    map_path: str,
) -> None:
    if body_point not in _BODY_POINTS:
        msg = f"body_point must be one of {_BODY_POINTS}, got {body_point!r}"
        raise ConfigError(msg)
    if version_minor not in SCHEMA_FILES:
        msg = (
            f"OpenSCENARIO 1.{version_minor} is not supported; choose a minor version in "
            f"{sorted(SCHEMA_FILES)}"
        )
        raise ConfigError(msg)
    if not (math.isfinite(max_vertex_spacing_m) and max_vertex_spacing_m > 0):
        msg = f"max_vertex_spacing_m must be positive metres, got {max_vertex_spacing_m!r}"
        raise ConfigError(msg)
    if not (math.isfinite(stop_margin_s) and stop_margin_s >= 0):
        msg = f"stop_margin_s must be a non-negative number of seconds, got {stop_margin_s!r}"
        raise ConfigError(msg)
    if not map_path.strip():
        msg = "map_path is empty; give the OpenDRIVE map relative to the .xosc file"
        raise ConfigError(msg)


def _check_scenario(scenario: Scenario) -> None:
    t = np.asarray(scenario.trajectory.t, dtype=np.float64)
    if not (np.all(np.isfinite(t)) and np.all(np.diff(t) > 0)):
        msg = (
            "scenario trajectory times must be finite and strictly increasing for an "
            "OpenSCENARIO polyline; re-run `cam2sim scenario` to rebuild scenario.json"
        )
        raise ConfigError(msg)
    counts = Counter(car.id for car in scenario.parked)
    bad = sorted(n for n, k in counts.items() if k > 1 or n in {_HERO, ""})
    if bad:
        msg = (
            f"parked vehicle ids must be unique, non-empty and not {_HERO!r}; offending ids: "
            f"{bad}; fix them in scenario.json"
        )
        raise ConfigError(msg)


def _document(
    xosc: ModuleType,
    scenario: Scenario,
    *,
    map_path: str,
    body_point: BodyPoint,
    version_minor: int,
    name: str,
    max_vertex_spacing_m: float,
    stop_margin_s: float,
) -> tuple[ET.Element, int]:
    """Build the OpenSCENARIO document; return its root element and the route's vertex count."""
    vehicle = scenario.vehicle
    offset = _body_point_xyz(vehicle, body_point)
    entities = xosc.Entities()
    init = xosc.Init()

    hero_body = _body(vehicle, offset)
    entities.add_scenario_object(_HERO, _vehicle(xosc, _HERO, xosc.VehicleCategory.car, hero_body))
    start = scenario.hero_start
    init.add_init_action(
        _HERO, xosc.TeleportAction(_position(xosc, _shift(start.position, start.heading, offset)))
    )
    init.add_init_action(
        _HERO,
        xosc.AbsoluteSpeedAction(
            float(start.speed),
            xosc.TransitionDynamics(xosc.DynamicsShapes.step, xosc.DynamicsDimension.time, 0.0),
        ),
    )

    for car in scenario.parked:
        scaled = _scaled_offset(car, vehicle, offset)
        category = xosc.VehicleCategory.van if car.size_class == "van" else xosc.VehicleCategory.car
        entities.add_scenario_object(
            car.id, _vehicle(xosc, car.id, category, _parked_body(car, vehicle, scaled))
        )
        init.add_init_action(
            car.id, xosc.TeleportAction(_position(xosc, _shift(car.position, car.heading, scaled)))
        )

    follow, n_vertices = _follow_route(xosc, scenario, body_point, offset, max_vertex_spacing_m)
    end_s = float(scenario.trajectory.t[-1]) + stop_margin_s
    storyboard = xosc.StoryBoard(init, _time_trigger(xosc, "scenario_end", end_s, stop=True))
    storyboard.add_story(_hero_story(xosc, follow))

    document = xosc.Scenario(
        name,
        f"cam2sim {__version__}",
        xosc.ParameterDeclarations(),
        entities,
        storyboard,
        xosc.RoadNetwork(roadfile=map_path),
        xosc.Catalog(),
        osc_minor_version=version_minor,
        creation_date=_recorded_at(scenario),
    )
    element: ET.Element = document.get_element()
    return element, n_vertices


def _hero_story(xosc: ModuleType, follow: _Xosc) -> _Xosc:
    """One Story/Act/ManeuverGroup/Maneuver/Event running ``follow`` on the hero from t = 0."""
    event = xosc.Event("follow_recorded_route", xosc.Priority.parallel)
    event.add_action("follow_recorded_route", follow)
    event.add_trigger(_time_trigger(xosc, "route_start", 0.0, stop=False))
    maneuver = xosc.Maneuver("recorded_drive")
    maneuver.add_event(event)
    group = xosc.ManeuverGroup("hero_drive")
    group.add_actor(_HERO)
    group.add_maneuver(maneuver)
    act = xosc.Act("replay", _time_trigger(xosc, "replay_start", 0.0, stop=False))
    act.add_maneuver_group(group)
    story = xosc.Story("recorded_drive", xosc.ParameterDeclarations())
    story.add_act(act)
    return story


def _follow_route(
    xosc: ModuleType,
    scenario: Scenario,
    body_point: BodyPoint,
    offset: tuple[float, float, float],
    max_vertex_spacing_m: float,
) -> tuple[_Xosc, int]:
    """The hero's FollowTrajectoryAction: a timed polyline of the recorded route."""
    traj = scenario.trajectory
    xyz = np.asarray(traj.points(body_point), dtype=np.float64)
    xyz[:, 2] -= offset[2]  # the reference point lies on the ground
    keep = _downsample(xyz, max_vertex_spacing_m)
    times = np.asarray(traj.t, dtype=np.float64)[keep].tolist()
    heads = np.asarray(traj.heading, dtype=np.float64)[keep].tolist()
    positions = [
        xosc.WorldPosition(x, y, z, h)
        for (x, y, z), h in zip(xyz[keep].tolist(), heads, strict=True)
    ]
    trajectory = xosc.Trajectory("recorded_route", False)  # noqa: FBT003 - library's positional flag
    trajectory.add_shape(xosc.Polyline(times, positions))
    action = xosc.FollowTrajectoryAction(
        trajectory, xosc.FollowingMode.position, xosc.ReferenceContext.absolute, 1.0, 0.0
    )
    return action, len(positions)


def _downsample(xyz: npt.NDArray[np.float64], max_spacing_m: float) -> npt.NDArray[np.intp]:
    """Indices of the samples to keep as route vertices.

    Greedy along the arc length: from each kept sample, keep the farthest sample within
    ``max_spacing_m`` of arc length (at least the next one). The first and last samples are
    kept; chord ≤ arc length, so consecutive kept points are at most ``max_spacing_m`` apart
    unless two recorded samples already are. One loop step per kept vertex.

    Args:
        xyz: ``(N, 3)`` float64, metres, world frame; ``N >= 2``.
        max_spacing_m: Largest arc length between kept samples.

    Returns:
        ``(M,)`` increasing indices, ``M >= 2``.
    """
    step = np.linalg.norm(np.diff(xyz, axis=0), axis=1)
    arc = np.concatenate(([0.0], np.cumsum(step)))
    last = len(arc) - 1
    keep = [0]
    while keep[-1] < last:
        i = keep[-1]
        j = int(np.searchsorted(arc, arc[i] + max_spacing_m, side="right")) - 1
        keep.append(max(j, i + 1))
    return np.asarray(keep, dtype=np.intp)


def _body_point_xyz(vehicle: VehicleGeometry, body_point: BodyPoint) -> tuple[float, float, float]:
    """The body point in the vehicle frame (origin: footprint centre on the ground)."""
    if body_point == "rear_axle":
        return vehicle.rear_axle_xyz
    if body_point == "reference":
        return vehicle.reference_xyz
    return (0.0, 0.0, 0.0)


def _body(vehicle: VehicleGeometry, offset: tuple[float, float, float]) -> _Body:
    """The hero's geometry relative to its reference point ``offset`` (vehicle frame)."""
    rear_x = vehicle.rear_axle_xyz[0] - offset[0]
    return _Body(
        size=(vehicle.length_m, vehicle.width_m, vehicle.height_m),
        center=(0.0 - offset[0], 0.0 - offset[1], vehicle.height_m / 2),
        rear_axle_x=rear_x,
        front_axle_x=rear_x + vehicle.wheelbase_m,
    )


def _scaled_offset(
    car: ScenarioVehicle, vehicle: VehicleGeometry, offset: tuple[float, float, float]
) -> tuple[float, float, float]:
    """The hero's body point ``offset`` scaled to a parked vehicle's length and width."""
    return (
        offset[0] * car.size[0] / vehicle.length_m,
        offset[1] * car.size[1] / vehicle.width_m,
        0.0,
    )


def _parked_body(
    car: ScenarioVehicle, vehicle: VehicleGeometry, offset: tuple[float, float, float]
) -> _Body:
    """A parked vehicle's geometry: its size, with the hero's axle layout scaled by length."""
    length, _, height = car.size
    scale = length / vehicle.length_m
    rear_x = vehicle.rear_axle_xyz[0] * scale - offset[0]
    return _Body(
        size=(float(car.size[0]), float(car.size[1]), float(height)),
        center=(0.0 - offset[0], 0.0 - offset[1], height / 2),
        rear_axle_x=rear_x,
        front_axle_x=rear_x + vehicle.wheelbase_m * scale,
    )


def _vehicle(xosc: ModuleType, name: str, category: _Xosc, body: _Body) -> _Xosc:
    length, width, height = body.size
    box = xosc.BoundingBox(width, length, height, *body.center)
    track = _TRACK_WIDTH_FRACTION * width
    radius = _WHEEL_DIAMETER_M / 2
    front = xosc.Axle(_MAX_STEERING_RAD, _WHEEL_DIAMETER_M, track, body.front_axle_x, radius)
    rear = xosc.Axle(0.0, _WHEEL_DIAMETER_M, track, body.rear_axle_x, radius)
    return xosc.Vehicle(
        name,
        category,
        box,
        front,
        rear,
        _MAX_SPEED_MPS,
        _MAX_ACCELERATION_MPS2,
        _MAX_DECELERATION_MPS2,
    )


def _shift(
    center: tuple[float, float, float], heading: float, offset: tuple[float, float, float]
) -> tuple[float, float, float, float]:
    """Move a ground centre by a vehicle-frame ``offset`` (x, y) along ``heading``.

    Returns:
        ``(x, y, z, heading)`` of the reference point, world frame.
    """
    c, s = math.cos(heading), math.sin(heading)
    dx, dy = offset[0], offset[1]
    return (center[0] + c * dx - s * dy, center[1] + s * dx + c * dy, center[2], heading)


def _position(xosc: ModuleType, pose: tuple[float, float, float, float]) -> _Xosc:
    x, y, z, h = (float(v) for v in pose)
    return xosc.WorldPosition(x, y, z, h)


def _time_trigger(xosc: ModuleType, name: str, time_s: float, *, stop: bool) -> _Xosc:
    """A trigger firing once simulation time exceeds ``time_s``."""
    condition = xosc.SimulationTimeCondition(time_s, xosc.Rule.greaterThan)
    edge = xosc.ConditionEdge.rising if stop else xosc.ConditionEdge.none
    return xosc.ValueTrigger(name, 0.0, edge, condition, "stop" if stop else "start")


def _recorded_at(scenario: Scenario) -> dt.datetime:
    """The recording time of the first sample: a reproducible header date."""
    return dt.datetime.fromtimestamp(scenario.trajectory.stamp_ns[0] / 1e9, tz=dt.UTC)


def _to_bytes(element: ET.Element) -> bytes:
    """Serialise with a declaration and 4-space indentation (indents ``element`` in place)."""
    ET.indent(element, space="    ")
    data: bytes = ET.tostring(element, encoding="utf-8", xml_declaration=True)
    return data + b"\n"


def _version_minor(root: ET.Element, path: Path) -> int:
    """The OpenSCENARIO 1.x minor version from the file header."""
    header = root.find("FileHeader")
    if root.tag != "OpenSCENARIO" or header is None:
        msg = (
            f"{path} is not an OpenSCENARIO file (root <{root.tag}>, no <FileHeader>); "
            "give a .xosc file"
        )
        raise ConfigError(msg)
    major, minor = header.get("revMajor"), header.get("revMinor")
    if major != "1" or minor is None or not minor.isdigit() or int(minor) not in SCHEMA_FILES:
        versions = ", ".join(f"1.{m}" for m in sorted(SCHEMA_FILES))
        msg = (
            f"{path} declares OpenSCENARIO {major}.{minor}; only {versions} can be validated "
            "(OpenSCENARIO 2 is a different language)"
        )
        raise ConfigError(msg)
    return int(minor)


@functools.cache
def _schema(minor: int) -> xmlschema.XMLSchema:
    """The compiled official XSD for OpenSCENARIO 1.``minor`` (cached: compiling takes ~1 s)."""
    require_module("xmlschema", _INSTALL_HINT, "OpenSCENARIO support")
    import xmlschema  # noqa: PLC0415 - optional (scenario extra); _require said how to install

    return xmlschema.XMLSchema(str(_schema_path(SCHEMA_FILES[minor])))


def _schema_path(filename: str) -> Path:
    """Find an XSD that scenariogeneration bundles.

    Inside the package (``scenariogeneration/schemas/``) if a release puts it there, else in the
    distribution's file list (0.16 installs a top-level ``schemas/`` folder).
    """
    require_module("scenariogeneration", _INSTALL_HINT, "OpenSCENARIO support")
    inside = importlib.resources.files("scenariogeneration") / "schemas" / filename
    if inside.is_file():
        return Path(str(inside))
    try:
        files = importlib.metadata.files("scenariogeneration") or []
    except importlib.metadata.PackageNotFoundError:
        files = []
    for file in files:
        if file.name == filename and file.parent.name == "schemas":
            located = Path(str(file.locate()))
            if located.is_file():
                return located
    msg = (
        f"scenariogeneration does not ship {filename}; reinstall it "
        "(`pip install --force-reinstall scenariogeneration`) or "
        f"{_INSTALL_HINT}"
    )
    raise BackendUnavailableError(msg)
