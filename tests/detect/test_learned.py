"""Learned detectors on small models the tests build: ONNX graphs, TorchScript, torch.export."""

from __future__ import annotations

import pickle
import subprocess
import sys
import types
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from onnx import TensorProto, helper, numpy_helper, save_model

from cam2sim.core.errors import BackendUnavailableError, ConfigError
from cam2sim.detect import learned
from cam2sim.detect.detector import CameraDetector, LidarDetector, load_detector
from cam2sim.detect.learned import (
    MMDet3DCameraDetector,
    MMDet3DLidarDetector,
    MonocularErrorModel,
    OnnxCameraDetector,
    OnnxLidarDetector,
    TorchCameraDetector,
)

# Constant boxes the test models add their input-derived row to: x, y, z, l, w, h, yaw.
# Row 0/1 are cars to keep; row 2 lies beyond the 50 m depth cut (camera), row 3 has label 3,
# row 4 scores below the threshold.
_BASE = np.array(
    [
        [0.0, 0.0, 10.0, 4.0, 1.8, 1.5, 0.2],
        [0.0, 0.0, 30.0, 4.5, 1.9, 1.6, -0.4],
        [0.0, 0.0, 60.0, 4.0, 1.8, 1.5, 0.0],
        [0.0, 0.0, 12.0, 4.0, 1.8, 1.5, 0.0],
        [0.0, 0.0, 15.0, 4.0, 1.8, 1.5, 0.0],
    ],
    dtype=np.float32,
)
_SCORES = np.array([0.9, 0.8, 0.9, 0.9, 0.1], dtype=np.float32)
_LABELS = np.array([0, 0, 0, 3, 0], dtype=np.int64)


def _const(name: str, value: np.ndarray) -> Any:
    return helper.make_node("Constant", [], [name], value=numpy_helper.from_array(value, name))


def _save(path: Path, nodes: list[Any], inputs: list[Any], outputs: list[Any]) -> Path:
    graph = helper.make_graph(nodes, "test", inputs, outputs)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    save_model(model, str(path))
    return path


def _outputs(
    names: tuple[str, ...] = ("boxes", "scores", "labels"), box_cols: int | str = 7
) -> list[Any]:
    types_ = (TensorProto.FLOAT, TensorProto.FLOAT, TensorProto.INT64)
    shapes: tuple[list[Any], ...] = (["M", box_cols], ["M"], ["M"])
    return [
        helper.make_tensor_value_info(n, t, s)
        for n, t, s in zip(names, types_, shapes, strict=False)
    ]


def _lidar_model(
    path: Path,
    *,
    rank: int = 2,
    count: int | str = "N",
    names: tuple[str, ...] = ("boxes", "scores", "labels"),
) -> Path:
    """Box 0 sits at the points' centroid; the rest are the constant rows of ``_BASE``."""
    shape: list[Any] = [count, 4] if rank == 2 else [1, count, 4]
    nodes = [
        helper.make_node("ReduceMean", ["points"], ["mean"], axes=[rank - 2], keepdims=0),
        _const("mshape", np.array([1, 4], dtype=np.int64)),
        helper.make_node("Reshape", ["mean", "mshape"], ["mean2"]),
        _const("st", np.array([0], dtype=np.int64)),
        _const("en", np.array([3], dtype=np.int64)),
        _const("ax", np.array([1], dtype=np.int64)),
        helper.make_node("Slice", ["mean2", "st", "en", "ax"], ["xyz"]),
        _const("zeros", np.zeros((1, 4), dtype=np.float32)),
        helper.make_node("Concat", ["xyz", "zeros"], ["probe"], axis=1),
        _const("base", _BASE),
        helper.make_node("Add", ["base", "probe"], ["boxes_"]),
        _const("scores_", _SCORES),
        _const("labels_", _LABELS),
    ]
    outs = ["boxes_", "scores_", "labels_"]
    nodes += [helper.make_node("Identity", [o], [n]) for o, n in zip(outs, names, strict=False)]
    inp = [helper.make_tensor_value_info("points", TensorProto.FLOAT, shape)]
    return _save(path, nodes, inp, _outputs(names))


def _camera_model(
    path: Path,
    *,
    size: tuple[int, int] | None = None,
    with_k: bool = True,
    box_cols: int = 7,
    scores: np.ndarray = _SCORES,
) -> Path:
    """Every box gets x = mean red value of the image and y = cx of the K it was given."""
    h, w = ("H", "W") if size is None else (size[1], size[0])
    nodes = [
        _const("s0", np.array([0], dtype=np.int64)),
        _const("e1", np.array([1], dtype=np.int64)),
        _const("a1", np.array([1], dtype=np.int64)),
        helper.make_node("Slice", ["image", "s0", "e1", "a1"], ["red"]),
        helper.make_node("ReduceMean", ["red"], ["rmean"], axes=[1, 2, 3], keepdims=1),
        _const("shape11", np.array([1, 1], dtype=np.int64)),
        helper.make_node("Reshape", ["rmean", "shape11"], ["r11"]),
    ]
    if with_k:
        nodes += [
            _const("ks", np.array([0, 0, 2], dtype=np.int64)),
            _const("ke", np.array([1, 1, 3], dtype=np.int64)),
            _const("ka", np.array([0, 1, 2], dtype=np.int64)),
            helper.make_node("Slice", ["K", "ks", "ke", "ka"], ["cx"]),
            helper.make_node("Reshape", ["cx", "shape11"], ["c11"]),
        ]
    else:
        nodes.append(_const("c11", np.zeros((1, 1), dtype=np.float32)))
    nodes += [
        _const("tail", np.zeros((1, 5), dtype=np.float32)),
        helper.make_node("Concat", ["r11", "c11", "tail"], ["probe"], axis=1),
        _const("base", _BASE),
        helper.make_node("Add", ["base", "probe"], ["sum"]),
        _const("cols", np.arange(box_cols, dtype=np.int64)),
        helper.make_node("Gather", ["sum", "cols"], ["boxes"], axis=1),
        _const("scores", scores),
        _const("labels", _LABELS),
    ]
    inputs = [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, h, w])]
    if with_k:
        inputs.append(helper.make_tensor_value_info("K", TensorProto.FLOAT, [1, 3, 3]))
    return _save(path, nodes, inputs, _outputs(box_cols=box_cols))


def _image(h: int = 64, w: int = 96, red: int = 204) -> np.ndarray:
    img = np.zeros((h, w, 3), dtype=np.uint8)
    img[..., 0] = red
    img[..., 2] = 255 - red
    return img


def _k(h: int = 64, w: int = 96) -> np.ndarray:
    return np.array([[80.0, 0.0, (w - 1) / 2], [0.0, 90.0, (h - 1) / 2], [0.0, 0.0, 1.0]])


# --- error model -----------------------------------------------------------------------------


def test_monocular_sigma_grows_with_depth_and_shrinks_with_focal_length() -> None:
    model = MonocularErrorModel()
    depth = np.array([5.0, 10.0, 20.0, 40.0])
    sigma = model.sigma_m(depth, focal_px=778.0)
    assert np.all(np.diff(sigma) > 0)
    assert sigma[0] > model.floor_m
    np.testing.assert_allclose(sigma, 0.5 + depth**2 * 2.0 / (778.0 * 1.5))
    assert np.all(model.sigma_m(depth, focal_px=1500.0) < sigma)


def test_monocular_error_model_rejects_non_positive_values() -> None:
    with pytest.raises(ConfigError, match="pixel_sigma_px"):
        MonocularErrorModel(pixel_sigma_px=0.0)


# --- ONNX LiDAR ------------------------------------------------------------------------------


@pytest.mark.parametrize("rank", [2, 3])
def test_onnx_lidar_model_boxes_come_back_in_link_frame(tmp_path: Path, rank: int) -> None:
    path = _lidar_model(tmp_path / "lidar.onnx", rank=rank)
    det = load_detector(str(path), "lidar")
    assert isinstance(det, OnnxLidarDetector)
    assert isinstance(det, LidarDetector)
    rng = np.random.default_rng(0)
    points = (rng.normal(size=(200, 4)) + np.array([5.0, -2.0, 0.5, 0.0])).astype(np.float32)
    boxes = det.detect(points)
    assert boxes.axes == "link"
    assert len(boxes) == 3  # label 3 and the low score go; LiDAR has no depth cut
    centroid = points[:, :3].astype(np.float64).mean(axis=0)
    np.testing.assert_allclose(boxes.center[0], centroid + _BASE[0, :3], atol=1e-5)
    np.testing.assert_allclose(boxes.size, _BASE[[0, 1, 2], 3:6], atol=1e-6)
    np.testing.assert_allclose(boxes.yaw, _BASE[[0, 1, 2], 6], atol=1e-6)
    np.testing.assert_allclose(boxes.score, _SCORES[[0, 1, 2]], atol=1e-6)
    np.testing.assert_allclose(boxes.sigma_m, learned.LIDAR_SIGMA_M)


def test_onnx_lidar_threshold_and_labels_are_options(tmp_path: Path) -> None:
    path = _lidar_model(tmp_path / "lidar.onnx")
    points = np.ones((10, 4), dtype=np.float32)
    every = OnnxLidarDetector(path, score_threshold=0.0, vehicle_labels=None)
    assert len(every.detect(points)) == 5
    strict = OnnxLidarDetector(path, score_threshold=0.85, vehicle_labels=frozenset({0, 3}))
    np.testing.assert_allclose(strict.detect(points).score, [0.9, 0.9, 0.9], atol=1e-6)


def test_onnx_lidar_fixed_point_count_is_met(tmp_path: Path) -> None:
    det = OnnxLidarDetector(_lidar_model(tmp_path / "fixed.onnx", count=8))
    points = np.array([[1, 2, 3, 0], [3, 2, 1, 0], [2, 2, 2, 1], [2, 6, 2, 1]], dtype=np.float32)
    np.testing.assert_allclose(det.detect(points).center[0], [2.0, 3.0, 12.0], atol=1e-5)
    assert len(det.detect(np.ones((100, 4), dtype=np.float32))) == 3


def test_onnx_lidar_empty_scan_gives_no_boxes(tmp_path: Path) -> None:
    det = OnnxLidarDetector(_lidar_model(tmp_path / "lidar.onnx"))
    assert len(det.detect(np.zeros((0, 4), dtype=np.float32))) == 0


def test_onnx_wrong_output_names_are_listed(tmp_path: Path) -> None:
    path = _lidar_model(tmp_path / "named.onnx", names=("bbox", "score", "cls"))
    with pytest.raises(ConfigError, match=r"boxes \(M, 7\).*outputs \[bbox .*score .*cls"):
        OnnxLidarDetector(path)


def test_onnx_lidar_points_must_be_n_by_4(tmp_path: Path) -> None:
    det = OnnxLidarDetector(_lidar_model(tmp_path / "lidar.onnx"))
    with pytest.raises(ValueError, match=r"\(N, 4\)"):
        det.detect(np.zeros((5, 3), dtype=np.float32))


def test_onnx_unreadable_model_is_a_config_error(tmp_path: Path) -> None:
    path = tmp_path / "bad.onnx"
    path.write_bytes(b"not a model")
    with pytest.raises(ConfigError, match="cannot load ONNX model"):
        load_detector(str(path), "lidar")


def test_missing_model_file_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="does not exist"):
        load_detector(str(tmp_path / "nope.onnx"), "camera")
    with pytest.raises(ConfigError, match="does not exist"):
        OnnxCameraDetector(tmp_path / "nope.onnx")


def test_missing_onnxruntime_names_the_install(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = _lidar_model(tmp_path / "lidar.onnx")
    monkeypatch.setitem(sys.modules, "onnxruntime", None)
    with pytest.raises(BackendUnavailableError, match="pip install"):
        OnnxLidarDetector(path)


# --- ONNX camera -----------------------------------------------------------------------------


def test_onnx_camera_boxes_carry_score_and_depth_sigma(tmp_path: Path) -> None:
    det = load_detector(str(_camera_model(tmp_path / "cam.onnx")), "camera")
    assert isinstance(det, OnnxCameraDetector)
    assert isinstance(det, CameraDetector)
    k = _k()
    boxes = det.detect(_image(red=204), k)
    assert boxes.axes == "optical"
    assert len(boxes) == 2  # 60 m is beyond the depth cut; label 3 and the low score go
    np.testing.assert_allclose(boxes.center[:, 0], 0.8, atol=1e-5)  # RGB, scaled to [0, 1]
    np.testing.assert_allclose(boxes.center[:, 1], k[0, 2], atol=1e-4)  # K reached the model
    np.testing.assert_allclose(boxes.center[:, 2], [10.0, 30.0])
    np.testing.assert_allclose(boxes.score, [0.9, 0.8], atol=1e-6)
    expected = MonocularErrorModel().sigma_m(np.array([10.0, 30.0]), focal_px=90.0)
    np.testing.assert_allclose(boxes.sigma_m, expected, rtol=1e-6)
    assert boxes.sigma_m[1] > boxes.sigma_m[0]


def test_onnx_camera_fixed_input_size_resizes_and_scales_k(tmp_path: Path) -> None:
    det = OnnxCameraDetector(_camera_model(tmp_path / "fixed.onnx", size=(48, 32)))
    k = _k(64, 96)
    boxes = det.detect(_image(64, 96, red=102), k)
    np.testing.assert_allclose(boxes.center[:, 0], 0.4, atol=1e-5)
    np.testing.assert_allclose(boxes.center[:, 1], (k[0, 2] + 0.5) * 0.5 - 0.5, atol=1e-4)
    expected = MonocularErrorModel().sigma_m(np.array([10.0, 30.0]), focal_px=45.0)
    np.testing.assert_allclose(boxes.sigma_m, expected, rtol=1e-6)


def test_onnx_camera_input_size_must_match_a_fixed_model(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="fixed size"):
        OnnxCameraDetector(
            _camera_model(tmp_path / "fixed.onnx", size=(48, 32)), input_size=(64, 64)
        )


def test_onnx_camera_model_without_k_input_runs(tmp_path: Path) -> None:
    det = OnnxCameraDetector(_camera_model(tmp_path / "nok.onnx", with_k=False))
    boxes = det.detect(_image(), _k())
    np.testing.assert_allclose(boxes.center[:, 1], 0.0)


def test_onnx_camera_depth_cut_and_threshold_are_options(tmp_path: Path) -> None:
    errors = MonocularErrorModel(max_depth_m=20.0)
    det = OnnxCameraDetector(
        _camera_model(tmp_path / "cam.onnx"), error_model=errors, score_threshold=0.0
    )
    np.testing.assert_allclose(det.detect(_image(), _k()).center[:, 2], [10.0, 15.0])


def test_onnx_camera_declared_narrow_boxes_are_rejected(tmp_path: Path) -> None:
    with pytest.raises(
        ConfigError, match=r"boxes \(M, 7\).*outputs \[boxes tensor\(float\) \[\S+, 5\]"
    ):
        OnnxCameraDetector(_camera_model(tmp_path / "narrow.onnx", box_cols=5))


def test_onnx_camera_inconsistent_outputs_at_run_time_are_rejected(tmp_path: Path) -> None:
    det = OnnxCameraDetector(_camera_model(tmp_path / "four.onnx", scores=_SCORES[:4]))
    with pytest.raises(ConfigError, match=r"shapes .*'boxes': \(5, 7\), 'scores': \(4,\)"):
        det.detect(_image(), _k())


def test_onnx_scores_must_be_probabilities(tmp_path: Path) -> None:
    det = OnnxCameraDetector(_camera_model(tmp_path / "logits.onnx", scores=_SCORES * 10 - 3))
    with pytest.raises(ConfigError, match="sigmoid"):
        det.detect(_image(), _k())


def test_importing_learned_loads_no_backend() -> None:
    code = (
        "import sys, cam2sim.detect.learned; "
        "print(sorted({'torch', 'onnxruntime', 'mmdet3d'} & set(sys.modules)))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_onnx_camera_image_is_checked(tmp_path: Path) -> None:
    det = OnnxCameraDetector(_camera_model(tmp_path / "cam.onnx"))
    with pytest.raises(ValueError, match="uint8"):
        det.detect(_image().astype(np.float32), _k())


def test_geometric_detector_is_lidar_only() -> None:
    with pytest.raises(ConfigError, match="LiDAR scans only"):
        load_detector("geometric", "camera")


# --- torch -----------------------------------------------------------------------------------


def _torch_module(
    *, with_k: bool = True, keys: tuple[str, str, str] = ("boxes", "scores", "labels")
) -> Any:
    import torch

    class Mono(torch.nn.Module):
        if TYPE_CHECKING:  # buffers, for mypy (TorchScript cannot resolve these annotations)
            base: torch.Tensor
            scores: torch.Tensor
            labels: torch.Tensor

        def __init__(self) -> None:
            super().__init__()
            self.register_buffer("base", torch.from_numpy(_BASE))
            self.register_buffer("scores", torch.from_numpy(_SCORES))
            self.register_buffer("labels", torch.from_numpy(_LABELS))
            self.keys = list(keys)

        def forward(self, image: torch.Tensor, K: torch.Tensor) -> dict[str, torch.Tensor]:
            probe = torch.zeros(1, 7)
            probe[0, 0] = image[:, 0].mean()
            probe[0, 1] = K[0, 0, 2]
            boxes = self.base + probe
            return {self.keys[0]: boxes, self.keys[1]: self.scores, self.keys[2]: self.labels}

    class MonoNoK(torch.nn.Module):
        if TYPE_CHECKING:
            base: torch.Tensor
            scores: torch.Tensor

        def __init__(self) -> None:
            super().__init__()
            self.register_buffer("base", torch.from_numpy(_BASE))
            self.register_buffer("scores", torch.from_numpy(_SCORES))

        def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            probe = torch.zeros(1, 7)
            probe[0, 0] = image[:, 0].mean()
            return self.base + probe, self.scores

    return Mono() if with_k else MonoNoK()


def _torchscript(path: Path, module: Any) -> Path:
    import torch

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # torch >= 2.10 deprecates TorchScript
        torch.jit.save(torch.jit.script(module), str(path))
    return path


def test_torchscript_camera_model_runs(tmp_path: Path) -> None:
    path = _torchscript(tmp_path / "mono.pt", _torch_module())
    det = load_detector(str(path), "camera")
    assert isinstance(det, TorchCameraDetector)
    k = _k()
    boxes = det.detect(_image(red=51), k)
    assert boxes.axes == "optical"
    np.testing.assert_allclose(boxes.center[:, 0], 0.2, atol=1e-5)
    np.testing.assert_allclose(boxes.center[:, 1], k[0, 2], atol=1e-4)
    np.testing.assert_allclose(boxes.center[:, 2], [10.0, 30.0])
    np.testing.assert_allclose(boxes.score, [0.9, 0.8], atol=1e-6)
    assert np.all(np.diff(boxes.sigma_m) > 0)


def test_torchscript_tuple_output_without_k_and_input_size(tmp_path: Path) -> None:
    path = _torchscript(tmp_path / "nok.ts", _torch_module(with_k=False))
    det = TorchCameraDetector(path, input_size=(48, 32))
    boxes = det.detect(_image(), _k())
    assert len(boxes) == 3  # no labels output: the label-3 box counts as a vehicle
    expected = MonocularErrorModel().sigma_m(boxes.center[:, 2], focal_px=45.0)
    np.testing.assert_allclose(boxes.sigma_m, expected, rtol=1e-6)


def test_torch_wrong_output_keys_are_listed(tmp_path: Path) -> None:
    path = _torchscript(tmp_path / "keys.pt", _torch_module(keys=("bbox", "score", "cls")))
    det = TorchCameraDetector(path)
    with pytest.raises(ConfigError, match=r"\['bbox', 'cls', 'score'\]"):
        det.detect(_image(), _k())


def test_torch_export_program_declares_its_input_size(tmp_path: Path) -> None:
    import torch

    example = (torch.zeros(1, 3, 32, 48), torch.from_numpy(_k(32, 48)[None].astype(np.float32)))
    program = torch.export.export(_torch_module(), example)
    path = tmp_path / "mono_export.pt"
    torch.export.save(program, str(path))
    det = TorchCameraDetector(path)
    k = _k(64, 96)
    boxes = det.detect(_image(64, 96, red=102), k)
    np.testing.assert_allclose(boxes.center[:, 0], 0.4, atol=1e-5)
    np.testing.assert_allclose(boxes.center[:, 1], (k[0, 2] + 0.5) * 0.5 - 0.5, atol=1e-4)


def test_torch_state_dict_is_refused_with_the_fix(tmp_path: Path) -> None:
    import torch

    path = tmp_path / "weights.pth"
    torch.save({"w": torch.zeros(2)}, str(path))
    with pytest.raises(ConfigError, match=r"state dict.*torch\.export\.save"):
        load_detector(str(path), "camera")


def test_missing_torch_names_the_install(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "m.pt"
    path.write_bytes(b"x")
    monkeypatch.setitem(sys.modules, "torch", None)
    with pytest.raises(BackendUnavailableError, match="pip install torch"):
        TorchCameraDetector(path)


# --- mmdetection3d ---------------------------------------------------------------------------


@pytest.fixture
def mm_files(tmp_path: Path) -> tuple[Path, Path]:
    config, checkpoint = tmp_path / "cfg.py", tmp_path / "model.pth"
    config.write_text("model = dict()\n")
    checkpoint.write_bytes(b"\0")
    return config, checkpoint


def test_missing_mmdet3d_names_the_install(
    mm_files: tuple[Path, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "mmdet3d", None)
    monkeypatch.setitem(sys.modules, "mmdet3d.apis", None)
    cfg, ckpt = mm_files
    with pytest.raises(BackendUnavailableError, match="pip install mmdet3d"):
        load_detector(f"pointpillars:{cfg}:{ckpt}", "lidar")
    with pytest.raises(BackendUnavailableError, match="mmcv, mmengine"):
        MMDet3DCameraDetector(cfg, ckpt)


def test_mmdet3d_missing_files_are_config_errors(
    mm_files: tuple[Path, Path], tmp_path: Path
) -> None:
    cfg, ckpt = mm_files
    with pytest.raises(ConfigError, match="mmdet3d config"):
        MMDet3DLidarDetector(tmp_path / "none.py", ckpt)
    with pytest.raises(ConfigError, match="mmdet3d checkpoint"):
        load_detector(f"fcos3d:{cfg}:{tmp_path / 'none.pth'}", "camera")
    with pytest.raises(ConfigError, match="camera detector"):
        load_detector(f"fcos3d:{cfg}:{ckpt}", "lidar")


def _sample(tensor: np.ndarray, scores: list[float], labels: list[int]) -> Any:
    ns = types.SimpleNamespace
    pred = ns(bboxes_3d=ns(tensor=tensor), scores_3d=np.array(scores), labels_3d=np.array(labels))
    return ns(pred_instances_3d=pred)


@pytest.fixture
def fake_mmdet3d(monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    """A stand-in ``mmdet3d.apis`` with the 1.x call signatures, recording its calls."""
    calls: dict[str, Any] = {}
    apis = types.ModuleType("mmdet3d.apis")

    def init_model(config: str, checkpoint: str, device: str) -> str:
        calls["init"] = (config, checkpoint, device)
        return "model"

    def inference_detector(model: str, points: np.ndarray) -> tuple[Any, dict[str, Any]]:
        calls["points"] = points
        # x, y, z_bottom, dx, dy, dz, yaw: a car and a pedestrian (KITTI 3-class: Car = 2)
        t = np.array([[10.0, 2.0, -1.7, 4.0, 1.8, 1.5, 0.3], [5.0, 1.0, -1.7, 0.6, 0.6, 1.7, 0.0]])
        return _sample(t, [0.8, 0.9], [2, 0]), {}

    def inference_mono_3d_detector(model: str, img: str, ann_file: str, cam_type: str) -> Any:
        info = pickle.loads(Path(ann_file).read_bytes())["data_list"][0]["images"][cam_type]
        calls["mono"] = (Path(img).is_file(), Path(img).name == info["img_path"], info["cam2img"])
        # x, y_bottom, z, l, h, w, yaw, vx, vz (nuScenes FCOS3D: car = 0)
        t = np.array([[1.0, 1.6, 12.0, 4.2, 1.5, 1.8, -1.2, 0.0, 0.0]])
        return _sample(t, [0.5], [0])

    apis.init_model = init_model  # type: ignore[attr-defined]
    apis.inference_detector = inference_detector  # type: ignore[attr-defined]
    apis.inference_mono_3d_detector = inference_mono_3d_detector  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "mmdet3d", types.ModuleType("mmdet3d"))
    monkeypatch.setitem(sys.modules, "mmdet3d.apis", apis)
    return calls


def test_mmdet3d_lidar_boxes_move_from_bottom_to_centre(
    mm_files: tuple[Path, Path], fake_mmdet3d: dict[str, Any]
) -> None:
    det = MMDet3DLidarDetector(*mm_files, device="cpu")
    boxes = det.detect(np.ones((20, 4), dtype=np.float32))
    assert fake_mmdet3d["init"][2] == "cpu"
    assert fake_mmdet3d["points"].dtype == np.float32
    assert len(boxes) == 1  # the pedestrian (label 0) is not a vehicle
    np.testing.assert_allclose(boxes.center[0], [10.0, 2.0, -0.95])
    np.testing.assert_allclose(boxes.size[0], [4.0, 1.8, 1.5])
    np.testing.assert_allclose(boxes.yaw, [0.3])


def test_mmdet3d_camera_boxes_reorder_sizes_and_centre(
    mm_files: tuple[Path, Path], fake_mmdet3d: dict[str, Any]
) -> None:
    det = MMDet3DCameraDetector(*mm_files, device="cpu")
    k = _k()
    boxes = det.detect(_image(), k)
    found, same_name, cam2img = fake_mmdet3d["mono"]
    assert found
    assert same_name
    np.testing.assert_allclose(cam2img, k)
    assert boxes.axes == "optical"
    np.testing.assert_allclose(boxes.center[0], [1.0, 0.85, 12.0])
    np.testing.assert_allclose(boxes.size[0], [4.2, 1.8, 1.5])
    np.testing.assert_allclose(
        boxes.sigma_m, MonocularErrorModel().sigma_m(np.array([12.0]), focal_px=90.0)
    )
