"""Steering agreement: a policy's steering on rendered frames against recorded ones."""

from __future__ import annotations

import shutil
from typing import TYPE_CHECKING

import numpy as np
import pytest

from cam2sim.metrics.steering_agreement import SteeringAgreement, steering_agreement
from conftest import street_workspace

if TYPE_CHECKING:
    from pathlib import Path


def test_the_gaps_are_summarised_with_the_worst_frame_and_the_scale() -> None:
    recorded = np.array([0.0, 1.0, -1.0, 0.5, 0.0])
    rendered = recorded + np.array([0.1, -0.1, 0.0, 1.2, 0.05])
    frames = [f"{k:06d}" for k in range(5)]
    a = steering_agreement("splat", "dave2.onnx", frames, recorded, rendered)
    assert a.mean_abs_gap == pytest.approx(0.29)
    assert a.max_abs_gap == pytest.approx(1.2)
    assert a.max_gap_frame == "000003"
    assert a.p95_abs_gap == pytest.approx(np.percentile([0.1, 0.1, 0.0, 1.2, 0.05], 95))
    assert a.correlation == pytest.approx(np.corrcoef(recorded, rendered)[0, 1])
    assert a.recorded_std == pytest.approx(np.std(recorded))
    assert a.held_out_frames == 0
    assert a.held_out_mean_abs_gap is None
    # The frames the renderer never trained on, summarised on their own.
    held_real, held_sim = [0.0, 0.5, -0.5, 1.0], [0.1, 0.4, -0.2, 1.0]
    b = steering_agreement("splat", "p", frames, recorded, rendered, held_out=(held_real, held_sim))
    assert b.held_out_frames == 4
    assert b.held_out_mean_abs_gap == pytest.approx((0.1 + 0.1 + 0.3 + 0.0) / 4)
    assert b.held_out_correlation == pytest.approx(np.corrcoef(held_real, held_sim)[0, 1])
    with pytest.raises(ValueError, match="held-out series of different lengths"):
        steering_agreement("splat", "p", frames, recorded, rendered, held_out=([0.1], []))


def test_a_constant_series_has_no_correlation_and_bad_lengths_are_refused() -> None:
    a = steering_agreement("raster", "p", ["a", "b", "c"], [0.2, 0.2, 0.2], [0.1, 0.3, 0.2])
    assert a.correlation is None
    with pytest.raises(ValueError, match="3 frames, 2 recorded and 3 rendered"):
        steering_agreement("raster", "p", ["a", "b", "c"], [0.2, 0.2], [0.1, 0.3, 0.2])


def test_the_replay_frames_are_shown_to_the_policy_beside_the_recorded_ones(
    tmp_path: Path,
) -> None:
    pytest.importorskip("moderngl")
    from cam2sim.scenario.synthetic import StreetSpec
    from cam2sim.stages.reconstruction import evaluate_replay_steering
    from cam2sim.stages.runs import ReplayOptions, replay

    ws = street_workspace(tmp_path / "ws", StreetSpec(length_m=16.0))
    try:
        run = replay(ws, options=ReplayOptions(cameras=("raster",), image_size=(160, 100)))
    except Exception as err:  # noqa: BLE001 -- no headless OpenGL here
        pytest.skip(f"no raster renderer: {err}")
    rendered = sorted((run.folder / "frames" / "raster").glob("*.png"))
    frames = [p.stem for p in rendered]
    recorded = ws.dataset_dir / "frames"  # the street has none: the test writes its own
    recorded.mkdir(parents=True, exist_ok=True)
    for p in rendered:
        shutil.copyfile(p, recorded / p.name)
    # A splat's held-out view: its render beside the prepared image it is scored against.
    import cv2

    image = cv2.imread(str(rendered[0]))
    renders, prepared = ws.splat_files.renders_dir, ws.splat_files.prep_images_dir
    renders.mkdir(parents=True)
    prepared.mkdir(parents=True)
    assert cv2.imwrite(str(renders / "000007.webp"), image)
    assert cv2.imwrite(str(prepared / "000007.png"), image)
    shutil.copytree(run.folder / "frames" / "raster", run.folder / "frames" / "splat")
    written = evaluate_replay_steering(ws, run.folder, tmp_path / "out", "constant:0.25")  # type: ignore[arg-type]
    assert written == [tmp_path / "out" / name / "steering.json" for name in ("raster", "splat")]
    assert SteeringAgreement.load(written[0]).held_out_frames == 0
    splat = SteeringAgreement.load(written[1])
    assert splat.held_out_frames == 1
    assert splat.held_out_mean_abs_gap == 0.0
    saved = SteeringAgreement.load(written[0])
    assert saved.frames == frames
    assert saved.recorded == saved.rendered == [0.25] * len(frames)
    assert saved.max_abs_gap == 0.0
    assert saved.policy == "constant:0.25"
