"""Paper-ready copies of the report's tables: CSV and a LaTeX ``tabular`` per table.

The HTML report renders each exported table from the same cells these files are written from
(:class:`ExportedTable`), so the numbers agree to the digit. ``report/tables/<name>.csv`` holds
the header row and the cells; ``<name>.tex`` a ``table`` environment with a ``tabular`` (left
column left-aligned, the rest right), the caption and a label ``tab:<name>``; LaTeX's special
characters are escaped.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from typing import TYPE_CHECKING

from cam2sim.core.files import write_text_atomic

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

__all__ = ["ExportedTable", "latex_escape", "write_tables"]

_LATEX = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
    "±": r"$\pm$",
    "≥": r"$\geq$",
    "≤": r"$\leq$",
}


def latex_escape(text: str) -> str:
    """``text`` with LaTeX's special characters escaped (and ±, ≥, ≤ as math)."""
    return "".join(_LATEX.get(ch, ch) for ch in text)


@dataclass(frozen=True)
class ExportedTable:
    """One table of the report, as its cells."""

    name: str
    headers: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    caption: str

    @classmethod
    def of(
        cls, name: str, headers: Sequence[str], rows: Sequence[Sequence[object]], caption: str
    ) -> ExportedTable:
        """The table with every cell as the text the HTML shows."""
        return cls(name, tuple(headers), tuple(tuple(str(c) for c in row) for row in rows), caption)

    def csv(self) -> str:
        """The header row and the cells as CSV."""
        out = io.StringIO()
        writer = csv.writer(out, lineterminator="\n")
        writer.writerow(self.headers)
        writer.writerows(self.rows)
        return out.getvalue()

    def latex(self) -> str:
        """A ``table`` environment holding a ``tabular`` of the cells."""
        spec = "l" + "r" * (len(self.headers) - 1)
        lines = [
            "\\begin{table}[t]",
            "\\centering",
            f"\\caption{{{latex_escape(self.caption)}}}",
            f"\\label{{tab:{self.name}}}",
            f"\\begin{{tabular}}{{{spec}}}",
            "\\hline",
            " & ".join(latex_escape(h) for h in self.headers) + " \\\\",
            "\\hline",
            *(" & ".join(latex_escape(c) for c in row) + " \\\\" for row in self.rows),
            "\\hline",
            "\\end{tabular}",
            "\\end{table}",
        ]
        return "\n".join(lines) + "\n"


def write_tables(folder: Path, tables: Sequence[ExportedTable]) -> list[Path]:
    """Write ``<name>.csv`` and ``<name>.tex`` of each table into ``folder``; the paths."""
    written = []
    for table in tables:
        for suffix, text in ((".csv", table.csv()), (".tex", table.latex())):
            path = folder / f"{table.name}{suffix}"
            write_text_atomic(path, text)
            written.append(path)
    return written
