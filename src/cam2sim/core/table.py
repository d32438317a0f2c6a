"""Column tables as CSV: written atomically with a fixed precision per column, read back typed.

Integer columns (``frame``, ``index`` and names ending in ``_ns`` or ``_count``) stay exact
int64; everything else is float64.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from cam2sim.core.errors import WorkspaceError
from cam2sim.core.files import write_text_atomic

if TYPE_CHECKING:
    from collections.abc import Mapping

__all__ = ["is_integer_column", "read_table", "write_table"]

_INT_NAMES = {"frame", "index", "scan", "points", "vehicle"}


def is_integer_column(name: str) -> bool:
    """Whether a column of this name holds exact integers."""
    return name in _INT_NAMES or name.endswith(("_ns", "_count"))


def write_table(
    path: Path,
    columns: Mapping[str, npt.ArrayLike],
    *,
    precision: Mapping[str, int] | None = None,
    default_precision: int = 6,
) -> None:
    """Write equally long columns to a CSV file atomically.

    Args:
        path: Destination file.
        columns: Column name to 1-D values, in output order.
        precision: Decimal places per float column (default ``default_precision``).
        default_precision: Decimal places for float columns not named in ``precision``.
    """
    names = list(columns)
    arrays = [np.asarray(columns[n]) for n in names]
    lengths = {a.shape[0] for a in arrays}
    if len(lengths) > 1:
        msg = f"columns of {path.name} differ in length: " + ", ".join(
            f"{n}={a.shape[0]}" for n, a in zip(names, arrays, strict=True)
        )
        raise ValueError(msg)
    precision = precision or {}
    fmts = [
        "%d" if is_integer_column(n) else f"%.{precision.get(n, default_precision)}f" for n in names
    ]
    buffer = io.StringIO()
    buffer.write(",".join(names) + "\n")
    if arrays and arrays[0].shape[0]:
        table = np.empty((arrays[0].shape[0], len(names)), dtype=object)
        for i, (name, arr) in enumerate(zip(names, arrays, strict=True)):
            table[:, i] = arr.astype(np.int64) if is_integer_column(name) else arr.astype(float)
        np.savetxt(buffer, table, fmt=fmts, delimiter=",")
    write_text_atomic(path, buffer.getvalue())


def read_table(path: Path) -> dict[str, npt.NDArray[np.generic]]:
    """Read a CSV table written by :func:`write_table` (or any numeric CSV with a header).

    Raises:
        WorkspaceError: The file is missing or a value is not numeric.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        msg = f"{path} does not exist; run the stage that writes it first"
        raise WorkspaceError(msg) from None
    lines = text.splitlines()
    if not lines:
        msg = f"{path} is empty; expected a header line"
        raise WorkspaceError(msg)
    names = [n.strip() for n in lines[0].lstrip("#").split(",")]
    if len(lines) == 1:
        return {
            n: np.zeros(0, dtype=np.int64 if is_integer_column(n) else np.float64) for n in names
        }
    try:
        raw = np.loadtxt(io.StringIO("\n".join(lines[1:])), delimiter=",", dtype=str, ndmin=2)
    except ValueError as err:
        msg = f"{path}: malformed table ({err}); delete it and re-run the stage"
        raise WorkspaceError(msg) from None
    if raw.shape[1] != len(names):
        msg = f"{path}: {raw.shape[1]} values per row but {len(names)} header names"
        raise WorkspaceError(msg)
    out: dict[str, npt.NDArray[np.generic]] = {}
    for i, name in enumerate(names):
        try:
            out[name] = (
                raw[:, i].astype(np.int64) if is_integer_column(name) else raw[:, i].astype(float)
            )
        except ValueError:
            msg = f"{path}: column {name!r} has a non-numeric value; fix or regenerate the file"
            raise WorkspaceError(msg) from None
    return out
