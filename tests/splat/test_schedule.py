"""The learning-rate schedules: the means' decay (re-aimed when the cap moves) and the tail."""

from __future__ import annotations

import pytest

from cam2sim.splat.schedule import MEANS_END_SHARE, MeansDecay, tail_factor


def test_the_means_rate_reaches_its_end_at_the_cap_and_after_a_new_aim() -> None:
    decay = MeansDecay.over(2.0, 100)
    for _ in range(100):
        decay.advance()
    assert decay.lr == pytest.approx(2.0 * MEANS_END_SHARE)
    # Halfway, the cap moves from 100 to 60: the rest of the decay fits the 10 steps left.
    decay = MeansDecay.over(2.0, 100)
    for _ in range(50):
        decay.advance()
    halfway = decay.lr
    assert halfway == pytest.approx(2.0 * MEANS_END_SHARE**0.5)
    decay.aim(50, 60)
    for _ in range(10):
        decay.advance()
    assert decay.lr == pytest.approx(2.0 * MEANS_END_SHARE)


@pytest.mark.parametrize(
    ("step", "expected"),
    [(500, None), (1000, None), (1500, 0.1**0.5), (2000, 0.1), (2500, 0.1)],
)
def test_the_tail_falls_from_densification_to_the_cap(step: int, expected: float | None) -> None:
    factor = tail_factor(step, 1000, 2000, 0.1)
    if expected is None:
        assert factor is None
    else:
        assert factor == pytest.approx(expected)


def test_no_tail_when_the_cap_is_not_past_its_start() -> None:
    assert tail_factor(1500, 1000, 900, 0.1) is None
