"""The pinhole camera: the one owner of intrinsics, their scaling and undistortion.

:class:`PinholeCamera` is what every stage means by "camera intrinsics": focal lengths and
principal point in pixels, the image size, and the lens distortion of the recorded images
(OpenCV plumb-bob ``(k1, k2, p1, p2[, k3, ...])`` or equidistant ``(k1..k4)``). Pixel
coordinates follow OpenCV: pixel centres at integer coordinates, x right, y down; the camera
frame is optical (x right, y down, z forward).

The persisted records are adapters onto it and keep their file formats: ``config.yaml``'s
:class:`cam2sim.core.config.IntrinsicsConfig`, ``dataset.json``'s
:class:`cam2sim.core.dataset.CameraIntrinsics` and ``scene.json``'s frame records each have a
``camera()`` method. Camera poses (mount composed with the vehicle poses) are owned by
:func:`cam2sim.core.frames.camera_poses`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np

from cam2sim.core.errors import ConfigError

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = ["DistortionModel", "PinholeCamera", "PixelConvention", "project_points"]

DistortionModel = Literal["plumb_bob", "equidistant"]
#: How a resize maps pixel coordinates: ``centres`` keeps pixel centres aligned (the image was
#: resampled, OpenCV's convention); ``corners`` scales coordinates from the image corner.
PixelConvention = Literal["centres", "corners"]


@dataclass(frozen=True, slots=True)
class PinholeCamera:
    """A pinhole camera: ``K = [[fx, skew, cx], [0, fy, cy], [0, 0, 1]]`` and its image size.

    Attributes:
        fx: Horizontal focal length, pixels (> 0).
        fy: Vertical focal length, pixels (> 0).
        cx: Principal point x, pixels.
        cy: Principal point y, pixels.
        width: Image width, pixels (> 0).
        height: Image height, pixels (> 0).
        distortion: Lens distortion coefficients of ``distortion_model`` (empty: none).
        distortion_model: ``plumb_bob`` or ``equidistant``.
        skew: ``K[0, 1]``, pixels (0 for every camera cam2sim makes).

    Raises:
        ConfigError: A non-positive size or focal length, or a non-finite value.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    distortion: tuple[float, ...] = ()
    distortion_model: DistortionModel = "plumb_bob"
    skew: float = 0.0

    def __post_init__(self) -> None:
        values = (self.fx, self.fy, self.cx, self.cy, self.skew, *self.distortion)
        if not all(math.isfinite(v) for v in values):
            msg = f"camera intrinsics must be finite, got {self!r}"
            raise ConfigError(msg)
        if self.fx <= 0 or self.fy <= 0:
            msg = f"camera focal lengths must be positive, got fx={self.fx!r}, fy={self.fy!r}"
            raise ConfigError(msg)
        if self.width <= 0 or self.height <= 0:
            msg = f"camera image size must be positive, got {self.width!r}x{self.height!r}"
            raise ConfigError(msg)

    @classmethod
    def from_K(
        cls,
        K: npt.ArrayLike,
        width: int,
        height: int,
        distortion: tuple[float, ...] | list[float] = (),
        *,
        distortion_model: DistortionModel = "plumb_bob",
    ) -> PinholeCamera:
        """The camera of a ``(3, 3)`` intrinsics matrix (its last row ``[0, 0, 1]``).

        Raises:
            ConfigError: ``K`` is not 3x3, or not of the upper-triangular pinhole form.
        """
        k = np.asarray(K, dtype=np.float64)
        if k.size != 9:
            msg = f"camera K must be 3x3, got shape {k.shape}"
            raise ConfigError(msg)
        k = k.reshape(3, 3)
        if k[1, 0] != 0 or k[2, 0] != 0 or k[2, 1] != 0 or k[2, 2] != 1:
            msg = f"camera K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got {k.tolist()}"
            raise ConfigError(msg)
        return cls(
            fx=float(k[0, 0]),
            fy=float(k[1, 1]),
            cx=float(k[0, 2]),
            cy=float(k[1, 2]),
            width=int(width),
            height=int(height),
            distortion=tuple(float(v) for v in distortion),
            distortion_model=distortion_model,
            skew=float(k[0, 1]),
        )

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)``, pixels."""
        return self.width, self.height

    def K(self) -> npt.NDArray[np.float64]:
        """``(3, 3)`` float64 intrinsics matrix (a fresh array)."""
        return np.array(
            [[self.fx, self.skew, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]],
            dtype=np.float64,
        )

    def scaled(
        self, width: int, height: int, *, convention: PixelConvention = "centres"
    ) -> PinholeCamera:
        """This camera for its images resized to ``width`` x ``height`` (distortion kept).

        Focal lengths (and skew) scale by ``sx = width / self.width`` and
        ``sy = height / self.height``. With ``centres`` (the default) pixel centres stay
        aligned: ``c' = (c + 0.5) * s - 0.5``; with ``corners`` ``c' = c * s``.
        """
        if width <= 0 or height <= 0:
            msg = f"cannot scale a camera to {width!r}x{height!r}; sizes must be positive"
            raise ConfigError(msg)
        sx, sy = width / self.width, height / self.height
        if convention == "centres":
            cx = (self.cx + 0.5) * width / self.width - 0.5
            cy = (self.cy + 0.5) * height / self.height - 0.5
        else:
            cx, cy = self.cx * sx, self.cy * sy
        return PinholeCamera(
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=cx,
            cy=cy,
            width=int(width),
            height=int(height),
            distortion=self.distortion,
            distortion_model=self.distortion_model,
            skew=self.skew * sx,
        )

    def require_undistorted(self, who: str) -> None:
        """Raise ValueError when this camera has lens distortion.

        ``who`` names the renderer in the message (renderers draw undistorted pinhole images;
        the fix is to render :meth:`undistorted`).
        """
        if any(self.distortion):
            msg = (
                f"{who} draws undistorted pinhole images, but the camera has "
                f"{self.distortion_model} distortion {self.distortion}; render "
                f"camera.undistorted() (the camera of the undistorted images) instead"
            )
            raise ValueError(msg)

    def undistorted(self) -> PinholeCamera:
        """The distortion-free camera of this camera's undistorted images (same size).

        alpha = 0 (OpenCV ``getOptimalNewCameraMatrix``; ``balance = 0`` for equidistant
        lenses): every output pixel sees the scene. Without distortion, the camera itself.
        """
        dist = np.asarray(self.distortion, dtype=np.float64)
        if dist.size == 0 or not np.any(dist):
            return PinholeCamera(
                self.fx, self.fy, self.cx, self.cy, self.width, self.height, skew=self.skew
            )
        import cv2  # noqa: PLC0415 -- lazy: OpenCV is heavy and only undistortion needs it

        K = self.K()
        if self.distortion_model == "equidistant":
            d4 = np.zeros(4)
            d4[: min(4, dist.size)] = dist[:4]
            K_new = cv2.fisheye.estimateNewCameraMatrixForUndistortRectify(
                K, d4, self.size, np.eye(3), balance=0.0
            )
        else:
            K_new, _ = cv2.getOptimalNewCameraMatrix(K, dist, self.size, 0.0, self.size)
        return PinholeCamera.from_K(K_new, self.width, self.height)

    def pinhole_remap(
        self, *, centred: bool = False
    ) -> tuple[PinholeCamera, npt.NDArray[np.float32], npt.NDArray[np.float32]] | None:
        """How to show this camera's view with a pinhole renderer: a camera and remap tables.

        Returns ``(pinhole, map_x, map_y)``: render ``pinhole`` (this camera's focal lengths,
        an image just large enough to hold every ray this camera sees), then
        ``cv2.remap(image, map_x, map_y, ...)`` gives the image as this camera records it,
        lens distortion included. Entry ``(v, u)`` of the tables is where this camera's pixel
        ``(u, v)`` lies in the pinhole image (always inside it). None without distortion: render
        this camera itself.

        ``centred``: a pinhole camera as CARLA's sensors are (one focal length, the larger of
        ``fx`` and ``fy``; the principal point at ``(width / 2, height / 2)``), described
        completely by its size and horizontal field of view.
        """
        dist = np.asarray(self.distortion, dtype=np.float64)
        if dist.size == 0 or not np.any(dist):
            return None
        import cv2  # noqa: PLC0415 -- lazy: OpenCV is heavy and only distortion needs it

        u, v = np.meshgrid(
            np.arange(self.width, dtype=np.float64), np.arange(self.height, dtype=np.float64)
        )
        pixels = np.stack([u.ravel(), v.ravel()], axis=-1)[:, None, :]
        if self.distortion_model == "equidistant":
            d4 = np.zeros(4)
            d4[: min(4, dist.size)] = dist[:4]
            rays = cv2.fisheye.undistortPoints(pixels, self.K(), d4)
        else:
            rays = cv2.undistortPoints(pixels, self.K(), dist)
        xy = np.asarray(rays, dtype=np.float64).reshape(self.height, self.width, 2)
        # Pixel coordinates at the focal lengths, shifted so every ray lands inside.
        fx, fy = (max(self.fx, self.fy),) * 2 if centred else (self.fx, self.fy)
        px = xy[..., 0] * fx
        py = xy[..., 1] * fy
        if centred:
            width = 2 * math.ceil(max(-float(px.min()), float(px.max())) + 2.0)
            height = 2 * math.ceil(max(-float(py.min()), float(py.max())) + 2.0)
            cx, cy = width / 2.0, height / 2.0
        else:
            cx, cy = 1.0 - float(px.min()), 1.0 - float(py.min())
            width = math.ceil(float(px.max()) + cx) + 2
            height = math.ceil(float(py.max()) + cy) + 2
        pinhole = PinholeCamera(fx, fy, cx, cy, width, height)
        return (
            pinhole,
            np.ascontiguousarray(px + cx, dtype=np.float32),
            np.ascontiguousarray(py + cy, dtype=np.float32),
        )


def project_points(
    xyz: npt.ArrayLike,
    T_world_cam: npt.ArrayLike,
    K: npt.ArrayLike,
    *,
    min_depth: float = 1e-6,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.bool_]]:
    """Pixel coordinates ``u, v`` of ``(N, 3)`` world points in a pinhole view, and which are ahead.

    A point is ahead when its camera depth is above ``min_depth``; ``u, v`` of the others are
    meaningless. Optical camera axes, no distortion: the camera of an undistorted image.
    """
    pose = np.asarray(T_world_cam, dtype=np.float64)
    k = np.asarray(K, dtype=np.float64)
    pc = (np.asarray(xyz, dtype=np.float64) - pose[:3, 3]) @ pose[:3, :3]
    z = pc[:, 2]
    front = z > min_depth
    zs = np.where(front, z, 1.0)
    return k[0, 0] * pc[:, 0] / zs + k[0, 2], k[1, 1] * pc[:, 1] / zs + k[1, 2], front
