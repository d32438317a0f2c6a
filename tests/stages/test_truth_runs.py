"""The truth camera: drives in the ground-truth world are real runs; the world's semantic IoU."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import numpy as np
import pytest

from cam2sim.core.errors import StageError
from cam2sim.render.truth import TruthCar, TruthWorld, truth_world_path
from cam2sim.scenario.model import Scenario
from cam2sim.scenario.synthetic import StreetSpec
from cam2sim.stages.runs import DriveOptions, drive
from conftest import has_egl, street_workspace, truth_workspace

if TYPE_CHECKING:
    from pathlib import Path

    from cam2sim.core.workspace import Workspace

SPEC = StreetSpec(length_m=40.0)


needs_gl = pytest.mark.skipif(not has_egl(), reason="no headless OpenGL (EGL) here")


def _with_truth(root: Path, *, cars: bool = True, look: str = "photographic") -> Workspace:
    """A synthetic street workspace whose ground truth is the same street (cars optional)."""
    return truth_workspace(root, SPEC, cars=cars, look=look)


def test_the_truth_camera_needs_a_ground_truth_world(tmp_path: Path) -> None:
    ws = street_workspace(tmp_path / "ws", SPEC)
    with pytest.raises(StageError, match=r"truth/world\.json"):
        drive(ws, options=DriveOptions(camera="truth"))


def _events(ws: Workspace, judge: str) -> list[str]:
    options = DriveOptions(policy="pure-pursuit", camera="none", judge=judge)  # type: ignore[arg-type]
    (run,) = drive(ws, options=options)
    return [e["kind"] for e in run.events]


def test_runs_can_be_judged_in_the_ground_truth_world(tmp_path: Path) -> None:
    import re

    # The truth street lies 12 m north of the map's: the recorded route is not on its road.
    ws = _with_truth(tmp_path / "ws", cars=False)
    world = TruthWorld.load(truth_world_path(ws.root))
    moved = re.sub(
        r'(<geometry\b[^>]*\by=")([^"]*)"',
        lambda m: f'{m.group(1)}{float(m.group(2)) + 12.0}"',
        world.xodr,
    )
    world.model_copy(update={"xodr": moved}).save(truth_world_path(ws.root))
    assert "off_road" not in _events(ws, "map")
    assert _events(ws, "truth")[0] == "off_road"
    # A truth car standing in the lane: a collision only where the truth is the judge.
    ws2 = _with_truth(tmp_path / "ws2", cars=False)
    world = TruthWorld.load(truth_world_path(ws2.root))
    sc = Scenario.load(ws2.scenario_dir / "scenario.json")
    x, y = sc.trajectory.center[len(sc.trajectory.center) // 2][:2]
    car = TruthCar(x=x, y=y, yaw=0.0, length=4.5, width=1.8, height=1.5)
    world.model_copy(update={"cars": (car,)}).save(truth_world_path(ws2.root))
    assert "collision" not in _events(ws2, "map")
    assert "collision" in _events(ws2, "truth")


def test_judging_in_the_truth_needs_the_builtin_simulator_and_a_truth_world(
    tmp_path: Path,
) -> None:
    from cam2sim.core.errors import ConfigError

    with pytest.raises(ConfigError, match="builtin simulator"):
        DriveOptions(judge="truth", simulator="carla", camera="none")
    ws = street_workspace(tmp_path / "ws", SPEC)
    with pytest.raises(StageError, match="--judge map"):
        _events(ws, "truth")


@needs_gl
def test_a_drive_in_the_ground_truth_world_is_a_real_run(tmp_path: Path) -> None:
    ws = _with_truth(tmp_path / "ws")
    options = DriveOptions(camera="truth", image_size=(160, 100), save_frames=True)
    (run,) = drive(ws, options=options)
    meta = json.loads((run.folder / "run.json").read_text())
    assert meta["method"] == "real"
    assert meta["camera"] == "truth"
    frames = sorted((run.folder / "frames" / "truth").glob("*.png"))
    assert frames
    import cv2

    image = cv2.imread(str(frames[0]))
    # The photographic look: no flat colour areas (textures and sensor noise everywhere).
    assert np.abs(np.diff(image.astype(np.int16), axis=1)).mean() > 1.5


@needs_gl
def test_semantic_iou_is_high_for_the_same_world_and_drops_without_its_cars(
    tmp_path: Path,
) -> None:
    from cam2sim.metrics.semantic import SemanticResult
    from cam2sim.stages.reconstruction import evaluate_world_semantics

    same = _with_truth(tmp_path / "same", look="raster")
    path = evaluate_world_semantics(same, same.report_dir / "semantic", every=5)
    result = SemanticResult.load(path)
    assert result.frames
    assert result.summary.miou.mean is not None
    assert result.summary.miou.mean > 0.99
    bare = _with_truth(tmp_path / "bare", cars=False)
    worse = SemanticResult.load(evaluate_world_semantics(bare, bare.report_dir / "sem", every=5))
    car = worse.summary.classes["car"].mean
    assert car is not None
    assert car < 0.5


@needs_gl
def test_campaign_runs_in_the_ground_truth_world_are_scored_like_the_others(
    tmp_path: Path,
) -> None:
    from cam2sim.campaign.executors import LocalPool
    from cam2sim.campaign.runner import run_campaign

    _with_truth(tmp_path / "ws", look="raster")
    plan = tmp_path / "plan.yaml"
    plan.write_text(
        "workspaces: [ws]\npolicies: [pure-pursuit]\ncameras: [truth]\nseeds: [0]\n"
        "drive: {image_size: [32, 24]}\n",
        encoding="utf-8",
    )
    result = run_campaign(plan, executor=LocalPool(1))
    assert (result.specs, result.ran, result.failed) == (1, 1, 0)
    # Scored like any run (before, real-world runs were left out of the summary's metrics).
    (row,) = result.rows
    assert row.camera == "truth"
    assert row.completion is not None
    assert row.completion > 0.8
    (summary,) = result.summary
    assert summary.camera == "truth"
    assert summary.completion_mean == pytest.approx(row.completion)
