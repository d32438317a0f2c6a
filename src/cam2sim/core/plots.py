"""Shared matplotlib plumbing: a headless pyplot and atomic PNG saving."""

from __future__ import annotations

import io
from typing import TYPE_CHECKING, Any

from cam2sim.core.files import write_bytes_atomic

if TYPE_CHECKING:
    from pathlib import Path

__all__ = ["pyplot", "save_figure"]


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the non-interactive Agg backend (imported on first use)."""
    import matplotlib as mpl  # noqa: PLC0415

    mpl.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    return plt


def save_figure(fig: Any, path: Path, *, dpi: int = 130) -> None:
    """Write ``fig`` to ``path`` as PNG atomically and close it."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi, bbox_inches="tight")
    pyplot().close(fig)
    write_bytes_atomic(path, buffer.getvalue())
