"""The benchmark's figures across streets: failure rates with intervals, paired differences.

Each world of a suite (``cam2sim bench``) ends in a :class:`WorldResult`: its behaviour per
method (Real, splat, Sim; the drive metrics' method summaries), its splat's quality and its
failures. :func:`aggregate` puts them together:

- **failure rate per method** over every closed-loop run of every world (Real's recorded drive
  left out), with a 95 % Wilson score interval
  (:func:`wilson_interval`). Runs of one street share the street, so the interval is narrower
  than one over streets would be; the per-street figures below carry the spread between
  streets;
- **per street, splat against Real** (paired: same street, same seeds): the difference of the
  closed-loop failure rates (Real's recorded drive left out: it completes by construction) and
  the ratio of the mean Min-Fréchet distances, with a 95 % bootstrap interval over the runs
  (:func:`ratio_interval`): three runs a method leave the ratio uncertain, and the interval
  says by how much;
- **the verdict**: splat is *indistinguishable from Real* on a street when it fails no more
  often than Real's closed-loop runs there and its Min-Fréchet distance is at most
  :data:`FRECHET_RATIO_MAX` times Real's (or every run of both fails, so neither has one);
  *Sim fails* on a street when one of its runs fails. Where Sim does not fail, its
  corridor violations and Min-Fréchet ratio are what separate it from Real. The verdict also
  counts the streets whose ratio is over the line beyond doubt (its whole interval above it),
  and gives the range of the streets' splat-to-twin distances (each splat run against the
  closed-loop Real run of its seed), which the draw of the starts does not move as it moves
  the ratio's divisor (docs/benchmarks.md, "Seven untuned streets again with their own seeds").

The Real group is what the behaviour table's is (``docs/metrics.md``): the recorded drive plus
the closed-loop runs in the ground-truth world. Rates count the closed-loop runs alone, so each
method has the same number per street; Min-Fréchet and the corridor keep the group's averages.
"""

from __future__ import annotations

import math
from typing import Final

import pydantic

from cam2sim.core.schema import Artifact

__all__ = [
    "FRECHET_RATIO_MAX",
    "Aggregate",
    "FailureRow",
    "MethodRate",
    "MethodRow",
    "StreetPair",
    "WorldResult",
    "aggregate",
    "ratio_interval",
    "wilson_interval",
]

FRECHET_RATIO_MAX: Final = 1.5
"""Splat's Min-Fréchet may be this many times Real's on a street it matches Real on."""
METHODS: Final = ("Real", "splat", "Sim")


class _Model(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)


class MethodRow(_Model):
    """One method's behaviour on one street (a column of its behaviour table).

    ``runs`` and ``failures`` count the whole group, the recorded drives included (Real's
    first run; it completes by construction); ``recorded`` says how many there are, so
    ``closed_loop_runs`` compares like with like.
    """

    method: str
    runs: int
    failures: int
    recorded: int = 0
    completion_mean: float
    min_frechet_m: float | None
    corridor_violation_pct: float | None
    jitter: float | None
    failure_types: dict[str, int] = pydantic.Field(default_factory=dict)
    min_frechet_runs_m: list[float] = pydantic.Field(
        default_factory=list,
        description="Min-Fréchet of each run that completed (min_frechet_m is their mean)",
    )
    twin_frechet_runs_m: list[float] = pydantic.Field(
        default_factory=list,
        description=(
            "Fréchet distance of each completed closed-loop run to the Real run of its seed "
            "(its twin: the same drawn start, the truth world's camera); empty for Real and "
            "for results made before it was measured"
        ),
    )

    @property
    def twin_frechet_m(self) -> float | None:
        """The mean of :attr:`twin_frechet_runs_m`, or None where none was measured."""
        return _mean(self.twin_frechet_runs_m)

    @property
    def closed_loop_runs(self) -> int:
        """Closed-loop runs of the method (the recorded drives left out)."""
        return self.runs - self.recorded

    @property
    def closed_loop_rate(self) -> float | None:
        """Failures per closed-loop run (a recorded drive never fails), or None without runs."""
        n = self.closed_loop_runs
        return self.failures / n if n > 0 else None


class FailureRow(_Model):
    """One failed run: what happened, where, and what the cameras saw there."""

    method: str
    run: str
    kind: str
    reason: str = ""
    s_m: float | None = None
    route_share: float | None = None
    image: str | None = pydantic.Field(None, description="the views at the failure (PNG)")
    views: list[str] = pydantic.Field(default_factory=list)
    views_psnr_db: list[float | None] = pydantic.Field(default_factory=list)
    splat_psnr_on_path_db: float | None = None


class WorldResult(Artifact):
    """``BENCH/worlds/<label>/result.json``: one street of the suite, all its figures."""

    label: str
    spec_id: str = pydantic.Field(
        "",
        description="the suite world's id (label and a hash of what it ran: its route, seeds, "
        "settings); empty in results written before it was recorded",
    )
    run_seed: int | None = pydantic.Field(None, description="seed of the world's first run")
    title: str
    tuned: bool
    source: str
    notes: list[str] = pydantic.Field(default_factory=list)
    route_m: float | None = None
    seconds: float
    step_seconds: dict[str, float] = pydantic.Field(default_factory=dict)
    splat_device: str | None = None
    splat_steps: list[int] = pydantic.Field(default_factory=list)
    splat_stopped: list[str] = pydantic.Field(default_factory=list)
    splat_start_gaussians: list[int] = pydantic.Field(
        default_factory=list, description="each chunk's street Gaussians when it started"
    )
    splat_gaussians: list[int] = pydantic.Field(
        default_factory=list, description="each chunk's street Gaussians when it stopped"
    )
    splat_held_out_psnr_db: float | None = None
    splat_held_out_ssim: float | None = None
    splat_truth_psnr_db: dict[str, float | None] = pydantic.Field(default_factory=dict)
    methods: list[MethodRow]
    failures: list[FailureRow] = pydantic.Field(default_factory=list)
    profile: dict[str, object] | None = None

    def method(self, name: str) -> MethodRow | None:
        """The row of method ``name`` (Real, splat, Sim), or None."""
        return next((m for m in self.methods if m.method == name), None)


class MethodRate(_Model):
    """A method's failure rate over all streets, with its 95 % Wilson interval."""

    method: str
    streets: int
    runs: int
    failures: int
    rate: float
    low: float
    high: float
    streets_failing: int
    min_frechet_m: float | None
    corridor_violation_pct: float | None


class StreetPair(_Model):
    """Splat against Real (and Sim) on one street."""

    label: str
    tuned: bool
    real_failures: str = pydantic.Field(description="closed-loop failures / runs")
    splat_failures: str
    sim_failures: str
    failure_rate_diff: float | None
    frechet_ratio: float | None
    frechet_ratio_low: float | None = None
    frechet_ratio_high: float | None = None
    splat_twin_frechet_m: float | None = pydantic.Field(
        None,
        description=(
            "mean Fréchet distance of the splat runs to their Real twins (same seed, same "
            "start: what the splat's images alone changed), metres"
        ),
    )
    splat_matches_real: bool | None
    sim_fails: bool | None
    sim_corridor_excess_pct: float | None


class Aggregate(_Model):
    """Every figure across the streets of a suite."""

    streets: int
    rates: list[MethodRate]
    pairs: list[StreetPair]
    verdict: str
    matched: int
    compared: int
    sim_failing: int
    frechet_within: int
    frechet_over_beyond_doubt: int = 0
    frechet_intervals: int = 0


def wilson_interval(failures: int, runs: int, z: float = 1.959964) -> tuple[float, float]:
    """The Wilson score interval of a rate ``failures / runs`` (95 % by default).

    Unlike the normal approximation it stays within [0, 1] and is not empty at 0 or ``runs``
    failures (0 of 30 runs still allows up to 11.4 %).
    """
    if runs <= 0:
        return (0.0, 1.0)
    p = failures / runs
    z2 = z * z
    centre = (p + z2 / (2 * runs)) / (1 + z2 / runs)
    half = z * math.sqrt(p * (1 - p) / runs + z2 / (4 * runs * runs)) / (1 + z2 / runs)
    return (max(0.0, centre - half), min(1.0, centre + half))


def ratio_interval(
    numerator: list[float],
    denominator: list[float],
    *,
    level: float = 0.95,
    draws: int = 4_000,
    seed: int = 0,
) -> tuple[float, float] | None:
    """A bootstrap interval of ``mean(numerator) / mean(denominator)``.

    Each side's runs are drawn again with replacement (``draws`` times, seeded, so the report
    is the same on every machine) and the ratio's ``(1 - level) / 2`` and ``(1 + level) / 2``
    quantiles are returned. With three or four runs a side the percentile bootstrap is, if
    anything, too narrow: an interval wholly above a line says the ratio is over it; one that
    straddles it says the runs cannot tell.

    Returns:
        ``(low, high)``, or None with fewer than two values on either side or a denominator
        that can be zero.
    """
    import numpy as np  # noqa: PLC0415 -- lazy: the module is read by light tools

    if len(numerator) < 2 or len(denominator) < 2 or min(denominator) <= 0:
        return None
    rng = np.random.default_rng(seed)
    top = np.asarray(numerator, dtype=np.float64)
    bottom = np.asarray(denominator, dtype=np.float64)
    top_means = top[rng.integers(0, top.size, (draws, top.size))].mean(axis=1)
    bottom_means = bottom[rng.integers(0, bottom.size, (draws, bottom.size))].mean(axis=1)
    low, high = np.quantile(top_means / bottom_means, [(1 - level) / 2, (1 + level) / 2])
    return float(low), float(high)


def _mean(values: list[float]) -> float | None:
    return sum(values) / len(values) if values else None


def _rate(method: str, worlds: list[WorldResult]) -> MethodRate:
    rows = [r for w in worlds if (r := w.method(method)) is not None]
    runs = sum(r.closed_loop_runs for r in rows)
    failures = sum(r.failures for r in rows)
    low, high = wilson_interval(failures, runs)
    return MethodRate(
        method=method,
        streets=len(rows),
        runs=runs,
        failures=failures,
        rate=failures / runs if runs else 0.0,
        low=low,
        high=high,
        streets_failing=sum(r.failures > 0 for r in rows),
        min_frechet_m=_mean([r.min_frechet_m for r in rows if r.min_frechet_m is not None]),
        corridor_violation_pct=_mean(
            [r.corridor_violation_pct for r in rows if r.corridor_violation_pct is not None]
        ),
    )


def _count(row: MethodRow | None) -> str:
    """Closed-loop failures / closed-loop runs."""
    return "-" if row is None else f"{row.failures}/{row.closed_loop_runs}"


def _pair(world: WorldResult) -> StreetPair:
    real, splat, sim = (world.method(m) for m in METHODS)
    diff = ratio = excess = None
    matches = sim_fails = None
    interval = None
    real_rate = None if real is None else real.closed_loop_rate
    splat_rate = None if splat is None else splat.closed_loop_rate
    if real is not None and splat is not None and real_rate is not None and splat_rate is not None:
        diff = splat_rate - real_rate
        if splat.min_frechet_m is not None and real.min_frechet_m:
            ratio = splat.min_frechet_m / real.min_frechet_m
            interval = ratio_interval(splat.min_frechet_runs_m, real.min_frechet_runs_m)
        all_fail = splat.min_frechet_m is None and splat_rate == 1.0 and real_rate == 1.0
        close = ratio is not None and ratio <= FRECHET_RATIO_MAX
        matches = diff <= 0.0 and (close or all_fail)
    if sim is not None and sim.runs:
        sim_fails = sim.failures > 0
        if real is not None and sim.corridor_violation_pct is not None:
            excess = sim.corridor_violation_pct - (real.corridor_violation_pct or 0.0)
    return StreetPair(
        label=world.label,
        tuned=world.tuned,
        real_failures=_count(real),
        splat_failures=_count(splat),
        sim_failures=_count(sim),
        failure_rate_diff=diff,
        frechet_ratio=ratio,
        frechet_ratio_low=None if interval is None else interval[0],
        frechet_ratio_high=None if interval is None else interval[1],
        splat_twin_frechet_m=None if splat is None else splat.twin_frechet_m,
        splat_matches_real=matches,
        sim_fails=sim_fails,
        sim_corridor_excess_pct=excess,
    )


def aggregate(worlds: list[WorldResult]) -> Aggregate:
    """The suite's figures over ``worlds`` (see the module's description)."""
    pairs = [_pair(w) for w in worlds]
    compared = [p for p in pairs if p.splat_matches_real is not None]
    matched = sum(bool(p.splat_matches_real) for p in compared)
    sim_failing = sum(bool(p.sim_fails) for p in pairs)
    within = sum(
        p.frechet_ratio is not None and p.frechet_ratio <= FRECHET_RATIO_MAX for p in pairs
    )
    with_sim = sum(p.sim_fails is not None for p in pairs)
    lows = [p.frechet_ratio_low for p in pairs if p.frechet_ratio_low is not None]
    over = sum(low > FRECHET_RATIO_MAX for low in lows)
    verdict = (
        f"splat indistinguishable from Real on {matched} of {len(compared)} streets "
        f"(fails no more often, Min-Fréchet within {FRECHET_RATIO_MAX:g}x); "
        f"Sim fails on {sim_failing} of {with_sim}"
    )
    if lows:
        verdict += (
            f"; Min-Fréchet over {FRECHET_RATIO_MAX:g}x beyond its 95 % interval on {over} of "
            f"{len(lows)}"
        )
    twins = [p.splat_twin_frechet_m for p in pairs if p.splat_twin_frechet_m is not None]
    if twins:
        verdict += (
            f"; splat runs {min(twins):.2f}-{max(twins):.2f} m from their Real twins on "
            f"{len(twins)} of {len(pairs)}"
        )
    return Aggregate(
        streets=len(worlds),
        rates=[_rate(m, worlds) for m in METHODS],
        pairs=pairs,
        verdict=verdict,
        matched=matched,
        compared=len(compared),
        sim_failing=sim_failing,
        frechet_within=within,
        frechet_over_beyond_doubt=over,
        frechet_intervals=len(lows),
    )
