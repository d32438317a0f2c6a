"""Tests for cam2sim.core.frames: rotations, poses, projections and the CARLA boundary."""

from __future__ import annotations

import math

import numpy as np
import pyproj
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from cam2sim.core.errors import ConfigError
from cam2sim.core.frames import (
    CarlaTransform,
    Pose,
    WorldFrame,
    angle_difference,
    carla_to_world,
    carla_yaw_deg_to_heading,
    circular_mean,
    euler_from_quat,
    heading_to_carla_yaw_deg,
    interpolate_poses,
    pose_from_carla,
    pose_to_carla,
    quat_angle_between,
    quat_conjugate,
    quat_from_euler,
    quat_from_matrix,
    quat_from_yaw,
    quat_inverse,
    quat_multiply,
    quat_normalize,
    quat_rotate,
    quat_to_matrix,
    slerp,
    unwrap_angles,
    utm_crs_for,
    world_to_carla,
    wrap_angle,
    yaw_from_quat,
)

FAST = settings(max_examples=30, deadline=None, derandomize=True)
SLOW = settings(max_examples=12, deadline=None, derandomize=True)  # one pyproj setup per example

UTM32N = "EPSG:32632"
MUNICH = WorldFrame(48.2, 11.6, 520.0)
WGS84_TO_UTM32N = pyproj.Transformer.from_crs("EPSG:4326", UTM32N, always_xy=True)

# --------------------------------------------------------------------------------------------
# Strategies
# --------------------------------------------------------------------------------------------

finite = st.floats(-1.0, 1.0, allow_nan=False)
angles = st.floats(-math.pi, math.pi, allow_nan=False, exclude_max=True)


@st.composite
def unit_quats(draw: st.DrawFn) -> np.ndarray:
    v = draw(arrays(np.float64, 4, elements=finite))
    norm = float(np.linalg.norm(v))
    assume(norm > 0.1)
    return v / norm


@st.composite
def poses(draw: st.DrawFn) -> Pose:
    xyz = draw(arrays(np.float64, 3, elements=st.floats(-1e3, 1e3, allow_nan=False)))
    return Pose(xyz, draw(unit_quats()))


@st.composite
def munich_origins(draw: st.DrawFn) -> WorldFrame:
    lat = draw(st.floats(48.1, 48.3))
    lon = draw(st.floats(11.4, 11.7))
    return WorldFrame(lat, lon, draw(st.floats(400.0, 600.0)))


@st.composite
def utm_points(draw: st.DrawFn, n: int = 5) -> np.ndarray:
    """(n, 3) UTM 32N points around Munich (lat 48.1-48.3, lon 11.4-11.7)."""
    lat = draw(arrays(np.float64, n, elements=st.floats(48.1, 48.3)))
    lon = draw(arrays(np.float64, n, elements=st.floats(11.4, 11.7)))
    h = draw(arrays(np.float64, n, elements=st.floats(300.0, 700.0)))
    e, nn = WGS84_TO_UTM32N.transform(lon, lat)
    return np.stack([e, nn, h], axis=-1)


def same_rotation(a: np.ndarray, b: np.ndarray, tol: float = 1e-9) -> bool:
    return bool(np.all(quat_angle_between(a, b) < tol))


def rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def ue4_rotation_matrix(pitch_deg: float, yaw_deg: float, roll_deg: float) -> np.ndarray:
    """Reference: UE4 ``FRotationMatrix`` (Engine/Source/Runtime/Core/Public/Math/RotationMatrix.h).

    With P, Y, R in radians, SP = sin(P), CP = cos(P) and so on::

        M[0] = ( CP*CY,              CP*SY,              SP     )   # forward (X axis)
        M[1] = ( SR*SP*CY - CR*SY,   SR*SP*SY + CR*CY,   -SR*CP )   # right   (Y axis)
        M[2] = ( -(CR*SP*CY + SR*SY), CY*SR - CR*SP*SY,  CR*CP  )   # up      (Z axis)

    UE multiplies row vectors (``v' = v @ M``), so row i is the image of body axis i in CARLA's
    left-handed frame. CARLA's ``Rotation.get_forward_vector()`` equals ``M[0]``.
    """
    p, y, r = (math.radians(a) for a in (pitch_deg, yaw_deg, roll_deg))
    sp, cp, sy, cy, sr, cr = (
        math.sin(p),
        math.cos(p),
        math.sin(y),
        math.cos(y),
        math.sin(r),
        math.cos(r),
    )
    return np.array(
        [
            [cp * cy, cp * sy, sp],
            [sr * sp * cy - cr * sy, sr * sp * sy + cr * cy, -sr * cp],
            [-(cr * sp * cy + sr * sy), cy * sr - cr * sp * sy, cr * cp],
        ]
    )


# --------------------------------------------------------------------------------------------
# Quaternions and Euler angles
# --------------------------------------------------------------------------------------------


@FAST
@given(q=unit_quats())
def test_quat_matrix_round_trip_preserves_rotation(q: np.ndarray) -> None:
    R = quat_to_matrix(q)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    assert same_rotation(quat_from_matrix(R), q)
    np.testing.assert_allclose(quat_to_matrix(quat_from_matrix(R)), R, atol=1e-12)


@FAST
@given(q=unit_quats(), v=arrays(np.float64, 3, elements=finite))
def test_quat_rotate_matches_matrix(q: np.ndarray, v: np.ndarray) -> None:
    np.testing.assert_allclose(quat_rotate(q, v), quat_to_matrix(q) @ v, atol=1e-12)


@pytest.mark.parametrize(
    "R",
    [np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0]), np.eye(3)],
)
def test_quat_from_matrix_is_exact_for_half_turns(R: np.ndarray) -> None:
    np.testing.assert_allclose(quat_to_matrix(quat_from_matrix(R)), R, atol=1e-15)


def test_quat_from_matrix_is_vectorised_over_batches() -> None:
    q = quat_normalize(np.random.default_rng(0).normal(size=(2, 5, 4)))
    out = quat_from_matrix(quat_to_matrix(q))
    assert out.shape == (2, 5, 4)
    assert same_rotation(out, q)


@FAST
@given(r=angles, p=st.floats(-1.5, 1.5), y=angles)
def test_quat_euler_round_trip_away_from_gimbal_lock(r: float, p: float, y: float) -> None:
    e = euler_from_quat(quat_from_euler(r, p, y))
    assert abs(angle_difference(float(e.roll), r)) < 1e-9
    assert float(e.pitch) == pytest.approx(p, abs=1e-9)
    assert abs(angle_difference(float(e.yaw), y)) < 1e-9


@FAST
@given(r=angles, p=angles, y=angles)
def test_quat_from_euler_is_zyx(r: float, p: float, y: float) -> None:
    expected = rot_z(y) @ rot_y(p) @ rot_x(r)
    np.testing.assert_allclose(quat_to_matrix(quat_from_euler(r, p, y)), expected, atol=1e-12)


@FAST
@given(yaw=angles)
def test_yaw_from_quat_inverts_quat_from_yaw(yaw: float) -> None:
    assert abs(angle_difference(float(yaw_from_quat(quat_from_yaw(yaw))), yaw)) < 1e-12


@FAST
@given(a=unit_quats(), b=unit_quats())
def test_quat_multiply_is_matrix_product(a: np.ndarray, b: np.ndarray) -> None:
    np.testing.assert_allclose(
        quat_to_matrix(quat_multiply(a, b)), quat_to_matrix(a) @ quat_to_matrix(b), atol=1e-12
    )


def test_quat_inverse_undoes_a_non_unit_quaternion() -> None:
    q = np.array([0.2, -0.4, 1.0, 2.0])
    np.testing.assert_allclose(quat_multiply(q, quat_inverse(q)), [0, 0, 0, 1], atol=1e-15)
    np.testing.assert_array_equal(quat_conjugate(q), [-0.2, 0.4, -1.0, 2.0])


@FAST
@given(a=unit_quats(), b=unit_quats())
def test_quat_angle_between_is_sign_invariant(a: np.ndarray, b: np.ndarray) -> None:
    assert quat_angle_between(a, b) == pytest.approx(quat_angle_between(a, -b), abs=1e-12)
    assert quat_angle_between(a, -a) == pytest.approx(0.0, abs=1e-7)


def test_quat_angle_between_measures_a_yaw_step() -> None:
    assert quat_angle_between(quat_from_yaw(0.1), quat_from_yaw(0.4)) == pytest.approx(0.3)


def test_quat_normalize_rejects_zero_quaternion() -> None:
    with pytest.raises(ValueError, match="zero-norm"):
        quat_normalize([0.0, 0.0, 0.0, 0.0])


def test_quat_functions_reject_wrong_last_axis() -> None:
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 4\)"):
        quat_to_matrix(np.zeros((5, 3)))


# --------------------------------------------------------------------------------------------
# slerp and pose interpolation
# --------------------------------------------------------------------------------------------


def test_slerp_midpoint_of_yaw_0_and_90_is_yaw_45() -> None:
    q = slerp(quat_from_yaw(0.0), quat_from_yaw(math.pi / 2), 0.5)
    assert float(yaw_from_quat(q)) == pytest.approx(math.pi / 4, abs=1e-12)


def test_slerp_takes_the_shortest_path_for_sign_flipped_input() -> None:
    q = slerp(quat_from_yaw(0.0), -quat_from_yaw(math.pi / 2), 0.5)
    assert float(yaw_from_quat(q)) == pytest.approx(math.pi / 4, abs=1e-12)
    assert quat_angle_between(q, quat_from_yaw(0.0)) == pytest.approx(math.pi / 4)


def test_slerp_is_safe_for_nearly_identical_quaternions() -> None:
    q0 = quat_from_euler(0.1, 0.2, 0.3)
    q1 = quat_normalize(q0 + 1e-13)
    out = slerp(q0, q1, np.linspace(0.0, 1.0, 5))
    assert np.all(np.isfinite(out))
    np.testing.assert_allclose(np.linalg.norm(out, axis=-1), 1.0, atol=1e-15)
    assert same_rotation(out, q0, tol=1e-10)


@FAST
@given(a=unit_quats(), b=unit_quats(), t=st.floats(0.0, 1.0))
def test_slerp_moves_at_constant_angular_rate(a: np.ndarray, b: np.ndarray, t: float) -> None:
    total = float(quat_angle_between(a, b))
    q = slerp(a, b, t)
    assert float(quat_angle_between(a, q)) == pytest.approx(t * total, abs=1e-7)
    assert float(quat_angle_between(q, b)) == pytest.approx((1 - t) * total, abs=1e-7)


def _track() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t0 = 1_700_000_000_123_456_789
    times = t0 + np.array([0, 100_000_000, 250_000_000, 400_000_000], dtype=np.int64)
    positions = np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 0.0], [2.5, 1.0, 0.1], [4.0, 1.0, 0.2]])
    quats = quat_from_euler([0.0, 0.01, 0.02, 0.0], [0.0, 0.0, -0.01, 0.0], [0.0, 0.3, 2.0, -3.0])
    return times, positions, quats


def test_interpolate_poses_reproduces_samples_exactly_at_sample_times() -> None:
    times, positions, quats = _track()
    out = interpolate_poses(times, positions, quats, times)
    np.testing.assert_array_equal(out.positions, positions)
    np.testing.assert_array_equal(out.quats, quat_normalize(quats))


def test_interpolate_poses_uses_exact_integer_fractions_on_large_stamps() -> None:
    times, positions, quats = _track()
    # 1 ns after a 1.7e18 ns stamp: float64 stamps could not resolve this.
    query = np.array([times[0] + 50_000_000, times[1] + 1], dtype=np.int64)
    out = interpolate_poses(times, positions, quats, query)
    np.testing.assert_allclose(out.positions[0], [0.5, 0.25, 0.0], atol=1e-15)
    expected = positions[1] + (positions[2] - positions[1]) / 150_000_000
    np.testing.assert_allclose(out.positions[1], expected, rtol=1e-15, atol=1e-15)
    assert not np.array_equal(out.positions[1], positions[1])
    assert float(yaw_from_quat(out.quats[0])) == pytest.approx(0.15)


def test_interpolate_poses_slerps_the_short_way_across_pi() -> None:
    times, positions, quats = _track()
    mid = np.array([(times[2] + times[3]) // 2], dtype=np.int64)
    yaw = float(yaw_from_quat(interpolate_poses(times, positions, quats, mid).quats[0]))
    # 2.0 → -3.0 rad is 1.283 rad the short way (through π), not 5 rad the long way.
    assert abs(angle_difference(yaw, 2.0 + (2 * math.pi - 5.0) / 2)) < 0.02


def test_interpolate_poses_rejects_queries_outside_the_sampled_range() -> None:
    times, positions, quats = _track()
    with pytest.raises(ValueError, match=r"outside the sampled range \[1700000000123456789"):
        interpolate_poses(times, positions, quats, np.array([times[-1] + 1]))
    with pytest.raises(ValueError, match="outside the sampled range"):
        interpolate_poses(times, positions, quats, times[0] - 1)


def test_interpolate_poses_rejects_float_stamps() -> None:
    times, positions, quats = _track()
    with pytest.raises(TypeError, match="integer nanoseconds"):
        interpolate_poses(times.astype(float), positions, quats, times)


def test_interpolate_poses_rejects_unsorted_stamps() -> None:
    times, positions, quats = _track()
    with pytest.raises(ValueError, match="strictly increasing"):
        interpolate_poses(times[::-1], positions, quats, times)


# --------------------------------------------------------------------------------------------
# Angles
# --------------------------------------------------------------------------------------------


@FAST
@given(a=st.floats(-1e4, 1e4, allow_nan=False))
def test_wrap_angle_lands_in_half_open_interval(a: float) -> None:
    w = wrap_angle(a)
    assert -math.pi <= w < math.pi
    assert math.isclose(math.cos(w), math.cos(a), abs_tol=1e-9)
    assert math.isclose(math.sin(w), math.sin(a), abs_tol=1e-9)


def test_wrap_angle_maps_pi_to_minus_pi_and_keeps_array_shape() -> None:
    assert wrap_angle(math.pi) == -math.pi
    assert wrap_angle(-1e-9) == pytest.approx(-1e-9, abs=1e-15)
    assert wrap_angle(-3 * math.pi) == pytest.approx(-math.pi)
    assert wrap_angle(np.zeros((2, 3))).shape == (2, 3)


def test_angle_difference_wraps() -> None:
    assert angle_difference(math.radians(1), math.radians(359)) == pytest.approx(math.radians(2))


def test_unwrap_angles_removes_jumps_along_last_axis() -> None:
    a = wrap_angle(np.linspace(0.0, 10.0, 50))
    np.testing.assert_allclose(
        unwrap_angles(np.stack([a, a])), np.stack([np.linspace(0, 10, 50)] * 2)
    )


def test_circular_mean_of_359_and_1_degrees_is_zero() -> None:
    m = circular_mean(np.radians([359.0, 1.0]))
    assert float(m) == pytest.approx(0.0, abs=1e-12)


def test_circular_mean_weights_pull_towards_heavier_angle() -> None:
    assert float(circular_mean([0.0, math.pi / 2], [3.0, 1.0])) == pytest.approx(math.atan2(1, 3))
    assert float(circular_mean([0.3, 2.0], [1.0, 0.0])) == pytest.approx(0.3)
    rows = circular_mean(np.radians([[350.0, 10.0], [80.0, 100.0]]))
    np.testing.assert_allclose(rows, np.radians([0.0, 90.0]), atol=1e-12)


def test_circular_mean_rejects_zero_weight_sum() -> None:
    with pytest.raises(ValueError, match="sum to 0"):
        circular_mean([0.1, 0.2], [0.0, 0.0])


def test_circular_mean_rejects_cancelling_angles() -> None:
    with pytest.raises(ValueError, match="undefined"):
        circular_mean([0.0, math.pi])
    with pytest.raises(ValueError, match="undefined"):
        circular_mean([0.0, 2 * math.pi / 3, 4 * math.pi / 3])


# --------------------------------------------------------------------------------------------
# Pose
# --------------------------------------------------------------------------------------------


@FAST
@given(a=poses(), b=poses())
def test_pose_compose_matches_matrix_product(a: Pose, b: Pose) -> None:
    np.testing.assert_allclose((a @ b).as_matrix(), a.as_matrix() @ b.as_matrix(), atol=1e-9)
    np.testing.assert_allclose(a.compose(b).position, (a @ b).position)


@FAST
@given(a=poses(), b=poses())
def test_pose_compose_inverse_round_trip(a: Pose, b: Pose) -> None:
    back = (a @ b) @ b.inverse()
    np.testing.assert_allclose(back.position, a.position, atol=1e-9)
    assert same_rotation(back.quat, a.quat)
    ident = a @ a.inverse()
    np.testing.assert_allclose(ident.position, 0.0, atol=1e-9)
    assert same_rotation(ident.quat, Pose.identity().quat)


@FAST
@given(p=poses())
def test_pose_matrix_round_trip(p: Pose) -> None:
    back = Pose.from_matrix(p.as_matrix())
    np.testing.assert_allclose(back.position, p.position, atol=0)
    assert same_rotation(back.quat, p.quat)


@FAST
@given(p=poses(), pts=arrays(np.float64, (4, 3), elements=st.floats(-50, 50)))
def test_pose_apply_matches_homogeneous_matrix(p: Pose, pts: np.ndarray) -> None:
    homo = np.c_[pts, np.ones(4)] @ p.as_matrix().T
    np.testing.assert_allclose(p.apply(pts), homo[:, :3], atol=1e-9)


def test_pose_from_xyz_rpy_sets_heading() -> None:
    p = Pose.from_xyz_rpy([1.0, 2.0, 3.0], [0.0, 0.0, 2.5])
    assert p.heading == pytest.approx(2.5)
    np.testing.assert_allclose(
        p.apply([[1.0, 0.0, 0.0]]), [[1 + math.cos(2.5), 2 + math.sin(2.5), 3]]
    )


def test_pose_normalises_nearly_unit_quaternion_and_is_read_only() -> None:
    p = Pose(np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.0, 1.0 + 5e-7]))
    assert np.linalg.norm(p.quat) == pytest.approx(1.0, abs=1e-15)
    with pytest.raises(ValueError, match="read-only"):
        p.position[0] = 1.0


def test_pose_rejects_non_unit_quaternion() -> None:
    with pytest.raises(ValueError, match="unit quaternion"):
        Pose(np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.0, 2.0]))


def test_pose_rejects_bad_shapes_and_nan() -> None:
    with pytest.raises(ValueError, match=r"position \(3,\)"):
        Pose(np.array([0.0, 0.0]), np.array([0.0, 0.0, 0.0, 1.0]))
    with pytest.raises(ValueError, match="non-finite"):
        Pose(np.array([0.0, math.nan, 0.0]), np.array([0.0, 0.0, 0.0, 1.0]))


def test_pose_from_matrix_rejects_reflection() -> None:
    with pytest.raises(ValueError, match="not a rigid transform"):
        Pose.from_matrix(np.diag([1.0, 1.0, -1.0, 1.0]))


# --------------------------------------------------------------------------------------------
# Projections
# --------------------------------------------------------------------------------------------


def test_world_frame_proj_string_is_a_centred_tmerc() -> None:
    assert MUNICH.proj_string == (
        "+proj=tmerc +lat_0=48.2000000000 +lon_0=11.6000000000 +k=1 +x_0=0 +y_0=0 "
        "+ellps=WGS84 +units=m +no_defs"
    )
    np.testing.assert_allclose(MUNICH.from_wgs84(48.2, 11.6, 520.0), [[0.0, 0.0, 0.0]], atol=1e-8)


def test_world_frame_axes_point_east_and_north() -> None:
    xyz = MUNICH.from_wgs84([48.2, 48.21], [11.61, 11.6], [520.0, 530.0])
    assert xyz[0, 0] > 700
    assert abs(xyz[0, 1]) < 1.0
    assert xyz[1, 1] > 1000
    assert abs(xyz[1, 0]) < 1e-6
    assert xyz[1, 2] == pytest.approx(10.0)


def test_world_frame_origin_is_quantised_like_its_proj_string() -> None:
    frame = WorldFrame(48.123456789012345, 11.98765432109876, 1.5)
    assert frame.origin_lat_deg == 48.1234567890
    assert frame.origin_lon_deg == 11.9876543211
    assert frame == WorldFrame(48.1234567890, 11.9876543211, 1.5)


def test_world_frame_rejects_bad_origin() -> None:
    with pytest.raises(ConfigError, match="latitude first"):
        WorldFrame(148.0, 11.6)


@SLOW
@given(
    frame=munich_origins(),
    xyz=arrays(np.float64, (5, 3), elements=st.floats(-20_000.0, 20_000.0)),
)
def test_wgs84_world_round_trip(frame: WorldFrame, xyz: np.ndarray) -> None:
    geo = frame.to_wgs84(xyz)
    np.testing.assert_allclose(
        frame.from_wgs84(geo.lat_deg, geo.lon_deg, geo.alt_m), xyz, atol=1e-6
    )


@SLOW
@given(frame=munich_origins(), pts=utm_points())
def test_utm_world_round_trip_to_a_millimetre(frame: WorldFrame, pts: np.ndarray) -> None:
    world = frame.from_crs(UTM32N, pts)
    np.testing.assert_allclose(world[:, 2], pts[:, 2] - frame.origin_alt_m, atol=1e-9)
    np.testing.assert_allclose(frame.to_crs(UTM32N, world), pts, atol=1e-3, rtol=0)


@SLOW
@given(frame=munich_origins(), pts=utm_points())
def test_utm_and_wgs84_paths_agree(frame: WorldFrame, pts: np.ndarray) -> None:
    lon, lat = WGS84_TO_UTM32N.transform(pts[:, 0], pts[:, 1], direction="INVERSE")
    via_geo = frame.from_wgs84(lat, lon, pts[:, 2])
    np.testing.assert_allclose(frame.from_crs(UTM32N, pts), via_geo, atol=1e-6)


@SLOW
@given(
    frame=munich_origins(),
    pts=utm_points(),
    heading=arrays(np.float64, 5, elements=angles),
)
def test_heading_crs_round_trip(frame: WorldFrame, pts: np.ndarray, heading: np.ndarray) -> None:
    world_xy = frame.from_crs(UTM32N, pts)[:, :2]
    h_world = frame.heading_from_crs(UTM32N, pts[:, :2], heading)
    back = frame.heading_to_crs(UTM32N, world_xy, h_world)
    assert np.all(np.abs(angle_difference(back, heading)) < 1e-9)


@SLOW
@given(frame=munich_origins(), pts=utm_points(), q=unit_quats())
def test_quats_crs_round_trip_and_match_headings(
    frame: WorldFrame, pts: np.ndarray, q: np.ndarray
) -> None:
    quats = np.broadcast_to(q, (5, 4))
    world_xy = frame.from_crs(UTM32N, pts)[:, :2]
    q_world = frame.quats_from_crs(UTM32N, pts[:, :2], quats)
    assert same_rotation(frame.quats_to_crs(UTM32N, world_xy, q_world), quats)
    # Yaw (the heading of the body x axis projected onto the ground) moves like a heading.
    yaw_crs = yaw_from_quat(quats)
    expected = frame.heading_from_crs(UTM32N, pts[:, :2], yaw_crs)
    assert np.all(np.abs(angle_difference(yaw_from_quat(q_world), expected)) < 1e-9)


def _meridian_convergence_rad(crs: str, lat: float, lon: float) -> float:
    return math.radians(pyproj.Proj(crs).get_factors(lon, lat).meridian_convergence)


@pytest.mark.parametrize(
    ("origin", "convergence_deg"), [((48.2, 11.6), 1.9388), ((48.15, 11.45), 1.8270)]
)
def test_utm_convergence_at_munich_matches_pyproj_factors(
    origin: tuple[float, float], convergence_deg: float
) -> None:
    frame = WorldFrame(*origin, 0.0)
    lat, lon = 48.2, 11.6
    e, n = WGS84_TO_UTM32N.transform(lon, lat)
    expected = _meridian_convergence_rad(UTM32N, lat, lon) - _meridian_convergence_rad(
        frame.proj_string, lat, lon
    )
    # Grid north of UTM 32N lies east of true north at Munich by ~1.94°: far too much to ignore.
    assert math.degrees(expected) == pytest.approx(convergence_deg, abs=1e-4)
    h_crs = np.array([0.0, 1.0, -2.5])
    h_world = frame.heading_from_crs(UTM32N, np.array([[e, n]] * 3), h_crs)
    np.testing.assert_allclose(angle_difference(h_world, h_crs - expected), 0.0, atol=1e-8)


def test_world_distances_match_the_ellipsoid_near_the_origin() -> None:
    geod = pyproj.Geod(ellps="WGS84")
    rng = np.random.default_rng(7)
    start = rng.uniform(-1000.0, 1000.0, size=(20, 2))
    heading = rng.uniform(-math.pi, math.pi, size=20)
    end = start + 100.0 * np.stack([np.cos(heading), np.sin(heading)], axis=-1)
    a = MUNICH.to_wgs84(np.c_[start, np.zeros(20)])
    b = MUNICH.to_wgs84(np.c_[end, np.zeros(20)])
    _, _, dist = geod.inv(a.lon_deg, a.lat_deg, b.lon_deg, b.lat_deg)
    np.testing.assert_allclose(dist, 100.0, atol=1e-3, rtol=0)


def test_at_crs_point_puts_origin_on_that_point() -> None:
    frame = WorldFrame.at_crs_point(UTM32N, 691_000.0, 5_334_000.0, 515.0)
    # The origin is quantised to 1e-10 degrees (the proj_string precision), i.e. < 12 µm.
    np.testing.assert_allclose(
        frame.from_crs(UTM32N, [[691_000.0, 5_334_000.0, 515.0]]), [[0, 0, 0]], atol=2e-5
    )
    assert 48.0 < frame.origin_lat_deg < 48.3
    assert 11.5 < frame.origin_lon_deg < 11.7


@pytest.mark.parametrize(
    ("lat", "lon", "crs"),
    [(48.2, 11.6, "EPSG:32632"), (-33.9, 151.2, "EPSG:32756"), (0.0, -180.0, "EPSG:32601")],
)
def test_utm_crs_for_picks_the_zone(lat: float, lon: float, crs: str) -> None:
    assert utm_crs_for(lat, lon) == crs


def test_invalid_crs_raises_config_error_with_an_example() -> None:
    with pytest.raises(ConfigError, match=r"'EPSG:99999'.*EPSG:32632"):
        MUNICH.from_crs("EPSG:99999", [[0.0, 0.0, 0.0]])


def test_headings_need_a_projected_crs() -> None:
    with pytest.raises(ConfigError, match="projected CRS"):
        MUNICH.heading_from_crs("EPSG:4326", [[11.6, 48.2]], [0.0])


# --------------------------------------------------------------------------------------------
# CARLA boundary
# --------------------------------------------------------------------------------------------


@FAST
@given(xyz=arrays(np.float64, (3, 3), elements=st.floats(-1e4, 1e4)))
def test_world_carla_points_round_trip(xyz: np.ndarray) -> None:
    np.testing.assert_array_equal(carla_to_world(world_to_carla(xyz)), xyz)
    np.testing.assert_array_equal(world_to_carla(xyz)[:, 1], -xyz[:, 1])


@FAST
@given(h=st.floats(-20.0, 20.0))
def test_heading_carla_yaw_round_trip(h: float) -> None:
    yaw = heading_to_carla_yaw_deg(h)
    assert -180.0 <= yaw < 180.0
    assert abs(angle_difference(carla_yaw_deg_to_heading(yaw), h)) < 1e-12


def test_carla_yaw_is_clockwise_degrees() -> None:
    assert heading_to_carla_yaw_deg(math.pi / 2) == pytest.approx(-90.0)  # north
    assert carla_yaw_deg_to_heading(90.0) == pytest.approx(-math.pi / 2)  # CARLA +y = south
    np.testing.assert_allclose(heading_to_carla_yaw_deg(np.array([0.0, math.pi])), [0.0, -180.0])


@FAST
@given(
    xyz=arrays(np.float64, 3, elements=st.floats(-1e3, 1e3)),
    r=angles,
    y=angles,
    p=st.floats(-1.48, 1.48),
)
def test_pose_carla_round_trip(xyz: np.ndarray, r: float, p: float, y: float) -> None:
    pose = Pose.from_xyz_rpy(xyz, [r, p, y])
    t = pose_to_carla(pose)
    assert -180.0 <= t.yaw_deg < 180.0
    back = pose_from_carla(t)
    np.testing.assert_array_equal(back.position, pose.position)
    assert same_rotation(back.quat, pose.quat)


@FAST
@given(
    pitch=st.floats(-85.0, 85.0),
    yaw=st.floats(-180.0, 180.0, exclude_max=True),
    roll=st.floats(-179.0, 179.0),
)
def test_carla_transform_round_trip(pitch: float, yaw: float, roll: float) -> None:
    t = CarlaTransform(np.array([1.0, -2.0, 3.0]), pitch, yaw, roll)
    back = pose_to_carla(pose_from_carla(t))
    np.testing.assert_array_equal(back.location, t.location)
    assert back.pitch_deg == pytest.approx(pitch, abs=1e-8)
    assert abs((back.yaw_deg - yaw + 180.0) % 360.0 - 180.0) < 1e-8
    assert back.roll_deg == pytest.approx(roll, abs=1e-8)


@FAST
@given(
    pitch=st.floats(-89.0, 89.0),
    yaw=st.floats(-180.0, 180.0),
    roll=st.floats(-180.0, 180.0),
    body=arrays(np.float64, (4, 3), elements=st.floats(-5.0, 5.0)),
)
def test_carla_pose_matches_ue4_rotation_matrix(
    pitch: float, yaw: float, roll: float, body: np.ndarray
) -> None:
    t = CarlaTransform(np.array([10.0, 20.0, 0.5]), pitch, yaw, roll)
    pose = pose_from_carla(t)
    M = ue4_rotation_matrix(pitch, yaw, roll)
    # Body axes: world body frame is (forward, left, up); CARLA's is (forward, right, up).
    forward, right, up = (
        world_to_carla(pose.apply(v) - pose.position) for v in np.eye(3) * [1, -1, 1]
    )
    np.testing.assert_allclose(forward, M[0], atol=1e-12)
    np.testing.assert_allclose(right, M[1], atol=1e-12)
    np.testing.assert_allclose(up, M[2], atol=1e-12)
    # Whole points: UE transforms row vectors, v_carla = location + v_body_carla @ M.
    ue_points = t.location + world_to_carla(body) @ M
    np.testing.assert_allclose(world_to_carla(pose.apply(body)), ue_points, atol=1e-9)
    # And pose_to_carla gives back the same physical rotation.
    back = pose_to_carla(pose)
    np.testing.assert_allclose(
        ue4_rotation_matrix(back.pitch_deg, back.yaw_deg, back.roll_deg), M, atol=1e-9
    )


def test_carla_forward_vector_for_a_northbound_nose_up_car() -> None:
    # Heading north (world +y) with 10° nose up: CARLA yaw -90°, pitch +10°.
    pose = Pose.from_xyz_rpy([0.0, 0.0, 0.0], [0.0, -math.radians(10.0), math.pi / 2])
    t = pose_to_carla(pose)
    assert t.yaw_deg == pytest.approx(-90.0)
    assert t.pitch_deg == pytest.approx(10.0)
    cp, sp = math.cos(math.radians(10)), math.sin(math.radians(10))
    cy, sy = math.cos(math.radians(t.yaw_deg)), math.sin(math.radians(t.yaw_deg))
    np.testing.assert_allclose(
        world_to_carla(quat_rotate(pose.quat, [1.0, 0.0, 0.0])), [cp * cy, cp * sy, sp], atol=1e-12
    )


def test_carla_positive_roll_puts_the_right_side_down() -> None:
    pose = pose_from_carla(CarlaTransform(np.zeros(3), 0.0, 0.0, 10.0))
    right_world = quat_rotate(pose.quat, [0.0, -1.0, 0.0])
    assert right_world[2] < -0.1
    assert float(euler_from_quat(pose.quat).roll) == pytest.approx(math.radians(10.0))


def test_camera_poses_compose_body_and_mount() -> None:
    from cam2sim.core.frames import camera_poses, quat_from_yaw

    mount_t = np.array([1.6, 0.0, 1.4])
    optical = np.array([-0.5, 0.5, -0.5, 0.5])  # optical axes (z forward) in the body frame
    T = camera_poses([[10.0, 5.0, 0.0]], quat_from_yaw([np.pi / 2])[None], mount_t, optical)
    # The car faces north (+y): the camera sits 1.6 m ahead of it and looks north.
    np.testing.assert_allclose(T[0, :3, 3], [10.0, 6.6, 1.4], atol=1e-12)
    np.testing.assert_allclose(T[0, :3, 2], [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(T[0, :3, 0], [1.0, 0.0, 0.0], atol=1e-12)  # image right = east
