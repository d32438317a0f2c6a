"""The evaluate stage: a workspace's drives scored once, recorded, and skipped when up to date."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest
import typer
from typer.testing import CliRunner

from cam2sim.cli.evaluate import evaluate_app
from cam2sim.core.errors import StageError
from cam2sim.metrics.drive_quality import DriveMetrics
from cam2sim.scenario.synthetic import StreetSpec
from cam2sim.stages.evaluate import (
    EVALUATE_STAGE,
    EvaluateOptions,
    evaluate_workspace,
    lane_margin,
)
from cam2sim.stages.runs import DriveOptions, drive
from conftest import street_workspace

if TYPE_CHECKING:
    from pathlib import Path

    from cam2sim.core.workspace import Workspace


def _workspace(root: Path) -> Workspace:
    return street_workspace(root, StreetSpec(length_m=30.0, radius_m=60.0))


def test_evaluate_scores_every_drive_writes_the_metrics_and_skips_when_up_to_date(
    tmp_path: Path,
) -> None:
    ws = _workspace(tmp_path / "ws")
    runs = drive(ws, options=DriveOptions(camera="none", runs=2))
    first = evaluate_workspace(ws)
    assert not first.up_to_date
    assert first.metrics == ws.drive_eval_dir / "metrics.json"
    metrics = DriveMetrics.load(first.metrics)
    assert {r.name for r in metrics.runs} == {"real/recorded"} | {
        f"drive-none/{r.run_id}" for r in runs
    }
    for name in ("segment.json", "behaviour.md", "lateral_offset.png", "steering.png"):
        assert (ws.drive_eval_dir / name).is_file()
    assert "no replay frames: image quality not computed" in first.notes
    record = ws.stage_record(EVALUATE_STAGE)
    assert record is not None
    assert record.state == "done"
    assert evaluate_workspace(ws).up_to_date
    assert ws.stage_record(EVALUATE_STAGE) == record
    assert not evaluate_workspace(ws, options=EvaluateOptions(force=True)).up_to_date
    drive(ws, options=DriveOptions(camera="none", runs=1, seed=7))  # a new run: new inputs
    assert not evaluate_workspace(ws).up_to_date


def test_the_recorded_drive_alone_gives_a_corridor_of_the_lanes_margin(tmp_path: Path) -> None:
    """The street's 3.5 m lanes and the 2.16 m car leave 0.67 m either side."""
    ws = _workspace(tmp_path / "ws")
    assert lane_margin(ws) == pytest.approx((3.5 - 2.16) / 2, abs=0.01)
    drive(ws, options=DriveOptions(camera="none", runs=1))
    metrics = DriveMetrics.load(evaluate_workspace(ws).metrics)
    assert metrics.corridor_rule == "single drive +- 0.67 m"
    assert metrics.corridor_mean_width_m == pytest.approx(1.34, abs=0.01)
    ws.map_xodr_path.unlink()
    assert lane_margin(ws) is None  # no map: the published zero-width envelope


def test_evaluate_without_drives_says_what_to_run(tmp_path: Path) -> None:
    ws = _workspace(tmp_path / "ws")
    with pytest.raises(StageError, match=r"no drive runs to evaluate; run `cam2sim drive "):
        evaluate_workspace(ws)


def test_evaluate_workspace_command_prints_the_table_and_writes_metrics(tmp_path: Path) -> None:
    ws = _workspace(tmp_path / "ws")
    drive(ws, options=DriveOptions(camera="none", runs=1))
    app = typer.Typer()
    app.add_typer(evaluate_app, name="evaluate")
    result = CliRunner().invoke(
        app, ["evaluate", "workspace", str(ws.root)], env={"COLUMNS": "200"}
    )
    assert result.exit_code == 0, result.output
    assert "drive-none" in result.stdout
    assert (ws.drive_eval_dir / "metrics.json").is_file()
    again = CliRunner().invoke(app, ["evaluate", "workspace", str(ws.root)])
    assert "up to date" in again.stdout
