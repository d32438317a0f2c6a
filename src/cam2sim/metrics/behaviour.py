"""The behaviour table: Real / splat / Sim side by side, in the paper's layout.

Closed-loop runs in the ground-truth world (the ``truth`` camera, run method ``real``) are
real-world drives. :func:`evaluate_with_real_runs` makes them part of the Real group: the
recorded drive and every closed-loop real run that completes the route are the references (the
reference path, the segment and the corridor come from them, and each is scored leave-one-out
against the others); a closed-loop real run that fails is scored against the references like a
simulated run and counts in the Real group's failure rate. ``docs/metrics.md`` says why.

:func:`behaviour_table` lays the per-method summaries out as the paper does: one column per
method (Real, then the simulated ones), one row per metric. Runs with the splat camera carry
the splat's quality along their path (``run.json``); :func:`evaluate_with_real_runs` puts the
splat quality gate's verdict per method into the metrics (:mod:`cam2sim.metrics.splat_gate`),
and the table labels a method that failed it ``splat (unfit)`` with the reason under the table:
its failures measure the splat, not the system under test.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Final

from cam2sim.metrics.drive_io import DriveRun
from cam2sim.metrics.drive_quality import evaluate_drives
from cam2sim.metrics.splat_gate import gate_methods, unfit_label

if TYPE_CHECKING:
    from collections.abc import Sequence

    from cam2sim.metrics.drive_quality import (
        DriveEvaluation,
        DriveMetrics,
        DriveOptions,
        MethodSummary,
        Segment,
    )
    from cam2sim.scenario.model import Scenario

__all__ = [
    "CAMERA_LABELS",
    "METHOD_COLOURS",
    "METHOD_LABELS",
    "REAL_METHOD",
    "BehaviourTable",
    "behaviour_table",
    "evaluate_with_real_runs",
    "recorded_drive",
]

REAL_METHOD: Final = "real"
"""The method of real drives, recorded or closed loop in the ground-truth world."""
METHOD_LABELS: Final = {
    REAL_METHOD: "Real",
    "drive-splat": "splat",
    "drive-raster": "Sim",
    "drive-carla": "CARLA",
    "drive-none": "no camera",
}
"""Column names of the behaviour table (other methods keep their own name)."""
CAMERA_LABELS: Final = {
    "truth": "Real",
    "splat": "splat",
    "raster": "Sim",
    "carla": "Sim (CARLA)",
    "none": "no camera",
}
"""The paper's name of what a camera shows, wherever a camera is named to a reader."""
METHOD_COLOURS: Final = {"Real": "#1b7837", "splat": "#2166ac", "Sim": "#b2182b"}
"""One colour per method (by its label), in every plot of the reports."""


def recorded_drive(scenario: Scenario, *, source: str = "") -> DriveRun:
    """The scenario's recorded drive (its reference-point trajectory) as a real run."""
    import numpy as np  # noqa: PLC0415

    tr = scenario.trajectory
    return DriveRun(
        name=f"{REAL_METHOD}/recorded",
        method=REAL_METHOD,
        real=True,
        t=np.asarray(tr.t, dtype=np.float64),
        xy=np.asarray(tr.reference, dtype=np.float64)[:, :2],
        crs=scenario.world.proj_string,
        source=source,
    )


def evaluate_with_real_runs(
    recorded: Sequence[DriveRun],
    runs: Sequence[DriveRun],
    *,
    segment: Segment | None = None,
    options: DriveOptions | None = None,
) -> DriveEvaluation:
    """Score runs against the recorded drives, closed-loop real runs joining the Real group.

    Args:
        recorded: The recorded drives (``real=True``).
        runs: Closed-loop runs; those of method :data:`REAL_METHOD` are real-world runs.
        segment: A saved segment to score against (None: computed from the references).
        options: Metric parameters.

    Returns:
        The evaluation; its Real group holds the recorded drives and every closed-loop real
        run, completed ones as references, failed ones scored against them. Its metrics hold
        the splat quality gate's verdict for each method whose runs recorded splat quality.
    """
    closed = [r for r in runs if r.method == REAL_METHOD]
    others = [r for r in runs if r.method != REAL_METHOD]
    done: set[str] = set()
    if closed:
        probe = evaluate_drives(list(recorded), closed, segment=segment, options=options)
        done = {m.name for m in probe.metrics.runs if not m.real and m.success}
    references = [*recorded, *(replace(r, real=True) for r in closed if r.name in done)]
    failed = [r for r in closed if r.name not in done]
    ev = evaluate_drives(references, failed + others, segment=segment, options=options)

    gates = gate_methods([(r.method, r.splat_quality) for r in runs if r.splat_quality])
    if not gates:
        return ev
    return replace(ev, metrics=ev.metrics.model_copy(update={"splat_gate": gates}))


@dataclass(frozen=True)
class BehaviourTable:
    """The paper's behaviour table: ``rows`` of ``(metric, value per column)``.

    ``notes`` are lines that belong under the table (a method that failed the splat quality
    gate, and why).
    """

    columns: tuple[str, ...]
    rows: tuple[tuple[str, tuple[str, ...]], ...]
    notes: tuple[str, ...] = ()

    def markdown(self) -> str:
        """The table as Markdown (its notes under it)."""
        lines = [
            "| metric | " + " | ".join(self.columns) + " |",
            "|---|" + "---:|" * len(self.columns),
        ]
        lines += [f"| {name} | " + " | ".join(values) + " |" for name, values in self.rows]
        if self.notes:
            lines += ["", *self.notes]
        return "\n".join(lines) + "\n"


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def _order(methods: Sequence[MethodSummary]) -> list[MethodSummary]:
    """Real first, then splat, Sim, then the others in their order."""
    rank = {m: i for i, m in enumerate(METHOD_LABELS)}
    return sorted(methods, key=lambda s: rank.get(s.method, len(rank)))


def behaviour_table(metrics: DriveMetrics) -> BehaviourTable:
    """The per-method summaries of ``metrics`` in the paper's layout.

    Failure rate and completion count every run of a method; Min-Fréchet, corridor violations
    and the excesses average the successful runs; jitter averages all runs. Failure types are
    ``OR-CC-OS-US`` counts (out of road, car crash, oversteer, understeer). "to Real twin" is
    the mean Fréchet distance of the successful runs to the real run of their seed. A method that
    failed the splat quality gate is labelled ``(unfit)``, with a note giving the reason.
    """
    methods = _order(metrics.methods)
    gates = {g.method: g for g in metrics.splat_gate}
    labels = {s.method: METHOD_LABELS.get(s.method, s.method) for s in methods}
    notes = []
    for method, gate in gates.items():
        if method in labels and not gate.fit:
            labels[method] = unfit_label(labels[method])
            notes.append(
                f"{labels[method]}: {gate.reason}. Its runs fail the splat quality gate "
                f"({gate.unfit_runs}/{gate.runs}), so its column measures the splat, not the "
                "system under test."
            )
    columns = tuple(labels[s.method] for s in methods)

    def row(name: str, values: list[str]) -> tuple[str, tuple[str, ...]]:
        return name, tuple(values)

    def types(s: MethodSummary) -> str:
        ft = s.failure_types
        return f"{ft['out_of_road']}-{ft['collision']}-{ft['oversteer']}-{ft['understeer']}"

    rows = (
        row("runs", [str(s.runs) for s in methods]),
        row("failure rate", [f"{s.runs - s.successes}/{s.runs}" for s in methods]),
        row(
            "completion avg-max-min",
            [
                f"{s.completion_mean:.2f}-{s.completion_max:.2f}-{s.completion_min:.2f}"
                for s in methods
            ],
        ),
        row("failure types OR-CC-OS-US", [types(s) for s in methods]),
        row("Min-Fréchet (m)", [_fmt(s.avg_min_frechet_m, ".2f") for s in methods]),
        row("to Real twin (m)", [_fmt(s.avg_twin_frechet_m, ".2f") for s in methods]),
        row(
            "corridor violations (%)", [_fmt(s.avg_corridor_violation_pct, ".1f") for s in methods]
        ),
        row("mean excess (m)", [_fmt(s.avg_mean_excess_m, ".3f") for s in methods]),
        row("excess when out (m)", [_fmt(s.avg_mean_excess_when_out_m, ".3f") for s in methods]),
        row("steering jitter (units/s)", [_fmt(s.avg_jitter, ".3f") for s in methods]),
        row("max jitter (units/s)", [_fmt(s.max_jitter, ".3f") for s in methods]),
    )
    return BehaviourTable(columns=columns, rows=rows, notes=tuple(notes))
