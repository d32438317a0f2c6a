"""Hood and sky masks on synthetic frames (and a tiny random SegFormer)."""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from cam2sim.splat.masks import (
    CITYSCAPES_SKY_ID,
    detect_hood_mask,
    hood_mask_from_polygon,
    hood_mask_from_rows,
    sky_label_id,
    sky_mask_classical,
    sky_mask_segformer,
)

H, W = 120, 160


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def _hood_truth() -> np.ndarray:
    """A curved hood: an ellipse cap rising from the bottom border."""
    mask = np.zeros((H, W), dtype=np.uint8)
    cv2.ellipse(mask, (W // 2, H + 10), (W // 2 + 20, 40), 0, 0, 360, 1, -1)
    return mask.astype(bool)


def _moving_frames(n: int, hood: np.ndarray) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    texture = rng.integers(0, 256, size=(H, W * 4, 3), dtype=np.uint8)
    texture = cv2.GaussianBlur(texture, (5, 5), 0)
    hood_colour = np.array([40, 60, 90], dtype=np.uint8)
    frames = []
    for i in range(n):
        frame = np.roll(texture, -7 * i, axis=1)[:, :W].copy()
        frame[hood] = hood_colour + rng.integers(0, 2, size=3, dtype=np.uint8)
        frames.append(frame)
    return frames


def test_hood_mask_from_rows_covers_bottom_rows() -> None:
    mask = hood_mask_from_rows(H, W, 25)
    assert mask.shape == (H, W)
    assert mask[-25:].all()
    assert not mask[:-25].any()


def test_hood_mask_from_rows_rejects_rows_beyond_height() -> None:
    with pytest.raises(ValueError, match="hood rows"):
        hood_mask_from_rows(H, W, H + 1)


def test_hood_mask_from_polygon_fills_inside() -> None:
    mask = hood_mask_from_polygon(H, W, [(0, H - 1), (W - 1, H - 1), (W - 1, H - 30), (0, H - 30)])
    assert mask[-29:].all()
    assert not mask[: H - 31].any()


def test_hood_mask_from_polygon_rejects_two_vertices() -> None:
    with pytest.raises(ValueError, match="polygon"):
        hood_mask_from_polygon(H, W, [(0, 0), (1, 1)])


def test_detect_hood_finds_constant_region_under_moving_scene() -> None:
    truth = _hood_truth()
    found = detect_hood_mask(_moving_frames(40, truth))
    assert found is not None
    assert _iou(found, truth) > 0.9


def test_detect_hood_returns_none_without_hood() -> None:
    empty = np.zeros((H, W), dtype=bool)
    assert detect_hood_mask(_moving_frames(40, empty)) is None


def test_detect_hood_returns_none_when_scene_stands_still() -> None:
    frame = _moving_frames(1, _hood_truth())[0]
    assert detect_hood_mask([frame] * 10) is None


def _sky_scene() -> tuple[np.ndarray, np.ndarray]:
    """A blue-gradient sky above a textured street, with a rough skyline."""
    rng = np.random.default_rng(1)
    image = rng.integers(30, 160, size=(H, W, 3), dtype=np.uint8)
    x = np.arange(W)
    skyline = (45 + 8 * np.sin(x / 9.0) + 5 * (x % 37 > 20)).astype(int)
    rows = np.arange(H)[:, None]
    truth = rows < skyline[None, :]
    t = rows / H
    sky = np.zeros((H, W, 3), dtype=np.float64)
    sky[..., 0] = 90 + 80 * t  # red rises towards the horizon
    sky[..., 1] = 150 + 60 * t
    sky[..., 2] = 235 + 0 * t
    image[truth] = sky.astype(np.uint8)[truth]
    return image, truth


def test_sky_classical_finds_blue_gradient_above_textured_street() -> None:
    image, truth = _sky_scene()
    found = sky_mask_classical(image)
    assert _iou(found, truth) > 0.9


def test_sky_classical_ignores_smooth_bright_region_below_horizon() -> None:
    image, truth = _sky_scene()
    image[-30:] = (200, 200, 205)  # a bright, flat, grey road surface
    found = sky_mask_classical(image)
    assert not found[-30:].any()
    assert _iou(found, truth) > 0.9


def test_sky_label_id_reads_label_map_then_cityscapes_default() -> None:
    assert sky_label_id({0: "wall", 2: "Sky "}, 150) == 2
    assert sky_label_id({i: f"LABEL_{i}" for i in range(19)}, 19) == CITYSCAPES_SKY_ID
    with pytest.raises(ValueError, match="no 'sky' class"):
        sky_label_id({0: "road", 1: "car"}, 2)


def test_sky_segformer_runs_a_tiny_random_model(tmp_path: Path) -> None:
    transformers = pytest.importorskip("transformers")
    import torch

    torch.manual_seed(0)
    labels = ["road", "sidewalk", "building", "wall", "fence", "pole", "traffic light"]
    labels += ["traffic sign", "vegetation", "terrain", "sky", "person", "rider", "car"]
    labels += ["truck", "bus", "train", "motorcycle", "bicycle"]
    config = transformers.SegformerConfig(
        num_labels=19,
        id2label=dict(enumerate(labels)),
        label2id={n: i for i, n in enumerate(labels)},
        hidden_sizes=[8, 16, 16, 16],
        num_attention_heads=[1, 1, 1, 1],
        depths=[1, 1, 1, 1],
        decoder_hidden_size=16,
    )
    model = transformers.SegformerForSemanticSegmentation(config)
    with torch.no_grad():  # make every pixel "sky": a bias on the classifier's sky channel
        model.decode_head.classifier.bias.zero_()
        model.decode_head.classifier.bias[10] = 100.0
    model.save_pretrained(tmp_path / "tiny")
    image, _ = _sky_scene()
    masks = sky_mask_segformer([image, image[:60]], str(tmp_path / "tiny"))
    assert [m.shape for m in masks] == [(H, W), (60, W)]
    assert all(m.all() for m in masks)


def test_sky_segformer_without_transformers_names_the_install(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from cam2sim.core.errors import BackendUnavailableError

    monkeypatch.setitem(sys.modules, "transformers", None)
    with pytest.raises(BackendUnavailableError, match="pip install transformers"):
        sky_mask_segformer([np.zeros((4, 4, 3), np.uint8)], "some/model")
