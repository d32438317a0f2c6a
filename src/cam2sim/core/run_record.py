"""The records of one run folder: ``run.json`` (what was run) and ``events.json`` (what happened).

Replay and drive (:mod:`cam2sim.stages.runs`) write them through these models, atomically;
the metrics, the report, the campaign and the CLI read them back with :meth:`Artifact.load`,
which names the broken file and the fix. Files written before the records carried a
``schema_version`` load as version 1; a bare JSON list of events (the earliest ``events.json``)
loads too.

``run.json``'s splat blocks (``splat_quality``, ``splat_gate``) are the JSON of
:mod:`cam2sim.metrics.splat_gate`'s models, validated there (the core knows no metrics).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar, Literal

import pydantic

from cam2sim.core.files import write_text_atomic
from cam2sim.core.schema import Artifact

__all__ = ["RUN_BROKEN_FIX", "EventRecord", "JsonObject", "RunEvents", "RunRecord"]

#: A JSON object: options, simulator settings and the splat blocks are free-form by design
#: (their own models validate them where they are used), hence ``Any``.
JsonObject = dict[str, Any]

RUN_BROKEN_FIX = "delete the run folder and drive again"
"""What to do with a run folder whose records are broken."""


class RunRecord(Artifact):
    """``run.json``: what a replay or drive ran.

    Every field but ``method`` is optional: replays and drives record different ones, and
    hand-made run folders (published runs converted, tests) record few.

    Attributes:
        kind: ``replay`` or ``drive``.
        method: The group the run is scored in (``drive-raster``, ``drive-splat``, ``real`` for
            drives in the ground-truth world, ``replay-raster+splat``...).
        camera: The camera the policy saw (drive), or the cameras joined by ``+`` (replay).
        cameras: The replay's cameras.
        frames: The replayed sample range ``[first, stop)``.
        rendered: Frames the replay rendered.
        policy: The drive's policy name.
        seed: The drive's seed.
        sim: The simulator backend (``builtin``, ``carla``).
        steps: Simulated steps.
        seconds: Wall time of the run.
        steps_per_s: Simulated steps per wall second.
        render_ms: Mean camera time per policy decision, milliseconds.
        policy_ms: Mean policy time per decision, milliseconds.
        rendered_rows: The rows ``[first, stop)`` of the camera's frames a drive rendered,
            when the policy reads only those (the splat camera); absent = whole frames.
        options: The replay's or drive's options, as JSON.
        simulator: The simulator's options, as JSON.
        proj_string: pyproj string of the world frame the trajectory is written in.
        variation: The run's seeded start and speed variation (drives with one).
        splat_quality: The splat's quality along the run (the splat camera's drives).
        splat_gate: The splat quality gate's verdict on the run.
    """

    BROKEN_FIX: ClassVar[str] = RUN_BROKEN_FIX

    kind: Literal["replay", "drive"] | None = None
    method: str | None = None
    camera: str | None = None
    cameras: tuple[str, ...] | None = None
    frames: tuple[int, int] | None = None
    rendered: int | None = None
    policy: str | None = None
    seed: int | None = None
    sim: str | None = None
    steps: int | None = None
    seconds: float | None = None
    steps_per_s: float | None = None
    render_ms: float | None = None
    policy_ms: float | None = None
    rendered_rows: tuple[int, int] | None = None
    options: JsonObject | None = None
    simulator: JsonObject | None = None
    proj_string: str | None = None
    variation: dict[str, float] | None = None
    splat_quality: JsonObject | None = None
    splat_gate: JsonObject | None = None

    def save(self, path: Path) -> None:
        """Write ``run.json`` atomically, leaving out what the run did not record."""
        write_text_atomic(Path(path), self.model_dump_json(indent=2, exclude_none=True) + "\n")

    @property
    def label(self) -> str:
        """The method the run is scored as: ``method``, else ``camera``, else ``sim``."""
        return self.method or self.camera or "sim"


class EventRecord(pydantic.BaseModel):
    """One thing that happened in a run (collision, off_road, route_completed, policy_error...).

    Attributes:
        kind: What happened.
        t: Simulation time, seconds.
        x: Where (world frame, metres); None when not recorded.
        y: Where (world frame, metres); None when not recorded.
        reason: Free text (the policy's error, the car hit...).
    """

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    kind: str
    t: float = 0.0
    x: float | None = None
    y: float | None = None
    reason: str = ""


class RunEvents(Artifact):
    """``events.json``: the run's events in time order."""

    BROKEN_FIX: ClassVar[str] = RUN_BROKEN_FIX

    events: tuple[EventRecord, ...] = ()

    @pydantic.model_validator(mode="before")
    @classmethod
    def _bare_list(cls, data: object) -> object:
        """Accept the earliest format, a bare JSON list of events."""
        return {"events": data} if isinstance(data, list) else data
