"""Native libraries' own console output: what our messages cannot catch, kept off the screen.

OpenCV's FFmpeg backend prints ``OpenCV: FFMPEG: tag 0x30385056/'VP80' is not supported with
codec id 139 and format 'webm / WebM'`` from C when it opens a WebM writer, although it then
writes the VP8 stream the browsers play. :func:`native_stderr_silenced` sends file descriptor 2
to the null device for the length of such a call; Python's own ``sys.stderr`` is flushed first
and comes back unchanged. Whether the call worked is the caller's to check (``isOpened()``).
"""

from __future__ import annotations

import contextlib
import os
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Iterator

__all__ = ["native_stderr_silenced"]


@contextlib.contextmanager
def native_stderr_silenced() -> Iterator[None]:
    """File descriptor 2 goes to the null device inside the block (then back)."""
    sys.stderr.flush()
    saved = os.dup(2)
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(null)
        os.close(saved)
