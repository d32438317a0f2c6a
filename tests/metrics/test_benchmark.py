"""The benchmark's figures across streets: Wilson intervals, paired splat-Real, the verdict."""

from __future__ import annotations

import math

import pytest

from cam2sim.metrics.benchmark import (
    MethodRow,
    WorldResult,
    aggregate,
    ratio_interval,
    wilson_interval,
)


def test_wilson_interval_matches_the_textbook_values() -> None:
    # Agresti & Coull's and R's prop.test(correct=FALSE) values.
    low, high = wilson_interval(5, 10)
    assert low == pytest.approx(0.2366, abs=1e-4)
    assert high == pytest.approx(0.7634, abs=1e-4)
    low, high = wilson_interval(0, 30)
    assert low == 0.0
    assert high == pytest.approx(0.1135, abs=1e-4)  # 0 of 30 still allows 11 %
    low, high = wilson_interval(30, 30)
    assert high == 1.0
    assert low == pytest.approx(1 - 0.1135, abs=1e-4)


def test_wilson_interval_narrows_with_runs_and_is_defined_without_any() -> None:
    assert wilson_interval(0, 0) == (0.0, 1.0)
    widths = [math.fsum((-a, b)) for a, b in (wilson_interval(n // 10, n) for n in (10, 100, 1000))]
    assert widths[0] > widths[1] > widths[2]


def _row(method: str, runs: int, failures: int, frechet: float | None, corridor: float = 50.0,
         recorded: int = 0) -> MethodRow:  # fmt: skip
    return MethodRow(
        method=method,
        runs=runs,
        failures=failures,
        recorded=recorded,
        completion_mean=1.0,
        min_frechet_m=frechet,
        corridor_violation_pct=corridor,
        jitter=1.0,
    )


def _world(label: str, real: tuple[int, float | None], splat: tuple[int, float | None],
           sim: tuple[int, float | None], *, tuned: bool = False) -> WorldResult:  # fmt: skip
    return WorldResult(
        label=label,
        title=label,
        tuned=tuned,
        source="test",
        seconds=1.0,
        methods=[
            _row("Real", 4, real[0], real[1], 40.0, recorded=1),
            _row("splat", 3, splat[0], splat[1], 50.0),
            _row("Sim", 3, sim[0], sim[1], 90.0),
        ],
    )


def test_aggregate_counts_closed_loop_runs_and_judges_each_street() -> None:
    worlds = [
        _world("same", (0, 0.4), (0, 0.5), (3, None), tuned=True),
        _world("far", (0, 0.4), (0, 0.8), (0, 2.0)),  # splat 2x Real's Min-Frechet
        _world("worse", (0, 0.4), (1, 0.5), (3, None)),  # splat fails where Real never does
        _world("policy", (3, None), (3, None), (3, None)),  # every run fails: the policy's fault
    ]
    agg = aggregate(worlds)
    rates = {r.method: r for r in agg.rates}
    # Real's recorded drive is left out: 3 closed-loop runs a street, as for the others.
    assert (rates["Real"].runs, rates["Real"].failures) == (12, 3)
    assert (rates["splat"].runs, rates["splat"].failures) == (12, 4)
    assert rates["splat"].low < 4 / 12 < rates["splat"].high
    assert rates["Sim"].streets_failing == 3
    pairs = {p.label: p for p in agg.pairs}
    assert pairs["same"].splat_matches_real is True
    assert pairs["far"].splat_matches_real is False
    assert pairs["far"].frechet_ratio == pytest.approx(2.0)
    assert pairs["worse"].splat_matches_real is False
    assert pairs["worse"].failure_rate_diff == pytest.approx(1 / 3)
    assert pairs["policy"].splat_matches_real is True
    assert pairs["policy"].real_failures == "3/3"
    assert pairs["far"].sim_fails is False
    assert pairs["far"].sim_corridor_excess_pct == pytest.approx(50.0)
    assert (agg.matched, agg.compared, agg.sim_failing) == (2, 4, 3)
    assert agg.verdict.startswith("splat indistinguishable from Real on 2 of 4 streets")
    assert agg.verdict.endswith("Sim fails on 3 of 4")


def test_the_ratio_interval_holds_the_ratio_and_widens_with_the_spread_of_the_runs() -> None:
    assert ratio_interval([0.2, 0.2, 0.2], [0.1, 0.1, 0.1, 0.1]) == pytest.approx((2.0, 2.0))
    assert ratio_interval([0.2], [0.1, 0.1]) is None  # one run says nothing of the spread
    assert ratio_interval([0.2, 0.3], [0.0, 0.1]) is None  # a Real mean of 0 has no ratio
    tight = ratio_interval([0.24, 0.25, 0.26], [0.13, 0.14, 0.14, 0.13])
    loose = ratio_interval([0.10, 0.21, 0.32], [0.04, 0.18, 0.04, 0.18])
    assert tight is not None
    assert loose is not None
    assert tight[0] < 0.25 / 0.135 < tight[1]
    assert tight[0] > 1.5  # over the line beyond doubt
    assert loose[0] < 1.5 < loose[1]  # the runs cannot tell
    assert loose[1] - loose[0] > 3 * (tight[1] - tight[0])
    assert ratio_interval([0.10, 0.21, 0.32], [0.04, 0.18, 0.04, 0.18]) == loose  # seeded


def test_the_verdict_counts_the_streets_over_the_line_beyond_doubt() -> None:
    def world(label: str, splat: list[float], real: list[float]) -> WorldResult:
        w = _world(label, (0, sum(real) / len(real)), (0, sum(splat) / len(splat)), (3, None))
        rows = {"Real": real, "splat": splat}
        methods = [m.model_copy(update={"min_frechet_runs_m": rows.get(m.method, [])})
                   for m in w.methods]  # fmt: skip
        return w.model_copy(update={"methods": methods})

    agg = aggregate([
        world("over", [0.24, 0.25, 0.26], [0.13, 0.14, 0.14, 0.13]),
        world("unclear", [0.10, 0.21, 0.32], [0.04, 0.18, 0.04, 0.18]),
        world("under", [0.10, 0.11, 0.10], [0.10, 0.12, 0.11, 0.10]),
        _world("old", (0, 0.1), (0, 0.2), (3, None)),  # a result without its runs' values
    ])  # fmt: skip
    pairs = {p.label: p for p in agg.pairs}
    assert pairs["over"].frechet_ratio_low is not None
    assert pairs["over"].frechet_ratio_low > 1.5
    assert pairs["old"].frechet_ratio_low is None
    assert (agg.frechet_within, agg.frechet_over_beyond_doubt, agg.frechet_intervals) == (1, 1, 3)
    assert agg.verdict.endswith("; Min-Fréchet over 1.5x beyond its 95 % interval on 1 of 3")


def test_the_verdict_gives_the_range_of_the_splat_runs_distance_to_their_twins() -> None:
    def world(label: str, twins: list[float]) -> WorldResult:
        w = _world(label, (0, 0.1), (0, 0.12), (3, None))
        methods = [
            m.model_copy(update={"twin_frechet_runs_m": twins if m.method == "splat" else []})
            for m in w.methods
        ]
        return w.model_copy(update={"methods": methods})

    agg = aggregate([world("near", [0.02, 0.03, 0.01]), world("far", [0.28, 0.27, 0.29]),
                     world("old", [])])  # fmt: skip
    pairs = {p.label: p for p in agg.pairs}
    assert pairs["near"].splat_twin_frechet_m == pytest.approx(0.02)
    assert pairs["old"].splat_twin_frechet_m is None
    assert agg.verdict.endswith("; splat runs 0.02-0.28 m from their Real twins on 2 of 3")
    # Without any twin distance the verdict ends as before.
    assert aggregate([world("old", [])]).verdict.endswith("Sim fails on 1 of 1")
