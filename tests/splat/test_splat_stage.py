"""`cam2sim splat` end to end on CPU: prepare, train a few steps, write chunk models."""

from __future__ import annotations

import dataclasses
import datetime as dt
from pathlib import Path

import numpy as np
import pytest
from test_prepare import _workspace
from typer.testing import CliRunner

from cam2sim.cli.main import app
from cam2sim.splat.sfm import has_pycolmap


@pytest.mark.skipif(not has_pycolmap(), reason="needs pycolmap (pip install cam2sim[splat])")
def test_splat_command_prepares_trains_and_records_the_stage(tmp_path: Path) -> None:
    pytest.importorskip("torch")
    ws = _workspace(tmp_path / "ws", lidar=False)
    ws.record_stage("extract", state="done", started=dt.datetime.now(dt.UTC), inputs_hash="x")
    args = ["--no-progress", "splat", str(ws.root), "--device", "cpu", "--max-steps", "20"]
    args += ["--min-steps", "20", "--downscale", "2", "--chunk-length", "10"]
    args += ["--time-budget", "600"]  # ample: the 20 steps end it
    result = CliRunner().invoke(app, args, env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    assert "chunk 0: 20 steps in " in result.output
    assert "(stopped: max_steps)" in result.output
    assert "held-out (" in result.output  # the evaluation's headline
    assert (ws.splat_dir / "eval.json").is_file()
    assert sorted(p.name for p in (ws.splat_dir / "models").glob("chunk_*.pt")) == ["chunk_00.pt"]
    assert (ws.splat_dir / "prep" / "scene.json").is_file()
    record = ws.stage_record("splat")
    assert record is not None
    assert record.state == "done"


def test_splat_command_without_a_dataset_says_to_extract_first(tmp_path: Path) -> None:
    from cam2sim.core.config import Config
    from cam2sim.core.workspace import Workspace

    ws = Workspace.create(tmp_path / "ws", Config())
    result = CliRunner().invoke(app, ["--no-progress", "splat", str(ws.root)])
    assert result.exit_code == 1
    assert "cam2sim extract" in result.stderr


def test_splat_command_refuses_a_time_budget_of_zero(tmp_path: Path) -> None:
    result = CliRunner().invoke(
        app, ["--no-progress", "splat", str(tmp_path), "--time-budget", "0"]
    )
    assert result.exit_code == 1
    assert "time_budget_s=0" in result.stderr


def test_the_stage_scores_against_the_truth_only_where_a_truth_world_exists(
    tmp_path: Path,
) -> None:
    from cam2sim.render.truth import TruthWorld, truth_world_path
    from cam2sim.scenario.synthetic import StreetSpec, synthetic_street
    from cam2sim.splat.envelope import TruthEnvelopeOptions
    from cam2sim.splat.scene import SceneRecord
    from cam2sim.stages.splat import SplatStageOptions, _truth_reference
    from conftest import has_egl, street_workspace

    if not has_egl():
        pytest.skip("no headless OpenGL (EGL) for the truth camera")
    ws = street_workspace(tmp_path / "ws", StreetSpec(length_m=30.0))
    scene = SceneRecord(frames=[], chunks=[], pose_source="recording")
    notes: list[str] = []
    with _truth_reference(ws, SplatStageOptions(), scene, notes) as truth:
        assert truth is None  # no truth/world.json
    _, xodr = synthetic_street(StreetSpec(length_m=30.0))
    TruthWorld(crs="EPSG:32632", origin=(0.0, 0.0), xodr=xodr).save(truth_world_path(ws.root))
    options = SplatStageOptions(truth=TruthEnvelopeOptions(max_frames=3))
    with _truth_reference(ws, options, scene, notes) as truth:
        assert truth is not None
        assert truth.options.max_frames == 3
        assert truth.ground_z is not None  # from the scenario: the road is at z = 0
        assert truth.ground_z(np.array([10.0, 0.0])) == pytest.approx(0.0)
    with _truth_reference(ws, SplatStageOptions(truth_envelope=False), scene, notes) as truth:
        assert truth is None
    assert notes == []
    sfm = scene.model_copy(update={"scale_ambiguous": True})
    with _truth_reference(ws, options, sfm, notes) as truth:
        assert truth is None
    assert notes == ["not scored against the ground truth: the scene's scale is unknown (SfM)"]


def test_a_failed_training_resumes_from_the_chunks_it_finished(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    pytest.importorskip("torch")
    from cam2sim.splat.prepare import PrepareOptions
    from cam2sim.splat.train_options import TrainOptions, chunk_result_path
    from cam2sim.stages.splat import SplatStageOptions, run_splat

    ws = _workspace(tmp_path / "ws", lidar=True)
    ws.record_stage("extract", state="done", started=dt.datetime.now(dt.UTC), inputs_hash="x")
    options = SplatStageOptions(
        prepare=PrepareOptions(chunk_length_m=3.0, overlap_m=0.5, triangulate=False),
        train=TrainOptions(
            device="cpu", max_steps=6, min_steps=6, val_every=3, downscale=2, sky_points=20
        ),
        evaluate=False,
    )
    first = run_splat(ws, options=options)
    assert first.trained is not None
    ids = [c.chunk_id for c in first.trained.chunks]
    assert len(ids) >= 2
    models = ws.splat_files.models_dir
    # As after a run in which the last chunk failed: its model and result are missing, and
    # the stage is not done.
    last = ids[-1]
    (models / f"chunk_{last:02d}.pt").unlink()
    (models / f"chunk_{last:02d}.json").unlink()
    chunk_result_path(models, last).unlink()
    ws.record_stage("splat", state="failed", started=dt.datetime.now(dt.UTC), inputs_hash="y")
    written = {c: (models / f"chunk_{c:02d}.pt").stat().st_mtime_ns for c in ids[:-1]}
    with caplog.at_level("INFO", logger="cam2sim.stages.splat"):
        again = run_splat(ws, options=options)
    assert again.trained is not None
    assert again.trained.chunks == (*first.trained.chunks[:-1], again.trained.chunks[-1])
    assert again.trained.chunks[-1].chunk_id == last
    assert (models / f"chunk_{last:02d}.pt").is_file()
    assert {c: (models / f"chunk_{c:02d}.pt").stat().st_mtime_ns for c in ids[:-1]} == written
    assert f"training [{last}]" in caplog.text
    # A workspace moved elsewhere resumes the same way, from its models where they are now.
    moved = tmp_path / "moved"
    ws.root.rename(moved)
    from cam2sim.core.workspace import Workspace

    ws = Workspace.open(moved)
    models = ws.splat_files.models_dir
    (models / f"chunk_{last:02d}.pt").unlink()
    ws.record_stage("splat", state="failed", started=dt.datetime.now(dt.UTC), inputs_hash="y")
    before_move = {c: (models / f"chunk_{c:02d}.pt").stat().st_mtime_ns for c in ids[:-1]}
    after_move = run_splat(ws, options=options)
    assert {c: (models / f"chunk_{c:02d}.pt").stat().st_mtime_ns for c in ids[:-1]} == before_move
    assert after_move.trained is not None
    assert [c.model_path for c in after_move.trained.chunks] == [
        models / f"chunk_{c:02d}.pt" for c in ids
    ]
    written = {c: (models / f"chunk_{c:02d}.pt").stat().st_mtime_ns for c in ids[:-1]}
    # Other options are another training: nothing is kept.
    changed = dataclasses.replace(options, train=dataclasses.replace(options.train, max_steps=7))
    third = run_splat(ws, options=changed)
    assert third.trained is not None
    assert [c.steps for c in third.trained.chunks] == [7] * len(ids)
    # force trains every chunk again although the inputs are the same.
    forced = run_splat(ws, options=changed, force=True)
    assert forced.trained is not None
    assert all(c.model_path.stat().st_mtime_ns > written[ids[0]] for c in forced.trained.chunks)
