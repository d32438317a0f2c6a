"""Seeding a chunk model: the distance-thinned subset of the starting points."""

from __future__ import annotations

import itertools

import numpy as np

from cam2sim.splat.model import screen_density_keep


def _street(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Ground points up to 40 m either side of cameras driving along x."""
    rng = np.random.default_rng(seed)
    pts = np.column_stack([rng.uniform(0, 100, n), rng.uniform(-40, 40, n), np.zeros(n)])
    cams = np.column_stack([np.linspace(0, 100, 51), np.zeros(51), np.full(51, 1.4)])
    return pts.astype(np.float32), cams


def test_keeps_about_the_budget() -> None:
    pts, cams = _street(50_000)
    p = screen_density_keep(pts, cams, 10_000)
    assert p.min() >= 0.0
    assert p.max() <= 1.0
    assert abs(p.sum() - 10_000) < 10


def test_near_points_are_kept_and_far_ones_thinned() -> None:
    pts, cams = _street(50_000)
    p = screen_density_keep(pts, cams, 10_000)
    lateral = np.abs(pts[:, 1])
    near, far = p[lateral < 2].mean(), p[lateral > 30].mean()
    assert near > 0.95  # the road next to the path stays whole
    assert far < 0.1
    # The share kept falls band by band away from the path.
    bands = [
        p[(lateral >= a) & (lateral < b)].mean() for a, b in ((2, 5), (5, 10), (10, 20), (20, 40))
    ]
    assert all(x > y for x, y in itertools.pairwise(bands))


def test_budget_above_the_count_keeps_everything() -> None:
    pts, cams = _street(1_000)
    assert np.allclose(screen_density_keep(pts, cams, 5_000), 1.0)


def test_visible_points_are_those_inside_some_view() -> None:
    """Points seen once are not projected again; the answer is the every-view one."""
    from cam2sim.core.camera import project_points
    from cam2sim.splat.model import visible_points
    from cam2sim.splat.scene import FrameRecord

    rng = np.random.default_rng(3)
    # Points all around a 60 m drive along x (behind, beside, ahead); forward cameras.
    pts = np.column_stack(
        [rng.uniform(-40, 100, 40_000), rng.uniform(-30, 30, 40_000), rng.uniform(-1, 8, 40_000)]
    ).astype(np.float32)
    cam_to_world = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # optical
    frames = []
    for i, x in enumerate(np.linspace(0.0, 60.0, 31)):
        pose = np.eye(4)
        pose[:3, :3] = cam_to_world
        pose[:3, 3] = (x, 0.3 * np.sin(x / 9.0), 1.5)
        intrinsics = {"fx": 160.0, "fy": 160.0, "cx": 160.0, "cy": 100.0}
        frame = FrameRecord(
            index=i, dataset_frame=i, stamp_ns=i, T_world_cam=pose.tolist(),
            width=320, height=200, **intrinsics,
        )  # fmt: skip
        frames.append(frame)
    every = np.zeros(len(pts), dtype=bool)
    for f in frames:
        u, v, front = project_points(pts, f.T(), f.K(), min_depth=1e-3)
        every |= front & (u >= 0) & (u < f.width) & (v >= 0) & (v < f.height)
    seen = visible_points(pts, frames)
    np.testing.assert_array_equal(seen, every)
    assert 0.2 < seen.mean() < 0.9  # some seen, some never (behind the start, far aside)
