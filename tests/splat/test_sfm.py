"""SfM: known-pose triangulation on a rendered scene; images-only SfM on real frames."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from cam2sim.core import frames as fr
from cam2sim.splat.geometry import interpolated_corrections
from cam2sim.splat.sfm import (
    FeatureOptions,
    KnownView,
    PoseAdjustment,
    SfmCamera,
    SfmOptions,
    apply_similarity,
    sfm_images_only,
    similarity_from_poses,
    triangulate_known_poses,
)

pytest.importorskip("pycolmap")

W, H = 320, 240
K = np.array([[260.0, 0.0, 160.0], [0.0, 260.0, 120.0], [0.0, 0.0, 1.0]])
UDACITY = Path(__file__).resolve().parents[3] / "shared" / "data" / "images" / "udacity-ch2"

# Two textured walls facing the cameras: (origin, axis a, axis b, texture metres per pixel).
WALLS = (
    (np.array([-6.0, -2.5, 8.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), 0.012),
    (np.array([-1.0, -1.5, 5.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), 0.006),
)


def _texture(seed: int, size: int = 512) -> np.ndarray:
    """Blob texture at several scales (SIFT-friendly), RGB uint8."""
    rng = np.random.default_rng(seed)
    out = np.zeros((size, size, 3), np.float64)
    for cells in (8, 24, 64):
        noise = rng.random((cells, cells, 3))
        out += cv2.resize(noise, (size, size), interpolation=cv2.INTER_CUBIC)
    out -= out.min()
    texture: np.ndarray = (255 * out / out.max()).astype(np.uint8)
    return texture


def render(T_world_cam: np.ndarray) -> np.ndarray:
    """Render the walls (far first) through a pinhole camera ``K`` at ``T_world_cam``."""
    T_cam_world = np.linalg.inv(T_world_cam)
    R, t = T_cam_world[:3, :3], T_cam_world[:3, 3]
    image = np.full((H, W, 3), 90, np.uint8)
    for k, (origin, a, b, scale) in enumerate(WALLS):
        tex = _texture(k)
        Hmat = K @ np.column_stack([R @ (scale * a), R @ (scale * b), R @ origin + t])
        warped = cv2.warpPerspective(tex, Hmat, (W, H), flags=cv2.INTER_LINEAR)
        cover = cv2.warpPerspective(np.full(tex.shape[:2], 255, np.uint8), Hmat, (W, H)) > 128
        image[cover] = warped[cover]
    return image


def wall_distance(xyz: np.ndarray) -> np.ndarray:
    """Distance of points to the nearest wall (planes z = 5 within its extent, else z = 8)."""
    origin, _, _, scale = WALLS[1]
    near = (
        (xyz[:, 0] >= origin[0])
        & (xyz[:, 0] <= origin[0] + 512 * scale)
        & (xyz[:, 1] >= origin[1])
        & (xyz[:, 1] <= origin[1] + 512 * scale)
    )
    return np.where(near, np.abs(xyz[:, 2] - 5.0), np.abs(xyz[:, 2] - 8.0))


def camera_track(n: int = 10, step_m: float = 0.25) -> np.ndarray:
    """Cameras sliding sideways (x) and a little forward (z), looking along +z."""
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 0, 3] = np.arange(n) * step_m - 1.0
    poses[:, 2, 3] = np.arange(n) * 0.05
    return poses


def _write_views(folder: Path, poses: np.ndarray) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    files = []
    for i, T in enumerate(poses):
        path = folder / f"{i:06d}.png"
        cv2.imwrite(str(path), cv2.cvtColor(render(T), cv2.COLOR_RGB2BGR))
        files.append(path)
    return files


def test_similarity_from_poses_recovers_roll_about_a_straight_track() -> None:
    src = camera_track(6)
    src[:, 2, 3] = 0.0  # centres exactly on a line: the centres alone leave the roll free
    angle = 0.7
    S = np.eye(4)
    S[:3, :3] = 2.5 * np.array(
        [[1.0, 0, 0], [0, np.cos(angle), -np.sin(angle)], [0, np.sin(angle), np.cos(angle)]]
    )
    S[:3, 3] = [1.0, -2.0, 3.0]
    dst = apply_similarity(S, src)
    assert np.allclose(similarity_from_poses(src, dst), S, atol=1e-9)
    assert np.allclose(dst[:, :3, 3], src[:, :3, 3] @ S[:3, :3].T + S[:3, 3])


def test_sfm_camera_converts_simple_radial_to_opencv() -> None:
    cam = SfmCamera("SIMPLE_RADIAL", 640, 480, (500.0, 320.0, 240.0, -0.1))
    assert np.allclose(cam.K(), [[500, 0, 320], [0, 500, 240], [0, 0, 1]])
    assert cam.distortion() == (-0.1, 0.0, 0.0, 0.0)


def test_triangulate_known_poses_recovers_walls_within_centimetres(tmp_path: Path) -> None:
    poses = camera_track()
    files = _write_views(tmp_path / "images", poses)
    result = triangulate_known_poses(
        files, [KnownView(K, T) for T in poses], window=5, features=FeatureOptions(num_threads=2)
    )
    assert len(result.points) > 300
    err = wall_distance(result.points.xyz)
    assert np.median(err) < 0.03
    assert np.quantile(err, 0.9) < 0.08
    assert result.mean_reprojection_error_px < 1.0
    assert np.array_equal(result.T_world_cam, poses)


def test_triangulate_known_poses_refine_keeps_the_recorded_frame(tmp_path: Path) -> None:
    poses = camera_track()
    files = _write_views(tmp_path / "images", poses)
    noisy = poses.copy()
    noisy[1:, :3, 3] += np.random.default_rng(0).normal(scale=0.01, size=(len(poses) - 1, 3))
    result = triangulate_known_poses(
        files,
        [KnownView(K, T) for T in noisy],
        window=5,
        refine=True,
        features=FeatureOptions(num_threads=2),
    )
    assert result.refined
    moved = np.linalg.norm(result.T_world_cam[:, :3, 3] - poses[:, :3, 3], axis=1)
    assert moved.max() < 0.05
    assert np.median(wall_distance(result.points.xyz)) < 0.05


def test_interpolated_corrections_carry_the_neighbours_correction() -> None:
    recorded = camera_track(5)
    turn = np.eye(4)
    turn[:3, :3] = fr.quat_to_matrix(fr.quat_from_yaw(0.02))
    shift = np.eye(4)
    shift[:3, 3] = [0.1, 0.0, 0.0]
    adjusted = recorded.copy()
    adjusted[1] = recorded[1] @ turn
    adjusted[3] = recorded[3] @ shift
    adjusted[2] = adjusted[0] = adjusted[4] = np.nan  # unfitted rows are never read
    fitted = np.array([False, True, False, True, False])
    out = interpolated_corrections(recorded, adjusted, fitted)
    assert np.allclose(out[[1, 3]], adjusted[[1, 3]])
    half = np.linalg.inv(recorded[2]) @ out[2]
    assert np.allclose(half[:3, 3], [0.05, 0.0, 0.0])
    assert np.isclose(fr.yaw_from_quat(fr.quat_from_matrix(half[:3, :3])), 0.01)
    assert np.allclose(out[0], recorded[0] @ turn)  # beyond the ends: the nearest one's
    assert np.allclose(out[4], recorded[4] @ shift)
    everything = np.ones(5, bool)
    assert np.array_equal(interpolated_corrections(recorded, recorded, everything), recorded)
    with pytest.raises(ValueError, match="at least one"):
        interpolated_corrections(recorded, adjusted, np.zeros(5, bool))


@pytest.mark.parametrize("prior_m", [None, 1.0])
def test_held_out_views_shape_nothing_and_are_aligned_to_their_own_images(
    tmp_path: Path, prior_m: float | None
) -> None:
    """A held-out view is kept out of the triangulation and the adjustment: whatever its
    recorded pose, the other poses and the points come out the same (scoring the splat there
    stays honest). Its own pose is then fitted to its image against the adjusted points."""
    poses = camera_track()
    files = _write_views(tmp_path / "images", poses)
    noisy = poses.copy()
    noisy[1:, :3, 3] += np.random.default_rng(0).normal(scale=0.005, size=(len(poses) - 1, 3))
    held = [i == 4 for i in range(len(poses))]
    fitted = ~np.array(held)
    runs = []
    for error_m in (0.08, -0.15):
        recorded = noisy.copy()
        recorded[4, 1, 3] += error_m  # this view's own error
        runs.append(
            triangulate_known_poses(
                files,
                [KnownView(K, T) for T in recorded],
                window=5,
                refine=PoseAdjustment(prior_m=prior_m, held_out=tuple(held)),
                # One thread: matching and the adjustment on threads vary in the last bits from
                # run to run, and the adjustment can carry that far (flaky at 2 threads).
                features=FeatureOptions(num_threads=1),
            )
        )
    a, b = runs
    assert np.allclose(a.T_world_cam[fitted], b.T_world_cam[fitted], atol=1e-4)
    assert np.allclose(a.points.xyz, b.points.xyz, atol=1e-4)
    for run in runs:
        assert np.linalg.norm(run.T_world_cam[4, :3, 3] - poses[4, :3, 3]) < 0.03  # aligned
        others = np.linalg.norm(run.T_world_cam[fitted, :3, 3] - poses[fitted, :3, 3], axis=1)
        assert others.max() < 0.03


def test_triangulate_known_poses_rejects_mismatched_views(tmp_path: Path) -> None:
    files = _write_views(tmp_path / "images", camera_track(3))
    with pytest.raises(ValueError, match="one KnownView per image"):
        triangulate_known_poses(files, [KnownView(K, np.eye(4))])


@pytest.mark.requires_shared_data
def test_sfm_images_only_registers_real_udacity_frames() -> None:
    if not UDACITY.is_dir():
        pytest.skip(f"real data not found at {UDACITY}")
    files = sorted(UDACITY.glob("*.jpg"))[:40:2]
    result = sfm_images_only(files, options=SfmOptions(mapper="global"))
    assert result.registered == len(files)
    assert result.scale_ambiguous
    assert result.mean_reprojection_error_px < 1.5
    assert len(result.points) > 500
    centres = result.T_world_cam[:, :3, 3]
    # The car drives forward: camera centres advance along the optical axis.
    forward = result.T_world_cam[0, :3, 2]
    assert np.all(np.diff(centres @ forward) > 0)


def test_sfm_without_pycolmap_names_the_extra(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from cam2sim.core.errors import BackendUnavailableError

    monkeypatch.setitem(sys.modules, "pycolmap", None)
    with pytest.raises(BackendUnavailableError, match=r"pip install cam2sim\[splat\]"):
        sfm_images_only([tmp_path / "a.png", tmp_path / "b.png"])


def test_sfm_defaults_follow_the_forward_driving_lessons() -> None:
    opts = SfmOptions()
    assert opts.mapper == "incremental"
    assert not opts.refine_focal
    assert opts.features.window == 20


@pytest.mark.parametrize("focal", [False, True])
def test_final_refinement_refines_the_focal_length_only_when_asked(
    monkeypatch: pytest.MonkeyPatch, focal: bool
) -> None:
    import pycolmap

    from cam2sim.splat import sfm

    seen: list[Any] = []
    monkeypatch.setattr(pycolmap, "bundle_adjustment", lambda _rec, options: seen.append(options))
    sfm._final_refinement(pycolmap, object(), 1, focal=focal)
    (options,) = seen
    assert options.refine_focal_length is focal
    assert options.refine_extra_params
    assert not options.refine_principal_point


def test_sift_threads_are_the_cpus_this_process_may_use(monkeypatch: pytest.MonkeyPatch) -> None:
    """Not the host's core count: a container or a Ray task gets a share of them."""
    from cam2sim.core.machine import available_cpus
    from cam2sim.splat.sfm import FeatureOptions

    assert FeatureOptions().threads() == available_cpus()
    monkeypatch.setenv("OMP_NUM_THREADS", "1")  # as Ray sets it for a task given one CPU
    assert FeatureOptions().threads() == 1
    assert FeatureOptions(num_threads=3).threads() == 3
