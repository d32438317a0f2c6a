"""The workspace contract: every path a stage writes is named once, in core/workspace.py."""

from __future__ import annotations

import re
from pathlib import Path

SRC = Path(__file__).resolve().parents[2] / "src" / "cam2sim"
# A workspace folder joined with a literal name: ws.splat_dir / "eval.json", ws.root / "real".
LITERAL_JOIN = re.compile(r"\bws\.(?:\w+_dir|root) / [\"']")


def test_no_literal_workspace_join_outside_the_contract() -> None:
    found = []
    for path in sorted(SRC.rglob("*.py")):
        if path.parent.name == "core":
            continue
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
            if LITERAL_JOIN.search(line):
                found.append(f"{path.relative_to(SRC)}:{number}: {line.strip()}")
    assert found == [], "name these paths in core/workspace.py:\n" + "\n".join(found)


def test_the_contract_names_each_stages_files(tmp_path: Path) -> None:
    from cam2sim.core.config import Config
    from cam2sim.core.workspace import Workspace

    ws = Workspace.create(tmp_path / "ws", Config())
    assert ws.map_xodr_path == ws.map_files.xodr == ws.root / "map" / "map.xodr"
    assert ws.splat_files.eval_json == ws.root / "splat" / "eval.json"
    assert ws.splat_files.prep_images_dir == ws.root / "splat" / "prep" / "images"
    assert ws.ads_files.onnx == ws.root / "ads" / "dave2.onnx"
    assert ws.report_files.metrics_json == ws.drive_eval_dir / "metrics.json"
    assert ws.truth_world_json == ws.root / "truth" / "world.json"
