"""Splat preparation: frame selection, chunks, undistortion, and prepare_scene end to end."""

from __future__ import annotations

import itertools
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from cam2sim.core import frames
from cam2sim.core.config import Config
from cam2sim.core.dataset import (
    LIDAR_COLUMNS,
    POSE_COLUMNS,
    POSE_PRECISION,
    Calibration,
    CameraIntrinsics,
    DatasetCounts,
    DatasetInfo,
    MountRecord,
)
from cam2sim.core.errors import StageError
from cam2sim.core.table import write_table
from cam2sim.core.workspace import DatasetPaths, Workspace, WorldFrameRecord
from cam2sim.splat.prepare import (
    PREP_DIR,
    PrepareOptions,
    camera_poses,
    chunks_by_distance,
    distance_travelled,
    prepare_scene,
    select_by_distance,
    undistorter,
    voxel_downsample,
)
from cam2sim.splat.scene import SceneRecord, load_points

W, H = 240, 180
K = np.array([[170.0, 0.0, 120.0], [0.0, 170.0, 90.0], [0.0, 0.0, 1.0]])
HOOD_ROWS = 22
SKY = np.array([110, 170, 240], np.uint8)
# The camera looks to the vehicle's left (+y): image right = body forward, image down = body down.
LEFT_CAMERA = MountRecord(
    translation_m=(0.0, 0.0, 1.5),
    quat_xyzw=tuple(
        float(v)
        for v in frames.quat_from_matrix(np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]]))
    ),
    axes="optical",
    source="config",
)
# Walls beside the road (world frame, the car drives along +x): origin, axis a, axis b, m/texel.
WALLS = (
    (np.array([-8.0, 11.0, 3.5]), np.array([1.0, 0, 0]), np.array([0, 0, -1.0]), 0.05),
    (np.array([0.5, 6.0, 2.2]), np.array([1.0, 0, 0]), np.array([0, 0, -1.0]), 0.012),
)


# -- pure helpers ------------------------------------------------------------------------------


def test_select_by_distance_takes_one_frame_per_spacing_and_skips_standing_still() -> None:
    x = np.concatenate([np.linspace(0, 10, 101), np.full(50, 10.0), np.linspace(10, 20, 51)])
    positions = np.stack([x, np.zeros_like(x), np.zeros_like(x)], 1)
    idx = select_by_distance(positions, 0.5)
    assert idx[0] == 0
    steps = np.diff(x[idx])
    assert np.allclose(steps, 0.5, atol=0.11)
    assert not np.any((idx > 101) & (idx < 151))  # nothing while standing still
    assert x[idx[-1]] == pytest.approx(20.0)


def test_chunks_by_distance_overlap_and_cover_every_frame() -> None:
    s = np.linspace(0.0, 400.0, 801)
    positions = np.stack([s, np.zeros_like(s), np.zeros_like(s)], 1)
    chunks = chunks_by_distance(s, positions, chunk_length_m=150.0, overlap_m=30.0)
    assert [c.id for c in chunks] == list(range(len(chunks)))
    assert chunks[0].start_m == 0.0
    assert chunks[-1].end_m == pytest.approx(400.0)
    counts = np.zeros(len(s), int)
    for c in chunks:
        counts[c.frames] += 1
        # Three of equal length: the 10 m past three 150 m steps absorbed, not a fourth chunk.
        assert c.end_m - c.start_m == pytest.approx((400.0 + 2 * 30.0) / 3)
    assert len(chunks) == 3
    assert counts.min() == 1
    assert counts.max() == 2
    for a, b in itertools.pairwise(chunks):
        shared = s[sorted(set(a.frames) & set(b.frames))]
        assert shared.max() - shared.min() == pytest.approx(30.0, abs=0.5)


@pytest.mark.parametrize(
    ("route_m", "n_chunks"),
    [
        (150.0, 1),
        (180.0, 1),
        (181.0, 2),
        (184.0, 2),
        (300.0, 2),
        (301.0, 3),
        (390.7, 3),
        (700.0, 6),
    ],
)
def test_chunks_by_distance_are_equal_and_none_lies_inside_another(
    route_m: float, n_chunks: int
) -> None:
    s = np.linspace(0.0, route_m, int(route_m * 2) + 1)
    positions = np.stack([s, np.zeros_like(s), np.zeros_like(s)], 1)
    chunks = chunks_by_distance(s, positions, chunk_length_m=150.0, overlap_m=30.0)
    assert len(chunks) == n_chunks
    lengths = [c.end_m - c.start_m for c in chunks]
    assert np.allclose(lengths, lengths[0])
    assert lengths[0] <= 150.0 + 30.0 / n_chunks + 1e-9  # a remainder up to the overlap absorbed
    assert chunks[-1].end_m == pytest.approx(route_m)
    for a, b in itertools.pairwise(chunks):
        assert a.end_m - b.start_m == pytest.approx(30.0)  # the overlap as asked
        assert b.end_m - a.end_m >= 0.4 * 150.0  # each chunk adds a good part of its own


def test_chunks_by_distance_short_route_is_one_chunk() -> None:
    s = np.array([0.0, 1.0, 2.0])
    chunks = chunks_by_distance(s, np.zeros((3, 3)), chunk_length_m=150.0, overlap_m=30.0)
    assert len(chunks) == 1
    assert chunks[0].frames == [0, 1, 2]


def test_distance_travelled_sums_steps() -> None:
    p = np.array([[0.0, 0, 0], [3.0, 4.0, 0], [3.0, 4.0, 0]])
    assert np.allclose(distance_travelled(p), [0.0, 5.0, 5.0])


def test_voxel_downsample_averages_per_voxel() -> None:
    xyz = np.array([[0.01, 0.01, 0.01], [0.03, 0.05, 0.07], [1.0, 1.0, 1.0]])
    rgb = np.array([[0, 0, 0], [100, 100, 100], [255, 0, 0]], np.uint8)
    out_xyz, out_rgb = voxel_downsample(xyz, rgb, 0.1)
    assert len(out_xyz) == 2
    assert np.allclose(out_xyz[0], [0.02, 0.03, 0.04])
    assert out_rgb[0].tolist() == [50, 50, 50]


def test_options_reject_overlap_of_half_a_chunk() -> None:
    with pytest.raises(ValueError, match="overlap_m"):
        PrepareOptions(chunk_length_m=100.0, overlap_m=50.0)


# -- undistortion ------------------------------------------------------------------------------

DIST = (-0.28, 0.09, 0.001, -0.0005, -0.01)
K_REC = np.array([[300.0, 0.0, 322.0], [0.0, 300.0, 238.0], [0.0, 0.0, 1.0]])


def test_undistorter_maps_undistorted_pixels_back_to_distorted_points() -> None:
    und = undistorter(K_REC, DIST, (640, 480))
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-0.6, 0.6, (200, 2)), np.ones(200)])
    distorted, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K_REC, np.asarray(DIST))
    distorted = distorted.reshape(-1, 2)
    ideal = pts @ und.K_new.T
    ideal = ideal[:, :2] / ideal[:, 2:]
    inside = (ideal[:, 0] >= 0) & (ideal[:, 0] < 639) & (ideal[:, 1] >= 0) & (ideal[:, 1] < 479)
    assert inside.sum() > 100
    assert und.maps is not None
    mx, my = cv2.convertMaps(und.maps[0], und.maps[1], cv2.CV_32FC1)
    sample = ideal[inside].astype(np.float32).reshape(-1, 1, 2)
    back_x = cv2.remap(mx, sample[..., 0], sample[..., 1], cv2.INTER_LINEAR)
    back_y = cv2.remap(my, sample[..., 0], sample[..., 1], cv2.INTER_LINEAR)
    back = np.column_stack([back_x.ravel(), back_y.ravel()])
    assert np.abs(back - distorted[inside]).max() < 0.1


def _line_image(und_K: np.ndarray, line: tuple[float, float, float]) -> np.ndarray:
    """A recorded (distorted) image whose white pixels lie on a straight line once undistorted."""
    v, u = np.mgrid[0:480, 0:640].astype(np.float32)
    grid = np.stack([u.ravel(), v.ravel()], 1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-9)
    norm = cv2.undistortPoints(grid, K_REC, np.asarray(DIST), criteria=criteria)
    pix = norm.reshape(-1, 2) @ und_K[:2, :2].T + und_K[:2, 2]
    a, b, c = line
    on_line = np.abs(a * pix[:, 0] + b * pix[:, 1] + c) < 1.0
    return np.where(on_line, 255, 0).astype(np.uint8).reshape(480, 640)


def _line_residual(image: np.ndarray) -> float:
    """RMS distance of the white pixels to the best straight line through them."""
    v, u = np.nonzero(image > 127)
    pts = np.column_stack([u, v]).astype(float)
    pts -= pts.mean(0)
    return float(np.sqrt(np.linalg.svd(pts, compute_uv=False)[-1] ** 2 / len(pts)))


def test_undistorted_image_maps_straight_lines_straight() -> None:
    und = undistorter(K_REC, DIST, (640, 480))
    lines = [(0.0, 1.0, -60.0), (1.0, 0.0, -70.0), (0.3, 1.0, -400.0)]  # a u + b v + c = 0
    for line in lines:
        recorded = _line_image(und.K_new, line)
        straight = und.apply(recorded)
        assert _line_residual(straight) < 1.0  # the 2-px wide band alone gives ~0.6
        assert _line_residual(recorded) > 2.0  # the distortion bent them


def test_undistorter_without_distortion_is_identity() -> None:
    und = undistorter(K, (), (W, H))
    image = np.arange(W * H, dtype=np.uint8).reshape(H, W)
    assert und.maps is None
    assert np.array_equal(und.apply(image), image)
    assert np.array_equal(und.K_new, K)


def test_camera_poses_compose_body_and_mount() -> None:
    T = camera_poses(
        np.array([[1.0, 2.0, 0.0]]), frames.quat_from_yaw(np.array([np.pi / 2])), LEFT_CAMERA
    )
    # Heading north, the left-looking camera looks west (-x), sits 1.5 m up.
    assert np.allclose(T[0, :3, 3], [1.0, 2.0, 1.5])
    assert np.allclose(T[0, :3, 2], [-1.0, 0.0, 0.0], atol=1e-9)


# -- end to end --------------------------------------------------------------------------------


def _texture(seed: int, size: int = 512) -> np.ndarray:
    rng = np.random.default_rng(seed)
    out = np.zeros((size, size, 3), np.float64)
    for cells in (8, 24, 64):
        out += cv2.resize(
            rng.random((cells, cells, 3)), (size, size), interpolation=cv2.INTER_CUBIC
        )
    out -= out.min()
    return (40 + 140 * out / out.max()).astype(np.uint8)


def _render(T_world_cam: np.ndarray) -> np.ndarray:
    T_cam_world = np.linalg.inv(T_world_cam)
    R, t = T_cam_world[:3, :3], T_cam_world[:3, 3]
    image = np.empty((H, W, 3), np.uint8)
    image[:] = SKY
    image[:] = np.clip(image.astype(int) - np.arange(H)[:, None, None] // 6, 0, 255)
    for k, (origin, a, b, scale) in enumerate(WALLS):
        tex = _texture(k)
        Hmat = K @ np.column_stack([R @ (scale * a), R @ (scale * b), R @ origin + t])
        warped = cv2.warpPerspective(tex, Hmat, (W, H), flags=cv2.INTER_LINEAR)
        cover = cv2.warpPerspective(np.full(tex.shape[:2], 255, np.uint8), Hmat, (W, H)) > 128
        image[cover] = warped[cover]
    image[-HOOD_ROWS:] = (35, 38, 45)  # the ego hood: constant in every frame
    return image


def _drive_x() -> np.ndarray:
    """Where the car is at each frame of :func:`_workspace`: 6 m along +x, standing still once."""
    return np.concatenate([np.arange(0.0, 3.0, 0.25), np.full(3, 3.0), np.arange(3.25, 6.01, 0.25)])


def _workspace(
    root: Path,
    *,
    pose_less: bool = False,
    lidar: bool = True,
    pose_error_m: float = 0.0,
    heading_from_motion: bool = False,
) -> Workspace:
    """A tiny dataset: the car drives 6 m along +x (stopping once), looking at walls to its left.

    ``pose_error_m``: the recorded positions are off by that much (seeded, each axis), the
    frames rendered where the car was.
    """
    ws = Workspace.create(root, Config())
    paths = DatasetPaths(ws.dataset_dir)
    paths.frames_dir.mkdir(parents=True)
    x = _drive_x()
    n = len(x)
    stamps = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 100_000_000
    pos = np.stack([x, np.zeros(n), np.zeros(n)], 1)
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    poses = camera_poses(pos, quat, LEFT_CAMERA)
    for i, T in enumerate(poses):
        cv2.imwrite(str(paths.frame_file(i, "png")), cv2.cvtColor(_render(T), cv2.COLOR_RGB2BGR))
    base = {"frame": np.arange(n), "stamp_ns": stamps, "t": (stamps - stamps[0]) / 1e9}
    recorded = pos + np.random.default_rng(3).normal(scale=pose_error_m, size=pos.shape)
    if pose_less:
        write_table(paths.frames_csv, base, precision=POSE_PRECISION)
    else:
        cols = dict(zip(("x", "y", "z"), recorded.T, strict=True)) | dict(
            zip(("qx", "qy", "qz", "qw"), quat.T, strict=True)
        )
        cols |= {"heading": np.zeros(n), "speed": np.full(n, 2.5)}
        write_table(
            paths.poses_csv, base | {c: cols[c] for c in POSE_COLUMNS[3:]}, precision=POSE_PRECISION
        )
    if lidar and not pose_less:
        _write_lidar(paths, stamps[::4], pos[::4])
    Calibration(
        camera=CameraIntrinsics(width=W, height=H, K=tuple(map(tuple, K)), source="config"),
        camera_mount=LEFT_CAMERA,
    ).save(paths.calibration_json)
    DatasetInfo(
        kind="images",
        pose_less=pose_less,
        sources=(),
        time_base="file",
        counts=DatasetCounts(frames=n, pose_samples=0 if pose_less else n),
        start_ns=int(stamps[0]),
        end_ns=int(stamps[-1]),
        duration_s=float(stamps[-1] - stamps[0]) / 1e9,
        frame_format="png",
        world=WorldFrameRecord(proj_string=None),
        heading_from_motion=heading_from_motion,
    ).save(paths.dataset_json)
    return ws


def _write_lidar(paths: DatasetPaths, stamps: np.ndarray, pos: np.ndarray) -> None:
    """Scans of the near wall (y = 6), sensor 1.8 m above the body origin, axes = body axes."""
    paths.lidar_dir.mkdir()
    rng = np.random.default_rng(5)
    sensor = pos + np.array([0.0, 0.0, 1.8])
    for i, p in enumerate(sensor):
        wall = np.column_stack(
            [rng.uniform(0.5, 6.0, 400), np.full(400, 6.0), rng.uniform(0.0, 2.2, 400)]
        )
        local = wall - p
        scan = np.zeros(400, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])
        scan["x"], scan["y"], scan["z"] = local.T
        np.save(paths.lidar_file(i), scan)
    n = len(stamps)
    cols = {"scan": np.arange(n), "stamp_ns": stamps, "t": (stamps - stamps[0]) / 1e9}
    cols |= dict(zip(("x", "y", "z"), sensor.T, strict=True))
    cols |= {"qx": np.zeros(n), "qy": np.zeros(n), "qz": np.zeros(n), "qw": np.ones(n)}
    cols["points"] = np.full(n, 400)
    write_table(paths.lidar_csv, {c: cols[c] for c in LIDAR_COLUMNS}, precision=POSE_PRECISION)


def test_prepare_scene_writes_a_valid_scene(tmp_path: Path) -> None:
    ws = _workspace(tmp_path / "ws")
    # Exact poses: kept as recorded (the adjustment of a real recording's has its own tests).
    opts = PrepareOptions(chunk_length_m=3.0, overlap_m=1.0, match_window=6, refine_poses=False)
    steps: list[str] = []
    scene = prepare_scene(ws, options=opts, progress=lambda task, done, total: steps.append(task))
    prep = ws.splat_dir / PREP_DIR
    assert SceneRecord.load(prep / "scene.json") == scene
    assert scene.pose_source == "recording"
    assert not scene.scale_ambiguous
    # 6 m at 0.5 m spacing: 13 frames; the 3 frames standing still are skipped.
    assert len(scene.frames) == 13
    assert [f.dataset_frame for f in scene.frames][:8] == [0, 2, 4, 6, 8, 10, 12, 16]
    # Every 8th frame from the middle of each 8: never the first, where the drives start.
    assert [f.held_out for f in scene.frames] == [i % 8 == 4 for i in range(13)]
    assert {"frames", "triangulation", "lidar"} <= set(steps)
    for f in scene.frames:
        stem = f"{f.index:06d}.png"
        image = cv2.imread(str(prep / "images" / stem))
        mask = cv2.imread(str(prep / "masks" / stem), cv2.IMREAD_GRAYSCALE)
        sky = cv2.imread(str(prep / "sky" / stem), cv2.IMREAD_GRAYSCALE)
        assert image.shape == (H, W, 3)
        assert (mask[-HOOD_ROWS + 2 :] == 0).all()  # hood detected and excluded
        assert (mask[: H - HOOD_ROWS - 3] == 255).all()
        assert (sky[:5] == 255).all()  # the sky above the walls
        assert (sky[-HOOD_ROWS:] == 0).all()
        assert (f.fx, f.fy, f.cx, f.cy, f.width, f.height) == (170.0, 170.0, 120.0, 90.0, W, H)
    # Chunks of 3 m with 1 m overlap over 6 m: [0, 3], [2, 5], [4, 6]; every frame in one or two.
    assert [(c.start_m, c.end_m) for c in scene.chunks] == [(0.0, 3.5), (2.5, 6.0)]  # equal
    assert all(1 <= len(f.chunks) <= 2 for f in scene.frames)
    expected = camera_poses(np.array([[3.0, 0.0, 0.0]]), np.array([[0.0, 0, 0, 1]]), LEFT_CAMERA)
    assert np.allclose(scene.frames[6].T(), expected[0])
    xyz, rgb, source = load_points(prep / "points.npz")
    tri, lid = xyz[source == 0], xyz[source == 1]
    assert len(tri) > 100
    assert len(lid) > 100
    near = (tri[:, 0] > 0.7) & (tri[:, 0] < 5.8) & (tri[:, 2] > 0.1) & (tri[:, 2] < 2.1)
    assert np.median(np.abs(tri[near, 1] - 6.0)) < 0.05
    assert np.allclose(lid[:, 1], 6.0, atol=0.01)
    seen = rgb[source == 1]
    assert (np.abs(seen.astype(int) - 128).sum(1) > 0).mean() > 0.5  # coloured from the frames


def test_poses_of_a_real_recording_are_bundle_adjusted_toward_where_the_car_was(
    tmp_path: Path,
) -> None:
    """Poses 4 cm off: GPS-grade ones (no orientation given) are refined by bundle adjustment
    within 1 m; ones with an orientation within 5 cm (``refine_oriented``, the default), kept
    when told not to; a demo world's (exact, its ground truth beside them) are kept as
    recorded."""
    opts = PrepareOptions(chunk_length_m=3.0, overlap_m=1.0, match_window=6)
    gps = prepare_scene(
        _workspace(tmp_path / "gps", lidar=False, pose_error_m=0.04, heading_from_motion=True),
        options=opts,
    )
    oriented = prepare_scene(
        _workspace(tmp_path / "odometry", lidar=False, pose_error_m=0.04), options=opts
    )
    demo_ws = _workspace(tmp_path / "demo", lidar=False, pose_error_m=0.04)
    demo_ws.truth_world_json.parent.mkdir(parents=True, exist_ok=True)
    demo_ws.truth_world_json.write_text("{}")
    kept = prepare_scene(demo_ws, options=opts)
    assert gps.pose_source == oriented.pose_source == "refined"
    assert any("refined by bundle adjustment" in n for n in gps.notes)
    (points,) = [n for n in gps.notes if n.startswith("points:")]
    assert float(points.split("(")[1].split(" px")[0]) < 1.0  # every point kept fits its views
    assert kept.pose_source == "recording"
    x = _drive_x()

    def error(scene: SceneRecord) -> float:
        where = np.stack([[x[f.dataset_frame], 0.0, 0.0] for f in scene.frames])
        want = camera_poses(where, np.tile([0.0, 0.0, 0.0, 1.0], (len(where), 1)), LEFT_CAMERA)
        got = np.stack([f.T() for f in scene.frames])
        return float(np.linalg.norm(got[:, :3, 3] - want[:, :3, 3], axis=1).mean())

    assert error(gps) < 0.7 * error(kept)  # nearer where the frames were taken
    assert error(oriented) < error(kept)
    # The closed loop poses the camera where the recording put it: each adjusted frame says
    # how to reach the model from there; frames kept as recorded need nothing.
    assert all(f.from_recorded is not None for f in gps.frames + oriented.frames)
    assert all(f.from_recorded is None for f in kept.frames)
    left = prepare_scene(
        _workspace(tmp_path / "asked", lidar=False), options=replace(opts, refine_oriented=False)
    )
    assert left.pose_source == "recording"  # oriented poses kept when told to


def test_a_pose_prior_holds_the_adjusted_centres_to_the_recording(tmp_path: Path) -> None:
    """A prior of 1 mm keeps every centre where it was recorded (the turns are still refined);
    a loose one lets the chain move as the images say."""
    ws = _workspace(tmp_path / "ws", lidar=False, pose_error_m=0.04)
    recorded = np.stack([f.T() for f in prepare_scene(ws, options=PrepareOptions(
        chunk_length_m=3.0, overlap_m=1.0, match_window=6, refine_poses=False
    )).frames])  # fmt: skip

    def moved(prior: float | None) -> float:
        opts = PrepareOptions(
            chunk_length_m=3.0, overlap_m=1.0, match_window=6, refine_poses=True,
            pose_prior_m=prior,
        )  # fmt: skip
        frames = prepare_scene(ws, options=opts).frames
        got = np.stack([f.T() for f in frames])
        fitted = ~np.array([f.held_out for f in frames])  # the held-out ones: their own images
        return float(np.linalg.norm(got[fitted, :3, 3] - recorded[fitted, :3, 3], axis=1).max())

    assert moved(1e-3) < 0.005
    assert moved(10.0) > 0.02
    with pytest.raises(ValueError, match="pose_prior_m"):
        PrepareOptions(pose_prior_m=0.0)


def test_prepare_scene_needs_a_dataset(tmp_path: Path) -> None:
    ws = Workspace.create(tmp_path / "ws", Config())
    with pytest.raises(StageError, match="cam2sim extract"):
        prepare_scene(ws)


def test_prepare_scene_leaves_old_scene_when_it_fails(tmp_path: Path) -> None:
    ws = _workspace(tmp_path / "ws", lidar=False)
    prep = ws.splat_dir / PREP_DIR
    prep.mkdir(parents=True)
    (prep / "scene.json").write_text("old")
    with pytest.raises(StageError, match="frame"):
        prepare_scene(ws, options=PrepareOptions(spacing_m=100.0))
    assert (prep / "scene.json").read_text() == "old"


def test_prepare_scene_pose_less_runs_sfm(tmp_path: Path) -> None:
    ws = _workspace(tmp_path / "ws", pose_less=True)
    opts = PrepareOptions(frame_step=2, detect_hood=False, hood_rows=HOOD_ROWS)
    scene = prepare_scene(ws, options=opts)
    assert scene.pose_source == "sfm"
    assert scene.scale_ambiguous
    assert len(scene.chunks) == 1
    assert len(scene.frames) == len(scene.chunks[0].frames) >= 8
    xyz, _, source = load_points(ws.splat_dir / PREP_DIR / "points.npz")
    assert len(xyz) > 50
    assert (source == 0).all()


def test_prepare_scene_without_intrinsics_aligns_sfm_to_the_recorded_poses(tmp_path: Path) -> None:
    ws = _workspace(tmp_path / "ws", lidar=False)
    calib_path = DatasetPaths(ws.dataset_dir).calibration_json
    Calibration(camera=None, camera_mount=LEFT_CAMERA).save(calib_path)
    opts = PrepareOptions(detect_hood=False, hood_rows=HOOD_ROWS, chunk_length_m=3.0, overlap_m=1.0)
    scene = prepare_scene(ws, options=opts)
    assert scene.pose_source == "sfm"
    assert not scene.scale_ambiguous
    assert len(scene.chunks) == 2  # two of 3.5 m (the 6 m route, 3 m at most, 1 m shared)
    recorded = camera_poses(
        np.array([[f.progress_m, 0.0, 0.0] for f in scene.frames]),
        np.tile([0.0, 0.0, 0.0, 1.0], (len(scene.frames), 1)),
        LEFT_CAMERA,
    )
    centres = np.stack([f.T()[:3, 3] for f in scene.frames])
    error = np.linalg.norm(centres - recorded[:, :3, 3], axis=1)
    assert error.mean() < 0.04
    assert error.max() < 0.1
    # (The focal length is not checked: sideways translation past parallel walls only fixes
    # focal / depth, so self-calibration cannot recover it from this scene.)
