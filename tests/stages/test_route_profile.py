"""The along-route profile's records: PSNR and the policy's steering on both views."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cam2sim.metrics.benchmark import WorldResult
from cam2sim.report.bench import steering_gap_peak
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


def test_without_a_policy_the_profile_is_psnr_only() -> None:
    prof = _profile(with_policy=False)
    assert prof.steering_gap() is None
    data = prof.to_json()
    assert set(data) == {"s_m", "offsets_m", "psnr_db"}
    assert steering_gap_peak(WorldResult.model_construct(profile=data)) is None
