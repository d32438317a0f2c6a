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
