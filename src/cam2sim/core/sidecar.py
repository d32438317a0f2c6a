"""One function run in its own process beside the caller's work, reporting as if it ran here.

``cam2sim run`` on a GPU trains DAVE-2 while the splat trains: the two share nothing but the
workspace's manifest (locked while written, :meth:`~cam2sim.core.workspace.Workspace.record_stage`)
and the GPU, and DAVE-2's 100 s on KITTI 03 then hide behind the splat's CPU-bound preparation.
A process, not a thread: both seed torch's global generators, which a thread would share.

    side = Sidecar(train_policy, (root, options), progress=report, name="ads")
    trained = run_splat(...)        # this process
    result = side.result()          # waits; the function's value, or its error as StageError

The process is spawned (CUDA cannot be forked), ignores Ctrl-C (the caller decides: it calls
:meth:`Sidecar.stop`), and sends its progress (at most every 0.1 s, and every task's end), its
log records and its result or error through one queue; a thread of the caller hands progress to
``progress`` and log records to this process's loggers as they come. ``target`` must be a
module-level function (spawn pickles it by name) taking ``progress=`` as its last argument;
its arguments and value must pickle.
"""

from __future__ import annotations

import logging
import logging.handlers
import os
import queue
import signal
import threading
import time
import traceback
from typing import TYPE_CHECKING, Any

from cam2sim.core.errors import StageError
from cam2sim.core.machine import children_allotted
from cam2sim.core.progress import ProgressCallback, no_progress

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable

__all__ = ["LogForwarder", "Sidecar", "end_processes"]

logger = logging.getLogger(__name__)

_PROGRESS_SECONDS = 0.1  # the process reports a task's count at most this often
_POLL_SECONDS = 0.5  # the reading thread checks this often whether the process died
_JOIN_SECONDS = 10.0  # how long a terminated process may take to go


class LogForwarder(logging.handlers.QueueHandler):
    """Sends a child process's log records to its parent as ``("log", *tag, record)``.

    The parent hands each record to its own logger of the same name
    (``logging.getLogger(record.name).handle(record)``). ``tag`` says which child sent it (the
    splat's chunk workers tag theirs with the chunk id; a :class:`Sidecar` has none).
    """

    def __init__(self, messages: Any, *tag: object) -> None:
        super().__init__(messages)
        self.tag = tag

    def enqueue(self, record: logging.LogRecord) -> None:
        """Put ``("log", *tag, record)`` on the queue without waiting."""
        self.queue.put_nowait(("log", *self.tag, record))


def end_processes(processes: Iterable[Any]) -> None:
    """Terminate ``processes`` together, then wait for each (killed after 10 s if still there)."""
    running = [p for p in processes if p.is_alive()]
    for process in running:
        process.terminate()
    for process in running:
        process.join(_JOIN_SECONDS)
        if process.is_alive():
            process.kill()
            process.join()


def _end_with_children(signum: int, frame: object) -> None:
    """SIGTERM (:meth:`Sidecar.stop`): end the processes this one started, then this one.

    Its pool's workers would otherwise live on: they ignore Ctrl-C as it does, and wait for
    work from a queue they hold both ends of.
    """
    del frame
    import multiprocessing  # noqa: PLC0415

    end_processes(multiprocessing.active_children())
    os._exit(128 + signum)


def _main(target: Callable[..., Any], args: tuple[Any, ...], messages: Any, level: int) -> None:
    """The spawned process: run ``target(*args, progress=...)``; send its value or error."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the caller, which stops us
    signal.signal(signal.SIGTERM, _end_with_children)
    root = logging.getLogger()
    root.handlers[:] = [LogForwarder(messages)]
    root.setLevel(level)
    last: dict[str, float] = {}

    def report(task: str, completed: int, total: int | None) -> None:
        now = time.perf_counter()
        ended = total is not None and completed >= total
        if ended or task not in last or now - last[task] >= _PROGRESS_SECONDS:
            last[task] = now
            messages.put(("progress", (task, completed, total)))

    try:
        value = target(*args, progress=report)
    except BaseException as err:  # noqa: BLE001 -- goes to the caller, which raises it
        messages.put(("error", f"{type(err).__name__}: {err}\n{traceback.format_exc()}"))
    else:
        messages.put(("result", value))


class Sidecar:
    """``target(*args, progress=...)`` running in a spawned process from construction on.

    Args:
        target: A module-level function; its last parameter is ``progress``.
        args: Its other arguments (pickled).
        progress: Receives the function's progress here, from a reading thread: give one that
            may be called from another thread (or serialise it).
        name: The process's name (in ``ps`` and the logs).
        cpus: CPU threads of its pools (:func:`~cam2sim.core.machine.children_allotted`);
            None: this process's.
        daemon: Start it as a daemon process (ended with this one); a daemon process may
            start no processes of its own, so a function that does (a pool) needs False.
            :meth:`stop` ends it either way.
    """

    def __init__(
        self,
        target: Callable[..., Any],
        args: tuple[Any, ...],
        *,
        progress: ProgressCallback = no_progress,
        name: str = "cam2sim-sidecar",
        cpus: int | None = None,
        daemon: bool = True,
    ) -> None:
        import multiprocessing  # noqa: PLC0415

        context = multiprocessing.get_context("spawn")
        self.name = name
        self._messages: Any = context.Queue()
        self._progress = progress
        self._outcome: tuple[str, Any] | None = None
        self._stopping = threading.Event()
        self._process = context.Process(
            target=_main,
            args=(target, args, self._messages, logging.getLogger().getEffectiveLevel()),
            name=name,
            daemon=daemon,
        )
        with children_allotted(cpus):
            self._process.start()
        logger.info("%s: started in process %d", name, self._process.pid)
        self._reader = threading.Thread(target=self._read, name=f"{name}-reader", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        """Hand on messages until the result or error comes, or the process is gone."""
        while self._outcome is None:
            try:
                kind, payload = self._messages.get(timeout=_POLL_SECONDS)
            except queue.Empty:
                if not self._process.is_alive() and self._messages.empty():
                    code = self._process.exitcode
                    why = f"its process exited with code {code} without a result"
                    stopped = self._stopping.is_set()
                    self._outcome = (
                        "error",
                        "stopped" if stopped else f"{why} (killed for memory?)",
                    )
                continue
            if kind == "progress":
                self._progress(*payload)
            elif kind == "log":
                logging.getLogger(payload.name).handle(payload)
            else:
                self._outcome = (kind, payload)

    def result(self) -> Any:
        """Wait for the function; return its value.

        Raises:
            StageError: It raised (its type, message and traceback's first line are in the
                message), or its process died.
        """
        self._reader.join()
        self._process.join()
        self._messages.close()
        assert self._outcome is not None  # the reader ends only with one
        kind, payload = self._outcome
        if kind == "error":
            first = str(payload).splitlines()[0] if payload else "no reason given"
            logger.debug("%s failed:\n%s", self.name, payload)
            msg = f"{self.name} (in its own process) failed: {first}"
            raise StageError(msg)
        return payload

    def stop(self) -> None:
        """End the process now (the caller was interrupted or failed); idempotent."""
        self._stopping.set()
        if self._process.is_alive():
            logger.warning("%s: ending its process", self.name)
            end_processes([self._process])
        self._reader.join()
