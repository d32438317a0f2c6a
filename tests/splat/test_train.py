"""Training and evaluation on a small synthetic street: ground, a wall, sky, a hood mask.

The scene is ray-cast exactly (textured ground plane z = 0, a wall at y = 9 m up to 3 m, sky
above), seen by cameras 1.5 m above the ground driving along +y; the points are sampled on the
surfaces with noisy colours. Everything runs on the CPU with the torch rasterizer.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("torch")

import torch
from gaussian_fixtures import check_aligned, model_and_adam

from cam2sim.core.errors import StageError
from cam2sim.splat import model as gm
from cam2sim.splat.densify import Densifier
from cam2sim.splat.evaluate import EvalOptions, SplatEval, evaluate_splat
from cam2sim.splat.raster import RasterOutput
from cam2sim.splat.scene import ChunkRecord, FrameRecord, SceneRecord, save_points
from cam2sim.splat.stop import plateau_reached, steps_that_fit, time_share
from cam2sim.splat.train import (
    MCMC_MIN_STEPS,
    STREET_SCALE_M,
    DensifyOptions,
    LearningRates,
    SceneTrainResult,
    TrainOptions,
    resolve_options,
    train_chunk,
    train_scene,
)

SKY = np.array([0.55, 0.7, 0.95])
WALL_Y, WALL_TOP = 9.0, 3.0
STEP_M = 0.25


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def ground_rgb(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.stack(
        [0.45 + 0.3 * np.sin(2.0 * x), 0.4 + 0.25 * np.cos(1.5 * y), 0.35 + 0.2 * np.sin(x + y)], -1
    )


def wall_rgb(x: np.ndarray, z: np.ndarray) -> np.ndarray:
    return np.stack(
        [0.5 + 0.4 * np.sin(1.3 * x), 0.5 + 0.4 * np.cos(2.1 * z), 0.4 + 0.3 * np.sin(0.7 * x + z)],
        -1,
    )


def camera_pose(y: float, x: float = 0.0) -> np.ndarray:
    """T_world_cam of a camera at (x, y, 1.5) looking along +y (OpenCV optical axes)."""
    pose = np.eye(4)
    pose[:3, :3] = [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]
    pose[:3, 3] = (x, y, 1.5)
    return pose


def ray_cast(pose: np.ndarray, k: np.ndarray, w: int, h: int) -> tuple[np.ndarray, np.ndarray]:
    """Exact image (uint8) and sky mask (bool) of the synthetic street."""
    j, i = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    rays = np.stack([(j - k[0, 2]) / k[0, 0], (i - k[1, 2]) / k[1, 1], np.ones_like(j)], -1)
    d = rays @ pose[:3, :3].T
    o = pose[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ground = np.where(d[..., 2] < 0, -o[2] / d[..., 2], np.inf)
        t_wall = np.where(d[..., 1] > 0, (WALL_Y - o[1]) / d[..., 1], np.inf)
    on_wall = o + np.where(np.isfinite(t_wall), t_wall, 0.0)[..., None] * d
    on_ground = o + np.where(np.isfinite(t_ground), t_ground, 0.0)[..., None] * d
    wall = np.isfinite(t_wall) & (t_wall < t_ground) & (on_wall[..., 2] <= WALL_TOP)
    ground = np.isfinite(t_ground) & ~wall
    out = np.broadcast_to(SKY, d.shape).copy()
    out[ground] = ground_rgb(on_ground[ground][:, 0], on_ground[ground][:, 1])
    out[wall] = wall_rgb(on_wall[wall][:, 0], on_wall[wall][:, 2])
    return (np.clip(out, 0, 1) * 255).round().astype(np.uint8), ~(ground | wall)


def make_prepared_scene(
    root: Path,
    *,
    n_frames: int = 12,
    chunks: tuple[tuple[int, int], ...] = ((0, 8), (4, 12)),
    size: tuple[int, int] = (64, 48),
    spacing: float = 0.25,
) -> Path:
    """Write ``root/splat/prep`` (scene.json, images, masks, sky, points.npz); frames 2, 6, ...
    are held out, the bottom 3 rows are masked as ego hood."""
    w, h = size
    prep = root / "splat" / "prep"
    for sub in ("images", "masks", "sky"):
        (prep / sub).mkdir(parents=True, exist_ok=True)
    k = np.array([[40.0 * w / 64, 0, w / 2], [0, 40.0 * h / 48, h / 2], [0, 0, 1]])
    frames = []
    for n in range(n_frames):
        pose = camera_pose(n * STEP_M)
        image, sky = ray_cast(pose, k, w, h)
        mask = np.full((h, w), 255, np.uint8)
        mask[h - 3 :] = 0
        stem = f"{n:06d}.png"
        cv2.imwrite(str(prep / "images" / stem), image[..., ::-1])
        cv2.imwrite(str(prep / "masks" / stem), mask)
        cv2.imwrite(str(prep / "sky" / stem), sky.astype(np.uint8) * 255)
        frames.append(
            FrameRecord(
                index=n,
                dataset_frame=n,
                stamp_ns=n * 100_000_000,
                T_world_cam=pose.tolist(),
                fx=k[0, 0],
                fy=k[1, 1],
                cx=k[0, 2],
                cy=k[1, 2],
                width=w,
                height=h,
                held_out=n % 4 == 2,
                chunks=[c for c, (a, b) in enumerate(chunks) if a <= n < b],
                progress_m=n * STEP_M,
            )
        )
    records = [
        ChunkRecord(
            id=c,
            start_m=a * STEP_M,
            end_m=(b - 1) * STEP_M,
            frames=list(range(a, b)),
            center=[0.0, (a + b - 1) / 2 * STEP_M, 1.5],
        )
        for c, (a, b) in enumerate(chunks)
    ]
    SceneRecord(frames=frames, chunks=records, pose_source="recording").save(prep / "scene.json")
    gx, gy = np.meshgrid(np.arange(-5, 5, spacing), np.arange(1.0, WALL_Y, spacing))
    wx, wz = np.meshgrid(np.arange(-7, 7, spacing), np.arange(0, WALL_TOP, spacing))
    ground = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], -1)
    wall = np.stack([wx.ravel(), np.full(wx.size, WALL_Y), wz.ravel()], -1)
    rgb = np.concatenate([ground_rgb(ground[:, 0], ground[:, 1]), wall_rgb(wall[:, 0], wall[:, 2])])
    rgb = np.clip(rgb + np.random.default_rng(0).normal(0, 0.15, rgb.shape), 0, 1)
    xyz = np.concatenate([ground, wall]).astype(np.float32)
    save_points(
        prep / "points.npz", xyz, (rgb * 255).astype(np.uint8), np.zeros(len(xyz), np.uint8)
    )
    return prep


def fast_options(**changes: object) -> TrainOptions:
    """Options that make a CPU run of a few dozen steps learn something."""
    base = TrainOptions(
        max_steps=40,
        min_steps=40,
        val_every=10,
        n_val_views=3,
        sh_degree=1,
        sh_degree_interval=25,
        sky_points=150,
        lr=LearningRates(means=1.6e-3, scales=1e-2, sh0=2e-2),
        densify=DensifyOptions(refine_start=15, refine_every=15, refine_stop=35, reset_every=1000),
        device="cpu",
    )
    return dataclasses.replace(base, **changes)  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, SceneTrainResult]:
    prep = make_prepared_scene(tmp_path_factory.mktemp("ws"))
    return prep, train_scene(prep, options=fast_options())


# ----------------------------------------------------------------------------------- tests


def test_training_raises_held_in_psnr(trained: tuple[Path, SceneTrainResult]) -> None:
    _, result = trained
    for chunk in result.chunks:
        first, last = chunk.val_history[0][1], chunk.val_history[-1][1]
        assert last > first + 2.0, chunk.val_history
        assert chunk.stopped == "max_steps"
        assert chunk.steps == 40


def test_every_chunk_is_written_with_its_header(trained: tuple[Path, SceneTrainResult]) -> None:
    prep, result = trained
    assert [c.chunk_id for c in result.chunks] == [0, 1]
    for chunk in result.chunks:
        assert chunk.model_path == prep.parent / "models" / f"chunk_{chunk.chunk_id:02d}.pt"
        header = gm.load_chunk_header(chunk.model_path)
        assert header.n_gaussians == chunk.n_gaussians
        assert [v.index for v in header.train_views] == [
            i for i in range(4 * chunk.chunk_id, 4 * chunk.chunk_id + 8) if i % 4 != 2
        ]
        assert header.backend == "torch"


def test_held_out_frames_reach_a_psnr_floor(trained: tuple[Path, SceneTrainResult]) -> None:
    prep, _ = trained
    result = evaluate_splat(
        prep,
        prep.parent / "models",
        offsets=(-1.0, 0.5, 2.0),
        options=EvalOptions(lpips=False, device="cpu"),
    )
    assert result.n_held_out == 3
    assert result.psnr_db.mean is not None
    assert result.psnr_db.mean > 24.0, result.frames
    assert result.ssim.mean is not None
    assert result.ssim.mean > 0.7
    assert result.lpips.n == 0
    assert result.psnr_db_raw is not None
    assert result.psnr_db_raw.n == 3
    coverage = {o.offset_m: o.coverage.mean or 0.0 for o in result.offsets}
    assert coverage[0.5] < coverage[-1.0] < coverage[2.0]
    assert all(0.0 <= (o.street_hole_fraction.mean or 0.0) <= 1.0 for o in result.offsets)
    assert SplatEval.load(prep.parent / "eval.json") == result


def test_evaluation_writes_the_held_out_renders_it_scored(
    trained: tuple[Path, SceneTrainResult], tmp_path: Path
) -> None:
    from cam2sim.core.images import read_rgb
    from cam2sim.splat.evaluate import frame_exclusion
    from cam2sim.splat.scores import score_pair

    prep, _ = trained
    renders = tmp_path / "renders"
    result = evaluate_splat(
        prep,
        prep.parent / "models",
        offsets=(),
        options=EvalOptions(lpips=False, device="cpu", renders_dir=renders),
        out_path=tmp_path / "eval.json",
    )
    scene = SceneRecord.load(prep / "scene.json")
    held = {f.index: f for f in scene.frames if f.held_out}
    assert sorted(p.name for p in renders.iterdir()) == [f"{i:06d}.webp" for i in sorted(held)]
    for row in result.frames:  # lossless: the written render scores exactly as the evaluation
        frame = held[row.index]
        real = read_rgb(prep / "images" / f"{row.index:06d}.png")
        render = read_rgb(renders / f"{row.index:06d}.webp")
        assert render.shape == real.shape
        again = score_pair(real, render, frame_exclusion(prep, frame), None)
        assert again.psnr == pytest.approx(row.psnr_db, abs=1e-9)


def test_chunk_model_roundtrips(trained: tuple[Path, SceneTrainResult], tmp_path: Path) -> None:
    _, result = trained
    loaded = gm.load_chunk_model(result.chunks[0].model_path)
    copy = tmp_path / "chunk_00.pt"
    gm.save_chunk_model(loaded, copy)
    again = gm.load_chunk_model(copy)
    assert again.header == loaded.header
    for a, b in ((loaded.gaussians, again.gaussians), (loaded.sky, again.sky)):
        for name in gm.PARAM_NAMES:
            torch.testing.assert_close(a.params[name], b.params[name], rtol=0, atol=0)
    torch.testing.assert_close(loaded.appearance, again.appearance, rtol=0, atol=0)


def test_ply_export_has_the_3dgs_layout(tmp_path: Path) -> None:
    xyz = torch.rand(5, 3)
    model = gm.GaussianModel.from_points(xyz, torch.rand(5, 3), sh_degree=2)
    sky = gm.GaussianModel.from_points(torch.rand(2, 3) + 5, torch.rand(2, 3), sh_degree=0)
    path = tmp_path / "m.ply"
    gm.export_ply(model, path, extra=sky)
    data = path.read_bytes()
    head, _, body = data.partition(b"end_header\n")
    lines = head.decode().splitlines()
    assert lines[:3] == ["ply", "format binary_little_endian 1.0", "element vertex 7"]
    names = [line.split()[-1] for line in lines if line.startswith("property")]
    assert names[:9] == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    assert names[9:33] == [f"f_rest_{i}" for i in range(24)]
    assert names[33:] == ["opacity", *(f"scale_{i}" for i in range(3))] + [
        f"rot_{i}" for i in range(4)
    ]
    table = np.frombuffer(body, dtype=[(n, "<f4") for n in names])
    np.testing.assert_allclose(table["x"][:5], xyz[:, 0].numpy())
    assert np.all(table["f_rest_0"][5:] == 0)


def test_plateau_stops_training(tmp_path: Path) -> None:
    prep = make_prepared_scene(tmp_path, n_frames=4, chunks=((0, 4),), size=(32, 24))
    scene = SceneRecord.load(prep / "scene.json")
    options = fast_options(
        max_steps=100,
        min_steps=4,
        val_every=2,
        patience=2,
        min_gain_db=1e6,  # per 1,000 steps: unreachable in 2-step intervals
        min_gain_ssim=1e6,
        sky_points=0,
    )
    result = train_chunk(scene, 0, prep, options, models_dir=tmp_path / "models")
    assert result.stopped == "plateau"
    assert result.steps == 6
    assert [s for s, *_ in result.val_history] == [2, 4, 6]
    assert all(0.0 < q <= 1.0 for *_, q in result.val_history)  # held-in SSIM
    assert (tmp_path / "models" / "chunk_00.json").is_file()


@pytest.mark.parametrize(
    ("n_chunks", "slots", "share"),
    [(1, 2, 600.0), (4, 1, 150.0), (4, 2, 300.0), (3, 2, 300.0), (4, 4, 600.0), (2, 8, 600.0)],
)
def test_time_share_divides_the_budget_by_the_rounds(
    n_chunks: int, slots: int, share: float
) -> None:
    assert time_share(600.0, n_chunks, slots) == pytest.approx(share)
    assert time_share(None, n_chunks, slots) is None
    assert time_share(600.0, n_chunks, slots, per_chunk=True) == 600.0


def test_steps_that_fit_follow_the_recent_pace() -> None:
    # 0.1 s a step since the start; 200 s left -> 2,000 more steps.
    assert steps_that_fit(1000, 100.0, 300.0, (0, 0.0)) == 3000
    # Since the last validation 500 steps took 40 s (0.08 s a step) -> 2,500 more.
    assert steps_that_fit(1000, 100.0, 300.0, (500, 60.0)) == 3500
    # A spent share, or no interval to measure: one more step, then the caller stops.
    assert steps_that_fit(1000, 310.0, 300.0, (500, 60.0)) == 1001
    assert steps_that_fit(1000, 100.0, 300.0, (1000, 100.0)) == 1001


def test_time_budget_ends_training_with_a_last_validation(tmp_path: Path) -> None:
    prep = make_prepared_scene(tmp_path, n_frames=4, chunks=((0, 4),), size=(32, 24))
    scene = SceneRecord.load(prep / "scene.json")
    # Neither the step cap nor the plateau can end this run: only the 1.5 s budget.
    options = fast_options(
        max_steps=1_000_000, min_steps=1_000_000, val_every=2, sky_points=0, time_budget_s=1.5
    )
    result = train_chunk(scene, 0, prep, options, models_dir=tmp_path / "models")
    assert result.stopped == "time"
    assert 2 < result.steps < 1_000_000
    assert result.val_history[-1][0] == result.steps  # scored where it stopped
    assert len(result.val_history) >= 2
    header = json.loads((tmp_path / "models" / "chunk_00.json").read_text())
    assert header["stopped"] == "time"


def test_unknown_chunk_is_refused(tmp_path: Path) -> None:
    prep = make_prepared_scene(tmp_path, n_frames=4, chunks=((0, 4),), size=(32, 24))
    with pytest.raises(StageError, match=r"no chunk \[7\]"):
        train_scene(prep, options=fast_options(), chunk_ids=(7,))


def test_invalid_options_are_refused() -> None:
    with pytest.raises(ValueError, match="sh_degree=4"):
        TrainOptions(sh_degree=4)
    with pytest.raises(ValueError, match="time_budget_s=0"):
        TrainOptions(time_budget_s=0)


# --------------------------------------------------------------------- densification surgery


def test_duplicate_split_remove_keep_optimizer_state_aligned() -> None:
    model, opts = model_and_adam()
    mask = torch.tensor([True, False, True, False, False, False])
    gm.duplicate(model, opts, mask)
    assert len(model) == 8
    check_aligned(model, opts)
    means_before = model.params["means"][1].clone()
    gm.split(model, opts, torch.tensor([False, True, False, False, False, False, False, True]))
    assert len(model) == 10
    check_aligned(model, opts)
    assert not torch.isclose(model.params["means"], means_before).all(dim=1).any()
    gm.remove(model, opts, torch.arange(10) < 3)
    assert len(model) == 7
    check_aligned(model, opts)


def test_opacity_reset_clamps_and_clears_moments() -> None:
    model, opts = model_and_adam()
    with torch.no_grad():
        model.params["opacities"][:3] = 5.0
    gm.reset_opacity(model, opts, 0.01)
    assert torch.sigmoid(model.params["opacities"]).max() <= 0.01 + 1e-6
    state = opts["opacities"].state[model.params["opacities"]]
    assert state["exp_avg"].abs().sum() == 0


def _views_of_two_gaussians(
    grads: list[tuple[float, float]],
    radii: list[tuple[int, int]],
    depths: list[tuple[float, float]],
) -> list[RasterOutput]:
    """One fake raster output per view: two Gaussians with these gradients (normalised screen
    units), screen radii (pixels, square boxes) and depths (metres)."""
    views = []
    for g, r, d in zip(grads, radii, depths, strict=True):
        means2d = torch.zeros(1, 2, 2, requires_grad=True)
        # grad * (width / 2) is the normalised gradient the statistics use (width = height = 2)
        means2d.grad = torch.tensor([[[g[0], 0.0], [g[1], 0.0]]])
        views.append(
            RasterOutput(
                colors=torch.zeros(1, 2, 2, 3),
                alphas=torch.zeros(1, 2, 2, 1),
                means2d=means2d,
                radii=torch.tensor([[[r[0], r[0]], [r[1], r[1]]]], dtype=torch.int32),
                depths=torch.tensor([d]),
                info={"width": 2, "height": 2, "n_cameras": 1},
                backend="torch",
            )
        )
    return views


@pytest.mark.parametrize(
    ("pixel_weighted", "near_damping", "grown"),
    [(False, 0.0, 0), (True, 0.0, 1), (True, 2.0, 0)],
)
def test_pixel_weighted_statistics_grow_gaussians_seen_large_in_few_views(
    pixel_weighted: bool, near_damping: float, grown: int
) -> None:
    # Gaussian 0: large (20 px) with a high gradient in one view at 5 m, one pixel with none in
    # nine views from afar; Gaussian 1: one pixel and a middling gradient everywhere.
    grads = [(1e-3, 1e-4)] + [(0.0, 1e-4)] * 9
    radii = [(20, 1)] + [(1, 1)] * 9
    depths = [(5.0, 30.0)] + [(40.0, 30.0)] * 9
    options = DensifyOptions(
        strategy="simple",
        refine_start=0,
        refine_every=10,
        grow_grad2d=2e-4,
        grow_scale3d=100.0,  # clone, never split: the count says how many grew
        pixel_weighted=pixel_weighted,
        near_damping=near_damping,
    )
    densifier = Densifier(options, scene_scale=10.0, use_gsplat=False)
    model, opts = model_and_adam(2)
    for step, out in enumerate(_views_of_two_gaussians(grads, radii, depths), start=1):
        densifier.post_backward(step, model, opts, out, 2, torch.Generator())
    # plain mean of Gaussian 0: 1e-4 (not grown); weighted: 400e-3 / 409 (grown) unless the
    # view that saw it large is damped by (5 m / (2 x 10 m))^2
    assert len(model) == 2 + grown
    check_aligned(model, opts)


@pytest.mark.parametrize(("max_steps", "reset"), [(None, True), (6000, True), (5999, False)])
def test_no_opacity_reset_too_close_to_the_end(max_steps: int | None, reset: bool) -> None:
    options = DensifyOptions(strategy="simple", refine_start=10_000, reset_every=3000)
    densifier = Densifier(options, scene_scale=10.0, use_gsplat=False, max_steps=max_steps)
    model, opts = model_and_adam(2)
    with torch.no_grad():
        model.params["opacities"][:] = 3.0
    out = _views_of_two_gaussians([(0.0, 0.0)], [(1, 1)], [(5.0, 5.0)])[0]
    densifier.post_backward(3000, model, opts, out, 2, torch.Generator())
    opacity = float(torch.sigmoid(model.params["opacities"].detach()).max())
    assert (opacity < 0.02) is reset


def test_broken_gaussians_are_made_transparent_and_then_pruned() -> None:
    # A NaN or inf parameter (as a degenerate covariance's gradient can give) must not reach
    # the refinement: MCMC's draw over the live opacities asserts on the GPU with a NaN in them.
    options = DensifyOptions(strategy="simple", refine_start=0, refine_every=10)
    densifier = Densifier(options, scene_scale=10.0, use_gsplat=False)
    model, opts = model_and_adam(6)
    with torch.no_grad():
        model.params["opacities"][:] = 2.0
        model.params["means"][1, 0] = float("nan")
        model.params["scales"][4, 2] = float("-inf")
    opts["means"].state[model.params["means"]]["exp_avg"][1] = float("nan")
    good = model.params["means"].detach()[[0, 2, 3, 5]].clone()
    means2d = torch.zeros(1, 6, 2, requires_grad=True)
    means2d.grad = torch.zeros(1, 6, 2)  # no growth
    out = RasterOutput(
        colors=torch.zeros(1, 2, 2, 3),
        alphas=torch.zeros(1, 2, 2, 1),
        means2d=means2d,
        radii=torch.ones(1, 6, 2, dtype=torch.int32),
        depths=torch.full((1, 6), 5.0),
        info={"width": 2, "height": 2, "n_cameras": 1},
        backend="torch",
    )
    # Not a refinement step: nothing is looked at.
    densifier.post_backward(5, model, opts, out, 6, torch.Generator())
    assert densifier.n_non_finite == 0
    with torch.no_grad():
        model.params["quats"][1] = float("nan")  # all four: nan_to_num alone would give 0
    assert gm.quench_non_finite(model, opts) == 2
    assert all(bool(torch.isfinite(p).all()) for p in model.params.values())
    # A unit quaternion (gsplat normalises by rsqrt of the norm: a zero one is NaN there),
    # and a small finite scale where it was -inf.
    quats = model.params["quats"].detach()
    torch.testing.assert_close(quats[[1, 4]], torch.tensor([[1.0, 0.0, 0.0, 0.0]] * 2))
    assert bool(torch.isfinite(quats * torch.rsqrt((quats**2).sum(dim=1, keepdim=True))).all())
    assert float(model.params["scales"].detach()[4, 2]) == gm.DEAD_LOG_SCALE
    opacity = torch.sigmoid(model.params["opacities"].detach()).flatten()
    assert float(opacity[[1, 4]].max()) < 1e-12
    assert float(opacity[[0, 2, 3, 5]].min()) > 0.8
    assert bool(torch.isfinite(opts["means"].state[model.params["means"]]["exp_avg"]).all())
    with torch.no_grad():  # broken again; the densifier's refinement step finds and prunes it
        model.params["quats"][3, 0] = float("inf")
    densifier.post_backward(10, model, opts, out, 6, torch.Generator())
    assert densifier.n_non_finite == 1
    assert len(model) == 3  # the three transparent ones pruned
    torch.testing.assert_close(model.params["means"].detach(), good[[0, 1, 3]])
    check_aligned(model, opts)


def test_sky_sphere_points_lie_on_the_sphere() -> None:
    pts = gm.sky_sphere_points(np.array([1.0, 2.0, 3.0]), 50.0, 500)
    np.testing.assert_allclose(np.linalg.norm(pts - [1.0, 2.0, 3.0], axis=1), 50.0)
    assert abs(pts[:, 2].mean() - 3.0) < 1.0


def test_nearest_neighbour_scales_match_brute_force() -> None:
    xyz = torch.rand(200, 3, dtype=torch.float64)
    d = torch.cdist(xyz, xyz)
    expected = torch.topk(d, 4, largest=False).values[:, 1:].mean(dim=1)
    torch.testing.assert_close(gm.nearest_neighbour_distances(xyz), expected)


def gsplat_training(tmp_path: Path, densify: DensifyOptions, **changes: object) -> SceneTrainResult:
    """600 gsplat steps on a 320x240 synthetic street (skips without gsplat)."""
    from cam2sim.splat.raster import has_gsplat

    if not has_gsplat():
        pytest.skip("gsplat is not installed (pip install 'cam2sim[splat-cuda]')")
    prep = make_prepared_scene(tmp_path, size=(320, 240), spacing=0.2)
    options = fast_options(
        max_steps=600, min_steps=600, val_every=100, device="cuda", backend="gsplat",
        densify=densify, **changes,
    )  # fmt: skip
    return train_scene(prep, options=options)


@pytest.mark.requires_cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_gsplat_training_densifies_and_resets(tmp_path: Path) -> None:
    # The synthetic street is ~1 m of driving: scene scale ~1 m, so allow 1 m Gaussians.
    result = gsplat_training(
        tmp_path,
        DensifyOptions(
            refine_start=50, refine_every=50, reset_every=300, refine_stop=450, prune_scale3d=1.0
        ),
    )
    for chunk in result.chunks:
        assert chunk.backend == "gsplat"
        assert chunk.val_history[0][1] > 25.0, chunk.val_history
        assert chunk.val_history[-1][1] > 25.0, chunk.val_history  # recovered from the reset
        assert chunk.n_gaussians != chunk.n_initial_gaussians  # the strategy cloned/split/pruned
        header = gm.load_chunk_header(chunk.model_path)
        assert header.n_gaussians == chunk.n_gaussians
    assert result.peak_memory_bytes is not None


def test_plateau_follows_the_trend_of_psnr_and_ssim() -> None:
    rising_ssim = [(1000, 28.0, 0.80), (2000, 28.6, 0.81), (3000, 28.1, 0.82), (4000, 28.3, 0.83)]
    # PSNR zig-zags with no trend, but SSIM still gains 0.01 per 1,000 steps: not a plateau.
    assert not plateau_reached(rising_ssim, 3, 0.05, 0.002)
    flat = [
        (s, 28.0 + (0.4 if i % 2 else 0.0), 0.85) for i, s in enumerate(range(1000, 6000, 1000))
    ]
    assert plateau_reached(flat, 4, 0.05, 0.002)
    # A steady PSNR gain of 0.2 dB per 1,000 steps under the swings is progress.
    steady = [
        (s, 28.0 + 0.2 * i + (0.3 if i % 2 else -0.3), 0.85)
        for i, s in enumerate(range(1000, 7000, 1000))
    ]
    assert not plateau_reached(steady, 5, 0.05, 0.002)
    assert not plateau_reached(flat[:4], 4, 0.05, 0.002)  # too few validations for a trend


def test_absgrad_needs_the_gsplat_rasterizer(tmp_path: Path) -> None:
    prep = make_prepared_scene(tmp_path, n_frames=4, chunks=((0, 4),), size=(32, 24))
    scene = SceneRecord.load(prep / "scene.json")
    options = fast_options(
        max_steps=2, densify=DensifyOptions(absgrad=True), backend="torch", device="cpu"
    )
    with pytest.raises(StageError, match="absgrad needs the gsplat rasterizer"):
        train_chunk(scene, 0, prep, options, models_dir=tmp_path / "models")


def test_auto_densification_is_mcmc_for_long_gsplat_runs_only() -> None:
    long = TrainOptions(max_steps=30_000, min_steps=7_000)
    mcmc = resolve_options(long, "gsplat")
    assert mcmc.densify.strategy == "mcmc"
    # MCMC's own start and no sky-share term; the whole schedule, no plateau stop.
    assert (mcmc.init_opacity, mcmc.sky_weight) == (0.5, 0.0)
    assert mcmc.min_steps == long.max_steps
    # Relocation until 25,000, then the scene's rates decay to a tenth; ground seeds.
    assert (mcmc.densify.refine_stop, mcmc.lr.tail, mcmc.ground_points) == (25_000, 0.1, 100_000)
    short = resolve_options(TrainOptions(max_steps=MCMC_MIN_STEPS - 1), "gsplat")
    budget = resolve_options(TrainOptions(time_budget_s=60.0), "gsplat")
    cpu = resolve_options(long, "torch")
    for options, strategy in ((short, "gsplat"), (budget, "gsplat"), (cpu, "simple")):
        assert options.densify.strategy == strategy
        assert (options.init_opacity, options.sky_weight) == (0.1, 0.05)
        assert (options.densify.refine_stop, options.lr.tail, options.ground_points) == (
            15_000,
            1.0,
            0,
        )
    assert cpu.min_steps == 7_000
    # What the caller set stays, with or without MCMC.
    chosen = resolve_options(
        replace(
            long,
            init_opacity=0.2,
            sky_weight=0.1,
            ground_points=0,
            lr=LearningRates(tail=1.0),
            densify=DensifyOptions(refine_stop=15_000),
        ),
        "gsplat",
    )
    assert (chosen.densify.strategy, chosen.init_opacity, chosen.sky_weight) == ("mcmc", 0.2, 0.1)
    assert (chosen.densify.refine_stop, chosen.lr.tail, chosen.ground_points) == (15_000, 1.0, 0)
    fixed = resolve_options(replace(long, densify=DensifyOptions(strategy="gsplat")), "gsplat")
    assert fixed.densify.strategy == "gsplat"
    off = resolve_options(replace(long, densify=DensifyOptions(enabled=False)), "gsplat")
    assert (off.init_opacity, off.sky_weight, off.min_steps) == (0.1, 0.05, 7_000)


def test_classic_training_learns_and_marks_its_models(tmp_path: Path) -> None:
    prep = make_prepared_scene(tmp_path)
    scene = SceneRecord.load(prep / "scene.json")
    assert TrainOptions().antialiased  # the default; the classic filter is the option
    options = fast_options(antialiased=False)
    result = train_chunk(scene, 0, prep, options, models_dir=tmp_path / "m")
    first, last = result.val_history[0][1], result.val_history[-1][1]
    assert last > first + 2.0, result.val_history
    assert last > 25.0, result.val_history
    assert not gm.load_chunk_header(result.model_path).antialiased


def test_mcmc_needs_the_gsplat_rasterizer(tmp_path: Path) -> None:
    prep = make_prepared_scene(tmp_path, n_frames=4, chunks=((0, 4),), size=(32, 24))
    scene = SceneRecord.load(prep / "scene.json")
    options = fast_options(
        max_steps=2, densify=DensifyOptions(strategy="mcmc"), backend="torch", device="cpu"
    )
    with pytest.raises(StageError, match="mcmc' needs the gsplat backend") as err:
        train_chunk(scene, 0, prep, options, models_dir=tmp_path / "models")
    assert "strategy='auto'" in str(err.value)  # the message names the fix


@pytest.mark.requires_cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
@pytest.mark.parametrize(("error_weight", "inherit"), [(0.0, False), (1.0, False), (0.0, True)])
def test_mcmc_training_grows_to_its_cap_and_learns(
    tmp_path: Path, error_weight: float, inherit: bool
) -> None:
    result = gsplat_training(
        tmp_path,
        DensifyOptions(
            strategy="mcmc",
            refine_start=50,
            refine_every=50,
            refine_stop=450,
            mcmc_cap=20_000,
            mcmc_error_weight=error_weight,
            mcmc_inherit_moments=inherit,
        ),
        # MCMC seeds 100,000 ground points by default: ~45,000 land in these views, above
        # the cap, and a model that starts above its cap never grows. 5,000 keep it below.
        ground_points=5_000,
    )
    for chunk in result.chunks:
        assert chunk.val_history[-1][1] > 25.0, chunk.val_history
        assert chunk.n_initial_gaussians < chunk.n_gaussians <= 20_000


def test_mcmc_warns_when_a_chunk_starts_at_its_cap(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    # MCMC needs gsplat; on CPU the trainer is stopped at its densifier, after the seeding.
    import cam2sim.splat.chunk_trainer as train_module
    import cam2sim.splat.densify as densify_module

    class StopAtDensifierError(Exception):
        pass

    def stop(*_args: object, **_kwargs: object) -> None:
        raise StopAtDensifierError

    monkeypatch.setattr(train_module, "_check_backend", lambda *_: None)
    monkeypatch.setattr(densify_module, "Densifier", stop)
    prep = make_prepared_scene(tmp_path, n_frames=8, chunks=((0, 8),), size=(48, 32))
    scene = SceneRecord.load(prep / "scene.json")
    for ground, warned in ((2_000, True), (0, False)):
        caplog.clear()
        options = fast_options(
            ground_points=ground, densify=DensifyOptions(strategy="mcmc", mcmc_cap=3_000)
        )
        with (
            caplog.at_level("WARNING", logger="cam2sim.splat.chunk_trainer"),
            pytest.raises(StopAtDensifierError),
        ):
            train_chunk(scene, 0, prep, options, models_dir=tmp_path / "models")
        messages = [r.getMessage() for r in caplog.records if "mcmc_cap=3000" in r.getMessage()]
        assert bool(messages) == warned, caplog.text
        if warned:  # it says why and what to change
            assert "never grows" in messages[0]
            assert "ground_points" in messages[0]


def test_coarse_to_fine_training_learns_and_validates_at_full_size(tmp_path: Path) -> None:
    prep = make_prepared_scene(tmp_path, n_frames=8, chunks=((0, 8),), size=(48, 32))
    scene = SceneRecord.load(prep / "scene.json")
    options = fast_options(coarse_levels=1, coarse_every=20)
    result = train_chunk(scene, 0, prep, options, models_dir=tmp_path / "models")
    assert result.steps == 40
    first, last = result.val_history[0][1], result.val_history[-1][1]
    assert last > first + 2.0, result.val_history
    with pytest.raises(ValueError, match="coarse_levels"):
        TrainOptions(coarse_levels=-1)


def test_scene_scale_is_metric_for_recordings_and_the_camera_spread_for_sfm(
    tmp_path: Path,
) -> None:
    prep = make_prepared_scene(tmp_path, n_frames=4, chunks=((0, 4),), size=(32, 24))
    scene = SceneRecord.load(prep / "scene.json")
    models = tmp_path / "models"

    def scale_of(scene: SceneRecord, **changes: object) -> float:
        options = fast_options(max_steps=2, **changes)
        result = train_chunk(scene, 0, prep, options, models_dir=models)
        return gm.load_chunk_header(result.model_path).scene_scale

    assert scale_of(scene) == STREET_SCALE_M
    assert scale_of(scene, scene_scale=3.5) == 3.5
    sfm = scene.model_copy(update={"scale_ambiguous": True, "pose_source": "sfm"})
    spread = scale_of(sfm)
    # Three training views 0.25 m apart: the spread rule, not the metric constant.
    assert 0.0 < spread < 1.0


def test_robust_weighting_trains_and_reports_what_it_left_out(tmp_path: Path) -> None:
    from cam2sim.splat.robust import RobustLoss

    prep = make_prepared_scene(tmp_path, n_frames=4, chunks=((0, 4),), size=(32, 24))
    scene = SceneRecord.load(prep / "scene.json")
    robust = RobustLoss(quantile=0.8, after_steps=10, patch=8)
    result = train_chunk(
        scene, 0, prep, fast_options(robust=robust, sky_points=0), models_dir=tmp_path / "m"
    )
    assert result.steps == 40
    assert result.robust_outlier_share is not None
    assert 0.0 <= result.robust_outlier_share < 0.2  # blobs only: a static scene has few
    plain = train_chunk(scene, 0, prep, fast_options(sky_points=0), models_dir=tmp_path / "p")
    assert plain.robust_outlier_share is None
    assert result.best_val_psnr_db is not None
    assert plain.best_val_psnr_db is not None
    assert result.best_val_psnr_db > plain.best_val_psnr_db - 1.0  # no worse on a static scene
    # The views it left out most, kept as a picture beside the model (2 x 2 frames of 32 x 24).
    picture = cv2.imread(str(tmp_path / "m" / "chunk_00_outliers.jpg"))
    assert picture is not None
    assert picture.shape == (48, 64, 3)
    assert not (tmp_path / "p" / "chunk_00_outliers.jpg").exists()


def test_pose_refinement_learns_small_corrections_and_writes_them_back(tmp_path: Path) -> None:
    from cam2sim.splat.model import load_chunk_model

    prep = make_prepared_scene(tmp_path, n_frames=4, chunks=((0, 4),), size=(32, 24))
    scene = SceneRecord.load(prep / "scene.json")
    lr = LearningRates(means=1.6e-3, scales=1e-2, sh0=2e-2, poses=1e-3)
    result = train_chunk(
        scene, 0, prep, fast_options(lr=lr, sky_points=0), models_dir=tmp_path / "m"
    )
    assert result.pose_correction is not None
    mean_t, max_t, mean_r, max_r = result.pose_correction
    assert 0.0 < mean_t <= max_t < 0.5  # moved, but not far: 40 steps of 1e-3
    assert 0.0 < mean_r <= max_r < 5.0
    plain = train_chunk(scene, 0, prep, fast_options(sky_points=0), models_dir=tmp_path / "p")
    assert plain.pose_correction is None
    moved = load_chunk_model(result.model_path).header.train_views
    kept = load_chunk_model(plain.model_path).header.train_views
    shifts = [
        np.linalg.norm(np.subtract(a.position, b.position))
        for a, b in zip(moved, kept, strict=True)
    ]
    assert 0.0 < max(shifts) <= max_t + 1e-6
    assert all(v.correction is not None and len(v.correction) == 6 for v in moved)
    assert all(v.correction is None for v in kept)


def test_ground_seeds_join_the_starting_model(tmp_path: Path) -> None:
    prep = make_prepared_scene(tmp_path)
    scene = SceneRecord.load(prep / "scene.json")
    plain = train_chunk(scene, 0, prep, fast_options(max_steps=2), models_dir=tmp_path / "a")
    seeded = train_chunk(
        scene, 0, prep, fast_options(max_steps=2, ground_points=3000), models_dir=tmp_path / "b"
    )
    added = seeded.n_initial_gaussians - plain.n_initial_gaussians
    assert 2500 <= added <= 3000
    assert f"{added} ground seeds" in gm.load_chunk_header(seeded.model_path).notes


def test_scene_rates_decay_to_the_tail_after_densification(tmp_path: Path) -> None:
    from cam2sim.splat.chunk_trainer import ChunkTrainer
    from cam2sim.splat.scene import load_points

    prep = make_prepared_scene(tmp_path, n_frames=4, chunks=((0, 4),), size=(32, 24))
    scene = SceneRecord.load(prep / "scene.json")
    lr = LearningRates(means=1.6e-3, scales=1e-2, sh0=2e-2, tail=0.1)
    options = fast_options(lr=lr, sky_points=20)  # densification stops at 35 of 40 steps
    xyz, rgb, _ = load_points(prep / "points.npz")
    trainer = ChunkTrainer(scene.chunks[0], scene, prep, (xyz, rgb), options, "cpu", "torch")

    def rates() -> dict[str, float]:
        got = {n: o.param_groups[0]["lr"] for n, o in trainer.optimizers.items()}
        got["sky"] = trainer.extra_optimizers[0].param_groups[0]["lr"]
        got["appearance"] = trainer.extra_optimizers[-1].param_groups[0]["lr"]
        return got

    start = rates()
    while trainer.step_no < 35:
        trainer.step()
    assert {k: v for k, v in rates().items() if k != "means"} == {
        k: v for k, v in start.items() if k != "means"
    }  # constant while densifying
    while not trainer.done:
        trainer.step()
    end = rates()
    for name in ("scales", "quats", "opacities", "sh0", "shN", "sky", "appearance"):
        assert end[name] == pytest.approx(0.1 * start[name]), name
    assert end["means"] == pytest.approx(0.01 * start["means"], rel=1e-3)  # their own decay
    header = gm.load_chunk_header(trainer.save(tmp_path / "models").model_path)
    assert "learning rates to 0.1x after densification (the per-view colour" in " ".join(
        header.notes
    )
    # Every validation is in the header, for the report's training curve.
    assert header.val_history == [tuple(v) for v in trainer.state.history]
    assert [step for step, _, _ in header.val_history][-1] == trainer.step_no


def test_the_per_view_transforms_keep_their_rate_without_tail_views(tmp_path: Path) -> None:
    from cam2sim.splat.chunk_trainer import ChunkTrainer
    from cam2sim.splat.scene import load_points

    prep = make_prepared_scene(tmp_path, n_frames=4, chunks=((0, 4),), size=(32, 24))
    scene = SceneRecord.load(prep / "scene.json")
    lr = LearningRates(sh0=2e-2, tail=0.1, tail_views=False, poses=1e-4)
    options = fast_options(lr=lr, sky_points=20)
    xyz, rgb, _ = load_points(prep / "points.npz")
    trainer = ChunkTrainer(scene.chunks[0], scene, prep, (xyz, rgb), options, "cpu", "torch")
    start = [o.param_groups[0]["lr"] for o in trainer.extra_optimizers]
    while not trainer.done:
        trainer.step()
    sky, appearance, poses = (o.param_groups[0]["lr"] for o in trainer.extra_optimizers)
    assert sky == pytest.approx(0.1 * start[0])  # the sky is part of the scene
    assert (appearance, poses) == (start[1], start[2])
    notes = " ".join(gm.load_chunk_header(trainer.save(tmp_path / "models").model_path).notes)
    assert "after densification" in notes
    assert "per-view colour" not in notes


def test_training_clears_the_drives_path_of_gaussians(tmp_path: Path) -> None:
    from cam2sim.splat.model import load_chunk_model
    from cam2sim.splat.scene import load_points

    prep = make_prepared_scene(tmp_path, n_frames=8, chunks=((0, 8),), size=(48, 36))
    # Plant opaque points on the cameras' path (1.5 over the ground, x = 0, moving along y):
    # nothing of a street is there, the car was.
    xyz, rgb, labels = load_points(prep / "points.npz")
    planted = np.stack([np.zeros(10), np.linspace(0.4, 1.6, 10), np.full(10, 1.5)], -1)
    save_points(
        prep / "points.npz",
        np.concatenate([xyz, planted]).astype(np.float32),
        np.concatenate([rgb, np.full((10, 3), 255, np.uint8)]),
        np.concatenate([labels, np.zeros(10, np.uint8)]),
    )
    scene = SceneRecord.load(prep / "scene.json")
    result = train_chunk(
        scene, 0, prep, fast_options(clear_path=0.5), models_dir=tmp_path / "models"
    )
    chunk = load_chunk_model(result.model_path)
    notes = " ".join(chunk.header.notes)
    assert "cleared from the drive's path (radius 0.75 scene units)" in notes  # 0.5 x 1.5 m
    cleared = int(notes.split(" Gaussians cleared")[0].split()[-1])
    assert cleared >= 10
    means = chunk.gaussians.params["means"].detach()
    opacity = torch.sigmoid(chunk.gaussians.params["opacities"].detach())
    on_path = (means[:, 0].abs() < 0.5) & ((means[:, 2] - 1.5).abs() < 0.5)
    on_path &= (means[:, 1] > 0.0) & (means[:, 1] < 1.75)
    assert float(torch.cat([opacity[on_path], torch.zeros(1)]).max()) < 0.01
    plain = train_chunk(scene, 0, prep, fast_options(), models_dir=tmp_path / "plain")
    assert "cleared" not in " ".join(load_chunk_model(plain.model_path).header.notes)


def test_a_nan_gradient_does_not_enter_the_model(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # One step whose loss (so every gradient) is NaN: the update treats it as zero gradient,
    # the model and its colour transforms stay finite and go on learning, the step is counted.
    import cam2sim.splat.chunk_trainer as train_module

    real = train_module.photometric_loss
    calls = {"n": 0}

    def sometimes_nan(*args: object, **kwargs: object) -> torch.Tensor:
        calls["n"] += 1
        loss = real(*args, **kwargs)  # type: ignore[arg-type]
        return loss * float("nan") if calls["n"] in (5, 6) else loss

    monkeypatch.setattr(train_module, "photometric_loss", sometimes_nan)
    prep = make_prepared_scene(tmp_path, n_frames=8, chunks=((0, 8),), size=(48, 32))
    scene = SceneRecord.load(prep / "scene.json")
    result = train_chunk(scene, 0, prep, fast_options(), models_dir=tmp_path / "models")
    assert result.non_finite_steps == 2
    model = gm.load_chunk_model(result.model_path)
    for p in model.gaussians.params.values():
        assert torch.isfinite(p).all()
    assert torch.isfinite(model.appearance).all()
    first, last = result.val_history[0][1], result.val_history[-1][1]
    assert last > first + 2.0, result.val_history
    assert any("NaN or inf gradient values on 2 steps" in n for n in model.header.notes)


def test_a_diverged_chunk_stops_with_an_error_and_writes_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Every loss NaN from step 3 on: most steps' gradients are non-finite, so the chunk has
    # diverged; it stops at the next validation and leaves no model a drive could load.
    import cam2sim.splat.chunk_trainer as train_module

    real = train_module.photometric_loss
    calls = {"n": 0}

    def diverging(*args: object, **kwargs: object) -> torch.Tensor:
        calls["n"] += 1
        loss = real(*args, **kwargs)  # type: ignore[arg-type]
        return loss * float("nan") if calls["n"] >= 3 else loss

    monkeypatch.setattr(train_module, "photometric_loss", diverging)
    prep = make_prepared_scene(tmp_path, n_frames=8, chunks=((0, 8),), size=(48, 32))
    scene = SceneRecord.load(prep / "scene.json")
    with pytest.raises(
        StageError, match=r"splat chunk 0 diverged at step 10: NaN or inf gradients on 8 steps"
    ):
        train_chunk(scene, 0, prep, fast_options(), models_dir=tmp_path / "models")
    assert not (tmp_path / "models").exists() or not any((tmp_path / "models").iterdir())


@pytest.mark.parametrize(
    ("skipped", "steps", "psnr", "expected"),
    [(0, 100, 20.0, False), (2, 40, 20.0, False), (50, 100, 20.0, False), (51, 100, 20.0, True),
     (0, 100, float("nan"), True), (1, 0, 20.0, True)],
)  # fmt: skip
def test_the_divergence_rule(skipped: int, steps: int, psnr: float, expected: bool) -> None:
    from cam2sim.splat.stop import diverged

    assert diverged(skipped, steps, psnr) is expected
