"""Terminal display for the CLI: rich progress bars, logging and warnings."""

from __future__ import annotations

import contextlib
import logging
import time
import warnings
from typing import IO, TYPE_CHECKING, Any, ClassVar, TextIO

import typer
import typer.core
from rich.console import Console
from rich.logging import RichHandler
from rich.markup import escape
from rich.measure import Measurement
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    SpinnerColumn,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path

    from rich.table import Table

    from cam2sim.metrics.drive_quality import DriveMetrics

from cam2sim.core.errors import Cam2SimError

__all__ = [
    "LineProgress",
    "StageErrorGroup",
    "console",
    "error_console",
    "error_exit",
    "print_behaviour",
    "print_steering_agreement",
    "print_table",
    "progress_bars",
    "setup_logging",
    "show_progress",
]

console = Console()
error_console = Console(stderr=True)


class StageErrorGroup(typer.core.TyperGroup):
    """A command group whose commands' stage errors end as one ``error:`` line.

    The root group (``cam2sim``) and the sub-command groups (``cam2sim ads``, ``cam2sim
    evaluate``) use it, so that no command catches :class:`~cam2sim.core.errors.Cam2SimError`
    itself and a sub-group run on its own prints the same line. ``debug`` (the root's
    ``--debug``) lets the traceback through instead.
    """

    debug: ClassVar[bool] = False

    def invoke(self, ctx: Any) -> Any:
        """Run the command; a stage error becomes one ``error:`` line and exit code 1."""
        try:
            return super().invoke(ctx)
        except Cam2SimError as err:
            if StageErrorGroup.debug:
                raise
            raise error_exit(err) from None


def error_exit(err: BaseException) -> typer.Exit:
    """Print ``error: <message>`` on stderr as one line and return the exit (code 1) to raise.

    The message is escaped: brackets in it (a path, a list) are not read as console markup.
    """
    error_console.print(f"[bold red]error:[/] {escape(str(err))}", highlight=False, soft_wrap=True)
    return typer.Exit(code=1)


def print_table(table: Table) -> None:
    """Print a table; off a terminal (pipes, CI logs) at its natural width, never truncated."""
    if console.is_terminal:
        console.print(table)
        return
    natural = Measurement.get(console, console.options.update(width=10_000), table).maximum
    old = console.width
    console.width = max(natural, old)
    try:
        console.print(table)
    finally:
        console.width = old


def setup_logging(*, verbose: int) -> None:
    """Route cam2sim's log records and warnings to the terminal."""
    level = logging.WARNING if verbose <= 0 else logging.INFO if verbose == 1 else logging.DEBUG
    handler = RichHandler(console=error_console, show_path=False, show_time=verbose > 1)
    logging.basicConfig(level=level, handlers=[handler], format="%(message)s", force=True)

    def show(
        message: Warning | str,
        category: type[Warning],
        filename: str,
        lineno: int,
        file: TextIO | None = None,
        line: str | None = None,
    ) -> None:
        del category, filename, lineno, file, line
        error_console.print(f"[yellow]warning:[/] {message}", highlight=False, soft_wrap=True)

    warnings.showwarning = show


_LINE_EVERY_S = 30.0
"""Off a terminal, a running task prints a line at most this often."""


class LineProgress:
    """Progress as plain lines, for logs and pipes (no terminal to draw bars on).

    One line when a task starts, one when it completes, and one every :data:`_LINE_EVERY_S`
    seconds in between: ``[  42 s] splat training: 350/700``.
    """

    def __init__(self, stream: IO[str], *, every_s: float = _LINE_EVERY_S) -> None:
        self._stream = stream
        self._every_s = every_s
        self._started = time.monotonic()
        self._last: dict[str, float] = {}
        self._done: set[str] = set()

    def _line(self, text: str) -> None:
        elapsed = time.monotonic() - self._started
        self._stream.write(f"[{elapsed:5.0f} s] {text}\n")
        self._stream.flush()

    def __call__(self, task: str, completed: int, total: int | None) -> None:
        """Print the task's start, its end, and a line every so often in between."""
        now = time.monotonic()
        count = f"{completed}/{total}" if total is not None else str(completed)
        if task not in self._last:
            self._last[task] = now
            self._done.discard(task)
            self._line(f"{task}: started ({count})")
            return
        if total is not None and completed >= total:
            if task not in self._done:
                self._done.add(task)
                self._line(f"{task}: done ({count})")
            return
        if now - self._last[task] >= self._every_s:
            self._last[task] = now
            self._line(f"{task}: {count}")


_shown = {"progress": True}


def show_progress(*, enabled: bool) -> None:
    """Whether commands show progress at all (``cam2sim --no-progress`` turns it off)."""
    _shown["progress"] = enabled


@contextlib.contextmanager
def progress_bars(*, enabled: bool | None = None) -> Iterator[ProgressSink | LineProgress]:
    """Yield a stage progress callback: rich bars on a terminal, plain lines elsewhere.

    ``enabled`` None follows :func:`show_progress` (on unless ``--no-progress``); False shows
    nothing.
    """
    if enabled is None:
        enabled = _shown["progress"]
    if enabled and not error_console.is_terminal:
        yield LineProgress(error_console.file)
        return
    bars = Progress(
        SpinnerColumn(),
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=error_console,
        transient=False,
        disable=not enabled,
    )
    with bars:
        yield ProgressSink(bars)


class ProgressSink:
    """A :class:`cam2sim.core.progress.ProgressCallback` backed by rich bars."""

    def __init__(self, bars: Progress) -> None:
        self._bars = bars
        self._tasks: dict[str, TaskID] = {}

    def __call__(self, task: str, completed: int, total: int | None) -> None:
        """Update (or create) the bar of ``task``."""
        tid = self._tasks.get(task)
        if tid is None:
            tid = self._bars.add_task(task, total=total)
            self._tasks[task] = tid
        self._bars.update(tid, completed=completed, total=total)


def print_steering_agreement(images_dir: Path) -> None:
    """One line per replayed camera: DAVE-2 on its frames against the recorded ones."""
    from cam2sim.metrics.behaviour import CAMERA_LABELS  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
    from cam2sim.metrics.steering_agreement import SteeringAgreement  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    rank = list(CAMERA_LABELS)  # splat before the simulator, as the paper's columns
    found = sorted(
        images_dir.glob("*/steering.json"),
        key=lambda p: (rank.index(p.parent.name) if p.parent.name in rank else len(rank), p),
    )
    for path in found:
        try:
            a = SteeringAgreement.load(path)
        except Cam2SimError:
            continue
        corr = "-" if a.correlation is None else f"{a.correlation:.3f}"
        held = (
            f"; on its {a.held_out_frames} never-trained views {a.held_out_correlation:.3f}"
            if a.held_out_frames and a.held_out_correlation is not None
            else ""
        )
        console.print(
            f"DAVE-2 on the {CAMERA_LABELS.get(a.camera, a.camera)} frames against the recorded "
            f"ones: correlation {corr}, mean gap {a.mean_abs_gap:.3f} units (recorded spread "
            f"{a.recorded_std:.3f}){held}",
            highlight=False,
            soft_wrap=True,
        )


def print_behaviour(metrics: DriveMetrics) -> None:
    """Print the behaviour table in the paper's layout (Real / splat / Sim), notes under it."""
    from rich.table import Table  # noqa: PLC0415

    from cam2sim.metrics.behaviour import behaviour_table  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    paper = behaviour_table(metrics)
    table = Table(title="Behaviour (averages over successful runs; jitter over all runs)")
    table.add_column("metric")
    for column in paper.columns:
        table.add_column(column, justify="right")
    for name, values in paper.rows:
        table.add_row(name, *values)
    print_table(table)
    for note in paper.notes:  # a method that failed the splat quality gate, and why
        console.print(f"[bold yellow]{escape(note)}[/]", highlight=False, soft_wrap=True)
