"""The splat models scored against the ground truth, on and off the recorded path.

A street workspace whose ground-truth world is the same street with a parked car and two
buildings; the "recording" is its truth camera driving along the street (with sensor noise, as
recorded), the points are sampled on its surfaces and coloured from the frames, and a few dozen
CPU steps train a model. A drive with the splat camera then records the splat's quality.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("torch")

from test_train import fast_options

from cam2sim.core.camera import PinholeCamera
from cam2sim.render.truth import TruthBuilding, TruthCar, TruthRenderer, TruthWorld
from cam2sim.scenario.synthetic import StreetSpec, synthetic_street
from cam2sim.splat.envelope import (
    TruthEnvelopeOptions,
    TruthReference,
    even_picks,
    perturbed_pose,
)
from cam2sim.splat.evaluate import EvalOptions, SplatEval, evaluate_splat
from cam2sim.splat.scene import ChunkRecord, FrameRecord, SceneRecord, save_points
from cam2sim.splat.train import train_scene
from conftest import has_egl, street_workspace

pytestmark = [
    pytest.mark.usefixtures("one_torch_thread"),
    pytest.mark.skipif(not has_egl(), reason="no headless OpenGL (EGL) for the truth camera"),
]

W, H = 64, 40
K = np.array([[36.0, 0.0, W / 2], [0.0, 36.0, H / 2], [0.0, 0.0, 1.0]])
CAMERA = PinholeCamera.from_K(K, W, H)
CAR = TruthCar(x=18.0, y=-4.0, yaw=0.0, length=4.5, width=1.9, height=1.5)
BUILDINGS = (
    TruthBuilding(xy=((6.0, 9.0), (26.0, 9.0), (26.0, 17.0), (6.0, 17.0)), height_m=9.0),
    TruthBuilding(xy=((10.0, -17.0), (34.0, -17.0), (34.0, -9.0), (10.0, -9.0)), height_m=7.0),
)


def truth_world() -> TruthWorld:
    _, xodr = synthetic_street(StreetSpec(length_m=40.0, parked=()))
    return TruthWorld(
        crs="EPSG:32632", origin=(0.0, 0.0), xodr=xodr, cars=(CAR,), buildings=BUILDINGS
    )


def camera_at(x: float, y: float = 0.0) -> np.ndarray:
    """T_world_cam 1.4 m above the road at (x, y), looking along +x (optical axes)."""
    T = np.eye(4)
    T[:3, :3] = [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]
    T[:3, 3] = (x, y, 1.4)
    return T


def _surface_points() -> np.ndarray:
    """Points on the road plane, the car box and the buildings' street facades."""
    g = np.mgrid[0.0:40.0:0.4, -12.0:12.0:0.4].reshape(2, -1).T
    ground = np.column_stack([g, np.zeros(len(g))])
    s = np.mgrid[-0.5:0.5:0.1, -0.5:0.5:0.1, 0.0:1.0:0.1].reshape(3, -1).T
    car = s * [CAR.length, CAR.width, CAR.height] + [CAR.x, CAR.y, CAR.height / 2]
    facades = []
    for b, y in zip(BUILDINGS, (9.0, -9.0), strict=True):
        xs = np.asarray(b.xy)[:, 0]
        f = np.mgrid[xs.min() : xs.max() : 0.4, 0.0 : b.height_m : 0.4].reshape(2, -1).T
        facades.append(np.column_stack([f[:, 0], np.full(len(f), y), f[:, 1]]))
    return np.concatenate([ground, car, *facades])


def _colours(xyz: np.ndarray, frames: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """Each point's colour in the first frame that sees it (grey where none does)."""
    rgb = np.full((len(xyz), 3), 128, np.uint8)
    todo = np.ones(len(xyz), bool)
    for T, image in frames:
        cam = (np.linalg.inv(T) @ np.column_stack([xyz, np.ones(len(xyz))]).T).T[:, :3]
        z = np.maximum(cam[:, 2], 1e-6)
        u, v = K[0, 0] * cam[:, 0] / z + K[0, 2], K[1, 1] * cam[:, 1] / z + K[1, 2]
        seen = todo & (cam[:, 2] > 0.5) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
        rgb[seen] = image[v[seen].astype(int), u[seen].astype(int)]
        todo &= ~seen
    return rgb


def recorded_scene(root: Path, world: TruthWorld) -> Path:
    """``root/splat/prep`` of a drive along the street every 0.5 m; every 4th frame held out."""
    from cam2sim.render.meshes import Label

    prep = root / "splat" / "prep"
    for sub in ("images", "masks", "sky"):
        (prep / sub).mkdir(parents=True, exist_ok=True)
    xs = np.arange(4.0, 24.01, 0.5)
    frames, seen = [], []
    with TruthRenderer(world, None) as camera:
        for n, x in enumerate(xs):
            T = camera_at(float(x))
            shot = camera.render(T, CAMERA)  # as recorded: with sensor noise
            stem = f"{n:06d}.png"
            cv2.imwrite(str(prep / "images" / stem), shot.rgb[..., ::-1])
            cv2.imwrite(str(prep / "masks" / stem), np.full((H, W), 255, np.uint8))
            sky = (shot.labels == Label.SKY).astype(np.uint8) * 255
            cv2.imwrite(str(prep / "sky" / stem), sky)
            seen.append((T, shot.rgb))
            frames.append(
                FrameRecord(
                    index=n, dataset_frame=n, stamp_ns=n * 62_500_000, T_world_cam=T.tolist(),
                    fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], width=W, height=H,
                    held_out=n % 4 == 2, chunks=[0], progress_m=float(x - xs[0]),
                )
            )  # fmt: skip
    chunk = ChunkRecord(
        id=0,
        start_m=0.0,
        end_m=float(xs[-1] - xs[0]),
        frames=list(range(len(xs))),
        center=[float(xs.mean()), 0.0, 1.4],
    )
    SceneRecord(frames=frames, chunks=[chunk], pose_source="recording").save(prep / "scene.json")
    xyz = _surface_points()
    lidar = np.ones(len(xyz), np.uint8)
    save_points(prep / "points.npz", xyz.astype(np.float32), _colours(xyz, seen), lidar)
    return prep


@pytest.fixture(scope="module")
def scored(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, SplatEval]:
    """A street workspace (scenario: the same street) with trained, evaluated splat models."""
    world = truth_world()
    ws = street_workspace(tmp_path_factory.mktemp("ws") / "ws", StreetSpec(length_m=40.0))
    prep = recorded_scene(ws.root, world)
    train_scene(prep, options=fast_options(max_steps=60, min_steps=60, sky_points=100))
    calls: list[tuple[str, int, int | None]] = []
    with TruthRenderer(world, None) as camera:
        truth = TruthReference(camera, options=TruthEnvelopeOptions(max_frames=5))
        result = evaluate_splat(
            prep,
            prep.parent / "models",
            offsets=(-1.0, 1.0),
            options=EvalOptions(lpips=False, compare_appearance=False, device="cpu"),
            truth=truth,
            progress=lambda *a: calls.append(a),
        )
    envelope = [c for c in calls if c[0] == "splat truth envelope"]
    assert envelope[-1][1:] == (45, 45)  # 5 frames x 9 poses
    return prep, result


def test_the_truth_envelope_scores_every_offset_and_turn(scored: tuple[Path, SplatEval]) -> None:
    _, result = scored
    truth = result.truth
    assert truth is not None
    labels = [row.label() for row in truth.scores]
    assert labels == [
        "on path", "-2 m", "-1 m", "-0.5 m", "+0.5 m", "+1 m", "+2 m", "yaw -5 deg", "yaw +5 deg",
    ]  # fmt: skip
    assert len(truth.frames) == 5
    assert not truth.sensor_noise
    assert all(row.psnr_db.n == row.ssim.n == 5 for row in truth.scores)
    assert all(row.lpips.n == 0 for row in truth.scores)  # LPIPS off
    assert truth.lpips_net is None


def test_on_the_path_the_splat_is_closer_to_the_truth_than_two_metres_off(
    scored: tuple[Path, SplatEval],
) -> None:
    _, result = scored
    assert result.truth is not None
    rows = {row.label(): row for row in result.truth.scores}
    on, left, right = rows["on path"], rows["-2 m"], rows["+2 m"]
    for off in (left, right):
        assert on.psnr_db.mean is not None
        assert off.psnr_db.mean is not None
        assert on.ssim.mean is not None
        assert off.ssim.mean is not None
        assert on.psnr_db.mean > off.psnr_db.mean + 1.0, (on.psnr_db, off.psnr_db)
        assert on.ssim.mean > off.ssim.mean, (on.ssim, off.ssim)
        assert on.coverage.mean is not None
        assert off.coverage.mean is not None
        assert off.coverage.mean > on.coverage.mean  # further from the training views


def test_eval_json_round_trips_with_and_without_the_truth_section(
    scored: tuple[Path, SplatEval], tmp_path: Path
) -> None:
    prep, result = scored
    assert SplatEval.load(prep.parent / "eval.json") == result
    old = json.loads((prep.parent / "eval.json").read_text(encoding="utf-8"))
    del old["truth"]  # as written before the section existed
    (tmp_path / "old.json").write_text(json.dumps(old), encoding="utf-8")
    loaded = SplatEval.load(tmp_path / "old.json")
    assert loaded.truth is None
    assert loaded.psnr_db == result.psnr_db
    without = result.model_copy(update={"truth": None})
    without.save(tmp_path / "none.json")
    assert SplatEval.load(tmp_path / "none.json") == without


def test_a_perturbed_pose_moves_right_and_turns_left_about_the_vertical() -> None:
    T = camera_at(5.0, 1.0)
    right = perturbed_pose(T, lateral_m=0.5)
    assert np.allclose(right[:3, 3], [5.0, 0.5, 1.4])  # looking along +x, right is -y
    assert np.allclose(right[:3, :3], T[:3, :3])
    left = perturbed_pose(T, yaw_deg=90.0)
    assert np.allclose(left[:3, 3], T[:3, 3])
    assert np.allclose(left[:3, 2], [0.0, 1.0, 0.0])  # now looking along +y
    assert np.allclose(left[:3, 1], T[:3, 1])  # still upright
    assert even_picks(10, 4) == [0, 3, 6, 9]
    assert even_picks(3, 12) == [0, 1, 2]
    # The relative offsets are taken on the frames the truth envelope picks (renders reused).
    assert EvalOptions().max_offset_frames == TruthEnvelopeOptions().max_frames


def test_a_drive_with_the_splat_camera_records_its_quality_and_the_gate(
    scored: tuple[Path, SplatEval],
) -> None:
    from cam2sim.core.workspace import Workspace
    from cam2sim.metrics.drive_io import load_run_dir
    from cam2sim.stages.runs import DriveOptions, drive

    prep, result = scored
    ws = Workspace.open(prep.parent.parent)
    options = DriveOptions(camera="splat", image_size=(W, H), max_steps=45)
    (run,) = drive(ws, options=options)
    meta = json.loads((run.folder / "run.json").read_text(encoding="utf-8"))
    quality, gate = meta["splat_quality"], meta["splat_gate"]
    assert quality["frames"] == 15  # every 3rd of 45 steps
    assert 0.0 <= quality["coverage_mean"] <= quality["coverage_max"] <= 1.0
    assert quality["held_out_psnr_db"] == pytest.approx(result.psnr_db.mean)
    assert result.truth is not None
    on_path = result.truth.on_path()
    assert on_path is not None
    assert quality["truth_ssim"] == pytest.approx(on_path.ssim.mean)
    assert len(quality["truth_envelope"]) == 9
    assert gate["fit"] == (gate["failures"] == [])
    loaded = load_run_dir(run.folder)
    assert loaded.method == "drive-splat"
    assert loaded.splat_quality is not None
    assert loaded.splat_quality.frames == 15


class _BandPolicy:
    """Steers straight and keeps what it saw; reads only rows ``rows`` of each frame."""

    name = "band"
    needs_image = True

    def __init__(self, rows: tuple[int, int]) -> None:
        self.rows = rows
        self.seen: list[np.ndarray] = []

    def image_rows(self, height: int) -> tuple[int, int]:
        assert height == H
        return self.rows

    def reset(self) -> None:
        self.seen.clear()

    def predict(self, obs: object) -> float:
        self.seen.append(np.array(obs.image))  # type: ignore[attr-defined]
        return 0.0

    def close(self) -> None:
        pass


def test_a_policy_that_reads_a_band_gets_the_splat_camera_render_only_that_band(
    scored: tuple[Path, SplatEval], monkeypatch: pytest.MonkeyPatch
) -> None:
    import cam2sim.ads.policy as policies
    from cam2sim.core.workspace import Workspace
    from cam2sim.stages.runs import DriveOptions, drive

    prep, _ = scored
    ws = Workspace.open(prep.parent.parent)
    rows = (H // 3, 2 * H // 3)
    policy = _BandPolicy(rows)
    monkeypatch.setattr(policies, "load_policy", lambda *_a, **_k: policy)
    (banded,) = drive(ws, options=DriveOptions(camera="splat", image_size=(W, H), max_steps=9))
    band_frames = list(policy.seen)
    # Kept frames are what people look at: whole frames then.
    options = DriveOptions(camera="splat", image_size=(W, H), max_steps=9, save_frames=True)
    (whole,) = drive(ws, options=options)
    assert len(band_frames) == len(policy.seen) == 3
    for band, full in zip(band_frames, policy.seen, strict=True):
        assert band.shape == full.shape == (H, W, 3)
        np.testing.assert_array_equal(band[rows[0] : rows[1]], full[rows[0] : rows[1]])
        assert not band[: rows[0]].any()
        assert not band[rows[1] :].any()
        assert full[: rows[0]].any()  # the whole frame has something there
    meta = json.loads((banded.folder / "run.json").read_text(encoding="utf-8"))
    assert meta["rendered_rows"] == list(rows)
    assert "rendered_rows" not in json.loads((whole.folder / "run.json").read_text("utf-8"))
