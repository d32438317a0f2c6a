"""Stage detect: parked vehicles from LiDAR scans or camera frames, fused in the world frame.

Reads the dataset (``lidar.csv`` + scans, or ``poses.csv`` + frames with the calibration),
runs a detector (:mod:`cam2sim.detect.detector`) on every ``every``-th scan or frame, moves the
boxes into the world frame with each sensor's pose, and fuses them
(:mod:`cam2sim.detect.fusion`). Writes ``WS/detections/``:

- ``parked_vehicles.json``: the fused list (:class:`~cam2sim.detect.vehicles.ParkedVehicles`);
  the version it replaces (hand edits included) is kept under ``history/``;
- ``boxes_<source>.csv``: every per-frame box in the world frame and the vehicle it joined;
- ``parked_vehicles.png``: a bird's-eye picture of route, boxes and vehicles.
"""

from __future__ import annotations

import logging
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from cam2sim.core import frames as fr
from cam2sim.core.dataset import NO_INTRINSICS_HINT, Calibration, DatasetInfo
from cam2sim.core.errors import StageError, WorkspaceError
from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.core.table import read_table, write_table
from cam2sim.core.workspace import DatasetPaths, Workspace, dataset_paths, hash_inputs
from cam2sim.detect.bev import BEV_PNG, load_or_build_bev
from cam2sim.detect.detector import load_detector
from cam2sim.detect.fusion import FusionOptions, WorldBoxes, boxes_to_world, fuse
from cam2sim.detect.route import Route
from cam2sim.detect.snap import snap_to_road_edges
from cam2sim.detect.vehicles import ParkedVehicles, parked_vehicles_path, save_parked_vehicles
from cam2sim.recording.pointcloud import xyz_from_points
from cam2sim.report.detection_figures import plot_parked_vehicles
from cam2sim.splat.geometry import camera_poses, undistort_camera
from cam2sim.stages._runner import stage_run
from cam2sim.stages.map import load_road_map

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator
    from pathlib import Path

    from cam2sim.detect.boxes import Boxes
    from cam2sim.detect.detector import CameraDetector, LidarDetector, Source
    from cam2sim.detect.snap import SnapOptions

__all__ = ["DetectOptions", "DetectResult", "run_detect"]

logger = logging.getLogger(__name__)
STAGE = "detect"
BOX_COLUMNS = (
    "frame", "x", "y", "z", "yaw", "length", "width", "height", "score", "sigma_m", "range_m",
    "vehicle",
)  # fmt: skip


@dataclass(frozen=True)
class DetectOptions:
    """What ``cam2sim detect`` does.

    Attributes:
        source: ``lidar`` or ``camera``; None takes LiDAR when the dataset has scans.
        model: Detector name (see :func:`~cam2sim.detect.detector.load_detector`); None is
            ``geometric`` for LiDAR (camera detection needs a model).
        every: Use every n-th scan or frame.
        fusion: Association and fusion settings.
        snap: Snap vehicles to the map's road edge (needs ``cam2sim map`` first).
        snap_options: How snapping works.
        workers: Threads running the detector (numpy and onnxruntime release the GIL).
    """

    source: Source | None = None
    model: str | None = None
    every: int = 1
    fusion: FusionOptions = field(default_factory=FusionOptions)
    snap: bool = False
    snap_options: SnapOptions | None = None
    workers: int = 2

    def __post_init__(self) -> None:
        if self.every < 1:
            msg = f"every must be >= 1, got {self.every}"
            raise ValueError(msg)
        if self.workers < 1:
            msg = f"workers must be >= 1, got {self.workers}"
            raise ValueError(msg)


@dataclass(frozen=True)
class DetectResult:
    """Where the stage wrote and what it found (``vehicles`` is None when up to date)."""

    path: Path
    figure: Path | None
    vehicles: ParkedVehicles | None


@dataclass(frozen=True)
class _Frames:
    """The frames to run: index, sensor -> world transform, and a loader."""

    index: npt.NDArray[np.int64]
    T_world_sensor: npt.NDArray[np.float64]
    load: Callable[[int], npt.NDArray[np.generic]]


def _load_dataset(ws: Workspace) -> tuple[DatasetPaths, DatasetInfo, Calibration]:
    record = ws.stage_record("extract")
    if record is None or record.state != "done":
        msg = f"{ws.root} has no dataset; run `cam2sim extract {ws.root}` (or import) first"
        raise StageError(msg)
    paths = dataset_paths(ws.dataset_dir)
    try:
        return paths, DatasetInfo.load(paths.dataset_json), Calibration.load(paths.calibration_json)
    except WorkspaceError as err:
        msg = f"the dataset is incomplete ({err}); re-run `cam2sim extract {ws.root}`"
        raise StageError(msg) from err


def _poses_to_matrices(table: dict[str, npt.NDArray[np.generic]]) -> npt.NDArray[np.float64]:
    q = np.stack([table[c] for c in ("qx", "qy", "qz", "qw")], 1).astype(np.float64)
    T = np.tile(np.eye(4), (q.shape[0], 1, 1))
    T[:, :3, :3] = fr.quat_to_matrix(fr.quat_normalize(q))
    T[:, :3, 3] = np.stack([table[c] for c in ("x", "y", "z")], 1).astype(np.float64)
    return T


def scan_points(points: npt.NDArray[np.void]) -> npt.NDArray[np.float32]:
    """``(N, 4)`` float32 x, y, z, intensity in ``[0, 1]`` from a stored scan."""
    xyz = xyz_from_points(points).astype(np.float32)
    names = points.dtype.names or ()
    field_name = next((n for n in ("intensity", "i", "reflectivity") if n in names), None)
    if field_name is None or xyz.shape[0] != points.shape[0]:
        inten = np.zeros(xyz.shape[0], np.float32)
    else:
        inten = points[field_name].astype(np.float32)
        top = float(inten.max()) if inten.size else 0.0
        if top > 1.0:
            inten /= max(255.0, top)
    return np.concatenate([xyz, inten[:, None]], axis=1)


def _lidar_frames(paths: DatasetPaths, every: int) -> _Frames:
    if not paths.lidar_csv.is_file():
        msg = (
            "the dataset has no LiDAR scans; run with --source camera --model MODEL, or extract "
            "a recording with topics.lidar set"
        )
        raise StageError(msg)
    table = read_table(paths.lidar_csv)
    rows = np.arange(0, table["scan"].shape[0], every)
    T = _poses_to_matrices(table)[rows]

    def load(i: int) -> npt.NDArray[np.generic]:
        return scan_points(np.load(paths.lidar_file(i)))

    return _Frames(table["scan"].astype(np.int64)[rows], T, load)


def _camera_frames(
    paths: DatasetPaths, info: DatasetInfo, calib: Calibration, every: int
) -> tuple[_Frames, npt.NDArray[np.float64]]:
    import cv2  # noqa: PLC0415

    if info.pose_less:
        msg = (
            "camera detection needs camera poses to place boxes in the world, and this dataset "
            "has none (imported images without poses); import a pose CSV with the images"
        )
        raise StageError(msg)
    cam = calib.camera
    if cam is None:
        msg = f"the dataset has no camera intrinsics; {NO_INTRINSICS_HINT}"
        raise StageError(msg)
    table = read_table(paths.poses_csv)
    rows = np.arange(0, table["frame"].shape[0], every)
    T = camera_poses(
        np.stack([table[c] for c in ("x", "y", "z")], 1)[rows],
        np.stack([table[c] for c in ("qx", "qy", "qz", "qw")], 1)[rows],
        calib.camera_mount,
    )
    und = undistort_camera(cam.camera())

    def load(i: int) -> npt.NDArray[np.generic]:
        path = paths.frame_file(i, info.frame_format)
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if bgr is None:
            msg = f"cannot read frame {path}; re-run `cam2sim extract`"
            raise StageError(msg)
        rgb: npt.NDArray[np.generic] = cv2.cvtColor(und.apply(bgr), cv2.COLOR_BGR2RGB)
        return rgb

    return _Frames(table["frame"].astype(np.int64)[rows], T, load), und.K_new


def _detect_all(
    frames: _Frames,
    run: Callable[[npt.NDArray[np.generic]], Boxes],
    workers: int,
    report: ProgressCallback,
    task: str,
) -> Iterator[WorldBoxes]:
    total = int(frames.index.shape[0])

    def one(k: int) -> WorldBoxes:
        i = int(frames.index[k])
        return boxes_to_world(run(frames.load(i)), frames.T_world_sensor[k], i)

    report(task, 0, total)
    with ThreadPoolExecutor(max_workers=workers) as pool:
        for done, out in enumerate(pool.map(one, range(total)), start=1):
            report(task, done, total)
            yield out


def _route(paths: DatasetPaths) -> Route:
    """The driven route (a car that stood still: the line along its heading)."""
    table = read_table(paths.trajectory_csv)
    xy = np.stack([table["x"], table["y"]], 1).astype(np.float64)
    return Route.from_xy(xy, heading=np.asarray(table["heading"], dtype=np.float64))


def _detect_boxes(
    paths: DatasetPaths,
    info: DatasetInfo,
    calib: Calibration,
    source: Source,
    detector: LidarDetector | CameraDetector,
    opts: DetectOptions,
    report: ProgressCallback,
) -> tuple[WorldBoxes, int]:
    """Run the detector on every selected frame; the world boxes and the frame count."""
    if source == "lidar":
        frames = _lidar_frames(paths, opts.every)
        lidar: LidarDetector = detector  # type: ignore[assignment]

        def run(x: npt.NDArray[np.generic]) -> Boxes:
            return lidar.detect(x.astype(np.float32, copy=False))

        task = "LiDAR scans"
    else:
        frames, K = _camera_frames(paths, info, calib, opts.every)
        camera: CameraDetector = detector  # type: ignore[assignment]

        def run(x: npt.NDArray[np.generic]) -> Boxes:
            return camera.detect(x.astype(np.uint8, copy=False), K)

        task = "camera frames"
    parts = list(_detect_all(frames, run, opts.workers, report, task))
    return WorldBoxes.concatenate(parts), int(frames.index.shape[0])


def run_detect(
    ws: Workspace,
    *,
    options: DetectOptions | None = None,
    force: bool = False,
    progress: ProgressCallback | None = None,
) -> DetectResult:
    """Detect and fuse the workspace's parked vehicles.

    Raises:
        StageError: No dataset, no LiDAR for ``--source lidar``, no model or poses for camera
            detection, or no map for ``snap``.
        ConfigError: An unknown or unusable detector.
        BackendUnavailableError: The detector needs a package that is not installed.
    """
    opts = options or DetectOptions()
    report = progress or no_progress
    paths, info, calib = _load_dataset(ws)
    source: Source = opts.source or ("lidar" if info.counts.lidar_scans > 0 else "camera")
    model = opts.model or ("geometric" if source == "lidar" else None)
    if model is None:
        msg = (
            "this dataset has no LiDAR scans, and camera detection needs a model: "
            "--model path/to/detector.onnx (or .pt TorchScript, or fcos3d:CONFIG:CHECKPOINT)"
        )
        raise StageError(msg)
    out_path = parked_vehicles_path(ws.detections_dir)
    extract = ws.stage_record("extract")
    inputs = hash_inputs(
        {
            "dataset": extract.inputs_hash if extract else None,
            "source": source,
            "model": model,
            "options": repr(opts),
        }
    )
    if not force and out_path.is_file() and ws.is_up_to_date(STAGE, inputs):
        logger.info("detect: up to date; skipping (use --force to run again)")
        return DetectResult(out_path, None, None)
    detector = load_detector(model, source)
    road_map = None
    if opts.snap:
        road_map = load_road_map(ws)
    with stage_run(ws, STAGE, inputs_hash=inputs, config=None):
        boxes, frames_used = _detect_boxes(paths, info, calib, source, detector, opts, report)
        route = _route(paths)
        vehicles, member = fuse(boxes, route, source=source, options=opts.fusion)
        snapped = False
        if road_map is not None:
            vehicles, moved = snap_to_road_edges(vehicles, road_map, opts.snap_options)
            snapped = True
            logger.info("snapped %d of %d vehicles to the road edge", moved, len(vehicles))
        doc = ParkedVehicles(
            source=source,
            detector=getattr(detector, "name", model),
            frames_used=frames_used,
            detections=len(boxes),
            min_hits=opts.fusion.min_hits,
            snapped=snapped,
            vehicles=tuple(vehicles),
        )
        ws.detections_dir.mkdir(parents=True, exist_ok=True)
        _write_boxes(ws.detections_dir / f"boxes_{source}.csv", boxes, member)
        archived = save_parked_vehicles(doc, ws.detections_dir)
        if archived is not None:
            logger.info("the previous parked_vehicles.json is kept as %s", archived)
        figure = _figure(ws, doc, boxes, route, road_map)
    return DetectResult(out_path, figure, doc)


def _write_boxes(path: Path, boxes: WorldBoxes, member: npt.NDArray[np.int64]) -> None:
    write_table(
        path,
        {
            "frame": boxes.frame,
            "x": boxes.bottom[:, 0],
            "y": boxes.bottom[:, 1],
            "z": boxes.bottom[:, 2],
            "yaw": boxes.yaw,
            "length": boxes.size[:, 0],
            "width": boxes.size[:, 1],
            "height": boxes.size[:, 2],
            "score": boxes.score,
            "sigma_m": boxes.sigma_m,
            "range_m": boxes.range_m,
            "vehicle": member,
        },
    )


def _figure(
    ws: Workspace,
    doc: ParkedVehicles,
    boxes: WorldBoxes,
    route: object,
    road_map: object,
) -> Path:
    bev = load_or_build_bev(ws)
    background = (
        None
        if bev is None
        else (ws.detections_dir / BEV_PNG, (bev.x_min, bev.x_max, bev.y_min, bev.y_max))
    )
    path = ws.detection_files.picture
    plot_parked_vehicles(path, doc, boxes, route, road_map, background)  # type: ignore[arg-type]
    return path
