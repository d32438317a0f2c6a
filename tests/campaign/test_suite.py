"""The benchmark suite file: validation, expansion into worlds, stable ids."""

from __future__ import annotations

import shutil
from typing import TYPE_CHECKING

import pytest

from cam2sim.campaign.suite import expand_suite, load_suite
from cam2sim.core.errors import ConfigError

if TYPE_CHECKING:
    from pathlib import Path

SUITE = """
name: s
seeds: 2
worlds:
  - builtin: l-street
    tuned: true
  - osm: maps/a.osm
    routes: 3
    tuned: [0]
  - osm: maps/a.osm
    route: ["48.1,11.5", "48.2,11.6"]
"""


def _suite(root: Path, text: str = SUITE) -> Path:
    (root / "maps").mkdir(parents=True, exist_ok=True)
    (root / "maps" / "a.osm").write_text("<osm/>", encoding="utf-8")
    path = root / "suite.yaml"
    path.write_text(text, encoding="utf-8")
    return path


def test_a_suite_expands_to_one_world_a_route(tmp_path: Path) -> None:
    path = _suite(tmp_path)
    specs = expand_suite(load_suite(path), tmp_path)
    assert [s.label for s in specs] == ["l-street", "a-r0", "a-r1", "a-r2", "a-route"]
    assert [s.tuned for s in specs] == [True, True, False, False, False]
    assert [s.pick for s in specs] == [0, 0, 1, 2, 0]
    assert specs[1].osm_path == str((tmp_path / "maps" / "a.osm").resolve())
    assert all(s.seeds == 2 and s.needs_gpu for s in specs)
    assert len({s.spec_id for s in specs}) == len(specs)


def test_ids_stay_when_the_suite_and_its_maps_move(tmp_path: Path) -> None:
    first = expand_suite(load_suite(_suite(tmp_path / "a")), tmp_path / "a")
    shutil.copytree(tmp_path / "a", tmp_path / "b")
    second = expand_suite(load_suite(tmp_path / "b" / "suite.yaml"), tmp_path / "b")
    assert [s.spec_id for s in first] == [s.spec_id for s in second]
    changed = SUITE.replace("seeds: 2", "seeds: 3")
    third = expand_suite(load_suite(_suite(tmp_path / "c", changed)), tmp_path / "c")
    assert not {s.spec_id for s in first} & {s.spec_id for s in third}


def test_picks_run_some_routes_under_the_names_and_ids_of_the_larger_suite(
    tmp_path: Path,
) -> None:
    whole = expand_suite(load_suite(_suite(tmp_path)), tmp_path)
    some = SUITE.replace("routes: 3\n    tuned: [0]", "picks: [2, 1]\n    tuned: [0]")
    part = expand_suite(load_suite(_suite(tmp_path / "p", some)), tmp_path / "p")
    assert [s.label for s in part] == ["l-street", "a-r2", "a-r1", "a-route"]
    assert [s.pick for s in part] == [0, 2, 1, 0]
    by_label = {s.label: s.spec_id for s in whole}
    assert all(by_label[s.label] == s.spec_id for s in part)


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("worlds:\n  - builtin: l-street\n    tunde: true\n", "did you mean 'tuned'"),
        ("worlds:\n  - builtin: l-street\n    osm: maps/a.osm\n", "exactly one of `builtin:`"),
        ("worlds:\n  - builtin: moon\n", "worlds.0.builtin"),
        ("worlds:\n  - osm: maps/a.osm\n    routes: 2\n    route: [a, b]\n", "not both"),
        ("worlds:\n  - osm: maps/a.osm\n    routes: 2\n    picks: [1]\n", "not both"),
        ("worlds:\n  - osm: maps/a.osm\n    picks: [1, 1]\n", "names a route twice"),
        ("worlds:\n  - osm: maps/a.osm\n    picks: [-1]\n", "worlds.0.picks"),
        ("worlds:\n  - builtin: paper\n    picks: [1]\n", "go with `osm:`"),
        ("worlds: []\n", "worlds"),
        ("seeds: 0\nworlds:\n  - builtin: paper\n", "seeds"),
        (
            "worlds:\n  - builtin: paper\nsettings:\n  splat_init_points: 0\n",
            "settings.splat_init_points",
        ),
    ],
)
def test_a_bad_suite_says_which_key_and_what_to_do(tmp_path: Path, text: str, needle: str) -> None:
    path = _suite(tmp_path, text)
    with pytest.raises(ConfigError, match="invalid benchmark suite") as err:
        load_suite(path)
    assert str(path) in str(err.value)
    assert needle in str(err.value)


def test_a_missing_map_is_named_with_its_resolved_path(tmp_path: Path) -> None:
    path = _suite(tmp_path, "worlds:\n  - osm: maps/b.osm\n")
    with pytest.raises(ConfigError, match=r"maps/b\.osm: no such file"):
        expand_suite(load_suite(path), tmp_path)


def test_a_missing_suite_file_says_what_to_write(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="benchmark suite"):
        load_suite(tmp_path / "none.yaml")


def test_the_splat_settings_change_the_preset_and_the_world_ids(tmp_path: Path) -> None:
    from cam2sim.campaign.bench import splat_options
    from cam2sim.stages.splat import SplatStageOptions

    thinned = SUITE + "settings:\n  splat_init_points: 150000\n"
    plain = expand_suite(load_suite(_suite(tmp_path / "a")), tmp_path / "a")
    specs = expand_suite(load_suite(_suite(tmp_path / "b", thinned)), tmp_path / "b")
    assert [s.label for s in specs] == [s.label for s in plain]
    # Another experiment: a run of the thinned suite never resumes a plain one's worlds.
    assert not {s.spec_id for s in plain} & {s.spec_id for s in specs}
    preset = SplatStageOptions.demo(cuda=True).train
    assert preset is not None
    assert preset.max_init_points == 250_000  # the GPU preset's thinned start
    assert preset.densify.max_gaussians == 400_000  # and its cap
    train = splat_options(specs[0].settings, cuda=True).train
    assert train is not None
    assert train.max_init_points == 150_000
    assert (train.min_steps, train.max_steps, train.time_budget_s) == (
        preset.min_steps,
        preset.max_steps,
        preset.time_budget_s,
    )
    both = splat_options(specs[0].settings.model_copy(update={"splat_steps": 40}), cuda=False)
    assert both.train is not None
    assert (both.train.min_steps, both.train.max_steps, both.train.max_init_points) == (
        40,
        40,
        150_000,
    )
    assert both.train.time_budget_s is None
    capped = specs[0].settings.model_copy(update={"splat_max_gaussians": 300_000})
    train = splat_options(capped, cuda=True).train
    assert train is not None
    assert train.densify.max_gaussians == 300_000
    assert train.densify.strategy == preset.densify.strategy  # only the cap differs
    assert both.prepare == SplatStageOptions.demo(cuda=False).prepare


def test_each_world_draws_its_own_runs_unless_the_suite_shares_the_seeds(tmp_path: Path) -> None:
    from cam2sim.stages.variation import DEMO_RUN_VARIATION

    specs = expand_suite(load_suite(_suite(tmp_path / "a")), tmp_path / "a")
    seeds = [s.run_seed for s in specs]
    assert len(set(seeds)) == len(seeds)  # no two streets run the same draws
    # The seed comes from the label alone: the same on another machine, from another folder.
    again = expand_suite(load_suite(_suite(tmp_path / "b")), tmp_path / "b")
    assert [s.run_seed for s in again] == seeds
    # Their start offsets differ from street to street, as repeated drives of different
    # streets would (with seeds 0, 1, 2 everywhere, every street drew the same three).
    starts = {round(DEMO_RUN_VARIATION.draw(seed).lateral_m, 6) for seed in seeds}
    assert len(starts) == len(seeds)
    shared = expand_suite(
        load_suite(_suite(tmp_path / "c", SUITE + "settings:\n  run_seeds: shared\n")),
        tmp_path / "c",
    )
    assert [s.run_seed for s in shared] == [0] * len(shared)
    # Another experiment: shared seeds never resume a per-world suite's worlds.
    assert not {s.spec_id for s in shared} & {s.spec_id for s in specs}
