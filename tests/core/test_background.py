"""BackgroundJobs: results in submission order, bounded in flight, errors in the caller."""

from __future__ import annotations

import threading
import time

import pytest

from cam2sim.core.background import BackgroundJobs


def test_results_come_back_in_submission_order() -> None:
    def slow_square(n: int) -> int:
        time.sleep(0.002 * (10 - n))  # the first jobs finish last
        return n * n

    with BackgroundJobs[int](4) as jobs:
        for n in range(10):
            jobs.submit(slow_square, n)
        assert jobs.results() == [n * n for n in range(10)]


def test_no_more_than_in_flight_jobs_are_out() -> None:
    gate = threading.Event()
    started: list[int] = []

    def held(n: int) -> int:
        started.append(n)
        gate.wait(5)
        return n

    jobs = BackgroundJobs[int](2, in_flight=2)
    try:
        jobs.submit(held, 0)
        jobs.submit(held, 1)
        waiter = threading.Thread(target=jobs.submit, args=(held, 2))
        waiter.start()
        time.sleep(0.1)
        assert waiter.is_alive()  # the third submit waits for the oldest job
        assert jobs.collected == 0
        gate.set()
        waiter.join(5)
        assert not waiter.is_alive()
        assert jobs.results() == [0, 1, 2]
    finally:
        gate.set()
        jobs.close()


def test_a_failed_job_raises_in_the_caller_and_later_jobs_are_cancelled() -> None:
    ran: list[int] = []

    def job(n: int) -> int:
        if n == 1:
            msg = "cannot write frame 1"
            raise OSError(msg)
        time.sleep(0.01)
        ran.append(n)
        return n

    def submit_all() -> None:
        with BackgroundJobs[int](1, in_flight=50) as jobs:
            for n in range(40):
                jobs.submit(job, n)

    with pytest.raises(OSError, match="frame 1"):
        submit_all()
    assert len(ran) < 39  # the queued jobs after the failure did not all run


def test_the_callers_error_waits_for_running_jobs() -> None:
    done: list[int] = []

    def job(n: int) -> None:
        time.sleep(0.05)
        done.append(n)

    def render_fails() -> None:
        with BackgroundJobs[None](2) as jobs:
            jobs.submit(job, 0)
            jobs.submit(job, 1)
            time.sleep(0.01)  # both are running
            msg = "render failed"
            raise RuntimeError(msg)

    with pytest.raises(RuntimeError, match="render failed"):
        render_fails()
    assert sorted(done) == [0, 1]  # no thread still writing after the block


def test_imap_reads_ahead_in_order_and_raises_at_the_failed_item() -> None:
    started: list[int] = []

    def read(n: int) -> int:
        started.append(n)
        if n == 7:
            msg = "frame 7 is not an image"
            raise ValueError(msg)
        time.sleep(0.001 * (n % 3))
        return 10 * n

    with BackgroundJobs[int](2, in_flight=3) as jobs:
        got = jobs.imap(read, range(20))
        assert [next(got) for _ in range(2)] == [0, 10]
        time.sleep(0.05)
        assert len(started) <= 2 + 3 + 1  # no more than in_flight ahead of the consumer
        assert [next(got) for _ in range(5)] == [20, 30, 40, 50, 60]
        with pytest.raises(ValueError, match="frame 7"):
            next(got)
