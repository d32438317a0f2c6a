from __future__ import annotations

import os
from typing import TYPE_CHECKING

from cam2sim.core.machine import available_cpus
from cam2sim.stages.pipeline import default_drive_workers

if TYPE_CHECKING:
    import pytest


def test_a_ray_tasks_share_caps_the_cpus(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(os, "sched_getaffinity", lambda _pid: set(range(64)), raising=False)
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    assert available_cpus() == 64
    monkeypatch.setenv("OMP_NUM_THREADS", "16")  # what Ray sets for a task of 16 CPUs
    assert available_cpus() == 16
    # 3 cameras x 3 seeds on 16 CPUs: 4 processes; on 2 cores: one.
    assert default_drive_workers(9) == 4
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    assert default_drive_workers(9) == 1
    monkeypatch.setenv("OMP_NUM_THREADS", "junk")
    assert available_cpus() == 64
