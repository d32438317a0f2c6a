"""Ray, the optional cluster backend (``pip install 'cam2sim[ray]'``), imported only on use.

:func:`ray_session` connects to a cluster (``HOST:PORT``, ``auto``) or starts a local instance
(``local``), unless Ray is already initialised in this process (an embedding program, the tests):
that instance is used and left running.
"""

from __future__ import annotations

import contextlib
from typing import TYPE_CHECKING, Any

from cam2sim.core.errors import BackendUnavailableError

if TYPE_CHECKING:
    from collections.abc import Iterator

__all__ = ["import_ray", "ray_session"]


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
