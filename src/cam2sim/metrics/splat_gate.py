"""The splat quality gate: is a splat camera fit to stand in for the real one in closed loop?

A closed-loop run with the splat camera measures the system under test only where the splat
images are close to what the real camera would have seen; elsewhere its failures measure the
splat. Each drive with the splat camera records in its ``run.json`` the splat's quality along
the path it drove (:class:`SplatPathQuality`, the ``splat_quality`` block) and the verdict
(:class:`SplatGate`, ``splat_gate``); the drive metrics gather the runs of each method into one
verdict (:class:`MethodGate`, ``metrics.json``'s ``splat_gate``), and the behaviour table labels
an unfit method's column and says why.

The gate (thresholds are this module's constants; ``docs/metrics.md`` says why these):

1. **validated**: the splat has held-out scores (``WS/splat/eval.json``);
2. **held out**: against the recorded frames it never trained on, mean PSNR >=
   :data:`HELD_OUT_MIN_PSNR_DB` and mean SSIM >= :data:`HELD_OUT_MIN_SSIM`;
3. **truth** (only with a ground-truth world): against the noise-free truth camera at the
   held-out poses (on the path), mean PSNR >= :data:`TRUTH_MIN_PSNR_DB` and mean SSIM >=
   :data:`TRUTH_MIN_SSIM` (the same bar as check 2);
4. **envelope**: at most :data:`MAX_BEYOND_ENVELOPE` of the run's camera frames lie beyond the
   validated envelope.

**The validated envelope** is a coverage value (:class:`~cam2sim.splat.render.SplatRenderer`:
0 on a training view, toward 1 far from every one): the highest mean coverage at which the
splat was measured and passed. With a ground-truth world, that is the largest mean coverage of
the perturbations (on path, lateral offsets, yaw turns) that pass check 3's bar against the
truth; without one, the mean coverage of the held-out frames when they pass
check 2. A frame of the run is beyond it when its coverage is higher.

Limits: coverage is one number for distance and angle from the nearest training view, so a
held-out frame far along the path validates a lateral distance just as large, which the truth
envelope may show to be worse; coverage saturates toward 1 beyond about 3 m (or 45 degrees);
the thresholds are fixed, not fitted to any policy's sensitivity.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Final, Literal, Protocol

import numpy as np
import pydantic

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = [
    "HELD_OUT_MIN_PSNR_DB",
    "HELD_OUT_MIN_SSIM",
    "MAX_BEYOND_ENVELOPE",
    "THRESHOLDS",
    "TRUTH_MIN_PSNR_DB",
    "TRUTH_MIN_SSIM",
    "EnvelopePoint",
    "GateFailure",
    "MethodGate",
    "SplatGate",
    "SplatPathQuality",
    "SplatScores",
    "gate_methods",
    "gate_run",
    "path_quality",
    "unfit_label",
    "validated_envelope",
]


class _Summary(Protocol):
    @property
    def mean(self) -> float | None: ...


class _Perturbation(Protocol):
    """One row of a truth envelope: a perturbation and its scores against the truth."""

    @property
    def lateral_m(self) -> float: ...
    @property
    def yaw_deg(self) -> float: ...
    @property
    def psnr_db(self) -> _Summary: ...
    @property
    def ssim(self) -> _Summary: ...
    @property
    def lpips(self) -> _Summary: ...
    @property
    def coverage(self) -> _Summary: ...


class _Envelope(Protocol):
    @property
    def scores(self) -> Sequence[_Perturbation]: ...
    def on_path(self) -> _Perturbation | None: ...


class _Frame(Protocol):
    @property
    def coverage(self) -> float: ...


class SplatScores(Protocol):
    """What the gate reads of a splat's evaluation.

    :class:`cam2sim.splat.evaluate.SplatEval` (``WS/splat/eval.json``) is one; the gate reads
    the scores whoever computed them, and this package does not import the splat package,
    which imports the image metrics.
    """

    @property
    def psnr_db(self) -> _Summary:
        """Held-out PSNR, dB."""
        ...

    @property
    def ssim(self) -> _Summary:
        """Held-out SSIM."""
        ...

    @property
    def lpips(self) -> _Summary:
        """Held-out LPIPS."""
        ...

    @property
    def frames(self) -> Sequence[_Frame]:
        """The held-out frames, each with its coverage."""
        ...

    @property
    def truth(self) -> _Envelope | None:
        """The scores against the ground-truth world, if there is one."""
        ...


HELD_OUT_MIN_PSNR_DB: Final = 25.0
"""Least mean held-out PSNR against the recorded frames, dB."""
HELD_OUT_MIN_SSIM: Final = 0.80
"""Least mean held-out SSIM against the recorded frames."""
TRUTH_MIN_PSNR_DB: Final = HELD_OUT_MIN_PSNR_DB
"""Least mean PSNR against the noise-free truth on the path (and for a perturbation to count as
validated), dB."""
TRUTH_MIN_SSIM: Final = HELD_OUT_MIN_SSIM
"""Least mean SSIM against the noise-free truth on the path (and for a perturbation to count as
validated)."""
MAX_BEYOND_ENVELOPE: Final = 0.20
"""Largest share of a run's camera frames beyond the validated envelope."""
THRESHOLDS: Final = {
    "held_out_min_psnr_db": HELD_OUT_MIN_PSNR_DB,
    "held_out_min_ssim": HELD_OUT_MIN_SSIM,
    "truth_min_psnr_db": TRUTH_MIN_PSNR_DB,
    "truth_min_ssim": TRUTH_MIN_SSIM,
    "max_beyond_envelope": MAX_BEYOND_ENVELOPE,
}
"""The gate's thresholds by name (as ``metrics.json`` records them)."""

GateCheck = Literal["validated", "held_out", "truth", "envelope"]


class EnvelopePoint(pydantic.BaseModel):
    """The truth envelope at one perturbation: means over its frames (see ``eval.json``)."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    lateral_m: float
    yaw_deg: float
    psnr_db: float | None
    ssim: float | None
    lpips: float | None
    coverage: float | None


class SplatPathQuality(pydantic.BaseModel):
    """``run.json``'s ``splat_quality``: the splat along the path a run drove (module doc).

    Coverage values are the renderer's for each camera frame the policy saw; the held-out and
    truth scores are copied from ``eval.json`` (means), so the run states what it was driven
    with even if the models are trained again later.
    """

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    frames: int = pydantic.Field(description="Camera frames rendered")
    coverage_mean: float | None
    coverage_max: float | None
    envelope_coverage: float | None = pydantic.Field(
        description="The validated envelope (coverage); None where nothing passed"
    )
    envelope_source: Literal["truth", "held_out"] | None
    beyond_envelope_share: float | None = pydantic.Field(
        description="Share of frames with a coverage above the envelope"
    )
    held_out_psnr_db: float | None
    held_out_ssim: float | None
    held_out_lpips: float | None
    truth_psnr_db: float | None = pydantic.Field(description="On the path, against the truth")
    truth_ssim: float | None
    truth_lpips: float | None
    truth_envelope: list[EnvelopePoint] = pydantic.Field(default_factory=list)
    notes: list[str] = pydantic.Field(default_factory=list)


class GateFailure(pydantic.BaseModel):
    """One check a run failed, with its plain reason."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    check: GateCheck
    reason: str


class SplatGate(pydantic.BaseModel):
    """``run.json``'s ``splat_gate``: the verdict on one run."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    fit: bool
    failures: list[GateFailure] = pydantic.Field(default_factory=list)

    @property
    def reason(self) -> str:
        """Why the run is unfit ("" when fit)."""
        return "; ".join(f.reason for f in self.failures)


class MethodGate(pydantic.BaseModel):
    """``metrics.json``'s verdict on one method's splat runs (unfit when any run is)."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    method: str
    fit: bool
    runs: int
    unfit_runs: int
    reason: str = pydantic.Field(description="Why unfit, plainly; empty when fit")
    evidence: str = pydantic.Field(description="The measured values the verdict rests on")
    thresholds: dict[str, float] = pydantic.Field(default_factory=lambda: dict(THRESHOLDS))


def _meets(value: float | None, least: float) -> bool:
    return value is not None and value >= least


def validated_envelope(
    evaluation: SplatScores | None,
) -> tuple[float | None, Literal["truth", "held_out"] | None]:
    """The validated envelope (coverage) of an evaluation and where it comes from (module doc)."""
    if evaluation is None:
        return None, None
    if evaluation.truth is not None:
        passed = [
            row.coverage.mean
            for row in evaluation.truth.scores
            if _meets(row.psnr_db.mean, TRUTH_MIN_PSNR_DB)
            and _meets(row.ssim.mean, TRUTH_MIN_SSIM)
            and row.coverage.mean is not None
        ]
        return (max(passed), "truth") if passed else (None, "truth")
    psnr, ssim = evaluation.psnr_db.mean, evaluation.ssim.mean
    if psnr is None or ssim is None or psnr < HELD_OUT_MIN_PSNR_DB or ssim < HELD_OUT_MIN_SSIM:
        return None, "held_out"
    coverage = [f.coverage for f in evaluation.frames]
    return (float(np.mean(coverage)), "held_out") if coverage else (None, "held_out")


def path_quality(
    coverage: Sequence[float], evaluation: SplatScores | None, *, notes: Sequence[str] = ()
) -> SplatPathQuality:
    """The splat's quality along a driven path.

    Args:
        coverage: The renderer's coverage of each camera frame of the run.
        evaluation: The splat's ``eval.json`` (None: not evaluated).
        notes: Remarks to keep with it (why there is no evaluation, say).
    """
    cov = np.asarray(coverage, dtype=np.float64)
    envelope, source = validated_envelope(evaluation)
    beyond = float((cov > envelope).mean()) if envelope is not None and cov.size else None
    truth = evaluation.truth if evaluation is not None else None
    on_path = truth.on_path() if truth is not None else None
    points = [
        EnvelopePoint(
            lateral_m=row.lateral_m,
            yaw_deg=row.yaw_deg,
            psnr_db=row.psnr_db.mean,
            ssim=row.ssim.mean,
            lpips=row.lpips.mean,
            coverage=row.coverage.mean,
        )
        for row in (truth.scores if truth is not None else [])
    ]
    return SplatPathQuality(
        frames=int(cov.size),
        coverage_mean=float(cov.mean()) if cov.size else None,
        coverage_max=float(cov.max()) if cov.size else None,
        envelope_coverage=envelope,
        envelope_source=source,
        beyond_envelope_share=beyond,
        held_out_psnr_db=evaluation.psnr_db.mean if evaluation is not None else None,
        held_out_ssim=evaluation.ssim.mean if evaluation is not None else None,
        held_out_lpips=evaluation.lpips.mean if evaluation is not None else None,
        truth_psnr_db=on_path.psnr_db.mean if on_path is not None else None,
        truth_ssim=on_path.ssim.mean if on_path is not None else None,
        truth_lpips=on_path.lpips.mean if on_path is not None else None,
        truth_envelope=points,
        notes=list(notes),
    )


def _envelope_reason(share: float, envelope: float, *, runs: str = "") -> str:
    """``runs``: e.g. `` in 2/3 runs`` (then the share is the largest of them)."""
    most = "up to " if runs else ""
    return (
        f"splat driven off its envelope{runs}: {most}{share:.0%} of frames beyond the "
        f"validated coverage {envelope:.2f} (at most {MAX_BEYOND_ENVELOPE:.0%})"
    )


def gate_run(quality: SplatPathQuality) -> SplatGate:
    """The verdict on one run (the checks of the module doc, in order)."""
    q = quality
    failures: list[GateFailure] = []
    if q.held_out_psnr_db is None or q.held_out_ssim is None:
        why = "splat not validated: no held-out scores (WS/splat/eval.json; run cam2sim splat)"
        failures.append(GateFailure(check="validated", reason=why))
    else:
        low = []
        if q.held_out_psnr_db < HELD_OUT_MIN_PSNR_DB:
            low.append(f"held-out {q.held_out_psnr_db:.1f} dB < {HELD_OUT_MIN_PSNR_DB:g} dB")
        if q.held_out_ssim < HELD_OUT_MIN_SSIM:
            low.append(f"held-out SSIM {q.held_out_ssim:.2f} < {HELD_OUT_MIN_SSIM:.2f}")
        if low:
            failures.append(
                GateFailure(check="held_out", reason="splat under-trained: " + ", ".join(low))
            )
    low = []
    if q.truth_psnr_db is not None and q.truth_psnr_db < TRUTH_MIN_PSNR_DB:
        low.append(f"{q.truth_psnr_db:.1f} dB < {TRUTH_MIN_PSNR_DB:g} dB")
    if q.truth_ssim is not None and q.truth_ssim < TRUTH_MIN_SSIM:
        low.append(f"SSIM {q.truth_ssim:.2f} < {TRUTH_MIN_SSIM:.2f}")
    if low:
        why = "splat unlike the ground truth on the path: " + ", ".join(low)
        failures.append(GateFailure(check="truth", reason=why))
    share, envelope = q.beyond_envelope_share, q.envelope_coverage
    if share is not None and envelope is not None and share > MAX_BEYOND_ENVELOPE:
        failures.append(GateFailure(check="envelope", reason=_envelope_reason(share, envelope)))
    return SplatGate(fit=not failures, failures=failures)


def _evidence(q: SplatPathQuality) -> str:
    def num(value: float | None, spec: str) -> str:
        return "-" if value is None else format(value, spec)

    parts = [f"held-out {num(q.held_out_psnr_db, '.1f')} dB / SSIM {num(q.held_out_ssim, '.2f')}"]
    if q.truth_ssim is not None or q.truth_psnr_db is not None:
        parts.append(
            f"on path vs truth {num(q.truth_psnr_db, '.1f')} dB / SSIM {num(q.truth_ssim, '.2f')}"
        )
    if q.envelope_coverage is not None:
        parts.append(f"validated envelope coverage {q.envelope_coverage:.2f} ({q.envelope_source})")
    parts.append(
        f"driven coverage mean {num(q.coverage_mean, '.2f')}, max {num(q.coverage_max, '.2f')}"
    )
    return ", ".join(parts)


def gate_methods(runs: Sequence[tuple[str, SplatPathQuality]]) -> list[MethodGate]:
    """One verdict per method over its runs' ``(method, quality)``, in order of first run.

    A method is unfit when any of its runs is; its reason lists each failed check once (for the
    envelope: how many runs left it and the largest share of frames beyond it).
    """
    by_method: dict[str, list[SplatPathQuality]] = {}
    for method, quality in runs:
        by_method.setdefault(method, []).append(quality)
    out = []
    for method, qualities in by_method.items():
        gates = [gate_run(q) for q in qualities]
        reasons: list[str] = []
        off = [
            (q.beyond_envelope_share or 0.0, q.envelope_coverage or 0.0)
            for q, g in zip(qualities, gates, strict=True)
            if any(f.check == "envelope" for f in g.failures)
        ]
        for g in gates:
            reasons += [f.reason for f in g.failures if f.check != "envelope"]
        if off:
            share, envelope = max(off)
            many = f" in {len(off)}/{len(gates)} runs" if len(gates) > 1 else ""
            reasons.append(_envelope_reason(share, envelope, runs=many))
        unfit = sum(not g.fit for g in gates)
        worst = max(qualities, key=lambda q: q.beyond_envelope_share or 0.0)
        out.append(
            MethodGate(
                method=method,
                fit=unfit == 0,
                runs=len(gates),
                unfit_runs=unfit,
                reason="; ".join(dict.fromkeys(reasons)),
                evidence=_evidence(worst),
            )
        )
    return out


def unfit_label(label: str) -> str:
    """A method's column label once its splat runs failed the gate."""
    return f"{label} (unfit)"
