"""Learned detectors: models the user supplies (ONNX, torch) and mmdetection3d models.

Every detector here returns :class:`~cam2sim.detect.boxes.Boxes` of vehicles, with the model's
own score as confidence and an error model's ``sigma_m`` (see :class:`MonocularErrorModel`);
nothing is corrected by fixed factors.

Tensor contract of user-supplied models
---------------------------------------
LiDAR, ONNX (:class:`OnnxLidarDetector`):

- one input (any name; ``points`` by convention), float32 (float64 accepted), ``(N, C)`` or
  ``(1, N, C)``: x, y, z in metres in the LiDAR link frame (x forward, y left, z up), then
  intensity in ``[0, 1]`` when ``C == 4``; ``C`` is 4 (or 3: xyz only). A fixed ``N`` declared by
  the model is met by repeating points cyclically (fewer) or taking evenly spaced ones (more).

Camera, ONNX (:class:`OnnxCameraDetector`) and torch (:class:`TorchCameraDetector`):

- ``image``: float32 ``(1, 3, H, W)``, RGB, values ``pixel / 255`` in ``[0, 1]``, no mean/std
  normalisation (put it inside the model). If the model declares a fixed ``H`` and ``W`` (or the
  detector is given ``input_size``), the undistorted image is resized to it and ``K`` scaled to
  match (pixel-centre convention); otherwise the image goes in at its own size.
- ``K`` (optional second input): float32 ``(1, 3, 3)`` or ``(3, 3)`` pinhole matrix of the image
  the model sees (a declared ``4 x 4`` gets the homogeneous padding, as mmdet3d's ``cam2img``).
  ONNX inputs are matched by name (``image``, ``K``), else by rank; torch models take
  ``forward(image)`` or ``forward(image, K)``, positionally.

Outputs (all models; a leading batch dimension of 1 is dropped):

- ``boxes``: ``(M, 7)`` ``x, y, z, l, w, h, yaw``, metres and radians, geometric box centre
  (not its bottom). LiDAR: link frame, yaw about +z from +x towards +y. Camera: optical frame
  (x right, y down, z forward; ``z`` is the depth of the centre), yaw about the up axis in the
  mmdetection3d camera-box convention, so the length axis is ``(cos yaw, 0, -sin yaw)``.
  Further trailing columns (velocities) are ignored.
- ``scores``: ``(M,)`` confidence in ``[0, 1]`` (apply the sigmoid/softmax inside the model).
- ``labels`` (optional): ``(M,)`` integer class ids; only ids in ``vehicle_labels`` are kept
  (default ``{0}``; ``None`` keeps all). Without ``labels`` every box counts as a vehicle.

ONNX outputs are looked up by these names; torch models (a TorchScript archive from
``torch.jit.save`` or a ``torch.export.save`` program) return a dict with these keys or a tuple
``(boxes, scores[, labels])``. Boxes scoring below ``score_threshold`` (default 0.3) are
dropped. A model that breaks the contract raises :class:`~cam2sim.core.errors.ConfigError`
naming the inputs and outputs it actually has.

mmdetection3d (when installed): ``pointpillars:CONFIG:CHECKPOINT`` runs
``mmdet3d.apis.inference_detector`` (PointPillars boxes have their origin at the bottom centre;
converted to the centre), ``fcos3d:CONFIG:CHECKPOINT`` runs ``inference_mono_3d_detector``
(mmdet3d >= 1.1; camera boxes ``x, y, z, l, h, w, yaw`` with origin at the bottom centre).
"""

from __future__ import annotations

import logging
import pickle
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

import cv2
import numpy as np

from cam2sim.core.backends import (
    ONNX_FLOAT_TYPES,
    TORCH_HINT,
    checked_size,
    fixed_dim,
    image_tensor,
    load_torch_model,
    local_file,
    onnx_session,
    require_module,
    to_numpy,
)
from cam2sim.core.camera import PinholeCamera
from cam2sim.core.errors import ConfigError
from cam2sim.detect.boxes import Boxes

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping
    from types import ModuleType

    import numpy.typing as npt

__all__ = [
    "DEFAULT_SCORE_THRESHOLD",
    "LIDAR_SIGMA_M",
    "MMDet3DCameraDetector",
    "MMDet3DLidarDetector",
    "MonocularErrorModel",
    "OnnxCameraDetector",
    "OnnxLidarDetector",
    "TorchCameraDetector",
    "load_torch_model",
]

_log = logging.getLogger(__name__)

DEFAULT_SCORE_THRESHOLD: Final = 0.3
"""Boxes scoring below this are dropped (fusion also weights the rest by score)."""

LIDAR_SIGMA_M: Final = 0.3
"""Centre standard deviation of learned LiDAR boxes, metres: published nuScenes mean translation
errors (mATE) of LiDAR detectors lie between about 0.25 m (CenterPoint) and 0.5 m
(PointPillars)."""

_MMDET3D_HINT: Final = (
    "pip install mmdet3d (and mmcv, mmengine; OpenMMLab's route: pip install -U openmim && "
    "mim install mmengine 'mmcv>=2.0.0' 'mmdet>=3.0.0' 'mmdet3d>=1.1.0')"
)
_OUTPUTS: Final = ("boxes", "scores", "labels")
_MM_CAMERA: Final = "CAM_FRONT"


@dataclass(frozen=True)
class MonocularErrorModel:
    """How far a monocular box centre may be off, growing with depth.

    ``sigma(z) = floor_m + z**2 * pixel_sigma_px / (focal_px * object_height_m)``

    A monocular detector gets depth mainly from apparent size, ``z = f H / h``, so an error of
    ``dh`` pixels in the object's image height moves it by ``z**2 dh / (f H)``: the error grows
    with the square of depth and shrinks with focal length (``focal_px`` is the vertical focal
    length of the image the model saw). Defaults: ``floor_m`` 0.5 m is the error of near boxes
    (FCOS3D's published nuScenes test mean translation error, mATE, is 0.69 m over boxes matched
    within 2 m, most of them 10-30 m away); ``pixel_sigma_px`` 2 px is a typical 2D box-edge error
    and ``object_height_m`` 1.5 m a car's height. With the reference camera (f = 778 px) this
    gives 0.7 m at 10 m, 1.6 m at 25 m and 4.8 m at 50 m (5-10 % of depth, the range the KITTI
    monocular literature reports, e.g. MonoDLE, CVPR 2021, which finds depth the dominant error
    and drops far objects). ``max_depth_m`` (50 m, the nuScenes detection range for cars) drops
    boxes farther away. Fusion weights boxes by ``score / sigma**2``, so the weight of a camera
    box falls with distance; its score stays the model's.
    """

    floor_m: float = 0.5
    pixel_sigma_px: float = 2.0
    object_height_m: float = 1.5
    max_depth_m: float = 50.0

    def __post_init__(self) -> None:
        bad = {
            k: v
            for k, v in (
                ("floor_m", self.floor_m),
                ("pixel_sigma_px", self.pixel_sigma_px),
                ("object_height_m", self.object_height_m),
                ("max_depth_m", self.max_depth_m),
            )
            if not (np.isfinite(v) and v > 0)
        }
        if bad:
            msg = f"MonocularErrorModel needs finite positive values, got {bad!r}"
            raise ConfigError(msg)

    def sigma_m(
        self, depth_m: npt.NDArray[np.float64], *, focal_px: float
    ) -> npt.NDArray[np.float64]:
        """``(N,)`` centre standard deviation, metres, of boxes at ``depth_m`` (``(N,)``, m)."""
        z = np.asarray(depth_m, dtype=np.float64)
        return self.floor_m + z**2 * (self.pixel_sigma_px / (focal_px * self.object_height_m))


@dataclass(frozen=True)
class _Raw:
    """Detections in the contract's layout: boxes ``(M, 7)``, scores ``(M,)``, labels or None."""

    boxes: npt.NDArray[np.float64]
    scores: npt.NDArray[np.float64]
    labels: npt.NDArray[np.int64] | None


@dataclass(frozen=True)
class _Filter:
    """Which raw detections count: score threshold and vehicle class ids (None: all)."""

    score_threshold: float
    vehicle_labels: frozenset[int] | None

    def __post_init__(self) -> None:
        if not 0.0 <= self.score_threshold <= 1.0:
            msg = f"score_threshold must lie in [0, 1], got {self.score_threshold!r}"
            raise ConfigError(msg)

    def keep(self, raw: _Raw) -> npt.NDArray[np.bool_]:
        keep = raw.scores >= self.score_threshold
        if raw.labels is not None and self.vehicle_labels is not None:
            keep &= np.isin(raw.labels, np.fromiter(self.vehicle_labels, dtype=np.int64))
        return keep


def _drop_batch(a: npt.NDArray[Any], rank: int) -> npt.NDArray[Any]:
    while a.ndim > rank and a.shape[0] == 1:
        a = a[0]
    return a


def _raw_from_outputs(out: Mapping[str, npt.NDArray[Any]], model: str) -> _Raw:
    """Check the model's outputs against the contract and return them as float64/int64."""
    boxes = _drop_batch(np.asarray(out["boxes"]), 2)
    scores = _drop_batch(np.asarray(out["scores"]), 1)
    labels = None if out.get("labels") is None else _drop_batch(np.asarray(out["labels"]), 1)
    m = boxes.shape[0] if boxes.ndim == 2 else -1
    shapes_ok = boxes.ndim == 2 and boxes.shape[1] >= 7 and scores.shape == (m,)
    if not shapes_ok or (labels is not None and labels.shape != (m,)):
        got = {k: np.shape(v) for k, v in out.items()}
        msg = (
            f"{model} returned outputs of shapes {got}; the contract is boxes (M, 7), "
            "scores (M,) and optionally labels (M,) (see cam2sim.detect.learned)"
        )
        raise ConfigError(msg)
    boxes64 = boxes[:, :7].astype(np.float64)
    scores64 = scores.astype(np.float64)
    finite = np.isfinite(boxes64).all(axis=1) & np.isfinite(scores64)
    if np.any((scores64[finite] < 0.0) | (scores64[finite] > 1.0)):
        msg = (
            f"{model} returned scores outside [0, 1] (range {scores64[finite].min():.3g} to "
            f"{scores64[finite].max():.3g}); scores must be probabilities: apply the "
            "sigmoid/softmax inside the model"
        )
        raise ConfigError(msg)
    labels64 = None
    if labels is not None:
        labels64 = np.rint(labels).astype(np.int64)
        if not np.array_equal(labels64, labels):
            msg = f"{model} returned non-integer labels; labels must be class ids"
            raise ConfigError(msg)
    if not finite.all():
        _log.warning("%s: dropped %d boxes with non-finite values", model, int((~finite).sum()))
        labels64 = None if labels64 is None else labels64[finite]
    return _Raw(boxes64[finite], scores64[finite], labels64)


def _lidar_boxes(raw: _Raw, keep: npt.NDArray[np.bool_], sigma_m: float) -> Boxes:
    b = raw.boxes[keep]
    return Boxes(b[:, :3], b[:, 3:6], b[:, 6], raw.scores[keep], np.full(len(b), sigma_m), "link")


def _camera_boxes(
    raw: _Raw, keep: npt.NDArray[np.bool_], errors: MonocularErrorModel, focal_px: float
) -> Boxes:
    depth = raw.boxes[:, 2]
    keep = keep & (depth > 0.0) & (depth <= errors.max_depth_m)
    b = raw.boxes[keep]
    sigma = errors.sigma_m(b[:, 2], focal_px=focal_px)
    return Boxes(b[:, :3], b[:, 3:6], b[:, 6], raw.scores[keep], sigma, "optical")


def _box_rows(t: npt.NDArray[Any]) -> npt.NDArray[np.float64]:
    b = np.asarray(t, dtype=np.float64)
    if b.ndim != 2 or b.shape[1] < 7:
        msg = f"mmdet3d returned boxes of shape {b.shape}; expected (M, 7) or wider"
        raise ConfigError(msg)
    return b[:, :7]


def _from_mmdet3d_lidar(t: npt.NDArray[Any]) -> npt.NDArray[np.float64]:
    """LiDAR boxes ``x, y, z_bottom, dx, dy, dz, yaw`` (mmdet3d) to the contract's layout."""
    b = _box_rows(t).copy()
    b[:, 2] += 0.5 * b[:, 5]
    return b


def _from_mmdet3d_camera(t: npt.NDArray[Any]) -> npt.NDArray[np.float64]:
    """Camera boxes ``x, y_bottom, z, l, h, w, yaw`` (mmdet3d) to the contract's layout."""
    b = _box_rows(t)
    out = b.copy()
    out[:, 1] = b[:, 1] - 0.5 * b[:, 4]  # y points down: the centre is half a height above
    out[:, 4] = b[:, 5]
    out[:, 5] = b[:, 4]
    return out


def _check_points(points: npt.NDArray[Any]) -> npt.NDArray[np.float32]:
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != 4:
        msg = f"points must be (N, 4) x, y, z, intensity; got shape {pts.shape}"
        raise ValueError(msg)
    return np.ascontiguousarray(pts, dtype=np.float32)


def _check_image(
    image: npt.NDArray[Any], K: npt.NDArray[Any]
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.float64]]:
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8 or min(img.shape[:2]) < 1:
        msg = f"image must be (H, W, 3) uint8 RGB; got {img.dtype} of shape {img.shape}"
        raise ValueError(msg)
    k = np.asarray(K, dtype=np.float64)
    if k.shape != (3, 3) or not np.isfinite(k).all() or k[0, 0] <= 0 or k[1, 1] <= 0:
        msg = f"K must be a finite (3, 3) pinhole matrix with positive focal lengths; got {k!r}"
        raise ValueError(msg)
    return img, k


def _resize(
    image: npt.NDArray[np.uint8], K: npt.NDArray[np.float64], size: tuple[int, int] | None
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.float64]]:
    """Resize to ``size`` (width, height) and scale ``K`` to match (pixel centres stay aligned)."""
    h, w = image.shape[:2]
    if size is None or size == (w, h):
        return image, K
    sx, sy = size[0] / w, size[1] / h
    interp = cv2.INTER_AREA if sx * sy < 1.0 else cv2.INTER_LINEAR
    out = np.asarray(cv2.resize(image, size, interpolation=interp), dtype=np.uint8)
    return out, PinholeCamera.from_K(K, w, h).scaled(*size).K()


def _k_tensor(K: npt.NDArray[np.float64], rank: int, dim: int) -> npt.NDArray[np.float64]:
    k = np.eye(dim)
    k[:3, :3] = K
    return k[None] if rank == 3 else k


class _OnnxModel:
    """An onnxruntime session with its declared inputs and outputs."""

    def __init__(self, path: Path, role: str) -> None:
        self.path = local_file(path, "ONNX model")
        self._session = onnx_session(self.path, f"the ONNX {role} detector")
        # Any: onnxruntime is untyped; its NodeArg has .name, .shape (int | str | None), .type
        self.inputs: list[Any] = list(self._session.get_inputs())
        self.outputs: list[Any] = list(self._session.get_outputs())
        names = {o.name for o in self.outputs}
        self.fetch = [n for n in _OUTPUTS if n in names]
        box_shape = next((o.shape for o in self.outputs if o.name == "boxes"), None)
        last = None if not box_shape else box_shape[-1]
        if "boxes" not in names or "scores" not in names or (isinstance(last, int) and last < 7):
            msg = f"{role} model outputs must include boxes (M, 7) and scores (M,)"
            raise self.error(msg)
        _log.info("ONNX %s model %s on %s", role, self.path.name, self._session.get_providers()[0])

    def describe(self) -> str:
        """The model's actual inputs and outputs, for error messages."""

        def part(args: list[Any]) -> str:
            return ", ".join(f"{a.name} {a.type} {list(a.shape)}" for a in args)

        return f"it has inputs [{part(self.inputs)}] and outputs [{part(self.outputs)}]"

    def error(self, what: str) -> ConfigError:
        """A ConfigError saying what the contract wants and what the model has."""
        msg = f"{self.path.name}: {what}; {self.describe()} (contract: cam2sim.detect.learned)"
        return ConfigError(msg)

    def dtype(self, arg: Any) -> type[np.floating[Any]]:  # Any: an onnxruntime NodeArg
        if arg.type not in ONNX_FLOAT_TYPES:
            msg = f"input {arg.name!r} must be float32 or float64"
            raise self.error(msg)
        return ONNX_FLOAT_TYPES[arg.type]

    def run(self, feeds: dict[str, npt.NDArray[Any]]) -> dict[str, npt.NDArray[Any]]:
        try:
            values = self._session.run(self.fetch, feeds)
        except Exception as err:  # onnxruntime's errors derive from Exception only
            shapes = {k: v.shape for k, v in feeds.items()}
            msg = f"inference failed on inputs of shapes {shapes} ({err})"
            raise self.error(msg) from err
        return {n: np.asarray(v) for n, v in zip(self.fetch, values, strict=True)}


def _fit_count(points: npt.NDArray[np.float32], n: int) -> npt.NDArray[np.float32]:
    """Exactly ``n`` points: evenly spaced ones when there are more, repeated when fewer."""
    if len(points) >= n:
        return points[np.linspace(0, len(points) - 1, n).round().astype(np.int64)]
    return points[np.arange(n) % len(points)]


class OnnxLidarDetector:
    """A user-supplied ONNX model run on LiDAR scans (contract in the module doc).

    Args:
        path: The ``.onnx`` file.
        score_threshold: Boxes scoring below this are dropped.
        vehicle_labels: Class ids that count as vehicles (None: all classes).
        sigma_m: Centre standard deviation given to every box, metres.
    """

    name: str

    def __init__(
        self,
        path: Path,
        *,
        score_threshold: float = DEFAULT_SCORE_THRESHOLD,
        vehicle_labels: frozenset[int] | None = frozenset({0}),
        sigma_m: float = LIDAR_SIGMA_M,
    ) -> None:
        self._filter = _Filter(score_threshold, vehicle_labels)
        if not sigma_m > 0:
            msg = f"sigma_m must be positive, got {sigma_m!r}"
            raise ConfigError(msg)
        self._sigma_m = sigma_m
        self._model = _OnnxModel(Path(path), "LiDAR")
        self.name = f"onnx:{self._model.path.name}"
        if len(self._model.inputs) != 1:
            msg = "a LiDAR model takes one input, points (N, 4) or (1, N, 4)"
            raise self._model.error(msg)
        arg = self._model.inputs[0]
        shape = list(arg.shape)
        channels = fixed_dim(shape[-1]) if shape else None
        batch_ok = len(shape) == 2 or fixed_dim(shape[0]) in (None, 1)
        if len(shape) not in (2, 3) or channels not in (None, 3, 4) or not batch_ok:
            msg = "the points input must be (N, 4) or (1, N, 4), or with 3 channels"
            raise self._model.error(msg)
        self._input, self._rank, self._dtype = arg.name, len(shape), self._model.dtype(arg)
        self._channels = channels or 4
        self._count = fixed_dim(shape[-2])

    def detect(self, points: npt.NDArray[np.float32]) -> Boxes:
        """Boxes (``axes="link"``) of the vehicles in one scan.

        Args:
            points: ``(N, 4)`` x, y, z (metres, LiDAR link frame) and intensity in ``[0, 1]``.
        """
        pts = _check_points(points)[:, : self._channels]
        if len(pts) == 0:
            return Boxes.empty("link")
        if self._count is not None:
            pts = _fit_count(pts, self._count)
        x = pts[None] if self._rank == 3 else pts
        raw = _raw_from_outputs(self._model.run({self._input: x.astype(self._dtype)}), self.name)
        return _lidar_boxes(raw, self._filter.keep(raw), self._sigma_m)


class OnnxCameraDetector:
    """A user-supplied monocular 3D ONNX model run on camera images (contract in the module doc).

    Args:
        path: The ``.onnx`` file.
        score_threshold: Boxes scoring below this are dropped.
        vehicle_labels: Class ids that count as vehicles (None: all classes).
        error_model: Gives each box its ``sigma_m`` and the depth cut.
        input_size: ``(width, height)`` to resize images to; None uses the size the model
            declares, or the image's own size when the model's is dynamic.
    """

    name: str

    def __init__(
        self,
        path: Path,
        *,
        score_threshold: float = DEFAULT_SCORE_THRESHOLD,
        vehicle_labels: frozenset[int] | None = frozenset({0}),
        error_model: MonocularErrorModel | None = None,
        input_size: tuple[int, int] | None = None,
    ) -> None:
        self._filter = _Filter(score_threshold, vehicle_labels)
        self._errors = error_model or MonocularErrorModel()
        model = self._model = _OnnxModel(Path(path), "camera")
        self.name = f"onnx:{model.path.name}"
        by_name = {a.name: a for a in model.inputs}
        image = by_name.get("image") or next((a for a in model.inputs if len(a.shape) == 4), None)
        rest = [a for a in model.inputs if a is not image]
        k_arg = by_name.get("K") or (rest[0] if len(rest) == 1 else None)
        shape = list(image.shape) if image is not None else []
        ok_image = (
            len(shape) == 4
            and fixed_dim(shape[0]) in (None, 1)
            and fixed_dim(shape[1]) in (None, 3)
        )
        k_shape = list(k_arg.shape) if k_arg is not None else [3, 3]
        ok_k = len(k_shape) in (2, 3) and fixed_dim(k_shape[-1]) in (None, 3, 4)
        if image is None or not (ok_image and ok_k) or len(model.inputs) != 1 + (k_arg is not None):
            msg = "a camera model takes image (1, 3, H, W) and optionally K (1, 3, 3)"
            raise model.error(msg)
        self._image, self._image_dtype = image.name, model.dtype(image)
        self._k = None if k_arg is None else (k_arg.name, model.dtype(k_arg))
        self._k_rank, self._k_dim = len(k_shape), fixed_dim(k_shape[-1]) or 3
        h, w = fixed_dim(shape[2]), fixed_dim(shape[3])
        declared = (w, h) if w is not None and h is not None else None
        self._size = checked_size(input_size) or declared
        if declared is not None and self._size != declared:
            msg = f"input_size {input_size!r} differs from the model's fixed size {declared}"
            raise model.error(msg)

    def detect(self, image: npt.NDArray[np.uint8], K: npt.NDArray[np.float64]) -> Boxes:
        """Boxes (``axes="optical"``) of the vehicles in one image.

        Args:
            image: ``(H, W, 3)`` undistorted RGB image.
            K: ``(3, 3)`` pinhole matrix of ``image``.
        """
        img, k = _resize(*_check_image(image, K), self._size)
        feeds = {self._image: image_tensor(img).astype(self._image_dtype)}
        if self._k is not None:
            feeds[self._k[0]] = _k_tensor(k, self._k_rank, self._k_dim).astype(self._k[1])
        raw = _raw_from_outputs(self._model.run(feeds), self.name)
        return _camera_boxes(raw, self._filter.keep(raw), self._errors, float(k[1, 1]))


class TorchCameraDetector:
    """A user-supplied monocular 3D torch model (TorchScript or ``torch.export`` archive).

    The contract is in the module doc. A ``torch.export`` program traced with a fixed image size
    declares it (the image is then resized and ``K`` scaled); TorchScript declares none, so give
    ``input_size`` if the model needs one.

    Args:
        path: The ``.pt`` / ``.pth`` / ``.ts`` archive.
        score_threshold: Boxes scoring below this are dropped.
        vehicle_labels: Class ids that count as vehicles (None: all classes).
        error_model: Gives each box its ``sigma_m`` and the depth cut.
        input_size: ``(width, height)`` to resize images to (None: as declared, or unchanged).
        device: torch device to run on.
    """

    name: str

    def __init__(
        self,
        path: Path,
        *,
        score_threshold: float = DEFAULT_SCORE_THRESHOLD,
        vehicle_labels: frozenset[int] | None = frozenset({0}),
        error_model: MonocularErrorModel | None = None,
        input_size: tuple[int, int] | None = None,
        device: str = "cpu",
    ) -> None:
        path = local_file(Path(path), "torch model")
        require_module("torch", TORCH_HINT, "the torch camera detector")
        self._filter = _Filter(score_threshold, vehicle_labels)
        self._errors = error_model or MonocularErrorModel()
        self.name = f"torch:{path.name}"
        self._device = device
        self._module, n_inputs, declared = load_torch_model(path, device)
        if n_inputs not in (1, 2):
            msg = (
                f"{path.name}: forward takes {n_inputs} inputs; the contract is forward(image) "
                "or forward(image, K) (see cam2sim.detect.learned)"
            )
            raise ConfigError(msg)
        self._takes_k = n_inputs == 2
        self._size = checked_size(input_size) or declared
        if declared is not None and self._size != declared:
            msg = f"{path.name}: input_size {input_size!r} differs from its fixed size {declared}"
            raise ConfigError(msg)

    def detect(self, image: npt.NDArray[np.uint8], K: npt.NDArray[np.float64]) -> Boxes:
        """Boxes (``axes="optical"``) of the vehicles in one image.

        Args:
            image: ``(H, W, 3)`` undistorted RGB image.
            K: ``(3, 3)`` pinhole matrix of ``image``.
        """
        import torch  # noqa: PLC0415  (an optional backend; checked in __init__)

        img, k = _resize(*_check_image(image, K), self._size)
        args = [torch.from_numpy(image_tensor(img)).to(self._device)]
        if self._takes_k:
            k32 = _k_tensor(k, 3, 3).astype(np.float32)
            args.append(torch.from_numpy(k32).to(self._device))
        try:
            with torch.inference_mode(), warnings.catch_warnings():
                warnings.filterwarnings("ignore", r".*torch\.jit", DeprecationWarning)
                out = self._module(*args)
        except (RuntimeError, ValueError, TypeError) as err:
            msg = f"{self.name}: inference failed on image {tuple(args[0].shape)} ({err})"
            raise ConfigError(msg) from err
        raw = _raw_from_outputs(_torch_outputs(out, self.name), self.name)
        return _camera_boxes(raw, self._filter.keep(raw), self._errors, float(k[1, 1]))


def _torch_outputs(out: object, model: str) -> dict[str, npt.NDArray[Any]]:
    """A torch model's dict or tuple result as named numpy arrays."""
    if isinstance(out, dict):
        named = {str(key): value for key, value in out.items()}
    elif isinstance(out, (tuple, list)) and len(out) in (2, 3):
        named = dict(zip(_OUTPUTS, out, strict=False))
    else:
        named = {}
    if "boxes" not in named or "scores" not in named:
        got = sorted(named) if isinstance(out, dict) else type(out).__name__
        msg = (
            f"{model} returned {got!r}; the contract is a dict with keys boxes, scores "
            "(and optionally labels), or a tuple (boxes, scores[, labels])"
        )
        raise ConfigError(msg)
    return {n: to_numpy(named[n]) for n in _OUTPUTS if named.get(n) is not None}


def _mmdet3d_raw(result: Any, model: str, convert: Callable[..., Any]) -> _Raw:
    """An mmdet3d ``Det3DDataSample`` (or ``(sample, data)``) as contract-layout detections."""
    # Any: mmdet3d results are untyped InstanceData of torch tensors.
    sample = result[0] if isinstance(result, (tuple, list)) else result
    pred = sample.pred_instances_3d
    boxes = convert(to_numpy(pred.bboxes_3d.tensor))
    raw = {"boxes": boxes, "scores": to_numpy(pred.scores_3d)}
    return _raw_from_outputs({**raw, "labels": to_numpy(pred.labels_3d)}, model)


def _mmdet3d_model(
    config: Path, checkpoint: Path, device: str | None, what: str
) -> tuple[ModuleType, Any]:
    """Check the files, import ``mmdet3d.apis`` and build the model (Any: an nn.Module)."""
    config = local_file(Path(config), "mmdet3d config")
    checkpoint = local_file(Path(checkpoint), "mmdet3d checkpoint")
    apis = require_module("mmdet3d.apis", _MMDET3D_HINT, what)
    if device is None:
        import torch  # noqa: PLC0415  (mmdet3d depends on torch)

        device = "cuda:0" if torch.cuda.is_available() else "cpu"
    try:
        return apis, apis.init_model(str(config), str(checkpoint), device=device)
    except (RuntimeError, ValueError, KeyError, TypeError, OSError) as err:
        msg = f"mmdet3d cannot build {what} from {str(config)!r} and {str(checkpoint)!r}: {err}"
        raise ConfigError(msg) from err


class MMDet3DLidarDetector:
    """PointPillars (or another mmdetection3d LiDAR detector), when mmdet3d is installed.

    Args:
        config_path: mmdet3d config file (e.g. the KITTI 3-class PointPillars config).
        checkpoint_path: Its checkpoint.
        score_threshold: Boxes scoring below this are dropped.
        vehicle_labels: Class ids that count as vehicles; default ``{2}``, Car in the KITTI
            3-class configs (Pedestrian, Cyclist, Car).
        sigma_m: Centre standard deviation given to every box, metres.
        device: torch device; None picks ``cuda:0`` when available, else ``cpu``.
    """

    name: str

    def __init__(
        self,
        config_path: Path,
        checkpoint_path: Path,
        *,
        score_threshold: float = DEFAULT_SCORE_THRESHOLD,
        vehicle_labels: frozenset[int] | None = frozenset({2}),
        sigma_m: float = LIDAR_SIGMA_M,
        device: str | None = None,
    ) -> None:
        self._filter = _Filter(score_threshold, vehicle_labels)
        if not sigma_m > 0:
            msg = f"sigma_m must be positive, got {sigma_m!r}"
            raise ConfigError(msg)
        self._sigma_m = sigma_m
        self._apis, self._model = _mmdet3d_model(config_path, checkpoint_path, device, "LiDAR")
        self.name = f"pointpillars:{Path(checkpoint_path).name}"

    def detect(self, points: npt.NDArray[np.float32]) -> Boxes:
        """Boxes (``axes="link"``) of the vehicles in one scan (``(N, 4)`` x, y, z, intensity)."""
        pts = _check_points(points)
        if len(pts) == 0:
            return Boxes.empty("link")
        result = self._apis.inference_detector(self._model, pts)
        raw = _mmdet3d_raw(result, self.name, _from_mmdet3d_lidar)
        return _lidar_boxes(raw, self._filter.keep(raw), self._sigma_m)


class MMDet3DCameraDetector:
    """FCOS3D (or another mmdetection3d monocular detector), when mmdet3d >= 1.1 is installed.

    Each image is written, with its ``K`` as ``cam2img``, to a temporary folder for
    ``mmdet3d.apis.inference_mono_3d_detector``, which reads files only.

    Args:
        config_path: mmdet3d config file (e.g. the nuScenes FCOS3D config).
        checkpoint_path: Its checkpoint.
        score_threshold: Boxes scoring below this are dropped.
        vehicle_labels: Class ids that count as vehicles; default ``{0}``, car in the nuScenes
            classes.
        error_model: Gives each box its ``sigma_m`` and the depth cut.
        device: torch device; None picks ``cuda:0`` when available, else ``cpu``.
    """

    name: str

    def __init__(
        self,
        config_path: Path,
        checkpoint_path: Path,
        *,
        score_threshold: float = DEFAULT_SCORE_THRESHOLD,
        vehicle_labels: frozenset[int] | None = frozenset({0}),
        error_model: MonocularErrorModel | None = None,
        device: str | None = None,
    ) -> None:
        self._filter = _Filter(score_threshold, vehicle_labels)
        self._errors = error_model or MonocularErrorModel()
        self._apis, self._model = _mmdet3d_model(config_path, checkpoint_path, device, "camera")
        self.name = f"fcos3d:{Path(checkpoint_path).name}"

    def detect(self, image: npt.NDArray[np.uint8], K: npt.NDArray[np.float64]) -> Boxes:
        """Boxes (``axes="optical"``) of the vehicles in one undistorted RGB image with ``K``."""
        img, k = _check_image(image, K)
        with tempfile.TemporaryDirectory(prefix="cam2sim-mono3d-") as tmp:
            image_path, info_path = Path(tmp) / "frame.png", Path(tmp) / "frame.pkl"
            if not cv2.imwrite(str(image_path), np.ascontiguousarray(img[:, :, ::-1])):  # BGR
                msg = f"cannot write a temporary image to {tmp!r} for mmdet3d"
                raise OSError(msg)
            info = {"images": {_MM_CAMERA: {"img_path": image_path.name, "cam2img": k.tolist()}}}
            info_path.write_bytes(pickle.dumps({"metainfo": {}, "data_list": [info]}))
            result = self._apis.inference_mono_3d_detector(
                self._model, str(image_path), str(info_path), cam_type=_MM_CAMERA
            )
        raw = _mmdet3d_raw(result, self.name, _from_mmdet3d_camera)
        return _camera_boxes(raw, self._filter.keep(raw), self._errors, float(k[1, 1]))
