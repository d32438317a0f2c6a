"""One campaign run in a worker process: the drive, its log, its time limit.

:func:`execute` is what the local pool and Ray run for every spec. It never raises for a failed
run: the run's output (stdout, stderr, log records, the traceback, and a fault handler's
traceback if the process dies) goes to the run's log file, and a :class:`RunOutcome` says what
happened. The time limit is a ``SIGALRM`` timer in the worker, so a run that overruns ends with
its partial run folder discarded (``cam2sim drive`` builds runs under a temporary name); a
run stuck in native code past the limit is ended by killing its worker.
"""

from __future__ import annotations

import contextlib
import errno
import faulthandler
import logging
import os
import signal
import sys
import threading
import time
import traceback
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cam2sim.campaign.state import RunOutcome, RunStatus
from cam2sim.core.cluster import worker_place
from cam2sim.core.machine import keep_to_allotment
from cam2sim.core.workspace import Workspace
from cam2sim.stages.runs import DriveOptions, default_judge, drive

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator
    from typing import TextIO

    from cam2sim.campaign.plan import RunSpec

__all__ = ["RunTimeoutError", "execute", "run_logged"]


class RunTimeoutError(BaseException):
    """The run's time limit passed (a BaseException: ``except Exception`` must not swallow it)."""


@contextlib.contextmanager
def _captured(log: TextIO) -> Iterator[None]:
    """Send fd 1 and 2, Python's streams, log records and fatal-signal tracebacks to ``log``."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    os.dup2(log.fileno(), 1)
    os.dup2(log.fileno(), 2)
    handler = logging.StreamHandler(log)
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    level = root.level
    root.addHandler(handler)
    root.setLevel(logging.INFO)
    faulthandler.enable(log)
    try:
        yield
    finally:
        faulthandler.disable()
        root.removeHandler(handler)
        root.setLevel(level)
        log.flush()
        sys.stdout.flush()
        sys.stderr.flush()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in saved:
            os.close(fd)


HARD_LIMIT_GRACE_S = 30.0
"""How long past its time limit a run stuck where Python cannot interrupt it may go on."""


def _kill(seconds: float) -> None:
    """End this worker process: the run is stuck in code that ignores the timeout signal."""
    msg = (
        f"\nstill running {HARD_LIMIT_GRACE_S:g} s past timeout_s={seconds:g}; killing the worker\n"
    )
    os.write(2, msg.encode())
    os._exit(70)


@contextlib.contextmanager
def _deadline(seconds: float | None) -> Iterator[None]:
    """Raise :class:`RunTimeoutError` in this (main) thread after ``seconds``.

    A run stuck in native code (no Python bytecode runs, so the signal handler cannot) is
    ended ``HARD_LIMIT_GRACE_S`` later by killing the worker process; the executor then records
    it as crashed, its log ending with why.
    """
    if seconds is None or not hasattr(signal, "setitimer"):
        yield
        return
    limit = seconds

    def expire(signum: int, frame: Any) -> None:
        del signum, frame
        msg = f"the run took longer than timeout_s={limit:g}"
        raise RunTimeoutError(msg)

    try:
        before = signal.signal(signal.SIGALRM, expire)
    except ValueError:  # not the main thread: the caller's own limit applies
        yield
        return
    watchdog = threading.Timer(limit + HARD_LIMIT_GRACE_S, _kill, args=(limit,))
    watchdog.daemon = True
    watchdog.start()
    signal.setitimer(signal.ITIMER_REAL, limit)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, before)
        watchdog.cancel()


def _drive(spec: RunSpec) -> str:
    """Run the spec with ``cam2sim drive``'s code; return the run id."""
    ws = Workspace.open(Path(spec.workspace_path))
    d = spec.drive
    judge = default_judge(ws) if d.judge == "auto" else d.judge  # "auto": as cam2sim run
    options = DriveOptions(
        policy=spec.policy_arg,
        camera=spec.camera,
        runs=1,
        speed_kmh=spec.speed_kmh,
        seed=spec.seed,
        policy_every=d.policy_every,
        image_size=d.image_size,
        max_steps=d.max_steps,
        save_frames=d.save_frames,
        video=d.video,
        steering_noise_std=d.steering_noise_std,
        recorded_speed=d.recorded_speed and spec.speed_kmh is None,
        judge=judge,
        start_offset=(spec.lateral_m, spec.heading_deg),
    )
    (result,) = drive(ws, options=options)
    return result.run_id


def _why(err: Exception) -> str:
    """One line for a failed run's error; a full disk says what to do."""
    if isinstance(err, OSError) and err.errno == errno.ENOSPC:
        where = f" ({err.filename})" if err.filename else ""
        return (
            f"the disk is full{where}: free space there and run the campaign again "
            "(it resumes: finished runs are kept, this one was discarded)"
        )
    return f"{type(err).__name__}: {err}"


def execute(spec: RunSpec, log_path: str, timeout_s: float | None) -> RunOutcome:
    """Run one spec; record its output in ``log_path``; never raise for a failed run."""
    return run_logged(spec.spec_id, str(spec), lambda: _drive(spec), log_path, timeout_s)


def run_logged(
    spec_id: str,
    what: str,
    body: Callable[[], str],
    log_path: str,
    timeout_s: float | None,
) -> RunOutcome:
    """Run ``body`` (it returns the run id) with its output in ``log_path`` and a time limit.

    The same harness for every kind of campaign job (a drive, a benchmark world): never raises
    for a failed job; the outcome says ``done``, ``failed`` or ``timeout``.
    """
    started = time.perf_counter()
    keep_to_allotment()  # a Ray task's thread pools: its CPUs, not the node's
    path = Path(log_path)
    path.parent.mkdir(parents=True, exist_ok=True)
    run_id = error = None
    status: RunStatus = "crashed"
    with path.open("w", encoding="utf-8") as log:
        log.write(f"spec {spec_id}: {what}\npid {os.getpid()}\n")
        log.flush()
        with _captured(log):
            try:
                with _deadline(timeout_s):
                    run_id = body()
                status = "done"
            except RunTimeoutError as err:
                status, error = "timeout", str(err)
                traceback.print_exc(file=log)
            except Exception as err:  # noqa: BLE001 - any failure of a run is recorded, not raised
                status, error = "failed", _why(err)
                traceback.print_exc(file=log)
        log.write(f"{status} after {time.perf_counter() - started:.2f} s\n")
    return RunOutcome(
        spec_id=spec_id,
        status=status,
        run_id=run_id,
        seconds=time.perf_counter() - started,
        error=error,
        log=str(path),
        place=worker_place(),
    )
