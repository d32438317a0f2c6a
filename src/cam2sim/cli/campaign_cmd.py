"""``cam2sim campaign``: many closed-loop runs from a plan, locally or on a Ray cluster."""

from __future__ import annotations

from pathlib import Path  # noqa: TC003 - typer reads annotations at run time
from typing import TYPE_CHECKING, Annotated

import typer

from cam2sim.cli.display import console, print_table, progress_bars

if TYPE_CHECKING:
    from cam2sim.campaign.summary import SummaryRow

__all__ = ["campaign"]


def _number(value: float | None, digits: int = 2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _print_summary(rows: list[SummaryRow]) -> None:
    from rich.table import Table  # noqa: PLC0415

    table = Table(title="campaign summary")
    for col in ("recording", "policy", "camera", "runs", "failed", "success", "completion",
                "Min-Fréchet m", "corridor viol. %"):  # fmt: skip
        table.add_column(
            col, justify="left" if col in ("recording", "policy", "camera") else "right"
        )
    for r in rows:
        table.add_row(
            r.workspace,
            r.policy,
            r.camera,
            f"{r.done}/{r.runs}",
            str(r.failed),
            str(r.successes),
            _number(r.completion_mean, 3),
            _number(r.min_frechet_mean_m),
            _number(r.corridor_violation_mean_pct, 1),
        )
    print_table(table)


def campaign(
    plan: Annotated[Path, typer.Argument(help="The campaign plan (YAML).")],
    *,
    ray: Annotated[
        str | None,
        typer.Option(help="Run on Ray: a cluster address (HOST:PORT, auto) or local."),
    ] = None,
    workers: Annotated[
        int | None,
        typer.Option(min=1, help="Local pool processes (default: CPU count); Ray local CPUs."),
    ] = None,
    gpus_per_run: Annotated[
        float,
        typer.Option(
            min=0.01,
            help="With --ray: the share of a GPU a splat-camera run holds (0.5: two a GPU, "
            "which ran 1.2-1.4x faster than one; 1 for splats too large for two a GPU).",
        ),
    ] = 0.5,
    retry_failed: Annotated[
        bool, typer.Option(help="Run failed, timed-out and crashed runs again.")
    ] = True,
) -> None:
    """Run a test campaign: every workspace x policy x camera x seed x perturbation of PLAN.

    Runs land in each workspace's runs/ as cam2sim drive runs do; state, logs, the summary
    (summary.csv, summary.json) and report.html in the campaign folder. A re-run does only
    what is missing.

    Example: cam2sim campaign plan.yaml --ray auto
    """
    from cam2sim.campaign.executors import LocalPool, RayCluster  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
    from cam2sim.campaign.runner import run_campaign  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    executor = (
        LocalPool(workers)
        if ray is None
        else RayCluster(ray, num_cpus=workers, gpus_per_job=gpus_per_run)
    )
    with progress_bars() as sink:
        result = run_campaign(plan, executor=executor, retry_failed=retry_failed, progress=sink)
    _print_summary(result.summary)
    rate = 60.0 * result.ran / result.seconds if result.seconds > 0 and result.ran else 0.0
    console.print(
        f"{result.ran} of {result.specs} runs done now ({result.failed} failed; "
        f"{rate:.1f} runs/min on the {executor.name}); results in {result.folder}, "
        f"report: {result.folder / 'report.html'}",
        highlight=False,
    )
