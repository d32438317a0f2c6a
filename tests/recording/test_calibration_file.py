"""Calibration files as the tools write them: ROS, OpenCV, Kalibr, COLMAP, nerfstudio."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from cam2sim.core.dataset import Calibration
from cam2sim.core.errors import RecordingError
from cam2sim.core.workspace import DatasetPaths
from cam2sim.recording.calibration_file import model_named
from cam2sim.recording.intrinsics import intrinsics_from_file
from cam2sim.stages.image_import import ImportOptions, import_images
from conftest import write_frames

K = np.array([[701.5, 0.0, 640.2], [0.0, 699.8, 359.7], [0.0, 0.0, 1.0]])
D5 = [-0.281, 0.074, 0.0002, -0.0001, 0.01]
FISHEYE = [0.012, -0.004, 0.0011, -0.0002]

ROS_YAML = """\
image_width: 1280
image_height: 720
camera_name: front
camera_matrix:
  rows: 3
  cols: 3
  data: [701.5, 0, 640.2, 0, 699.8, 359.7, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.281, 0.074, 0.0002, -0.0001, 0.01]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [650.0, 0, 640.0, 0, 0, 650.0, 360.0, 0, 0, 0, 1, 0]
"""

KALIBR_CHAIN = """\
cam0:
  T_cam_imu:
  - [0.01, -0.99, 0.0, 0.06]
  - [0.99, 0.01, 0.0, -0.01]
  - [0.0, 0.0, 1.0, 0.0]
  - [0.0, 0.0, 0.0, 1.0]
  camera_model: pinhole
  distortion_coeffs: [0.012, -0.004, 0.0011, -0.0002]
  distortion_model: equidistant
  intrinsics: [701.5, 699.8, 640.2, 359.7]
  resolution: [1280, 720]
  rostopic: /cam0/image_raw
cam1:
  camera_model: pinhole
  distortion_coeffs: [0.0, 0.0, 0.0, 0.0]
  distortion_model: radtan
  intrinsics: [500.0, 500.0, 320.0, 240.0]
  resolution: [640, 480]
"""

EUROC_SENSOR = """\
sensor_type: camera
comment: VI-Sensor cam0 (MT9M034)
T_BS:
  cols: 4
  rows: 4
  data: [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]
rate_hz: 20
resolution: [752, 480]
camera_model: pinhole
intrinsics: [458.654, 457.296, 367.215, 248.375] #fu, fv, cu, cv
distortion_model: radial-tangential
distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
"""


def _read(path: Path, size: tuple[int, int] | None = (1280, 720)):
    intr, mount = intrinsics_from_file(path, size)
    assert mount is None
    return intr


def test_ros_camera_info_yaml(tmp_path: Path) -> None:
    path = tmp_path / "ost.yaml"
    path.write_text(ROS_YAML)
    intr = _read(path)
    np.testing.assert_allclose(intr.K, K)
    assert (intr.width, intr.height) == (1280, 720)
    np.testing.assert_allclose(intr.distortion, D5)
    assert intr.distortion_model == "plumb_bob"
    assert "ROS camera_info YAML" in intr.source


@pytest.mark.parametrize("suffix", ["yml", "xml"])
def test_opencv_filestorage_written_by_opencv(tmp_path: Path, suffix: str) -> None:
    """The files OpenCV's own FileStorage writes (its calibration sample's keys)."""
    path = tmp_path / f"camera.{suffix}"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 1280)
    fs.write("image_height", 720)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", np.array(D5).reshape(5, 1))
    fs.release()
    assert path.read_text().startswith("%YAML" if suffix == "yml" else "<?xml")
    intr = _read(path)
    np.testing.assert_allclose(intr.K, K)
    np.testing.assert_allclose(intr.distortion, D5)
    assert (intr.width, intr.height) == (1280, 720)
    assert "OpenCV FileStorage" in intr.source


def test_opencv_yaml_with_other_key_names_and_a_fisheye_flag(tmp_path: Path) -> None:
    path = tmp_path / "calib.yaml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("K", K)
    fs.write("D", np.array(FISHEYE).reshape(4, 1))
    fs.write("distortion_model", "fisheye")
    fs.write("imageSize", np.array([1280, 720]))  # a 2x1 matrix, not a list
    fs.release()
    intr = _read(path, size=None)
    assert intr.distortion_model == "equidistant"
    np.testing.assert_allclose(intr.distortion, FISHEYE)
    assert (intr.width, intr.height) == (1280, 720)


def test_kalibr_chain_takes_cam0_and_says_so(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "camchain.yaml"
    path.write_text(KALIBR_CHAIN)
    intr = _read(path)
    np.testing.assert_allclose(intr.K, K)
    assert intr.distortion_model == "equidistant"
    np.testing.assert_allclose(intr.distortion, FISHEYE)
    assert "took cam0, the first of its cameras (not cam1)" in caplog.text


def test_euroc_sensor_yaml(tmp_path: Path) -> None:
    path = tmp_path / "sensor.yaml"
    path.write_text(EUROC_SENSOR)
    intr = _read(path, size=(752, 480))
    assert intr.K[0][0] == pytest.approx(458.654)
    assert intr.K[1][2] == pytest.approx(248.375)
    assert intr.distortion_model == "plumb_bob"
    assert len(intr.distortion) == 4


def test_colmap_cameras_txt(tmp_path: Path) -> None:
    path = tmp_path / "cameras.txt"
    path.write_text(
        "# Camera list with one line of data per camera:\n"
        "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
        "# Number of cameras: 1\n"
        "1 OPENCV 1280 720 701.5 699.8 640.2 359.7 -0.281 0.074 0.0002 -0.0001\n"
    )
    intr = _read(path)
    np.testing.assert_allclose(intr.K, K)
    np.testing.assert_allclose(intr.distortion, D5[:4])
    (tmp_path / "radial.txt").write_text("3 SIMPLE_RADIAL 1280 720 700.0 640.0 360.0 -0.2\n")
    radial = _read(tmp_path / "radial.txt")
    assert radial.distortion == (-0.2, 0.0, 0.0, 0.0)
    assert radial.K[0][0] == radial.K[1][1] == 700.0


def test_nerfstudio_transforms_json(tmp_path: Path) -> None:
    path = tmp_path / "transforms.json"
    data = {"camera_model": "OPENCV_FISHEYE", "fl_x": 701.5, "fl_y": 699.8, "cx": 640.2,
            "cy": 359.7, "w": 1280, "h": 720, "k1": FISHEYE[0], "k2": FISHEYE[1],
            "k3": FISHEYE[2], "k4": FISHEYE[3], "frames": []}  # fmt: skip
    path.write_text(json.dumps(data))
    intr = _read(path)
    np.testing.assert_allclose(intr.K, K)
    assert intr.distortion_model == "equidistant"
    np.testing.assert_allclose(intr.distortion, FISHEYE)


def test_plain_json_of_fx_fy_cx_cy_takes_the_size_of_the_images(tmp_path: Path) -> None:
    path = tmp_path / "intrinsics.json"
    path.write_text(json.dumps({"fx": 701.5, "fy": 699.8, "cx": 640.2, "cy": 359.7}))
    intr = _read(path)
    np.testing.assert_allclose(intr.K, K)
    assert (intr.width, intr.height) == (1280, 720)
    assert "size from the images" in intr.source


def test_plain_json_names_its_distortion_model(tmp_path: Path) -> None:
    """A fisheye's four coefficients are not read as k1, k2, p1, p2."""
    path = tmp_path / "calib.json"
    data = {"K": K.tolist(), "distortion": FISHEYE, "distortion_model": "equidistant"}
    path.write_text(json.dumps({**data, "width": 1280, "height": 720}))
    assert _read(path).distortion_model == "equidistant"


def test_a_calibration_of_the_same_shape_is_scaled_to_the_images(tmp_path: Path) -> None:
    path = tmp_path / "ost.yaml"
    path.write_text(ROS_YAML)
    intr = _read(path, size=(640, 360))
    assert (intr.width, intr.height) == (640, 360)
    assert intr.K[0][0] == pytest.approx(701.5 / 2)
    assert intr.K[0][2] == pytest.approx((640.2 + 0.5) / 2 - 0.5)
    np.testing.assert_allclose(intr.distortion, D5)  # distortion is in normalised coordinates
    assert "scaled from 1280x720" in intr.source


@pytest.mark.parametrize(
    ("name", "text", "match"),
    [
        ("omni.yaml", KALIBR_CHAIN.replace("camera_model: pinhole", "camera_model: omni", 1),
         r"camera_model 'omni' \(Kalibr\) is not a pinhole camera"),
        ("eq5.yaml", ROS_YAML.replace("plumb_bob", "equidistant"),
         r"equidistant \(fisheye\) lens has 4 coefficients k1..k4, found 5"),
        ("bad.yaml", ROS_YAML.replace("data: [701.5, 0, 640.2, 0, 699.8, 359.7, 0, 0, 1]",
                                      "data: [701.5, 0, 640.2]"),
         r"bad.yaml: camera_matrix should be 3x3 finite numbers"),
        ("model.yaml", ROS_YAML.replace("plumb_bob", "mei"),
         r"distortion model 'mei' is not one this project undistorts"),
        ("cameras.txt", "1 FOV 1280 720 700 700 640 360 0.9\n",
         r"COLMAP camera model FOV is not read here; use one of SIMPLE_PINHOLE"),
        ("notes.yaml", "just: some\nother: yaml\n",
         r"neither JSON .* nor a calibration YAML, OpenCV XML or COLMAP cameras.txt"),
    ],
)  # fmt: skip
def test_malformed_or_unsupported_files_name_the_file_and_the_element(
    tmp_path: Path, name: str, text: str, match: str
) -> None:
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(RecordingError, match=match):
        _read(path)


def test_import_takes_a_ros_calibration_for_resized_frames(tmp_path: Path) -> None:
    """End to end: 1280x720 calibration, frames saved at 320x180 (a quarter)."""
    images = tmp_path / "images"
    write_frames(images, 3, size=(320, 180))
    calib = tmp_path / "ost.yaml"
    calib.write_text(ROS_YAML)
    import_images(tmp_path / "ws", images, options=ImportOptions(calibration=calib, fps=10.0))
    saved = Calibration.load(DatasetPaths(tmp_path / "ws" / "dataset").calibration_json)
    assert saved.camera is not None
    assert (saved.camera.width, saved.camera.height) == (320, 180)
    assert saved.camera.K[0][0] == pytest.approx(701.5 / 4)


@pytest.mark.parametrize(
    ("name", "model"),
    [(None, "plumb_bob"), ("plumb_bob", "plumb_bob"), ("rational_polynomial", "plumb_bob"),
     ("radtan", "plumb_bob"), ("equidistant", "equidistant"), ("fisheye", "equidistant"),
     ("Kannala_Brandt", "equidistant")],
)  # fmt: skip
def test_distortion_model_names_as_tools_and_camera_info_topics_write_them(
    name: str | None, model: str
) -> None:
    """Also what extract takes from a bag's CameraInfo (a driver's 'fisheye' is equidistant)."""
    assert model_named("topics.camera_info /cam/camera_info", name) == model
    with pytest.raises(RecordingError, match=r"/cam/camera_info: distortion model 'mei'"):
        model_named("topics.camera_info /cam/camera_info", "mei")
