"""PSNR, SSIM, folder pairing, masks and the image-quality artifact."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from cam2sim.core.errors import StageError, WorkspaceError
from cam2sim.metrics.image_quality import (
    PSNR_CAP_DB,
    ImageQualityOptions,
    ImageQualityResult,
    evaluate_image_folders,
    exclusion_mask,
    pair_images_by_stem,
    psnr,
    read_mask,
    read_rgb,
    ssim,
    ssim_map,
    write_image_quality,
)
from cam2sim.metrics.summary import MetricSummary, summarise

NO_LPIPS = ImageQualityOptions(lpips_net=None)


def _image(h: int = 48, w: int = 64, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 256, size=(h // 4, w // 4, 3), dtype=np.uint8)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)


def _write(path: Path, rgb: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    return path


def _folders(tmp_path: Path, n: int = 3, *, size: tuple[int, int] = (48, 64)) -> tuple[Path, Path]:
    real, sim = tmp_path / "real", tmp_path / "sim"
    for i in range(n):
        img = _image(*size, seed=i)
        _write(real / f"{i:06d}.png", img)
        _write(sim / f"{i:06d}.png", cv2.GaussianBlur(img, (0, 0), 0.5 + i))
    return real, sim


# ----------------------------------------------------------------------------------------- PSNR


def test_psnr_of_a_constant_error_is_analytic() -> None:
    a = np.full((20, 20, 3), 100, np.uint8)
    b = a + np.uint8(5)
    assert psnr(a, b) == pytest.approx(10 * math.log10(255**2 / 25))


def test_psnr_of_identical_images_is_the_cap() -> None:
    a = _image()
    assert psnr(a, a) == PSNR_CAP_DB


def test_masked_psnr_uses_only_kept_pixels() -> None:
    a = np.full((20, 20, 3), 100, np.uint8)
    b = a.copy()
    b[:10] += 5
    b[10:] = 0
    exclude = np.zeros((20, 20), bool)
    exclude[10:] = True
    assert psnr(a, b, exclude=exclude) == pytest.approx(10 * math.log10(255**2 / 25))
    assert psnr(a, b, exclude=np.ones((20, 20), bool)) is None


# ----------------------------------------------------------------------------------------- SSIM


def test_ssim_equals_scikit_image_gaussian_ssim() -> None:
    metrics = pytest.importorskip("skimage.metrics")
    a = _image(60, 80, seed=1)
    for b in (_image(60, 80, seed=2), cv2.GaussianBlur(a, (0, 0), 1.2)):
        ref = metrics.structural_similarity(
            a,
            b,
            gaussian_weights=True,
            sigma=1.5,
            use_sample_covariance=False,
            data_range=255,
            channel_axis=2,
        )
        assert ssim(a, b) == pytest.approx(ref, abs=1e-10)


def test_ssim_map_covers_the_valid_region_and_identical_is_one() -> None:
    a = _image(30, 40)
    smap = ssim_map(a, a)
    assert smap.shape == (20, 30)
    np.testing.assert_allclose(smap, 1.0)
    assert ssim(a[..., 0], a[..., 0]) == pytest.approx(1.0)


def test_masked_ssim_ignores_excluded_pixels() -> None:
    a = _image(60, 80)
    b = a.copy()
    b[40:] = 255 - b[40:]
    exclude = np.zeros((60, 80), bool)
    exclude[30:] = True  # covers the change and every window that reaches it
    assert ssim(a, b, exclude=exclude) == pytest.approx(1.0)
    full = ssim(a, b)
    assert full is not None
    assert full < 0.8
    assert ssim(a, b, exclude=np.ones((60, 80), bool)) is None


def test_ssim_rejects_tiny_and_mismatched_images() -> None:
    with pytest.raises(ValueError, match="at least 11x11"):
        ssim_map(np.zeros((8, 8, 3), np.uint8), np.zeros((8, 8, 3), np.uint8))
    with pytest.raises(ValueError, match="one shape"):
        psnr(np.zeros((8, 8, 3), np.uint8), np.zeros((8, 9, 3), np.uint8))


# ------------------------------------------------------------------------------- stats, masks


def test_stats_skip_missing_values_and_never_give_nan() -> None:
    got = summarise([1.0, None, 3.0, float("nan")])
    assert (got.mean, got.std, got.n) == (2.0, 1.0, 2)
    assert (got.p10, got.p90) == pytest.approx((1.2, 2.8))
    assert summarise([None, None]) == MetricSummary(mean=None, std=None, p10=None, p90=None, n=0)


def test_exclusion_mask_combines_hood_rows_and_masks(tmp_path: Path) -> None:
    assert exclusion_mask((10, 8)) is None
    sky = np.zeros((10, 8), bool)
    sky[0] = True
    mask = exclusion_mask((10, 8), hood_rows=3, masks=[(tmp_path / "sky.png", sky)])
    assert mask is not None
    assert mask.sum() == 4 * 8
    assert mask[0].all()
    assert mask[7:].all()
    with pytest.raises(StageError, match=r"sky.png is 8x9 but the image is 8x10"):
        exclusion_mask((10, 8), masks=[(tmp_path / "sky.png", np.zeros((9, 8), bool))])


def test_read_mask_conventions(tmp_path: Path) -> None:
    raw = np.zeros((4, 4), np.uint8)
    raw[0] = 255
    path = tmp_path / "m.png"
    cv2.imwrite(str(path), raw)
    assert read_mask(path).sum() == 4
    assert read_mask(path, keep_nonzero=True).sum() == 12


def test_read_rgb_converts_grey_and_refuses_broken_files(tmp_path: Path) -> None:
    grey = tmp_path / "g.png"
    cv2.imwrite(str(grey), np.full((5, 6), 7, np.uint8))
    assert read_rgb(grey).shape == (5, 6, 3)
    broken = tmp_path / "broken.png"
    broken.write_bytes(b"not a png")
    with pytest.raises(WorkspaceError, match=r"cannot read image .*broken.png"):
        read_rgb(broken)
    deep = tmp_path / "deep.png"
    cv2.imwrite(str(deep), np.zeros((5, 6), np.uint16))
    with pytest.raises(WorkspaceError, match="only 8-bit"):
        read_rgb(deep)


# ----------------------------------------------------------------------------------- pairing


def test_pairing_by_stem_lists_unmatched(tmp_path: Path) -> None:
    real, sim = _folders(tmp_path, 2)
    _write(real / "extra.png", _image())
    (sim / "000000.png").rename(sim / "000000.jpg")
    _write(sim / "only_sim.png", _image())
    (sim / "notes.txt").write_text("ignored")
    pairing = pair_images_by_stem(real, sim)
    assert [p.stem for p in pairing.pairs] == ["000000", "000001"]
    assert pairing.pairs[0].sim.name == "000000.jpg"
    assert pairing.real_only == ("extra",)
    assert pairing.sim_only == ("only_sim",)


def test_pairing_errors_are_clear(tmp_path: Path) -> None:
    real, sim = _folders(tmp_path, 1)
    with pytest.raises(WorkspaceError, match="does not exist"):
        pair_images_by_stem(real, tmp_path / "missing")
    _write(sim / "000000.jpg", _image())
    with pytest.raises(WorkspaceError, match="two images of stem '000000'"):
        pair_images_by_stem(real, sim)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(StageError, match="no image pairs"):
        pair_images_by_stem(real, empty)


# ------------------------------------------------------------------------------ folder scoring


def test_folder_scores_and_summary(tmp_path: Path) -> None:
    real, sim = _folders(tmp_path, 3)
    _write(sim / "000000.png", read_rgb(real / "000000.png"))  # identical pair
    result = evaluate_image_folders(real, sim, options=NO_LPIPS)
    assert [r.stem for r in result.images] == ["000000", "000001", "000002"]
    assert result.images[0].psnr_db == PSNR_CAP_DB
    assert result.images[0].ssim == pytest.approx(1.0)
    assert result.images[1].psnr_db > result.images[2].psnr_db  # type: ignore[operator]
    assert result.summary["psnr_db"].n == 3
    assert result.summary["lpips"] == MetricSummary(n=0)
    assert result.lpips_net is None


def test_folder_masks_pair_by_stem_and_a_fully_masked_frame_is_left_out(tmp_path: Path) -> None:
    real, sim = _folders(tmp_path, 2)
    masks = tmp_path / "masks"
    masks.mkdir()
    cv2.imwrite(str(masks / "000000.png"), np.zeros((48, 64), np.uint8))
    cv2.imwrite(str(masks / "000001.png"), np.full((48, 64), 255, np.uint8))
    options = ImageQualityOptions(mask_dir=masks, lpips_net=None)
    result = evaluate_image_folders(real, sim, options=options)
    assert result.images[0].excluded_fraction == 0.0
    assert result.images[1].psnr_db is None
    assert result.images[1].excluded_fraction == 1.0
    assert result.summary["psnr_db"].n == 1
    assert result.summary["ssim"].n == 1
    inverted = ImageQualityOptions(mask_dir=masks, mask_keeps_nonzero=True, lpips_net=None)
    flipped = evaluate_image_folders(real, sim, options=inverted)
    assert flipped.images[0].psnr_db is None
    assert flipped.images[1].excluded_fraction == 0.0


def test_folder_hood_rows_exclude_the_bottom(tmp_path: Path) -> None:
    real, sim = _folders(tmp_path, 1)
    img = read_rgb(real / "000000.png")
    changed = img.copy()
    changed[-10:] = 0
    _write(sim / "000000.png", changed)
    result = evaluate_image_folders(
        real, sim, options=ImageQualityOptions(hood_rows=10, lpips_net=None)
    )
    assert result.images[0].psnr_db == PSNR_CAP_DB
    assert result.images[0].excluded_fraction == pytest.approx(10 / 48)


def test_missing_mask_size_mismatch_and_unreadable_files_are_errors(tmp_path: Path) -> None:
    real, sim = _folders(tmp_path, 2)
    masks = tmp_path / "masks"
    masks.mkdir()
    cv2.imwrite(str(masks / "000000.png"), np.zeros((48, 64), np.uint8))
    with pytest.raises(StageError, match="1 image pairs have no mask.*000001"):
        evaluate_image_folders(
            real, sim, options=ImageQualityOptions(mask_dir=masks, lpips_net=None)
        )
    _write(sim / "000001.png", _image(40, 64))
    with pytest.raises(StageError, match=r"000001.png is 64x48 but .*000001.png is 64x40"):
        evaluate_image_folders(real, sim, options=NO_LPIPS)
    (sim / "000001.png").write_bytes(b"")
    with pytest.raises(WorkspaceError, match=r"cannot read image .*sim/000001.png"):
        evaluate_image_folders(real, sim, options=NO_LPIPS)


def test_artifact_and_csv_roundtrip(tmp_path: Path) -> None:
    real, sim = _folders(tmp_path, 2)
    _write(sim / "000000.png", read_rgb(real / "000000.png"))
    result = evaluate_image_folders(real, sim, options=NO_LPIPS)
    json_path, csv_path = write_image_quality(result, tmp_path / "out")
    assert ImageQualityResult.load(json_path) == result
    assert "NaN" not in json_path.read_text()
    assert "Infinity" not in json_path.read_text()
    lines = csv_path.read_text().splitlines()
    assert lines[0] == "stem,psnr_db,ssim,lpips,excluded_fraction,real,sim"
    assert lines[1].startswith("000000,100.000000,1.000000,,0.000000,")
