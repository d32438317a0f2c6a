"""``cam2sim bench``: the paper's experiment on every street of a suite, with honest rates."""

from __future__ import annotations

import os
from pathlib import Path  # noqa: TC003 - typer reads annotations at run time
from typing import TYPE_CHECKING, Annotated

import typer

from cam2sim.cli.display import console, print_table, progress_bars

if TYPE_CHECKING:
    from cam2sim.metrics.benchmark import Aggregate

__all__ = ["bench"]


def _print(agg: Aggregate) -> None:
    from rich.table import Table  # noqa: PLC0415

    table = Table(title="benchmark: failures over all streets (95 % Wilson interval)")
    for col in ("method", "streets", "runs", "failed", "rate", "95 % interval",
                "streets failing", "Min-Fréchet m", "corridor %"):  # fmt: skip
        table.add_column(col, justify="left" if col == "method" else "right")
    for r in agg.rates:
        table.add_row(
            r.method,
            str(r.streets),
            str(r.runs),
            str(r.failures),
            f"{r.rate:.1%}",
            f"{r.low:.1%}-{r.high:.1%}",
            str(r.streets_failing),
            "-" if r.min_frechet_m is None else f"{r.min_frechet_m:.2f}",
            "-" if r.corridor_violation_pct is None else f"{r.corridor_violation_pct:.1f}",
        )
    print_table(table)
    console.print(agg.verdict, highlight=False)


def bench(
    suite: Annotated[Path, typer.Argument(help="The benchmark suite (YAML; see docs/bench.md).")],
    *,
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="Benchmark folder (default: SUITE_STEM-bench/)."),
    ] = None,
    ray: Annotated[
        str | None,
        typer.Option(help="Run on Ray, one GPU a world where it has GPUs: HOST:PORT, auto, local."),
    ] = None,
    workers: Annotated[
        int,
        typer.Option(
            min=1, help="Worlds at a time on the local pool (each gets CPUs / N threads)."
        ),
    ] = 1,
    cpus_per_world: Annotated[
        int | None,
        typer.Option(min=1, help="On Ray: CPUs a world reserves (default: CPUs / GPUs)."),
    ] = None,
    retry_failed: Annotated[
        bool, typer.Option(help="Run worlds that failed, timed out or crashed again.")
    ] = True,
) -> None:
    """Run the experiment (recording, map, splat, DAVE-2, Real / splat / Sim drives) on a suite.

    Each world lands in OUT/worlds/LABEL/ (its workspace, result.json, failure views); the
    report (report.html, summary.md, tables/*.csv) in OUT. A re-run does only the worlds
    without a result.

    Example: cam2sim bench streets.yaml -o bench --ray local
    """
    from cam2sim.campaign.bench import execute_world, run_bench  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)
    from cam2sim.campaign.executors import LocalPool, RayCluster  # noqa: PLC0415 -- lazy: imports numpy (keeps --help fast)

    if ray is None:
        executor: LocalPool | RayCluster = LocalPool(workers, task=execute_world)
    else:
        cpus = cpus_per_world or max(1, (os.cpu_count() or 1) // max(1, _gpus()))
        executor = RayCluster(ray, task=execute_world, cpus_per_job=cpus)
    with progress_bars() as sink:
        result = run_bench(suite, output=out, executor=executor, retry_failed=retry_failed,
                           progress=sink)  # fmt: skip
    _print(result.aggregate)
    console.print(
        f"{result.ran} of {result.worlds} worlds run now ({result.failed} failed) in "
        f"{result.seconds:.0f} s on the {executor.name}; report: {result.report}",
        highlight=False,
    )


def _gpus() -> int:
    """CUDA GPUs on this machine (a local Ray instance gets them all)."""
    import torch  # noqa: PLC0415

    return int(torch.cuda.device_count()) if torch.cuda.is_available() else 0
