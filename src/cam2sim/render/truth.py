"""The ground-truth world and its camera: closed-loop drives "in the real world".

A :class:`TruthWorld` describes the world a recording was made in, as far as it is known
exactly: the street (OpenDRIVE text), the parked cars (boxes), the buildings (footprints and
heights) and the look the camera had, all in a local metric frame anchored at a point of a
named CRS. It lives in the workspace at ``WS/truth/world.json`` (:func:`truth_world_path`); the
demo writes it for its synthetic recording (``cam2sim demo``), and anyone who has an exact model
of a recording's world can write one.

:class:`TruthRenderer` is the ``truth`` camera of ``cam2sim drive`` and ``cam2sim replay``: it
takes camera poses in the workspace world frame, moves them into the truth frame (a rigid
transform fitted through the two projections) and renders the truth scene with the raster
renderer and, for ``look.kind == "photographic"``, :func:`~cam2sim.render.look.photographic_look`
with per-pose noise (:func:`~cam2sim.render.look.frame_noise_rng`): the very pipeline that made
the demo recording, so a pose renders as the recording would have seen it. With
``sensor_noise=False`` it renders the same image without the noise (the reference the splat
models are scored against off the recorded path).
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import TYPE_CHECKING, Literal, Self

import numpy as np
import pydantic

from cam2sim.core.errors import StageError
from cam2sim.core.scene import Ground, SceneBox, StreetScene
from cam2sim.core.schema import Artifact
from cam2sim.core.workspace import TRUTH_WORLD_FILE
from cam2sim.render.look import frame_noise_rng, photographic_look
from cam2sim.render.raster import (
    BuildingFootprint,
    RasterOptions,
    RasterRenderer,
    RasterResult,
    RasterScene,
)
from cam2sim.scenario.model import ScenarioVehicle

if TYPE_CHECKING:
    import numpy.typing as npt

    from cam2sim.core.camera import PinholeCamera
    from cam2sim.map.query import RoadMap

__all__ = [
    "TRUTH_WORLD_FILE",
    "TruthBuilding",
    "TruthCar",
    "TruthLook",
    "TruthRenderer",
    "TruthWorld",
    "truth_world_path",
]

_FIT_HALF_M = 500.0
_GEOMETRY = re.compile(r"<geometry\b[^>]*>")
_ATTR = re.compile(r'\b(\w+)="([^"]*)"')
_ATTR_X = re.compile(r'\bx="[^"]*"')
_ATTR_Y = re.compile(r'\by="[^"]*"')
_ATTR_HDG = re.compile(r'\bhdg="[^"]*"')
"""Half extent of the grid the truth frame -> world frame transform is fitted on."""


class TruthCar(pydantic.BaseModel):
    """A parked car: bottom centre, heading (rad) and size (m) in the truth frame."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    x: float
    y: float
    yaw: float
    length: float = pydantic.Field(gt=0)
    width: float = pydantic.Field(gt=0)
    height: float = pydantic.Field(gt=0)
    side: str = "right"


class TruthBuilding(pydantic.BaseModel):
    """A building: footprint ring (truth frame, metres) and height."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    xy: tuple[tuple[float, float], ...] = pydantic.Field(min_length=3)
    height_m: float = pydantic.Field(gt=0)


class TruthLook(pydantic.BaseModel):
    """How the truth camera looks: ``photographic`` (textures and noise) or plain ``raster``."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    kind: Literal["photographic", "raster"] = "photographic"
    seed: int = 0


class TruthWorld(Artifact):
    """``WS/truth/world.json``: the ground-truth world of a recording.

    Attributes:
        crs: pyproj CRS the frame's origin is given in (e.g. ``EPSG:32632``).
        origin: ``(x, y)`` of the truth frame's origin in ``crs``; the frame's axes are the
            CRS grid's (x east, y north), z up from the road surface.
        xodr: The street as OpenDRIVE text, in the truth frame.
        cars: Parked cars.
        buildings: Buildings.
        look: The camera's look (and the seed of its textures and noise).
        lane_markings: Whether the roadway has markings between its driving lanes.
        title: What the world is, in a line (the demo's street title; empty when not given).
        notes: How it was made (a route picked from an OSM extract: which, and what it lacks).
    """

    crs: str
    origin: tuple[float, float]
    xodr: str
    cars: tuple[TruthCar, ...] = ()
    buildings: tuple[TruthBuilding, ...] = ()
    look: TruthLook = TruthLook()
    lane_markings: bool = True
    title: str = ""
    notes: tuple[str, ...] = ()

    def lidar_scene(self) -> StreetScene:
        """The scene a ray-cast LiDAR scans: flat ground, car boxes, building boxes.

        A rectangular building is a box over its footprint, reaching 3 m below the road (so no
        ray passes under it) up to its height; any other footprint (a real outline from OSM) is
        a 0.3 m thick wall box inside each of its edges, so rays stop at the outline itself.
        """
        cars = tuple(
            SceneBox((c.x, c.y, c.height / 2.0), (c.length, c.width, c.height), c.yaw)
            for c in self.cars
        )
        structures: list[SceneBox] = []
        for b in self.buildings:
            structures += _building_boxes(np.asarray(b.xy, dtype=np.float64), b.height_m)
        ground = Ground(road_half_width_m=1e9, kerb_height_m=0.0)
        return StreetScene(ground=ground, cars=cars, structures=tuple(structures))

    def raster_scene(self) -> RasterScene:
        """The scene the raster renderer draws (street, cars, buildings)."""
        from cam2sim.map.query import RoadMap  # noqa: PLC0415 -- lazy: imports shapely

        vehicles = self._vehicles(np.eye(4))
        buildings = [BuildingFootprint(np.asarray(b.xy), b.height_m) for b in self.buildings]
        options = RasterOptions(lane_markings=self.lane_markings)
        return RasterScene(RoadMap.from_xodr(self.xodr), vehicles, buildings, options=options)

    def in_world_frame(self, proj_string: str | None) -> tuple[RoadMap, list[ScenarioVehicle]]:
        """The road and the parked cars moved into the workspace world frame (``proj_string``).

        What a drive judged in the ground truth checks against (off the road, collisions):
        the same rigid transform as the truth camera's, applied to every ``<geometry>`` of the
        street's plan view and to every car.
        """
        from cam2sim.map.query import RoadMap  # noqa: PLC0415 -- lazy: imports shapely

        T = np.asarray(np.linalg.inv(truth_from_world(self, proj_string)), dtype=np.float64)
        yaw = math.atan2(T[1, 0], T[0, 0])

        def move(match: re.Match[str]) -> str:
            attrs = dict(_ATTR.findall(match.group(0)))
            x, y = (
                float(v) for v in (T[:2, :2] @ [float(attrs["x"]), float(attrs["y"])]) + T[:2, 3]
            )
            hdg = float(attrs["hdg"]) + yaw
            out = _ATTR_X.sub(f'x="{x!r}"', match.group(0), count=1)
            out = _ATTR_Y.sub(f'y="{y!r}"', out, count=1)
            return _ATTR_HDG.sub(f'hdg="{hdg!r}"', out, count=1)

        xodr = _GEOMETRY.sub(move, self.xodr)
        return RoadMap.from_xodr(xodr), self._vehicles(T)

    def _vehicles(self, T: npt.NDArray[np.float64]) -> list[ScenarioVehicle]:
        """The parked cars as scenario vehicles, moved by ``T`` (truth frame -> target)."""
        yaw = math.atan2(T[1, 0], T[0, 0])
        out = []
        for k, c in enumerate(self.cars):
            x, y = (T[:2, :2] @ [c.x, c.y]) + T[:2, 3]
            out.append(
                ScenarioVehicle(
                    id=f"pv_{k:03d}",
                    position=(float(x), float(y), 0.0),
                    heading=c.yaw + yaw,
                    size=(c.length, c.width, c.height),
                    size_class="medium",
                    side=c.side,
                    orientation="parallel",
                )
            )
        return out


_WALL_M = 0.3


def _building_boxes(ring: npt.NDArray[np.float64], height_m: float) -> list[SceneBox]:
    """Boxes a ray-cast LiDAR sees of one footprint (see :meth:`TruthWorld.lidar_scene`)."""
    if len(ring) > 3 and np.allclose(ring[0], ring[-1]):
        ring = ring[:-1]
    z, tall = (height_m - 3.0) / 2.0, height_m + 3.0
    edges = np.roll(ring, -1, axis=0) - ring
    if len(ring) == 4:
        unit = edges / np.maximum(np.linalg.norm(edges, axis=1, keepdims=True), 1e-12)
        if np.all(np.abs(np.sum(unit * np.roll(unit, -1, axis=0), axis=1)) < 1e-3):
            centre = ring.mean(axis=0)
            size = (float(np.linalg.norm(edges[0])), float(np.linalg.norm(edges[1])), tall)
            yaw = math.atan2(edges[0, 1], edges[0, 0])
            return [SceneBox((float(centre[0]), float(centre[1]), z), size, yaw)]
    # Inwards is to the left of counter-clockwise edges.
    area2 = float(
        np.sum(ring[:, 0] * np.roll(ring[:, 1], -1) - np.roll(ring[:, 0], -1) * ring[:, 1])
    )
    inward = 1.0 if area2 > 0 else -1.0
    out = []
    for p, e in zip(ring, edges, strict=True):
        length = float(np.linalg.norm(e))
        if length < 1e-6:
            continue
        n = inward * np.array([-e[1], e[0]]) / length
        c = p + e / 2.0 + n * _WALL_M / 2.0
        yaw = math.atan2(e[1], e[0])
        out.append(SceneBox((float(c[0]), float(c[1]), z), (length, _WALL_M, tall), yaw))
    return out


def truth_world_path(root: Path) -> Path:
    """Where the workspace at ``root`` keeps its ground-truth world."""
    return Path(root) / TRUTH_WORLD_FILE


def _rigid_fit(
    src: npt.NDArray[np.float64], dst: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """The ``(4, 4)`` rotation about z plus translation that best maps ``src`` xy onto ``dst``."""
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    u, _, vt = np.linalg.svd((src - cs).T @ (dst - cd))
    rot = (u @ vt).T
    if np.linalg.det(rot) < 0:
        vt[-1] *= -1.0
        rot = (u @ vt).T
    out = np.eye(4)
    out[:2, :2] = rot
    out[:2, 3] = cd - rot @ cs
    return out


def truth_from_world(world: TruthWorld, proj_string: str | None) -> npt.NDArray[np.float64]:
    """``(4, 4)`` transform from the workspace world frame (``proj_string``) to the truth frame.

    Without a projection (a workspace that is not geo-referenced) the frames are taken to be
    the same.
    """
    if proj_string is None:
        return np.eye(4)
    from pyproj import Transformer  # noqa: PLC0415

    g = np.linspace(-_FIT_HALF_M, _FIT_HALF_M, 5)
    local = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    to_world = Transformer.from_crs(world.crs, proj_string, always_xy=True)
    x, y = to_world.transform(local[:, 0] + world.origin[0], local[:, 1] + world.origin[1])
    scene = np.column_stack([np.asarray(x, np.float64), np.asarray(y, np.float64)])
    if not np.isfinite(scene).all():
        msg = f"cannot project the truth frame ({world.crs}) into the world frame {proj_string}"
        raise StageError(msg)
    return np.asarray(np.linalg.inv(_rigid_fit(local, scene)), dtype=np.float64)


class TruthRenderer:
    """The ``truth`` camera: renders the ground-truth world at world-frame camera poses."""

    def __init__(self, world: TruthWorld, proj_string: str | None) -> None:
        """Build the truth scene and the transform from the world frame (``proj_string``)."""
        self.world = world
        self.T_truth_world = truth_from_world(world, proj_string)
        self._raster: RasterRenderer = RasterRenderer(world.raster_scene())

    @classmethod
    def open(cls, root: Path, proj_string: str | None) -> Self:
        """The truth camera of the workspace at ``root``.

        Raises:
            StageError: The workspace has no ``truth/world.json``.
        """
        path = truth_world_path(root)
        if not path.is_file():
            msg = (
                f"{root} has no ground-truth world ({TRUTH_WORLD_FILE}); the truth camera needs "
                "one (cam2sim demo writes it; see docs/architecture.md for the format)"
            )
            raise StageError(msg)
        return cls(TruthWorld.load(path), proj_string)

    def render(
        self,
        T_world_cam: npt.NDArray[np.float64],
        camera: PinholeCamera,
        *,
        sensor_noise: bool = True,
    ) -> RasterResult:
        """RGB (with the world's look) and labels of a camera at a world-frame pose.

        ``sensor_noise=False`` leaves out the photographic look's sensor noise (textures, blur,
        grading and vignetting stay): the noise-free image of the pose, the same every time,
        which models are scored against (:mod:`cam2sim.splat.envelope`).

        Args:
            T_world_cam: ``(4, 4)`` camera (OpenCV optical axes) -> world frame, metres.
            camera: The camera of the wanted image, without lens distortion.
            sensor_noise: Whether the photographic look adds its per-pose sensor noise.

        Raises:
            ValueError: A pose that is not ``(4, 4)``, or a camera with lens distortion.
        """
        T = self.T_truth_world @ np.asarray(T_world_cam, dtype=np.float64)
        frame = self._raster.render(T, camera)
        look = self.world.look
        if look.kind == "raster":
            return frame
        rng = frame_noise_rng(look.seed, T) if sensor_noise else None
        rgb = photographic_look(frame.rgb, frame.labels, T, camera.K(), rng=rng, seed=look.seed)
        return RasterResult(rgb=rgb, labels=frame.labels)

    def close(self) -> None:
        """Release the raster renderer."""
        self._raster.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
