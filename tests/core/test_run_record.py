"""run.json and events.json: typed, schema-versioned records of a run folder."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import pytest

from cam2sim.core.errors import SchemaVersionError, WorkspaceError
from cam2sim.core.run_record import EventRecord, RunEvents, RunRecord

if TYPE_CHECKING:
    from pathlib import Path


def test_run_record_round_trips_and_leaves_out_what_was_not_recorded(tmp_path: Path) -> None:
    record = RunRecord(
        kind="drive", method="drive-raster", camera="raster", seed=3, seconds=1.5,
        options={"runs": 1, "start_offset": [0.0, 0.0]}, proj_string="EPSG:32632",
    )  # fmt: skip
    path = tmp_path / "run.json"
    record.save(path)
    assert RunRecord.load(path) == record
    raw = json.loads(path.read_text(encoding="utf-8"))
    assert raw["schema_version"] == 1
    assert "variation" not in raw
    assert "splat_quality" not in raw


def test_events_round_trip_and_the_earliest_bare_list_loads(tmp_path: Path) -> None:
    events = RunEvents(events=(EventRecord(kind="off_road", t=2.5, x=1.0, y=2.0, reason="kerb"),))
    path = tmp_path / "events.json"
    events.save(path)
    assert RunEvents.load(path) == events
    path.write_text('[{"kind": "route_completed", "t": 9.0}]', encoding="utf-8")
    assert RunEvents.load(path).events == (EventRecord(kind="route_completed", t=9.0),)


def test_records_without_schema_version_load_as_version_1(tmp_path: Path) -> None:
    path = tmp_path / "run.json"
    path.write_text('{"kind": "replay", "method": "replay-raster", "frames": [0, 5]}')
    record = RunRecord.load(path)
    assert record.schema_version == 1
    assert record.frames == (0, 5)
    assert record.label == "replay-raster"


def test_a_newer_run_record_names_both_versions(tmp_path: Path) -> None:
    path = tmp_path / "run.json"
    path.write_text('{"schema_version": 9, "method": "drive-raster"}')
    with pytest.raises(SchemaVersionError, match=r"run\.json has schema_version 9.*version 1"):
        RunRecord.load(path)


def test_a_malformed_record_names_the_file_the_field_and_the_fix(tmp_path: Path) -> None:
    path = tmp_path / "run.json"
    path.write_text('{"method": "drive-raster", "seed": "three"}')
    with pytest.raises(WorkspaceError, match=r"run\.json: seed"):
        RunRecord.load(path)
    path.write_text('{"method": ')
    with pytest.raises(WorkspaceError, match=r"run\.json is not valid JSON.*drive again"):
        RunRecord.load(path)
    events = tmp_path / "events.json"
    events.write_text('{"events": [{"t": 1.0}]}')
    with pytest.raises(WorkspaceError, match=r"events\.json: events\.0\.kind"):
        RunEvents.load(events)
