"""Where campaign runs execute: a local process pool, or tasks on a Ray cluster.

Both run :func:`cam2sim.campaign.worker.execute` once per job and hand every outcome to a
callback in the calling process, in the order runs finish.

- :class:`LocalPool`: a ``ProcessPoolExecutor`` (``spawn``) with ``workers`` processes, each
  allotted its share of the CPUs as Ray allots a task's (:func:`~cam2sim.core.machine.allot_cpus`).
  At most ``workers`` runs are in flight, so when a worker process dies (a crash the run's own error
  handling cannot catch) the runs in flight are the only suspects: each is tried again alone, and
  the one that kills its worker again is recorded ``crashed``.
- :class:`RayCluster`: runs on a Ray cluster with their resource needs: a run that wants no
  GPU is a task with one CPU; the splat camera's runs go to a worker (an actor) per GPU slot
  (a GPU, or a share of one), which runs one after another in the same process. ``ray`` is an
  optional extra, imported only here.
"""

from __future__ import annotations

import collections
import logging
import multiprocessing
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from cam2sim.campaign.state import RunOutcome
from cam2sim.campaign.worker import execute
from cam2sim.core.cluster import LOST_WORKER_RETRIES, ray_session
from cam2sim.core.errors import ConfigError
from cam2sim.core.machine import allot_cpus, available_cpus, share_gpu

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
        self.workers = max(1, workers or available_cpus())
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
        processes = min(workers, len(jobs))
        share = max(1, available_cpus() // processes)  # each its share, not every core
        with ProcessPoolExecutor(  # and the GPU: the workers' GPU work all lands on the first
            max_workers=processes,
            mp_context=context,
            initializer=allot_cpus,
            initargs=(share, processes),
        ) as pool:
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
    cluster has GPUs (0.5: two runs share a GPU, each holding it about half the time), on a
    worker that keeps its process and GPU from one such job to the next (:class:`_GpuWorkers`);
    on a cluster without any it runs on CPUs (asking for one there would wait forever).

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
        """Submit every job (a task, or to a GPU worker), then report outcomes as they finish."""
        with ray_session(self.address, num_cpus=self.num_cpus) as ray:
            self._run(ray, jobs, report)

    def _run(self, ray: Any, jobs: Sequence[Job], report: Callable[[RunOutcome], None]) -> None:
        gpus = float(ray.cluster_resources().get("GPU", 0.0))
        if gpus == 0 and any(job.spec.needs_gpu for job in jobs):
            logger.warning("the Ray cluster has no GPU: jobs that want one run on CPUs")
        cpus = min(self.cpus_per_job, float(ray.cluster_resources().get("CPU", 1.0)))
        on_gpu = [job for job in jobs if job.spec.needs_gpu] if gpus > 0 else []
        slots = min(len(on_gpu), int(gpus / self.gpus_per_job + 1e-9))
        if slots == 0:  # no job wants a GPU, or none fits: every job is a task
            on_gpu = []
        task = ray.remote(self.task).options(
            num_cpus=cpus, num_gpus=0, max_retries=LOST_WORKER_RETRIES
        )
        pending: dict[Any, tuple[Job, Any]] = {
            task.remote(job.spec, job.log, job.timeout_s): (job, None)
            for job in jobs
            if not (on_gpu and job.spec.needs_gpu)
        }
        gpu_workers = _GpuWorkers(ray, self.task, cpus, self.gpus_per_job, on_gpu)
        for _ in range(slots):
            gpu_workers.start(pending)
        while pending:
            refs = list(pending)
            first, rest = ray.wait(refs, num_returns=1)  # block for one, then take all ready
            more, _ = ray.wait(rest, num_returns=len(rest), timeout=0) if rest else ([], [])
            for ref in first + more:
                job, worker = pending.pop(ref)
                try:
                    outcome = ray.get(ref)
                except ray.exceptions.RayError as err:  # the worker died or the task was lost
                    outcome = _died(job, f"the Ray task failed: {type(err).__name__}: {err}")
                if worker is not None:  # its next job first: scoring this one takes a while
                    gpu_workers.next(worker, pending)
                report(outcome)


class _Worker:
    """A process that runs one job after another (a Ray actor holding its share of a GPU).

    ``sharers``: the processes its GPU is shared among (2 for half a GPU), said to its jobs
    through :func:`~cam2sim.core.machine.share_gpu`.
    """

    def __init__(self, task: Callable[..., RunOutcome], sharers: int = 1) -> None:
        self.task = task
        share_gpu(sharers)

    def run(self, spec: Spec, log: str, timeout_s: float | None) -> RunOutcome:
        """Run one job with the task."""
        return self.task(spec, log, timeout_s)


class _GpuWorkers:
    """The GPU jobs' workers: one Ray actor per GPU slot, each given the next job as it ends one.

    Ray starts a new worker process for every task that asks for a GPU (its ``max_calls`` is 1
    for them, to give back GPU memory), so every short drive paid for importing torch, a CUDA
    context and loading its models before its first step, and many at once queued on the
    host's CPUs for it. An actor keeps its process, its GPU and what it has imported for all the
    jobs it runs. A worker process that dies is restarted (on another node when its node is
    lost) and its job run again, once (:data:`~cam2sim.core.cluster.LOST_WORKER_RETRIES`, as
    for tasks); a job that kills it again is reported, and the restarted worker goes on with
    the next. A worker with nothing left to run is ended, giving its CPU and GPU back.
    """

    def __init__(
        self, ray: Any, task: Callable[..., RunOutcome], cpus: float, gpus: float, queue: list[Job]
    ) -> None:
        self.ray = ray
        self.queue = collections.deque(queue)
        self.actor = ray.remote(_Worker).options(
            num_cpus=cpus,
            num_gpus=gpus,
            max_restarts=-1,  # a process that dies is restarted for the next job
            max_task_retries=LOST_WORKER_RETRIES,
        )
        self.task = task
        self.sharers = max(1, round(1 / gpus)) if gpus < 1 else 1  # 0.5: two a GPU

    def start(self, pending: dict[Any, tuple[Job, Any]]) -> None:
        """Start a worker and give it the next job."""
        self.next(self.actor.remote(self.task, self.sharers), pending)

    def next(self, worker: Any, pending: dict[Any, tuple[Job, Any]]) -> None:
        """Give ``worker`` the next job, or end it when none is left."""
        if not self.queue:
            self.ray.kill(worker)
            return
        job = self.queue.popleft()
        pending[worker.run.remote(job.spec, job.log, job.timeout_s)] = (job, worker)
