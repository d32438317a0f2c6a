"""The campaign's results: every run scored, and a table per recording, policy and camera.

Each workspace's finished runs are scored against its recorded drive with
:func:`cam2sim.stages.evaluate.evaluate_workspace_drives` (``CAMPAIGN/metrics/<ws>/``: the
``metrics.json``, table and figures of the evaluate stage). ``runs.csv`` holds one row per spec
(its status and metrics), ``summary.csv`` and ``summary.json`` one row per recording, policy
and camera.
"""

from __future__ import annotations

import csv
import io
import json
import logging
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from cam2sim.core.errors import Cam2SimError
from cam2sim.core.files import write_text_atomic
from cam2sim.core.workspace import Workspace
from cam2sim.metrics.drive_quality import DriveMetrics
from cam2sim.stages.evaluate import evaluate_workspace_drives

if TYPE_CHECKING:
    from collections.abc import Sequence

    from cam2sim.campaign.plan import RunSpec
    from cam2sim.campaign.state import CampaignState
    from cam2sim.metrics.drive_quality import RunMetrics

__all__ = ["RunRow", "SummaryRow", "score_runs", "summarize", "write_summary"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class RunRow:
    """One spec: what it ran, what became of it, and its drive metrics (None: not scored)."""

    spec_id: str
    workspace: str
    policy: str
    camera: str
    seed: int
    repetition: int
    lateral_m: float
    heading_deg: float
    speed_kmh: float | None
    status: str
    run_id: str | None
    seconds: float | None
    place: str | None
    completion: float | None
    success: bool | None
    min_frechet_m: float | None
    corridor_violation_pct: float | None
    ended_by: str | None


@dataclass(frozen=True)
class SummaryRow:
    """Runs of one recording, policy and camera.

    Attributes:
        runs: Specs in the plan.
        done: Runs that finished (whatever their drive's outcome).
        failed: Runs that failed, timed out or crashed (see their logs).
        successes: Finished runs that completed the route (the metrics' success).
        completion_mean: Mean route completion of the finished runs, 0..1.
        min_frechet_mean_m: Mean Min-Fréchet distance to the recorded drive of the successful runs.
        corridor_violation_mean_pct: Mean corridor violation of the successful runs.
    """

    workspace: str
    policy: str
    camera: str
    runs: int
    done: int
    failed: int
    successes: int
    completion_mean: float | None
    min_frechet_mean_m: float | None
    corridor_violation_mean_pct: float | None


def _folder_name(workspace: str) -> str:
    return workspace.strip("/").replace("/", "_").replace("..", "up") or "workspace"


def score_runs(
    specs: Sequence[RunSpec], state: CampaignState, folder: Path
) -> dict[str, RunMetrics]:
    """Score every finished run against its recorded drive; spec id to metrics."""
    by_ws: dict[str, list[RunSpec]] = {}
    for spec in specs:
        record = state.runs.get(spec.spec_id)
        if record is not None and record.status == "done" and record.run_id:
            by_ws.setdefault(spec.workspace, []).append(spec)
    scored: dict[str, RunMetrics] = {}
    for name, group in by_ws.items():
        run_of = {s.spec_id: state.runs[s.spec_id].run_id for s in group}
        try:
            ws = Workspace.open(Path(group[0].workspace_path))
            out = folder / "metrics" / _folder_name(name)
            metrics = DriveMetrics.load(
                evaluate_workspace_drives(ws, [r for r in run_of.values() if r], out)
            )
        except Cam2SimError as err:
            logger.warning("%s: the runs could not be scored: %s", name, err)
            continue
        # Every run, real-world (truth camera) runs included: the recorded drive has no run id.
        by_run = {m.name.rsplit("/", 1)[-1]: m for m in metrics.runs}
        scored |= {sid: by_run[rid] for sid, rid in run_of.items() if rid in by_run}
    return scored


def _mean(values: list[float | None]) -> float | None:
    vals = [v for v in values if v is not None]
    return float(np.mean(vals)) if vals else None


def summarize(
    specs: Sequence[RunSpec], state: CampaignState, scored: dict[str, RunMetrics]
) -> tuple[list[RunRow], list[SummaryRow]]:
    """One row per spec and one per recording, policy and camera (plan order)."""
    rows: list[RunRow] = []
    for s in specs:
        rec = state.runs.get(s.spec_id)
        m = scored.get(s.spec_id)
        rows.append(
            RunRow(
                spec_id=s.spec_id, workspace=s.workspace, policy=s.policy, camera=s.camera,
                seed=s.seed, repetition=s.repetition, lateral_m=s.lateral_m,
                heading_deg=s.heading_deg, speed_kmh=s.speed_kmh,
                status=rec.status if rec else "missing", run_id=rec.run_id if rec else None,
                seconds=rec.seconds if rec else None, place=rec.place if rec else None,
                completion=m.completion if m else None, success=m.success if m else None,
                min_frechet_m=m.min_frechet_m if m else None,
                corridor_violation_pct=m.corridor_violation_pct if m else None,
                ended_by=(m.failure or "route_completed") if m else None,
            )
        )  # fmt: skip
    groups: dict[tuple[str, str, str], list[RunRow]] = {}
    for r in rows:
        groups.setdefault((r.workspace, r.policy, r.camera), []).append(r)
    summary = []
    for (ws, policy, camera), group in groups.items():
        done = [r for r in group if r.status == "done"]
        ok = [r for r in done if r.success]
        summary.append(
            SummaryRow(
                workspace=ws,
                policy=policy,
                camera=camera,
                runs=len(group),
                done=len(done),
                failed=sum(r.status in ("failed", "timeout", "crashed") for r in group),
                successes=len(ok),
                completion_mean=_mean([r.completion for r in done]),
                min_frechet_mean_m=_mean([r.min_frechet_m for r in ok]),
                corridor_violation_mean_pct=_mean([r.corridor_violation_pct for r in ok]),
            )
        )
    return rows, summary


def _csv(rows: Sequence[RunRow] | Sequence[SummaryRow]) -> str:
    buffer = io.StringIO()
    if rows:
        fields = list(asdict(rows[0]))
        writer = csv.DictWriter(buffer, fieldnames=fields, lineterminator="\n")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: "" if v is None else v for k, v in asdict(row).items()})
    return buffer.getvalue()


def write_summary(folder: Path, rows: list[RunRow], summary: list[SummaryRow]) -> None:
    """Write ``runs.csv``, ``summary.csv`` and ``summary.json`` into ``folder`` atomically."""
    write_text_atomic(folder / "runs.csv", _csv(rows))
    write_text_atomic(folder / "summary.csv", _csv(summary))
    body = {"summary": [asdict(s) for s in summary], "runs": [asdict(r) for r in rows]}
    write_text_atomic(folder / "summary.json", json.dumps(body, indent=1) + "\n")
