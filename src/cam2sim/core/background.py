"""Work on worker threads behind the caller's own: encoding, writing and scoring images.

OpenCV and NumPy let go of the GIL in their heavy calls, so a frame's PNG encoding, its SSIM or
its undistortion can run beside the next frame's render on the GPU (or the next frame's
reading). :class:`BackgroundJobs` keeps a bounded number of jobs in flight (memory stays
bounded: each job holds its images), gives the results back in the order the jobs were
submitted, and raises the first job's error in the caller's thread; on an error, or when the
caller's own code raises, jobs not yet started are cancelled and running ones are waited for, so
no thread is left writing after the caller returns.

    with BackgroundJobs() as jobs:
        for frame in frames:
            image = render(frame)              # this thread (the GPU)
            jobs.submit(write_png, path, image)  # a worker thread
    # every write has finished (or the first error was raised)

:meth:`BackgroundJobs.imap` reads ahead instead: ``for image in jobs.imap(read_rgb, paths)``.
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from typing import TYPE_CHECKING, Any, Generic, TypeVar

from cam2sim.core.machine import available_cpus

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Iterator
    from types import TracebackType

__all__ = ["MAX_WORKERS", "BackgroundJobs"]

T = TypeVar("T")

MAX_WORKERS = 8
"""Default thread cap: each job in flight holds its images (a 4K frame is 25 MB), and eight
threads already hide PNG encoding behind a GPU's renders."""


class BackgroundJobs(Generic[T]):
    """A bounded queue of jobs on worker threads, their results in submission order.

    Args:
        workers: Threads; None: the CPUs this process may use
            (:func:`~cam2sim.core.machine.available_cpus`), at most :data:`MAX_WORKERS`.
        in_flight: Jobs submitted and not yet collected before :meth:`submit` waits for the
            oldest; None: twice ``workers``.
        name: Thread-name prefix (seen in profilers and tracebacks).
    """

    def __init__(
        self, workers: int | None = None, *, in_flight: int | None = None, name: str = "cam2sim"
    ) -> None:
        self.workers = max(
            1, workers if workers is not None else min(available_cpus(), MAX_WORKERS)
        )
        self.in_flight = max(1, in_flight if in_flight is not None else 2 * self.workers)
        self._pool = ThreadPoolExecutor(max_workers=self.workers, thread_name_prefix=name)
        self._pending: list[Future[T]] = []
        self._done: list[T] = []

    def submit(self, fn: Callable[..., T], /, *args: Any) -> None:
        """Run ``fn(*args)`` on a worker; first collect the oldest job if too many are out.

        Raises:
            Exception: The error of a job collected here.
        """
        self._pending.append(self._pool.submit(fn, *args))
        while len(self._pending) > self.in_flight:
            self._done.append(self._pending.pop(0).result())

    def imap(self, fn: Callable[..., T], items: Iterable[Any]) -> Iterator[T]:
        """``fn(item)`` for each item, computed ahead on the workers, yielded in order.

        At most ``in_flight`` results wait to be taken (reading frames ahead of the thread
        that uses them). Jobs given to :meth:`submit` meanwhile share the workers and are
        collected apart, by :meth:`submit` and :meth:`results`.

        Raises:
            Exception: The first failed job's error, when its turn comes.
        """
        ahead: list[Future[T]] = []
        for item in items:
            ahead.append(self._pool.submit(fn, item))
            if len(ahead) > self.in_flight:
                yield ahead.pop(0).result()
        while ahead:
            yield ahead.pop(0).result()

    @property
    def collected(self) -> int:
        """Jobs finished and collected so far (for progress)."""
        return len(self._done)

    def results(self) -> list[T]:
        """Wait for every job; their results in submission order.

        Raises:
            Exception: The first failed job's error.
        """
        while self._pending:
            self._done.append(self._pending.pop(0).result())
        return list(self._done)

    def close(self) -> None:
        """Cancel the jobs not started, wait for the running ones, end the threads."""
        for fut in self._pending:
            fut.cancel()
        self._pool.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> BackgroundJobs[T]:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        try:
            if exc_type is None:
                self.results()
        finally:
            self.close()
