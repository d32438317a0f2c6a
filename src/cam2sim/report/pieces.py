"""Small pieces every HTML page of cam2sim is built from: escaped text, tables, figures."""

from __future__ import annotations

import base64
import io
from html import escape
from typing import TYPE_CHECKING, Any, Final

import numpy as np

from cam2sim.core.plots import pyplot

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence
    from pathlib import Path

    import numpy.typing as npt

__all__ = [
    "FRAME_WIDTH",
    "data_uri",
    "esc",
    "evenly",
    "figure_bytes",
    "fmt",
    "html_table",
    "img",
    "jpeg",
    "not_available",
    "png_img",
    "section",
]

FRAME_WIDTH: Final = 1280
"""Width (px) of a frame shown in a page: recorded, rendered or side by side."""


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


def img(data: bytes, alt: str, *, mime: str = "image/png", cls: str = "fig") -> str:
    """An ``<img>`` of ``data`` embedded as a data URI."""
    return f'<img class="{cls}" alt="{esc(alt)}" src="{data_uri(data, mime)}">'


def not_available(what: str, command: str) -> str:
    """The line a section shows when its inputs are missing, with the command that makes them."""
    return f'<p class="na">{esc(what)} not available: run <code>{esc(command)}</code></p>'


def section(sid: str, title: str, body: str) -> str:
    """A page section with its stable id and title."""
    return f'<section id="{sid}"><h2>{esc(title)}</h2>{body}</section>'


def figure_bytes(fig: Any) -> bytes:
    """A matplotlib figure as PNG bytes; the figure is closed."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110, bbox_inches="tight")
    pyplot().close(fig)
    return buffer.getvalue()


def evenly(items: Sequence[Path], n: int) -> list[Path]:
    """At most ``n`` of ``items``, evenly spread, the first and the last among them."""
    if len(items) <= n:
        return list(items)
    return [items[int(i)] for i in np.linspace(0, len(items) - 1, n).round()]


def jpeg(path: Path, width: int) -> bytes:
    """The image at ``path`` as JPEG bytes, at most ``width`` pixels wide.

    Raises:
        OSError: The file is not a readable image, or cannot be encoded.
    """
    import cv2  # noqa: PLC0415 -- lazy: the pages without frames need no OpenCV

    image: npt.NDArray[Any] | None = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        msg = f"{path} is not a readable image"
        raise OSError(msg)
    h, w = image.shape[:2]
    if w > width:
        image = cv2.resize(
            image, (width, max(1, round(h * width / w))), interpolation=cv2.INTER_AREA
        )
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 85])
    if not ok:
        msg = f"cannot encode {path}"
        raise OSError(msg)
    return bytes(buf.tobytes())
