"""A function in its own process beside the caller: value, progress, logs, errors, stopping."""

from __future__ import annotations

import logging
import os
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from cam2sim.core.errors import StageError
from cam2sim.core.sidecar import Sidecar

if TYPE_CHECKING:
    from cam2sim.core.progress import ProgressCallback


def _count(n: int, *, progress: ProgressCallback) -> dict[str, int]:
    logging.getLogger("cam2sim.sidecar-test").warning("counting to %d in %d", n, os.getpid())
    for k in range(n + 1):
        progress("counting", k, n)
    return {"n": n, "pid": os.getpid()}


def _fail(why: str, *, progress: ProgressCallback) -> None:
    del progress
    raise ValueError(why)


def _die(*, progress: ProgressCallback) -> None:
    del progress
    os._exit(3)


def _sleep(seconds: float, *, progress: ProgressCallback) -> None:
    progress("sleeping", 0, 1)
    time.sleep(seconds)


def test_the_value_progress_and_logs_come_back(caplog: pytest.LogCaptureFixture) -> None:
    seen: list[tuple[str, int, int | None]] = []
    threads: set[str] = set()

    def report(task: str, completed: int, total: int | None) -> None:
        seen.append((task, completed, total))
        threads.add(threading.current_thread().name)

    with caplog.at_level(logging.WARNING, logger="cam2sim"):
        side = Sidecar(_count, (50,), progress=report, name="counter")
        value = side.result()
    assert value["n"] == 50
    assert value["pid"] != os.getpid()  # it ran in its own process
    assert seen[0] == ("counting", 0, 50)
    assert seen[-1] == ("counting", 50, 50)  # a task's end always comes through
    assert [c for _, c, _ in seen] == sorted(c for _, c, _ in seen)
    assert threads == {"counter-reader"}
    assert f"counting to 50 in {value['pid']}" in caplog.text


def test_an_error_in_the_process_is_raised_here_with_its_message() -> None:
    side = Sidecar(_fail, ("no frames in WS/dataset",), name="trainer")
    with pytest.raises(StageError, match=r"trainer .*failed: ValueError: no frames in WS/dataset"):
        side.result()


def test_a_process_that_dies_without_a_word_is_a_failure() -> None:
    with pytest.raises(StageError, match="exited with code 3 without a result"):
        Sidecar(_die, (), name="dier").result()


def test_stop_ends_the_process_at_once() -> None:
    started = time.perf_counter()
    side = Sidecar(_sleep, (60.0,), name="sleeper")
    side.stop()
    side.stop()  # idempotent
    assert time.perf_counter() - started < 30.0
    with pytest.raises(StageError, match="stopped"):
        side.result()


def _pool_of_sleepers(pids_file: str, *, progress: ProgressCallback) -> None:
    """Start a process pool of two sleeping workers, write their pids, wait for them."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = [pool.submit(time.sleep, 60.0) for _ in range(2)]
        while len(multiprocessing.active_children()) < 2:
            time.sleep(0.05)
        pids = " ".join(str(c.pid) for c in multiprocessing.active_children())
        Path(pids_file).write_text(pids, encoding="utf-8")
        progress("pool", 1, 2)
        for future in futures:
            future.result()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return Path(f"/proc/{pid}").exists() and "Z" not in _state(pid)


def _state(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[1].split()[0]
    except (FileNotFoundError, IndexError):
        return "Z"


def test_stop_ends_the_processes_the_sidecar_started(tmp_path: Path) -> None:
    """A sidecar that runs a process pool (not a daemon, so it may) takes its workers along."""
    pids_file = tmp_path / "pids"
    side = Sidecar(_pool_of_sleepers, (str(pids_file),), name="pool", daemon=False)
    deadline = time.perf_counter() + 60.0
    while not pids_file.is_file() and time.perf_counter() < deadline:
        time.sleep(0.1)
    time.sleep(0.2)  # the file is whole
    workers = [int(p) for p in pids_file.read_text(encoding="utf-8").split()]
    assert len(workers) == 2
    assert all(_alive(pid) for pid in workers)
    side.stop()
    deadline = time.perf_counter() + 15.0
    while any(_alive(pid) for pid in workers) and time.perf_counter() < deadline:
        time.sleep(0.1)
    assert not any(_alive(pid) for pid in workers)  # no worker left sleeping on


def _pools(*, progress: ProgressCallback) -> dict[str, object]:
    del progress
    import torch

    return {"omp": os.environ.get("OMP_NUM_THREADS"), "torch": torch.get_num_threads()}


def test_a_sidecar_given_cpus_sizes_its_pools_to_them(monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("torch")
    monkeypatch.setattr(os, "sched_getaffinity", lambda _pid: set(range(8)), raising=False)
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "7")
    pools = Sidecar(_pools, (), name="pools", cpus=1).result()
    assert pools == {"omp": "1", "torch": 1}  # its torch started with one thread
    # This process's variables are as they were: absent stays absent, set keeps its value.
    assert "OMP_NUM_THREADS" not in os.environ
    assert os.environ["OPENBLAS_NUM_THREADS"] == "7"
