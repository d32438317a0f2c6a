"""Splat preparation: turn ``WS/dataset/`` into a prepared scene ``WS/splat/prep/``.

The prepared scene is the contract described in :mod:`cam2sim.splat.scene`. Steps:

1. **Frame selection** by distance travelled (one frame every ``spacing_m``; standing still adds
   no frames), or every ``frame_step``-th frame for pose-less datasets.
2. **Undistortion** with the calibration (OpenCV; plumb-bob or equidistant). The new pinhole K
   comes from ``getOptimalNewCameraMatrix`` with ``alpha=0`` at the same image size (every output
   pixel valid) and is what ``scene.json`` records.
3. **Ego-hood mask** from the configured rows or polygon (recorded-image pixels), else detected
   as the bottom region that stays constant while the scene moves; undistorted with the frames.
4. **Sky masks**: SegFormer when a model is given, else the classical heuristic
   (:mod:`cam2sim.splat.masks`).
5. **Camera poses** ``T_world_cam = T_world_body (poses.csv) o T_body_camera (calibration)``.
6. **Chunks** of equal length along the route by distance (at most ``chunk_length_m``,
   ``overlap_m`` shared by neighbours; :func:`chunks_by_distance`); a frame
   belongs to one or two chunks. Every ``held_out_every``-th frame is held out for evaluation,
   from the middle of each interval (:func:`is_held_out`): never the first frame, where every
   closed-loop run starts.
7. **Initial points**: known-pose triangulation (pycolmap) and, when the dataset has LiDAR
   scans, the scans in the world frame, coloured from the nearest frame, voxel-downsampled.

Datasets without poses get poses, intrinsics and points from images-only SfM
(:func:`cam2sim.splat.sfm.sfm_images_only`): ``pose_source="sfm"``, ``scale_ambiguous=True``,
one chunk. Datasets with poses but no intrinsics also run SfM (focal length at its prior, the
distortion refined); its result is then aligned to the recorded camera centres by a similarity,
so the world frame stays metric.
"""

from __future__ import annotations

import logging
import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from cam2sim.core import frames as fr
from cam2sim.core.background import BackgroundJobs
from cam2sim.core.dataset import Calibration, CameraIntrinsics, DatasetInfo, MountRecord
from cam2sim.core.errors import StageError, WorkspaceError
from cam2sim.core.files import atomic_folder
from cam2sim.core.progress import no_progress
from cam2sim.core.table import read_table
from cam2sim.core.workspace import DatasetPaths
from cam2sim.splat import masks
from cam2sim.splat.geometry import (
    Undistorter,
    camera_poses,
    chunk_membership,
    chunks_by_distance,
    distance_travelled,
    select_by_distance,
    smoothed_corrections,
    undistort_camera,
    undistorter,
    voxel_downsample,
)
from cam2sim.splat.scene import ChunkRecord, FrameRecord, SceneRecord, save_points
from cam2sim.splat.sfm import (
    FeatureOptions,
    KnownView,
    PoseAdjustment,
    SfmOptions,
    SfmResult,
    apply_similarity,
    sfm_images_only,
    similarity_from_poses,
    triangulate_known_poses,
)

if TYPE_CHECKING:
    from collections.abc import Sequence

    from cam2sim.core.camera import PinholeCamera
    from cam2sim.core.progress import ProgressCallback
    from cam2sim.core.workspace import Workspace

__all__ = [
    "GPS_PRIOR_M",
    "ORIENTED_PRIOR_M",
    "PREP_DIR",
    "PrepareOptions",
    "Undistorter",
    "camera_poses",
    "chunks_by_distance",
    "colour_from_view",
    "distance_travelled",
    "is_held_out",
    "prepare_scene",
    "select_by_distance",
    "undistorter",
    "voxel_downsample",
]

logger = logging.getLogger(__name__)

PREP_DIR = "prep"
"""Folder of the prepared scene inside ``WS/splat/``."""

GPS_PRIOR_M = 1.0
"""How far (one standard deviation, metres) the bundle adjustment of poses without orientation
may move a camera centre from its recorded position: a GNSS fix fused with an IMU, or a good
receiver alone (docs/benchmarks.md, "Noisy poses and bundle adjustment")."""
ORIENTED_PRIOR_M = 0.05
"""The same for poses that came with an orientation (odometry, SLAM, a survey's ground truth):
KITTI 03's ground-truth poses are not pixel-consistent with its frames; held to them within
5 cm the adjustment moved them 0.08 m on average (0.18 m at most), and the CPU splat gained on
held-out frames that took no part in it (docs/benchmarks.md). A freer chain drifts from the
record (0.54 m rms at 1 m), which the closed loop, rendering at recorded poses, would see."""
CORRECTION_SIGMA_M = 2.0
"""Where the preparation adjusted the recorded poses, the renderer maps a recorded (or
simulated) pose into the model through the corrections of the nearby frames, smoothed with a
Gaussian of this many metres of the route: a GPS drift or a heading that missed the car's slip
in a turn varies over tens of metres and stays, a fix's frame-to-frame jitter goes."""

_HOOD_FRAMES = 30
_SKY_BATCH = 8
_LIDAR_MIN_RANGE_M = 1.0  # closer returns hit the ego vehicle
_LIDAR_COMPACT_EVERY = 32
_GREY = 128


@dataclass(frozen=True)
class PrepareOptions:
    """Options of :func:`prepare_scene`.

    Attributes:
        spacing_m: Distance travelled between selected frames, metres.
        frame_step: Pose-less datasets: keep every n-th frame.
        max_frames: Keep at most this many selected frames (the first ones), or None.
        hood_rows: Bottom rows of the recorded image showing the ego hood, or None.
        hood_polygon_px: Hood polygon ``((x, y), ...)`` in recorded-image pixels, or None.
        detect_hood: Detect the hood when neither rows nor polygon are given.
        segformer: SegFormer model (local folder or hub id) for sky masks; None = classical.
        device: torch device for SegFormer.
        chunk_length_m: Longest route chunk, metres: the route is cut into as few chunks of
            equal length as keep each within it, a remainder up to ``overlap_m`` absorbed
            (:func:`chunks_by_distance`).
        overlap_m: Overlap of consecutive chunks, metres (less than half a chunk).
        held_out_every: Every n-th selected frame is held out for evaluation (0 = none), from
            the middle of each interval (:func:`is_held_out`).
        triangulate: Triangulate initial points from the frames (pycolmap).
        refine_poses: Refine the recorded poses by bundle adjustment (intrinsics fixed) after
            triangulating at them, the held-out frames kept out of it and aligned to their own
            images afterwards (:func:`~cam2sim.splat.sfm.triangulate_known_poses`). None =
            when the poses gave no orientation (``DatasetInfo.heading_from_motion``: GPS
            fixes, whose heading is the direction of travel and whose roll and pitch are
            zero), and, with ``refine_oriented`` (the default), when a real recording's poses
            came with one (a demo world's poses are exact and stay). On 85 m of KITTI 03 with a
            GPS-like error the adjustment took the rotation error from 0.63 to 0.16 degrees and the
            frame-to-frame error from 25 to 7 cm (reprojection 1.83 -> 0.26 px)
            (docs/benchmarks.md, "Noisy poses and bundle adjustment").
        refine_oriented: Under ``refine_poses=None``, also adjust a real recording's poses
            that came with an orientation (held within :data:`ORIENTED_PRIOR_M`). On KITTI 03's
            ground-truth poses it took the weakest chunk's held-out SSIM on one GPU from 0.768
            to 0.835 in the same time (preparation 129 s against 128), and on 2 cores the whole
            drive's closed-loop splat runs complete 3 of 3 with it (20.8 dB held out against
            20.1; the trial of 2026-12-05 left the road at the start, before recorded poses
            reached the model through the frames' corrections): docs/benchmarks.md, "GPS
            fixes smoothed".
        pose_prior_m: With ``refine_poses``: hold each camera centre to its recorded position
            with this standard deviation, metres (a pose-prior bundle adjustment, so a long
            drive cannot drift from its recording); None = by the poses' kind:
            :data:`GPS_PRIOR_M` without an orientation, :data:`ORIENTED_PRIOR_M` with one.
        match_window: Sequential matching window, frames.
        lidar_voxel_m: Voxel size for downsampling LiDAR points, metres.
        sfm: Options of images-only SfM (pose-less datasets, or no intrinsics).
    """

    spacing_m: float = 0.5
    frame_step: int = 1
    max_frames: int | None = None
    hood_rows: int | None = None
    hood_polygon_px: tuple[tuple[float, float], ...] | None = None
    detect_hood: bool = True
    segformer: str | None = None
    device: str = "cpu"
    chunk_length_m: float = 150.0
    overlap_m: float = 30.0
    held_out_every: int = 8
    triangulate: bool = True
    refine_poses: bool | None = None
    refine_oriented: bool = True
    pose_prior_m: float | None = None
    match_window: int = 20
    lidar_voxel_m: float = 0.1
    sfm: SfmOptions = field(default_factory=SfmOptions)

    def __post_init__(self) -> None:
        problems = []
        if not self.spacing_m >= 0:
            problems.append(f"spacing_m must be >= 0, got {self.spacing_m!r}")
        if self.frame_step < 1:
            problems.append(f"frame_step must be >= 1, got {self.frame_step!r}")
        if not self.chunk_length_m > 0:
            problems.append(f"chunk_length_m must be > 0, got {self.chunk_length_m!r}")
        if not 0 <= self.overlap_m < self.chunk_length_m / 2:
            problems.append(
                f"overlap_m must lie in [0, chunk_length_m / 2), got {self.overlap_m!r}"
            )
        if self.held_out_every < 0 or self.held_out_every == 1:
            problems.append(f"held_out_every must be 0 or >= 2, got {self.held_out_every!r}")
        if not self.lidar_voxel_m > 0:
            problems.append(f"lidar_voxel_m must be > 0, got {self.lidar_voxel_m!r}")
        if self.pose_prior_m is not None and not self.pose_prior_m > 0:
            problems.append(f"pose_prior_m must be > 0 or None, got {self.pose_prior_m!r}")
        if problems:
            raise ValueError("; ".join(problems))


# --------------------------------------------------------------------------------------------
# Dataset input
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class _Source:
    """The selected dataset frames."""

    frame: npt.NDArray[np.int64]  # dataset frame numbers
    stamp_ns: npt.NDArray[np.int64]
    files: list[Path]
    position: npt.NDArray[np.float64] | None  # (M, 3) body positions
    quat: npt.NDArray[np.float64] | None
    progress_m: npt.NDArray[np.float64] | None  # distance travelled at each selected frame


def _load_dataset(paths: DatasetPaths) -> tuple[DatasetInfo, Calibration]:
    if not paths.dataset_json.is_file():
        msg = (
            f"no dataset at {paths.root}; run `cam2sim extract` (or `cam2sim import`) before "
            "preparing the splat scene"
        )
        raise StageError(msg)
    try:
        return DatasetInfo.load(paths.dataset_json), Calibration.load(paths.calibration_json)
    except WorkspaceError as err:
        msg = f"the dataset is incomplete ({err}); re-run `cam2sim extract`"
        raise StageError(msg) from err


def _select(paths: DatasetPaths, info: DatasetInfo, opts: PrepareOptions) -> _Source:
    fmt = info.frame_format
    if info.pose_less:
        table = read_table(paths.frames_csv)
        rows = np.arange(0, table["frame"].shape[0], opts.frame_step)
        position = quat = progress = None
    else:
        table = read_table(paths.poses_csv)
        xyz = np.stack([table["x"], table["y"], table["z"]], 1).astype(np.float64)
        rows = select_by_distance(xyz, opts.spacing_m)
        position = xyz[rows]
        quat = np.stack([table[c] for c in ("qx", "qy", "qz", "qw")], 1).astype(np.float64)[rows]
        progress = distance_travelled(xyz)[rows]
    if opts.max_frames is not None:
        rows = rows[: opts.max_frames]
        position = None if position is None else position[: opts.max_frames]
        quat = None if quat is None else quat[: opts.max_frames]
        progress = None if progress is None else progress[: opts.max_frames]
    if rows.shape[0] < 2:
        msg = f"only {rows.shape[0]} frame(s) selected; record a longer drive or lower spacing_m"
        raise StageError(msg)
    frame = table["frame"][rows].astype(np.int64)
    files = [paths.frame_file(int(i), fmt) for i in frame]
    return _Source(frame, table["stamp_ns"][rows].astype(np.int64), files, position, quat, progress)


def _read_rgb(path: Path) -> npt.NDArray[np.uint8]:
    import cv2  # noqa: PLC0415

    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        msg = f"{path} cannot be read; re-run `cam2sim extract`"
        raise StageError(msg)
    return np.asarray(cv2.cvtColor(image, cv2.COLOR_BGR2RGB), dtype=np.uint8)


def _write_png(path: Path, image: npt.NDArray[Any], *, rgb: bool = False) -> None:
    import cv2  # noqa: PLC0415

    data = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if rgb else image
    if not cv2.imwrite(str(path), data):
        msg = f"cannot write {path}"
        raise StageError(msg)


# --------------------------------------------------------------------------------------------
# Masks and views
# --------------------------------------------------------------------------------------------


def _hood(files: Sequence[Path], size: tuple[int, int], opts: PrepareOptions) -> tuple[Any, str]:
    """The hood in recorded-image pixels (bool (H, W) or None) and a note saying where from."""
    w, h = size
    if opts.hood_polygon_px is not None:
        return masks.hood_mask_from_polygon(h, w, opts.hood_polygon_px), "hood: config polygon"
    if opts.hood_rows is not None:
        return masks.hood_mask_from_rows(h, w, opts.hood_rows), f"hood: {opts.hood_rows} rows"
    if not opts.detect_hood or len(files) < 3:
        return None, "hood: none"
    pick = np.unique(np.linspace(0, len(files) - 1, min(_HOOD_FRAMES, len(files))).astype(int))
    found = masks.detect_hood_mask([_read_rgb(files[int(i)]) for i in pick])
    if found is None:
        return None, "hood: none detected"
    return found, f"hood: detected ({100 * found.mean():.1f}% of the image)"


def _sky_masks(images: list[npt.NDArray[np.uint8]], opts: PrepareOptions) -> list[Any]:
    if opts.segformer is not None:
        return masks.sky_mask_segformer(images, opts.segformer, device=opts.device)
    return [masks.sky_mask_classical(im) for im in images]


@dataclass(frozen=True, eq=False)
class _Views:
    """Where the undistorted views were written."""

    images: list[Path]
    masks: list[Path]


def _write_views(
    files: Sequence[Path],
    undist: Undistorter,
    hood_raw: npt.NDArray[np.bool_] | None,
    out: Path,
    opts: PrepareOptions | None,
    report: ProgressCallback,
) -> _Views:
    """Undistort frames into ``out/images``, ``out/masks`` and (when ``opts``) ``out/sky``."""
    w, h = undist.size
    valid = undist.apply(np.full((h, w), 255, np.uint8), nearest=True) > 0
    hood = (
        undist.apply(hood_raw.astype(np.uint8), nearest=True) > 0 if hood_raw is not None else None
    )
    keep = valid & ~hood if hood is not None else valid
    for name in ("images", "masks") + (("sky",) if opts is not None else ()):
        (out / name).mkdir(parents=True, exist_ok=True)
    mask = np.where(keep, 255, 0).astype(np.uint8)
    stems = [f"{n:06d}.png" for n in range(len(files))]

    def write(stem: str, image: npt.NDArray[np.uint8], sky: npt.NDArray[np.bool_] | None) -> None:
        _write_png(out / "images" / stem, image, rgb=True)
        _write_png(out / "masks" / stem, mask)
        if sky is not None:
            _write_png(out / "sky" / stem, np.where(sky & keep, 255, 0).astype(np.uint8))

    def view(stem: str, file: Path) -> None:  # one frame, whole, on a worker thread
        image = undist.apply(_read_rgb(file))
        write(stem, image, None if opts is None else masks.sky_mask_classical(image))

    # OpenCV lets go of the GIL: frames are read, undistorted, masked and written on worker
    # threads (on KITTI's 741 frames 35 s on one thread of a 16-core machine). SegFormer's sky
    # masks come in batches from this thread (its model), their writes from the workers.
    with BackgroundJobs[None](name="cam2sim-views") as jobs:
        if opts is None or opts.segformer is None:
            for n, (stem, file) in enumerate(zip(stems, files, strict=True)):
                jobs.submit(view, stem, file)
                if (n + 1) % _SKY_BATCH == 0:
                    report("frames", jobs.collected, len(files))
        else:
            for start in range(0, len(files), _SKY_BATCH):
                block = [undist.apply(_read_rgb(f)) for f in files[start : start + _SKY_BATCH]]
                for stem, image, sky in zip(
                    stems[start:], block, _sky_masks(block, opts), strict=False
                ):
                    jobs.submit(write, stem, image, sky)
                report("frames", jobs.collected, len(files))
    report("frames", len(files), len(files))
    return _Views([out / "images" / t for t in stems], [out / "masks" / t for t in stems])


# --------------------------------------------------------------------------------------------
# Points
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class _Points:
    xyz: npt.NDArray[np.float64]
    rgb: npt.NDArray[np.uint8]
    source: npt.NDArray[np.uint8]

    @classmethod
    def empty(cls) -> _Points:
        return cls(np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros(0, np.uint8))

    def __add__(self, other: _Points) -> _Points:
        return _Points(
            np.concatenate([self.xyz, other.xyz]),
            np.concatenate([self.rgb, other.rgb]),
            np.concatenate([self.source, other.source]),
        )


def colour_from_view(
    xyz: npt.NDArray[np.float64],
    T_world_cam: npt.NDArray[np.float64],
    K: npt.NDArray[np.float64],
    image: npt.NDArray[np.uint8],
    mask: npt.NDArray[np.uint8] | None = None,
) -> npt.NDArray[np.uint8]:
    """Colours ``(N, 3)`` of world points seen in one view; grey where unseen or masked out.

    The view is a pinhole camera ``K`` at ``T_world_cam`` (optical axes); ``mask`` (0 = not
    used) limits the pixels that colour points.
    """
    T_cam_world = np.linalg.inv(T_world_cam)
    cam = xyz @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    z = cam[:, 2]
    safe = np.where(z > 0.1, z, 1.0)
    u = np.round(K[0, 0] * cam[:, 0] / safe + K[0, 2]).astype(np.int64)
    v = np.round(K[1, 1] * cam[:, 1] / safe + K[1, 2]).astype(np.int64)
    h, w = image.shape[:2]
    seen = (z > 0.1) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    if mask is not None:
        seen[seen] &= mask[v[seen], u[seen]] > 0
    rgb = np.full((xyz.shape[0], 3), _GREY, np.uint8)
    rgb[seen] = image[v[seen], u[seen]]
    return rgb


def _lidar_points(
    paths: DatasetPaths,
    stamps: npt.NDArray[np.int64],
    poses: npt.NDArray[np.float64],
    K: npt.NDArray[np.float64],
    views: _Views,
    opts: PrepareOptions,
) -> _Points:
    """LiDAR scans in the world frame, coloured from the nearest frame, voxel-downsampled."""
    table = read_table(paths.lidar_csv)
    n = table["scan"].shape[0]
    if n == 0:
        return _Points.empty()
    pos = np.stack([table["x"], table["y"], table["z"]], 1).astype(np.float64)
    rot = fr.quat_to_matrix(np.stack([table[c] for c in ("qx", "qy", "qz", "qw")], 1))
    scan_ns = table["stamp_ns"].astype(np.int64)
    nearest = np.clip(np.searchsorted(stamps, scan_ns), 0, len(stamps) - 1)
    before = np.clip(nearest - 1, 0, len(stamps) - 1)
    closer = np.abs(stamps[before] - scan_ns) < np.abs(stamps[nearest] - scan_ns)
    nearest = np.where(closer, before, nearest)
    acc = _Points.empty()
    cached: tuple[int, npt.NDArray[np.uint8], npt.NDArray[np.uint8]] | None = None
    for i in range(n):
        scan = np.load(paths.lidar_file(int(table["scan"][i])))
        local = np.stack([scan[c] for c in ("x", "y", "z")], 1).astype(np.float64)
        near = np.linalg.norm(local, axis=1) <= _LIDAR_MIN_RANGE_M
        local = local[np.isfinite(local).all(1) & ~near]
        world = local @ rot[i].T + pos[i]
        j = int(nearest[i])
        if cached is None or cached[0] != j:
            cached = (j, _read_rgb(views.images[j]), _read_mask(views.masks[j]))
        rgb = colour_from_view(world, poses[j], K, cached[1], cached[2])
        xyz_d, rgb_d = voxel_downsample(world, rgb, opts.lidar_voxel_m)
        acc = acc + _Points(xyz_d, rgb_d, np.ones(len(xyz_d), np.uint8))
        if i % _LIDAR_COMPACT_EVERY == _LIDAR_COMPACT_EVERY - 1 or i == n - 1:
            xyz, rgb = voxel_downsample(acc.xyz, acc.rgb, opts.lidar_voxel_m)
            acc = _Points(xyz, rgb, np.ones(len(xyz), np.uint8))
    logger.info("lidar: %d scans -> %d points (%.2f m voxels)", n, len(acc.xyz), opts.lidar_voxel_m)
    return acc


def _read_mask(path: Path) -> npt.NDArray[np.uint8]:
    import cv2  # noqa: PLC0415

    mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if mask is None:
        msg = f"{path} cannot be read"
        raise StageError(msg)
    return np.asarray(mask, dtype=np.uint8)


# --------------------------------------------------------------------------------------------
# The stage step
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class _Posed:
    """Frames with final poses and intrinsics, ready to be recorded."""

    source: _Source
    poses: npt.NDArray[np.float64]  # (M, 4, 4) T_world_cam
    camera: PinholeCamera  # of the undistorted images
    views: _Views
    points: _Points
    progress_m: npt.NDArray[np.float64]
    pose_source: str
    scale_ambiguous: bool
    notes: list[str]
    recorded: npt.NDArray[np.float64] | None = None  # (M, 4, 4) where ``poses`` are not these


def is_held_out(index: int, every: int) -> bool:
    """Whether selected frame ``index`` is held out: the middle frame of each ``every``.

    Frames ``every // 2``, ``every // 2 + every``, ...: as many as every ``every``-th, but never
    the first frame. The closed-loop runs start at the first recorded pose, so the splat
    must have seen that view; held out, it was the worst-rendered frame of a real drive
    (KITTI 03: 15.2 dB against a 24.8 dB median on an H200, docs/benchmarks.md).
    """
    return every > 0 and index % every == every // 2


def prepare_scene(
    ws: Workspace,
    *,
    options: PrepareOptions | None = None,
    progress: ProgressCallback | None = None,
) -> SceneRecord:
    """Prepare the splat training scene ``WS/splat/prep/`` from ``WS/dataset/``.

    The folder is built beside the old one and swapped in at the end; an error leaves the old
    one in place. See the module docstring for the steps.

    Args:
        ws: The workspace.
        options: Selection, mask, chunk and point options.
        progress: Reports ``frames``, ``triangulation``/``sfm`` and ``lidar`` steps.

    Returns:
        The scene record also written to ``scene.json``.

    Raises:
        StageError: No dataset (run ``cam2sim extract``), too few frames, or reconstruction
            failed.
        BackendUnavailableError: pycolmap (or transformers for SegFormer) is missing.
    """
    opts = options or PrepareOptions()
    report = progress or no_progress
    paths = DatasetPaths(ws.dataset_dir)
    info, calib = _load_dataset(paths)
    if opts.refine_poses is None:
        real = not ws.truth_world_json.is_file()  # a demo world's poses are exact
        auto = info.heading_from_motion or (real and opts.refine_oriented and not info.pose_less)
        opts = replace(opts, refine_poses=auto)
    if opts.pose_prior_m is None:
        kind = GPS_PRIOR_M if info.heading_from_motion else ORIENTED_PRIOR_M
        opts = replace(opts, pose_prior_m=kind)
    source = _select(paths, info, opts)
    size = _frame_size(source.files[0])
    logger.info("splat prep: %d frames selected from %s", len(source.files), paths.root)
    if calib.camera is not None and (calib.camera.width, calib.camera.height) != size:
        msg = (
            f"calibration.json is for {calib.camera.width}x{calib.camera.height} images but the "
            f"frames are {size[0]}x{size[1]}; fix the calibration and re-run `cam2sim extract`"
        )
        raise StageError(msg)
    with atomic_folder(ws.splat_dir / PREP_DIR) as tmp:
        hood, hood_note = _hood(source.files, size, opts)
        if info.pose_less or calib.camera is None:
            posed = _with_sfm(source, calib, hood, tmp, opts, report)
        else:
            posed = _with_poses(source, calib.camera, calib.camera_mount, hood, tmp, opts, report)
        if source.position is not None and not posed.scale_ambiguous and _has_lidar(paths):
            report("lidar", 0, 1)
            stamps = posed.source.stamp_ns
            lidar = _lidar_points(paths, stamps, posed.poses, posed.camera.K(), posed.views, opts)
            posed = replace(posed, points=posed.points + lidar)
            posed.notes.append(f"points: {len(lidar.xyz)} from LiDAR")
            report("lidar", 1, 1)
        pts = posed.points
        save_points(tmp / "points.npz", pts.xyz.astype(np.float32), pts.rgb, pts.source)
        scene = _scene_record(posed, [hood_note, *posed.notes], opts)
        scene.save(tmp / "scene.json")
    logger.info(
        "splat prep: %d frames, %d chunks, %d points (%s poses%s)",
        len(scene.frames),
        len(scene.chunks),
        len(posed.points.xyz),
        scene.pose_source,
        ", scale ambiguous" if scene.scale_ambiguous else "",
    )
    return scene


def _has_lidar(paths: DatasetPaths) -> bool:
    return paths.lidar_csv.is_file() and paths.lidar_dir.is_dir()


def _frame_size(path: Path) -> tuple[int, int]:
    image = _read_rgb(path)
    return int(image.shape[1]), int(image.shape[0])


def _with_poses(
    source: _Source,
    camera: CameraIntrinsics,
    mount: MountRecord,
    hood: npt.NDArray[np.bool_] | None,
    out: Path,
    opts: PrepareOptions,
    report: ProgressCallback,
) -> _Posed:
    """Recorded poses and calibration: undistort, triangulate (optionally refine)."""
    assert source.position is not None
    assert source.quat is not None
    assert source.progress_m is not None
    undist = undistort_camera(camera.camera())
    views = _write_views(source.files, undist, hood, out, opts, report)
    recorded = poses = camera_poses(source.position, source.quat, mount)
    points, pose_source, notes = _Points.empty(), "recording", []
    if opts.triangulate:
        tri = triangulate_known_poses(
            views.images,
            [KnownView(undist.K_new, T) for T in poses],
            views.masks,
            window=opts.match_window,
            # The held-out views stay out of the adjustment: no point or other pose is
            # fitted to the images they are scored on.
            refine=PoseAdjustment(
                prior_m=opts.pose_prior_m,
                held_out=tuple(is_held_out(i, opts.held_out_every) for i in range(len(poses))),
            )
            if opts.refine_poses
            else False,
            # Full resolution from the first octave: about 3x faster than upsampled SIFT.
            features=FeatureOptions(window=opts.match_window, first_octave=0),
            progress=report,
        )
        points = _Points(tri.points.xyz, tri.points.rgb, np.zeros(len(tri.points), np.uint8))
        notes.append(
            f"points: {len(tri.points)} triangulated "
            f"({tri.mean_reprojection_error_px:.2f} px mean reprojection error)"
        )
        if tri.refined:
            poses, pose_source = tri.T_world_cam, "refined"
            moved = np.linalg.norm(poses[:, :3, 3] - recorded[:, :3, 3], axis=1)
            notes.append(
                f"poses refined by bundle adjustment: cameras moved {moved.mean():.2f} m on "
                f"average ({moved.max():.2f} m at most)"
            )
    return _Posed(
        source,
        poses,
        undist.camera,
        views,
        points,
        source.progress_m,
        pose_source,
        scale_ambiguous=False,
        notes=notes,
        recorded=recorded if pose_source == "refined" else None,
    )


def _with_sfm(
    source: _Source,
    calib: Calibration,
    hood: npt.NDArray[np.bool_] | None,
    out: Path,
    opts: PrepareOptions,
    report: ProgressCallback,
) -> _Posed:
    """No poses, or no intrinsics: images-only SfM (aligned to the recorded poses if any)."""
    camera = calib.camera
    with tempfile.TemporaryDirectory(prefix="cam2sim-sfm-in-") as work_name:
        work = Path(work_name)
        if camera is not None:
            # Known intrinsics: SfM on the undistorted frames with K held fixed.
            undist = undistort_camera(camera.camera())
            staged = _write_views(source.files, undist, hood, work, None, report)
            new = undist.camera
            sfm_opts = replace(
                opts.sfm, camera_model="PINHOLE", camera_params=(new.fx, new.fy, new.cx, new.cy)
            )
            names = [p.name for p in staged.images]
            result = sfm_images_only(staged.images, staged.masks, options=sfm_opts, progress=report)
        else:
            # Unknown intrinsics: SfM on the recorded frames, distortion refined at the end.
            masks = None
            if hood is not None:
                _write_png(work / "hood.png", np.where(hood, 0, 255).astype(np.uint8))
                masks = [work / "hood.png"] * len(source.files)
            names = [p.name for p in source.files]
            result = sfm_images_only(source.files, masks, options=opts.sfm, progress=report)
            undist = undistort_camera(result.camera.camera())
    return _posed_from_sfm(
        _SfmInput(source, result, names, calib.camera_mount), undist, hood, out, opts, report
    )


@dataclass(frozen=True, eq=False)
class _SfmInput:
    source: _Source
    result: SfmResult
    names: list[str]  # file names SfM saw, in source order
    mount: MountRecord


def _posed_from_sfm(
    sfm: _SfmInput,
    undist: Undistorter,
    hood: npt.NDArray[np.bool_] | None,
    out: Path,
    opts: PrepareOptions,
    report: ProgressCallback,
) -> _Posed:
    source, result = sfm.source, sfm.result
    index = {n: i for i, n in enumerate(sfm.names)}
    rows = np.array([index[n] for n in result.names], dtype=np.int64)
    if rows.shape[0] < 2:
        msg = f"SfM registered {rows.shape[0]} of {len(sfm.names)} frames; cannot prepare a scene"
        raise StageError(msg)
    kept = _Source(
        source.frame[rows],
        source.stamp_ns[rows],
        [source.files[i] for i in rows],
        None if source.position is None else source.position[rows],
        None if source.quat is None else source.quat[rows],
        None if source.progress_m is None else source.progress_m[rows],
    )
    notes = [
        (
            f"sfm ({result.mapper}): {result.registered} of {result.total_images} frames "
            f"registered, {result.mean_reprojection_error_px:.2f} px mean reprojection error, "
            f"camera {result.camera.model} {tuple(round(p, 4) for p in result.camera.params)}"
        )
    ]
    poses, xyz = result.T_world_cam, result.points.xyz
    scale_ambiguous, recorded = True, None
    if kept.position is not None and kept.quat is not None and rows.shape[0] >= 3:
        recorded = camera_poses(kept.position, kept.quat, sfm.mount)
        S = similarity_from_poses(poses, recorded)
        poses = apply_similarity(S, poses)
        xyz = xyz @ S[:3, :3].T + S[:3, 3]
        residual = np.linalg.norm(poses[:, :3, 3] - recorded[:, :3, 3], axis=1)
        notes.append(
            f"sfm aligned to the recorded positions ({residual.mean():.2f} m mean residual)"
        )
        scale_ambiguous = False
    views = _write_views(kept.files, undist, hood, out, opts, report)
    if not scale_ambiguous and kept.progress_m is not None:
        progress_m = kept.progress_m
    else:
        progress_m = distance_travelled(poses[:, :3, 3])
        notes.append("scale ambiguous: progress in SfM units, one chunk")
    points = _Points(xyz, result.points.rgb, np.zeros(len(xyz), np.uint8))
    notes.append(f"points: {len(xyz)} from SfM")
    return _Posed(
        kept,
        poses,
        undist.camera,
        views,
        points,
        progress_m,
        "sfm",
        scale_ambiguous,
        notes,
        recorded=recorded,
    )


def _scene_record(posed: _Posed, notes: list[str], opts: PrepareOptions) -> SceneRecord:
    centres = posed.poses[:, :3, 3]
    if posed.scale_ambiguous:
        s = posed.progress_m
        chunks = [
            ChunkRecord(
                id=0,
                start_m=float(s[0]),
                end_m=float(s[-1]),
                frames=list(range(len(s))),
                center=[float(v) for v in centres.mean(axis=0)],
            )
        ]
    else:
        chunks = chunks_by_distance(
            posed.progress_m, centres, chunk_length_m=opts.chunk_length_m, overlap_m=opts.overlap_m
        )
    member = chunk_membership(chunks)
    cam = posed.camera
    held = [is_held_out(i, opts.held_out_every) for i in range(len(posed.source.frame))]
    from_recorded: list[list[float] | None] = [None] * len(held)
    if posed.recorded is not None and not all(held):
        # The closed loop renders at recorded poses: the model is reached through each pose's
        # smoothed correction (the held-out views', fitted to their own images, do not count).
        rows = smoothed_corrections(
            posed.recorded,
            posed.poses,
            posed.progress_m,
            ~np.asarray(held),
            sigma_m=CORRECTION_SIGMA_M,
        )
        from_recorded = [[float(v) for v in r] for r in rows]
    frame_records = [
        FrameRecord(
            index=i,
            dataset_frame=int(posed.source.frame[i]),
            stamp_ns=int(posed.source.stamp_ns[i]),
            T_world_cam=posed.poses[i].tolist(),
            fx=cam.fx,
            fy=cam.fy,
            cx=cam.cx,
            cy=cam.cy,
            width=cam.width,
            height=cam.height,
            held_out=held[i],
            chunks=member.get(i, []),
            progress_m=float(posed.progress_m[i]),
            from_recorded=from_recorded[i],
        )
        for i in range(len(posed.source.frame))
    ]
    return SceneRecord(
        frames=frame_records,
        chunks=chunks,
        scale_ambiguous=posed.scale_ambiguous,
        pose_source=posed.pose_source,
        notes=notes,
    )
