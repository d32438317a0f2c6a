"""Splat chunks trained side by side: one worker process per chunk on one device.

:func:`cam2sim.splat.train.train_scene` calls :func:`train_chunks_in_processes` when more than
one chunk may train at a time (``TrainOptions.concurrent_chunks``; by default 2 or 3 on CUDA:
:func:`cuda_slots`). One Python thread cannot keep a fast GPU busy (the step is host-bound),
while processes on one GPU overlap their kernels and host work: 1.75 times the steps per second
with two on an H100, 2 times on KITTI's full-size frames, little more with three.

Each chunk trains in its own spawned process (``torch.multiprocessing``, start method
``spawn``: CUDA cannot be forked), at most ``in_flight`` at a time (one more process loads its
chunk meanwhile and waits for a slot, so start-up hides behind training), the longest chunks
first (:func:`largest_first`), through the same
:func:`~cam2sim.splat.train.train_scene` call as a chunk trained alone, so a chunk's model does
not depend on what trained beside it (in the one-process loop, gsplat's densification draws its
splits from torch's global generator, which the chunks share). Workers send their progress (at
most every 0.1 s), log records and their result or failure through one queue; the parent adds
up the steps for the progress callback, re-emits the log records, and, once all chunks have
finished, raises one :class:`~cam2sim.core.errors.StageError` naming every chunk that failed
(a chunk whose worker ran out of GPU memory, taken by the processes beside it, first trains
again from its start with a slot fewer: :data:`OUT_OF_MEMORY_RETRIES`)
(:class:`ChunkOutcomes`, shared with the Ray path of :mod:`cam2sim.splat.distributed`). Ctrl-C
(or any error in the parent) terminates the workers; workers ignore SIGINT themselves so the
parent decides.

The gsplat CUDA extension is built (or loaded from ``TORCH_EXTENSIONS_DIR``) in the parent
before the first worker starts, so the workers load it instead of each compiling it.
"""

from __future__ import annotations

import dataclasses
import logging
import queue
import signal
import time
import traceback
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

from cam2sim.core.errors import StageError
from cam2sim.core.machine import available_cpus, children_allotted
from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.core.sidecar import LogForwarder, end_processes
from cam2sim.splat.raster import build_gsplat
from cam2sim.splat.train_options import SceneTrainResult

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable

    from cam2sim.splat.scene import SceneRecord
    from cam2sim.splat.train_options import TrainOptions, TrainResult

    #: ``train_scene``'s signature: what a worker runs for its one chunk.
    SceneTrainer = Callable[..., SceneTrainResult]

__all__ = [
    "CUDA_SLOT_RATES",
    "OUT_OF_MEMORY_RETRIES",
    "SHARED_GPU_WORKER_GIB",
    "ChunkOutcomes",
    "cuda_slots",
    "largest_first",
    "shared_gpu_slots",
    "train_chunks_in_processes",
    "wait_for_memory",
    "worker_cpus",
]

CUDA_SLOT_RATES: Final = {1: 0.5, 2: 1.0, 3: 1.04}
"""Steps a second of k chunks training at once on one GPU, relative to two: one process leaves
the GPU half idle (KITTI 03 on an H100: a lone chunk 66 steps/s, two together 133, three 138,
averaged over a run; at the 1M cap two and three alike step 84-88 times a second together:
docs/benchmarks.md, "KITTI 03 on one GPU", seventh and eighth runs). More than three were not
measured. On the GPU demo's street chunks (320x200 views, 0.1-0.7M Gaussians) one chunk already
fills an H100: one process taking a step of each chunk in turn and three worker processes at a
time trained the same 6,000 steps in 101 and 102 s (docs/benchmarks.md, "Five untuned streets
alone on an H100"); more at a time gain little there, and overlap the next chunk's loading."""

MIN_GIB_FOR_THREE: Final = 40.0
"""Three chunks at a time only on a GPU with at least this much memory (a worker of a real
chunk of 2M Gaussians at 1242x375 peaks at a few GiB; a 24 GiB card keeps two)."""

SHARED_GPU_WORKER_GIB: Final = 16.0
"""GPU memory a CUDA chunk worker of the demo's preset may hold, in GiB: the slots of a GPU that
other processes share (:func:`shared_gpu_slots`) come from it, and a chunk that ran out of
memory waits for this much to be free (at most half the card: :func:`wait_for_memory`). Five
benchmark worlds on one H100 (80 GB), two chunks training at a time in each, held 4-17.5 GiB a
worker (0.4-1.2M Gaussians), and two worlds' chunks ran out of memory (docs/benchmarks.md, "Five
worlds on one H100")."""

OUT_OF_MEMORY_RETRIES: Final = 2
"""Times a chunk whose worker ran out of GPU memory trains again from its start (with one slot
fewer, so it waits for a chunk beside it to end) before it counts as failed: the memory was
taken by processes beside it, which end."""

logger = logging.getLogger(__name__)

_PROGRESS_SECONDS = 0.1  # a worker reports its step count at most this often
_MEMORY_WAIT_S = 300.0  # a retried chunk's worker waits at most this long for free GPU memory
_MEMORY_POLL_S = 5.0
_POLL_SECONDS = 0.5  # the parent checks for dead workers this often


class ChunkOutcomes:
    """Results and failures of chunks trained apart (worker processes or Ray tasks).

    A failed chunk does not stop the others; :meth:`scene_result` raises once all are in.
    """

    def __init__(self, ids: Iterable[int], where: str) -> None:
        """Collect the outcomes of chunks ``ids``, trained ``where`` (e.g. ``"on Ray"``)."""
        self.ids = tuple(ids)
        self.where = where
        self.results: dict[int, TrainResult] = {}
        self.peaks: dict[int, int | None] = {}
        self.failures: dict[int, str] = {}

    def __contains__(self, chunk: object) -> bool:
        return chunk in self.results or chunk in self.failures

    @property
    def finished(self) -> int:
        """Chunks with a result or a failure."""
        return len(self.results) + len(self.failures)

    def succeeded(self, chunk: int, result: TrainResult, peak_memory_bytes: int | None) -> None:
        """Record chunk ``chunk``'s result and the peak CUDA memory of its process (or None)."""
        self.results[chunk] = result
        self.peaks[chunk] = peak_memory_bytes

    def failed(self, chunk: int, why: str) -> None:
        """Record that chunk ``chunk`` failed; ``why``'s first line goes into the error."""
        self.failures[chunk] = why
        logger.warning("chunk %d failed %s: %s", chunk, self.where, why)

    def scene_result(self, start: float, *, hint: str) -> SceneTrainResult:
        """The scene's result (peak memory: the largest of one chunk's), started at ``start``.

        Raises:
            StageError: Chunks failed; the message names each with its error, then ``hint``.
        """
        if self.failures:
            names = ", ".join(
                f"chunk {c}: {why.splitlines()[0] if why else 'no reason given'}"
                for c, why in sorted(self.failures.items())
            )
            msg = f"{len(self.failures)} of {len(self.ids)} chunks failed {self.where} ({names}); "
            raise StageError(msg + hint)
        peaks = [p for p in self.peaks.values() if p is not None]
        return SceneTrainResult(
            chunks=tuple(self.results[c] for c in self.ids),
            seconds=time.perf_counter() - start,
            peak_memory_bytes=max(peaks) if peaks else None,
        )


# ----------------------------------------------------------------------------------- worker


def _worker(  # noqa: PLR0913, PLR0917 -- a spawned process's whole job, positional
    chunk: int,
    train: SceneTrainer,
    scene: SceneRecord,
    prep_dir: Path,
    options: TrainOptions,
    models_dir: Path,
    settings: tuple[int, int, float],
    messages: Any,
    go: Any,
) -> None:
    """Worker process: train chunk ``chunk`` and send ``("done", chunk, (result, peak))``.

    ``train`` is :func:`cam2sim.splat.train.train_scene`, passed in (by reference: spawn
    pickles a module-level function by name) so that this module does not import the trainer
    that calls it.

    ``settings`` is (log level, CPU threads: :func:`worker_cpus`, GiB of GPU memory to wait for
    before it loads: a retry after running out of memory, else 0). After loading the chunk and
    its first step (at the first progress report) it sends ``("ready", chunk, None)`` and waits
    for the event ``go`` (a training slot). Sends ``("progress", chunk, steps)`` while training and
    ``("failed", chunk, text)`` on an error (``Type: message``, then the traceback).
    """
    entered = time.perf_counter()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the parent, which ends us
    level, threads, wait_gib = settings
    root = logging.getLogger()
    root.handlers[:] = [LogForwarder(messages, chunk)]
    root.setLevel(level)
    try:
        import torch  # noqa: PLC0415

        imported = time.perf_counter() - entered
        torch.set_num_threads(threads)
        if wait_gib > 0 and options.device.startswith("cuda"):
            device = torch.device(options.device)
            # At most half the card: a small one never has 16 GiB free.
            need = min(wait_gib * 2**30, torch.cuda.get_device_properties(device).total_memory / 2)
            waited_s = wait_for_memory(lambda: int(torch.cuda.mem_get_info(device)[0]), need)
            logger.info(
                "chunk %d: waited %.0f s for %.1f GiB of free GPU memory before training again",
                chunk, waited_s, need / 2**30,
            )  # fmt: skip
        last = 0.0
        waited = False

        def report(task: str, completed: int, total: int | None) -> None:
            nonlocal last, waited
            del task
            if not waited:
                logger.info(
                    "chunk %d: ready %.1f s after its worker started (torch imported in %.1f s)",
                    chunk, time.perf_counter() - entered, imported,
                )  # fmt: skip
                messages.put(("ready", chunk, None))
                go.wait()
                waited = True
            now = time.perf_counter()
            if now - last >= _PROGRESS_SECONDS or (total is not None and completed >= total):
                last = now
                messages.put(("progress", chunk, completed))

        trained = train(
            prep_dir,
            options=options,
            chunk_ids=(chunk,),
            models_dir=models_dir,
            progress=report,
            scene=scene,
        )
        if options.device.startswith("cuda"):  # what SHARED_GPU_WORKER_GIB must cover
            logger.info(
                "chunk %d: GPU memory at its peak %.1f GiB allocated, %.1f GiB held by torch",
                chunk, torch.cuda.max_memory_allocated(options.device) / 2**30,
                torch.cuda.max_memory_reserved(options.device) / 2**30,
            )  # fmt: skip
        messages.put(("done", chunk, (trained.chunks[0], trained.peak_memory_bytes)))
    except Exception as err:  # noqa: BLE001 -- goes to the parent with the chunk id
        messages.put(("failed", chunk, f"{type(err).__name__}: {err}\n{traceback.format_exc()}"))


# ----------------------------------------------------------------------------------- parent


class _Pool:
    """The parent's side: start workers, read their messages, end them."""

    def __init__(
        self,
        chunk_ids: tuple[int, ...],
        job: tuple[Any, ...],
        in_flight: int,
        outcomes: ChunkOutcomes,
        steps_per_chunk: int,
        progress: ProgressCallback,
        *,
        cpus: int | None,
    ) -> None:
        import torch.multiprocessing as tmp  # noqa: PLC0415

        # Each worker's pools (:func:`worker_cpus`; None: as this process's). On the CPU only
        # torch's is sized, in the worker: numba's compositing splits its tiles by its threads,
        # and a chunk's model must not depend on whether it trained in a worker.
        self.cpus = cpus
        self.context = tmp.get_context("spawn")
        self.messages: Any = self.context.Queue()
        self.order = tuple(chunk_ids)
        self.waiting = list(chunk_ids)
        self.job = job
        self.in_flight = in_flight
        self.running: dict[int, Any] = {}
        # One worker more than in_flight loads its chunk while the others train, then waits
        # for a slot: start-up (spawn, imports, views, seeding) is hidden behind training.
        self.ahead = 1 if len(chunk_ids) > in_flight else 0
        self.go: dict[int, Any] = {}
        self.ready: list[int] = []
        self.training: set[int] = set()
        self.outcomes = outcomes
        self.steps = dict.fromkeys(chunk_ids, 0)
        self.steps_per_chunk = steps_per_chunk
        self.progress = progress
        self.reported = -1
        self.retries = dict.fromkeys(chunk_ids, 0)
        self.restarting: set[int] = set()  # out of GPU memory: trains again once its worker ends

    def run(self) -> None:
        try:
            self._report()
            while self.waiting or self.running:
                self._start_workers()
                self._read(block=True)
                self._reap()
        except BaseException:
            self._terminate()
            raise
        finally:
            self.messages.close()
            self.messages.join_thread()

    def _start_workers(self) -> None:
        while self.waiting and len(self.running) < self.in_flight + self.ahead:
            chunk = self.waiting.pop(0)
            self.go[chunk] = self.context.Event()
            wait_gib = SHARED_GPU_WORKER_GIB if self.retries[chunk] else 0.0
            *job, settings = self.job
            process = self.context.Process(
                target=_worker,
                args=(chunk, *job, (*settings, wait_gib), self.messages, self.go[chunk]),
                name=f"splat-chunk-{chunk:02d}",
                daemon=True,
            )
            with children_allotted(self.cpus):
                process.start()
            self.running[chunk] = process
            logger.info("chunk %d: loading in worker process %d", chunk, process.pid)

    def _grant(self) -> None:
        """Let ready workers train, in the pool's order, at most ``in_flight`` at a time.

        The slots belong to the first ``in_flight`` chunks of the order that have not finished:
        a chunk that loads faster does not take the slot of a longer one still loading (a
        street's smallest chunk, seeded first, used to train before its largest, which then
        trained alone at the end).
        """
        pending = [c for c in self.order if c not in self.outcomes]
        for chunk in pending[: self.in_flight]:
            if chunk in self.ready and len(self.training) < self.in_flight:
                self.ready.remove(chunk)
                self.training.add(chunk)
                self.go[chunk].set()

    def _read(self, *, block: bool) -> None:
        """Handle every message there is (waiting up to a poll interval for the first)."""
        timeout: float | None = _POLL_SECONDS if block else None
        while True:
            try:
                kind, chunk, payload = (
                    self.messages.get(timeout=timeout) if timeout else self.messages.get_nowait()
                )
            except queue.Empty:
                break
            timeout = None
            if kind == "log":
                logging.getLogger(payload.name).handle(payload)
            elif kind == "ready":
                self.ready.append(chunk)
                self._grant()
            elif kind == "progress":
                self.steps[chunk] = max(self.steps[chunk], int(payload))
            elif kind == "done":
                self.outcomes.succeeded(chunk, *payload)
                self.steps[chunk] = self.steps_per_chunk
            elif kind == "failed":
                self._failed(chunk, str(payload))
        self._report()

    def _failed(self, chunk: int, why: str) -> None:
        """Record ``chunk``'s failure, or, out of GPU memory, let it train again (one slot fewer).

        The memory was held by the processes beside it (this street's other chunks, other
        streets' on a shared GPU); with a slot fewer it waits for one of this street's to end,
        so a street is not lost to a moment's crowding (five benchmark worlds on one H100 lost
        two streets' splats, each after minutes of training their other chunks).
        """
        if _out_of_memory(why) and self.retries[chunk] < OUT_OF_MEMORY_RETRIES:
            self.retries[chunk] += 1
            self.restarting.add(chunk)  # its steps stay counted: the progress never goes back
            self.in_flight = max(1, self.in_flight - 1)
            logger.warning(
                "chunk %d ran out of GPU memory (%s); it trains again from its start, "
                "%d chunk(s) at a time from now (retry %d of %d)",
                chunk, why.splitlines()[0][:200], self.in_flight, self.retries[chunk],
                OUT_OF_MEMORY_RETRIES,
            )  # fmt: skip
            return
        self.outcomes.failed(chunk, why)
        self.steps[chunk] = self.steps_per_chunk

    def _reap(self) -> None:
        """Join finished workers; a worker that died without a word failed."""
        for chunk, process in list(self.running.items()):
            if chunk in self.restarting:
                if not process.is_alive():
                    self._restart(chunk, process)
                continue
            if chunk not in self.outcomes and not process.is_alive():
                self._read(block=False)  # its last messages were flushed before it exited
                if chunk not in self.outcomes:
                    why = f"its worker process exited with code {process.exitcode} without a "
                    why += "result (killed for memory?)"
                    self.outcomes.failed(chunk, why)
                    self.steps[chunk] = self.steps_per_chunk
            if chunk in self.outcomes:
                self._release(chunk, process)
                self._grant()
        self._report()

    def _release(self, chunk: int, process: Any) -> None:
        """Join ``chunk``'s ended worker and free its place (running, ready, training)."""
        process.join()
        process.close()
        del self.running[chunk]
        self.training.discard(chunk)
        if chunk in self.ready:
            self.ready.remove(chunk)

    def _restart(self, chunk: int, process: Any) -> None:
        """Put ``chunk``, whose worker ran out of GPU memory and has ended, back to be started."""
        self._release(chunk, process)
        self.restarting.discard(chunk)
        self.waiting.insert(0, chunk)

    def _report(self) -> None:
        done = sum(self.steps.values())
        if done != self.reported:
            self.reported = done
            self.progress("splat steps", done, len(self.steps) * self.steps_per_chunk)

    def _terminate(self) -> None:
        if self.running:
            logger.warning("ending %d chunk worker process(es)", len(self.running))
        end_processes(self.running.values())
        self.running.clear()


def wait_for_memory(
    free_bytes: Callable[[], int],
    need_bytes: float,
    *,
    timeout_s: float = _MEMORY_WAIT_S,
    poll_s: float = _MEMORY_POLL_S,
    sleep: Callable[[float], None] = time.sleep,
    clock: Callable[[], float] = time.monotonic,
) -> float:
    """Wait until ``free_bytes()`` reaches ``need_bytes`` or ``timeout_s`` passed; seconds waited.

    A chunk that ran out of GPU memory waits so before it loads again: the memory was held by
    processes beside it, which free it as their chunks end (minutes), and a retry into the same
    crowd would fail the same way.
    """
    start = clock()
    while free_bytes() < need_bytes and clock() - start < timeout_s:
        sleep(poll_s)
    return clock() - start


def _out_of_memory(why: str) -> bool:
    """Whether a worker's failure text (``Type: message``, traceback) is CUDA out of memory."""
    first = why.splitlines()[0] if why else ""
    return first.startswith("OutOfMemoryError") or "CUDA out of memory" in first


def largest_first(scene: SceneRecord, chunk_ids: tuple[int, ...]) -> tuple[int, ...]:
    """``chunk_ids`` longest chunk first (metres of route, then frames; ties keep their order).

    A chunk's step costs what its Gaussians cost, and they grow with the street it covers: the
    longest chunks start first, so that the last round of slots holds the shortest (the
    longest-processing-time rule). On Aguascalientes route 0 the 183-frame end chunk (149k
    starting Gaussians) trained before the 524k-Gaussian first chunk, which then trained for
    5.5 minutes after it (docs/benchmarks.md, "The GPU demo's preset on four untuned streets").
    """
    known = {c.id: c for c in scene.chunks}

    def size(chunk: int) -> tuple[float, int]:
        record = known.get(chunk)
        return (record.end_m - record.start_m, len(record.frames)) if record else (0.0, 0)

    return tuple(sorted(chunk_ids, key=size, reverse=True))


def worker_cpus(cpus: int, in_flight: int, *, cuda: bool) -> int:
    """CPU threads of each chunk worker when ``in_flight`` train at once on ``cpus`` CPUs.

    On the CPU the workers share the CPUs. On CUDA a worker's host loop keeps one core busy
    and its pools are idle while it trains, but they start at one thread a core and spin on
    every NumPy or torch call on the CPU (seeding its Gaussians): the workers and this process
    (and DAVE-2's training beside it) take a share each
    (:func:`~cam2sim.core.machine.children_allotted`).
    """
    return max(1, cpus // (in_flight + 1 if cuda else in_flight))


def cuda_slots(n_chunks: int, gpu_gib: float) -> int:
    """How many of ``n_chunks`` equal chunks to train at once on one GPU of ``gpu_gib`` GiB.

    Chunks of equal steps run in rounds of ``k`` (a new one starts as one ends), the last round
    holding what is left: a chunk left to train alone runs at half the GPU's pace
    (:data:`CUDA_SLOT_RATES`). The rule takes the ``k`` whose rounds end first, the fewest
    slots on a tie: 5 chunks train 3 then 2 (4.9 rounds of two's time) rather than 2, 2, then
    1 alone (6); 4 chunks train 2 and 2.

    Args:
        n_chunks: Chunks to train (at least 1).
        gpu_gib: The GPU's memory in GiB (three slots need :data:`MIN_GIB_FOR_THREE`).

    Returns:
        Slots, 1 to 3 (never more than the chunks).
    """
    n = max(1, n_chunks)
    most = 3 if gpu_gib >= MIN_GIB_FOR_THREE else 2

    def makespan(k: int) -> float:
        full, rest = divmod(n, k)
        span = full * k / CUDA_SLOT_RATES[k]
        return span + (rest / CUDA_SLOT_RATES[rest] if rest else 0.0)

    candidates = range(1, min(most, n) + 1)
    return min(candidates, key=lambda k: (round(makespan(k), 6), k))


def shared_gpu_slots(n_chunks: int, gpu_gib: float, sharers: int) -> int:
    """Chunks to train at once on a GPU of ``gpu_gib`` GiB that ``sharers`` processes share.

    Two where each sharer's part of the memory holds two workers of
    :data:`SHARED_GPU_WORKER_GIB` (a chunk left alone does not leave a shared GPU idle), else
    one: the sharers' workers together must fit the card.
    """
    fits = int(gpu_gib / max(1, sharers) // SHARED_GPU_WORKER_GIB)
    return max(1, min(2, n_chunks, fits))


def train_chunks_in_processes(
    train: SceneTrainer,
    prep_dir: Path,
    scene: SceneRecord,
    chunk_ids: tuple[int, ...],
    options: TrainOptions,
    *,
    models_dir: Path,
    in_flight: int,
    progress: ProgressCallback = no_progress,
) -> SceneTrainResult:
    """Train ``chunk_ids`` in worker processes, ``in_flight`` at a time, on one device.

    ``options`` should name the resolved device and backend; each worker runs
    ``train(prep_dir, chunk_ids=(chunk,), options=options with concurrent_chunks=1)``.

    Args:
        train: :func:`cam2sim.splat.train.train_scene` (a module-level function).
        prep_dir: ``WS/splat/prep``.
        scene: Its scene record.
        chunk_ids: Chunks to train (results come back in this order).
        options: Training options.
        models_dir: Output folder.
        in_flight: Most worker processes at a time.
        progress: Called with ``("splat steps", done, cap)`` (cap = chunks times max_steps).

    Returns:
        Per-chunk results (peak memory: the largest of one worker's).

    Raises:
        StageError: Chunks failed (raised after the others finished, naming each).
        BackendUnavailableError: gsplat's CUDA extension does not build.
    """
    start = time.perf_counter()
    if options.backend == "gsplat":
        build_gsplat()  # here, once, so spawned workers find it built
    worker_options = dataclasses.replace(options, concurrent_chunks=1)
    level = logging.getLogger("cam2sim").getEffectiveLevel()
    threads = worker_cpus(available_cpus(), in_flight, cuda=options.device != "cpu")
    job = (train, scene, Path(prep_dir), worker_options, Path(models_dir), (level, threads))
    outcomes = ChunkOutcomes(chunk_ids, "in worker processes")
    logger.info(
        "training %d chunk(s) in worker processes, %d at a time, on %s (%d CPU threads each)",
        len(chunk_ids),
        in_flight,
        options.device,
        threads,
    )
    pool = _Pool(
        largest_first(scene, chunk_ids),
        job,
        in_flight,
        outcomes,
        options.max_steps,
        progress,
        cpus=None if options.device == "cpu" else threads,
    )
    pool.run()
    hint = "see the log above for each traceback, fix the cause, and train again"
    return outcomes.scene_result(start, hint=hint)
