"""Progress reporting from stages to whoever shows it (the CLI's rich bars, or nobody)."""

from __future__ import annotations

from typing import Protocol

__all__ = ["ProgressCallback", "no_progress", "serialized"]


class ProgressCallback(Protocol):
    """Called by long-running stages: ``progress(task, completed, total)``.

    ``task`` names the work ("frames", "lidar scans"), ``completed`` counts units done so far and
    ``total`` is the expected count, or None when unknown.
    """

    def __call__(self, task: str, completed: int, total: int | None) -> None:
        """Report progress on ``task``."""


def no_progress(task: str, completed: int, total: int | None) -> None:
    """Report nothing."""
    del task, completed, total


def serialized(progress: ProgressCallback) -> ProgressCallback:
    """``progress`` behind a lock: for work that reports from more than one thread at a time.

    The CLI's bars and lines keep per-task state that two threads could tear (a task added
    twice); each call through the returned callback runs alone.
    """
    import threading  # noqa: PLC0415

    lock = threading.Lock()

    def report(task: str, completed: int, total: int | None) -> None:
        with lock:
            progress(task, completed, total)

    return report
