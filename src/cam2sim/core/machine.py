"""What this process may use of the machine: its CPUs.

A Ray task sees every core of its node through ``os.cpu_count()`` but was given a share of
them; Ray says how many through ``OMP_NUM_THREADS`` (the task's ``num_cpus``). Work that
spreads over processes (the drive step's runs) sizes itself from :func:`available_cpus`.
"""

from __future__ import annotations

import os

__all__ = ["available_cpus"]


def available_cpus() -> int:
    """CPUs this process may use: its affinity mask, capped by ``OMP_NUM_THREADS`` when set."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cpus = os.cpu_count() or 1
    threads = os.environ.get("OMP_NUM_THREADS", "")
    if threads.isdigit() and int(threads) > 0:
        cpus = min(cpus, int(threads))
    return max(1, cpus)
