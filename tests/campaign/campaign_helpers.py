"""A small campaign for the campaign tests: one short synthetic street, pure pursuit, few runs."""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import TYPE_CHECKING

import pytest

from cam2sim.campaign.worker import execute
from cam2sim.scenario.synthetic import StreetSpec
from conftest import has_egl, street_workspace

if TYPE_CHECKING:
    from pathlib import Path

    from cam2sim.campaign.plan import RunSpec
    from cam2sim.campaign.state import RunOutcome

needs_egl = pytest.mark.skipif(
    not has_egl(), reason="no headless OpenGL (EGL) for the raster camera"
)

PLAN = """
workspaces: [ws]
policies: [pure-pursuit]
cameras: [none]
seeds: [0]
perturbations:
  - {lateral_m: [0.0, 0.3]}
drive: {image_size: [32, 24]}
timeout_s: 120
"""


def write_campaign(root: Path, plan: str = PLAN, *, name: str = "plan") -> Path:
    """``root/ws`` (a 30 m curved street, made once) and ``root/<name>.yaml``; the plan's path."""
    if not (root / "ws").is_dir():
        street_workspace(root / "ws", StreetSpec(length_m=30.0, radius_m=60.0))
    path = root / f"{name}.yaml"
    path.write_text(plan, encoding="utf-8")
    return path


def crashing_execute(spec: RunSpec, log: str, timeout_s: float | None) -> RunOutcome:
    """The worker's task, except that policy ``constant:13`` kills the worker process."""
    if spec.policy == "constant:13":
        os.abort()
    return execute(spec, log, timeout_s)


def dying_execute(spec: RunSpec, log: str, timeout_s: float | None) -> RunOutcome:
    """The worker's task, except that its worker process exits mid-run for two policies.

    ``constant:13``: on the first attempt only (a marker beside the run's log says it died
    once): what a worker killed for memory or a lost node does. ``constant:14``: every time.
    """
    from pathlib import Path

    marker = Path(log).with_suffix(".died")
    if spec.policy == "constant:14" or (spec.policy == "constant:13" and not marker.exists()):
        marker.parent.mkdir(parents=True, exist_ok=True)
        marker.write_text("the worker exited here\n", encoding="utf-8")
        os._exit(1)
    return execute(spec, log, timeout_s)


def probe_execute(spec: RunSpec, log: str, timeout_s: float | None) -> RunOutcome:
    """Instead of a drive: hold the task 1.5 s and log when, in which process and among how
    many processes its GPU is shared; the outcome says where it ran. Policy ``constant:13``:
    the process exits on the first attempt.

    A probe told it shares its GPU with others first waits (up to 30 s) until as many probes
    have begun (a ``.begun`` file each beside the logs): runs that share a GPU do run at the
    same time whatever the machine's load (a worker starting late on a busy machine made the
    overlap a race); runs that do not share one never meet, so the wait ends at its limit and
    the times show them apart."""
    import time
    from pathlib import Path

    from cam2sim.campaign.state import RunOutcome
    from cam2sim.core.cluster import worker_place
    from cam2sim.core.machine import gpu_sharers

    del timeout_s
    marker = Path(log).with_suffix(".died")
    if spec.policy == "constant:13" and not marker.exists():
        marker.parent.mkdir(parents=True, exist_ok=True)
        marker.write_text("the worker exited here\n", encoding="utf-8")
        os._exit(1)
    started = time.time()
    logs = Path(log).parent
    logs.mkdir(parents=True, exist_ok=True)
    sharers = gpu_sharers()
    if sharers > 1:
        Path(log).with_suffix(".begun").write_text(f"{started}\n", encoding="utf-8")
        deadline = time.monotonic() + 30.0
        while len(list(logs.glob("*.begun"))) < sharers and time.monotonic() < deadline:
            time.sleep(0.05)
    time.sleep(1.5)
    line = f"{started} {time.time()} {os.getpid()} {sharers}\n"
    Path(log).write_text(line, encoding="utf-8")
    return RunOutcome(spec.spec_id, "failed", None, 1.5, "a probe, no drive", log, worker_place())


def slow_execute(spec: RunSpec, log: str, timeout_s: float | None) -> RunOutcome:
    """The worker's task, after leaving ``<log>.started`` and waiting 4 s (time to kill a node)."""
    import time
    from pathlib import Path

    marker = Path(log).with_suffix(".started")
    marker.parent.mkdir(parents=True, exist_ok=True)
    marker.write_text(f"{os.getpid()}\n", encoding="utf-8")
    time.sleep(4.0)
    return execute(spec, log, timeout_s)


def full_disk_execute(spec: RunSpec, log: str, timeout_s: float | None) -> RunOutcome:
    """The worker's task; for policy ``constant:0.01`` the run folder's disk is full when the
    run writes its tables (in this worker process, for this run only)."""
    import errno

    from cam2sim.stages import runs

    if spec.policy != "constant:0.01":
        return execute(spec, log, timeout_s)
    real = runs._write_tables

    def full(folder: object, *args: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device", str(folder))

    runs._write_tables = full  # type: ignore[assignment]
    try:
        return execute(spec, log, timeout_s)
    finally:
        runs._write_tables = real


@dataclass(frozen=True)
class ThreadSpec:
    """A job for :func:`threads_execute`: an id and no GPU."""

    spec_id: str
    needs_gpu: bool = False


def threads_execute(spec: ThreadSpec, log: str, timeout_s: float | None) -> RunOutcome:
    """Instead of a run: log the CPUs the worker process was allotted, its torch threads and
    the processes its GPU is shared among."""
    from pathlib import Path

    import torch

    from cam2sim.campaign.state import RunOutcome

    del timeout_s
    Path(log).parent.mkdir(parents=True, exist_ok=True)
    Path(log).write_text(
        f"{os.environ.get('OMP_NUM_THREADS')} {torch.get_num_threads()} "
        f"{os.environ.get('CAM2SIM_GPU_SHARERS')}\n",
        encoding="utf-8",
    )
    return RunOutcome(spec.spec_id, "done", None, 0.0, None, log)
