"""Campaigns on Ray (a local instance, 2 CPUs): the same metrics as the local pool."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import campaign_helpers
import pytest
from campaign_helpers import PLAN, dying_execute, needs_egl, write_campaign

from cam2sim.campaign.executors import LocalPool, RayCluster
from cam2sim.campaign.runner import run_campaign
from cam2sim.campaign.state import CampaignState

if TYPE_CHECKING:
    from collections.abc import Iterator

ray = pytest.importorskip("ray")

# Seeds matter (steering noise), starts are perturbed; one spec fails (a bad policy).
DETERMINISM_PLAN = (
    PLAN.replace("[pure-pursuit]", '[pure-pursuit, "constant:nan"]')
    .replace("cameras: [none]", "cameras: [raster]")
    .replace("seeds: [0]", "seeds: [0, 1]")
    .replace("[32, 24]}", "[32, 24], steering_noise_std: 2}")
)


@pytest.fixture(scope="module")
def local_ray() -> Iterator[None]:
    """One local Ray instance for the module (it takes seconds to start)."""
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


def _two_chunk_street(
    root: Path, monkeypatch: pytest.MonkeyPatch, **changes: object
) -> tuple[Path, Any]:
    """The small synthetic street of the training tests (tests/splat/test_train.py), two chunks
    of 4 frames: its prepared folder and fast options of 4 steps (``changes`` on top)."""
    pytest.importorskip("torch")
    monkeypatch.syspath_prepend(str(Path(__file__).parents[1] / "splat"))
    from test_train import fast_options, make_prepared_scene

    prep = make_prepared_scene(root / "ws", n_frames=6, chunks=((0, 4), (2, 6)), size=(32, 24))
    base: dict[str, Any] = {"max_steps": 4, "min_steps": 4, "val_every": 2, "sky_points": 20}
    return prep, fast_options(**(base | changes))


@needs_egl
def test_ray_and_the_local_pool_give_identical_metrics(tmp_path: Path, local_ray: None) -> None:
    local = run_campaign(
        write_campaign(tmp_path, DETERMINISM_PLAN + "output: local\n", name="local"),
        executor=LocalPool(2),
    )
    on_ray = run_campaign(
        write_campaign(tmp_path, DETERMINISM_PLAN + "output: on-ray\n", name="on-ray"),
        executor=RayCluster(),
    )
    assert on_ray.ran == local.ran == 8
    assert [r.spec_id for r in on_ray.rows] == [r.spec_id for r in local.rows]
    keys = ("status", "completion", "success", "min_frechet_m", "corridor_violation_pct")
    for a, b in zip(local.rows, on_ray.rows, strict=True):
        assert [getattr(a, k) for k in keys] == [getattr(b, k) for k in keys], a.spec_id
        if a.status == "done":
            runs = tmp_path / "ws" / "runs"
            trajectory = (runs / str(a.run_id) / "trajectory.csv").read_text()
            assert trajectory == (runs / str(b.run_id) / "trajectory.csv").read_text()
    assert local.summary == on_ray.summary
    done = [r for r in local.rows if r.status == "done"]
    assert len(done) == 4
    assert len({r.min_frechet_m for r in done}) > 1  # the seeds and the offsets do change runs
    failed = [r for r in on_ray.rows if r.status == "failed"]
    assert len(failed) == 4
    log = (on_ray.folder / "logs" / f"{failed[0].spec_id}.log").read_text()
    assert "constant:VALUE needs a finite number" in log


def test_splat_chunks_train_as_ray_tasks_into_the_same_models_folder(
    tmp_path: Path, local_ray: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    prep, options = _two_chunk_street(tmp_path, monkeypatch, time_budget_s=600.0)
    from cam2sim.splat.distributed import train_scene_on_ray

    seen: list[tuple[int, int | None]] = []
    result = train_scene_on_ray(
        prep, options=options, progress=lambda _task, done, total: seen.append((done, total))
    )
    assert [(c.chunk_id, c.steps) for c in result.chunks] == [(0, 4), (1, 4)]
    assert seen[-1] == (2, 2)
    # What train_scene writes (tests/splat/test_train.py checks its files): one model per chunk.
    models = tmp_path / "ws" / "splat" / "models"
    assert sorted(p.name for p in models.iterdir()) == [
        "chunk_00.json", "chunk_00.pt", "chunk_01.json", "chunk_01.pt", "results",
    ]  # fmt: skip
    assert sorted(p.name for p in (models / "results").iterdir()) == [
        "chunk_00.json",
        "chunk_01.json",
    ]  # fmt: skip (each chunk's training result, kept as it is written: a stage resumes from it)
    assert [c.model_path for c in result.chunks] == [models / "chunk_00.pt", models / "chunk_01.pt"]


def test_a_failing_chunk_on_ray_is_named_after_the_others_are_saved(
    tmp_path: Path, local_ray: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    prep, options = _two_chunk_street(tmp_path, monkeypatch)
    from cam2sim.core.errors import StageError
    from cam2sim.splat.distributed import train_scene_on_ray

    (prep / "images" / "000005.png").write_bytes(b"broken")  # a frame of chunk 1 only
    with pytest.raises(StageError, match=r"1 of 2 chunks failed on Ray \(chunk 1: .*000005.png"):
        train_scene_on_ray(prep, options=options)
    models = tmp_path / "ws" / "splat" / "models"
    assert sorted(p.name for p in models.glob("chunk_*")) == ["chunk_00.json", "chunk_00.pt"]


def test_a_killed_worker_is_retried_once_and_then_reported(tmp_path: Path, local_ray: None) -> None:
    # The helpers' module is not importable in Ray's workers: send its functions by value.
    ray.cloudpickle.register_pickle_by_value(campaign_helpers)
    plan = write_campaign(
        tmp_path,
        PLAN.replace("[pure-pursuit]", '[pure-pursuit, "constant:13", "constant:14"]').replace(
            "{lateral_m: [0.0, 0.3]}", "{}"
        ),
    )
    result = run_campaign(plan, executor=RayCluster(task=dying_execute))
    status = {r.policy: r.status for r in result.rows}
    # Killed once: run again, and done; killed every time: reported, and the rest goes on.
    assert status == {"pure-pursuit": "done", "constant:13": "done", "constant:14": "crashed"}
    crashed = next(r for r in result.rows if r.status == "crashed")
    log = (result.folder / "logs" / f"{crashed.spec_id}.log").read_text()
    assert "the Ray task failed" in log
    # Nothing half-written: every run folder is a finished run with its tables.
    runs = tmp_path / "ws" / "runs"
    finished = sorted(p for p in runs.iterdir() if not p.name.startswith("."))
    assert len(finished) == 2
    assert all((p / "run.json").is_file() and (p / "trajectory.csv").is_file() for p in finished)
    # A resume redoes only what is not done: nothing without retries, the crashed run with.
    state = CampaignState.load(result.folder / "state.json")
    assert len(state.done()) == 2
    again = run_campaign(plan, executor=RayCluster(task=dying_execute), retry_failed=False)
    assert again.ran == 0
    retried = run_campaign(plan, executor=RayCluster(task=dying_execute))
    assert retried.ran == 1
    assert [r.status for r in retried.rows if r.policy == "constant:14"] == ["crashed"]
    assert sorted(p for p in runs.iterdir() if not p.name.startswith(".")) == finished


def _out_of_memory_once(
    scene: object, chunk_id: int, prep_dir: str, options: object, models: str
) -> object:
    """The Ray task of a chunk, except that chunk 1 runs out of GPU memory on its first try."""
    import torch

    from cam2sim.splat import distributed

    marker = Path(models).parent / f"oom-{chunk_id}"
    if chunk_id == 1 and not marker.exists():
        marker.parent.mkdir(parents=True, exist_ok=True)
        marker.touch()
        msg = "CUDA out of memory. Tried to allocate 102.00 MiB"
        raise torch.OutOfMemoryError(msg)
    result = distributed.train_chunk(
        scene, chunk_id, Path(prep_dir), options, models_dir=Path(models)
    )
    return result, None


def test_a_chunk_out_of_gpu_memory_on_ray_trains_again(
    tmp_path: Path, local_ray: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    import sys

    prep, options = _two_chunk_street(tmp_path, monkeypatch)
    from cam2sim.splat import distributed

    # This module is not importable in Ray's workers: send the task by value.
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    monkeypatch.setattr(distributed, "_train_one", _out_of_memory_once)
    result = distributed.train_scene_on_ray(prep, options=options)
    assert [(c.chunk_id, c.steps) for c in result.chunks] == [(0, 4), (1, 4)]
    assert (tmp_path / "ws" / "splat" / "oom-1").is_file()  # it did run out once


def test_ray_trains_only_the_chunks_asked_for(
    tmp_path: Path, local_ray: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    # What a splat stage resuming on Ray asks for: the chunks an earlier training did not finish.
    prep, options = _two_chunk_street(tmp_path, monkeypatch)
    from cam2sim.splat.distributed import train_scene_on_ray

    result = train_scene_on_ray(prep, options=options, chunk_ids=(1,))
    assert [c.chunk_id for c in result.chunks] == [1]
    models = tmp_path / "ws" / "splat" / "models"
    assert sorted(p.name for p in models.glob("chunk_*")) == ["chunk_01.json", "chunk_01.pt"]
