"""Seeded run-to-run variation: the same seed draws the same start and speed, others differ."""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING

import numpy as np
import pytest

from cam2sim.core.table import read_table
from cam2sim.scenario.model import Scenario
from cam2sim.scenario.synthetic import StreetSpec
from cam2sim.stages.runs import DriveOptions, drive
from cam2sim.stages.variation import DEMO_RUN_VARIATION, RunVariation
from conftest import street_workspace

if TYPE_CHECKING:
    from pathlib import Path


def test_draws_are_seeded_truncated_and_scaled() -> None:
    v = RunVariation(start_lateral_m=0.2, start_heading_deg=1.0, speed=0.05)
    assert v.draw(3) == v.draw(3)
    draws = [v.draw(s) for s in range(400)]
    lateral = np.array([d.lateral_m for d in draws])
    speed = np.array([d.speed_factor for d in draws])
    assert np.abs(lateral).max() <= 0.4 + 1e-12  # two standard deviations
    assert 0.15 < lateral.std() < 0.2  # a truncated normal of sigma 0.2
    assert np.abs(speed - 1.0).max() <= 0.1 + 1e-12
    assert len({d.heading_deg for d in draws}) > 350  # only the truncated tails repeat
    none = RunVariation().draw(7)
    assert (none.lateral_m, none.heading_deg, none.speed_factor) == (0.0, 0.0, 1.0)
    with pytest.raises(ValueError, match="standard deviations"):
        RunVariation(speed=-0.1)


def test_a_varied_run_starts_where_it_drew_and_says_so(tmp_path: Path) -> None:
    ws = street_workspace(tmp_path / "ws", StreetSpec(length_m=40.0))
    sc = Scenario.load(ws.scenario_dir / "scenario.json")
    vary = RunVariation(start_lateral_m=0.3, start_heading_deg=2.0, speed=0.1)
    options = DriveOptions(policy="pure-pursuit", camera="none", runs=2, seed=5, variation=vary)
    runs = drive(ws, options=options)
    plain = drive(ws, options=DriveOptions(policy="pure-pursuit", camera="none", seed=5))[0]
    starts = []
    for run, seed in zip(runs, (5, 6), strict=True):
        meta = json.loads((run.folder / "run.json").read_text())
        drawn = vary.draw(seed)
        assert meta["variation"] == {
            "lateral_m": drawn.lateral_m,
            "heading_deg": drawn.heading_deg,
            "speed_factor": drawn.speed_factor,
        }
        traj = read_table(run.folder / "trajectory.csv")
        # The start heading and the cruising speed follow the draw.
        heading0 = sc.hero_start.heading + math.radians(drawn.heading_deg)
        assert traj["heading"][0] == pytest.approx(heading0, abs=5e-3)  # one step steered
        assert np.median(traj["speed"][-20:]) == pytest.approx(
            sc.hero_start.speed * drawn.speed_factor, rel=0.02
        )
        starts.append((traj["x"][0], traj["y"][0]))
    assert starts[0] != starts[1]
    assert "variation" not in json.loads((plain.folder / "run.json").read_text())


def test_the_demo_varies_its_runs_like_a_driver() -> None:
    assert DEMO_RUN_VARIATION.start_lateral_m > 0
    assert DEMO_RUN_VARIATION.start_heading_deg > 0
    assert DEMO_RUN_VARIATION.speed > 0


def test_the_drive_command_varies_runs_and_refuses_a_bad_spec(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from cam2sim.cli.main import app

    ws = street_workspace(tmp_path / "ws", StreetSpec(length_m=30.0))
    args = ["drive", str(ws.root), "--camera", "none", "--runs", "2"]
    result = CliRunner().invoke(app, [*args, "--vary", "0.2,1,0.05"])
    assert result.exit_code == 0, result.output
    metas = [json.loads((d / "run.json").read_text()) for d in sorted(ws.runs_dir.iterdir())]
    assert len(metas) == 2
    assert metas[0]["variation"] != metas[1]["variation"]
    bad = CliRunner().invoke(app, [*args, "--vary", "0.2,1"])
    assert bad.exit_code != 0
    assert "LATERAL_M,HEADING_DEG,SPEED" in " ".join(bad.output.split())
