from __future__ import annotations

import datetime as dt
import json
from pathlib import Path

import pytest

from cam2sim.core.config import Config
from cam2sim.core.errors import SchemaVersionError, WorkspaceError
from cam2sim.core.workspace import Manifest, Workspace, WorldFrameRecord, hash_inputs


def test_create_writes_config_and_manifest(tmp_path: Path) -> None:
    ws = Workspace.create(tmp_path / "ws", Config())
    assert ws.config_path.is_file()
    manifest = ws.read_manifest()
    assert manifest.schema_version == 1
    assert manifest.stages == {}
    assert ws.load_config() == Config()


def test_create_refuses_an_existing_workspace_without_force(tmp_path: Path) -> None:
    Workspace.create(tmp_path / "ws", Config())
    with pytest.raises(WorkspaceError, match="already holds a cam2sim workspace"):
        Workspace.create(tmp_path / "ws", Config())
    Workspace.create(tmp_path / "ws", Config(), force=True)


def test_open_rejects_a_folder_that_is_not_a_workspace(tmp_path: Path) -> None:
    with pytest.raises(WorkspaceError, match="not a cam2sim workspace.*cam2sim init"):
        Workspace.open(tmp_path)


def test_stage_records_track_inputs_and_state(tmp_path: Path) -> None:
    ws = Workspace.create(tmp_path / "ws", Config())
    started = dt.datetime.now(dt.UTC)
    ws.record_stage("extract", state="done", started=started, inputs_hash="sha256:a")
    assert ws.is_up_to_date("extract", "sha256:a")
    assert not ws.is_up_to_date("extract", "sha256:b")
    ws.record_stage("extract", state="failed", started=started, message="boom")
    assert not ws.is_up_to_date("extract", "sha256:a")
    record = ws.stage_record("extract")
    assert record is not None
    assert record.message == "boom"


def test_world_frame_is_stored_in_the_manifest(tmp_path: Path) -> None:
    ws = Workspace.create(tmp_path / "ws", Config())
    world = WorldFrameRecord(
        proj_string="+proj=tmerc +lat_0=48 +lon_0=11", origin_lat_deg=48.0, origin_lon_deg=11.0
    )
    ws.record_stage("extract", state="done", started=dt.datetime.now(dt.UTC), world=world)
    assert Workspace.open(ws.root).world_frame() == world
    assert world.georeferenced


def test_manifest_round_trips(tmp_path: Path) -> None:
    m = Manifest(config={"a": 1})
    m.save(tmp_path / "m.json")
    assert Manifest.load(tmp_path / "m.json") == m


def test_manifest_from_a_newer_version_is_rejected(tmp_path: Path) -> None:
    ws = Workspace.create(tmp_path / "ws", Config())
    raw = json.loads(ws.manifest_path.read_text())
    raw["schema_version"] = 7
    ws.manifest_path.write_text(json.dumps(raw))
    with pytest.raises(SchemaVersionError, match="schema_version 7.*up to version 1"):
        ws.read_manifest()


def test_malformed_manifest_names_the_file_and_element(tmp_path: Path) -> None:
    ws = Workspace.create(tmp_path / "ws", Config())
    raw = json.loads(ws.manifest_path.read_text())
    raw["stages"] = {"extract": {"state": "maybe"}}
    ws.manifest_path.write_text(json.dumps(raw))
    with pytest.raises(WorkspaceError, match=r"workspace\.json: stages\.extract\.state"):
        ws.read_manifest()


def test_relative_config_paths_resolve_inside_the_workspace(tmp_path: Path) -> None:
    ws = Workspace.create(tmp_path / "ws", Config())
    assert ws.resolve("drive.bag") == ws.root / "drive.bag"
    assert ws.resolve("/abs/drive.bag") == Path("/abs/drive.bag")


def test_hash_inputs_is_stable_and_order_independent_for_dicts() -> None:
    assert hash_inputs({"a": 1, "b": [1, 2]}) == hash_inputs({"b": [1, 2], "a": 1})
    assert hash_inputs({"a": 1}) != hash_inputs({"a": 2})


def test_step_outcomes_and_made_runs_are_kept_in_the_manifest(tmp_path: Path) -> None:
    ws = Workspace.create(tmp_path / "ws", Config())
    started = dt.datetime.now(dt.UTC)
    ws.record_stage("drive", state="done", started=started, inputs_hash="sha256:d", runs=("a",))
    ws.record_step("drive", state="up_to_date", seconds=1.23456, message="1 run(s)")
    manifest = Workspace.open(ws.root).read_manifest()
    assert manifest.stages["drive"].runs == ("a",)
    assert manifest.steps["drive"].state == "up_to_date"
    assert manifest.steps["drive"].seconds == 1.235


def test_an_older_pipeline_json_is_merged_into_the_manifest_once(tmp_path: Path) -> None:
    from cam2sim.core.workspace import LEGACY_PIPELINE_FILE

    ws = Workspace.create(tmp_path / "ws", Config())
    ws.runs_dir.mkdir()
    legacy = ws.runs_dir / LEGACY_PIPELINE_FILE
    step = {"state": "done", "seconds": 2.0, "finished": "2026-01-02T03:04:05"}
    state = {
        "replay": {"inputs": "sha256:r", "runs": ["r1"]},
        "drive": {"inputs": "sha256:d", "runs": ["d1", "d2"]},
        "steps": {"drive": step},
    }
    legacy.write_text(json.dumps(state))
    manifest = ws.read_manifest()
    assert not legacy.exists()
    assert manifest.stages["drive"].runs == ("d1", "d2")
    assert ws.is_up_to_date("replay", "sha256:r")
    assert manifest.steps["drive"].finished == dt.datetime(2026, 1, 2, 3, 4, 5, tzinfo=dt.UTC)
    assert ws.read_manifest() == manifest  # written once, read back the same


def test_a_broken_older_pipeline_json_is_dropped(tmp_path: Path) -> None:
    from cam2sim.core.workspace import LEGACY_PIPELINE_FILE

    ws = Workspace.create(tmp_path / "ws", Config())
    ws.runs_dir.mkdir()
    (ws.runs_dir / LEGACY_PIPELINE_FILE).write_text("{")
    assert ws.read_manifest().stages == {}
    assert not (ws.runs_dir / LEGACY_PIPELINE_FILE).exists()


def test_records_from_many_threads_at_once_are_all_kept(tmp_path: Path) -> None:
    """The manifest's lock: no read-change-write drops another writer's record."""
    import datetime as dt
    import threading

    ws = Workspace.create(tmp_path / "ws", Config())
    now = dt.datetime.now(dt.UTC)

    def write(k: int) -> None:
        for i in range(5):
            ws.record_stage(f"stage{k}-{i}", state="done", started=now, inputs_hash=f"h{k}")
            ws.record_step(f"step{k}-{i}", state="done", seconds=1.0, message="")

    threads = [threading.Thread(target=write, args=(k,)) for k in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    manifest = ws.read_manifest()
    assert len(manifest.stages) == 30
    assert len(manifest.steps) == 30
