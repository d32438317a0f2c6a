from __future__ import annotations

import json
from pathlib import Path

import pytest

from cam2sim.core.errors import WorkspaceError
from cam2sim.core.schema import MAX_LISTED, Artifact


class _Frame(Artifact):
    index: int


class _Scene(Artifact):
    frames: list[_Frame]


def _write(path: Path, frames: list[dict[str, object]]) -> Path:
    path.write_text(json.dumps({"frames": frames}), encoding="utf-8")
    return path


def test_the_same_problem_in_every_list_item_is_named_once_with_its_count(tmp_path: Path) -> None:
    # A scene.json written by another cam2sim version: one unknown field in each of 365
    # frames, and one frame with a bad index.
    frames: list[dict[str, object]] = [{"index": i, "from_recorded": True} for i in range(365)]
    frames.append({"index": "first"})
    with pytest.raises(WorkspaceError) as caught:
        _Scene.load(_write(tmp_path / "scene.json", frames))
    msg = str(caught.value)
    assert msg.count("Extra inputs are not permitted") == 1
    assert "frames.0.from_recorded: Extra inputs are not permitted (and 364 more like it, " in msg
    assert "the last at frames.364.from_recorded" in msg
    assert "frames.365.index: Input should be a valid integer" in msg
    assert msg.endswith("delete it and re-run the stage that writes it")
    assert len(msg) < 500


def test_past_the_listed_kinds_the_rest_are_counted(tmp_path: Path) -> None:
    frames: list[dict[str, object]] = [{"index": 0, f"field_{k}": 1} for k in range(MAX_LISTED + 3)]
    with pytest.raises(WorkspaceError, match=r"frames\.0\.field_0: .*; 3 more kinds of problem\."):
        _Scene.load(_write(tmp_path / "scene.json", frames))
