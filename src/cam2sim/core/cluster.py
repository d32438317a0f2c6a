"""Ray, the optional cluster backend (``pip install 'cam2sim[ray]'``), imported only on use.

:func:`ray_session` connects to a cluster (``HOST:PORT``, ``auto``) or starts a local instance
(``local``), unless Ray is already initialised in this process (an embedding program, the tests):
that instance is used and left running.
"""

from __future__ import annotations

import contextlib
import os
import socket
import sys
from typing import TYPE_CHECKING, Any, Final

from cam2sim.core.errors import BackendUnavailableError

if TYPE_CHECKING:
    from collections.abc import Iterator

__all__ = ["LOST_WORKER_RETRIES", "import_ray", "ray_session", "worker_place"]

LOST_WORKER_RETRIES: Final = 1
"""Times Ray runs a task again whose worker process or node died (killed for memory, a node
lost or preempted). Safe: a campaign run writes only its own new folder, built under a
temporary name and renamed when complete, and a splat chunk writes its model atomically, so a
killed attempt leaves nothing a second one reads. An exception raised inside a task is its
outcome (a failed run, a failed chunk) and is not retried: runs are seeded, it would fail the
same way; except a splat chunk's CUDA out of memory (the memory of a GPU that fractional tasks
share was taken by the others: :mod:`cam2sim.splat.distributed`). A task whose worker dies
again is reported (a campaign run as ``crashed``), as the campaigns' local pool does (it
retries the runs of a broken pool one by one)."""


def import_ray() -> Any:
    """The ``ray`` module.

    Raises:
        BackendUnavailableError: Ray is not installed.
    """
    try:
        import ray  # noqa: PLC0415
    except ImportError:
        msg = "Ray is not installed; install the extra: pip install 'cam2sim[ray]'"
        raise BackendUnavailableError(msg) from None
    return ray


@contextlib.contextmanager
def ray_session(address: str = "local", *, num_cpus: int | None = None) -> Iterator[Any]:
    """Yield the ``ray`` module connected to ``address``; shut down what was started here.

    Args:
        address: ``local`` starts a local instance; anything else is passed to ``ray.init``
            (``auto``, ``HOST:PORT``, ``ray://HOST:PORT``).
        num_cpus: CPUs of a local instance (default: all).
    """
    ray = import_ray()
    started = not ray.is_initialized()
    if started:
        local = address == "local"
        ray.init(
            address=None if local else address,
            num_cpus=num_cpus if local else None,
            include_dashboard=False,
            log_to_driver=False,
        )
    try:
        yield ray
    finally:
        if started:
            ray.shutdown()


def worker_place() -> str:
    """Where this process runs: ``host GPU 2`` (the GPUs it was given), ``host CPU`` or ``host``.

    In a Ray task, the GPUs Ray gave it (none: ``host CPU``). Elsewhere a scheduler that
    assigns GPUs sets ``CUDA_VISIBLE_DEVICES`` (empty: none given); unset, nothing assigned
    devices (a local pool), and only the host is known.
    """
    host = socket.gethostname()
    ray = sys.modules.get("ray")  # imported: maybe a Ray worker; never imported here
    if ray is not None and ray.is_initialized():
        ids = ray.get_gpu_ids()
        return f"{host} GPU {','.join(str(i) for i in ids)}" if ids else f"{host} CPU"
    gpus = os.environ.get("CUDA_VISIBLE_DEVICES")
    if gpus is None:
        return host
    return f"{host} GPU {gpus}" if gpus.strip() else f"{host} CPU"
