"""What a report build found and the warnings it collected: the record every section reads."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from cam2sim.report.exports import ExportedTable
from cam2sim.report.pieces import html_table

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from cam2sim.core.run_record import RunRecord
    from cam2sim.core.workspace import Workspace
    from cam2sim.metrics.drive_io import DriveRun
    from cam2sim.metrics.drive_quality import DriveMetrics
    from cam2sim.scenario.model import Scenario


__all__ = ["ReportContext"]


@dataclass
class ReportContext:
    """What a report build found and the warnings it collected."""

    ws: Workspace
    warnings: list[str] = field(default_factory=list)
    scenario: Scenario | None = None
    runs: list[Path] = field(default_factory=list)
    meta: dict[str, RunRecord] = field(default_factory=dict)
    drives: dict[str, DriveRun] = field(default_factory=dict)
    metrics: DriveMetrics | None = None
    exported: list[ExportedTable] = field(default_factory=list)

    def table(
        self, name: str, headers: Sequence[str], rows: Sequence[Sequence[object]], caption: str
    ) -> str:
        """The HTML of a table that is also exported as ``report/tables/<name>.csv|.tex``."""
        table = ExportedTable.of(name, headers, rows, caption)
        self.exported.append(table)
        return html_table(table.headers, table.rows, caption)
