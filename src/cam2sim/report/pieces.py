"""Small pieces every HTML page of cam2sim is built from: escaped text, tables, figures."""

from __future__ import annotations

import base64
import io
from html import escape
from typing import TYPE_CHECKING, Any

from cam2sim.core.plots import pyplot

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

__all__ = ["data_uri", "esc", "fmt", "html_table", "png_img"]


def esc(value: object) -> str:
    """``value`` as text, escaped for HTML (attributes included)."""
    return escape(str(value), quote=True)


def fmt(value: float | None, spec: str = ".2f") -> str:
    """``value`` formatted with ``spec``; ``-`` for None."""
    return "-" if value is None else format(value, spec)


def html_table(headers: Sequence[str], rows: Iterable[Sequence[object]], caption: str = "") -> str:
    """A ``<table>`` with a header row and, when given, a caption; every cell escaped."""
    head = "".join(f"<th>{esc(h)}</th>" for h in headers)
    body = "".join("<tr>" + "".join(f"<td>{esc(c)}</td>" for c in row) + "</tr>" for row in rows)
    cap = f"<caption>{esc(caption)}</caption>" if caption else ""
    return f"<table>{cap}<thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def data_uri(data: bytes, mime: str) -> str:
    """``data`` as a ``data:`` URI."""
    return f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"


def png_img(fig: Any, *, alt: str = "plot", dpi: int = 110) -> str:
    """A matplotlib figure as an embedded PNG ``<img>``; the figure is closed."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi, bbox_inches="tight")
    pyplot().close(fig)
    return f'<img alt="{esc(alt)}" src="{data_uri(buffer.getvalue(), "image/png")}">'
