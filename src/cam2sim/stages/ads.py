"""Stages ``ads train`` and ``ads export``: the DAVE-2 system under test.

``ads train`` (:func:`train_ads`) trains DAVE-2 on the dataset's frames and a steering signal
(:mod:`cam2sim.ads.train`) and writes ``WS/ads/dave2.pt``, ``dave2.json``,
``train_report.json`` and ``train_report.png``. ``ads export`` (:func:`export_ads`) writes
``WS/ads/dave2.onnx`` (or ``out``) and ``WS/ads/export.json``, the torch/onnxruntime parity on
random inputs and on up to 8 of the dataset's frames (:mod:`cam2sim.ads.export`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Final

from cam2sim.ads.recovery import RecoveryGeometry
from cam2sim.core.dataset import Calibration, DatasetInfo
from cam2sim.core.errors import StageError, WorkspaceError
from cam2sim.core.files import file_fingerprint
from cam2sim.core.frames.rotation import quat_rotate
from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.core.workspace import Workspace, dataset_paths, hash_inputs
from cam2sim.stages._runner import stage_run
from cam2sim.stages.scenario import steering_calibration

if TYPE_CHECKING:
    from pathlib import Path

    import numpy as np
    import numpy.typing as npt

    from cam2sim.ads.dave2 import Dave2Config
    from cam2sim.ads.export import ExportReport
    from cam2sim.ads.train import TrainedModel, TrainReport
    from cam2sim.ads.train_options import TrainOptions

__all__ = [
    "DERIVED_STEERING",
    "ExportAdsResult",
    "TrainAdsResult",
    "derive_steering",
    "export_ads",
    "recovery_geometry",
    "train_ads",
    "train_model",
]

logger = logging.getLogger(__name__)
TRAIN_STAGE: Final = "ads_train"
EXPORT_STAGE: Final = "ads_export"
ONNX_FILE: Final = "dave2.onnx"
EXPORT_REPORT: Final = "export.json"
_PARITY_FRAMES: Final = 8
DERIVED_STEERING: Final = "steering_from_poses"
"""The signal :func:`derive_steering` writes for a recording without a steering signal."""
MOTION_STEERING_WINDOW_M: Final = 3.0
"""Half window (m) of the heading change behind the derived steering when the heading came
from motion (GPS fixes): KITTI 03 as GPS fixes (0.5 m drift, 0.1 m jitter) correlates 0.81
with the steering derived from its ground-truth poses at the 1 m of oriented poses, 0.92 at
2 m, 0.94 at 3 m, 0.94 at 4 m; the sharp junction's peak is 9 % flatter at 3 m."""


def derive_steering(ws: Workspace) -> str:
    """Write a steering signal derived from the recording's path; return its name.

    For recordings without a steering signal (a camera drive with GPS/IMU or SLAM poses): the
    curvature of the rear axle's path (the poses moved back from where config.yaml's vehicle
    puts them) in steering units (:func:`cam2sim.scenario.calibration.steering_from_poses`,
    with the workspace's steering calibration: the default without a steering signal to fit it
    on) at the times the path's 0.5 m samples were reached, as
    ``WS/dataset/signals/steering_from_poses.csv``. On the reference drives it correlates 0.996
    with the measured steering (``docs/benchmarks.md``). Poses without orientation (GPS fixes,
    heading from motion) take the heading's change over :data:`MOTION_STEERING_WINDOW_M`.

    Raises:
        StageError: No dataset or no trajectory, or the vehicle never drives.
    """
    import numpy as np  # noqa: PLC0415

    from cam2sim.core.errors import ConfigError  # noqa: PLC0415
    from cam2sim.core.table import read_table, write_table  # noqa: PLC0415
    from cam2sim.scenario.body import body_point_positions  # noqa: PLC0415
    from cam2sim.scenario.calibration import steering_from_poses  # noqa: PLC0415

    info = _dataset(ws)
    paths = dataset_paths(ws.dataset_dir)
    if not paths.trajectory_csv.is_file():
        msg = (
            f"{ws.root} has no steering signal and no trajectory ({paths.trajectory_csv}) to "
            "derive one from; map a steering topic in config.yaml or import poses"
        )
        raise StageError(msg)
    tr = read_table(paths.trajectory_csv)
    stamp = tr["stamp_ns"].astype(np.int64)
    heading = tr["heading"].astype(np.float64)
    # The bicycle model's curvature is the rear axle's: move the pose point back onto it.
    vehicle = ws.load_config().vehicle
    xy = body_point_positions(
        np.stack([tr["x"], tr["y"], np.zeros(len(heading))], 1),
        heading,
        vehicle.reference_xyz(),
        (vehicle.rear_axle_x_m, 0.0, 0.0),
    )[:, :2]
    try:
        t, value = steering_from_poses(
            (stamp - stamp[0]) / 1e9,
            xy,
            heading,
            tr["speed"].astype(np.float64),
            steering_calibration(ws),
            # A heading from motion is as noisy as the positions: a longer window.
            **({"window_m": MOTION_STEERING_WINDOW_M} if info.heading_from_motion else {}),
        )
    except ConfigError as err:
        msg = f"{ws.root}: {err}"
        raise StageError(msg) from None
    stamps = stamp[0] + np.round(t * 1e9).astype(np.int64)
    keep = np.concatenate([[True], np.diff(stamps) > 0])  # standing still: one sample a stamp
    write_table(
        paths.signal_file(DERIVED_STEERING),
        {"stamp_ns": stamps[keep], "t": stamps[keep] / 1e9, "value": value[keep]},
        precision={"value": 9},
    )
    logger.info("steering derived from the poses: %d samples", int(keep.sum()))
    return DERIVED_STEERING


@dataclass(frozen=True)
class TrainAdsResult:
    """Where ``ads train`` wrote (``report`` is None when the model was up to date)."""

    model: Path
    report_path: Path
    figure: Path
    report: TrainReport | None


@dataclass(frozen=True)
class ExportAdsResult:
    """The exported file and its parity report."""

    path: Path
    report_path: Path
    report: ExportReport


def _dataset(ws: Workspace) -> DatasetInfo:
    record = ws.stage_record("extract")
    if record is None or record.state != "done":
        msg = f"{ws.root} has no dataset; run `cam2sim extract {ws.root}` (or import) first"
        raise StageError(msg)
    try:
        return DatasetInfo.load(dataset_paths(ws.dataset_dir).dataset_json)
    except WorkspaceError as err:
        msg = f"the dataset is incomplete ({err}); re-run `cam2sim extract {ws.root}`"
        raise StageError(msg) from err


def train_ads(
    ws: Workspace,
    *,
    options: TrainOptions | None = None,
    force: bool = False,
    progress: ProgressCallback | None = None,
) -> TrainAdsResult:
    """Train DAVE-2 on the workspace's frames and steering signal.

    Args:
        ws: The workspace (extract done).
        options: Training options; defaults train on signal ``steering``.
        force: Train even when the model is up to date.
        progress: Receives ``loading frames`` and ``training DAVE-2`` progress.

    Raises:
        StageError: No dataset, no such signal (the message lists those available), too few
            frames, or constant steering.
    """
    from cam2sim.ads import train as tr  # noqa: PLC0415 -- lazy: imports cv2, torch
    from cam2sim.ads.train_options import TrainOptions  # noqa: PLC0415 -- lazy: imports cv2

    opts = options or TrainOptions()
    report = progress or no_progress
    _dataset(ws)  # refuses a workspace without a dataset, before anything else
    ads = ws.ads_dir
    result = TrainAdsResult(ads / tr.MODEL_FILE, ads / tr.REPORT_FILE, ads / tr.REPORT_FIGURE, None)
    extract = ws.stage_record("extract")
    signal = dataset_paths(ws.dataset_dir).signal_file(opts.signal)
    inputs = hash_inputs(
        {
            "dataset": extract.inputs_hash if extract else None,
            "options": repr(opts),
            # A signal derived from the poses and the recovery views' camera height change with
            # where config.yaml puts the poses on the car.
            "signal": file_fingerprint(signal) if signal.is_file() else None,
            "vehicle": ws.load_config().vehicle.model_dump(mode="json"),
        }
    )
    done = all(p.is_file() for p in (result.model, result.report_path, result.figure))
    if not force and done and ws.is_up_to_date(TRAIN_STAGE, inputs):
        logger.info("ads train: up to date; skipping (use --force to train again)")
        return result
    with stage_run(ws, TRAIN_STAGE, inputs_hash=inputs, config=None):
        trained = train_model(ws, opts, report)
        ads.mkdir(parents=True, exist_ok=True)
        tr.save_training(trained, ads)
    return TrainAdsResult(result.model, result.report_path, result.figure, trained.report)


def train_model(
    ws: Workspace, options: TrainOptions, progress: ProgressCallback | None = None
) -> TrainedModel:
    """DAVE-2 trained on the workspace's dataset (recovery views from its camera), not saved.

    :func:`train_ads` saves it as the workspace's model; ``benchmarks/dave2_seeds.py`` trains
    several beside it.

    Raises:
        StageError: No dataset, no such signal, too few frames, or constant steering.
    """
    from cam2sim.ads import train as tr  # noqa: PLC0415 -- lazy: imports cv2, torch

    info = _dataset(ws)
    report = progress or no_progress
    calib_path = dataset_paths(ws.dataset_dir).calibration_json
    if options.config is None and calib_path.is_file():  # the published crop, fitted to it
        from cam2sim.ads.dave2 import Dave2Config  # noqa: PLC0415

        camera = Calibration.load(calib_path).camera
        if camera is not None:
            options = replace(options, config=Dave2Config.for_camera(camera.width, camera.height))
    data = tr.assemble(dataset_paths(ws.dataset_dir), info.frame_format, options, report)
    geometry = recovery_geometry(ws) if options.uses_recovery else None
    return tr.train_dave2(data, options, report, geometry=geometry)


def recovery_geometry(ws: Workspace) -> RecoveryGeometry | None:
    """The camera and steering geometry the recovery views need, or None (logged why).

    The camera's intrinsics and mount come from the dataset's calibration. Its height over the
    road is the mount's height over the recorded pose point plus that point's height over the
    road (``vehicle.reference`` in config.yaml: 0 for ``base_link`` on the ground, 1.65 m for
    poses at a KITTI camera), as everywhere else in the pipeline. The curvature per steering
    unit is the scenario stage's fit of the recorded steering against the recorded path (or its
    default).
    """
    import math  # noqa: PLC0415

    import numpy as np  # noqa: PLC0415

    try:
        calib = Calibration.load(dataset_paths(ws.dataset_dir).calibration_json)
    except WorkspaceError as err:
        logger.info("no recovery views: %s", err)
        return None
    if calib.camera is None:
        logger.info("no recovery views: the dataset has no camera intrinsics")
        return None
    mount = calib.camera_mount
    forward = np.array([0.0, 0.0, 1.0] if mount.axes == "optical" else [1.0, 0.0, 0.0])
    ahead = quat_rotate(np.asarray(mount.quat_xyzw), forward)
    pose_point_m = float(ws.load_config().vehicle.reference_xyz()[2])
    height = float(mount.translation_m[2]) + pose_point_m
    if not height > 0:
        logger.info(
            "no recovery views: the camera is %.2f m over the road (mount %.2f m over the pose "
            "point, %.2f m over the road); set vehicle.reference in config.yaml",
            height, float(mount.translation_m[2]), pose_point_m,
        )  # fmt: skip
        return None
    cam = calib.camera
    return RecoveryGeometry(
        K=tuple((float(r[0]), float(r[1]), float(r[2])) for r in cam.K),
        width=cam.width,
        height=cam.height,
        height_m=height,
        pitch_rad=math.asin(float(np.clip(-ahead[2], -1.0, 1.0))),
        curvature_per_unit=steering_calibration(ws).curvature_per_unit,
    )


def _real_inputs(ws: Workspace, config: Dave2Config) -> npt.NDArray[np.float32] | None:
    """Up to 8 preprocessed dataset frames spread over the drive (None without frames)."""
    import cv2  # noqa: PLC0415
    import numpy as np  # noqa: PLC0415

    from cam2sim.ads.dave2 import preprocess  # noqa: PLC0415 -- lazy: imports cv2

    try:
        info = _dataset(ws)
    except StageError:
        return None
    paths = dataset_paths(ws.dataset_dir)
    files = sorted(paths.frames_dir.glob("*.jpg" if info.frame_format == "jpeg" else "*.png"))
    if not files:
        return None
    pick = np.unique(np.linspace(0, len(files) - 1, _PARITY_FRAMES).round().astype(int))
    images = [cv2.imread(str(files[i]), cv2.IMREAD_COLOR) for i in pick]
    rgb = [cv2.cvtColor(b, cv2.COLOR_BGR2RGB) for b in images if b is not None]
    if not rgb or len({im.shape for im in rgb}) != 1:
        return None
    return preprocess(np.stack(rgb), config)


def export_ads(
    ws: Workspace,
    *,
    out: Path | None = None,
    progress: ProgressCallback | None = None,
) -> ExportAdsResult:
    """Export the trained DAVE-2 to ONNX and check onnxruntime against torch.

    Args:
        ws: The workspace (``ads train`` done).
        out: The ``.onnx`` file; default ``WS/ads/dave2.onnx``.
        progress: Receives one ``exporting ONNX`` step.

    Raises:
        StageError: No trained model, or onnxruntime disagrees with torch.
        BackendUnavailableError: onnx or onnxruntime is missing.
    """
    from cam2sim.ads.export import export_onnx  # noqa: PLC0415 -- lazy: imports cv2, torch
    from cam2sim.ads.train import load_model  # noqa: PLC0415 -- lazy: imports cv2, torch

    report = progress or no_progress
    path = out or ws.ads_dir / ONNX_FILE
    if path.suffix.lower() != ".onnx":
        msg = f"the export file {str(path)!r} must end in .onnx"
        raise StageError(msg)
    model, info = load_model(ws.ads_dir)
    train = ws.stage_record(TRAIN_STAGE)
    inputs = hash_inputs({"model": train.inputs_hash if train else None, "out": str(path)})
    report("exporting ONNX", 0, 1)
    with stage_run(ws, EXPORT_STAGE, inputs_hash=inputs, config=None):
        doc = export_onnx(model, info.config, path, real_inputs=_real_inputs(ws, info.config))
        doc.save(ws.ads_dir / EXPORT_REPORT)
    report("exporting ONNX", 1, 1)
    logger.info(
        "exported %s: parity %.2g (random), %s (frames)",
        path,
        doc.max_abs_diff_random,
        "n/a" if doc.max_abs_diff_real is None else f"{doc.max_abs_diff_real:.2g}",
    )
    return ExportAdsResult(path, ws.ads_dir / EXPORT_REPORT, doc)
