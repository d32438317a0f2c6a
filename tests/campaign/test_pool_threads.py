"""The local pool gives each worker process its share of the CPUs, as Ray gives a task its own."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import pytest
from campaign_helpers import ThreadSpec, threads_execute

from cam2sim.campaign.executors import Job, LocalPool
from cam2sim.core.machine import allot_cpus, available_cpus

if TYPE_CHECKING:
    from pathlib import Path

    from cam2sim.campaign.state import RunOutcome


def _threads(tmp_path: Path, workers: int, jobs: int) -> list[tuple[int, int]]:
    outcomes: list[RunOutcome] = []
    batch = [Job(ThreadSpec(f"j{i}"), str(tmp_path / f"j{i}.log"), None) for i in range(jobs)]
    LocalPool(workers, task=threads_execute).run(batch, outcomes.append)
    assert sorted(o.status for o in outcomes) == ["done"] * jobs
    pairs = [(tmp_path / f"j{i}.log").read_text().split() for i in range(jobs)]
    return [(int(env), int(torch_threads)) for env, torch_threads in pairs]


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
