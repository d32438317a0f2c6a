"""`cam2sim splat` end to end on CPU: prepare, train a few steps, write chunk models."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

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
