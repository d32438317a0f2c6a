"""Triangle meshes of a simulator-style street scene, in world coordinates (metres, z up).

Every builder returns a :class:`Mesh`: a triangle list (three vertices per triangle, no index
buffer) with a colour and a semantic label per vertex. Colours are shaded once here, by the face
normal against a fixed sun direction, so the renderer needs no lighting. All builders are
vectorised over samples; Python loops run over lanes, buildings or faces of a box, never over
vertices.

* **Lanes** are strips between their left and right boundaries: one quad per pair of
  consecutive boundary samples (exact for curved, non-convex lanes, unlike a Delaunay
  triangulation of the lane polygon). Sidewalk-like lanes are raised by ``kerb_height_m`` and
  get vertical kerb faces along both boundaries.
* **Lane markings** are dashed white bands on each boundary shared by two driving lanes of the
  same lane section (OpenDRIVE ids ``-k`` / ``-(k+1)``, ``k`` / ``k+1`` and ``1`` / ``-1``).
* **Cars** are a body box over the whole footprint plus a narrower, shorter cabin box.
* **Buildings** are footprint prisms: walls per ring edge, roof by constrained Delaunay
  triangulation (exact for non-convex footprints).
* **Ground** is one large quad just below the road, labelled background.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import TYPE_CHECKING, Final

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy.typing as npt

    from cam2sim.map.query import Lane, RoadMap
    from cam2sim.scenario.model import ScenarioVehicle

__all__ = [
    "BuildingFootprint",
    "Label",
    "Mesh",
    "building_mesh",
    "car_mesh",
    "ground_mesh",
    "lane_mesh",
    "marking_mesh",
]


class Label(IntEnum):
    """Semantic label ids of the raster renderer.

    0, 1 and 2 are the labels of :meth:`cam2sim.core.labels.Palette.cityscapes`
    (background, road, car); the others follow in the order of
    :func:`cam2sim.render.raster.raster_palette`. Lane markings and parking lanes are road.
    """

    BACKGROUND = 0
    ROAD = 1
    CAR = 2
    SIDEWALK = 3
    BUILDING = 4
    SKY = 5


SIDEWALK_LANE_TYPES: Final = ("sidewalk", "curb", "walking")
_SUN: Final = np.array([0.35, -0.25, 0.9]) / np.linalg.norm([0.35, -0.25, 0.9])
_ROAD_RGB: Final = (72, 72, 76)
_PARKING_RGB: Final = (84, 84, 88)
_SIDEWALK_RGB: Final = (160, 158, 150)
_KERB_RGB: Final = (185, 183, 175)
_MARKING_RGB: Final = (235, 235, 230)
_GROUND_RGB: Final = (96, 110, 80)
_BUILDING_RGB: Final = (150, 138, 124)
_CABIN_RGB: Final = (45, 55, 68)
CAR_PAINTS: Final = ((170, 30, 35), (40, 70, 140), (200, 200, 205), (30, 30, 32), (90, 95, 100))


@dataclass(frozen=True)
class Mesh:
    """A triangle list.

    Attributes:
        positions: ``(3T, 3)`` float64 vertices, world metres; triangle ``t`` is rows
            ``3t .. 3t+2``.
        colours: ``(3T, 3)`` uint8 shaded RGB per vertex.
        labels: ``(3T,)`` uint8 :class:`Label` per vertex.
    """

    positions: npt.NDArray[np.float64]
    colours: npt.NDArray[np.uint8]
    labels: npt.NDArray[np.uint8]

    @classmethod
    def empty(cls) -> Mesh:
        """Return a mesh without triangles."""
        return cls(np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros(0, np.uint8))

    @classmethod
    def concat(cls, meshes: Sequence[Mesh]) -> Mesh:
        """Return all ``meshes`` as one."""
        if not meshes:
            return cls.empty()
        return cls(
            np.concatenate([m.positions for m in meshes]),
            np.concatenate([m.colours for m in meshes]),
            np.concatenate([m.labels for m in meshes]),
        )

    def __len__(self) -> int:
        """Number of vertices."""
        return len(self.positions)


@dataclass(frozen=True)
class BuildingFootprint:
    """A building: an outline extruded from the ground.

    Attributes:
        xy: ``(N, 2)`` exterior ring in world metres (closed or not, either orientation).
        height_m: Height above the ground.
    """

    xy: npt.NDArray[np.float64]
    height_m: float


def _shaded(
    rgb: tuple[int, int, int] | npt.NDArray[np.float64], normals: npt.NDArray[np.float64]
) -> npt.NDArray[np.uint8]:
    """Per-vertex colours ``(N, 3)``: ambient plus Lambert against the sun, by unit normals."""
    light = 0.55 + 0.45 * np.clip(normals @ _SUN, 0.0, 1.0)
    base = np.broadcast_to(np.asarray(rgb, dtype=np.float64), (len(normals), 3))
    out: npt.NDArray[np.uint8] = np.clip(base * light[:, None] + 0.5, 0, 255).astype(np.uint8)
    return out


def _mesh(
    positions: npt.NDArray[np.float64],
    rgb: tuple[int, int, int] | npt.NDArray[np.float64],
    normals: npt.NDArray[np.float64],
    label: Label,
) -> Mesh:
    return Mesh(positions, _shaded(rgb, normals), np.full(len(positions), label, np.uint8))


def _quads(
    a: npt.NDArray[np.float64],
    b: npt.NDArray[np.float64],
    c: npt.NDArray[np.float64],
    d: npt.NDArray[np.float64],
) -> npt.NDArray[np.float64]:
    """Triangles ``(a, b, c)`` and ``(a, c, d)`` of quads given by ``(Q, 3)`` corners."""
    return np.stack([a, b, c, a, c, d], axis=1).reshape(-1, 3)


def _lift(xy: npt.NDArray[np.float64], z: float) -> npt.NDArray[np.float64]:
    return np.column_stack([xy, np.full(len(xy), z)])


def _flat(positions: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    normals = np.zeros_like(positions)
    normals[:, 2] = 1.0
    return normals


_MAX_TURN_RAD = 0.035  # 2 degrees of boundary turn between kept samples


def _turn_breaks(xy: npt.NDArray[np.float64]) -> npt.NDArray[np.bool_]:
    """``(K - 2,)``: interior samples where the accumulated turn passes another 2 degrees.

    Dropping the samples in between keeps a boundary within ``L * 2deg / 8`` of its true line
    (1 cm on a 80 m radius, nothing on straights) with far fewer quads.
    """
    seg = np.diff(xy, axis=0)
    heading = np.unwrap(np.arctan2(seg[:, 1], seg[:, 0]))
    turn = np.abs(np.diff(heading))  # at interior vertices 1 .. K-2
    bucket = np.floor(np.cumsum(turn) / _MAX_TURN_RAD)
    previous = np.concatenate([[0.0], bucket[:-1]])
    breaks: npt.NDArray[np.bool_] = bucket > previous
    return breaks


def _corners(lane: Lane) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Left and right boundary, keeping a sample per 2 degrees of turn (fewer quads)."""
    keep = np.ones(len(lane.s), dtype=bool)
    if len(keep) > 2:
        keep[1:-1] = _turn_breaks(lane.left) | _turn_breaks(lane.right)
    return lane.left[keep], lane.right[keep]


def _strip(left: npt.NDArray[np.float64], right: npt.NDArray[np.float64], z: float
           ) -> npt.NDArray[np.float64]:  # fmt: skip
    """Triangles covering the strip between two boundaries ``(K, 2)`` at height ``z``."""
    lo, ro = _lift(left, z), _lift(right, z)
    return _quads(lo[:-1], lo[1:], ro[1:], ro[:-1])


def _wall_mesh(
    xy: npt.NDArray[np.float64], z0: float, z1: float, rgb: tuple[int, int, int], label: Label
) -> Mesh:
    """Vertical quads from ``z0`` to ``z1`` along a polyline ``(K, 2)``."""
    p, q = xy[:-1], xy[1:]
    seg = q - p
    length = np.hypot(seg[:, 0], seg[:, 1])
    keep = length > 1e-9
    if not keep.any():
        return Mesh.empty()
    p, q, seg, length = p[keep], q[keep], seg[keep], length[keep]
    positions = _quads(_lift(p, z0), _lift(q, z0), _lift(q, z1), _lift(p, z1))
    normal = np.column_stack([seg[:, 1], -seg[:, 0], np.zeros(len(seg))]) / length[:, None]
    # Either side of a wall can face the camera: shade by the better-lit side.
    normal = np.where((normal @ _SUN)[:, None] < 0, -normal, normal)
    return _mesh(positions, rgb, np.repeat(normal, 6, axis=0), label)


def lane_mesh(road_map: RoadMap, *, kerb_height_m: float = 0.15) -> Mesh:
    """Return the lane surfaces (road at z = 0, sidewalks raised) and kerb faces."""
    parts: list[Mesh] = []
    for lane in road_map.lanes:
        if len(lane.s) < 2:
            continue
        left, right = _corners(lane)
        if lane.type in SIDEWALK_LANE_TYPES:
            tris = _strip(left, right, kerb_height_m)
            parts.append(_mesh(tris, _SIDEWALK_RGB, _flat(tris), Label.SIDEWALK))
            parts.extend(
                _wall_mesh(side, 0.0, kerb_height_m, _KERB_RGB, Label.SIDEWALK)
                for side in (left, right)
            )
        else:
            tris = _strip(left, right, 0.0)
            rgb = _PARKING_RGB if lane.type == "parking" else _ROAD_RGB
            parts.append(_mesh(tris, rgb, _flat(tris), Label.ROAD))
    return Mesh.concat(parts)


def _dashes(
    xy: npt.NDArray[np.float64], width_m: float, dash_m: float, gap_m: float
) -> npt.NDArray[np.float64]:
    """Triangles of a dashed band ``width_m`` wide centred on a polyline (z = 0)."""
    seg = np.diff(xy, axis=0)
    length = np.hypot(seg[:, 0], seg[:, 1])
    mid = np.concatenate([[0.0], np.cumsum(length)])[:-1] + 0.5 * length
    keep = (length > 1e-9) & (np.mod(mid, dash_m + gap_m) < dash_m)
    p, q, seg, length = xy[:-1][keep], xy[1:][keep], seg[keep], length[keep]
    offset = 0.5 * width_m * np.column_stack([-seg[:, 1], seg[:, 0]]) / length[:, None]
    return _quads(
        _lift(p + offset, 0.0),
        _lift(q + offset, 0.0),
        _lift(q - offset, 0.0),
        _lift(p - offset, 0.0),
    )


def marking_mesh(
    road_map: RoadMap,
    *,
    width_m: float = 0.12,
    dash_m: float = 3.0,
    gap_m: float = 6.0,
    lift_m: float = 0.01,
) -> Mesh:
    """Return dashed markings on the boundaries between two driving lanes (module doc)."""
    types = {(ln.road_id, ln.section, ln.lane_id): ln.type for ln in road_map.lanes}
    parts: list[npt.NDArray[np.float64]] = []
    for lane in road_map.lanes:
        if lane.type != "driving" or len(lane.s) < 2:
            continue
        # The right boundary (in driving direction) faces lane id -(k+1) for -k, k-1 (or -1) for k.
        if lane.lane_id < 0:
            other = lane.lane_id - 1
        else:
            other = lane.lane_id - 1 if lane.lane_id > 1 else -1
        if types.get((lane.road_id, lane.section, other)) == "driving":
            parts.append(_dashes(lane.right, width_m, dash_m, gap_m))
    if not parts:
        return Mesh.empty()
    tris = np.concatenate(parts)
    tris[:, 2] = lift_m
    return _mesh(tris, _MARKING_RGB, _flat(tris), Label.ROAD)


# A box of unit size, bottom centre at the origin: 6 faces x 2 triangles, and its face normals.
_FACES: Final = (
    ((0.5, -0.5, 0), (0.5, 0.5, 0), (0.5, 0.5, 1), (0.5, -0.5, 1), (1, 0, 0)),
    ((-0.5, 0.5, 0), (-0.5, -0.5, 0), (-0.5, -0.5, 1), (-0.5, 0.5, 1), (-1, 0, 0)),
    ((0.5, 0.5, 0), (-0.5, 0.5, 0), (-0.5, 0.5, 1), (0.5, 0.5, 1), (0, 1, 0)),
    ((-0.5, -0.5, 0), (0.5, -0.5, 0), (0.5, -0.5, 1), (-0.5, -0.5, 1), (0, -1, 0)),
    ((-0.5, -0.5, 1), (0.5, -0.5, 1), (0.5, 0.5, 1), (-0.5, 0.5, 1), (0, 0, 1)),
    ((-0.5, 0.5, 0), (0.5, 0.5, 0), (0.5, -0.5, 0), (-0.5, -0.5, 0), (0, 0, -1)),
)
_BOX: Final = np.array([[f[i] for i in (0, 1, 2, 0, 2, 3)] for f in _FACES], float).reshape(-1, 3)
_BOX_NORMALS: Final = np.repeat(np.array([f[4] for f in _FACES], float), 6, axis=0)


def _boxes(
    centre: npt.NDArray[np.float64], yaw: npt.NDArray[np.float64], size: npt.NDArray[np.float64]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """``(36N, 3)`` positions and normals of N yawed boxes (bottom centre, length/width/height)."""
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.zeros((len(yaw), 3, 3))
    rot[:, 0, 0], rot[:, 0, 1], rot[:, 1, 0], rot[:, 1, 1], rot[:, 2, 2] = c, -s, s, c, 1.0
    local = _BOX[None] * size[:, None, :]
    positions = np.einsum("nij,nvj->nvi", rot, local) + centre[:, None, :]
    normals = np.einsum("nij,vj->nvi", rot, _BOX_NORMALS)
    return positions.reshape(-1, 3), normals.reshape(-1, 3)


def car_mesh(vehicles: Sequence[ScenarioVehicle]) -> Mesh:
    """Return car-shaped meshes (body box plus cabin) of ``vehicles``, labelled car."""
    if not vehicles:
        return Mesh.empty()
    pos = np.array([v.position for v in vehicles], dtype=np.float64)
    yaw = np.array([v.heading for v in vehicles], dtype=np.float64)
    size = np.array([v.size for v in vehicles], dtype=np.float64)
    fwd = np.column_stack([np.cos(yaw), np.sin(yaw), np.zeros(len(yaw))])
    body_size = size * [1.0, 1.0, 0.55]
    cabin_size = size * [0.55, 0.86, 0.45]
    cabin_centre = pos - 0.08 * size[:, :1] * fwd + [0.0, 0.0, 1.0] * body_size[:, 2:]
    body, body_n = _boxes(pos, yaw, body_size)
    cabin, cabin_n = _boxes(cabin_centre, yaw, cabin_size)
    paint = np.asarray(CAR_PAINTS, dtype=np.float64)[np.arange(len(vehicles)) % len(CAR_PAINTS)]
    return Mesh.concat(
        [
            _mesh(body, np.repeat(paint, len(_BOX), axis=0), body_n, Label.CAR),
            _mesh(cabin, _CABIN_RGB, cabin_n, Label.CAR),
        ]
    )


def building_mesh(buildings: Sequence[BuildingFootprint]) -> Mesh:
    """Return extruded footprints (walls and roofs), labelled building."""
    import shapely  # noqa: PLC0415

    parts: list[Mesh] = []
    for building in buildings:
        ring = np.asarray(building.xy, dtype=np.float64)
        if len(ring) < 3 or building.height_m <= 0:
            continue
        if not np.allclose(ring[0], ring[-1]):
            ring = np.vstack([ring, ring[:1]])
        h = float(building.height_m)
        parts.append(_wall_mesh(ring, 0.0, h, _BUILDING_RGB, Label.BUILDING))
        polygon = shapely.make_valid(shapely.Polygon(ring))
        tris = shapely.get_parts(shapely.constrained_delaunay_triangles(polygon))
        if len(tris) == 0:
            continue
        xy = shapely.get_coordinates(tris).reshape(len(tris), 4, 2)[:, :3].reshape(-1, 2)
        roof = _lift(xy, h)
        parts.append(_mesh(roof, _BUILDING_RGB, _flat(roof), Label.BUILDING))
    return Mesh.concat(parts)


def ground_mesh(
    bounds: tuple[float, float, float, float], *, margin_m: float = 300.0, z: float = -0.02
) -> Mesh:
    """Return one quad over ``(xmin, ymin, xmax, ymax)`` plus ``margin_m``, labelled background."""
    x0, y0, x1, y1 = bounds
    x0, y0, x1, y1 = x0 - margin_m, y0 - margin_m, x1 + margin_m, y1 + margin_m
    corners = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]])
    tris = _quads(corners[:1], corners[1:2], corners[2:3], corners[3:])
    return _mesh(tris, _GROUND_RGB, _flat(tris), Label.BACKGROUND)
