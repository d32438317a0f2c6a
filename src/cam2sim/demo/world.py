"""The demo world and its recording: an L-shaped residential street near Munich.

The world lives in a local metric frame whose origin sits at :data:`ORIGIN_UTM` in UTM 32N
(x east, y north, z up; the frame's axes are the UTM grid's). The route starts at the origin
heading east, runs :data:`STRAIGHT1_M` straight, turns left on a :data:`RADIUS_M` arc and runs
:data:`STRAIGHT2_M` north. The street around it has a driving lane, a parking lane and a
sidewalk each way (the route is the centre of the right driving lane); cars are parked on both
sides along the straights and buildings line both sidewalks.

:func:`build_demo_recording` writes, into one folder:

* ``demo.osm``: the street as a ``highway=residential`` way (``lanes=2``, ``width``) and the
  buildings as closed ``building=yes`` ways with ``building:levels``, in WGS84;
* ``recording/bag``: a ROS2 MCAP bag of a drive along the route at :data:`SPEED_MPS`, weaving
  gently about the lane centre (:func:`weave`, as a human driver does), with a
  JPEG camera (:data:`CAMERA_SIZE` at 20 Hz, rendered by the raster renderer and made to look
  photographic by :func:`photographic_look`), its camera info, odometry in UTM 32N with the
  reference car's axes (x to the left, y forward) at 50 Hz, a LiDAR ray-cast from the scene at
  5 Hz and the steering signal at 50 Hz (curvature / :data:`CURVATURE_PER_STEERING`);
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

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Final

import numpy as np

from cam2sim.core.files import atomic_folder, write_text_atomic
from cam2sim.render.look import photographic_look
from cam2sim.scenario.synthetic import lane_section_xml

if TYPE_CHECKING:
    import numpy.typing as npt

    from cam2sim.core.config import Config
    from cam2sim.core.progress import ProgressCallback
    from cam2sim.detect.synthetic import StreetScene
    from cam2sim.render.raster import RasterScene
    from cam2sim.render.truth import TruthWorld

__all__ = [
    "CAMERA_SIZE",
    "CRS",
    "CURVATURE_PER_STEERING",
    "ORIGIN_UTM",
    "SPEED_MPS",
    "TOPICS",
    "DemoBuilding",
    "DemoRecording",
    "DemoWorld",
    "ParkedCar",
    "build_demo_recording",
    "camera_matrix",
    "demo_world",
    "drive_points",
    "footprint_ring",
    "load_demo_recording",
    "photographic_look",
    "route_points",
    "weave",
]

CRS: Final = "EPSG:32632"
"""UTM 32N: the odometry's CRS."""
ORIGIN_UTM: Final = (691_000.0, 5_336_000.0)
"""Easting, northing of the local frame's origin (Munich)."""
SPEED_MPS: Final = 8.0
STRAIGHT1_M: Final = 60.0
RADIUS_M: Final = 40.0
STRAIGHT2_M: Final = 60.0
LEAD_M: Final = 30.0
WEAVE_M: Final = 0.35
"""Amplitude of the reference driver's weave about the lane centre, metres."""
WEAVE_PERIOD_M: Final = 40.0
"""Wavelength of the weave: the driver drifts and corrects every 2.5 s at 8 m/s."""
_WEAVE_RAMP_M: Final = 10.0
"""Street before the route's start and after its end."""
LANE_M: Final = 3.5
PARKING_M: Final = 2.5
SIDEWALK_M: Final = 2.0
CURVATURE_PER_STEERING: Final = 0.022
"""The steering calibration: curvature (1/m) = steering * this."""
CAMERA_SIZE: Final = (320, 200)
CAMERA_FOCAL_PX: Final = 200.0
CAMERA_MOUNT: Final = (1.6, 0.0, 1.4)
LIDAR_MOUNT: Final = (1.0, 0.0, 1.9)
CAMERA_HZ: Final = 20
ODOM_HZ: Final = 50
LIDAR_HZ: Final = 5
LIDAR_BEAMS: Final = 16
LIDAR_AZIMUTHS: Final = 720
TOPICS: Final = {
    "camera": "/camera/image_raw/compressed",
    "camera_info": "/camera/camera_info",
    "pose": "/odom",
    "lidar": "/lidar/points",
    "steering": "/vehicle/steering",
}
_MARKER: Final = "demo.json"
_TRUTH_WORLD: Final = "truth_world.json"
_VERSION: Final = 3
# Optical camera axes (x right, y down, z forward) in the body frame (x forward, y left, z up).
_R_BODY_OPTICAL: Final = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


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


@dataclass(frozen=True)
class DemoRecording:
    """What :func:`build_demo_recording` wrote.

    Attributes:
        root: The folder holding everything.
        bag: The ROS2 MCAP bag folder.
        osm: The OSM file of the street and buildings.
        config: The cam2sim config of the bag.
        truth: The parked cars (local frame; add :data:`ORIGIN_UTM` for UTM 32N).
        buildings: The buildings (local frame).
        truth_world: The :class:`~cam2sim.render.truth.TruthWorld` file of the world.
        camera_frames: Camera images in the bag.
        duration_s: Length of the drive.
    """

    root: Path
    bag: Path
    osm: Path
    config: Path
    truth: tuple[ParkedCar, ...]
    buildings: tuple[DemoBuilding, ...]
    truth_world: Path
    camera_frames: int
    duration_s: float


def _arc_m() -> float:
    return RADIUS_M * math.pi / 2.0


def route_length_m() -> float:
    """Length of the driven route."""
    return STRAIGHT1_M + _arc_m() + STRAIGHT2_M


def route_points(
    s: npt.ArrayLike, lateral: float | npt.NDArray[np.float64] = 0.0
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Positions ``(N, 2)`` and headings ``(N,)`` at route stations ``s``, ``lateral`` to the left.

    ``lateral`` is one offset or one per station.

    Stations before 0 or past :func:`route_length_m` continue the straights.
    """
    st = np.atleast_1d(np.asarray(s, dtype=np.float64))
    th = np.clip((st - STRAIGHT1_M) / RADIUS_M, 0.0, math.pi / 2.0)
    first = st <= STRAIGHT1_M
    last = st > STRAIGHT1_M + _arc_m()
    x = np.where(
        first, st, np.where(last, STRAIGHT1_M + RADIUS_M, STRAIGHT1_M + RADIUS_M * np.sin(th))
    )
    y = np.where(
        first,
        0.0,
        np.where(last, RADIUS_M + st - STRAIGHT1_M - _arc_m(), RADIUS_M - RADIUS_M * np.cos(th)),
    )
    xy = np.column_stack([x - lateral * np.sin(th), y + lateral * np.cos(th)])
    return xy, th


def route_curvature(s: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Curvature (1/m, positive left) of the route at stations ``s``."""
    st = np.asarray(s, dtype=np.float64)
    inside = (st > STRAIGHT1_M) & (st <= STRAIGHT1_M + _arc_m())
    out: npt.NDArray[np.float64] = np.where(inside, 1.0 / RADIUS_M, 0.0)
    return out


def weave(s: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """The driver's lateral offset (m, left) from the lane centre at stations ``s``.

    A sine of :data:`WEAVE_M` and :data:`WEAVE_PERIOD_M`, eased in from 10 m to 30 m (so the
    drive starts on the lane centre, straight): a human driver never holds the centre exactly,
    and the drift-and-correct is what teaches DAVE-2 to steer back towards it.
    """
    st = np.asarray(s, dtype=np.float64)
    ramp = np.clip((st - _WEAVE_RAMP_M) / (2.0 * _WEAVE_RAMP_M), 0.0, 1.0)
    out: npt.NDArray[np.float64] = (
        WEAVE_M * np.sin(2.0 * math.pi * st / WEAVE_PERIOD_M) * ramp * ramp * (3.0 - 2.0 * ramp)
    )
    return out


def drive_points(
    s: npt.ArrayLike,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Positions ``(N, 2)`` and headings ``(N,)`` of the driven path (the route plus the weave)."""
    st = np.atleast_1d(np.asarray(s, dtype=np.float64))
    xy, _ = route_points(st, weave(st))
    ds = 0.01
    a, _ = route_points(st - ds, weave(st - ds))
    b, _ = route_points(st + ds, weave(st + ds))
    heading: npt.NDArray[np.float64] = np.arctan2(b[:, 1] - a[:, 1], b[:, 0] - a[:, 0])
    return xy, heading


def drive_curvature(s: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Curvature (1/m, positive left) of the driven path at stations ``s``."""
    st = np.atleast_1d(np.asarray(s, dtype=np.float64))
    ds = 0.05
    a, ha = drive_points(st - ds)
    b, hb = drive_points(st + ds)
    turn = np.remainder(hb - ha + math.pi, 2.0 * math.pi) - math.pi
    out: npt.NDArray[np.float64] = turn / np.maximum(np.hypot(*(b - a).T), 1e-9)
    return out


def camera_matrix() -> npt.NDArray[np.float64]:
    """The demo camera's ``(3, 3)`` intrinsics."""
    w, h = CAMERA_SIZE
    return np.array(
        [[CAMERA_FOCAL_PX, 0.0, (w - 1) / 2.0], [0.0, CAMERA_FOCAL_PX, (h - 1) / 2.0], [0, 0, 1.0]]
    )


def body_pose(xy: npt.NDArray[np.float64], heading: float) -> npt.NDArray[np.float64]:
    c, s = math.cos(heading), math.sin(heading)
    pose = np.eye(4)
    pose[:2, :2] = [[c, -s], [s, c]]
    pose[:2, 3] = xy
    return pose


def camera_pose(station: float) -> npt.NDArray[np.float64]:
    """``T_world_cam`` (optical axes) of the demo camera with the car at ``station``."""
    xy, heading = drive_points([station])
    body = body_pose(xy[0], float(heading[0]))
    mount = np.eye(4)
    mount[:3, :3] = _R_BODY_OPTICAL
    mount[:3, 3] = CAMERA_MOUNT
    out: npt.NDArray[np.float64] = body @ mount
    return out


# -- the world -------------------------------------------------------------------------------
_LANES: Final = lane_section_xml(LANE_M, PARKING_M, SIDEWALK_M)


@dataclass(frozen=True)
class DemoWorld:
    """The street, the parked cars and the buildings (local frame)."""

    cars: tuple[ParkedCar, ...]
    buildings: tuple[DemoBuilding, ...]

    def xodr(self) -> str:
        """The street as OpenDRIVE 1.4 text (reference line between the driving lanes)."""
        half = LANE_M / 2.0
        r_ref = RADIUS_M - half
        a = STRAIGHT1_M + LEAD_M
        b = a + r_ref * math.pi / 2.0
        total = b + STRAIGHT2_M + LEAD_M
        geometry = (
            f'<geometry s="0" x="{-LEAD_M}" y="{half}" hdg="0" length="{a}"><line/></geometry>'
            f'<geometry s="{a}" x="{STRAIGHT1_M}" y="{half}" hdg="0" length="{b - a}">'
            f'<arc curvature="{1.0 / r_ref}"/></geometry>'
            f'<geometry s="{b}" x="{STRAIGHT1_M + r_ref}" y="{RADIUS_M}" hdg="{math.pi / 2}" '
            f'length="{total - b}"><line/></geometry>'
        )
        return f"""<?xml version="1.0"?>
<OpenDRIVE><header revMajor="1" revMinor="4"/>
  <road name="Demostraße" length="{total}" id="1" junction="-1">
    <planView>{geometry}</planView>
    <lanes><laneSection s="0">{_LANES}
    </laneSection></lanes>
  </road>
</OpenDRIVE>
"""

    def osm_xml(self) -> str:
        """The street and buildings as OSM XML (WGS84 nodes)."""
        from pyproj import Transformer  # noqa: PLC0415

        to_wgs84 = Transformer.from_crs(CRS, "EPSG:4326", always_xy=True)
        stations = np.arange(-LEAD_M, route_length_m() + LEAD_M + 1e-6, 5.0)
        road, _ = route_points(stations, LANE_M / 2.0)
        rings = [np.asarray(b.xy, dtype=np.float64) for b in self.buildings]
        local = np.concatenate([road, *rings])
        lon, lat = to_wgs84.transform(local[:, 0] + ORIGIN_UTM[0], local[:, 1] + ORIGIN_UTM[1])
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
            "width": f"{2 * LANE_M:g}",
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

    def truth_world(self, *, seed: int = 0) -> TruthWorld:
        """The world as the workspace's ground truth (the truth camera's world, UTM 32N)."""
        from cam2sim.render.truth import (  # noqa: PLC0415
            TruthBuilding,
            TruthCar,
            TruthLook,
            TruthWorld,
        )

        return TruthWorld(
            crs=CRS,
            origin=ORIGIN_UTM,
            xodr=self.xodr(),
            cars=tuple(TruthCar(**asdict(c)) for c in self.cars),
            buildings=tuple(TruthBuilding(xy=b.xy, height_m=b.height_m) for b in self.buildings),
            look=TruthLook(kind="photographic", seed=seed),
        )

    def raster_scene(self) -> RasterScene:
        """The scene the camera renders (the raster renderer's meshes)."""
        return self.truth_world().raster_scene()


def _cars(rng: np.random.Generator) -> tuple[ParkedCar, ...]:
    half = LANE_M / 2.0
    right = -(LANE_M - half) - PARKING_M / 2.0  # centre of the right parking lane
    left = half + LANE_M + PARKING_M / 2.0
    end = route_length_m() + LEAD_M
    spans = ((-LEAD_M + 3.0, STRAIGHT1_M - 8.0), (STRAIGHT1_M + _arc_m() + 8.0, end - 3.0))
    cars: list[ParkedCar] = []
    for lateral, side in ((right, "right"), (left, "left")):
        for lo, hi in spans:
            s = lo + rng.uniform(0.0, 2.0)
            while True:
                length = rng.uniform(4.0, 4.8)
                if s + length > hi:
                    break
                if rng.random() < 0.65:
                    xy, heading = route_points([s + length / 2.0], lateral)
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


def _buildings(rng: np.random.Generator) -> tuple[DemoBuilding, ...]:
    half = LANE_M / 2.0
    kerb = LANE_M + PARKING_M + SIDEWALK_M  # from the reference line
    length, depth, setback = 16.0, 10.0, 1.5
    out: list[DemoBuilding] = []
    corner = (STRAIGHT1_M - 12.0, STRAIGHT1_M + _arc_m() + 12.0)
    for sign in (1.0, -1.0):
        lateral = half + sign * (kerb + setback + depth / 2.0)
        for s in np.arange(-LEAD_M + 10.0, route_length_m() + LEAD_M - 8.0, 21.0):
            if sign > 0 and corner[0] < s < corner[1]:
                continue  # the inside of the bend stays open
            c, h = route_points([s], lateral)
            out.append(
                DemoBuilding(
                    xy=footprint_ring(c[0], float(h[0]), length, depth),
                    levels=int(rng.integers(2, 6)),
                )
            )
    return tuple(out)


def demo_world(seed: int = 0) -> DemoWorld:
    """The demo world; ``seed`` places the parked cars and picks building heights."""
    rng = np.random.default_rng(seed)
    return DemoWorld(cars=_cars(rng), buildings=_buildings(rng))


def demo_config(bag: Path) -> Config:
    """The cam2sim config of the demo bag."""
    from cam2sim.core.config import (  # noqa: PLC0415
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

    k = camera_matrix()
    width, height = CAMERA_SIZE
    return Config(
        recording=RecordingConfig(bags=[str(bag.absolute())]),
        topics=TopicsConfig(
            camera=TOPICS["camera"],
            pose=TOPICS["pose"],
            lidar=TOPICS["lidar"],
            signals={"steering": SignalConfig(topic=TOPICS["steering"])},
        ),
        pose=PoseConfig(crs=CRS, axis_convention=AxisConvention.X_LEFT),
        camera=CameraConfig(
            intrinsics=IntrinsicsConfig(
                fx=float(k[0, 0]),
                fy=float(k[1, 1]),
                cx=float(k[0, 2]),
                cy=float(k[1, 2]),
                width=width,
                height=height,
            ),
            mount=MountConfig(xyz=CAMERA_MOUNT),
        ),
        lidar=LidarConfig(mount=MountConfig(xyz=LIDAR_MOUNT)),
    )


def _paths(root: Path) -> tuple[Path, Path, Path, Path]:
    return root / "recording" / "bag", root / "demo.osm", root / "config.yaml", root / "truth.json"


def load_demo_recording(out_dir: Path) -> DemoRecording | None:
    """The recording already built in ``out_dir``, or None when there is none (or a partial one)."""
    root = Path(out_dir)
    marker = root / _MARKER
    bag, osm, config, truth = _paths(root)
    truth_world = root / _TRUTH_WORLD
    files = (marker, osm, config, truth_world)
    if not (bag.is_dir() and all(f.is_file() for f in files)):
        return None
    try:
        meta = json.loads(marker.read_text(encoding="utf-8"))
        data = json.loads(truth.read_text(encoding="utf-8"))
        if meta.get("version") != _VERSION:
            return None
        cars = tuple(ParkedCar(**c) for c in data["cars"])
        buildings = tuple(
            DemoBuilding(xy=tuple((float(x), float(y)) for x, y in b["xy"]), levels=b["levels"])
            for b in data["buildings"]
        )
        return DemoRecording(
            root=root,
            bag=bag,
            osm=osm,
            config=config,
            truth=cars,
            buildings=buildings,
            truth_world=truth_world,
            camera_frames=int(meta["camera_frames"]),
            duration_s=float(meta["duration_s"]),
        )
    except (OSError, ValueError, KeyError, TypeError):
        return None


def build_demo_recording(
    out_dir: Path, *, seed: int = 0, progress: ProgressCallback | None = None
) -> DemoRecording:
    """Write the demo's OSM file, bag, config and ground truth into ``out_dir``.

    Every file is written atomically, and ``demo.json`` last: a folder with it is complete
    (:func:`load_demo_recording` reads it back).

    Raises:
        BackendUnavailableError: No headless OpenGL for the raster renderer (the message says
            what to install).
    """
    from cam2sim.core.config import save_config  # noqa: PLC0415
    from cam2sim.core.progress import no_progress  # noqa: PLC0415
    from cam2sim.demo.bag import write_bag  # noqa: PLC0415

    root = Path(out_dir)
    root.mkdir(parents=True, exist_ok=True)
    world = demo_world(seed)
    bag, osm, config, truth = _paths(root)
    write_text_atomic(osm, world.osm_xml())
    with atomic_folder(bag.parent) as tmp:
        frames = write_bag(tmp / bag.name, world, seed=seed, progress=progress or no_progress)
    save_config(demo_config(bag), config, comment="The cam2sim demo recording (cam2sim demo)")
    data = {
        "crs": CRS,
        "origin_utm": list(ORIGIN_UTM),
        "cars": [asdict(c) for c in world.cars],
        "buildings": [{"xy": [list(p) for p in b.xy], "levels": b.levels} for b in world.buildings],
    }
    write_text_atomic(truth, json.dumps(data, indent=1) + "\n")
    world.truth_world(seed=seed).save(root / _TRUTH_WORLD)
    duration = route_length_m() / SPEED_MPS
    meta = {"version": _VERSION, "seed": seed, "camera_frames": frames, "duration_s": duration}
    write_text_atomic(root / _MARKER, json.dumps(meta, indent=1) + "\n")
    return DemoRecording(
        root=root,
        bag=bag,
        osm=osm,
        config=config,
        truth=world.cars,
        buildings=world.buildings,
        truth_world=root / _TRUTH_WORLD,
        camera_frames=frames,
        duration_s=duration,
    )
