"""The raster renderer puts road, cars and sky where the map and the camera say (issue 8)."""

from __future__ import annotations

import math
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from cam2sim.core.camera import PinholeCamera
from cam2sim.core.errors import BackendUnavailableError
from cam2sim.map.query import RoadMap
from cam2sim.render.meshes import CAR_PAINTS, Label
from cam2sim.render.raster import (
    BuildingFootprint,
    RasterRenderer,
    RasterResult,
    RasterScene,
    projection_matrix,
    raster_palette,
)
from cam2sim.scenario.model import ScenarioVehicle

_LANE = '<lane id="{}" type="{}"><width sOffset="0" a="{}" b="0" c="0" d="0"/></lane>'
_XODR = """<?xml version="1.0"?>
<OpenDRIVE><header revMajor="1" revMinor="4"/>
  <road name="street" length="100" id="1" junction="-1">
    <planView><geometry s="0" x="0" y="0" hdg="0" length="100"><line/></geometry></planView>
    <lanes><laneSection s="0"><left>{}</left><center><lane id="0" type="none"/></center>
      <right>{}</right></laneSection></lanes>
  </road>
</OpenDRIVE>
""".format(
    "".join(
        _LANE.format(*a) for a in ((3, "sidewalk", 2), (2, "parking", 2.5), (1, "driving", 3.5))
    ),
    "".join(
        _LANE.format(*a) for a in ((-1, "driving", 3.5), (-2, "parking", 2.5), (-3, "sidewalk", 2))
    ),
)
W = H = 256
K = np.array([[128.0, 0.0, 127.5], [0.0, 128.0, 127.5], [0.0, 0.0, 1.0]])
CAMERA = PinholeCamera.from_K(K, W, H)
CAR = ScenarioVehicle(
    id="parked",
    position=(25.0, -4.75, 0.0),
    heading=0.1,
    size=(4.5, 1.8, 1.5),
    size_class="medium",
    side="right",
    orientation="parallel",
)
# A building left of the street, 9 m high, L-shaped (non-convex roof).
HOUSE = BuildingFootprint(
    np.array([[10.0, 10.0], [30.0, 10.0], [30.0, 20.0], [20.0, 20.0], [20.0, 15.0], [10.0, 15.0]]),
    9.0,
)


def _pose(x: float, y: float, z: float, yaw: float, pitch: float = 0.0) -> np.ndarray:
    """Camera -> world with optical axes (x right, y down, z forward); pitch > 0 looks up."""
    fwd = np.array(
        [math.cos(yaw) * math.cos(pitch), math.sin(yaw) * math.cos(pitch), math.sin(pitch)]
    )
    right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])
    down = np.cross(fwd, right)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([right, down, fwd])
    pose[:3, 3] = (x, y, z)
    return pose


@pytest.fixture(scope="module")
def renderer(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RasterRenderer]:
    path = tmp_path_factory.mktemp("raster") / "map.xodr"
    path.write_text(_XODR, encoding="utf-8")
    scene = RasterScene(RoadMap.from_xodr(path), [CAR], [HOUSE])
    try:
        out = RasterRenderer(scene)
    except BackendUnavailableError as exc:
        pytest.skip(f"no raster backend here: {exc}")
    yield out
    out.close()


@pytest.fixture(scope="module")
def along(renderer: RasterRenderer) -> RasterResult:
    """1.5 m above the right driving lane, looking along the road."""
    return renderer.render(_pose(5.0, -1.75, 1.5, 0.0), CAMERA)


def test_images_have_the_asked_size_and_types(along: RasterResult) -> None:
    assert along.rgb.shape == (H, W, 3)
    assert along.labels.shape == (H, W)
    assert along.rgb.dtype == along.labels.dtype == np.uint8
    assert along.semantic_rgb().shape == (H, W, 3)


def test_road_is_below_the_horizon(along: RasterResult) -> None:
    horizon = K[1, 2]  # level camera: the horizon is the row of the principal point
    road = along.labels == Label.ROAD
    assert not road[: math.ceil(horizon)].any()
    lower = road[math.ceil(horizon) :]
    assert lower.mean() > 0.5
    assert road[-1, W // 2]  # straight down the lane
    assert (along.labels[: int(horizon) - 20] == Label.SKY).mean() > 0.5


def test_parked_car_lies_inside_its_projected_box(along: RasterResult) -> None:
    length, width, height = CAR.size
    corners = np.array(
        [
            [sx * length / 2, sy * width / 2, z]
            for sx in (-1, 1)
            for sy in (-1, 1)
            for z in (0, height)
        ]
    )
    c, s = math.cos(CAR.heading), math.sin(CAR.heading)
    world = corners @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]) + CAR.position
    pose = _pose(5.0, -1.75, 1.5, 0.0)
    cam = (world - pose[:3, 3]) @ pose[:3, :3]
    uv = (cam @ K.T)[:, :2] / cam[:, 2:]
    (u0, v0), (u1, v1) = uv.min(axis=0), uv.max(axis=0)
    rows, cols = np.nonzero(along.labels == Label.CAR)
    assert len(rows) > 0
    assert cols.min() >= math.floor(u0) - 1
    assert cols.max() <= math.ceil(u1) + 1
    assert rows.min() >= math.floor(v0) - 1
    assert rows.max() <= math.ceil(v1) + 1
    assert len(rows) > 0.5 * (u1 - u0) * (v1 - v0)


def test_car_pixels_have_car_colours(renderer: RasterRenderer, along: RasterResult) -> None:
    mesh = renderer.scene.mesh
    car_colours = np.unique(mesh.colours[mesh.labels == Label.CAR], axis=0).astype(int)
    pixels = along.rgb[along.labels == Label.CAR].astype(int)
    nearest = np.abs(pixels[:, None, :] - car_colours[None]).max(axis=2).min(axis=1)
    assert (nearest <= 1).all()
    assert (
        pixels[:, 0] > pixels[:, 2] + 30
    ).mean() > 0.3  # the red body is seen, not only the cabin
    road = along.rgb[along.labels == Label.ROAD]
    assert (np.abs(road.astype(int) - CAR_PAINTS[0]).max(axis=1) > 20).all()


def test_sky_only_when_looking_up(renderer: RasterRenderer) -> None:
    up = renderer.render(_pose(60.0, -1.75, 1.5, 0.0, pitch=math.radians(60)), CAMERA)
    assert set(np.unique(up.labels)) <= {Label.SKY, Label.BACKGROUND}
    assert (up.labels == Label.SKY).mean() > 0.99
    blue = up.rgb[..., 2].astype(int) - up.rgb[..., 0]
    assert (blue > 0).all()


def test_sidewalk_kerb_and_building_are_labelled(renderer: RasterRenderer) -> None:
    side = renderer.render(_pose(20.0, -1.75, 1.5, math.pi / 2), CAMERA)
    labels = set(np.unique(side.labels).tolist())
    assert {Label.ROAD, Label.SIDEWALK, Label.BUILDING, Label.SKY} <= labels
    # Looking across the road to the left, the building stands above the horizon.
    rows = np.nonzero((side.labels == Label.BUILDING).any(axis=1))[0]
    assert rows.min() < K[1, 2] < rows.max()


def test_any_size_and_principal_point(renderer: RasterRenderer) -> None:
    k = np.array([[100.0, 0.0, 90.0], [0.0, 100.0, 20.0], [0.0, 0.0, 1.0]])
    small = renderer.render(_pose(5.0, -1.75, 1.5, 0.0), PinholeCamera.from_K(k, 200, 66))
    assert small.labels.shape == (66, 200)
    road_rows = np.nonzero((small.labels == Label.ROAD).any(axis=1))[0]
    assert road_rows.min() >= 20


def test_projection_maps_pixel_centres() -> None:
    p = projection_matrix(K, W, H, 0.1, 100.0)
    point = np.array([0.3, -0.2, 4.0, 1.0])  # camera frame
    clip = p @ point
    ndc = clip[:3] / clip[3]
    u, v = (K @ point[:3])[:2] / point[2]
    assert ndc[0] == pytest.approx(2 * (u + 0.5) / W - 1)
    assert ndc[1] == pytest.approx(2 * (v + 0.5) / H - 1)
    assert (p @ [0, 0, 0.1, 1])[2] / 0.1 == pytest.approx(-1.0)
    assert (p @ [0, 0, 100.0, 1])[2] / 100.0 == pytest.approx(1.0)


def test_bad_arguments(renderer: RasterRenderer) -> None:
    with pytest.raises(ValueError, match="pose"):
        renderer.render(np.eye(3), CAMERA)
    with pytest.raises(ValueError, match="size must be positive"):  # the camera refuses it
        renderer.render(np.eye(4), PinholeCamera.from_K(K, 0, H))
    distorted = PinholeCamera.from_K(K, W, H, (-0.1, 0.01, 0.0, 0.0))
    with pytest.raises(ValueError, match=r"distortion .*camera\.undistorted\(\)"):
        renderer.render(np.eye(4), distorted)
    renderer.render(np.eye(4), PinholeCamera.from_K(K, W, H, (0.0, 0.0, 0.0, 0.0)))  # all zero


def test_palette_keeps_cityscapes_road_and_car() -> None:
    names = raster_palette().names
    assert names[:3] == ("background", "road", "car")
    assert [names.index(n.name.lower()) for n in Label] == [int(n) for n in Label]


def test_missing_moderngl_names_the_install(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    from cam2sim.render import raster

    monkeypatch.setitem(sys.modules, "moderngl", None)
    with pytest.raises(BackendUnavailableError, match="pip install moderngl"):
        raster._create_context()
