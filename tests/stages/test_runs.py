"""Replay and closed-loop drives: run folders, events where they happen, the real drive replayed."""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING

import numpy as np
import pytest
from typer.testing import CliRunner

from cam2sim.cli.main import app
from cam2sim.core.config import Config, RecordingConfig
from cam2sim.core.errors import ConfigError, StageError
from cam2sim.core.table import read_table
from cam2sim.core.workspace import Workspace
from cam2sim.metrics.drive_io import load_run_dir
from cam2sim.scenario.model import Scenario
from cam2sim.scenario.synthetic import StreetSpec
from cam2sim.stages.runs import DriveOptions, ReplayOptions, drive, replay
from conftest import street_workspace

if TYPE_CHECKING:
    from pathlib import Path


def _workspace(root: Path, spec: StreetSpec) -> tuple[Workspace, Scenario]:
    ws = street_workspace(root, spec)
    return ws, Scenario.load(ws.scenario_dir / "scenario.json")


def _egl() -> bool:
    try:
        import moderngl

        moderngl.create_context(standalone=True, backend="egl").release()
    except Exception:  # noqa: BLE001 - any failure means no headless GL here
        return False
    return True


@pytest.mark.parametrize("radius", [None, 60.0], ids=["straight", "curved"])
def test_pure_pursuit_completes_the_route_without_other_events(
    tmp_path: Path, radius: float | None
) -> None:
    ws, scenario = _workspace(tmp_path / "ws", StreetSpec(radius_m=radius))
    (run,) = drive(ws, options=DriveOptions(policy="pure-pursuit", camera="none"))
    assert [e["kind"] for e in run.events] == ["route_completed"]
    assert run.folder.parent == ws.runs_dir
    traj = read_table(run.folder / "trajectory.csv")
    ref = np.asarray(scenario.trajectory.reference)
    # The reference point stays near the recorded route all the way.
    d = np.min(
        np.hypot(traj["x"][:, None] - ref[None, :, 0], traj["y"][:, None] - ref[None, :, 1]), 1
    )
    assert d.max() < 0.5
    meta = json.loads((run.folder / "run.json").read_text())
    assert meta["policy"] == "pure-pursuit"
    assert meta["kind"] == "drive"
    steering = read_table(run.folder / "steering.csv")
    assert steering["t"].shape[0] == math.ceil(run.steps / 3)
    # The evaluation reader loads the run folder.
    loaded = load_run_dir(run.folder)
    assert loaded.xy.shape[0] == run.steps
    assert loaded.events[0].kind == "route_completed"


def test_hard_right_leaves_the_road_on_the_right(tmp_path: Path) -> None:
    ws, _ = _workspace(tmp_path / "ws", StreetSpec(parked=()))
    (run,) = drive(ws, options=DriveOptions(policy="constant:-25", camera="none"))
    kinds = [e["kind"] for e in run.events]
    assert kinds[0] == "off_road"
    ev = run.events[0]
    # The road's right edge (kerb of the right parking lane + sidewalk) is 1.75 + 2.5 + 2 m right
    # of the route; the car's corner crosses it, so the centre is within a car width of it.
    assert -9.0 < ev["y"] < -3.0
    assert ev["x"] < 30.0


def test_driving_into_a_parked_car_is_a_collision(tmp_path: Path) -> None:
    ws, scenario = _workspace(tmp_path / "ws", StreetSpec(parked=((30.0, 0.0, 0.0),)))
    (run,) = drive(ws, options=DriveOptions(policy="constant:0", camera="none"))
    assert run.events[0]["kind"] == "collision"
    car = scenario.parked[0].position
    assert abs(run.events[0]["x"] - car[0]) < 6.0
    assert "pv_000" in run.events[0]["reason"]


def test_runs_never_overwrite_each_other(tmp_path: Path) -> None:
    ws, _ = _workspace(tmp_path / "ws", StreetSpec(length_m=20.0))
    runs = drive(ws, options=DriveOptions(camera="none", runs=2))
    runs += drive(ws, options=DriveOptions(camera="none", runs=1))
    folders = {r.folder for r in runs}
    assert len(folders) == 3
    assert all(f.is_dir() for f in folders)
    assert not [p for p in ws.runs_dir.iterdir() if p.name.startswith(".tmp")]
    seeds = [json.loads((f / "run.json").read_text())["seed"] for f in sorted(folders)]
    assert sorted(seeds) == [0, 0, 1]


@pytest.mark.skipif(not _egl(), reason="no headless OpenGL (EGL) here")
def test_drive_with_the_raster_camera_writes_frames_and_video(tmp_path: Path) -> None:
    ws, _ = _workspace(tmp_path / "ws", StreetSpec(length_m=15.0))
    (run,) = drive(
        ws,
        options=DriveOptions(camera="raster", image_size=(200, 66), save_frames=True, video=True),
    )
    frames = sorted((run.folder / "frames" / "raster").glob("*.png"))
    assert len(frames) == math.ceil(run.steps / 3)
    assert (run.folder / "video.mp4").stat().st_size > 1000
    meta = json.loads((run.folder / "run.json").read_text())
    assert meta["camera"] == "raster"
    assert meta["render_ms"] > 0


@pytest.mark.skipif(not _egl(), reason="no headless OpenGL (EGL) here")
def test_replay_renders_each_frame_and_keeps_the_recorded_poses(tmp_path: Path) -> None:
    ws, scenario = _workspace(tmp_path / "ws", StreetSpec(length_m=16.0))
    run = replay(ws, options=ReplayOptions(cameras=("raster",), image_size=(160, 100)))
    n = len(scenario.trajectory.frame)
    assert run.steps == n
    assert len(list((run.folder / "frames" / "raster").glob("*.png"))) == n
    assert len(list((run.folder / "side_by_side").glob("*.png"))) == n
    traj = read_table(run.folder / "trajectory.csv")
    np.testing.assert_allclose(
        traj["x"], np.asarray(scenario.trajectory.reference)[:, 0], atol=1e-6
    )
    part = replay(ws, options=ReplayOptions(cameras=("raster",), frames=(2, 5), video=False))
    assert part.steps == 3
    with pytest.raises(StageError, match="selects no sample"):
        replay(ws, options=ReplayOptions(frames=(50, 60)))


def test_replay_of_the_real_reference_drive_reproduces_its_poses(
    tmp_path: Path, shared_data: Path
) -> None:
    from cam2sim.core.frames import WorldFrame
    from cam2sim.scenario.model import ScenarioTrajectory

    csv = shared_data / "reference-drives" / "trajectory1.csv"
    if not csv.is_file():
        pytest.skip(f"{csv} is absent")
    data = np.genfromtxt(csv, delimiter=",", names=True)
    utm = np.column_stack([data["x"], data["y"], np.zeros(len(data))])
    world = WorldFrame.at_crs_point("EPSG:32632", utm[0, 0], utm[0, 1])
    xyz = world.from_crs("EPSG:32632", utm)
    heading = world.heading_from_crs("EPSG:32632", utm[:, :2], data["yaw"] - math.pi / 2)
    ws, scenario = _workspace(tmp_path / "ws", StreetSpec())
    t = data["timestamp"] - data["timestamp"][0]
    rows = tuple(tuple(map(float, p)) for p in xyz)
    traj = ScenarioTrajectory(
        heading_source="orientation",
        frame=tuple(range(len(t))),
        stamp_ns=tuple(int(v * 1e9) for v in t),
        t=tuple(float(v) for v in t),
        heading=tuple(float(h) for h in heading),
        speed=(0.0,) * len(t),
        reference=rows,
        center=rows,
        rear_axle=rows,
    )
    scenario.model_copy(update={"trajectory": traj}).save(ws.scenario_dir / "scenario.json")
    run = replay(ws, options=ReplayOptions(cameras=("none",)))
    out = read_table(run.folder / "trajectory.csv")
    back = world.to_crs("EPSG:32632", np.column_stack([out["x"], out["y"], out["z"]]))
    assert np.abs(back[:, :2] - utm[:, :2]).max() < 1e-3  # every recorded pose within 1 mm
    np.testing.assert_allclose(out["heading"], heading, atol=1e-6)


def test_drive_needs_a_scenario_and_a_known_policy(tmp_path: Path) -> None:
    ws = Workspace.create(tmp_path / "ws", Config(recording=RecordingConfig(bags=[str(tmp_path)])))
    with pytest.raises(StageError, match="cam2sim scenario"):
        drive(ws)
    ws2, _ = _workspace(tmp_path / "ws2", StreetSpec(length_m=10.0))
    args = ["drive", str(ws2.root), "--camera", "none"]
    out = CliRunner().invoke(app, [*args, "--policy", "nonsense"])
    assert out.exit_code == 1
    out = CliRunner().invoke(app, args)
    assert out.exit_code == 0, out.output
    assert "route_completed" in out.output


def test_a_failing_policy_ends_the_run_with_an_event(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A remote policy that times out mid-run becomes a policy_error event; the run is kept."""
    from cam2sim.ads import policy as policy_module

    class Flaky:
        name = "flaky"
        needs_image = False

        def __init__(self) -> None:
            self.calls = 0

        def reset(self) -> None:
            self.calls = 0

        def predict(self, obs: object) -> float:
            del obs
            self.calls += 1
            if self.calls > 5:
                msg = "tcp://127.0.0.1:5090 sent no reply within 10 s; is it hung?"
                raise StageError(msg)
            return 0.0

        def close(self) -> None:
            pass

    monkeypatch.setattr(policy_module, "load_policy", lambda *a, **k: Flaky())
    ws, _ = _workspace(tmp_path / "ws", StreetSpec())
    (run,) = drive(ws, options=DriveOptions(policy="tcp://127.0.0.1:5090", camera="none"))
    assert run.events[-1]["kind"] == "policy_error"
    assert "no reply" in run.events[-1]["reason"]
    assert run.steps == 15  # five answers, every 3rd step; the sixth call fails at step 16
    assert read_table(run.folder / "trajectory.csv")["t"].shape[0] == 15
    assert json.loads((run.folder / "events.json").read_text())["events"][-1]["kind"] == (
        "policy_error"
    )


def _carla_fakes() -> object:
    """The CARLA stand-in of tests/sim (loaded by path: test folders are not packages)."""
    import importlib.util
    import sys
    from pathlib import Path

    path = Path(__file__).parents[1] / "sim" / "carla_fakes.py"
    spec = importlib.util.spec_from_file_location("carla_fakes", path)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("carla_fakes", module)
    spec.loader.exec_module(module)
    return module


CARS = ("vehicle.citroen.c3", "vehicle.seat.leon", "vehicle.toyota.prius", "vehicle.tesla.model3")


def test_drive_and_replay_in_carla_write_the_same_run_folders(tmp_path: Path) -> None:
    pytest.importorskip("carla")
    from cam2sim.sim.carla_backend import CarlaOptions

    fakes = _carla_fakes()
    ws, scenario = _workspace(tmp_path / "ws", StreetSpec(length_m=20.0))
    clients: list[object] = []

    def factory(*_: object) -> object:
        client = fakes.FakeClient(available=CARS)  # type: ignore[attr-defined]
        clients.append(client)
        return client

    carla_opts = CarlaOptions.model_validate({"image_size": (8, 5)})
    (run,) = drive(
        ws,
        options=DriveOptions(
            simulator="carla",
            camera="carla",
            carla=carla_opts,
            carla_client_factory=factory,
            max_steps=30,
            save_frames=True,
        ),
    )
    meta = json.loads((run.folder / "run.json").read_text())
    assert meta["sim"] == "carla"
    assert meta["camera"] == "carla"
    traj = read_table(run.folder / "trajectory.csv")
    assert traj["t"].shape[0] == run.steps == 30
    assert np.all(np.diff(traj["x"]) > 0)  # the fake server moves the hero forward
    assert len(list((run.folder / "frames" / "carla").glob("*.png"))) == 10
    world = clients[0].world  # type: ignore[attr-defined]
    assert {id(a) for a in world.destroyed} == {id(a) for a in world.actors}  # torn down
    rep = replay(
        ws,
        options=ReplayOptions(
            cameras=("carla",),
            simulator="carla",
            carla=carla_opts,
            carla_client_factory=factory,
            frames=(0, 4),
            video=False,
        ),
    )
    assert len(list((rep.folder / "frames" / "carla").glob("*.png"))) == 4
    with pytest.raises(ConfigError, match="needs --sim carla"):
        DriveOptions(camera="carla")
    assert scenario.parked


def test_a_drive_at_the_recorded_speed_slows_where_the_driver_slowed(tmp_path: Path) -> None:
    ws, scenario = _workspace(tmp_path / "ws", StreetSpec(radius_m=None, parked=()))
    tr = scenario.trajectory
    start = tr.speed[0]
    progress = np.asarray(tr.t) / tr.t[-1]
    slow = tuple(float(v) for v in np.where((progress > 0.4) & (progress < 0.7), 2.0, start))
    scenario.model_copy(update={"trajectory": tr.model_copy(update={"speed": slow})}).save(
        ws.scenario_dir / "scenario.json"
    )
    (held,) = drive(ws, options=DriveOptions(camera="none"))
    (recorded,) = drive(ws, options=DriveOptions(camera="none", recorded_speed=True))
    assert [e["kind"] for e in recorded.events] == ["route_completed"]
    fast = read_table(held.folder / "trajectory.csv")["speed"]
    speeds = read_table(recorded.folder / "trajectory.csv")["speed"]
    assert fast.min() > 0.9 * start  # held: the start speed all the way
    assert speeds.min() < 2.5  # slowed to the recorded 2 m/s ...
    assert speeds[: len(speeds) // 5].min() > 0.9 * start  # ... not before the slow part
    assert recorded.steps > held.steps  # the slow part takes longer
    meta = json.loads((recorded.folder / "run.json").read_text())
    assert meta["options"]["recorded_speed"] is True
    with pytest.raises(ConfigError, match="--speed recorded, not both"):
        DriveOptions(speed_kmh=20.0, recorded_speed=True)
    result = CliRunner().invoke(app, ["drive", str(ws.root), "--speed", "fast"])
    assert result.exit_code == 2
    assert "give km/h (a number >= 0) or 'recorded'" in result.output
