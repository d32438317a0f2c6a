"""The campaign state file: what became of every run spec (``CAMPAIGN/state.json``).

Only the process that runs the campaign writes it, atomically after every finished run, so an
interrupted campaign resumes from the last finished run and never reads a half-written file.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import pydantic

from cam2sim.core.schema import Artifact

if TYPE_CHECKING:
    from pathlib import Path

__all__ = ["CampaignState", "RunOutcome", "RunRecord", "RunStatus"]

RunStatus = Literal["done", "failed", "timeout", "crashed"]


@dataclass(frozen=True)
class RunOutcome:
    """What a worker reports for one spec (plain data: it crosses process boundaries).

    Attributes:
        spec_id: The spec.
        status: ``done``, ``failed`` (an exception), ``timeout`` or ``crashed`` (the worker died).
        run_id: The run folder's name under ``WS/runs/`` (done runs only).
        seconds: Wall time of the attempt.
        error: One line saying what went wrong (None when done).
        log: The attempt's log file.
        place: Where it ran: the host and the GPU it was given (``host GPU 2``), ``host CPU``
            when it was given none, the host alone when nothing assigned devices (a local
            pool); None when the worker died before saying.
    """

    spec_id: str
    status: RunStatus
    run_id: str | None
    seconds: float
    error: str | None
    log: str
    place: str | None = None


class RunRecord(pydantic.BaseModel):
    """The latest attempt of one spec."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    status: RunStatus
    workspace: str
    run_id: str | None = None
    seconds: float = 0.0
    error: str | None = None
    log: str | None = None
    place: str | None = None
    attempts: int = 1
    finished_at: str = ""


class CampaignState(Artifact):
    """``state.json``: spec id to the record of its latest attempt."""

    name: str
    runs: dict[str, RunRecord] = pydantic.Field(default_factory=dict)

    def done(self) -> set[str]:
        """Spec ids with a finished run."""
        return {k for k, r in self.runs.items() if r.status == "done"}

    def with_outcome(self, outcome: RunOutcome, workspace: str) -> CampaignState:
        """A copy with ``outcome`` recorded (attempts counted on)."""
        before = self.runs.get(outcome.spec_id)
        record = RunRecord(
            status=outcome.status,
            workspace=workspace,
            run_id=outcome.run_id,
            seconds=round(outcome.seconds, 3),
            error=outcome.error,
            log=outcome.log,
            place=outcome.place,
            attempts=1 + (before.attempts if before is not None else 0),
            finished_at=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        )
        return self.model_copy(update={"runs": {**self.runs, outcome.spec_id: record}})

    @classmethod
    def load_or_new(cls, path: Path, name: str) -> CampaignState:
        """The state at ``path``, or an empty one when there is none yet."""
        return cls.load(path) if path.is_file() else cls(name=name)
