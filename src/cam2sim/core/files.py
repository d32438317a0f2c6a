"""Atomic file and folder writes, and JSON reads that say which file is broken.

A reader never sees a half-written artifact: files are written to a temporary sibling and renamed
into place, and whole output folders are built beside the old one and swapped in at the end.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cam2sim.core.errors import WorkspaceError

if TYPE_CHECKING:
    from collections.abc import Iterator
    from typing import BinaryIO

__all__ = [
    "atomic_folder",
    "atomic_write",
    "file_fingerprint",
    "process_lock",
    "read_json",
    "waiting_lock",
    "write_bytes_atomic",
    "write_text_atomic",
]

_FINGERPRINT_BLOCK = 1 << 20


@contextlib.contextmanager
def atomic_write(path: Path) -> Iterator[BinaryIO]:
    """Yield a binary handle whose content replaces ``path`` only when the block succeeds.

    Readers see the old or the new file, never a part; on any exception the temporary file is
    removed and ``path`` is untouched. The file gets the permissions a plain ``open`` would give
    it (0666 less the umask), not the temporary file's private 0600: a report is shared.

    Args:
        path: Destination file. Its folder is created when missing.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        Path(tmp_name).chmod(0o666 & ~_umask())
        Path(tmp_name).replace(path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            Path(tmp_name).unlink()
        raise


@functools.cache
def _umask() -> int:
    """The process's umask, read once (by setting it and setting it back: not thread-safe)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_write`)."""
    with atomic_write(path) as handle:
        handle.write(data)


def write_text_atomic(path: Path, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically (see :func:`write_bytes_atomic`)."""
    write_bytes_atomic(path, text.encode("utf-8"))


@contextlib.contextmanager
def atomic_folder(path: Path) -> Iterator[Path]:
    """Build a folder beside ``path`` and swap it into place when the block succeeds.

    The block receives an empty temporary folder to fill. On success the previous ``path`` (if
    any) is replaced as a whole; on any exception, including ``KeyboardInterrupt``, the temporary
    folder is removed and ``path`` is left exactly as it was.

    Args:
        path: The folder to (re)create.

    Yields:
        The temporary folder to write into.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent))
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    old = path.parent / f".{path.name}.old-{os.getpid()}"
    if path.exists():
        path.replace(old)
    try:
        tmp.replace(path)
    except BaseException:
        if old.exists():
            old.replace(path)
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    shutil.rmtree(old, ignore_errors=True)


def file_fingerprint(path: Path) -> str:
    """Return a fast content fingerprint of a (possibly multi-GB) file.

    The SHA-256 of the file size, its first and its last MiB. It changes whenever a recording is
    replaced, truncated or appended to, without reading gigabytes on every run.

    Args:
        path: The file.

    Returns:
        ``"fp256:<hex>"``.
    """
    path = Path(path)
    size = path.stat().st_size
    digest = hashlib.sha256(str(size).encode())
    with path.open("rb") as handle:
        digest.update(handle.read(_FINGERPRINT_BLOCK))
        if size > _FINGERPRINT_BLOCK:
            handle.seek(max(size - _FINGERPRINT_BLOCK, _FINGERPRINT_BLOCK))
            digest.update(handle.read(_FINGERPRINT_BLOCK))
    return f"fp256:{digest.hexdigest()}"


def read_json(path: Path, *, fix: str = "delete it and re-run the stage that writes it") -> Any:
    """The parsed JSON of ``path``.

    Args:
        path: The file.
        fix: What the user should do when it is missing or broken (ends the message).

    Raises:
        WorkspaceError: The file is missing, unreadable, or not valid JSON (truncated by a
            crash, edited by hand); the message names the file, the place and ``fix``.
    """
    path = Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        msg = f"{path} does not exist; {fix}"
        raise WorkspaceError(msg) from None
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        msg = f"{path} is not valid JSON ({err}); {fix}"
        raise WorkspaceError(msg) from None


@contextlib.contextmanager
def process_lock(path: Path, *, busy: str) -> Iterator[None]:
    """Hold the lock file ``path`` for this process (released when it ends, even by a crash).

    Args:
        path: The lock file (created with its folder).
        busy: The message when another process holds it (what runs, what to do).

    Raises:
        WorkspaceError: Another process holds the lock.
    """
    import fcntl  # noqa: PLC0415 - POSIX only, like the campaign workers' time limit

    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise WorkspaceError(busy) from None
        yield


@contextlib.contextmanager
def waiting_lock(path: Path) -> Iterator[None]:
    """Hold the lock file ``path``, waiting while another process or thread holds it.

    For short read-change-write sections (the workspace manifest). Each call opens the file
    anew, so threads of one process exclude each other as processes do (``flock`` locks an
    open file, not a process); the lock goes with the process, even by a crash.
    """
    import fcntl  # noqa: PLC0415 - POSIX only, like process_lock

    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        yield
