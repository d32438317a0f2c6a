"""Semantic IoU: palette, labels, per-frame IoU, summary, hood exclusion, comparison images."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
import pytest

from cam2sim.core.errors import ConfigError, StageError
from cam2sim.metrics.image_quality import read_rgb
from cam2sim.metrics.semantic import (
    FrameIoU,
    Palette,
    SemanticClass,
    SemanticOptions,
    SemanticResult,
    SemanticSummary,
    comparison_image,
    evaluate_semantic_folders,
    labels_from_rgb,
    semantic_iou,
)

if TYPE_CHECKING:
    from cam2sim.metrics.summary import MetricSummary

ROAD = (128, 64, 128)
CAR = (0, 0, 142)
SKY = (70, 130, 180)
NAMES = ("background", "road", "car")


def _seg(h: int, w: int, *, road_from: int, car: tuple[int, int, int, int] | None) -> np.ndarray:
    """A segmentation: sky on top, road from row ``road_from``, a car box (r0, r1, c0, c1)."""
    img = np.zeros((h, w, 3), np.uint8)
    img[:] = SKY
    img[road_from:] = ROAD
    if car is not None:
        r0, r1, c0, c1 = car
        img[r0:r1, c0:c1] = CAR
    return img


def _write(path: Path, rgb: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    return path


# ------------------------------------------------------------------------------ palette, labels


def test_default_palette_is_cityscapes_road_and_car() -> None:
    palette = Palette.cityscapes()
    assert palette.names == NAMES
    assert palette.classes[0].colors == (ROAD,)
    assert palette.classes[1].colors == (CAR,)
    assert palette.tolerance == 0


def test_labels_exact_match_and_everything_else_is_background() -> None:
    img = np.array([[ROAD, CAR, SKY, (128, 64, 129)]], np.uint8)
    np.testing.assert_array_equal(labels_from_rgb(img, Palette.cityscapes()), [[1, 2, 0, 0]])


def test_labels_with_tolerance_take_the_nearest_colour() -> None:
    palette = Palette.from_mapping({"a": [100, 100, 100], "b": [110, 100, 100]}, tolerance=8)
    img = np.array([[(103, 100, 100), (107, 100, 100), (105, 100, 100), (120, 100, 100)]], np.uint8)
    np.testing.assert_array_equal(labels_from_rgb(img, palette), [[1, 2, 1, 0]])


def test_palette_from_yaml_with_extra_classes_and_several_colours(tmp_path: Path) -> None:
    path = tmp_path / "palette.yaml"
    path.write_text(
        "tolerance: 15\nclasses:\n  road: [128, 64, 128]\n  car: [[0, 0, 142], [0, 0, 70]]\n"
        "  sidewalk: [244, 35, 232]\n"
    )
    palette = Palette.from_yaml(path)
    assert palette.names == ("background", "road", "car", "sidewalk")
    assert palette.classes[1] == SemanticClass("car", ((0, 0, 142), (0, 0, 70)))
    assert palette.tolerance == 15
    img = np.array([[(0, 0, 70), (244, 35, 232)]], np.uint8)
    np.testing.assert_array_equal(labels_from_rgb(img, palette), [[2, 3]])


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("classes: {road: [128, 64]}", "is not \\[r, g, b\\]"),
        ("classes: {road: [128, 64, 300]}", "not an RGB colour"),
        ("classes: {road: [1, 2, 3], car: [1, 2, 3]}", "is in both 'road' and 'car'"),
        ("classes: {background: [1, 2, 3]}", "not 'background'"),
        ("classes: {road: [1, 2, 3]}\ncolour: red", "unknown keys"),
        ("- road", "expected a mapping"),
        ("classes: {road: [1, 2, 3]}\ntolerance: 300", "tolerance must be within"),
    ],
)
def test_bad_palette_files_are_config_errors(tmp_path: Path, text: str, match: str) -> None:
    path = tmp_path / "palette.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=match):
        Palette.from_yaml(path)


# --------------------------------------------------------------------------------------- IoU


def test_iou_per_class_and_miou() -> None:
    real = np.array([[1, 1, 1, 1], [2, 2, 0, 0]])
    sim = np.array([[1, 1, 1, 0], [2, 0, 0, 0]])
    result = semantic_iou(real, sim, classes=NAMES)
    assert result.iou == {"background": pytest.approx(2 / 4), "road": 3 / 4, "car": 1 / 2}
    assert result.miou == pytest.approx((0.5 + 0.75 + 0.5) / 3)
    assert result.pixels == 8


def test_class_absent_from_both_is_excluded_not_zero() -> None:
    real = np.array([[1, 1, 0, 0]])
    sim = np.array([[1, 0, 0, 0]])
    result = semantic_iou(real, sim, classes=NAMES)
    assert result.iou["car"] is None
    assert result.miou == pytest.approx((2 / 3 + 1 / 2) / 2)


def test_class_in_one_image_only_scores_zero() -> None:
    result = semantic_iou(np.array([[2, 0]]), np.array([[0, 0]]), classes=NAMES)
    assert result.iou["car"] == 0.0


def test_exclusion_removes_pixels_from_the_comparison() -> None:
    real = np.array([[1, 1], [2, 2]])
    sim = np.array([[1, 1], [1, 1]])
    exclude = np.array([[False, False], [True, True]])
    result = semantic_iou(real, sim, classes=NAMES, exclude=exclude)
    assert result == FrameIoU(
        iou={"background": None, "road": 1.0, "car": None}, miou=1.0, pixels=2
    )
    empty = semantic_iou(real, sim, classes=NAMES, exclude=np.ones((2, 2), bool))
    assert empty.miou is None
    assert empty.pixels == 0


def test_iou_rejects_bad_labels() -> None:
    with pytest.raises(ValueError, match="one shape"):
        semantic_iou(np.zeros((2, 2), int), np.zeros((2, 3), int), classes=NAMES)
    with pytest.raises(ValueError, match=r"lie in \[0, 3\)"):
        semantic_iou(np.full((2, 2), 3), np.zeros((2, 2), int), classes=NAMES)


def test_summary_counts_only_frames_where_the_class_is_present() -> None:
    from cam2sim.metrics.semantic import SemanticFrame

    frames = [
        SemanticFrame("a", "", "", {"background": 1.0, "road": 0.5, "car": None}, 0.75, 4),
        SemanticFrame("b", "", "", {"background": 0.5, "road": 1.0, "car": 0.25}, 0.5, 4),
    ]
    summary = SemanticSummary.from_frames(frames, NAMES)

    def stats(s: MetricSummary) -> tuple[float | None, float | None, int]:
        return (s.mean, s.std, s.n)

    assert stats(summary.classes["car"]) == (0.25, 0.0, 1)
    assert stats(summary.classes["road"]) == (0.75, 0.25, 2)
    assert stats(summary.miou) == (0.625, 0.125, 2)


# ---------------------------------------------------------------------------------- folders


def _folders(tmp_path: Path) -> tuple[Path, Path]:
    real, sim = tmp_path / "real", tmp_path / "sim"
    _write(real / "000000.png", _seg(40, 60, road_from=20, car=(22, 30, 10, 20)))
    _write(sim / "000000.png", _seg(40, 60, road_from=22, car=(24, 30, 10, 20)))
    _write(real / "000001.png", _seg(40, 60, road_from=20, car=None))
    _write(sim / "000001.png", _seg(40, 60, road_from=20, car=None))
    _write(real / "000002.png", _seg(40, 60, road_from=20, car=None))
    return real, sim


def test_folder_iou_summary_and_unmatched(tmp_path: Path) -> None:
    real, sim = _folders(tmp_path)
    result = evaluate_semantic_folders(real, sim)
    assert [f.stem for f in result.frames] == ["000000", "000001"]
    assert result.real_only == ("000002",)
    assert result.frames[1].iou == {"background": 1.0, "road": 1.0, "car": None}
    assert result.summary.classes["car"].n == 1
    assert result.summary.classes["road"].n == 2
    assert result.frames[0].iou["car"] == pytest.approx(60 / 80)


def test_hood_is_excluded_not_painted(tmp_path: Path) -> None:
    real, sim = _folders(tmp_path)
    hooded = read_rgb(sim / "000001.png")
    hooded[-6:] = (255, 255, 0)  # the simulated hood: an unknown colour in the bottom rows
    _write(sim / "000001.png", hooded)
    plain = evaluate_semantic_folders(real, sim).frames[1]
    assert plain.iou["road"] < 1.0  # type: ignore[operator]
    by_rows = evaluate_semantic_folders(real, sim, options=SemanticOptions(hood_rows=6)).frames[1]
    assert by_rows.iou == {"background": 1.0, "road": 1.0, "car": None}
    assert by_rows.pixels == 34 * 60
    mask = np.zeros((40, 60), np.uint8)
    mask[-6:] = 255
    cv2.imwrite(str(tmp_path / "hood.png"), mask)
    by_mask = evaluate_semantic_folders(
        real, sim, options=SemanticOptions(hood_mask=tmp_path / "hood.png")
    ).frames[1]
    assert by_mask == by_rows


def test_size_mismatch_names_both_files_and_sizes(tmp_path: Path) -> None:
    real, sim = _folders(tmp_path)
    _write(sim / "000001.png", _seg(36, 60, road_from=20, car=None))
    with pytest.raises(StageError, match=r"real/000001.png is 60x40 but .*sim/000001.png is 60x36"):
        evaluate_semantic_folders(real, sim)


def test_comparison_images_and_artifact_roundtrip(tmp_path: Path) -> None:
    real, sim = _folders(tmp_path)
    out = tmp_path / "cmp"
    result = evaluate_semantic_folders(
        real, sim, options=SemanticOptions(hood_rows=4), comparison_dir=out
    )
    assert sorted(p.name for p in out.iterdir()) == ["000000.png", "000001.png"]
    image = read_rgb(out / "000000.png")
    assert image.shape == (40, 3 * 60 + 8, 3)
    path = tmp_path / "semantic.json"
    result.save(path)
    assert SemanticResult.load(path) == result
    assert "NaN" not in path.read_text()


def test_comparison_panels_show_labels_mismatch_and_exclusion() -> None:
    real = np.array([[1, 2], [0, 1]])
    sim = np.array([[1, 0], [0, 1]])
    exclude = np.array([[False, False], [False, True]])
    image = comparison_image(real, sim, Palette.cityscapes(), exclude=exclude)
    left, middle, right = image[:, 0:2], image[:, 6:8], image[:, 12:14]
    assert tuple(left[0, 0]) == ROAD
    assert tuple(left[0, 1]) == CAR
    assert tuple(right[0, 1]) == (0, 0, 0)
    assert tuple(middle[0, 1]) == (255, 255, 255)  # mismatch
    assert tuple(middle[0, 0]) == tuple(int(c * 0.35) for c in ROAD)  # agreement, dimmed
    assert tuple(left[1, 1]) == tuple(middle[1, 1]) == tuple(right[1, 1]) == (128, 128, 128)
