"""The bad-input matrix (docs/errors.md): what users get wrong, each through the CLI.

Each case: exit code 1, one line naming the file or key and the fix, no traceback, and every
file that was there before is byte-for-byte unchanged. Cases covered elsewhere are listed in
docs/errors.md with their test.
"""

from __future__ import annotations

import hashlib
import json
import socket
from dataclasses import dataclass
from typing import TYPE_CHECKING

import pytest
from typer.testing import CliRunner

from cam2sim.cli.main import app
from cam2sim.scenario.synthetic import StreetSpec
from conftest import street_workspace

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path


@dataclass(frozen=True)
class Case:
    """One bad input: how to break a fresh workspace, the command, what the message says."""

    name: str
    breaks: Callable[[Path], None]
    command: Callable[[Path], list[str]]
    says: tuple[str, ...]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _truncate(rel: str) -> Callable[[Path], None]:
    def run(root: Path) -> None:
        path = root / "ws" / rel
        path.write_bytes(path.read_bytes()[: len(path.read_bytes()) // 2])

    return run


def _schema_99(root: Path) -> None:
    path = root / "ws" / "workspace.json"
    doc = json.loads(path.read_text(encoding="utf-8"))
    doc["schema_version"] = 99
    path.write_text(json.dumps(doc), encoding="utf-8")


def _config_line(old: str, new: str) -> Callable[[Path], None]:
    def run(root: Path) -> None:
        path = root / "ws" / "config.yaml"
        text = path.read_text(encoding="utf-8")
        assert old in text
        path.write_text(text.replace(old, new, 1), encoding="utf-8")

    return run


def _write(rel: str, data: bytes) -> Callable[[Path], None]:
    def run(root: Path) -> None:
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(data)

    return run


def _nothing(_: Path) -> None:
    return None


def _ws(root: Path) -> str:
    return str(root / "ws")


_FOOTWAY_OSM = (
    b"<?xml version='1.0' encoding='UTF-8'?><osm version='0.6'>"
    b"<node id='1' lat='48.0' lon='11.0' version='1'/><node id='2' lat='48.0' lon='11.001' "
    b"version='1'/><way id='9' version='1'><nd ref='1'/><nd ref='2'/>"
    b"<tag k='highway' v='footway'/></way></osm>"
)


def _images_folder(root: Path) -> None:
    (root / "frames").mkdir()
    for k in range(3):
        (root / "frames" / f"{k:06d}.png").write_bytes(b"not really")


def _comma_segment(root: Path) -> None:
    """A comma2k19 segment as comma ships it: video.hevc, global_pose/, processed_log/."""
    (root / "segment" / "global_pose").mkdir(parents=True)
    (root / "segment" / "video.hevc").write_bytes(b"not really")


def _demo_out(root: Path) -> None:
    """A folder laid out as `cam2sim demo -o root/out` leaves it: the workspace in out/ws."""
    (root / "out").mkdir()
    (root / "ws").rename(root / "out" / "ws")


CASES = [
    Case(
        "a folder of images where a bag is expected",
        _images_folder,
        lambda root: ["inspect", str(root / "frames")],
        ("no bag here", "holds 3 images", "cam2sim import WS --images"),
    ),
    Case(
        "a comma2k19 segment where a bag is expected",
        _comma_segment,
        lambda root: ["run", "-o", str(root / "cw"), str(root / "segment")],
        ("it is a comma2k19 segment", "--fps 20 --poses", "global_pose"),
    ),
    Case(
        "a demo's -o folder where its workspace is expected",
        _demo_out,
        lambda root: ["report", str(root / "out")],
        ("is not a workspace but holds one", "out/ws"),
    ),
    Case(
        "an unknown densification for the splat stage",
        _nothing,
        lambda root: ["splat", _ws(root), "--densify", "mcmcc"],
        ("--densify 'mcmcc' is not one of", "auto, mcmc, gsplat, simple"),
    ),
    Case(
        "a robust quantile of 1 or more",
        _nothing,
        lambda root: ["splat", _ws(root), "--robust-quantile", "1.5"],
        ("robust loss needs 0 <= quantile < 1",),
    ),
    Case(
        "a demo route without an OSM file",
        _nothing,
        lambda root: ["demo", "-o", str(root / "d"), "--route", "48.1,11.5", "48.2,11.5"],
        ("--route needs --osm",),
    ),
    Case(
        "a demo with both a built-in world and an OSM file",
        _write("x.osm", _FOOTWAY_OSM),
        lambda root: [
            "demo",
            "-o",
            str(root / "d"),
            "--world",
            "paper",
            "--osm",
            str(root / "x.osm"),
        ],
        ("give --world or --osm, not both",),
    ),
    Case(
        "a demo from an OSM file without drivable roads",
        _write("x.osm", _FOOTWAY_OSM),
        lambda root: ["demo", "-o", str(root / "d"), "--osm", str(root / "x.osm")],
        ("no drivable road", "footway (1)", "Export an area with residential streets"),
    ),
    Case(
        "drives judged in a ground truth the workspace does not have",
        _nothing,
        lambda root: ["drive", _ws(root), "--camera", "none", "--judge", "truth"],
        ("has no ground-truth world", "--judge map"),
    ),
    Case(
        "an empty folder as workspace",
        lambda root: (root / "empty").mkdir(),
        lambda root: ["drive", str(root / "empty")],
        ("not a cam2sim workspace", "cam2sim init"),
    ),
    Case(
        "a truncated workspace.json",
        _truncate("workspace.json"),
        lambda root: ["drive", _ws(root)],
        ("workspace.json is not valid JSON", "cam2sim init"),
    ),
    Case(
        "a workspace from a newer schema",
        _schema_99,
        lambda root: ["drive", _ws(root)],
        ("schema_version 99", "upgrade cam2sim"),
    ),
    Case(
        "a truncated scenario.json",
        _truncate("scenario/scenario.json"),
        lambda root: ["drive", _ws(root), "--camera", "none"],
        ("scenario.json is not valid JSON", "re-run the stage"),
    ),
    Case(
        "a wrong type in config.yaml",
        _config_line("  every: 1", "  every: many"),
        lambda root: ["extract", _ws(root)],
        ("config.yaml", "frames.every", "valid integer"),
    ),
    Case(
        "an unknown key in config.yaml",
        _config_line("sync:", "synk:"),
        lambda root: ["extract", _ws(root)],
        ("config.yaml", "synk", "did you mean 'sync'"),
    ),
    Case(
        "an image that is not an image",
        _write("frames/000001.jpg", b"not a jpeg"),
        lambda root: ["import", str(root / "imported"), "--images", str(root / "frames")],
        ("000001.jpg", "cannot be read as an image", "remove or replace it"),
    ),
    Case(
        "a policy file that is not a model",
        _write("policy.onnx", b"not a model"),
        lambda root: ["drive", _ws(root), "--policy", str(root / "policy.onnx")],
        ("policy.onnx",),
    ),
    Case(
        "a TorchScript policy that is not a model",
        _write("policy.pt", b"not a model"),
        lambda root: ["drive", _ws(root), "--policy", str(root / "policy.pt")],
        ("policy.pt", "torch.jit.save"),
    ),
    Case(
        "a tcp:// policy nobody listens on",
        _nothing,
        lambda root: [
            *("drive", _ws(root), "--camera", "none"),
            *("--policy", f"tcp://127.0.0.1:{_free_port()}"),
        ],
        ("cannot reach the remote policy", "cam2sim ads serve"),
    ),
    Case(
        "a campaign plan with a wrong key",
        _write("plan.yaml", b"workspaces: [ws]\npolicys: [pure-pursuit]\n"),
        lambda root: ["campaign", str(root / "plan.yaml")],
        ("plan.yaml", "policys"),
    ),
]


def _digests(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in root.rglob("*")
        if p.is_file()
    }


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_bad_input_is_one_line_with_the_fix_and_damages_nothing(case: Case, tmp_path: Path) -> None:
    street_workspace(tmp_path / "ws", StreetSpec(length_m=30.0, radius_m=60.0))
    case.breaks(tmp_path)
    before = _digests(tmp_path)
    result = CliRunner().invoke(app, case.command(tmp_path))
    text = " ".join(result.output.split())  # rich wraps long lines
    assert result.exit_code == 1, text
    assert result.exception is None or isinstance(result.exception, SystemExit)
    assert "Traceback" not in result.output
    assert text.startswith("error:") or "error:" in text
    flat = "".join(text.split())  # rich may break a long path anywhere
    for part in case.says:
        assert "".join(part.split()) in flat, f"{part!r} not in {text!r}"
    after = _digests(tmp_path)
    changed = [name for name, digest in before.items() if after.get(name) != digest]
    assert not changed, f"{case.name} changed {changed}"


def test_a_carla_host_that_does_not_answer(tmp_path: Path) -> None:
    pytest.importorskip("carla")
    street_workspace(tmp_path / "ws", StreetSpec(length_m=30.0, radius_m=60.0))
    port = _free_port()
    args = ["drive", _ws(tmp_path), "--camera", "none", "--sim", "carla"]
    result = CliRunner().invoke(
        app, [*args, "--carla-host", "127.0.0.1", "--carla-port", str(port)]
    )
    text = " ".join(result.output.split())
    assert result.exit_code == 1, text
    assert "Traceback" not in result.output
    assert f"127.0.0.1:{port}" in "".join(text.split())
    assert "CarlaUE4" in text or "carla.host" in text


def test_a_campaign_started_twice_is_refused(tmp_path: Path) -> None:
    from cam2sim.campaign.runner import campaign_lock

    street_workspace(tmp_path / "ws", StreetSpec(length_m=30.0, radius_m=60.0))
    plan = tmp_path / "plan.yaml"
    plan.write_text("workspaces: [ws]\npolicies: [pure-pursuit]\ncameras: [none]\n")
    with campaign_lock(tmp_path / "plan-campaign"):
        result = CliRunner().invoke(app, ["campaign", str(plan)])
    text = " ".join(result.output.split())
    assert result.exit_code == 1, text
    assert "another cam2sim campaign is running" in text


def test_an_editor_started_twice_is_refused(tmp_path: Path) -> None:
    from cam2sim.core.files import process_lock

    ws = street_workspace(tmp_path / "ws", StreetSpec(length_m=30.0, radius_m=60.0))
    with process_lock(ws.detections_dir / ".editor.lock", busy="held by the test"):
        result = CliRunner().invoke(app, ["refine", str(ws.root), "--port", str(_free_port())])
    text = " ".join(result.output.split())
    assert result.exit_code == 1, text
    assert "Traceback" not in result.output
    assert "held by the test" not in text  # the editor's own message, not the test's
    assert "another cam2sim editor is open" in text
