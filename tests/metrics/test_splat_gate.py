"""The splat quality gate: fit, under-trained, off its envelope; its place in the table."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import numpy as np
import pytest

from cam2sim.metrics.behaviour import behaviour_table, evaluate_with_real_runs
from cam2sim.metrics.drive_io import DriveRun, load_run_dir
from cam2sim.metrics.drive_quality import DriveMetrics
from cam2sim.metrics.splat_gate import (
    HELD_OUT_MIN_PSNR_DB,
    MAX_BEYOND_ENVELOPE,
    SplatPathQuality,
    gate_methods,
    gate_run,
    path_quality,
    validated_envelope,
)
from cam2sim.splat.evaluate import (
    HeldOutFrame,
    MetricSummary,
    SplatEval,
    TruthEnvelope,
    TruthScore,
    summarise,
)

if TYPE_CHECKING:
    from pathlib import Path

ON_PATH = [0.1, 0.2, 0.3, 0.25, 0.15] * 4  # a run near the recorded path


def _one(value: float) -> MetricSummary:
    return summarise([value])


def _evaluation(
    psnr: float, ssim: float, *, coverage: float = 0.6, truth: list[TruthScore] | None = None
) -> SplatEval:
    frame = HeldOutFrame(
        index=8, psnr_db=psnr, ssim=ssim, lpips=None, coverage=coverage, chunks={0: 1.0}
    )
    return SplatEval(
        models_dir="models",
        n_held_out=1,
        psnr_db=_one(psnr),
        ssim=_one(ssim),
        lpips=summarise([]),
        lpips_net=None,
        lower_fraction=0.5,
        frames=[frame],
        offsets=[],
        truth=None if truth is None else TruthEnvelope(frames=[8], lpips_net=None, scores=truth),
    )


def _truth(lateral: float, psnr: float, ssim: float, coverage: float) -> TruthScore:
    return TruthScore(
        lateral_m=lateral,
        yaw_deg=0.0,
        psnr_db=_one(psnr),
        ssim=_one(ssim),
        lpips=summarise([]),
        coverage=_one(coverage),
    )


def test_a_well_trained_splat_driven_along_its_path_is_fit() -> None:
    quality = path_quality(ON_PATH, _evaluation(28.4, 0.88))
    assert quality.envelope_source == "held_out"
    assert quality.envelope_coverage == pytest.approx(0.6)
    assert quality.beyond_envelope_share == 0.0
    assert quality.coverage_max == pytest.approx(0.3)
    gate = gate_run(quality)
    assert gate.fit
    assert gate.reason == ""


def test_an_under_trained_splat_is_unfit_and_says_by_how_much() -> None:
    gate = gate_run(path_quality(ON_PATH, _evaluation(21.34, 0.83)))
    assert not gate.fit
    assert gate.reason == "splat under-trained: held-out 21.3 dB < 25 dB"
    both = gate_run(path_quality(ON_PATH, _evaluation(21.34, 0.71)))
    assert both.reason == "splat under-trained: held-out 21.3 dB < 25 dB, held-out SSIM 0.71 < 0.80"
    # Under-trained: nothing was validated, so no envelope is claimed.
    assert path_quality(ON_PATH, _evaluation(21.3, 0.71)).envelope_coverage is None


def test_a_run_that_leaves_the_validated_envelope_is_unfit() -> None:
    far = [0.2] * 10 + [0.9] * 10  # half the frames far from every training view
    quality = path_quality(far, _evaluation(28.4, 0.88, coverage=0.6))
    assert quality.beyond_envelope_share == pytest.approx(0.5)
    gate = gate_run(quality)
    assert not gate.fit
    assert [f.check for f in gate.failures] == ["envelope"]
    assert gate.reason == (
        "splat driven off its envelope: 50% of frames beyond the validated coverage 0.60 "
        "(at most 20%)"
    )
    share = MAX_BEYOND_ENVELOPE - 0.05  # a few frames beyond: still fit
    few = [0.2] * round(20 * (1 - share)) + [0.9] * round(20 * share)
    assert gate_run(path_quality(few, _evaluation(28.4, 0.88, coverage=0.6))).fit


def test_without_an_evaluation_the_splat_is_not_validated() -> None:
    quality = path_quality(ON_PATH, None, notes=["eval.json missing"])
    gate = gate_run(quality)
    assert not gate.fit
    assert gate.failures[0].check == "validated"
    assert "no held-out scores" in gate.reason
    assert quality.notes == ["eval.json missing"]


def test_the_truth_envelope_sets_the_validated_coverage_and_checks_the_path() -> None:
    rows = [
        _truth(0.0, 27.0, 0.86, 0.5),
        _truth(1.0, 26.0, 0.82, 0.8),
        _truth(2.0, 22.0, 0.74, 0.95),  # fails: not part of the validated envelope
    ]
    evaluation = _evaluation(28.0, 0.87, coverage=0.5, truth=rows)
    assert validated_envelope(evaluation) == (pytest.approx(0.8), "truth")
    quality = path_quality(ON_PATH, evaluation)
    assert quality.truth_ssim == pytest.approx(0.86)
    assert [p.lateral_m for p in quality.truth_envelope] == [0.0, 1.0, 2.0]
    assert gate_run(quality).fit
    unlike = _evaluation(28.0, 0.87, truth=[_truth(0.0, 23.0, 0.62, 0.5)])
    gate = gate_run(path_quality(ON_PATH, unlike))
    assert (
        gate.reason
        == "splat unlike the ground truth on the path: 23.0 dB < 25 dB, SSIM 0.62 < 0.80"
    )


def test_a_method_is_unfit_when_any_of_its_runs_is() -> None:
    good = path_quality(ON_PATH, _evaluation(28.4, 0.88))
    off = path_quality([0.9] * 10, _evaluation(28.4, 0.88))
    gates = gate_methods([("drive-splat", good), ("drive-splat", off), ("drive-splat", good)])
    assert len(gates) == 1
    gate = gates[0]
    assert (gate.fit, gate.runs, gate.unfit_runs) == (False, 3, 1)
    assert gate.reason.startswith("splat driven off its envelope in 1/3 runs: up to 100% ")
    assert gate.thresholds["held_out_min_psnr_db"] == HELD_OUT_MIN_PSNR_DB
    assert "held-out 28.4 dB / SSIM 0.88" in gate.evidence


def _run(name: str, method: str, quality: SplatPathQuality | None = None) -> DriveRun:
    x = np.arange(0.0, 100.0, 0.5)
    t = x / 8.0
    return DriveRun(
        name=name,
        method=method,
        real=method == "real",
        t=t,
        xy=np.stack([x, 0.3 * np.sin(x / 15.0)], -1),
        crs=None,
        steering_t=t[::3],
        steering=0.1 * np.sin(t[::3]),
        splat_quality=quality,
    )


def test_the_behaviour_table_says_plainly_when_the_splat_is_unfit(tmp_path: Path) -> None:
    weak = path_quality(ON_PATH, _evaluation(21.3, 0.83))
    runs = [
        _run("splat/a", "drive-splat", weak),
        _run("splat/b", "drive-splat", weak),
        _run("sim/a", "drive-raster"),
    ]
    ev = evaluate_with_real_runs([_run("real/recorded", "real")], runs)
    (gate,) = ev.metrics.splat_gate
    assert (gate.method, gate.fit, gate.unfit_runs) == ("drive-splat", False, 2)
    table = behaviour_table(ev.metrics)
    assert table.columns == ("Real", "splat (unfit)", "Sim")
    text = table.markdown()
    assert "| metric | Real | splat (unfit) | Sim |" in text
    assert "splat (unfit): splat under-trained: held-out 21.3 dB < 25 dB." in text
    assert "measures the splat, not the system under test" in text
    ev.metrics.save(tmp_path / "metrics.json")  # the verdict is in metrics.json too
    loaded = DriveMetrics.load(tmp_path / "metrics.json")
    assert loaded.splat_gate == ev.metrics.splat_gate
    raw = json.loads((tmp_path / "metrics.json").read_text(encoding="utf-8"))
    assert raw["splat_gate"][0]["reason"] == "splat under-trained: held-out 21.3 dB < 25 dB"


def test_a_fit_splat_and_runs_without_splat_quality_keep_their_plain_columns() -> None:
    fit = path_quality(ON_PATH, _evaluation(28.4, 0.88))
    ev = evaluate_with_real_runs(
        [_run("real/recorded", "real")], [_run("splat/a", "drive-splat", fit)]
    )
    assert ev.metrics.splat_gate[0].fit
    table = behaviour_table(ev.metrics)
    assert table.columns == ("Real", "splat")
    assert table.notes == ()
    plain = evaluate_with_real_runs(
        [_run("real/recorded", "real")], [_run("sim/a", "drive-raster")]
    )
    assert plain.metrics.splat_gate == []
    old = plain.metrics.model_dump(mode="json")
    del old["splat_gate"]  # metrics.json written before the gate
    assert DriveMetrics.model_validate(old).splat_gate == []


def test_run_folders_carry_their_splat_quality(tmp_path: Path) -> None:
    quality = path_quality(ON_PATH, _evaluation(21.3, 0.83))
    run = tmp_path / "run"
    run.mkdir()
    (run / "trajectory.csv").write_text("t,x,y\n0,0,0\n0.1,1,0\n", encoding="utf-8")
    meta = {"method": "drive-splat", "splat_quality": quality.model_dump(mode="json")}
    (run / "run.json").write_text(json.dumps(meta), encoding="utf-8")
    assert load_run_dir(run).splat_quality == quality
    (run / "run.json").write_text(json.dumps({"method": "drive-raster"}), encoding="utf-8")
    assert load_run_dir(run).splat_quality is None
