"""Stage scenario end to end: bag -> extract -> (map, parked vehicles) -> WS/scenario/."""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING

import numpy as np
import pytest
from typer.testing import CliRunner

from cam2sim.cli.main import app
from cam2sim.core.config import (
    CameraConfig,
    Config,
    IntrinsicsConfig,
    PoseConfig,
    RecordingConfig,
    TopicsConfig,
)
from cam2sim.core.errors import StageError
from cam2sim.core.table import read_table
from cam2sim.core.workspace import Workspace
from cam2sim.detect.vehicles import ParkedVehicle, ParkedVehicles, parked_vehicles_path
from cam2sim.recording.bagwriter import BagWriter
from cam2sim.scenario.carla_export import trajectory_from_carla
from cam2sim.scenario.model import Scenario
from cam2sim.scenario.openscenario import validate_openscenario
from cam2sim.stages.extract import extract
from cam2sim.stages.scenario import ScenarioOptions, run_scenario, size_class

if TYPE_CHECKING:
    from pathlib import Path

UTM32N = "EPSG:32632"
E0, N0 = 691_000.0, 5_336_000.0
SPEED = 5.0
DURATION_S = 8.0


def _write_bag(path: Path) -> None:
    t0 = 1_700_000_000_000_000_000
    odom = [(t0 + k * 20_000_000, "odom") for k in range(int(DURATION_S * 50))]
    cam = [(t0 + 50_000_000 + k * 100_000_000, "cam") for k in range(int(DURATION_S * 10) - 1)]
    with BagWriter(path, "mcap") as w:
        for i, (stamp, kind) in enumerate(sorted(odom + cam)):
            t = (stamp - t0) / 1e9
            if kind == "odom":
                w.write_odometry("/odom", stamp, (E0 + SPEED * t, N0))
            else:
                w.write_fields(
                    "/camera/image_raw",
                    "sensor_msgs/msg/Image",
                    {
                        "header": {"stamp": stamp, "frame_id": "camera"},
                        "height": 4,
                        "width": 4,
                        "encoding": "rgb8",
                        "step": 12,
                        "data": np.full(48, i % 255, dtype=np.uint8),
                    },
                    receive_ns=stamp,
                )


def _xodr(start: np.ndarray, hdg: float, length: float) -> str:
    """A straight two-way street whose right driving lane is centred on the route."""
    left = np.array([-math.sin(hdg), math.cos(hdg)])
    back = start[:2] - 20.0 * np.array([math.cos(hdg), math.sin(hdg)]) + 1.75 * left
    lanes = """
      <left>
        <lane id="3" type="sidewalk"><width sOffset="0" a="2" b="0" c="0" d="0"/></lane>
        <lane id="2" type="parking"><width sOffset="0" a="2.5" b="0" c="0" d="0"/></lane>
        <lane id="1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane>
      </left>
      <center><lane id="0" type="none"/></center>
      <right>
        <lane id="-1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane>
        <lane id="-2" type="parking"><width sOffset="0" a="2.5" b="0" c="0" d="0"/></lane>
        <lane id="-3" type="sidewalk"><width sOffset="0" a="2" b="0" c="0" d="0"/></lane>
      </right>"""
    return f"""<?xml version="1.0"?>
<OpenDRIVE><header revMajor="1" revMinor="4"/>
  <road name="street" length="{length + 40}" id="1" junction="-1">
    <planView><geometry s="0" x="{back[0]}" y="{back[1]}" hdg="{hdg}" length="{length + 40}">
      <line/></geometry></planView>
    <lanes><laneSection s="0">{lanes}
    </laneSection></lanes>
  </road>
</OpenDRIVE>
"""


def _car(
    vid: str, s: float, lat: float, frame: tuple[np.ndarray, float], **kw: object
) -> ParkedVehicle:
    start, hdg = frame
    fwd = np.array([math.cos(hdg), math.sin(hdg)])
    left = np.array([-math.sin(hdg), math.cos(hdg)])
    xy = start[:2] + s * fwd + lat * left
    fields: dict[str, object] = {
        "id": vid,
        "position": (float(xy[0]), float(xy[1]), 0.0),
        "yaw": hdg,
        "size": (4.5, 1.8, 1.5),
        "confidence": 0.8,
        "hits": 6,
        "side": "left" if lat > 0 else "right",
        "orientation": "parallel",
        "source": "lidar",
    }
    return ParkedVehicle.model_validate(fields | kw)


@pytest.fixture(scope="module")
def street(tmp_path_factory: pytest.TempPathFactory) -> Workspace:
    root = tmp_path_factory.mktemp("scenario")
    _write_bag(root / "drive")
    cfg = Config(
        recording=RecordingConfig(bags=[str(root / "drive")]),
        topics=TopicsConfig(camera="/camera/image_raw", pose="/odom"),
        pose=PoseConfig(crs=UTM32N),
        camera=CameraConfig(
            intrinsics=IntrinsicsConfig(fx=4.0, fy=4.0, cx=2.0, cy=2.0, width=4, height=4)
        ),
    )
    ws = Workspace.create(root / "ws", cfg)
    extract(ws)
    poses = read_table(ws.dataset_dir / "poses.csv")
    xy = np.column_stack([poses["x"], poses["y"]])
    hdg = math.atan2(*(xy[-1] - xy[0])[::-1])
    length = float(np.linalg.norm(xy[-1] - xy[0]))
    ws.map_dir.mkdir(parents=True, exist_ok=True)
    (ws.map_dir / "map.xodr").write_text(_xodr(xy[0], hdg, length), encoding="utf-8")
    frame = (xy[0], hdg)
    cars = (
        _car("pv_000", 8.0, -4.75, frame),  # right parking lane: fine
        _car("pv_001", 16.0, 0.3, frame),  # on the recorded path
        _car("pv_002", 24.0, -4.75, frame, confidence=0.9),
        _car("pv_003", 25.5, -4.9, frame, confidence=0.4),  # overlaps pv_002
        _car("pv_004", 30.0, 5.2, frame, size=(5.6, 2.0, 2.2)),  # a van, left parking lane
    )
    ParkedVehicles(
        source="lidar", detector="geometric", frames_used=10, detections=40, min_hits=3,
        vehicles=cars,
    ).save(parked_vehicles_path(ws.detections_dir))  # fmt: skip
    return ws


def test_scenario_stage_writes_every_asset(street: Workspace) -> None:
    res = run_scenario(street, force=True)
    doc = res.scenario
    assert doc is not None
    folder = street.scenario_dir
    assert Scenario.load(folder / "scenario.json") == doc
    poses = read_table(street.dataset_dir / "poses.csv")
    tr = doc.trajectory
    assert len(tr.frame) == len(poses["frame"])
    np.testing.assert_allclose(np.asarray(tr.reference)[:, 0], poses["x"], atol=1e-6)
    # Recorded pose = rear axle; the centre is 1.393 m ahead along the heading.
    d = np.asarray(tr.center) - np.asarray(tr.reference)
    np.testing.assert_allclose(np.hypot(d[:, 0], d[:, 1]), 1.393, atol=1e-9)
    np.testing.assert_allclose(np.asarray(tr.rear_axle), np.asarray(tr.reference), atol=1e-12)
    assert doc.hero_start.position[:2] == pytest.approx(tr.center[0][:2])
    assert doc.hero_start.position[2] == 0.0
    # Checks: the car on the path and the less confident of the overlapping pair are left out.
    assert {r.id for r in doc.rejected} == {"pv_001", "pv_003"}
    assert [v.id for v in doc.parked] == ["pv_000", "pv_002", "pv_004"]
    assert doc.parked[-1].size_class == "van"
    assert doc.camera is not None
    # CARLA files: the centre trajectory round-trips to the scenario's centre points.
    entries = json.loads((folder / "carla" / "trajectory_center.json").read_text())
    back, heading = trajectory_from_carla(entries)
    np.testing.assert_allclose(back, np.asarray(tr.center), atol=1e-5)
    np.testing.assert_allclose(heading, tr.heading, atol=1e-6)
    data = json.loads((folder / "carla" / "vehicle_data.json").read_text())
    assert [s["cluster_id"] for s in data["spawn_positions"]] == ["pv_000", "pv_002", "pv_004"]
    assert data["spawn_positions"][0]["start"][1] == pytest.approx(-doc.parked[0].position[1])
    assert validate_openscenario(folder / "scenario.xosc") == []
    assert (folder / "scenario.png").stat().st_size > 10_000


def test_scenario_is_skipped_when_up_to_date_and_rebuilt_on_change(street: Workspace) -> None:
    run_scenario(street, force=True)
    assert run_scenario(street).scenario is None
    kept = run_scenario(street, options=ScenarioOptions(keep_conflicts=True))
    assert kept.scenario is not None
    assert len(kept.scenario.parked) == 5
    assert len(kept.scenario.rejected) == 2  # still reported


def test_heading_from_motion_matches_a_straight_drive(street: Workspace) -> None:
    res = run_scenario(street, options=ScenarioOptions(heading="motion"), force=True)
    assert res.scenario is not None
    h = np.asarray(res.scenario.trajectory.heading)
    assert np.ptp(h) < 1e-3
    assert res.scenario.trajectory.heading_source == "motion"


def test_scenario_needs_a_map(tmp_path: Path, street: Workspace) -> None:
    ws = Workspace.create(tmp_path / "ws", Config(recording=RecordingConfig(bags=[str(tmp_path)])))
    with pytest.raises(StageError, match="cam2sim extract"):
        run_scenario(ws)
    xodr = street.map_dir / "map.xodr"
    text = xodr.read_text()
    xodr.unlink()
    try:
        with pytest.raises(StageError, match="cam2sim map"):
            run_scenario(street, force=True)
    finally:
        xodr.write_text(text)


def test_cli_scenario(street: Workspace) -> None:
    out = CliRunner().invoke(app, ["scenario", str(street.root), "--force"])
    assert out.exit_code == 0, out.output
    text = " ".join(out.output.split())  # rich wraps long lines at the terminal width
    assert "3 parked vehicles, 2 left out" in text
    assert "left out pv_001: stands on the recorded path" in text


@pytest.mark.parametrize(
    ("size", "cls"),
    [((3.8, 1.7, 1.45), "small"), ((4.4, 1.8, 1.5), "medium"), ((4.9, 1.9, 1.5), "large"),
     ((5.0, 2.0, 2.1), "van"), ((5.6, 2.0, 1.8), "van")],
)  # fmt: skip
def test_size_class(size: tuple[float, float, float], cls: str) -> None:
    assert size_class(size) == cls
