"""Ground seeds under the cameras (cam2sim.splat.ground)."""

from __future__ import annotations

import numpy as np
import pytest

from cam2sim.splat.ground import MIN_ROAD_POINTS, camera_height, ground_points

W, H = 64, 48


def _street(scale: float = 1.0, n_views: int = 6) -> tuple[np.ndarray, ...]:
    """Cameras 1.5 m over flat ground (world z up) driving along x, road points ahead."""
    rot = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # cam x, y, z in world
    poses = np.tile(np.eye(4), (n_views, 1, 1))
    poses[:, :3, :3] = rot
    poses[:, :3, 3] = np.stack(
        [np.arange(n_views) * 2.0, np.zeros(n_views), np.full(n_views, 1.5)], 1
    )
    poses[:, :3, 3] *= scale
    rng = np.random.default_rng(0)
    road = np.stack([rng.uniform(2, 20, 400), rng.uniform(-3, 3, 400), np.zeros(400)], 1) * scale
    wall = np.stack([rng.uniform(2, 20, 200), np.full(200, 4.0), rng.uniform(0, 5, 200)], 1) * scale
    K = np.array([[30.0, 0.0, W / 2], [0.0, 30.0, H / 2], [0.0, 0.0, 1.0]])
    Ks = np.tile(K, (n_views, 1, 1))
    images = np.zeros((n_views, H, W, 3), np.uint8)
    images[:, H // 2 :, :, 0] = 200  # ground red, above the horizon blue
    images[:, : H // 2, :, 2] = 200
    usable = np.ones((n_views, H, W), bool)
    usable[:, : H // 4] = False  # sky
    return np.concatenate([road, wall]), poses, Ks, images, usable


@pytest.mark.parametrize("scale", [1.0, 10.0])
def test_ground_seeds_lie_on_the_road_plane_at_any_scene_scale(scale: float) -> None:
    xyz, poses, Ks, images, usable = _street(scale)
    assert camera_height(xyz, poses, Ks, usable) == pytest.approx(1.5 * scale)
    pts, rgb = ground_points(xyz, poses, Ks, images, usable, count=600, reach=8.0)
    assert 550 <= len(pts) <= 600
    np.testing.assert_allclose(pts[:, 2], 0.0, atol=1e-4 * scale)
    # within reach of some camera, ahead of it, and with the ground's colour
    dist = np.linalg.norm(pts[:, None] - poses[None, :, :3, 3], axis=-1).min(axis=1)
    assert dist.max() <= 8.0 * 1.5 * scale * (1 + 1e-6)
    assert (rgb[:, 0] == 200).all()
    assert (rgb[:, 2] == 0).all()


def test_no_ground_seeds_without_points_on_the_road_ahead() -> None:
    xyz, poses, Ks, images, usable = _street()
    wall_only = xyz[xyz[:, 2] > 0.5][:MIN_ROAD_POINTS]
    assert camera_height(wall_only, poses, Ks, usable) is None
    pts, rgb = ground_points(wall_only, poses, Ks, images, usable, count=100)
    assert pts.shape == (0, 3)
    assert rgb.shape == (0, 3)


def test_no_seeds_on_masked_pixels() -> None:
    xyz, poses, Ks, images, usable = _street()
    usable[:, H // 2 :, : W // 2] = False  # the left half of the ground is the ego hood
    pts, _ = ground_points(xyz, poses, Ks, images, usable, count=300, reach=8.0)
    assert len(pts) > 0
    # left of the image is world +y: every seed is right of the cameras' track
    assert (pts[:, 1] <= 1e-6).all()


def _reference_seeds(
    poses: np.ndarray,
    Ks: np.ndarray,
    images: np.ndarray,
    usable: np.ndarray,
    *,
    count: int,
    reach: float,
    seed: int,
    height: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The ground seeds as the module doc says, every pixel's world ray made (slow, plain)."""
    down = poses[:, :3, 1].mean(axis=0)
    down /= np.linalg.norm(down)
    rng = np.random.default_rng(seed)
    m, h, w = usable.shape
    vv, uu = np.mgrid[0:h, 0:w]
    pix = np.stack([uu + 0.5, vv + 0.5, np.ones_like(uu)], axis=-1).reshape(-1, 3).astype(float)
    out_xyz, out_rgb = [], []
    for pose, K, image, use in zip(poses, Ks, images, usable, strict=True):
        rays = pix @ np.linalg.inv(K).T @ pose[:3, :3].T
        drop = rays @ down
        hit = np.where(drop > 1e-6, height / np.where(drop > 1e-6, drop, 1.0), np.inf)
        ok = np.flatnonzero(use.reshape(-1) & (hit * np.linalg.norm(rays, axis=1) < reach * height))
        pick = rng.choice(ok, size=min(int(np.ceil(count / m)), len(ok)), replace=False)
        out_xyz.append(pose[:3, 3] + hit[pick, None] * rays[pick])
        out_rgb.append(image.reshape(-1, 3)[pick])
    return np.concatenate(out_xyz), np.concatenate(out_rgb)


def test_views_with_different_intrinsics_seed_as_the_plain_per_pixel_rays_do() -> None:
    """Only the picked pixels' rays are made, and their lengths kept per K: the same seeds."""
    xyz, poses, Ks, images, usable = _street(n_views=6)
    Ks[3:, 0, 0] = Ks[3:, 1, 1] = 60.0  # a longer lens on the last three views
    Ks[4, 0, 2] += 5.0  # and one view's centre moved
    rng = np.random.default_rng(5)
    images[:] = rng.integers(0, 256, images.shape, dtype=np.uint8)
    pts, rgb = ground_points(
        xyz, poses, Ks, images, usable, count=600, reach=8.0, seed=1, height=1.5
    )
    ref_pts, ref_rgb = _reference_seeds(
        poses, Ks, images, usable, count=600, reach=8.0, seed=1, height=1.5
    )
    np.testing.assert_array_equal(rgb, ref_rgb)  # the same pixels, drawn in the same order
    np.testing.assert_allclose(pts, ref_pts, atol=1e-5)
    np.testing.assert_allclose(pts[:, 2], 0.0, atol=1e-4)
