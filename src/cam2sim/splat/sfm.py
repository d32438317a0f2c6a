"""Structure from motion with pycolmap: points from known poses, or poses from images alone.

Two entry points:

- :func:`triangulate_known_poses`: the recorded camera poses and calibrated intrinsics are
  trusted; SIFT features are matched in a sequential window and triangulated into points (world
  metres), optionally followed by a bundle adjustment that refines the poses with the intrinsics
  fixed (the result is re-aligned to the recorded poses, so the world frame stays).
- :func:`sfm_images_only`: recordings without poses. Incremental (COLMAP) or global (GLOMAP)
  mapping with the intrinsics held fixed, then one final refinement of the distortion (the
  focal length stays at its prior unless asked). The result is in an arbitrary frame and scale
  (``scale_ambiguous``).

Lessons from forward-driving recordings, applied as defaults: COLMAP's self-calibration drifts
(focal 650 -> 1,300+ px) and the model fragments when intrinsics are free during mapping, so they
stay fixed until the end, where only the distortion is refined (a final focal refinement drifts
as well: 512 -> 775 px and 650 -> 1,114 px on the 300 Udacity frames, and cost the splat model
of those frames up to 0.7 dB mean and 5 dB 10th-percentile held-out PSNR); matching uses a
sequential window of 20 frames (frames are in recording order, i.e. their file names sort in
time; 10 frames and 2,048 features per image with the global mapper left a reconstruction of
7,200 points that the splat model fitted 2 dB worse); and the forward motion needs a relaxed
initial-pair search (small triangulation angle, forward motion allowed).

pycolmap is imported lazily; without it the functions raise
:class:`~cam2sim.core.errors.BackendUnavailableError` naming ``pip install cam2sim[splat]``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import numpy.typing as npt

from cam2sim.core.camera import PinholeCamera
from cam2sim.core.errors import BackendUnavailableError, StageError
from cam2sim.core.machine import available_cpus
from cam2sim.splat.geometry import (
    apply_similarity,
    interpolated_corrections,
    similarity_from_poses,
)

if TYPE_CHECKING:
    from collections.abc import Iterator, Sequence

    from cam2sim.core.progress import ProgressCallback

__all__ = [
    "CameraModel",
    "FeatureOptions",
    "KnownView",
    "Mapper",
    "PointCloud",
    "PoseAdjustment",
    "SfmCamera",
    "SfmOptions",
    "SfmResult",
    "TriangulationResult",
    "apply_similarity",
    "has_pycolmap",
    "sfm_images_only",
    "similarity_from_poses",
    "triangulate_known_poses",
]

logger = logging.getLogger(__name__)

_BA_MAX_ITERATIONS = 50
_ADJUSTED_MAX_ERROR_PX = 4.0
"""After a bundle adjustment of known poses, points with a larger mean reprojection error are
dropped (COLMAP's own triangulation filter; a few points end behind a camera or far off)."""

CameraModel = Literal["SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV"]
Mapper = Literal["incremental", "global"]

# pycolmap objects are untyped (no stubs); they travel as Any inside this module only.
_Colmap = Any


_ALIGN_MIN_INLIERS = 30
"""Fewest inlier matches that align a held-out view's pose to its own image."""
_ALIGN_MAX_MOVE_M = 2.0
"""Farthest a held-out view's aligned centre may lie from its interpolated one (metres); a
pose farther off is a wrong registration, and the view keeps its neighbours' corrections."""


def has_pycolmap() -> bool:
    """Whether pycolmap can be imported."""
    try:
        import pycolmap  # noqa: F401, PLC0415
    except ImportError:
        return False
    return True


def _pycolmap() -> _Colmap:
    try:
        import pycolmap  # noqa: PLC0415
    except ImportError as err:
        msg = f"structure from motion needs pycolmap ({err}); `pip install cam2sim[splat]`"
        raise BackendUnavailableError(msg) from err
    return pycolmap


# --------------------------------------------------------------------------------------------
# Records
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FeatureOptions:
    """SIFT extraction and sequential matching (shared by both entry points).

    Attributes:
        window: Each image is matched with the next ``window`` images (sequential overlap).
        max_image_size: Longest image side for feature extraction, pixels (-1 = full size);
            keypoints are scaled back to full resolution.
        max_num_features: SIFT features per image.
        first_octave: SIFT's first octave: -1 upsamples the image twice (more small features,
            about 3x slower), 0 starts at full resolution.
        max_ransac_trials: RANSAC trials per pair in geometric verification.
        num_threads: CPU threads (None = the CPUs this process may use,
            :func:`~cam2sim.core.machine.available_cpus`: its affinity, not the host's count,
            which a container or a Ray task sees too).
    """

    window: int = 20
    max_image_size: int = -1
    max_num_features: int = 4096
    first_octave: int = -1
    max_ransac_trials: int = 2000
    num_threads: int | None = None

    def threads(self) -> int:
        """The number of CPU threads to use."""
        return self.num_threads or available_cpus()


@dataclass(frozen=True, eq=False)
class PointCloud:
    """Triangulated points.

    Attributes:
        xyz: ``(N, 3)`` float64 positions, world metres (SfM units when scale-ambiguous).
        rgb: ``(N, 3)`` uint8 colours.
        error_px: ``(N,)`` float64 mean reprojection error per point, pixels.
        track_length: ``(N,)`` int64 number of images that see each point.
    """

    xyz: npt.NDArray[np.float64]
    rgb: npt.NDArray[np.uint8]
    error_px: npt.NDArray[np.float64]
    track_length: npt.NDArray[np.int64]

    def __len__(self) -> int:
        return int(self.xyz.shape[0])

    def subset(self, keep: npt.NDArray[np.bool_]) -> PointCloud:
        """The points where ``keep`` is set."""
        return PointCloud(
            self.xyz[keep], self.rgb[keep], self.error_px[keep], self.track_length[keep]
        )


@dataclass(frozen=True, eq=False)
class KnownView:
    """A calibrated pinhole view with a known pose (undistorted image).

    Attributes:
        K: ``(3, 3)`` float64 intrinsics, pixels.
        T_world_cam: ``(4, 4)`` float64, camera (OpenCV optical axes) -> world, metres.
    """

    K: npt.NDArray[np.float64]
    T_world_cam: npt.NDArray[np.float64]


@dataclass(frozen=True)
class PoseAdjustment:
    """How :func:`triangulate_known_poses` refines the poses by bundle adjustment.

    Attributes:
        prior_m: Hold each camera centre to its recorded position with this standard
            deviation (metres; a pose-prior adjustment), instead of mapping the adjusted chain
            back onto the recorded poses by one similarity (None).
        held_out: True for the images kept out of the triangulation and the adjustment (the
            held-out views: no point and no other pose depends on them, so scoring the splat
            on them stays honest). Each is then aligned to its own image against the adjusted
            points, the model fixed (test-time pose alignment, as pose-free NeRF and 3DGS
            papers evaluate), or, where that finds too little, takes its neighbours'
            corrections, interpolated (:func:`cam2sim.splat.geometry.interpolated_corrections`).
            None: none kept out.
    """

    prior_m: float | None = None
    held_out: tuple[bool, ...] | None = None


@dataclass(frozen=True, eq=False)
class _Work:
    """What the triangulation's steps share: COLMAP's database, the images, a scratch folder."""

    database: Path
    image_dir: Path
    tmp: Path
    pipeline: Any  # pycolmap.IncrementalPipelineOptions
    threads: int


@dataclass(frozen=True, eq=False)
class TriangulationResult:
    """What :func:`triangulate_known_poses` found.

    Attributes:
        points: The triangulated points, world metres.
        T_world_cam: ``(N, 4, 4)`` float64 camera poses, in input order: refined when
            ``refined`` is set, else the inputs.
        refined: Whether bundle adjustment refined the poses.
        mean_reprojection_error_px: Over all observations, pixels.
        seconds: Wall time per phase.
    """

    points: PointCloud
    T_world_cam: npt.NDArray[np.float64]
    refined: bool
    mean_reprojection_error_px: float
    seconds: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class SfmOptions:
    """Options of :func:`sfm_images_only`.

    Attributes:
        camera_model: COLMAP camera model of the images (one camera for all).
        camera_params: Known intrinsics in COLMAP's order for ``camera_model`` (e.g. PINHOLE
            ``fx, fy, cx, cy``); held fixed throughout, no final refinement. None: start from
            ``focal_guess_px`` and the image centre, refine the distortion at the end.
        focal_guess_px: Prior focal length; None = 0.8 x the longest image side.
        refine_intrinsics: Refine the distortion in a final bundle adjustment (only without
            ``camera_params``).
        refine_focal: Refine the focal length too in that final adjustment. Off by default: on
            forward-driving sequences it is barely constrained and drifts (see the module doc).
        mapper: ``incremental`` (COLMAP; the faster one on the 300 Udacity frames, 2 cores) or
            ``global`` (GLOMAP).
        features: Extraction and matching (window 20, 4,096 features at 640 px: about 6 min
            for the 300 Udacity frames on 2 cores).
        max_reprojection_error_px: Observations above this are filtered during mapping.
    """

    camera_model: CameraModel = "SIMPLE_RADIAL"
    camera_params: tuple[float, ...] | None = None
    focal_guess_px: float | None = None
    refine_intrinsics: bool = True
    refine_focal: bool = False
    mapper: Mapper = "incremental"
    features: FeatureOptions = FeatureOptions(
        window=20, max_image_size=640, max_num_features=4096, first_octave=0, max_ransac_trials=1000
    )
    max_reprojection_error_px: float = 4.0


@dataclass(frozen=True, eq=False)
class SfmCamera:
    """The camera SfM ended with.

    Attributes:
        model: COLMAP model name.
        width: Image width, pixels.
        height: Image height, pixels.
        params: COLMAP parameters of ``model``.
    """

    model: str
    width: int
    height: int
    params: tuple[float, ...]

    def camera(self) -> PinholeCamera:
        """The pinhole camera with its (plumb-bob) distortion."""
        p = self.params
        if self.model in {"SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"}:
            fx = fy = p[0]
            cx, cy = p[1], p[2]
        else:
            fx, fy, cx, cy = p[0], p[1], p[2], p[3]
        return PinholeCamera(fx, fy, cx, cy, self.width, self.height, self.distortion())

    def K(self) -> npt.NDArray[np.float64]:
        """``(3, 3)`` pinhole intrinsics (distortion in :meth:`distortion`)."""
        return self.camera().K()

    def distortion(self) -> tuple[float, ...]:
        """OpenCV plumb-bob coefficients ``(k1, k2, p1, p2)`` (empty when none)."""
        p = self.params
        if self.model == "SIMPLE_RADIAL":
            return (p[3], 0.0, 0.0, 0.0)
        if self.model == "RADIAL":
            return (p[3], p[4], 0.0, 0.0)
        if self.model == "OPENCV":
            return tuple(p[4:8])
        return ()


@dataclass(frozen=True, eq=False)
class SfmResult:
    """What :func:`sfm_images_only` found.

    Attributes:
        names: Registered image file names, sorted (recording order).
        T_world_cam: ``(M, 4, 4)`` float64 poses of ``names``, camera (optical) -> SfM world.
        camera: The final (refined) camera.
        points: Triangulated points in the SfM world.
        total_images: Images given.
        mean_reprojection_error_px: Over all observations, pixels.
        mapper: The mapper that ran.
        scale_ambiguous: Always True: the SfM frame has an arbitrary origin, rotation and scale.
        seconds: Wall time per phase.
    """

    names: tuple[str, ...]
    T_world_cam: npt.NDArray[np.float64]
    camera: SfmCamera
    points: PointCloud
    total_images: int
    mean_reprojection_error_px: float
    mapper: Mapper
    scale_ambiguous: bool = True
    seconds: dict[str, float] = field(default_factory=dict)

    @property
    def registered(self) -> int:
        """Number of registered images."""
        return len(self.names)


# --------------------------------------------------------------------------------------------
# Shared pieces
# --------------------------------------------------------------------------------------------


@contextlib.contextmanager
def _quiet_colmap(pycolmap: _Colmap) -> Iterator[None]:
    """Keep COLMAP's (glog) INFO chatter off stderr unless our logger is at DEBUG."""
    old = int(pycolmap.logging.minloglevel)
    if not logger.isEnabledFor(logging.DEBUG):
        pycolmap.logging.minloglevel = max(old, 1)
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = old


def _check_images(images: Sequence[Path]) -> tuple[Path, list[str]]:
    paths = [Path(p) for p in images]
    if len(paths) < 2:
        msg = f"structure from motion needs at least 2 images, got {len(paths)}"
        raise ValueError(msg)
    folders = {p.parent.resolve() for p in paths}
    if len(folders) != 1:
        msg = f"all images must lie in one folder, got {len(folders)} folders"
        raise ValueError(msg)
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        msg = f"{len(missing)} image file(s) do not exist, e.g. {missing[0]}"
        raise FileNotFoundError(msg)
    names = [p.name for p in paths]
    if names != sorted(names):
        msg = "image file names must sort in recording order (sequential matching relies on it)"
        raise ValueError(msg)
    return folders.pop(), names


def _mask_folder(names: list[str], masks: Sequence[Path] | None, tmp: Path) -> Path | None:
    """Lay masks out as COLMAP expects: ``<mask_dir>/<image name>.png``, 0 = ignore."""
    if masks is None:
        return None
    if len(masks) != len(names):
        msg = f"got {len(masks)} masks for {len(names)} images; pass one mask per image"
        raise ValueError(msg)
    folder = tmp / "masks"
    folder.mkdir()
    for name, mask in zip(names, masks, strict=True):
        shutil.copyfile(mask, folder / f"{name}.png")
    return folder


def _extract_and_match(
    pycolmap: _Colmap,
    database: Path,
    image_dir: Path,
    names: list[str],
    reader: _Colmap,
    opts: FeatureOptions,
) -> dict[str, float]:
    """Extract SIFT features and match them sequentially; return the seconds of each."""
    threads = opts.threads()
    start = time.perf_counter()
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = threads
    extraction.max_image_size = opts.max_image_size
    extraction.sift.max_num_features = opts.max_num_features
    extraction.sift.max_num_orientations = 1
    extraction.sift.first_octave = opts.first_octave
    pycolmap.extract_features(
        database,
        image_dir,
        image_names=names,
        camera_mode=pycolmap.CameraMode.SINGLE,
        reader_options=reader,
        extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )
    seconds = {"extraction": time.perf_counter() - start}
    start = time.perf_counter()
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = threads
    pairing = pycolmap.SequentialPairingOptions()
    pairing.overlap = max(1, min(opts.window, len(names) - 1))
    pairing.quadratic_overlap = False
    pairing.num_threads = threads
    verification = pycolmap.TwoViewGeometryOptions()
    verification.detect_watermark = False
    verification.ransac.max_num_trials = opts.max_ransac_trials
    pycolmap.match_sequential(
        database,
        matching_options=matching,
        pairing_options=pairing,
        verification_options=verification,
        device=pycolmap.Device.cpu,
    )
    seconds["matching"] = time.perf_counter() - start
    return seconds


def _point_cloud(rec: _Colmap) -> PointCloud:
    points = list(rec.points3D.values())
    n = len(points)
    if n == 0:
        return PointCloud(
            np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros(0), np.zeros(0, np.int64)
        )
    xyz = np.array([p.xyz for p in points], dtype=np.float64).reshape(n, 3)
    rgb = np.array([p.color for p in points], dtype=np.uint8).reshape(n, 3)
    err = np.array([p.error for p in points], dtype=np.float64)
    length = np.array([p.track.length() for p in points], dtype=np.int64)
    return PointCloud(xyz, rgb, err, length)


def _T_world_cam(image: _Colmap) -> npt.NDArray[np.float64]:
    T = np.eye(4)
    T[:3] = image.cam_from_world().inverse().matrix()
    return T


def _cam_from_world(pycolmap: _Colmap, T_world_cam: npt.NDArray[np.float64]) -> _Colmap:
    T = np.linalg.inv(T_world_cam)
    return pycolmap.Rigid3d(T[:3, :4])


def _known_reconstruction(
    pycolmap: _Colmap, database: Path, names: list[str], views: Sequence[KnownView]
) -> _Colmap:
    """A reconstruction holding the database's cameras and images at the known poses."""
    db = pycolmap.Database.open(database)
    try:
        by_name = {img.name: img for img in db.read_all_images()}
        rec = pycolmap.Reconstruction()
        for camera in db.read_all_cameras():
            rec.add_camera_with_trivial_rig(camera)
        for name, view in zip(names, views, strict=True):
            image = by_name[name]
            rec.add_image_with_trivial_frame(
                pycolmap.Image(name=name, camera_id=image.camera_id, image_id=image.image_id),
                _cam_from_world(pycolmap, view.T_world_cam),
            )
    finally:
        db.close()
    return rec


def _check_views(views: Sequence[KnownView], n: int) -> None:
    if len(views) != n:
        msg = f"got {len(views)} views for {n} images; pass one KnownView per image"
        raise ValueError(msg)
    for i, view in enumerate(views):
        if np.shape(view.K) != (3, 3) or np.shape(view.T_world_cam) != (4, 4):
            msg = f"view {i}: K must be (3, 3) and T_world_cam (4, 4)"
            raise ValueError(msg)
    if len({tuple(np.round(np.asarray(v.K), 6).ravel()) for v in views}) != 1:
        msg = "all views must share one K (one undistorted camera); undistort to a common K"
        raise ValueError(msg)


def triangulate_known_poses(
    images: Sequence[Path],
    views: Sequence[KnownView],
    masks: Sequence[Path] | None = None,
    *,
    window: int = 20,
    refine: bool | PoseAdjustment = False,
    features: FeatureOptions | None = None,
    progress: ProgressCallback | None = None,
) -> TriangulationResult:
    """Triangulate points from images with known poses and intrinsics (pycolmap).

    SIFT features are extracted (masked pixels ignored), matched with the next ``window``
    images and verified; COLMAP triangulates them with the poses held fixed. With ``refine``,
    a bundle adjustment then refines poses and points with the intrinsics fixed (robust loss),
    the centres held to their records by a prior or the result mapped back onto them by a
    similarity (:func:`similarity_from_poses`), so the world frame and scale stay the
    recording's; the points are triangulated again at the adjusted poses and adjusted once
    more (:class:`PoseAdjustment`).

    Args:
        images: Undistorted image files in one folder, names sorting in recording order.
        views: One :class:`KnownView` per image; all share one ``K``.
        masks: One mask file per image (uint8, 0 = ignore the pixel), or None.
        window: Sequential matching overlap (overrides ``features.window``).
        refine: Refine the poses by bundle adjustment (True: :class:`PoseAdjustment`'s
            defaults).
        features: Extraction and matching options.
        progress: Called with ``("triangulation", step, 3)``.

    Returns:
        The points (world metres) and the (refined) poses.

    Raises:
        BackendUnavailableError: pycolmap is missing.
        ValueError: Mismatched inputs.
        StageError: No point could be triangulated.
    """
    pycolmap = _pycolmap()
    image_dir, names = _check_images(images)
    _check_views(views, len(names))
    adjust = PoseAdjustment() if refine is True else (refine or None)
    held = None if adjust is None else adjust.held_out
    fitted = np.ones(len(names), bool) if held is None else ~np.asarray(held, bool)
    if fitted.shape != (len(names),) or not fitted.any():
        msg = f"held_out must be {len(names)} bools, not all True"
        raise ValueError(msg)
    opts = features or FeatureOptions()
    opts = dataclasses.replace(opts, window=window)
    report = progress or (lambda _task, _done, _total: None)
    K = np.asarray(views[0].K, dtype=np.float64)
    with tempfile.TemporaryDirectory(prefix="cam2sim-tri-") as tmp_name, _quiet_colmap(pycolmap):
        tmp = Path(tmp_name)
        database = tmp / "database.db"
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = "PINHOLE"
        reader.camera_params = ",".join(f"{v:.10g}" for v in (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
        mask_dir = _mask_folder(names, masks, tmp)
        if mask_dir is not None:
            reader.mask_path = str(mask_dir)
        seconds = _extract_and_match(pycolmap, database, image_dir, names, reader, opts)
        report("triangulation", 1, 3)
        rec = _known_reconstruction(pycolmap, database, names, views)
        if adjust is not None:  # the held-out views shape no point and no other pose
            _deregister(rec, names, fitted)
        pipeline = pycolmap.IncrementalPipelineOptions()
        pipeline.num_threads = opts.threads()
        work = _Work(database, image_dir, tmp, pipeline, opts.threads())
        start = time.perf_counter()
        rec = pycolmap.triangulate_points(
            rec, database, image_dir, tmp / "sparse", clear_points=True, options=pipeline
        )
        seconds["triangulation"] = time.perf_counter() - start
        report("triangulation", 2, 3)
        if rec.num_points3D() == 0:
            msg = (
                f"no point could be triangulated from {len(names)} images; check that the "
                "frames overlap and the poses and calibration belong to these images"
            )
            raise StageError(msg)
        poses = np.stack([np.asarray(v.T_world_cam, dtype=np.float64) for v in views])
        if adjust is not None:
            start = time.perf_counter()
            rec, poses = _adjust(pycolmap, rec, work, names, poses, fitted, adjust.prior_m)
            seconds["bundle_adjustment"] = time.perf_counter() - start
            rec.update_point_3d_errors()  # the adjusters leave the points' errors as they were
        report("triangulation", 3, 3)
        cloud = _point_cloud(rec)
        if adjust is not None:  # points the adjustment could not place (behind a camera) go
            cloud = cloud.subset(cloud.error_px <= _ADJUSTED_MAX_ERROR_PX)
        error = float(cloud.error_px.mean()) if len(cloud) else 0.0
    logger.info(
        "triangulation: %d points from %d images (%.2f px mean error%s)",
        len(cloud),
        len(names),
        error,
        ", poses refined" if adjust is not None else "",
    )
    return TriangulationResult(cloud, poses, adjust is not None, error, seconds)


def _adjust(
    pycolmap: _Colmap,
    rec: _Colmap,
    work: _Work,
    names: list[str],
    recorded: npt.NDArray[np.float64],
    fitted: npt.NDArray[np.bool_],
    prior_m: float | None,
) -> tuple[_Colmap, npt.NDArray[np.float64]]:
    """Adjust the poses twice, triangulating again between; align the held-out views.

    The second triangulation, at the adjusted poses, finds the matches that the recorded
    poses' error left untriangulated.
    """
    _refine_known(pycolmap, rec, names, recorded, fitted, work.threads, prior_m)
    first = rec.num_points3D()
    (work.tmp / "sparse2").mkdir()
    rec = pycolmap.triangulate_points(
        rec, work.database, work.image_dir, work.tmp / "sparse2", clear_points=True,
        options=work.pipeline,
    )  # fmt: skip
    poses = _refine_known(pycolmap, rec, names, recorded, fitted, work.threads, prior_m)
    poses = _align_held_out(pycolmap, rec, work.database, names, fitted, poses)
    logger.info(
        "bundle adjustment: %d points at the recorded poses, %d at the adjusted ones",
        first,
        rec.num_points3D(),
    )
    return rec, poses


def _deregister(rec: _Colmap, names: list[str], fitted: npt.NDArray[np.bool_]) -> None:
    """Take the images not ``fitted`` out of ``rec``, their observations with them.

    Out of the reconstruction, not only out of an adjustment: COLMAP holds a point constant
    while any image outside the adjustment observes it. (A reconstruction triangulated again
    without them no longer holds them.)
    """
    by_name = {img.name: img for img in rec.images.values()}
    registered = set(rec.reg_frame_ids())
    for name, fit in zip(names, fitted, strict=True):
        image = by_name.get(name)
        if not fit and image is not None and image.frame_id in registered:
            rec.deregister_frame(image.frame_id)


def _align_held_out(
    pycolmap: _Colmap,
    rec: _Colmap,
    database: Path,
    names: list[str],
    fitted: npt.NDArray[np.bool_],
    poses: npt.NDArray[np.float64],
) -> npt.NDArray[np.float64]:
    """Each held-out view's pose fitted to its own image against the adjusted points.

    The evaluation's test-time pose alignment, done here: the model (points, other poses) is
    already fixed, so the held-out image decides its own pose and nothing else. Its keypoints
    meet the points through their verified matches with the adjusted images; the pose is
    estimated robustly (LO-RANSAC, then refined) and kept only where it is well supported
    (:data:`_ALIGN_MIN_INLIERS`) and near the interpolated one (:data:`_ALIGN_MAX_MOVE_M`);
    else the view keeps its neighbours' corrections.
    """
    out = poses.copy()
    if fitted.all() or rec.num_points3D() == 0:
        return out
    point_ids = np.array(list(rec.points3D.keys()), dtype=np.int64)
    xyz = np.stack([rec.points3D[int(i)].xyz for i in point_ids])
    row_of = dict(zip(point_ids.tolist(), range(len(point_ids)), strict=True))
    observed: dict[int, npt.NDArray[np.int64]] = {}  # image id -> point row of each keypoint
    for image in rec.images.values():
        table = np.full(image.num_points2D(), -1, np.int64)
        idx = np.asarray(image.get_observation_point2D_idxs(), dtype=np.int64)
        table[idx] = [row_of[p.point3D_id] for p in image.get_observation_points2D()]
        observed[image.image_id] = table
    camera = next(iter(rec.cameras.values()))
    aligned = 0
    db = pycolmap.Database.open(database)
    try:
        ids = {img.name: img.image_id for img in db.read_all_images()}
        for k in np.flatnonzero(~fitted):
            held = ids[names[k]]
            keypoints = np.asarray(db.read_keypoints(held), dtype=np.float64)[:, :2]
            row = np.full(len(keypoints), -1, np.int64)
            for other, table in observed.items():
                if not db.exists_two_view_geometry(held, other):
                    continue
                pairs = np.asarray(db.read_two_view_geometry(held, other).inlier_matches)
                if pairs.size:
                    seen = table[pairs[:, 1]]
                    row[pairs[seen >= 0, 0]] = seen[seen >= 0]
            keep = row >= 0
            if keep.sum() < _ALIGN_MIN_INLIERS:
                continue
            # COLMAP's keypoints have the pixel centre at 0.5; the camera model agrees.
            found = pycolmap.estimate_and_refine_absolute_pose(
                keypoints[keep], xyz[row[keep]], camera
            )
            if found is None or int(found["num_inliers"]) < _ALIGN_MIN_INLIERS:
                continue
            T = np.eye(4)
            T[:3] = found["cam_from_world"].inverse().matrix()
            if np.linalg.norm(T[:3, 3] - poses[k, :3, 3]) > _ALIGN_MAX_MOVE_M:
                continue
            out[k] = T
            aligned += 1
    finally:
        db.close()
    logger.info(
        "held-out views: %d of %d aligned to their own images against the adjusted points",
        aligned,
        int((~fitted).sum()),
    )
    return out


def _refine_known(
    pycolmap: _Colmap,
    rec: _Colmap,
    names: list[str],
    poses: npt.NDArray[np.float64],
    fitted: npt.NDArray[np.bool_],
    threads: int,
    prior_m: float | None = None,
) -> npt.NDArray[np.float64]:
    """Bundle-adjust poses and points (intrinsics fixed), kept on the recorded poses.

    With ``prior_m`` every camera centre keeps a prior at its recorded position (that standard
    deviation, metres): the chain cannot drift from the recording further than its error
    allows. Without it a similarity maps the adjusted chain back onto the recorded poses as a
    whole (the chain may drift within). Only the ``fitted`` images take part: the others
    leave the reconstruction (their observations with them) and take their neighbours'
    corrections, interpolated.
    """
    options = pycolmap.BundleAdjustmentOptions()
    options.refine_focal_length = False
    options.refine_principal_point = False
    options.refine_extra_params = False
    options.print_summary = False
    options.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
    options.ceres.solver_options.num_threads = threads
    _deregister(rec, names, fitted)
    by_name = {img.name: img for img in rec.images.values()}
    if prior_m is None:
        pycolmap.bundle_adjustment(rec, options)
        refined = np.stack([_T_world_cam(by_name[n]) for n in np.asarray(names)[fitted]])
        T = similarity_from_poses(refined, poses[fitted])
        scale = float(np.cbrt(np.linalg.det(T[:3, :3])))
        rec.transform(pycolmap.Sim3d(T[:3, :4]))
    else:
        config = pycolmap.BundleAdjustmentConfig()  # the images' points are variable with them
        priors = []
        for name, pose, fit in zip(names, poses, fitted, strict=True):
            if not fit:
                continue
            image = by_name[name]
            config.add_image(image.image_id)
            priors.append(
                pycolmap.PosePrior(
                    position=pose[:3, 3],
                    position_covariance=np.eye(3) * prior_m**2,
                    coordinate_system=pycolmap.PosePriorCoordinateSystem.CARTESIAN,
                    corr_data_id=image.data_id,
                )
            )
        prior_options = pycolmap.PosePriorBundleAdjustmentOptions()
        adjuster = pycolmap.create_pose_prior_bundle_adjuster(
            options, prior_options, config, priors, rec
        )
        adjuster.solve()
        scale = 1.0
    out = poses.copy()
    for k, (name, fit) in enumerate(zip(names, fitted, strict=True)):
        if fit:
            out[k] = _T_world_cam(by_name[name])
    out = interpolated_corrections(poses, out, fitted)
    logger.info(
        "bundle adjustment: camera centres moved %.3f m on average (scale %.4f%s)",
        float(np.linalg.norm(out[:, :3, 3] - poses[:, :3, 3], axis=1).mean()),
        scale,
        "" if prior_m is None else f", centres held to their records within {prior_m:g} m",
    )
    return out


# --------------------------------------------------------------------------------------------
# Images only
# --------------------------------------------------------------------------------------------


def _incremental_options(pycolmap: _Colmap, opts: SfmOptions) -> _Colmap:
    o = pycolmap.IncrementalPipelineOptions()
    o.num_threads = opts.features.threads()
    o.ba_refine_focal_length = False
    o.ba_refine_principal_point = False
    o.ba_refine_extra_params = False
    o.mapper.abs_pose_refine_focal_length = False
    o.mapper.abs_pose_refine_extra_params = False
    # Forward driving: little parallax between neighbours, motion along the viewing axis.
    o.mapper.init_min_tri_angle = 4.0
    o.mapper.init_max_forward_motion = 1.0
    o.mapper.filter_max_reproj_error = opts.max_reprojection_error_px
    # Fewer global bundle adjustments: local BA keeps a video sequence consistent.
    o.ba_global_frames_ratio = 1.3
    o.ba_global_points_ratio = 1.3
    o.ba_global_max_num_iterations = 30
    o.ba_local_max_num_iterations = 20
    return o


def _global_options(pycolmap: _Colmap, opts: SfmOptions, names: list[str]) -> _Colmap:
    o = pycolmap.GlobalPipelineOptions()
    threads = opts.features.threads()
    o.num_threads = threads
    o.image_names = names
    mapper = o.mapper
    mapper.num_threads = threads
    mapper.bundle_adjustment.refine_focal_length = False
    mapper.bundle_adjustment.refine_extra_params = False
    mapper.bundle_adjustment.refine_principal_point = False
    mapper.bundle_adjustment.ceres.use_gpu = False
    mapper.global_positioning.use_gpu = False
    # Fewer, shorter global bundle adjustments: a video sequence converges quickly.
    mapper.ba_num_iterations = 2
    mapper.bundle_adjustment.ceres.solver_options.max_num_iterations = _BA_MAX_ITERATIONS
    return o


def _final_refinement(pycolmap: _Colmap, rec: _Colmap, threads: int, *, focal: bool) -> None:
    options = pycolmap.BundleAdjustmentOptions()
    options.refine_focal_length = focal
    options.refine_extra_params = True
    options.refine_principal_point = False
    options.print_summary = False
    options.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
    options.ceres.solver_options.num_threads = threads
    pycolmap.bundle_adjustment(rec, options)


def _camera_reader(
    pycolmap: _Colmap, opts: SfmOptions, size: tuple[int, int]
) -> tuple[_Colmap, bool]:
    """Reader options with the start camera; and whether the intrinsics are known."""
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = opts.camera_model
    if opts.camera_params is not None:
        reader.camera_params = ",".join(f"{v:.10g}" for v in opts.camera_params)
        return reader, True
    w, h = size
    f = opts.focal_guess_px or 0.8 * max(w, h)
    extra = {"SIMPLE_PINHOLE": [], "PINHOLE": [], "SIMPLE_RADIAL": [0.0], "RADIAL": [0.0, 0.0]}
    if opts.camera_model == "OPENCV":
        params = [f, f, w / 2, h / 2, 0.0, 0.0, 0.0, 0.0]
    elif opts.camera_model == "PINHOLE":
        params = [f, f, w / 2, h / 2]
    else:
        params = [f, w / 2, h / 2, *extra[opts.camera_model]]
    reader.camera_params = ",".join(f"{v:.10g}" for v in params)
    return reader, False


def _image_size(path: Path) -> tuple[int, int]:
    import cv2  # noqa: PLC0415

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        msg = f"{path} cannot be read as an image"
        raise ValueError(msg)
    return int(image.shape[1]), int(image.shape[0])


def _run_mapper(
    pycolmap: _Colmap,
    opts: SfmOptions,
    database: Path,
    image_dir: Path,
    names: list[str],
    out: Path,
) -> dict[int, _Colmap]:
    if opts.mapper == "incremental":
        models: dict[int, _Colmap] = pycolmap.incremental_mapping(
            database, image_dir, out, options=_incremental_options(pycolmap, opts)
        )
    else:
        models = pycolmap.global_mapping(
            database, image_dir, out, options=_global_options(pycolmap, opts, names)
        )
    return models


def sfm_images_only(
    images: Sequence[Path],
    masks: Sequence[Path] | None = None,
    *,
    options: SfmOptions | None = None,
    progress: ProgressCallback | None = None,
) -> SfmResult:
    """Recover camera poses, intrinsics and points from images alone (pycolmap).

    Features are matched in a sequential window; the mapper runs with the intrinsics fixed
    (prior focal length ``options.focal_guess_px`` or 0.8 x the longest side); then, unless
    the intrinsics were given, one bundle adjustment refines the distortion (and the focal
    length with ``options.refine_focal``). When
    the mapper splits the sequence into several models the largest is kept (and a warning
    logged). The frame and scale are arbitrary (``scale_ambiguous``).

    Args:
        images: Image files in one folder, names sorting in recording order, one size.
        masks: One mask file per image (uint8, 0 = ignore the pixel), or None.
        options: Camera model, mapper and matching options.
        progress: Called with ``("sfm", step, 3)``.

    Returns:
        The registered images' poses, the camera and the points.

    Raises:
        BackendUnavailableError: pycolmap is missing.
        ValueError: Fewer than 2 images or inconsistent inputs.
        StageError: No model could be reconstructed.
    """
    pycolmap = _pycolmap()
    opts = options or SfmOptions()
    image_dir, names = _check_images(images)
    report = progress or (lambda _task, _done, _total: None)
    size = _image_size(Path(images[0]))
    threads = opts.features.threads()
    with tempfile.TemporaryDirectory(prefix="cam2sim-sfm-") as tmp_name, _quiet_colmap(pycolmap):
        tmp = Path(tmp_name)
        database = tmp / "database.db"
        reader, known = _camera_reader(pycolmap, opts, size)
        mask_dir = _mask_folder(names, masks, tmp)
        if mask_dir is not None:
            reader.mask_path = str(mask_dir)
        seconds = _extract_and_match(pycolmap, database, image_dir, names, reader, opts.features)
        report("sfm", 1, 3)
        start = time.perf_counter()
        (tmp / "sparse").mkdir()
        models = _run_mapper(pycolmap, opts, database, image_dir, names, tmp / "sparse")
        seconds["mapping"] = time.perf_counter() - start
        report("sfm", 2, 3)
        if not models:
            msg = (
                f"{opts.mapper} mapping reconstructed nothing from {len(names)} images; the "
                "frames may overlap too little (try a larger window or the other mapper)"
            )
            raise StageError(msg)
        rec = max(models.values(), key=lambda r: r.num_reg_images())
        if len(models) > 1:
            logger.warning(
                "sfm: the sequence split into %d models; keeping the largest (%d of %d images)",
                len(models),
                rec.num_reg_images(),
                len(names),
            )
        if opts.refine_intrinsics and not known:
            start = time.perf_counter()
            _final_refinement(pycolmap, rec, threads, focal=opts.refine_focal)
            seconds["refinement"] = time.perf_counter() - start
        report("sfm", 3, 3)
        result = _sfm_result(rec, opts.mapper, len(names), seconds)
    logger.info(
        "sfm (%s): %d of %d images registered, %d points, %.2f px mean error, %.0f s",
        opts.mapper,
        result.registered,
        len(names),
        len(result.points),
        result.mean_reprojection_error_px,
        sum(seconds.values()),
    )
    return result


def _sfm_result(rec: _Colmap, mapper: Mapper, total: int, seconds: dict[str, float]) -> SfmResult:
    registered = sorted(
        (img for img in rec.images.values() if img.has_pose), key=lambda img: img.name
    )
    camera = rec.cameras[registered[0].camera_id]
    return SfmResult(
        names=tuple(img.name for img in registered),
        T_world_cam=np.stack([_T_world_cam(img) for img in registered]),
        camera=SfmCamera(
            model=str(camera.model_name),
            width=int(camera.width),
            height=int(camera.height),
            params=tuple(float(v) for v in camera.params),
        ),
        points=_point_cloud(rec),
        total_images=total,
        mean_reprojection_error_px=float(rec.compute_mean_reprojection_error()),
        mapper=mapper,
        seconds=seconds,
    )
