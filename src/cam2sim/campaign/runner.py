"""``cam2sim campaign``: run a plan's missing runs, record every outcome, summarise.

The campaign folder (the plan's ``output``, default ``PLAN_STEM-campaign/`` beside the plan)
holds ``state.json`` (spec id to run id and status), ``logs/<spec id>.log`` (each attempt's
output), ``metrics/<workspace>/`` and the summary tables. Runs land in their workspace's
``runs/`` exactly as ``cam2sim drive`` runs do. A second ``cam2sim campaign`` on the same plan
runs only specs without a finished run (failed ones are tried again unless ``retry_failed`` is
off); the state is written after every run (throttled for very large campaigns) and when the
campaign ends or is interrupted (Ctrl-C), so an interrupted campaign loses nothing finished.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from cam2sim.campaign.executors import Job, LocalPool
from cam2sim.campaign.plan import expand, load_plan
from cam2sim.campaign.state import CampaignState, RunOutcome
from cam2sim.campaign.summary import score_runs, summarize, write_summary
from cam2sim.core.files import process_lock
from cam2sim.core.progress import ProgressCallback, no_progress

if TYPE_CHECKING:
    from collections.abc import Iterator

    from cam2sim.campaign.executors import Executor
    from cam2sim.campaign.plan import Plan, RunSpec
    from cam2sim.campaign.summary import RunRow, SummaryRow

__all__ = ["CampaignResult", "campaign_folder", "campaign_lock", "run_campaign"]

logger = logging.getLogger(__name__)
TASK = "campaign runs"


@dataclass(frozen=True)
class CampaignResult:
    """What a campaign invocation did.

    Attributes:
        folder: The campaign folder.
        specs: Runs in the plan.
        ran: Runs attempted by this invocation.
        failed: Runs of this invocation that failed, timed out or crashed.
        seconds: Wall time of the runs (scoring excluded).
        rows: One row per spec (status and metrics).
        summary: One row per recording, policy and camera.
    """

    folder: Path
    specs: int
    ran: int
    failed: int
    seconds: float
    rows: list[RunRow]
    summary: list[SummaryRow]


def campaign_folder(plan: Plan, plan_path: Path) -> Path:
    """The campaign folder of a plan: its ``output``, or ``PLAN_STEM-campaign/`` beside it."""
    base = plan_path.resolve().parent
    if plan.output is None:
        return base / f"{plan_path.stem}-campaign"
    out = Path(plan.output).expanduser()
    return out if out.is_absolute() else base / out


def _missing(specs: list[RunSpec], state: CampaignState, *, retry_failed: bool) -> list[RunSpec]:
    """Specs without a finished run whose folder still exists (and, optionally, not failed)."""
    todo = []
    for spec in specs:
        rec = state.runs.get(spec.spec_id)
        if rec is None:
            todo.append(spec)
        elif rec.status == "done":
            if not rec.run_id or not (Path(spec.workspace_path) / "runs" / rec.run_id).is_dir():
                todo.append(spec)  # the run folder was deleted: run it again
        elif retry_failed:
            todo.append(spec)
    return todo


@contextlib.contextmanager
def campaign_lock(folder: Path) -> Iterator[None]:
    """Hold the campaign folder for this process (released when it ends, even by a crash).

    Raises:
        WorkspaceError: Another process runs this campaign.
    """
    busy = f"another cam2sim campaign is running in {folder}; wait for it to end or stop it"
    with process_lock(folder / ".lock", busy=busy):
        yield


def run_campaign(
    plan_path: Path,
    *,
    executor: Executor | None = None,
    retry_failed: bool = True,
    progress: ProgressCallback | None = None,
) -> CampaignResult:
    """Run the plan's missing runs, then score them all and write the summary.

    Args:
        plan_path: The ``PLAN.yaml``.
        executor: Where runs execute; default a :class:`LocalPool` of the CPU count.
        retry_failed: Try failed, timed-out and crashed runs again.
        progress: Receives ``("campaign runs", finished, to run)``.

    Raises:
        ConfigError: The plan is invalid (the message names the key and the fix).
        WorkspaceError: Another process runs the same campaign (its lock is held).
        BackendUnavailableError: Ray was asked for but is not installed.
    """
    plan_path = Path(plan_path)
    plan = load_plan(plan_path)
    folder = campaign_folder(plan, plan_path)
    with campaign_lock(folder):
        return _run(plan, plan_path, folder, executor, retry_failed, progress or no_progress)


def _run(
    plan: Plan,
    plan_path: Path,
    folder: Path,
    executor: Executor | None,
    retry_failed: bool,
    report: ProgressCallback,
) -> CampaignResult:
    specs = expand(plan, plan_path.resolve().parent)
    state_path = folder / "state.json"
    state = CampaignState.load_or_new(state_path, plan.name or plan_path.stem)
    todo = _missing(specs, state, retry_failed=retry_failed)
    runner = executor or LocalPool()
    logger.info("campaign %s: %d of %d runs to do on the %s", state.name, len(todo),
                len(specs), runner.name)  # fmt: skip
    by_id = {s.spec_id: s for s in todo}
    jobs = [Job(s, str(folder / "logs" / f"{s.spec_id}.log"), plan.timeout_s) for s in todo]
    finished: list[RunOutcome] = []
    places: collections.Counter[str] = collections.Counter()
    saved = {"at": 0.0, "cost": 0.0}

    def save() -> None:
        t0 = time.perf_counter()
        state.save(state_path)
        saved["at"], saved["cost"] = t0, time.perf_counter() - t0

    def record(outcome: RunOutcome) -> None:
        nonlocal state
        state = state.with_outcome(outcome, by_id[outcome.spec_id].workspace)
        # Saved after every run, unless saving takes long (a state of thousands of runs): then
        # at most a tenth of the time goes to it; the rest is saved at the end in any case.
        if time.perf_counter() - saved["at"] >= 10.0 * saved["cost"]:
            save()
        finished.append(outcome)
        if outcome.status != "done":
            logger.warning("run %s %s: %s (log: %s)", outcome.spec_id, outcome.status,
                           outcome.error, outcome.log)  # fmt: skip
        report(TASK, len(finished), len(jobs))
        if outcome.place is not None:
            places[outcome.place] += 1
            if len(places) > 1 or " GPU " in outcome.place:  # a bar a GPU (or node) at work
                report(f"  runs on {outcome.place}", places[outcome.place], None)

    started = time.perf_counter()
    report(TASK, 0, len(jobs))
    try:
        if jobs:
            runner.run(jobs, record)
    finally:
        save()  # also when interrupted: what finished is kept
    seconds = time.perf_counter() - started
    rows, summary = summarize(specs, state, score_runs(specs, state, folder))
    write_summary(folder, rows, summary)
    from cam2sim.report.campaign import write_campaign_report  # noqa: PLC0415 -- matplotlib

    write_campaign_report(
        folder, [asdict(s) for s in summary], [asdict(r) for r in rows], name=state.name,
        seconds=seconds, ran=len(finished),
    )  # fmt: skip
    return CampaignResult(
        folder=folder,
        specs=len(specs),
        ran=len(finished),
        failed=sum(o.status != "done" for o in finished),
        seconds=seconds,
        rows=rows,
        summary=summary,
    )
