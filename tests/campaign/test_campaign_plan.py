"""Campaign plans: validation messages that name the file, the key and the fix; expansion."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from cam2sim.campaign.plan import expand, load_plan
from cam2sim.core.errors import ConfigError

if TYPE_CHECKING:
    from pathlib import Path


def _plan(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "plan.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def test_a_misspelt_key_is_named_with_the_fix(tmp_path: Path) -> None:
    path = _plan(tmp_path, "workspace: [ws]\n")
    with pytest.raises(ConfigError) as err:
        load_plan(path)
    text = str(err.value)
    assert str(path) in text
    assert "workspace: unknown key (did you mean 'workspaces'?)" in text
    assert "workspaces: missing" in text


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("workspaces: [ws]\ncameras: [fisheye]\n", "cameras.0: Input should be"),
        ("workspaces: [ws]\nrepetitions: 0\n", "repetitions: Input should be greater than"),
        ("workspaces: [ws]\nperturbations: [{speed_kmh: -5}]\n", "speeds must be >= 0"),
        ("workspaces: [ws]\ndrive: {image_size: [0, 10]}\n", "image_size takes [width, height]"),
        ("workspaces: [ws]\ntimeout_s: 0\n", "timeout_s: Input should be greater than 0"),
        ("workspaces: [ws\n", "not valid YAML"),
        ("- ws\n", "expected a mapping with at least `workspaces:`"),
    ],
)
def test_invalid_plans_are_refused(tmp_path: Path, text: str, expected: str) -> None:
    with pytest.raises(ConfigError, match="plan.yaml") as err:
        load_plan(_plan(tmp_path, text))
    assert expected in str(err.value)


def test_a_missing_plan_says_how_to_write_one(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="does not exist; write a campaign plan"):
        load_plan(tmp_path / "nope.yaml")


def test_expansion_is_the_full_product_with_stable_ids(tmp_path: Path) -> None:
    path = _plan(
        tmp_path,
        """
workspaces: [a, /abs/b]
policies: [pure-pursuit, "constant:0"]
cameras: none
seeds: [0, 1]
repetitions: 2
perturbations:
  - {lateral_m: [-0.5, 0.5], heading_deg: 3}
  - {speed_kmh: 20}
""",
    )
    plan = load_plan(path)
    specs = expand(plan, tmp_path)
    # 2 workspaces x 2 policies x 1 camera x (2 + 1) perturbations x 2 seeds x 2 repetitions
    assert len(specs) == 2 * 2 * 1 * 3 * 2 * 2
    ids = [s.spec_id for s in specs]
    assert len(set(ids)) == len(ids)
    assert ids == [s.spec_id for s in expand(load_plan(path), tmp_path / "elsewhere")]
    first = specs[0]
    assert first.workspace_path == str(tmp_path / "a")
    assert specs[-1].workspace_path == "/abs/b"
    assert (first.lateral_m, first.heading_deg, first.speed_kmh) == (-0.5, 3.0, None)
    assert {s.speed_kmh for s in specs} == {None, 20.0}
    assert first.spec_id.startswith("a-none-s0-r0-")
    assert not first.needs_gpu


def test_a_run_listed_twice_is_refused(tmp_path: Path) -> None:
    plan = load_plan(_plan(tmp_path, "workspaces: [ws]\nseeds: [3, 3]\n"))
    with pytest.raises(ConfigError, match="same run more than once"):
        expand(plan, tmp_path)


def test_splat_runs_need_a_gpu(tmp_path: Path) -> None:
    plan = load_plan(_plan(tmp_path, "workspaces: [ws]\ncameras: [splat, raster]\n"))
    assert [s.needs_gpu for s in expand(plan, tmp_path)] == [True, False]


def test_model_policies_resolve_against_the_plan_folder(tmp_path: Path) -> None:
    plan = load_plan(_plan(tmp_path, "workspaces: [ws]\npolicies: [m/dave2.onnx, tcp://h:1]\n"))
    specs = expand(plan, tmp_path)
    assert [s.policy_arg for s in specs] == [str(tmp_path / "m" / "dave2.onnx"), "tcp://h:1"]
    assert [s.policy for s in specs] == ["m/dave2.onnx", "tcp://h:1"]


def test_each_workspace_drives_with_its_own_model(tmp_path: Path) -> None:
    for name in ("a", "b"):
        (tmp_path / name / "ads").mkdir(parents=True)
        (tmp_path / name / "ads" / "dave2.onnx").write_bytes(b"model " + name.encode())
    plan = load_plan(_plan(tmp_path, "workspaces: [a, b]\npolicies: [workspace-model]\n"))
    specs = expand(plan, tmp_path)
    assert [s.policy_arg for s in specs] == [
        str(tmp_path / "a" / "ads" / "dave2.onnx"), str(tmp_path / "b" / "ads" / "dave2.onnx"),
    ]  # fmt: skip
    # The id hashes the plan's word, not the path: a moved campaign keeps its ids.
    assert all(s.policy == "workspace-model" for s in specs)
    (tmp_path / "b" / "ads" / "dave2.onnx").unlink()
    with pytest.raises(ConfigError, match=r"workspace b has no dave2.onnx .*cam2sim ads train b"):
        expand(plan, tmp_path)
