"""Orientation from motion for poses that give none (GPS fixes): the pitch from the grade."""

from __future__ import annotations

import numpy as np
import pytest

from cam2sim.core.trajectory import pitch_from_motion


def _hill(n: int = 400, step_m: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A road along x: flat for 100 m, a 6 % climb for 150 m, flat again (heights, grade)."""
    x = np.arange(n) * step_m
    grade = np.where((x >= 100.0) & (x < 250.0), 0.06, 0.0)
    z = np.concatenate([[0.0], np.cumsum(grade[:-1] * step_m)])
    return np.stack([x, 0.5 * x, z], -1), grade


def test_pitch_is_the_grade_nose_up_when_climbing() -> None:
    xyz, _ = _hill()
    pitch = pitch_from_motion(xyz, window_m=15.0)
    along = np.hypot(xyz[:, 0], xyz[:, 1])
    mid_climb = (along > 130.0) & (along < 260.0)  # 15 m chords inside the climb
    flat = along < 100.0
    # ROS pitch is positive nose down: a climb is negative. The run is horizontal travel.
    run_grade = 0.06 / np.hypot(1.0, 0.5)
    want = -np.degrees(np.arctan(run_grade))
    assert np.degrees(pitch[mid_climb]) == pytest.approx(want, abs=0.01)
    assert np.abs(pitch[flat]).max() < 1e-12


def test_standing_still_and_noise_do_not_tilt_the_car() -> None:
    xyz, _ = _hill()
    still = np.repeat(xyz[150:151], 50, axis=0)  # 50 fixes at one place, mid-climb
    path = np.concatenate([xyz[:150], still, xyz[151:]])
    pitch = pitch_from_motion(path, window_m=15.0)
    assert np.ptp(pitch[150:200]) < 1e-12  # the same chord while standing
    noisy = xyz + np.random.default_rng(0).normal(0.0, 0.1, xyz.shape)
    err = pitch_from_motion(noisy, window_m=15.0) - pitch_from_motion(xyz, window_m=15.0)
    assert np.degrees(np.abs(err)).mean() < 0.6  # 0.1 m over 15 m: about half a degree


def test_no_heights_or_no_motion_give_a_level_car() -> None:
    flat = np.stack([np.arange(10.0), np.zeros(10), np.zeros(10)], -1)
    assert not pitch_from_motion(flat, window_m=15.0).any()
    assert not pitch_from_motion(np.zeros((5, 3)), window_m=15.0).any()
    assert pitch_from_motion(np.zeros((1, 3)), window_m=15.0).shape == (1,)


def test_slow_fixes_follow_the_turn_between_them_and_gaps_stay_gaps() -> None:
    """1 Hz fixes on a 10 m-radius circle at 8 m/s: chords would cut 0.8 m inside it."""
    from cam2sim.core.trajectory import densify_positions, gap_limit_s

    t = np.arange(0, 12, 1.0)
    t[8:] += 4.0  # a 5 s dropout between the 8th and 9th fixes
    angle = 0.8 * t
    xyz = np.column_stack([10 * np.sin(angle), 10 - 10 * np.cos(angle), np.zeros_like(t)])
    stamps = np.round(t * 1e9).astype(np.int64)
    gap = gap_limit_s(stamps, 0.5)
    assert gap == pytest.approx(2.5)  # one missing fix bridged, the dropout not
    dense_t, dense = densify_positions(stamps, xyz, max_gap_s=gap)
    assert np.all(np.diff(dense_t) > 0)
    assert np.isin(stamps, dense_t).all()  # the fixes kept
    radius = np.hypot(dense[:, 0], dense[:, 1] - 10)
    assert np.abs(radius - 10).max() < 0.15  # on the circle, not on its chords (0.76 m in)
    within = (dense_t > stamps[7]) & (dense_t < stamps[8])
    assert not within.any()  # nothing made up inside the dropout
    assert len(dense_t) == len(t) + 9 * 10  # 9 points in each of the 10 one-second intervals
    fast_t, fast = densify_positions(dense_t, dense, max_gap_s=gap)
    np.testing.assert_array_equal(fast_t, dense_t)  # 10 Hz already: as it is
    np.testing.assert_array_equal(fast, dense)


def test_jittery_fixes_are_smoothed_turns_and_gaps_kept() -> None:
    """10 Hz fixes with 0.1 m jitter on a 15 m-radius circle at 8 m/s, with a 10 s dropout."""
    from cam2sim.core.trajectory import Trajectory, smooth_positions

    rng = np.random.default_rng(0)
    t = np.arange(0, 30, 0.1)
    t[150:] += 10.0  # a dropout: the run after it starts 5 m off the circle
    angle = 8.0 / 15.0 * t
    truth = np.column_stack([15 * np.sin(angle), 15 - 15 * np.cos(angle), np.zeros_like(t)])
    truth[150:, 0] += 5.0
    noisy = truth + rng.normal(0, 0.1, truth.shape)
    stamps = np.round(t * 1e9).astype(np.int64)
    smooth, moved = smooth_positions(stamps, noisy, max_gap_s=0.5)
    err = np.linalg.norm(smooth - truth, axis=1)
    assert np.sqrt(np.mean(np.linalg.norm(noisy - truth, axis=1) ** 2)) > 0.15
    assert np.sqrt(np.mean(err**2)) < 0.06  # the jitter gone
    assert 0.1 < moved < 0.25  # and the measure of it says so
    radius = np.hypot(smooth[:150, 0], smooth[:150, 1] - 15)
    assert abs(np.median(radius) - 15) < 0.03  # the turn kept, not cut inside
    assert err[145:155].max() < 0.5  # a run's ends are noisier; a blend would be metres

    def speed(p: np.ndarray) -> np.ndarray:
        quat = np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1))
        return Trajectory(stamps, p, quat).speed_at(stamps, window_s=0.2)

    inside = np.r_[5:145, 155:295]
    assert np.abs(speed(noisy) - 8.0)[inside].mean() > 0.3  # 0.1 m over 0.2 s
    assert np.abs(speed(smooth) - 8.0)[inside].mean() < 0.1


def test_smoothing_keeps_clean_fixes_and_short_runs_and_shares_stamps() -> None:
    from cam2sim.core.trajectory import smooth_positions

    t = np.arange(0, 10, 0.1)
    line = np.column_stack([5 * t, 0.5 * t, np.zeros_like(t)])
    stamps = np.round(t * 1e9).astype(np.int64)
    smooth, moved = smooth_positions(stamps, line, max_gap_s=0.5)
    assert moved < 1e-3  # a clean straight drive stays where it is
    zigzag = line[:4] + np.outer([1, -1, 1, -1], [0, 0.3, 0])
    few, moved = smooth_positions(stamps[:4], zigzag, max_gap_s=0.5)
    np.testing.assert_array_equal(few, zigzag)
    assert moved == 0.0  # four fixes: too few to tell noise from the path
    twice = np.repeat(stamps, 2)  # two receivers' fixes at the same stamps, 0.2 m apart
    pair = np.repeat(line, 2, axis=0) + np.tile([[0, 0.1, 0], [0, -0.1, 0]], (len(t), 1))
    smooth, _ = smooth_positions(twice, pair, max_gap_s=0.5)
    np.testing.assert_allclose(smooth[0::2], smooth[1::2])  # one position a stamp
    np.testing.assert_allclose(smooth[0::2], line, atol=1e-3)  # their mean, on the line


def test_heading_off_travel_is_nan_standing_still_and_sees_a_turned_convention() -> None:
    from cam2sim.core.trajectory import heading_off_travel

    x = np.concatenate([np.zeros(10), np.linspace(0.0, 20.0, 41), np.full(10, 20.0)])
    xy = np.stack([x, np.zeros_like(x)], -1)  # standing, 20 m east, standing
    off = heading_off_travel(xy, np.zeros(len(x)))
    assert np.isfinite(off).sum() > 20
    np.testing.assert_allclose(off[np.isfinite(off)], 0.0, atol=1e-9)
    assert np.isnan(heading_off_travel(np.zeros((5, 2)), np.zeros(5))).all()  # never moved
    turned = heading_off_travel(xy, np.full(len(x), np.pi / 2))  # x to the left
    np.testing.assert_allclose(turned[np.isfinite(turned)], np.pi / 2)
