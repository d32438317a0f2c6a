"""The ground-truth world: its frame, its look's per-pose noise, the demo's world as truth."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest

from cam2sim.core.camera import PinholeCamera
from cam2sim.core.frames.projection import WorldFrame
from cam2sim.render.look import frame_noise_rng
from cam2sim.render.truth import TruthWorld, truth_from_world
from conftest import has_egl

if TYPE_CHECKING:
    from pathlib import Path

UTM = "EPSG:32632"
ORIGIN = (691_000.0, 5_336_000.0)


def _world() -> TruthWorld:
    return TruthWorld(crs=UTM, origin=ORIGIN, xodr="<OpenDRIVE/>")


def test_the_truth_frame_transform_follows_the_projections() -> None:
    from pyproj import Transformer

    frame = WorldFrame.at_crs_point(UTM, ORIGIN[0] + 40.0, ORIGIN[1] - 25.0)
    T = truth_from_world(_world(), frame.proj_string)
    to_world = Transformer.from_crs(UTM, frame.proj_string, always_xy=True)
    local = np.array([[0.0, 0.0], [150.0, 20.0], [-60.0, 120.0]])
    x, y = to_world.transform(local[:, 0] + ORIGIN[0], local[:, 1] + ORIGIN[1])
    world = np.column_stack([x, y, np.zeros(3), np.ones(3)])
    back = (T @ world.T).T[:, :2]
    assert np.abs(back - local).max() < 0.02
    # UTM grid north is not true north here: the transform rotates (grid convergence).
    assert abs(np.arctan2(T[1, 0], T[0, 0])) > np.radians(1.0)
    assert np.allclose(truth_from_world(_world(), None), np.eye(4))


def test_noise_depends_on_the_seed_and_the_pose_only() -> None:
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 2.0, 1.4]
    moved = pose.copy()
    moved[0, 3] += 0.01

    def draw(seed: int, T: np.ndarray) -> np.ndarray:
        return frame_noise_rng(seed, T).normal(size=8)

    assert np.array_equal(draw(0, pose), draw(0, pose.copy()))
    assert not np.array_equal(draw(0, pose), draw(0, moved))
    assert not np.array_equal(draw(0, pose), draw(1, pose))


def test_the_demo_world_round_trips_as_truth(tmp_path: Path) -> None:
    from cam2sim.demo.world import demo_world

    world = demo_world(3)
    truth = world.truth_world(seed=3)
    truth.save(tmp_path / "world.json")
    loaded = TruthWorld.load(tmp_path / "world.json")
    assert loaded == truth
    assert len(loaded.cars) == len(world.cars) > 10
    assert loaded.look.seed == 3
    assert loaded.cars[0].x == pytest.approx(world.cars[0].x)


class _NoNoise:
    """Stands in for the sensor-noise generator: draws zeros."""

    def normal(self, _loc: float, _scale: float, shape: tuple[int, ...]) -> np.ndarray:
        return np.zeros(shape)


def _ground_view(scale: int, T: np.ndarray) -> np.ndarray:
    """The look of a flat road (sky above the horizon) seen by a 120x80 camera at ``scale``x."""
    from cam2sim.render.look import photographic_look
    from cam2sim.render.meshes import Label

    w, h = 120 * scale, 80 * scale
    K = np.array([[75.0 * scale, 0.0, w / 2], [0.0, 75.0 * scale, h / 2], [0.0, 0.0, 1.0]])
    rows = np.arange(h)[:, None]
    labels = np.where(rows < h * 0.35, Label.SKY, Label.ROAD).astype(np.uint8)
    labels = np.broadcast_to(labels, (h, w)).copy()
    rgb = np.full((h, w, 3), 110, np.uint8)
    return photographic_look(rgb, labels, T, K, rng=_NoNoise(), seed=0)  # type: ignore[arg-type]


def test_road_texture_is_filtered_like_a_camera_would_see_it() -> None:
    """A 1x frame matches a 4x supersampled one: no texture aliasing that changes per pose."""
    import cv2

    from cam2sim.metrics.image_quality import ssim

    T = np.eye(4)
    # Optical axes: looking along +x, slightly down, camera 1.5 m above the road.
    pitch = np.radians(8.0)
    forward = np.array([np.cos(pitch), 0.0, -np.sin(pitch)])
    right = np.array([0.0, -1.0, 0.0])
    T[:3, 0], T[:3, 2] = right, forward
    T[:3, 1] = np.cross(forward, right)
    T[:3, 3] = [3.0, 1.0, 1.5]
    plain = _ground_view(1, T)
    fine = cv2.resize(_ground_view(4, T), (120, 80), interpolation=cv2.INTER_AREA)
    # The lens blur (0.6 px) acts on 1x pixels in one and on 4x pixels in the other.
    fine = np.clip(cv2.GaussianBlur(fine.astype(np.float32), (0, 0), 0.58) + 0.5, 0, 255)
    road = slice(32, 80)  # below the horizon
    score = ssim(plain[road], fine.astype(np.uint8)[road])
    # Point-sampled textures scored 0.72 here: distant grain aliased into per-pose patterns.
    assert score > 0.9, score


@pytest.mark.skipif(not has_egl(), reason="no headless OpenGL (EGL) here")
def test_the_truth_camera_renders_without_sensor_noise_on_request() -> None:
    """Noise-free renders of a pose are identical and differ from the noisy one by noise only."""
    from cam2sim.render.truth import TruthRenderer
    from cam2sim.scenario.synthetic import StreetSpec, synthetic_street

    _, xodr = synthetic_street(StreetSpec(length_m=30.0))
    world = TruthWorld(crs=UTM, origin=ORIGIN, xodr=xodr)
    T = np.eye(4)  # optical axes: looking along +x from 1.4 m above the road
    T[:3, :3] = [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]
    T[:3, 3] = [5.0, 0.0, 1.4]
    lens = PinholeCamera(fx=80.0, fy=80.0, cx=80.0, cy=50.0, width=160, height=100)
    with TruthRenderer(world, None) as camera:
        clean = camera.render(T, lens, sensor_noise=False).rgb
        again = camera.render(T, lens, sensor_noise=False).rgb
        noisy = camera.render(T, lens).rgb
    assert np.array_equal(clean, again)
    diff = noisy.astype(np.float64) - clean.astype(np.float64)
    assert abs(diff.mean()) < 0.5  # zero-mean noise: no change of textures, grading, vignetting
    assert 2.5 < diff.std() < 5.0  # the sensor's 0.015 (3.8 levels), less clipping and rounding
    assert np.abs(diff).max() < 30


def test_an_unmarked_world_draws_no_lane_markings() -> None:
    from cam2sim.demo.world import PAPER_STREET, demo_world
    from cam2sim.map.query import RoadMap
    from cam2sim.render.meshes import marking_mesh

    world = demo_world(0, PAPER_STREET).truth_world()
    marked = world.model_copy(update={"lane_markings": True})
    assert len(marking_mesh(RoadMap.from_xodr(world.xodr))) > 0  # the road has two lanes
    # The unmarked scene has exactly the marking triangles fewer.
    n_marks = len(marking_mesh(RoadMap.from_xodr(world.xodr)))
    assert len(marked.raster_scene().mesh) - len(world.raster_scene().mesh) == n_marks


def test_the_truth_street_and_cars_move_into_the_world_frame() -> None:
    import shapely
    from pyproj import Transformer

    from cam2sim.demo.world import demo_world

    demo = demo_world(0)
    truth = demo.truth_world()
    frame = WorldFrame.at_crs_point(truth.crs, truth.origin[0] + 40.0, truth.origin[1] - 25.0)
    road, cars = truth.in_world_frame(frame.proj_string)
    to_world = Transformer.from_crs(truth.crs, frame.proj_string, always_xy=True)

    def world(xy: np.ndarray) -> np.ndarray:
        x, y = to_world.transform(xy[:, 0] + truth.origin[0], xy[:, 1] + truth.origin[1])
        return np.column_stack([x, y])

    # The driven lane's centre (truth frame) lies on a driving lane of the moved road...
    s = np.linspace(0.0, demo.street.length_m, 50)
    route, _ = demo.street.route_points(s)
    assert road.on_lane(world(route), "driving").all()
    # ...and the sidewalk beyond the parking lane does not.
    kerb, _ = demo.street.route_points(s, -(demo.street.lane_m / 2 + demo.street.parking_m + 1.0))
    assert not road.on_lane(world(kerb)).any()
    # The cars keep their place and their heading (up to the grid's convergence).
    moved = np.array([c.position[:2] for c in cars])
    original = np.array([[c.x, c.y] for c in demo.cars])
    assert np.abs(moved - world(original)).max() < 0.02
    area = road.drivable_area()
    assert isinstance(area, shapely.Geometry)


def test_real_outlines_are_cast_as_walls_and_rectangles_as_boxes() -> None:
    from cam2sim.render.truth import TruthBuilding

    rect = TruthBuilding(xy=((0.0, 0.0), (10.0, 0.0), (10.0, 6.0), (0.0, 6.0)), height_m=9.0)
    ell = TruthBuilding(
        xy=((20.0, 0.0), (30.0, 0.0), (30.0, 4.0), (24.0, 4.0), (24.0, 10.0), (20.0, 10.0)),
        height_m=6.0,
    )
    scene = TruthWorld(crs=UTM, origin=ORIGIN, xodr="<OpenDRIVE/>", buildings=(rect, ell))
    boxes = scene.lidar_scene().structures
    assert len(boxes) == 1 + 6
    assert boxes[0].center[:2] == pytest.approx((5.0, 3.0))
    # Each wall's outer face lies on its edge: the L's inner corner edge (30,4)->(24,4).
    wall = boxes[3]
    assert wall.size[0] == pytest.approx(6.0)
    c = np.asarray(wall.center[:2])
    assert c[1] == pytest.approx(4.0 - 0.15)  # inside the outline (south), 0.15 m from the edge
