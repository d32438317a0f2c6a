"""The along-route profile's records: PSNR and the policy's steering on both views."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cam2sim.metrics.benchmark import WorldResult
from cam2sim.report.bench import (
    gap_figure,
    gap_prediction,
    rank_correlation,
    steering_gain,
    steering_gap_mean,
    steering_gap_peak,
)
from cam2sim.stages.route_profile import RouteProfile


def _profile(with_policy: bool) -> RouteProfile:
    psnr = np.array([[25.0, 26.0, math.nan], [27.0, 26.5, 24.0], [25.5, 25.0, 23.0]])
    truth = np.array([[0.1, 0.2, 0.3], [0.0, -0.5, 1.0], [0.2, 0.1, 0.0]])
    splat = truth + np.array([[0.0, 0.0, 0.0], [0.1, -0.9, 0.3], [0.0, 0.0, 2.0]])
    return RouteProfile(
        s_m=np.array([0.0, 10.0, 20.0]),
        offsets_m=(-1.0, 0.0, 1.0),
        psnr_db=psnr,
        steering_truth=truth if with_policy else None,
        steering_splat=splat if with_policy else None,
        policy="ws/ads/dave2.onnx" if with_policy else None,
    )


def test_the_steering_gap_is_splat_minus_truth_and_its_peak_is_on_the_path() -> None:
    prof = _profile(with_policy=True)
    gap = prof.steering_gap()
    assert gap is not None
    np.testing.assert_allclose(gap[1], [0.1, -0.9, 0.3])
    data = prof.to_json()
    assert data["psnr_db"][0][2] is None  # type: ignore[index]  # NaN: not scored
    assert data["steering_splat"][1][1] == pytest.approx(-1.4)  # type: ignore[index]
    world = WorldResult.model_construct(profile=data)
    # The largest gap on the path (offset 0): 0.9 at 10 m; the 2.0 at +1 m is off the path.
    peak = steering_gap_peak(world)
    assert peak is not None
    assert peak[0] == pytest.approx(0.9)
    assert peak[1] == 10.0
    # On the path the splat steers (0.1, -1.4, 1.3) where the truth steers (0, -0.5, 1.0).
    assert steering_gain(world) == pytest.approx((0.7 + 1.3) / 1.25)


def test_the_steering_gain_is_one_where_the_policy_acts_alike_and_grows_with_harder_turns() -> None:
    truth = [[0.0] * 4, [0.5, -2.0, 1.5, 0.0], [0.0] * 4]
    profile = {"s_m": [0.0, 10.0, 20.0, 30.0], "offsets_m": [-1.0, 0.0, 1.0],
               "steering_truth": truth}  # fmt: skip
    same = WorldResult.model_construct(profile=profile | {"steering_splat": truth})
    harder = [[1.1 * v for v in row] for row in truth]
    bends = WorldResult.model_construct(profile=profile | {"steering_splat": harder})
    assert steering_gain(same) == pytest.approx(1.0)
    assert steering_gain(bends) == pytest.approx(1.1)
    straight = {"s_m": [0.0], "offsets_m": [0.0], "steering_truth": [[0.0]],
                "steering_splat": [[0.3]]}  # fmt: skip
    assert steering_gain(WorldResult.model_construct(profile=straight)) is None


def test_the_mean_steering_gap_is_taken_on_the_path() -> None:
    world = WorldResult.model_construct(profile=_profile(with_policy=True).to_json())
    assert steering_gap_mean(world) == pytest.approx((0.1 + 0.9 + 0.3) / 3)
    assert steering_gap_mean(WorldResult.model_construct(profile=None)) is None


def test_rank_correlation_is_spearmans() -> None:
    assert rank_correlation([1.0, 2.0, 3.0, 4.0], [10.0, 20.0, 40.0, 30.0]) == pytest.approx(0.8)
    assert rank_correlation([1.0, 2.0, 3.0], [3.0, 2.0, 1.0]) == pytest.approx(-1.0)
    # ties share their mean rank: ranks (1.5, 1.5, 3) against (1, 2, 3)
    assert rank_correlation([5.0, 5.0, 7.0], [1.0, 2.0, 3.0]) == pytest.approx(0.866, abs=1e-3)
    assert rank_correlation([1.0, 2.0], [1.0, 2.0]) is None  # too few to rank
    assert rank_correlation([1.0, 1.0, 1.0], [1.0, 2.0, 3.0]) is None  # no spread


def _street(label: str, gap: float, frechet: float) -> WorldResult:
    """A street whose splat steers ``gap`` off the truth at one station, driven ``frechet``."""
    from cam2sim.metrics.benchmark import MethodRow

    profile = {"s_m": [0.0], "offsets_m": [0.0], "steering_truth": [[0.2]],
               "steering_splat": [[0.2 + gap]]}  # fmt: skip
    splat = MethodRow(method="splat", runs=3, failures=0, completion_mean=1.0,
                      min_frechet_m=frechet, corridor_violation_pct=0.0, jitter=0.1,
                      twin_frechet_runs_m=[frechet + 0.01] * 3)  # fmt: skip
    return WorldResult.model_construct(label=label, profile=profile, methods=[splat])


def test_the_steering_gap_is_set_against_the_drives_across_streets() -> None:
    streets = [_street("a", 0.02, 0.05), _street("b", 0.05, 0.15), _street("c", 0.1, 0.3),
               _street("d", 0.08, 0.35)]  # fmt: skip
    text = gap_prediction(streets)
    assert text is not None
    assert "over 4 streets: Spearman rank correlation 0.80" in text
    fig = gap_figure(streets)
    assert fig is not None
    (ax,) = fig.axes
    assert len(ax.collections) == 2  # Min-Fréchet and the twin distances
    assert gap_prediction(streets[:2]) is None  # two streets order nothing
    assert gap_figure(streets[:2]) is None


def test_without_a_policy_the_profile_is_psnr_only() -> None:
    prof = _profile(with_policy=False)
    assert prof.steering_gap() is None
    data = prof.to_json()
    assert set(data) == {"s_m", "offsets_m", "psnr_db"}
    assert steering_gap_peak(WorldResult.model_construct(profile=data)) is None
