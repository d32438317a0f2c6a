"""Where campaign runs execute: a local process pool, or tasks on a Ray cluster.

Both run :func:`cam2sim.campaign.worker.execute` once per job and hand every outcome to a
callback in the calling process, in the order runs finish.

- :class:`LocalPool`: a ``ProcessPoolExecutor`` (``spawn``) with ``workers`` processes. At most
  ``workers`` runs are in flight, so when a worker process dies (a crash the run's own error
  handling cannot catch) the runs in flight are the only suspects: each is tried again alone, and
  the one that kills its worker again is recorded ``crashed``.
- :class:`RayCluster`: one Ray task per run, with its resource needs (a GPU, or a share of one,
  for the splat camera; one CPU otherwise). ``ray`` is an optional extra, imported only here.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from cam2sim.campaign.state import RunOutcome
from cam2sim.campaign.worker import execute
from cam2sim.core.cluster import LOST_WORKER_RETRIES, ray_session
from cam2sim.core.errors import ConfigError

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

__all__ = ["Executor", "Job", "LocalPool", "RayCluster", "Spec"]

logger = logging.getLogger(__name__)


class Spec(Protocol):
    """What an executor needs of a job's spec (a drive's :class:`RunSpec`, a benchmark world)."""

    @property
    def spec_id(self) -> str:
        """The spec's id (the campaign state's key)."""

    @property
    def needs_gpu(self) -> bool:
        """Whether the job wants a GPU (on a cluster that has some)."""


@dataclass(frozen=True)
class Job:
    """One run to execute: the spec, its log file and its time limit."""

    spec: Spec
    log: str
    timeout_s: float | None


class Executor(Protocol):
    """Runs jobs and reports each outcome as it arrives."""

    name: str

    def run(self, jobs: Sequence[Job], report: Callable[[RunOutcome], None]) -> None:
        """Execute every job; call ``report`` once per job."""


def _died(job: Job, why: str) -> RunOutcome:
    """The outcome of a job whose worker process died; the reason is appended to its log."""
    path = Path(job.log)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a", encoding="utf-8") as log:
        log.write(f"\n{why}\n")
    return RunOutcome(job.spec.spec_id, "crashed", None, 0.0, why, job.log)


class LocalPool:
    """A local pool of ``workers`` processes (default: the CPU count).

    ``task`` is what runs a job (a module-level function, picklable by reference); tests swap
    in one that crashes.
    """

    name = "local pool"

    def __init__(
        self, workers: int | None = None, *, task: Callable[..., RunOutcome] = execute
    ) -> None:
        self.workers = max(1, workers or os.cpu_count() or 1)
        self.task = task

    def run(self, jobs: Sequence[Job], report: Callable[[RunOutcome], None]) -> None:
        """Execute ``jobs``; a dead worker's runs are retried alone to find the crashing one."""
        suspects = self._batch(list(jobs), self.workers, report)
        for job in suspects:
            again = self._batch([job], 1, report)
            if again:
                why = "the worker process died during the run (a crash, e.g. a segfault); "
                why += "its log ends where it died"
                report(_died(job, why))

    def _batch(
        self, jobs: list[Job], workers: int, report: Callable[[RunOutcome], None]
    ) -> list[Job]:
        """Run ``jobs`` with at most ``workers`` in flight; return those in flight at a crash."""
        if not jobs:
            return []
        context = multiprocessing.get_context("spawn")
        queue = list(reversed(jobs))
        inflight: dict[Future[RunOutcome], Job] = {}
        suspects: list[Job] = []
        with ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=context) as pool:
            while queue or inflight:
                while queue and len(inflight) < workers:
                    job = queue.pop()
                    inflight[pool.submit(self.task, job.spec, job.log, job.timeout_s)] = job
                finished, _ = wait(inflight, return_when=FIRST_COMPLETED)
                for future in finished:
                    job = inflight.pop(future)
                    try:
                        report(future.result())
                    except BrokenProcessPool:
                        suspects.append(job)
                if suspects:
                    break
        if suspects:  # the pool is broken: the rest runs in a new one
            suspects += list(inflight.values())
            logger.warning("a worker process died; retrying %d run(s) one by one", len(suspects))
            suspects += self._batch(list(reversed(queue)), workers, report)
        return suspects


class RayCluster:
    """Ray tasks on the cluster at ``address`` (``local``: start a local instance).

    When Ray is already initialised in this process (an embedding program, the tests) that
    instance is used and left running; otherwise one is connected to (or started) and shut down
    at the end. Workers need cam2sim installed and the workspaces at the same paths (a shared
    file system).

    ``task`` runs a job (default: a campaign drive); ``cpus_per_job`` CPUs are reserved for
    each (Ray also sets the task's thread count to it: a benchmark world trains DAVE-2 with
    torch and wants several). A job that needs a GPU gets ``gpus_per_job`` of one when the
    cluster has GPUs (0.5: two runs share a GPU, each holding it about half the time); on a
    cluster without any it runs on CPUs (asking for one there would wait forever).

    Raises:
        ConfigError: ``gpus_per_job`` is not in (0, 1] and not a whole number of GPUs.
    """

    name = "ray"

    def __init__(
        self,
        address: str = "local",
        *,
        num_cpus: int | None = None,
        task: Callable[..., RunOutcome] = execute,
        cpus_per_job: float = 1.0,
        gpus_per_job: float = 1.0,
    ) -> None:
        if not (gpus_per_job > 0 and (gpus_per_job <= 1 or float(gpus_per_job).is_integer())):
            msg = (
                f"gpus per job {gpus_per_job:g}: give a share of one GPU in (0, 1] "
                "(0.5: two jobs a GPU) or a whole number of GPUs"
            )
            raise ConfigError(msg)
        self.address = address
        self.num_cpus = num_cpus
        self.task = task
        self.cpus_per_job = cpus_per_job
        self.gpus_per_job = gpus_per_job

    def run(self, jobs: Sequence[Job], report: Callable[[RunOutcome], None]) -> None:
        """Submit every job as a task, then report outcomes as tasks finish."""
        with ray_session(self.address, num_cpus=self.num_cpus) as ray:
            self._run(ray, jobs, report)

    def _run(self, ray: Any, jobs: Sequence[Job], report: Callable[[RunOutcome], None]) -> None:
        task = ray.remote(self.task)
        gpus = float(ray.cluster_resources().get("GPU", 0.0))
        if gpus == 0 and any(job.spec.needs_gpu for job in jobs):
            logger.warning("the Ray cluster has no GPU: jobs that want one run on CPUs")
        cpus = min(self.cpus_per_job, float(ray.cluster_resources().get("CPU", 1.0)))
        pending: dict[Any, Job] = {}
        for job in jobs:
            needs = {
                "num_cpus": cpus,
                "num_gpus": self.gpus_per_job if job.spec.needs_gpu and gpus > 0 else 0,
                "max_retries": LOST_WORKER_RETRIES,
            }
            pending[task.options(**needs).remote(job.spec, job.log, job.timeout_s)] = job
        while pending:
            refs = list(pending)
            first, rest = ray.wait(refs, num_returns=1)  # block for one, then take all ready
            more, _ = ray.wait(rest, num_returns=len(rest), timeout=0) if rest else ([], [])
            for ref in first + more:
                job = pending.pop(ref)
                try:
                    outcome = ray.get(ref)
                except ray.exceptions.RayError as err:  # the worker died or the task was lost
                    outcome = _died(job, f"the Ray task failed: {type(err).__name__}: {err}")
                report(outcome)
