"""The ``Detector`` interfaces and loading a detector by name.

A LiDAR detector sees one scan in the LiDAR link frame; a camera detector one undistorted RGB
image with its pinhole matrix. Both return :class:`~cam2sim.detect.boxes.Boxes` of vehicles
(cars, vans) in their sensor frame; fusion across frames is shared code
(:mod:`cam2sim.detect.fusion`).

Names accepted by :func:`load_detector`:

- ``geometric`` (LiDAR, the default): ground removal, clustering and box fitting, no weights
  (:mod:`cam2sim.detect.lidar`);
- a path ending ``.onnx``: an ONNX model run with onnxruntime (LiDAR or camera; the tensor
  contract is in :mod:`cam2sim.detect.learned`);
- a path ending ``.pt``, ``.pth`` or ``.ts`` (camera): a TorchScript model;
- ``pointpillars:CONFIG:CHECKPOINT`` (LiDAR) or ``fcos3d:CONFIG:CHECKPOINT`` (camera):
  mmdetection3d models, when mmdet3d is installed.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Literal, Protocol, runtime_checkable

from cam2sim.core.errors import ConfigError
from cam2sim.detect.lidar import GeometricDetector

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from cam2sim.detect.boxes import Boxes

__all__ = ["CameraDetector", "LidarDetector", "Source", "load_detector"]

Source = Literal["lidar", "camera"]


@runtime_checkable
class LidarDetector(Protocol):
    """Finds vehicles in one LiDAR scan."""

    @property
    def name(self) -> str:
        """Detector name recorded in ``parked_vehicles.json``."""
        ...

    def detect(self, points: npt.NDArray[np.float32]) -> Boxes:
        """Boxes (``axes="link"``) in the scan's frame.

        Args:
            points: ``(N, 4)`` x, y, z (metres, LiDAR link frame) and intensity in ``[0, 1]``
                (zero when the sensor gives none).
        """
        ...


@runtime_checkable
class CameraDetector(Protocol):
    """Finds vehicles in one camera image."""

    @property
    def name(self) -> str:
        """Detector name recorded in ``parked_vehicles.json``."""
        ...

    def detect(self, image: npt.NDArray[np.uint8], K: npt.NDArray[np.float64]) -> Boxes:
        """Boxes (``axes="optical"``) in the camera's optical frame.

        Args:
            image: ``(H, W, 3)`` undistorted RGB image.
            K: ``(3, 3)`` pinhole matrix of ``image``.
        """
        ...


def load_detector(spec: str, source: Source) -> LidarDetector | CameraDetector:
    """Return the detector named by ``spec`` for ``source`` (see the module doc).

    Raises:
        ConfigError: The name is unknown, the model file is missing, or it does not fit the
            source.
        BackendUnavailableError: The model needs a package that is not installed.
    """
    from cam2sim.detect import learned  # noqa: PLC0415 -- lazy: imports cv2

    if spec == "geometric":
        if source != "lidar":
            msg = (
                "the geometric detector works on LiDAR scans only; for camera detection give a "
                "model: --model path/to/model.onnx (or .pt TorchScript, or fcos3d:CONFIG:CKPT)"
            )
            raise ConfigError(msg)

        return GeometricDetector()
    kind, _, rest = spec.partition(":")
    if kind in ("pointpillars", "fcos3d") and rest:
        config, _, checkpoint = rest.partition(":")
        wanted: Source = "lidar" if kind == "pointpillars" else "camera"
        if wanted != source:
            msg = f"{kind} is a {wanted} detector, but --source is {source}"
            raise ConfigError(msg)
        if kind == "pointpillars":
            return learned.MMDet3DLidarDetector(Path(config), Path(checkpoint))
        return learned.MMDet3DCameraDetector(Path(config), Path(checkpoint))
    path = Path(spec)
    suffix = path.suffix.lower()
    if suffix in (".onnx", ".pt", ".pth", ".ts"):
        if not path.is_file():
            msg = f"detector model {path} does not exist; give the path of a local model file"
            raise ConfigError(msg)
        if suffix == ".onnx":
            if source == "lidar":
                return learned.OnnxLidarDetector(path)
            return learned.OnnxCameraDetector(path)
        if source == "lidar":
            msg = f"TorchScript models ({path.name}) are supported for camera detection only"
            raise ConfigError(msg)
        return learned.TorchCameraDetector(path)
    msg = (
        f"unknown detector {spec!r}; use 'geometric' (LiDAR), a .onnx or .pt model path, "
        "'pointpillars:CONFIG:CHECKPOINT' or 'fcos3d:CONFIG:CHECKPOINT'"
    )
    raise ConfigError(msg)
