"""What this process may use of the machine: its CPUs, and how many processes share its GPU.

A Ray task sees every core of its node through ``os.cpu_count()`` but was given a share of
them; Ray says how many through ``OMP_NUM_THREADS`` (the task's ``num_cpus``). Work that
spreads over processes (the drive step's runs) sizes itself from :func:`available_cpus`, and
the thread pools that do not read ``OMP_NUM_THREADS`` themselves (onnxruntime's, OpenCV's) are
sized from it too (:func:`keep_to_allotment`): sixteen runs on a 64-core node, each with
pools of 64 threads, would contend for the cores their tasks were not given. The local process
pool allots its workers' shares the same way (:func:`allot_cpus`): three benchmark worlds
sharing 16 cores, each training DAVE-2 with 16 threads, took 50-75 s an epoch where one alone
takes about 1-2 s (docs/benchmarks.md).

The GPU is shared the same way: the local pool's workers all use the machine's first GPU, and
Ray's fractional GPUs put two or more jobs on one. :func:`gpu_sharers` says how many processes
share this one (``CAM2SIM_GPU_SHARERS``, set by the pool's initializer and Ray's GPU workers),
so that a time cap meant for a GPU of one's own stretches with the share (four benchmark worlds
on one H200 trained their splat chunks at a quarter of the pace, and half the chunks stopped on
the 120 s safety cap after 570-2,327 of their 2,500 steps: docs/benchmarks.md).
"""

from __future__ import annotations

import contextlib
import os
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Iterator

__all__ = [
    "GPU_SHARERS_VARIABLE",
    "allot_cpus",
    "available_cpus",
    "children_allotted",
    "gpu_sharers",
    "keep_to_allotment",
    "share_gpu",
]

#: The thread-count variables a process's libraries read when they start: OpenMP (torch's
#: intra-op pool), MKL, OpenBLAS, numba.
_THREAD_VARIABLES = (
    "OMP_NUM_THREADS",
    "MKL_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "NUMBA_NUM_THREADS",
)

GPU_SHARERS_VARIABLE = "CAM2SIM_GPU_SHARERS"
"""The environment variable that says how many processes share this process's GPU."""


def allot_cpus(cpus: int, gpu_sharers: int = 1) -> None:
    """Allot this process ``cpus`` CPUs, as Ray does for a task (a pool worker's initializer).

    Sets the thread-count variables before the heavy libraries start; a smaller allotment
    already set (by a scheduler above) is kept. ``gpu_sharers``: processes sharing the GPU
    with this one, itself included (a larger number already set is kept).
    """
    cpus = max(1, cpus)
    allotted = _allotted()
    if allotted is not None:
        cpus = min(cpus, allotted)
    for name in _THREAD_VARIABLES:
        os.environ[name] = str(cpus)
    share_gpu(gpu_sharers)


@contextlib.contextmanager
def children_allotted(cpus: int | None) -> Iterator[None]:
    """Allot ``cpus`` CPUs to the processes started inside the ``with`` block (None: as this one).

    A spawned child's libraries size their thread pools when they load, from the variables
    :func:`allot_cpus` sets, before any code of ours runs there; so they are set here while
    the child starts and restored after (this process's own pools, already started, keep
    their size). A smaller allotment of this process (a scheduler's above) caps ``cpus``.

    Processes sharing a machine need this: a splat chunk's worker beside DAVE-2's training on a
    16-core GPU machine, each with pools of 16 threads, took 25-32 s to seed its Gaussians
    (4 s alone) while DAVE-2 took 35 s an epoch (0.5 s alone) (docs/benchmarks.md).
    """
    if cpus is None:
        yield
        return
    cpus = max(1, min(cpus, available_cpus()))
    saved = {name: os.environ.get(name) for name in _THREAD_VARIABLES}
    try:
        for name in _THREAD_VARIABLES:
            os.environ[name] = str(cpus)
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def share_gpu(sharers: int) -> None:
    """Say that ``sharers`` processes (this one included) share this process's GPU.

    Its child processes inherit it; a larger number already set (by a scheduler above) is kept.
    """
    os.environ[GPU_SHARERS_VARIABLE] = str(max(1, sharers, gpu_sharers()))


def gpu_sharers() -> int:
    """How many processes share this process's GPU, itself included (1 when nothing said so)."""
    value = os.environ.get(GPU_SHARERS_VARIABLE, "")
    return int(value) if value.isdigit() and int(value) > 0 else 1


def available_cpus() -> int:
    """CPUs this process may use: its affinity mask, capped by ``OMP_NUM_THREADS`` when set."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cpus = os.cpu_count() or 1
    allotted = _allotted()
    if allotted is not None:
        cpus = min(cpus, allotted)
    return max(1, cpus)


def _allotted() -> int | None:
    """The CPUs a scheduler allotted (``OMP_NUM_THREADS``, as Ray sets it), or None."""
    threads = os.environ.get("OMP_NUM_THREADS", "")
    return int(threads) if threads.isdigit() and int(threads) > 0 else None


def keep_to_allotment() -> int | None:
    """Size OpenCV's and Mesa's thread pools to this process's CPUs when a scheduler allotted them.

    Mesa's software rasteriser (llvmpipe, the raster camera without a GPU) starts a thread per
    core unless ``LP_NUM_THREADS`` says otherwise; it is set here (when not set already) for the
    contexts this process creates afterwards.

    Returns the allotment (``OMP_NUM_THREADS``, as Ray sets it for a task), or None when
    nothing allotted CPUs (the pools are left as they are).
    """
    if _allotted() is None:
        return None
    import cv2  # noqa: PLC0415 -- lazy: only the processes that are given CPUs

    cpus = available_cpus()
    cv2.setNumThreads(cpus)
    torch = sys.modules.get("torch")  # already started: its pool was sized from every core
    if torch is not None and torch.get_num_threads() > cpus:
        torch.set_num_threads(cpus)
    os.environ.setdefault("LP_NUM_THREADS", str(cpus))
    return cpus
