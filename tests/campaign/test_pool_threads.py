"""The local pool gives each worker process its share of the CPUs, as Ray gives a task its own."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import pytest
from campaign_helpers import ThreadSpec, threads_execute

from cam2sim.campaign.executors import Job, LocalPool
from cam2sim.core.machine import (
    GPU_SHARERS_VARIABLE,
    allot_cpus,
    available_cpus,
    gpu_sharers,
    share_gpu,
)

if TYPE_CHECKING:
    from pathlib import Path

    from cam2sim.campaign.state import RunOutcome


def _logs(tmp_path: Path, workers: int, jobs: int) -> list[list[str]]:
    outcomes: list[RunOutcome] = []
    batch = [Job(ThreadSpec(f"j{i}"), str(tmp_path / f"j{i}.log"), None) for i in range(jobs)]
    LocalPool(workers, task=threads_execute).run(batch, outcomes.append)
    assert sorted(o.status for o in outcomes) == ["done"] * jobs
    return [(tmp_path / f"j{i}.log").read_text().split() for i in range(jobs)]


def _threads(tmp_path: Path, workers: int, jobs: int) -> list[tuple[int, int]]:
    logs = _logs(tmp_path, workers, jobs)
    return [(int(env), int(torch_threads)) for env, torch_threads, _share in logs]


@pytest.mark.skipif(available_cpus() < 2, reason="needs two CPUs to share")
def test_each_worker_gets_its_share_of_the_cpus_not_every_core(tmp_path: Path) -> None:
    cpus = available_cpus()
    shared = _threads(tmp_path / "two", workers=2, jobs=2)
    assert shared == [(cpus // 2, cpus // 2)] * 2
    alone = _threads(tmp_path / "one", workers=2, jobs=1)  # one job in flight: every CPU
    assert alone == [(cpus, cpus)]


def test_an_allotment_from_a_scheduler_above_is_not_raised(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    # setenv, not delenv: monkeypatch restores only what it recorded, and a variable left
    # behind here (NUMBA_NUM_THREADS=1) changes how later tests' worker processes compute.
    for name in ("MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS"):
        monkeypatch.setenv(name, "99")
    allot_cpus(8)
    assert os.environ["OMP_NUM_THREADS"] == "1"
    assert os.environ["NUMBA_NUM_THREADS"] == "1"
    assert available_cpus() == 1


def test_each_worker_knows_how_many_share_the_gpu(tmp_path: Path) -> None:
    # The pool's workers all put their GPU work on the machine's first GPU: a splat's time cap
    # stretches with the share (SplatStageOptions.demo).
    shared = _logs(tmp_path / "three", workers=3, jobs=3)
    assert [share for *_, share in shared] == ["3"] * 3
    alone = _logs(tmp_path / "one", workers=3, jobs=1)  # one job: one process, the GPU its own
    assert [share for *_, share in alone] == ["1"]


def test_gpu_sharers_reads_the_variable_and_keeps_a_larger_share(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv(GPU_SHARERS_VARIABLE, "")
    assert gpu_sharers() == 1
    monkeypatch.setenv(GPU_SHARERS_VARIABLE, "junk")
    assert gpu_sharers() == 1
    share_gpu(2)
    assert gpu_sharers() == 2
    share_gpu(1)  # a scheduler above said 2: kept
    assert gpu_sharers() == 2
