"""Camera calibration files as the calibration tools write them.

A real recording's camera comes calibrated by whatever tool its owner used. This module reads
the files those tools write into one record (:class:`CameraFile`: ``K``, the size, the
distortion and its model), so that ``cam2sim import --calibration FILE`` takes them as they
are:

- **ROS** ``camera_calibration`` / ``camera_info`` YAML (``image_width``, ``camera_matrix:
  {rows, cols, data}``, ``distortion_model``, ``distortion_coefficients``);
- **OpenCV** ``FileStorage`` YAML (``%YAML:1.0`` or ``%YAML 1.2``, ``!!opencv-matrix``) and XML
  (``<opencv_storage>``), under the key names OpenCV's samples and common scripts use
  (``camera_matrix``/``cameraMatrix``/``K``, ``distortion_coefficients``/``distCoeffs``/``D``,
  ``image_width``/``image_height`` or ``imageSize``);
- **Kalibr** camera chains (``cam0: {camera_model, intrinsics: [fu, fv, pu, pv],
  distortion_model, distortion_coeffs, resolution}``) and the EuRoC ``sensor.yaml`` of the same
  fields;
- **COLMAP** ``cameras.txt`` (``SIMPLE_PINHOLE``, ``PINHOLE``, ``SIMPLE_RADIAL``, ``RADIAL``,
  ``OPENCV``, ``FULL_OPENCV``, ``OPENCV_FISHEYE``);
- **nerfstudio** / instant-ngp ``transforms.json`` (``fl_x``, ``fl_y``, ``cx``, ``cy``, ``w``,
  ``h``, ``k1``..``p2``, ``camera_model``) and any JSON or YAML of ``fx``, ``fy``, ``cx``,
  ``cy`` (``width``, ``height``) or of ``K``.

Distortion models map onto the two the project undistorts (:mod:`cam2sim.core.camera`):
OpenCV's polynomial (``plumb_bob``, ``rational_polynomial``, Kalibr's ``radtan``) and the
equidistant fisheye (``equidistant``, ``fisheye``, Kannala-Brandt with four coefficients). A
model outside them (an omnidirectional camera) is refused naming it. A file that gives no size
leaves it to the images.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Final

import numpy as np
import numpy.typing as npt

from cam2sim.core.errors import RecordingError

if TYPE_CHECKING:
    from pathlib import Path

    from cam2sim.core.camera import DistortionModel

__all__ = ["CameraFile", "camera_from_mapping", "model_named", "read_camera_text"]

_MODELS: Final[dict[str, DistortionModel]] = {
    "plumb_bob": "plumb_bob",
    "rational_polynomial": "plumb_bob",
    "radtan": "plumb_bob",
    "radial-tangential": "plumb_bob",
    "radial_tangential": "plumb_bob",
    "brown": "plumb_bob",
    "brown_conrady": "plumb_bob",
    "opencv": "plumb_bob",
    "full_opencv": "plumb_bob",
    "pinhole": "plumb_bob",
    "none": "plumb_bob",
    "equidistant": "equidistant",
    "fisheye": "equidistant",
    "opencv_fisheye": "equidistant",
    "kannala_brandt": "equidistant",
    "kannala-brandt": "equidistant",
    "kb4": "equidistant",
}
"""Distortion model names as tools write them (lower case) -> the model undistorted here."""

_PLUMB_BOB_LENGTHS: Final = (0, 4, 5, 8, 12, 14)
"""Coefficient counts OpenCV's polynomial model takes (k1, k2, p1, p2[, k3[, k4..k6[, ...]]])."""

_COLMAP_MODELS: Final[dict[str, tuple[int, DistortionModel]]] = {
    "SIMPLE_PINHOLE": (3, "plumb_bob"),
    "PINHOLE": (4, "plumb_bob"),
    "SIMPLE_RADIAL": (4, "plumb_bob"),
    "RADIAL": (5, "plumb_bob"),
    "OPENCV": (8, "plumb_bob"),
    "FULL_OPENCV": (12, "plumb_bob"),
    "OPENCV_FISHEYE": (8, "equidistant"),
}
"""COLMAP camera models read here: their parameter count and distortion model."""

_K_KEYS: Final = ("camera_matrix", "cameraMatrix", "Camera_Matrix", "K", "intrinsic_matrix")
_D_KEYS: Final = (
    "distortion_coefficients",
    "Distortion_Coefficients",
    "distortion_coeffs",
    "dist_coeffs",
    "distCoeffs",
    "distortion",
    "D",
)
_MODEL_KEYS: Final = ("distortion_model", "camera_model", "model")


@dataclass(frozen=True)
class CameraFile:
    """One camera as a calibration file gives it.

    Attributes:
        K: ``(3, 3)`` intrinsics, pixels.
        width: Image width the calibration is for; None when the file does not say.
        height: Image height; None when the file does not say.
        distortion: Lens distortion coefficients of ``model``.
        model: ``plumb_bob`` (OpenCV's polynomial) or ``equidistant`` (fisheye).
        form: What kind of file it was, for messages (``ROS camera_info YAML``...).
        notes: What was chosen or assumed (another camera of a chain left out...).
    """

    K: npt.NDArray[np.float64]
    width: int | None
    height: int | None
    distortion: tuple[float, ...]
    model: DistortionModel
    form: str
    notes: tuple[str, ...] = field(default=())


def read_camera_text(path: Path, text: str) -> CameraFile | None:
    """The camera of a YAML, OpenCV XML or COLMAP ``cameras.txt`` calibration; else None.

    None means the text is none of these forms (the caller tries its own); a file of one of
    them that lacks what a camera needs raises.

    Raises:
        RecordingError: The file is of a known form but malformed, or its camera model is one
            this project cannot undistort; the message names the file and the element.
    """
    head = text.lstrip()[:200]
    if "<opencv_storage>" in head:
        return camera_from_mapping(path, _opencv_xml(path), "OpenCV FileStorage XML")
    colmap = _colmap(path, text)
    if colmap is not None:
        return colmap
    data = _yaml(text)
    if not isinstance(data, dict):
        return None
    opencv = head.startswith("%YAML") and "!!opencv-matrix" in text
    form = "OpenCV FileStorage YAML" if opencv else "YAML"
    return camera_from_mapping(path, data, form)


def camera_from_mapping(path: Path, data: dict[str, Any], form: str) -> CameraFile | None:
    """The camera of a parsed calibration (YAML, JSON or OpenCV); None if it holds none.

    Raises:
        RecordingError: A camera is there but malformed or of an unsupported model.
    """
    for read in (_chain, _sensor, _transforms, _k_style):
        cam = read(path, data, form)
        if cam is not None:
            return cam
    return None


def _chain(path: Path, data: dict[str, Any], _form: str) -> CameraFile | None:
    """A Kalibr camera chain (``cam0``, ``cam1``...): its first camera."""
    chain = sorted(k for k, v in data.items() if _is_kalibr_camera(k, v))
    if not chain:
        return None
    cam = _kalibr(path, data[chain[0]], f"Kalibr camera chain ({chain[0]})")
    if len(chain) > 1:
        others = ", ".join(chain[1:])
        cam = _with_note(
            cam, f"{path.name}: took {chain[0]}, the first of its cameras (not {others})"
        )
    return cam


def _sensor(path: Path, data: dict[str, Any], _form: str) -> CameraFile | None:
    """One camera of Kalibr's fields at the top level (EuRoC's ``sensor.yaml``)."""
    if not _is_list(data.get("intrinsics"), 4):
        return None
    return _kalibr(path, data, "Kalibr / EuRoC sensor YAML")


def _transforms(path: Path, data: dict[str, Any], _form: str) -> CameraFile | None:
    """The intrinsics of a ``transforms.json``, at the top level or on its first frame."""
    if "fl_x" in data or "camera_angle_x" in data:
        return _nerfstudio(path, data)
    frames = data.get("frames")
    if isinstance(frames, list) and frames and isinstance(frames[0], dict) and "fl_x" in frames[0]:
        cam = _nerfstudio(path, {**data, **frames[0]})
        return _with_note(cam, f"{path.name}: the intrinsics of its first frame")
    return None


def _k_style(path: Path, data: dict[str, Any], form: str) -> CameraFile | None:
    """A K matrix under one of its usual names (ROS, OpenCV, plain), or ``fx, fy, cx, cy``."""
    key = next((k for k in _K_KEYS if k in data), None)
    if key is not None:
        form = "ROS camera_info YAML" if "image_width" in data and form == "YAML" else form
        return _camera(path, data, _matrix(path, data[key], key, (3, 3)), form)
    if not all(k in data for k in ("fx", "fy", "cx", "cy")):
        return None
    K = np.array(
        [[_num(path, data, "fx"), 0.0, _num(path, data, "cx")],
         [0.0, _num(path, data, "fy"), _num(path, data, "cy")],
         [0.0, 0.0, 1.0]],
    )  # fmt: skip
    return _camera(path, data, K, form)


# -- the forms ----------------------------------------------------------------------------------


def _camera(path: Path, data: dict[str, Any], K: npt.NDArray[np.float64], form: str) -> CameraFile:
    """A K-style mapping (ROS, OpenCV, plain): size, distortion and model from its keys."""
    width, height = _size(path, data)
    dkey = next((k for k in _D_KEYS if k in data), None)
    coeffs = () if dkey is None else tuple(_matrix(path, data[dkey], dkey, None).ravel())
    named = next((str(data[k]) for k in _MODEL_KEYS if isinstance(data.get(k), str)), None)
    model = model_named(path, named)
    return CameraFile(K, width, height, _checked(path, coeffs, model), model, form)


def _kalibr(path: Path, cam: dict[str, Any], form: str) -> CameraFile:
    """Kalibr's ``camera_model`` / ``intrinsics`` / ``distortion_*`` / ``resolution``."""
    camera_model = str(cam.get("camera_model", "pinhole")).lower()
    if camera_model != "pinhole":
        msg = (
            f"{path}: camera_model {camera_model!r} (Kalibr) is not a pinhole camera; "
            "calibrate it as pinhole with radtan or equidistant distortion"
        )
        raise RecordingError(msg)
    fu, fv, pu, pv = (float(v) for v in _matrix(path, cam["intrinsics"], "intrinsics", (4,)))
    K = np.array([[fu, 0.0, pu], [0.0, fv, pv], [0.0, 0.0, 1.0]])
    coeffs = tuple(
        float(v)
        for key in ("distortion_coeffs", "distortion_coefficients")
        if key in cam
        for v in _matrix(path, cam[key], key, None).ravel()
    )
    model = model_named(path, cam.get("distortion_model"))
    width, height = _size(path, cam)
    return CameraFile(K, width, height, _checked(path, coeffs, model), model, form)


def _nerfstudio(path: Path, data: dict[str, Any]) -> CameraFile:
    """The intrinsics of nerfstudio's / instant-ngp's ``transforms.json``."""
    width, height = _size(path, data)
    if "fl_x" in data:
        fx = _num(path, data, "fl_x")
        fy = _num(path, data, "fl_y") if "fl_y" in data else fx
    else:  # instant-ngp: the horizontal field of view, radians
        if width is None:
            msg = f"{path}: camera_angle_x needs the image width (w)"
            raise RecordingError(msg)
        fx = 0.5 * width / np.tan(0.5 * _num(path, data, "camera_angle_x"))
        fy = fx
    cx = _num(path, data, "cx") if "cx" in data else (width or 0) / 2.0
    cy = _num(path, data, "cy") if "cy" in data else (height or 0) / 2.0
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    kind = str(data.get("camera_model", "OPENCV")).lower()
    if kind not in ("opencv", "opencv_fisheye", "pinhole"):
        msg = (
            f"{path}: camera_model {kind.upper()} is not a pinhole camera; use OPENCV or "
            "OPENCV_FISHEYE"
        )
        raise RecordingError(msg)
    model = _MODELS[kind]
    names = ("k1", "k2", "k3", "k4") if model == "equidistant" else ("k1", "k2", "p1", "p2", "k3")
    coeffs = _checked(path, tuple(float(data.get(n, 0.0)) for n in names), model)
    return CameraFile(K, width, height, coeffs, model, "nerfstudio transforms.json")


def _colmap(path: Path, text: str) -> CameraFile | None:
    """COLMAP's ``cameras.txt``: ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS...``; None if not one."""
    rows = [
        ln.split() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")
    ]
    if not rows or len(rows[0]) < 5 or not rows[0][1].isupper() or not rows[0][0].isdigit():
        return None
    _, name, w, h, *params = rows[0]
    if name not in _COLMAP_MODELS:
        known = ", ".join(_COLMAP_MODELS)
        msg = f"{path}: COLMAP camera model {name} is not read here; use one of {known}"
        raise RecordingError(msg)
    count, model = _COLMAP_MODELS[name]
    try:
        p = [float(v) for v in params]
        width, height = int(w), int(h)
    except ValueError:
        msg = f"{path}: line {' '.join(rows[0])!r} is not CAMERA_ID MODEL WIDTH HEIGHT PARAMS"
        raise RecordingError(msg) from None
    if len(p) != count:
        msg = f"{path}: a COLMAP {name} camera has {count} parameters, this one {len(p)}"
        raise RecordingError(msg)
    if name.startswith("SIMPLE") or name == "RADIAL":
        fx, cx, cy, *coeffs = p
        fy = fx
    else:
        fx, fy, cx, cy, *coeffs = p
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    notes = (
        (f"{path.name}: took camera {rows[0][0]}, the first of {len(rows)}",)
        if len(rows) > 1
        else ()
    )
    form = f"COLMAP cameras.txt ({name})"
    return CameraFile(K, width, height, _checked(path, tuple(coeffs), model), model, form, notes)


# -- parsing ------------------------------------------------------------------------------------


def _yaml(text: str) -> Any:
    """YAML, OpenCV's ``%YAML:1.0`` and ``!!opencv-matrix`` included; None if not YAML."""
    import yaml  # noqa: PLC0415 -- lazy: only calibration files need it here

    class _Loader(yaml.SafeLoader):
        pass

    def _opencv_matrix(loader: yaml.SafeLoader, _suffix: str, node: yaml.Node) -> Any:
        return loader.construct_mapping(node, deep=True)  # type: ignore[arg-type]

    # !!opencv-matrix and !!opencv-nd-matrix: mappings whose data is the matrix
    _Loader.add_multi_constructor("tag:yaml.org,2002:opencv-", _opencv_matrix)
    lines = text.splitlines()
    if lines and lines[0].startswith("%YAML"):  # OpenCV's "%YAML:1.0" is not YAML's directive
        lines = lines[1:]
    try:
        return yaml.load("\n".join(lines), Loader=_Loader)  # noqa: S506 -- a SafeLoader subclass
    except yaml.YAMLError:
        return None


def _opencv_xml(path: Path) -> dict[str, Any]:
    """The top-level nodes of an OpenCV FileStorage XML (matrices as arrays)."""
    import cv2  # noqa: PLC0415 -- lazy: heavy

    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    if not fs.isOpened():
        msg = f"{path}: OpenCV cannot read this FileStorage XML; check the file is whole"
        raise RecordingError(msg)
    try:
        out: dict[str, Any] = {}
        root = fs.root()
        for key in root.keys():  # noqa: SIM118 -- a cv2.FileNode, not a dict
            node = root.getNode(key)
            if node.isMap():
                mat = node.mat()
                if mat is not None:
                    out[key] = np.asarray(mat, dtype=np.float64)
            elif node.isSeq():
                out[key] = [node.at(i).real() for i in range(node.size())]
            elif node.isString():
                out[key] = node.string()
            elif node.isInt() or node.isReal():
                out[key] = node.real()
        return out
    finally:
        fs.release()


def _matrix(
    path: Path, value: Any, key: str, shape: tuple[int, ...] | None
) -> npt.NDArray[np.float64]:
    """A matrix as files write it: a list (flat or nested), ``{rows, cols, data}``, an array."""
    if isinstance(value, dict):
        value = value.get("data")
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        array = np.empty(0)
    if (
        array.dtype != np.float64
        or not np.all(np.isfinite(array))
        or (shape is not None and array.size != int(np.prod(shape)))
    ):
        want = "x".join(str(s) for s in shape) if shape else "a list of numbers"
        msg = f"{path}: {key} should be {want} finite numbers, found {value!r}"
        raise RecordingError(msg)
    return array.reshape(shape) if shape is not None else array.ravel()


def _num(path: Path, data: dict[str, Any], key: str) -> float:
    try:
        value = float(data[key])
    except (KeyError, TypeError, ValueError):
        msg = f"{path}: {key} should be a number, found {data.get(key)!r}"
        raise RecordingError(msg) from None
    if not np.isfinite(value):
        msg = f"{path}: {key} should be finite, found {value!r}"
        raise RecordingError(msg)
    return value


def _size(path: Path, data: dict[str, Any]) -> tuple[int | None, int | None]:
    """The image size a mapping names (width/height pairs, ``resolution``, ``imageSize``)."""
    for wk, hk in (("image_width", "image_height"), ("width", "height"), ("w", "h")):
        if wk in data and hk in data:
            return int(_num(path, data, wk)), int(_num(path, data, hk))
    for key in ("resolution", "imageSize", "image_size"):
        if key in data:
            w, h = _matrix(path, data[key], key, (2,))
            return int(w), int(h)
    return None, None


def model_named(where: object, named: Any) -> DistortionModel:
    """The distortion model a tool's name stands for (None: OpenCV's polynomial).

    Raises:
        RecordingError: The name is no model undistorted here; the message names ``where``.
    """
    if named is None or named == "":
        return "plumb_bob"
    model = _MODELS.get(str(named).lower())
    if model is None:
        known = ", ".join(sorted(_MODELS))
        msg = (
            f"{where}: distortion model {named!r} is not one this project undistorts ({known}); "
            "recalibrate with a polynomial or equidistant model"
        )
        raise RecordingError(msg)
    return model


def _checked(path: Path, coeffs: tuple[float, ...], model: DistortionModel) -> tuple[float, ...]:
    """Coefficients in a count the model takes (all zero -> none)."""
    coeffs = tuple(float(c) for c in coeffs)
    if not any(coeffs):
        return ()
    if model == "equidistant":
        if len(coeffs) != 4:
            n = len(coeffs)
            msg = f"{path}: an equidistant (fisheye) lens has 4 coefficients k1..k4, found {n}"
            raise RecordingError(msg)
        return coeffs
    if len(coeffs) < 4:  # radial terms only (k1[, k2]): no tangential ones
        coeffs = (*coeffs, *([0.0] * (4 - len(coeffs))))
    if len(coeffs) not in _PLUMB_BOB_LENGTHS:
        msg = (
            f"{path}: {len(coeffs)} distortion coefficients; OpenCV's model takes 4, 5, 8, 12 "
            "or 14 (k1, k2, p1, p2[, k3, ...])"
        )
        raise RecordingError(msg)
    return coeffs


def _is_kalibr_camera(key: str, value: Any) -> bool:
    return key.startswith("cam") and isinstance(value, dict) and "intrinsics" in value


def _is_list(value: Any, n: int) -> bool:
    return isinstance(value, list) and len(value) == n


def _with_note(cam: CameraFile, note: str) -> CameraFile:
    return CameraFile(
        cam.K, cam.width, cam.height, cam.distortion, cam.model, cam.form, (*cam.notes, note)
    )
