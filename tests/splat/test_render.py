"""The splat renderer: chunk choice and hand-over, coverage, appearance, lazy loading.

Chunk models are built directly (a textured wall of Gaussians at y = 8 m, ahead of a route along +y,
each chunk tinted differently), so these tests need no training.
"""

from __future__ import annotations

from itertools import pairwise
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")

import torch

from cam2sim.core.camera import PinholeCamera
from cam2sim.core.errors import WorkspaceError
from cam2sim.splat import model as gm
from cam2sim.splat.raster import rasterize
from cam2sim.splat.render import (
    RenderOptions,
    SplatRenderer,
    chunk_weights,
    smoothstep,
)

W, H = 32, 24


pytestmark = pytest.mark.usefixtures("one_torch_thread")


K = np.array([[30.0, 0.0, 16.0], [0.0, 30.0, 12.0], [0.0, 0.0, 1.0]])
CAMERA = PinholeCamera.from_K(K, W, H)


def camera_pose(y: float, x: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:
    """T_world_cam at (x, y, 1.5) looking along +y turned by ``yaw_deg`` (OpenCV axes)."""
    a = np.radians(yaw_deg)
    forward = np.array([np.sin(a), np.cos(a), 0.0])
    right = np.array([np.cos(a), -np.sin(a), 0.0])
    pose = np.eye(4)
    pose[:3, :3] = np.stack([right, [0.0, 0.0, -1.0], forward], axis=1)
    pose[:3, 3] = (x, y, 1.5)
    return pose


def wall(tint: tuple[float, float, float]) -> gm.GaussianModel:
    x, z = np.meshgrid(np.arange(-6.0, 6.0, 0.12), np.arange(0.0, 3.0, 0.12))
    xyz = np.stack([x.ravel(), np.full(x.size, 8.0), z.ravel()], axis=1)
    rgb = np.stack([0.5 + 0.3 * np.sin(3 * x), 0.5 + 0.3 * np.cos(2 * z), 0.4 + 0.2 * x / 6], -1)
    rgb = np.clip(rgb.reshape(-1, 3) + np.asarray(tint), 0.0, 1.0)
    return gm.GaussianModel.from_points(
        torch.tensor(xyz, dtype=torch.float32),
        torch.tensor(rgb, dtype=torch.float32),
        sh_degree=1,
        opacity=0.9,
        scales=torch.full((len(xyz),), 0.1),
    )


def sky() -> gm.GaussianModel:
    pts = gm.sky_sphere_points(np.array([0.0, 3.0, 1.5]), 80.0, 300)
    return gm.GaussianModel.from_points(
        torch.tensor(pts, dtype=torch.float32),
        torch.tensor([[0.5, 0.7, 0.9]]).expand(len(pts), 3),
        sh_degree=0,
        opacity=0.9,
        scales=torch.full((len(pts),), 15.0),
    )


def write_chunk(
    models: Path,
    chunk_id: int,
    extent: tuple[float, float],
    tint: tuple[float, float, float],
    gains: list[float] | None = None,
    *,
    antialiased: bool = False,
    from_recorded: list[float] | None = None,
    pitch_deg: float | None = None,
) -> None:
    """A chunk with training views every 0.5 m of its extent; ``gains`` scale their colours;
    ``from_recorded``: every view's correction from the recorded poses (the preparation's);
    ``pitch_deg``: the views look that much down and keep their image-down axis (else none)."""
    p_rad = np.radians(pitch_deg or 0.0)
    forward = [0.0, float(np.cos(p_rad)), float(-np.sin(p_rad))]
    down = None if pitch_deg is None else [0.0, float(-np.sin(p_rad)), float(-np.cos(p_rad))]
    progress = np.arange(extent[0], extent[1] + 1e-9, 0.5)
    views = [
        gm.ViewRecord(
            index=round(p * 2),
            progress_m=float(p),
            position=[0.0, float(p), 1.5],
            forward=forward,
            down=down,
            from_recorded=from_recorded,
        )
        for p in progress
    ]
    gains = gains or [1.0] * len(views)
    appearance = torch.stack([g * torch.eye(3, 4) for g in gains])
    header = gm.ChunkHeader(
        chunk_id=chunk_id,
        start_m=extent[0],
        end_m=extent[1],
        sh_degree=1,
        n_gaussians=0,
        n_sky=300,
        scene_scale=1.0,
        sky_radius_m=80.0,
        background=[0.0, 0.0, 0.0],
        train_views=views,
        antialiased=antialiased,
    )
    chunk = gm.ChunkModel(header=header, gaussians=wall(tint), sky=sky(), appearance=appearance)
    gm.save_chunk_model(chunk, gm.chunk_model_path(models, chunk_id))


@pytest.fixture
def two_chunks(tmp_path: Path) -> Path:
    """Chunk 0 covers [0, 3] m (redder), chunk 1 [2, 5] m (bluer): they overlap on [2, 3]."""
    models = tmp_path / "models"
    write_chunk(models, 0, (0.0, 3.0), (0.06, 0.0, -0.06))
    write_chunk(models, 1, (2.0, 5.0), (-0.06, 0.0, 0.06))
    return models


def _cpu(**kwargs: object) -> RenderOptions:
    return RenderOptions(device="cpu", **kwargs)  # type: ignore[arg-type]


# ----------------------------------------------------------------------------------- tests


def test_chunk_weights_cross_over_smoothly() -> None:
    extents = [(0, 0.0, 3.0), (1, 2.0, 5.0), (2, 4.5, 8.0)]
    assert chunk_weights(extents, -1.0) == {0: 1.0}
    assert chunk_weights(extents, 1.0) == {0: 1.0}
    mid = chunk_weights(extents, 2.5)
    assert mid == pytest.approx({0: 0.5, 1: 0.5})
    assert chunk_weights(extents, 9.0) == {2: 1.0}
    path = np.linspace(-1.0, 9.0, 2001)
    table = np.array([[chunk_weights(extents, p).get(c, 0.0) for c in range(3)] for p in path])
    np.testing.assert_allclose(table.sum(axis=1), 1.0)
    steps = np.abs(np.diff(table, axis=0)).max()
    assert steps < 1.5 * (path[1] - path[0]) / 0.5 + 1e-9  # max slope of S over a 0.5 m ramp


def test_touching_chunks_switch_at_the_border() -> None:
    extents = [(0, 0.0, 2.0), (1, 2.0, 4.0)]
    assert chunk_weights(extents, 1.99) == {0: 1.0}
    assert chunk_weights(extents, 2.01) == {1: 1.0}
    assert smoothstep(-1.0) == 0.0
    assert smoothstep(0.5) == 0.5
    assert smoothstep(2.0) == 1.0


def test_render_hands_over_between_chunks_without_a_jump(two_chunks: Path) -> None:
    with SplatRenderer(two_chunks, options=_cpu(appearance="none")) as renderer:
        ys = np.arange(1.0, 4.0001, 0.1)
        frames = [renderer.render(camera_pose(y), CAMERA) for y in ys]
        # One chunk alone at the pose where both blend: the jump a hard switch would make.
        pose = camera_pose(2.5)
        camera = (
            torch.tensor(np.linalg.inv(pose), dtype=torch.float32),
            torch.tensor(K, dtype=torch.float32),
            torch.tensor(pose[:3, 3], dtype=torch.float32),
        )
        alone, _ = renderer._render_chunk(renderer._load(1), camera, (W, H), 2.5, "none")
    blended = frames[15].rgb.astype(float)
    jump = 2.0 * np.abs((alone.clamp(0, 1) * 255).round().numpy() - blended).mean()
    diffs = np.array(
        [np.abs(a.rgb.astype(float) - b.rgb.astype(float)).mean() for a, b in pairwise(frames)]
    )
    overlap = (ys[1:] > 2.0) & (ys[:-1] < 3.0)
    assert frames[0].chunk_weights == {0: 1.0}
    assert frames[-1].chunk_weights == {1: 1.0}
    assert set(frames[15].chunk_weights) == {0, 1}
    assert jump > 10.0  # the chunks really differ: a hard switch would jump this much
    assert diffs[overlap].max() < 0.3 * jump
    assert diffs[overlap].max() <= 2.0 * diffs[~overlap].max() + 1.0


def test_coverage_grows_with_distance_from_training_views(two_chunks: Path) -> None:
    with SplatRenderer(two_chunks, options=_cpu()) as renderer:
        lateral = [renderer.render(camera_pose(1.0, x=x), CAMERA) for x in (0, 0.25, 0.5, 1, 2, 4)]
        turned = [renderer.render(camera_pose(1.0, yaw_deg=a), CAMERA) for a in (0, 10, 30)]
    cov = [r.coverage for r in lateral]
    assert cov[0] == pytest.approx(0.0, abs=1e-9)
    assert all(a < b for a, b in pairwise(cov))
    assert cov[3] == pytest.approx(1 - np.exp(-0.5), abs=1e-6)  # 1 m = d0
    assert lateral[4].distance_m == pytest.approx(2.0)
    assert turned[0].coverage < turned[1].coverage < turned[2].coverage
    assert turned[2].angle_deg == pytest.approx(30.0, abs=1e-6)


def direct_render(models: Path, pose: np.ndarray, *, antialiased: bool = False) -> np.ndarray:
    """Chunk 0 of ``models`` rasterized directly at ``pose``: float RGB in 0-255, rounded."""
    chunk = gm.load_chunk_model(gm.chunk_model_path(models, 0))
    campos = torch.tensor(pose[None, :3, 3], dtype=torch.float32)
    inputs = gm.gather_splats(chunk.gaussians, chunk.sky, campos, 1)
    out = rasterize(
        inputs.means, inputs.quats, inputs.scales, inputs.opacities, inputs.colors,
        torch.tensor(np.linalg.inv(pose)[None], dtype=torch.float32),
        torch.tensor(K[None], dtype=torch.float32), W, H,
        backgrounds=torch.zeros(1, 4), backend="torch", antialiased=antialiased,
    )  # fmt: skip
    return np.asarray((out.colors[0, ..., :3].detach().clamp(0, 1) * 255).round().numpy())


def test_render_matches_direct_rasterization(two_chunks: Path) -> None:
    pose = camera_pose(0.7)
    with SplatRenderer(two_chunks, options=_cpu(appearance="none", street_alpha=True)) as r:
        result = r.render(pose, CAMERA)
    expected = direct_render(two_chunks, pose)
    assert np.abs(result.rgb.astype(float) - expected).max() <= 1.0
    assert result.rgb.dtype == np.uint8
    assert result.rgb.shape == (H, W, 3)
    assert result.street_alpha is not None
    assert result.street_alpha.shape == (H, W)
    assert result.street_alpha[H // 2].mean() > 0.9  # the wall fills the middle rows
    assert result.street_alpha[0].mean() < 0.1  # sky Gaussians draw the top rows
    with SplatRenderer(two_chunks, options=_cpu(appearance="none")) as r:
        fast = r.render(pose, CAMERA)
    assert fast.street_alpha is None
    assert np.abs(fast.rgb.astype(float) - result.rgb.astype(float)).max() <= 1.0


def test_a_model_trained_antialiased_is_rendered_antialiased(tmp_path: Path) -> None:
    pose = camera_pose(0.7)
    images = []
    for flag in (False, True):
        models = tmp_path / f"aa_{flag}"
        write_chunk(models, 0, (0.0, 2.0), (0.8, 0.3, 0.2), antialiased=flag)
        with SplatRenderer(models, options=_cpu(appearance="none")) as renderer:
            images.append(renderer.render(pose, CAMERA).rgb.astype(float))
        assert gm.load_chunk_header(gm.chunk_model_path(models, 0)).antialiased is flag
        expected = direct_render(models, pose, antialiased=flag)
        assert np.abs(images[-1] - expected).max() <= 1.0
    assert np.abs(images[0] - images[1]).max() > 2.0  # the filter changes what is drawn


def test_appearance_is_interpolated_between_training_views(tmp_path: Path) -> None:
    models = tmp_path / "models"
    write_chunk(models, 0, (0.0, 1.0), (0.0, 0.0, 0.0), gains=[0.5, 0.7, 1.0])
    with SplatRenderer(models, options=_cpu()) as renderer:
        pose = camera_pose(0.25)
        plain = renderer.render(pose, CAMERA, appearance="none").rgb.astype(float)
        tuned = renderer.render(pose, CAMERA).rgb.astype(float)
    bright = plain > 40
    assert np.median(tuned[bright] / plain[bright]) == pytest.approx(0.6, abs=0.02)


def test_recorded_poses_reach_the_model_through_the_views_corrections(tmp_path: Path) -> None:
    """Models trained at adjusted poses (0.4 m right of and 2 degrees left of the record, in the
    camera frame): a recorded pose renders what the adjusted pose shows; the evaluation, at the
    scene's own poses, asks for the model's frame."""
    models = tmp_path / "models"
    turn = np.radians(2.0)
    write_chunk(models, 0, (0.0, 3.0), (0.0, 0.0, 0.0), from_recorded=[0.0, -turn, 0.0, 0.4, 0, 0])
    recorded = camera_pose(1.0, x=-0.4)
    adjusted = camera_pose(1.0, yaw_deg=-2.0)  # camera y points down: -turn about it is a left turn
    with SplatRenderer(models, options=_cpu(appearance="none")) as renderer:
        mapped = renderer.render(recorded, CAMERA)
    with SplatRenderer(models, options=_cpu(appearance="none", pose_frame="model")) as renderer:
        at_adjusted = renderer.render(adjusted, CAMERA).rgb.astype(float)
        at_recorded = renderer.render(recorded, CAMERA).rgb.astype(float)
    assert np.abs(mapped.rgb.astype(float) - at_adjusted).max() <= 1.0
    assert np.abs(at_recorded - at_adjusted).mean() > 5.0  # the correction matters here
    assert mapped.distance_m < 0.05  # coverage is measured in the model: on a training view


def pitched(pose: np.ndarray, pitch_deg: float) -> np.ndarray:
    """``pose`` looking ``pitch_deg`` further down (about its own x axis)."""
    a = np.radians(pitch_deg)
    turn = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), np.sin(a)], [0.0, -np.sin(a), np.cos(a)]])
    out = pose.copy()
    out[:3, :3] = pose[:3, :3] @ turn
    return out


def test_vehicle_poses_take_the_views_height_and_tilt(tmp_path: Path) -> None:
    """Views 1.5 m up looking 4 degrees down; a planar car's camera 0.3 m too high and level
    (a GPS altitude, a road without pitch), turned 3 degrees: with ``pose_frame="vehicle"`` it
    renders what the views' height and tilt show at its own place and heading."""
    models = tmp_path / "models"
    write_chunk(models, 0, (0.0, 3.0), (0.0, 0.0, 0.0), pitch_deg=4.0)
    car = camera_pose(1.0, x=0.2, yaw_deg=3.0)
    car[2, 3] = 1.8
    expected = pitched(camera_pose(1.0, x=0.2, yaw_deg=3.0), 4.0)
    with SplatRenderer(models, options=_cpu(appearance="none", pose_frame="vehicle")) as renderer:
        as_vehicle = renderer.render(car, CAMERA).rgb.astype(float)
    with SplatRenderer(models, options=_cpu(appearance="none", pose_frame="model")) as renderer:
        want = renderer.render(expected, CAMERA).rgb.astype(float)
        as_given = renderer.render(car, CAMERA).rgb.astype(float)
    assert np.abs(as_vehicle - want).max() <= 1.0
    assert np.abs(as_given - want).mean() > 5.0  # height and tilt matter here


def test_chunks_load_lazily_and_are_evicted(two_chunks: Path) -> None:
    with SplatRenderer(two_chunks, options=_cpu(max_loaded=1)) as renderer:
        assert not renderer._loaded
        renderer.render(camera_pose(0.5), CAMERA)
        assert list(renderer._loaded) == [0]
        renderer.render(camera_pose(4.5), CAMERA)
        assert list(renderer._loaded) == [1]
    assert not renderer._loaded


def test_missing_models_and_bad_inputs_raise(tmp_path: Path, two_chunks: Path) -> None:
    with pytest.raises(WorkspaceError, match="no chunk models"):
        SplatRenderer(tmp_path / "empty")
    with SplatRenderer(two_chunks, options=_cpu()) as renderer, pytest.raises(ValueError):
        renderer.render(np.eye(3), CAMERA)
    distorted = PinholeCamera.from_K(K, W, H, (0.0, 0.0, 0.0, 0.0, 0.02))
    with (
        SplatRenderer(two_chunks, options=_cpu()) as renderer,
        pytest.raises(ValueError, match=r"distortion .*camera\.undistorted\(\)"),
    ):
        renderer.render(camera_pose(0.5), distorted)
