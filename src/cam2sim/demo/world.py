"""The demo worlds: residential streets near Munich (recorded by :mod:`cam2sim.demo.recording`).

A world lives in a local metric frame whose origin sits at :data:`ORIGIN_UTM` in UTM 32N
(x east, y north, z up; the frame's axes are the UTM grid's). Its :class:`DemoStreet` says the
route (straights and arcs from the origin, heading east; :class:`~cam2sim.demo.route.
PiecewiseRoute`), the cross-section (a driving lane, a parking lane and a sidewalk each way; the
route is the centre of the right driving lane; marked or not), the parked cars (on both sides
along the straights) and the recorded driver. Buildings line both sidewalks, leaving the
insides of the bends open. The built-in streets (:data:`STREETS`): :data:`L_STREET` (the
default: 183 m, one bend) and :data:`PAPER_STREET` (the paper's street: 450 m, three bends,
unmarked, cars narrowing the lane, 20 km/h).

:func:`cam2sim.demo.recording.build_demo_recording` writes, into one folder:

* ``demo.osm``: the street as a ``highway=residential`` way (``lanes=2``, ``width``) and the
  buildings as closed ``building=yes`` ways with ``building:levels``, in WGS84;
* ``recording/bag``: a ROS2 MCAP bag of a drive along the route at the street's speed, weaving
  gently about the lane centre (:meth:`DemoStreet.weave`, as a human driver does), with a
  JPEG camera (:data:`~cam2sim.demo.rig.CAMERA_SIZE` at 20 Hz, rendered by the raster
  renderer and made to look photographic by :func:`photographic_look`), its camera info,
  odometry in UTM 32N with the reference car's axes (x to the left, y forward) at 50 Hz, a
  LiDAR ray-cast from the scene at 5 Hz and the steering signal at 50 Hz (curvature /
  :data:`~cam2sim.demo.rig.CURVATURE_PER_STEERING`); the sensors are
  :mod:`cam2sim.demo.rig`'s;
* ``config.yaml``: the cam2sim config of that recording (topics, intrinsics, mounts, pose CRS
  and axis convention);
* ``truth.json``: the parked cars (ground-truth boxes) and buildings in the local frame;
* ``truth_world.json``: the same world as a :class:`~cam2sim.render.truth.TruthWorld` (street,
  cars, buildings, the photographic look and its seed), which ``cam2sim demo`` copies to
  ``WS/truth/world.json`` for the ``truth`` camera (closed-loop drives in the ground truth).

The camera's sensor noise is drawn per frame from the seed and the camera pose
(:func:`~cam2sim.render.look.frame_noise_rng`), so the truth camera renders a recorded pose as
the recording has it (before JPEG).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Final

import numpy as np

from cam2sim.core.config import (
    AxisConvention,
    CameraConfig,
    Config,
    IntrinsicsConfig,
    LidarConfig,
    MountConfig,
    PoseConfig,
    RecordingConfig,
    SignalConfig,
    TopicsConfig,
)
from cam2sim.core.errors import ConfigError
from cam2sim.demo.rig import (
    CAMERA_MOUNT,
    LIDAR_MOUNT,
    TOPICS,
    body_pose,
    demo_camera,
)
from cam2sim.demo.route import PiecewiseRoute
from cam2sim.render.look import photographic_look
from cam2sim.render.truth import TruthBuilding, TruthCar, TruthLook, TruthWorld
from cam2sim.scenario.synthetic import lane_section_xml

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    import numpy.typing as npt

    from cam2sim.core.scene import StreetScene
    from cam2sim.render.raster import RasterScene

__all__ = [
    "CRS",
    "L_STREET",
    "ORIGIN_UTM",
    "PAPER_STREET",
    "STREETS",
    "DemoBuilding",
    "DemoStreet",
    "DemoWorld",
    "ParkedCar",
    "demo_street",
    "demo_world",
    "footprint_ring",
    "parked_cars",
    "photographic_look",
    "street_xodr",
]

CRS: Final = "EPSG:32632"
"""UTM 32N: the odometry's CRS."""
ORIGIN_UTM: Final = (691_000.0, 5_336_000.0)
"""Easting, northing of the local frame's origin (Munich)."""
# Optical camera axes (x right, y down, z forward) in the body frame (x forward, y left, z up).
_R_BODY_OPTICAL: Final = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
_WEAVE_RAMP_M: Final = 10.0


@dataclass(frozen=True)
class DemoStreet:
    """A demo street: its route, its cross-section, its parked cars and its driver.

    The street has a driving lane, a parking lane and a sidewalk each way; the route is the
    centre of the right driving lane. Cars park on the straights (not in the bends).

    Attributes:
        name: What ``cam2sim demo --world`` calls it.
        title: One line for people.
        route: The driven route (local frame, starting at the origin heading east).
        speed_mps: The recorded car's speed.
        lane_m: Driving lane width.
        parking_m: Parking lane width.
        sidewalk_m: Sidewalk width.
        lane_markings: Whether the roadway is marked between its driving lanes.
        car_intrusion_m: How far parked cars stand from their parking lane's centre towards the
            driving lane (so that they narrow it when their half width exceeds the rest).
        park_share: Share of the parking places taken.
        weave_m: Amplitude of the recorded driver's weave about the lane centre.
        weave_period_m: Its wavelength.
        lead_m: Street before the route's start and after its end.
        no_parking: ``(side, start, end)`` station ranges where no car parks on ``side``
            (``"left"`` or ``"right"`` of the route): signed-off kerbs and junctions.
        crs: The CRS whose grid the local frame is (odometry is written in it).
        origin: The local frame's origin in ``crs``.
    """

    name: str
    title: str
    route: PiecewiseRoute
    speed_mps: float = 8.0
    lane_m: float = 3.5
    parking_m: float = 2.5
    sidewalk_m: float = 2.0
    lane_markings: bool = True
    car_intrusion_m: float = 0.0
    park_share: float = 0.65
    weave_m: float = 0.35
    weave_period_m: float = 40.0
    lead_m: float = 30.0
    no_parking: tuple[tuple[str, float, float], ...] = ()
    crs: str = CRS
    origin: tuple[float, float] = ORIGIN_UTM

    @property
    def length_m(self) -> float:
        """Length of the driven route."""
        return self.route.length_m

    @property
    def duration_s(self) -> float:
        """Length of the recorded drive."""
        return self.length_m / self.speed_mps

    def route_points(
        self, s: npt.ArrayLike, lateral: float | npt.NDArray[np.float64] = 0.0
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Positions ``(N, 2)`` and headings ``(N,)`` at stations ``s``, ``lateral`` to the left.

        Stations before 0 or past :attr:`length_m` continue straight.
        """
        return self.route.points(s, lateral)

    def route_curvature(self, s: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Curvature (1/m, positive left) of the route at stations ``s``."""
        return self.route.curvature(s)

    def weave(self, s: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """The driver's lateral offset (m, left) from the lane centre at stations ``s``.

        A sine of :attr:`weave_m` and :attr:`weave_period_m`, eased in from 10 m to 30 m (so the
        drive starts on the lane centre, straight): a human driver never holds the centre
        exactly.
        """
        st = np.asarray(s, dtype=np.float64)
        ramp = np.clip((st - _WEAVE_RAMP_M) / (2.0 * _WEAVE_RAMP_M), 0.0, 1.0)
        out: npt.NDArray[np.float64] = (
            self.weave_m
            * np.sin(2.0 * math.pi * st / self.weave_period_m)
            * ramp
            * ramp
            * (3.0 - 2.0 * ramp)
        )
        return out

    def drive_points(
        self, s: npt.ArrayLike
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Positions ``(N, 2)`` and headings ``(N,)`` of the driven path (route plus weave)."""
        st = np.atleast_1d(np.asarray(s, dtype=np.float64))
        xy, _ = self.route_points(st, self.weave(st))
        ds = 0.01
        a, _ = self.route_points(st - ds, self.weave(st - ds))
        b, _ = self.route_points(st + ds, self.weave(st + ds))
        heading: npt.NDArray[np.float64] = np.arctan2(b[:, 1] - a[:, 1], b[:, 0] - a[:, 0])
        return xy, heading

    def drive_curvature(self, s: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Curvature (1/m, positive left) of the driven path at stations ``s``."""
        st = np.atleast_1d(np.asarray(s, dtype=np.float64))
        ds = 0.05
        a, ha = self.drive_points(st - ds)
        b, hb = self.drive_points(st + ds)
        turn = np.remainder(hb - ha + math.pi, 2.0 * math.pi) - math.pi
        out: npt.NDArray[np.float64] = turn / np.maximum(np.hypot(*(b - a).T), 1e-9)
        return out

    def camera_pose(self, station: float) -> npt.NDArray[np.float64]:
        """``T_world_cam`` (optical axes) of the demo camera with the car at ``station``."""
        xy, heading = self.drive_points([station])
        body = body_pose(xy[0], float(heading[0]))
        mount = np.eye(4)
        mount[:3, :3] = _R_BODY_OPTICAL
        mount[:3, 3] = CAMERA_MOUNT
        out: npt.NDArray[np.float64] = body @ mount
        return out


L_STREET: Final = DemoStreet(
    name="l-street",
    title="an L-shaped residential street: 183 m, one left bend of 40 m radius, 8 m/s",
    route=PiecewiseRoute(((60.0, 0.0), (40.0 * math.pi / 2.0, 1.0 / 40.0), (60.0, 0.0))),
)
PAPER_STREET: Final = DemoStreet(
    name="paper",
    title=(
        "the paper's street: 450 m, three bends, an unmarked two-way roadway, parked cars "
        "narrowing the lane, sidewalks, 20 km/h"
    ),
    route=PiecewiseRoute(
        (
            (80.0, 0.0),
            (30.0 * math.pi / 2.0, 1.0 / 30.0),
            (90.0, 0.0),
            (40.0 * math.pi / 3.0, -1.0 / 40.0),
            (70.0, 0.0),
            (35.0 * 5.0 * math.pi / 12.0, 1.0 / 35.0),
            (75.0, 0.0),
        )
    ),
    speed_mps=20.0 / 3.6,
    parking_m=2.0,
    lane_markings=False,
    car_intrusion_m=0.2,
    park_share=0.6,
    weave_m=0.2,
)
STREETS: Final = {s.name: s for s in (L_STREET, PAPER_STREET)}
"""The built-in demo streets by name."""


@dataclass(frozen=True)
class ParkedCar:
    """A parked car's ground-truth box in the local frame (bottom centre, metres, radians)."""

    x: float
    y: float
    yaw: float
    length: float
    width: float
    height: float
    side: str


@dataclass(frozen=True)
class DemoBuilding:
    """A building: a rectangular footprint (local frame, counter-clockwise) and its levels."""

    xy: tuple[tuple[float, float], ...]
    levels: int

    @property
    def height_m(self) -> float:
        """Height at 3 m a level."""
        return 3.0 * self.levels


# -- the world -------------------------------------------------------------------------------


@dataclass(frozen=True)
class DemoWorld:
    """The street, the parked cars and the buildings (local frame)."""

    street: DemoStreet
    cars: tuple[ParkedCar, ...]
    buildings: tuple[DemoBuilding, ...]
    osm: str | None = None
    """The OSM XML the map stage reads; None: :meth:`osm_xml` writes the street and buildings."""

    def xodr(self) -> str:
        """The street as OpenDRIVE 1.4 text (reference line between the driving lanes)."""
        return street_xodr(self.street)

    def osm_xml(self) -> str:
        """The street and buildings as OSM XML (WGS84 nodes), or :attr:`osm` when set."""
        if self.osm is not None:
            return self.osm
        from pyproj import Transformer  # noqa: PLC0415

        st = self.street
        to_wgs84 = Transformer.from_crs(st.crs, "EPSG:4326", always_xy=True)
        stations = np.arange(-st.lead_m, st.length_m + st.lead_m + 1e-6, 5.0)
        road, _ = st.route_points(stations, st.lane_m / 2.0)
        rings = [np.asarray(b.xy, dtype=np.float64) for b in self.buildings]
        local = np.concatenate([road, *rings])
        lon, lat = to_wgs84.transform(local[:, 0] + st.origin[0], local[:, 1] + st.origin[1])
        lon, lat = np.asarray(lon), np.asarray(lat)
        margin = 5e-4
        lines = [
            '<?xml version="1.0" encoding="UTF-8"?>',
            '<osm version="0.6" generator="cam2sim demo">',
            (
                f'  <bounds minlat="{lat.min() - margin:.8f}" minlon="{lon.min() - margin:.8f}" '
                f'maxlat="{lat.max() + margin:.8f}" maxlon="{lon.max() + margin:.8f}"/>'
            ),
        ]
        lines += [
            f'  <node id="{k + 1}" lat="{la:.8f}" lon="{lo:.8f}" version="1"/>'
            for k, (la, lo) in enumerate(zip(lat, lon, strict=True))
        ]
        tags = {
            "highway": "residential",
            "lanes": "2",
            "width": f"{2 * st.lane_m:g}",
            "name": "Demostraße",
            "parking:lane:both": "parallel",
            "surface": "asphalt",
        }
        lines += ['  <way id="1000" version="1">']
        lines += [f'    <nd ref="{k + 1}"/>' for k in range(len(road))]
        lines += [f'    <tag k="{k}" v="{v}"/>' for k, v in tags.items()]
        lines += ["  </way>"]
        first = len(road) + 1
        for j, (b, ring) in enumerate(zip(self.buildings, rings, strict=True)):
            refs = [*range(first, first + len(ring)), first]
            first += len(ring)
            lines += [f'  <way id="{2000 + j}" version="1">']
            lines += [f'    <nd ref="{r}"/>' for r in refs]
            lines += [
                '    <tag k="building" v="yes"/>',
                f'    <tag k="building:levels" v="{b.levels}"/>',
                "  </way>",
            ]
        lines += ["</osm>", ""]
        return "\n".join(lines)

    def lidar_scene(self) -> StreetScene:
        """The scene the LiDAR scans: flat ground, car boxes, building boxes."""
        return self.truth_world().lidar_scene()

    def truth_world(self, *, seed: int = 0, notes: Sequence[str] = ()) -> TruthWorld:
        """The world as the workspace's ground truth (the truth camera's world, UTM 32N).

        ``notes`` say how the world was made (they go into the report with its title).
        """
        return TruthWorld(
            crs=self.street.crs,
            origin=self.street.origin,
            xodr=self.xodr(),
            cars=tuple(TruthCar(**asdict(c)) for c in self.cars),
            buildings=tuple(TruthBuilding(xy=b.xy, height_m=b.height_m) for b in self.buildings),
            look=TruthLook(kind="photographic", seed=seed),
            lane_markings=self.street.lane_markings,
            title=self.street.title,
            notes=tuple(notes),
        )

    def raster_scene(self) -> RasterScene:
        """The scene the camera renders (the raster renderer's meshes)."""
        return self.truth_world().raster_scene()


def street_xodr(street: DemoStreet, name: str = "Demostraße") -> str:
    """``street`` as OpenDRIVE 1.4 text, one road named ``name``.

    The reference line runs between the driving lanes (half a lane left of the route), from
    ``lead_m`` before the route to ``lead_m`` past it.
    """
    geometry, total = street.route.offset_plan_view(street.lane_m / 2.0, street.lead_m)
    lanes = lane_section_xml(street.lane_m, street.parking_m, street.sidewalk_m)
    return f"""<?xml version="1.0"?>
<OpenDRIVE><header revMajor="1" revMinor="4"/>
  <road name="{name}" length="{total!r}" id="1" junction="-1">
    <planView>{geometry}</planView>
    <lanes><laneSection s="0">{lanes}
    </laneSection></lanes>
  </road>
</OpenDRIVE>
"""


def _straights(street: DemoStreet, margin_m: float) -> list[tuple[float, float]]:
    """``(start, end)`` stations of the street's straight stretches, ``margin_m`` from bends."""
    edges = [-street.lead_m + 3.0]
    for lo, hi in street.route.bends():
        edges += [lo - margin_m, hi + margin_m]
    edges.append(street.length_m + street.lead_m - 3.0)
    return [(lo, hi) for lo, hi in zip(edges[::2], edges[1::2], strict=True) if hi > lo]


def parked_cars(street: DemoStreet, rng: np.random.Generator) -> tuple[ParkedCar, ...]:
    """Cars parked along ``street``'s straights, both sides, at its density (``rng`` draws)."""
    half = street.lane_m / 2.0
    # Centres of the parking lanes, moved towards the roadway by the intrusion.
    right = -half - street.parking_m / 2.0 + street.car_intrusion_m
    left = half + street.lane_m + street.parking_m / 2.0 - street.car_intrusion_m
    cars: list[ParkedCar] = []
    for lateral, side in ((right, "right"), (left, "left")):
        for lo, hi in _straights(street, 8.0):
            s = lo + rng.uniform(0.0, 2.0)
            while True:
                length = rng.uniform(4.0, 4.8)
                if s + length > hi:
                    break
                centre = s + length / 2.0
                banned = any(
                    side == no_side and lo_s - length / 2.0 < centre < hi_s + length / 2.0
                    for no_side, lo_s, hi_s in street.no_parking
                )
                if rng.random() < street.park_share and not banned:
                    xy, heading = street.route_points([s + length / 2.0], lateral)
                    flip = math.pi if side == "left" and rng.random() < 0.5 else 0.0
                    cars.append(
                        ParkedCar(
                            x=float(xy[0, 0]),
                            y=float(xy[0, 1]),
                            yaw=float(heading[0] + flip + rng.normal(0.0, 0.02)),
                            length=float(length),
                            width=float(rng.uniform(1.75, 1.9)),
                            height=float(rng.uniform(1.45, 1.6)),
                            side=side,
                        )
                    )
                s += length + rng.uniform(1.0, 3.0)
    return tuple(cars)


def footprint_ring(
    centre: npt.ArrayLike, heading: float, length: float, depth: float
) -> tuple[tuple[float, float], ...]:
    """Corners of a ``length`` x ``depth`` rectangle at ``centre``, long side along ``heading``."""
    t = np.array([math.cos(heading), math.sin(heading)])
    n = np.array([-t[1], t[0]])
    c = np.asarray(centre, dtype=np.float64)[:2]
    ring = [
        c + a * length / 2.0 * t + b * depth / 2.0 * n
        for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))
    ]
    return tuple((float(p[0]), float(p[1])) for p in ring)


def _buildings(street: DemoStreet, rng: np.random.Generator) -> tuple[DemoBuilding, ...]:
    half = street.lane_m / 2.0
    kerb = street.lane_m + street.parking_m + street.sidewalk_m  # from the reference line
    length, depth, setback = 16.0, 10.0, 1.5
    out: list[DemoBuilding] = []
    stations = np.arange(-street.lead_m + 10.0, street.length_m + street.lead_m - 8.0, 21.0)
    for sign in (1.0, -1.0):
        lateral = half + sign * (kerb + setback + depth / 2.0)
        for s in stations:
            inside = [
                lo - 12.0 < s < hi + 12.0
                for lo, hi, turn in street.route.bend_turns()
                if turn * sign > 0
            ]
            if any(inside):
                continue  # the inside of a bend stays open
            c, h = street.route_points([s], lateral)
            out.append(
                DemoBuilding(
                    xy=footprint_ring(c[0], float(h[0]), length, depth),
                    levels=int(rng.integers(2, 6)),
                )
            )
    return tuple(out)


def demo_world(seed: int = 0, street: DemoStreet = L_STREET) -> DemoWorld:
    """The demo world on ``street``; ``seed`` places the parked cars and picks building heights."""
    rng = np.random.default_rng(seed)
    return DemoWorld(
        street=street, cars=parked_cars(street, rng), buildings=_buildings(street, rng)
    )


def demo_config(bag: Path, crs: str = CRS) -> Config:
    """The cam2sim config of the demo bag (odometry in ``crs``)."""
    cam = demo_camera()
    return Config(
        recording=RecordingConfig(bags=[str(bag.absolute())]),
        topics=TopicsConfig(
            camera=TOPICS["camera"],
            pose=TOPICS["pose"],
            lidar=TOPICS["lidar"],
            signals={"steering": SignalConfig(topic=TOPICS["steering"])},
        ),
        pose=PoseConfig(crs=crs, axis_convention=AxisConvention.X_LEFT),
        camera=CameraConfig(
            intrinsics=IntrinsicsConfig(
                fx=cam.fx, fy=cam.fy, cx=cam.cx, cy=cam.cy, width=cam.width, height=cam.height
            ),
            mount=MountConfig(xyz=CAMERA_MOUNT),
        ),
        lidar=LidarConfig(mount=MountConfig(xyz=LIDAR_MOUNT)),
    )


def demo_street(name: str) -> DemoStreet:
    """The built-in street called ``name``.

    Raises:
        ConfigError: No such street (the message lists them).
    """
    if name not in STREETS:
        msg = f"no demo world {name!r}; choose one of {', '.join(sorted(STREETS))}"
        raise ConfigError(msg)
    return STREETS[name]
