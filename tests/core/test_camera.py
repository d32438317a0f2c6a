"""The pinhole camera: K layout, scaling, round trips, undistortion and errors."""

from __future__ import annotations

import numpy as np
import pytest

from cam2sim.core.camera import PinholeCamera, project_points
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


# The reference car's calibration (../shared/data/reference-drives/camera.json): strong barrel.
REFERENCE = PinholeCamera(
    772.906855, 777.596896, 424.980372, 258.452509, 800, 503,
    (-0.274231, 0.034838, 0.00226, -0.000972, 0.0),
)  # fmt: skip


def test_no_distortion_needs_no_remap() -> None:
    assert CAM.pinhole_remap() is None


@pytest.mark.parametrize(
    "cam",
    [
        REFERENCE,
        PinholeCamera(300.0, 300.0, 320.0, 240.0, 640, 480, (0.1, -0.02, 0.01, 0.0),
                      distortion_model="equidistant"),
    ],
    ids=["plumb-bob", "equidistant"],
)  # fmt: skip
@pytest.mark.parametrize("centred", [False, True], ids=["tight", "centred"])
def test_the_remap_sends_each_pixel_to_its_ray_in_the_pinhole_image(
    cam: PinholeCamera, *, centred: bool
) -> None:
    import cv2

    rng = np.random.default_rng(0)
    # Points in front of the camera that land inside the distorted image.
    pts = np.column_stack([rng.uniform(-0.5, 0.5, 400), rng.uniform(-0.3, 0.3, 400), np.ones(400)])
    if cam.distortion_model == "equidistant":
        d = np.asarray(cam.distortion[:4], dtype=np.float64)
        seen = cv2.fisheye.projectPoints(pts[:, None, :], np.zeros(3), np.zeros(3), cam.K(), d)[0]
    else:
        d = np.asarray(cam.distortion, dtype=np.float64)
        seen = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), cam.K(), d)[0]
    seen = seen.reshape(-1, 2)
    inside = (seen[:, 0] > 1) & (seen[:, 0] < cam.width - 2) & (seen[:, 1] > 1)
    inside &= seen[:, 1] < cam.height - 2
    assert inside.sum() > 100
    remap = cam.pinhole_remap(centred=centred)
    assert remap is not None
    pinhole, map_x, map_y = remap
    assert map_x.shape == (cam.height, cam.width)
    assert pinhole.distortion == ()
    if centred:  # as CARLA's sensors: one focal length, the principal point at the centre
        assert pinhole.fx == pinhole.fy == max(cam.fx, cam.fy)
        assert (pinhole.cx, pinhole.cy) == (pinhole.width / 2, pinhole.height / 2)
    else:
        assert (pinhole.fx, pinhole.fy) == (cam.fx, cam.fy)
    # Every pixel's ray is inside the pinhole image (with a pixel to spare for bilinear reads).
    assert map_x.min() >= 1.0
    assert map_x.max() <= pinhole.width - 2
    assert map_y.min() >= 1.0
    assert map_y.max() <= pinhole.height - 2
    # Where the map sends the distorted pixel (bilinear between the table's entries) ...
    u, v = seen[inside, 0], seen[inside, 1]
    x0, y0 = np.floor(u).astype(int), np.floor(v).astype(int)
    fx, fy = u - x0, v - y0

    def bilinear(table: np.ndarray) -> np.ndarray:
        return (
            table[y0, x0] * (1 - fx) * (1 - fy) + table[y0, x0 + 1] * fx * (1 - fy)
            + table[y0 + 1, x0] * (1 - fx) * fy + table[y0 + 1, x0 + 1] * fx * fy
        )  # fmt: skip

    # ... is where the pinhole camera sees the same point.
    ideal = (pinhole.K() @ pts[inside].T).T
    ideal = ideal[:, :2] / ideal[:, 2:]
    err = np.hypot(bilinear(map_x) - ideal[:, 0], bilinear(map_y) - ideal[:, 1])
    assert np.percentile(err, 99) < 0.05, np.percentile(err, [50, 99, 100])


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


def test_project_points_matches_the_pinhole_model_and_flags_points_behind() -> None:
    cam = PinholeCamera(100.0, 90.0, 32.0, 24.0, 64, 48)
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 2.0, 3.0]  # camera at (1, 2, 3), axes as the world's
    pts = np.array([[1.0, 2.0, 5.0], [2.0, 1.0, 7.0], [1.0, 2.0, 2.0]])
    u, v, ahead = project_points(pts, pose, cam.K())
    np.testing.assert_allclose(u[:2], [32.0, 32.0 + 100.0 * 1.0 / 4.0])
    np.testing.assert_allclose(v[:2], [24.0, 24.0 - 90.0 * 1.0 / 4.0])
    assert ahead.tolist() == [True, True, False]
