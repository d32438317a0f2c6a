"""The pinhole camera: K layout, scaling, round trips, undistortion and errors."""

from __future__ import annotations

import numpy as np
import pytest

from cam2sim.core.camera import PinholeCamera
from cam2sim.core.config import IntrinsicsConfig
from cam2sim.core.dataset import CameraIntrinsics
from cam2sim.core.errors import ConfigError

CAM = PinholeCamera(fx=400.0, fy=380.0, cx=319.5, cy=239.5, width=640, height=480)


def _project(cam: PinholeCamera, point: list[float]) -> np.ndarray:
    p = cam.K() @ np.asarray(point, dtype=np.float64)
    return p[:2] / p[2]


def test_K_is_the_opencv_pinhole_matrix() -> None:
    K = CAM.K()
    assert K.dtype == np.float64
    assert K.shape == (3, 3)
    assert np.array_equal(K, [[400.0, 0.0, 319.5], [0.0, 380.0, 239.5], [0.0, 0.0, 1.0]])
    assert CAM.size == (640, 480)


def test_from_K_round_trips() -> None:
    K = np.array([[500.0, 0.25, 300.0], [0.0, 510.0, 200.0], [0.0, 0.0, 1.0]])
    cam = PinholeCamera.from_K(K, 600, 400, [0.1, -0.01, 0.0, 0.0])
    assert np.array_equal(cam.K(), K)
    assert cam.skew == 0.25
    assert cam.distortion == (0.1, -0.01, 0.0, 0.0)
    assert PinholeCamera.from_K(cam.K(), cam.width, cam.height, cam.distortion) == cam


def test_scaling_keeps_pixel_centres_aligned() -> None:
    half = CAM.scaled(320, 240)
    assert (half.width, half.height) == (320, 240)
    # The optical axis still hits the image centre, and a point maps to the resized pixel.
    assert _project(half, [0.0, 0.0, 1.0]) == pytest.approx([159.5, 119.5])
    u, v = _project(CAM, [1.0, -0.5, 10.0])
    assert _project(half, [1.0, -0.5, 10.0]) == pytest.approx(
        [(u + 0.5) / 2 - 0.5, (v + 0.5) / 2 - 0.5]
    )


def test_scaling_from_the_corner() -> None:
    half = CAM.scaled(320, 240, convention="corners")
    u, v = _project(CAM, [1.0, -0.5, 10.0])
    assert _project(half, [1.0, -0.5, 10.0]) == pytest.approx([u / 2, v / 2])


def test_scaling_to_the_same_size_is_the_identity() -> None:
    assert CAM.scaled(640, 480) == CAM


def test_undistorted_camera_without_distortion_is_the_camera() -> None:
    assert CAM.undistorted() == CAM


def test_undistorted_camera_is_distortion_free_and_same_size() -> None:
    cam = PinholeCamera(400.0, 400.0, 320.0, 240.0, 640, 480, (-0.2, 0.05, 0.0, 0.0))
    new = cam.undistorted()
    assert new.distortion == ()
    assert new.size == cam.size
    assert new.fx > 0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"fx": 0.0}, "focal"),
        ({"fy": -1.0}, "focal"),
        ({"width": 0}, "size"),
        ({"height": -4}, "size"),
        ({"cx": float("nan")}, "finite"),
    ],
)
def test_invalid_cameras_are_refused(kwargs: dict[str, float], match: str) -> None:
    args = {"fx": 1.0, "fy": 1.0, "cx": 0.0, "cy": 0.0, "width": 4, "height": 4} | kwargs
    with pytest.raises(ConfigError, match=match):
        PinholeCamera(**args)  # type: ignore[arg-type]


def test_from_K_refuses_a_non_pinhole_matrix() -> None:
    with pytest.raises(ConfigError, match="3x3"):
        PinholeCamera.from_K(np.eye(2), 4, 4)
    with pytest.raises(ConfigError, match=r"\[0, 0, 1\]"):
        PinholeCamera.from_K([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 2.0]], 4, 4)


def test_scaling_to_a_non_positive_size_is_refused() -> None:
    with pytest.raises(ConfigError, match="positive"):
        CAM.scaled(0, 240)


def test_config_and_dataset_records_adapt_onto_the_camera() -> None:
    cfg = IntrinsicsConfig(
        fx=400.0, fy=380.0, cx=319.5, cy=239.5, width=640, height=480, distortion=[0.1, 0.0]
    )
    cam = cfg.camera()
    assert cam == PinholeCamera(400.0, 380.0, 319.5, 239.5, 640, 480, (0.1, 0.0))
    record = CameraIntrinsics.from_camera(cam, "config")
    assert record.K == ((400.0, 0.0, 319.5), (0.0, 380.0, 239.5), (0.0, 0.0, 1.0))
    assert record.camera() == cam
