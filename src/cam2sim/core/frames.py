"""Frames, units and rotations: the one owner of every coordinate convention in cam2sim.

Conventions (see ``docs/architecture.md``, "Frames and units"):

* Quaternions are float64 arrays ``(..., 4)`` in ROS order ``(x, y, z, w)``, composed with the
  Hamilton product. Rotations are active: ``q`` rotates body vectors into the parent frame.
* Angles are radians unless the name ends in ``_deg``. Euler angles follow ROS (ZYX):
  ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.
* The world frame of a workspace is local, right-handed and metric: x east, y north, z up. It is a
  transverse Mercator projection centred on the workspace origin (:class:`WorldFrame`); the same
  projection string goes into the OpenDRIVE ``<geoReference>``, so map and world coordinates agree.
* Heading is the angle of the vehicle forward axis in the world frame, CCW from +x, radians.
* CARLA's left-handed Unreal frame (y flipped, yaw in degrees clockwise) appears only through
  :func:`world_to_carla`, :func:`pose_to_carla` and their inverses.

Every function broadcasts over leading dimensions and is vectorised with numpy.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple, overload

import numpy as np
import pyproj
from pyproj.exceptions import CRSError

from cam2sim.core.errors import ConfigError

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = [
    "CarlaTransform",
    "EulerAngles",
    "Pose",
    "PoseSamples",
    "Wgs84Points",
    "WorldFrame",
    "angle_difference",
    "carla_to_world",
    "carla_yaw_deg_to_heading",
    "circular_mean",
    "euler_from_quat",
    "heading_to_carla_yaw_deg",
    "interpolate_poses",
    "pose_from_carla",
    "pose_to_carla",
    "quat_angle_between",
    "quat_conjugate",
    "quat_from_euler",
    "quat_from_matrix",
    "quat_from_yaw",
    "quat_inverse",
    "quat_multiply",
    "quat_normalize",
    "quat_rotate",
    "quat_to_matrix",
    "slerp",
    "unwrap_angles",
    "utm_crs_for",
    "world_to_carla",
    "wrap_angle",
    "yaw_from_quat",
]

_CONJ: npt.NDArray[np.float64] = np.array([-1.0, -1.0, -1.0, 1.0])
_FLIP_Y: npt.NDArray[np.float64] = np.array([1.0, -1.0, 1.0])
_UNIT_TOL = 1e-6
_SLERP_SMALL_ANGLE = 1e-6
_RESULTANT_TOL = 1e-9
_HEADING_HALF_STEP_M = 20.0
_WGS84 = "EPSG:4326"
_ORIGIN_DECIMALS = 10  # proj_string precision: 1e-10 degrees, about 11 micrometres
_CRS_EXAMPLE = "use a pyproj CRS string such as 'EPSG:32632' (UTM zone 32N)"


# --------------------------------------------------------------------------------------------
# Input helpers
# --------------------------------------------------------------------------------------------


def _as_float(a: npt.ArrayLike, name: str) -> npt.NDArray[np.float64]:
    """Convert ``a`` to a float64 array or raise TypeError naming the argument."""
    try:
        return np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as err:
        msg = f"{name} must be numeric array-like, got {type(a).__name__}: {a!r:.80}"
        raise TypeError(msg) from err


def _as_vectors(a: npt.ArrayLike, size: int, name: str) -> npt.NDArray[np.float64]:
    """Convert ``a`` to float64 with a last axis of ``size`` or raise ValueError."""
    arr = _as_float(a, name)
    if arr.ndim == 0 or arr.shape[-1] != size:
        msg = f"{name} must have shape (..., {size}), got shape {arr.shape}; reshape the input"
        raise ValueError(msg)
    return arr


def _as_points(a: npt.ArrayLike, name: str) -> npt.NDArray[np.float64]:
    """Convert ``a`` to an ``(N, 3)`` float64 array (a single ``(3,)`` point is allowed)."""
    arr = _as_vectors(a, 3, name)
    if arr.ndim > 2:
        msg = f"{name} must have shape (N, 3) or (3,), got {arr.shape}; reshape to (-1, 3)"
        raise ValueError(msg)
    return arr


def _require_finite(arr: npt.NDArray[np.float64], name: str) -> None:
    """Raise ValueError when ``arr`` holds NaN or inf."""
    if not np.all(np.isfinite(arr)):
        bad = int(np.size(arr) - np.count_nonzero(np.isfinite(arr)))
        msg = f"{name} holds {bad} non-finite value(s) (NaN or inf); drop or repair them first"
        raise ValueError(msg)


# --------------------------------------------------------------------------------------------
# Quaternions
# --------------------------------------------------------------------------------------------


def quat_normalize(q: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Scale quaternions to unit norm.

    Args:
        q: ``(..., 4)`` quaternions ``(x, y, z, w)``.

    Returns:
        ``(..., 4)`` float64 unit quaternions.

    Raises:
        ValueError: When the shape is wrong or a quaternion has (near) zero norm.
    """
    arr = _as_vectors(q, 4, "q")
    norm = np.linalg.norm(arr, axis=-1, keepdims=True)
    if np.any(~(norm > 1e-12)):
        msg = "q holds zero-norm or non-finite quaternions; they encode no rotation"
        raise ValueError(msg)
    out: npt.NDArray[np.float64] = arr / norm
    return out


def quat_multiply(a: npt.ArrayLike, b: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Hamilton product ``a ⊗ b`` (apply ``b`` first, then ``a``).

    Args:
        a: ``(..., 4)`` quaternions ``(x, y, z, w)``.
        b: ``(..., 4)`` quaternions, broadcast against ``a``.

    Returns:
        ``(..., 4)`` float64 product.
    """
    qa = _as_vectors(a, 4, "a")
    qb = _as_vectors(b, 4, "b")
    ax, ay, az, aw = np.moveaxis(qa, -1, 0)
    bx, by, bz, bw = np.moveaxis(qb, -1, 0)
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=-1,
    )


def quat_conjugate(q: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Conjugate ``(-x, -y, -z, w)`` of ``(..., 4)`` quaternions."""
    arr = _as_vectors(q, 4, "q")
    return arr * _CONJ


def quat_inverse(q: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Inverse ``conj(q) / |q|²`` of ``(..., 4)`` quaternions (the conjugate for unit ones)."""
    arr = _as_vectors(q, 4, "q")
    norm2 = np.sum(arr * arr, axis=-1, keepdims=True)
    if np.any(~(norm2 > 1e-24)):
        msg = "q holds zero-norm or non-finite quaternions; they have no inverse"
        raise ValueError(msg)
    out: npt.NDArray[np.float64] = quat_conjugate(arr) / norm2
    return out


def quat_rotate(q: npt.ArrayLike, v: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Rotate vectors by quaternions (active rotation: body → parent frame).

    Args:
        q: ``(..., 4)`` quaternions ``(x, y, z, w)``; normalised internally.
        v: ``(..., 3)`` vectors in the body frame, broadcast against ``q``.

    Returns:
        ``(..., 3)`` float64 vectors in the parent frame, same unit as ``v``.
    """
    qn = quat_normalize(q)
    vec = _as_vectors(v, 3, "v")
    u = qn[..., :3]
    w = qn[..., 3:]
    t = 2.0 * np.cross(u, vec)
    return vec + w * t + np.cross(u, t)


def quat_to_matrix(q: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Convert quaternions to rotation matrices.

    Args:
        q: ``(..., 4)`` quaternions ``(x, y, z, w)``; need not be exactly unit.

    Returns:
        ``(..., 3, 3)`` float64 rotation matrices ``R`` with ``R @ v_body = v_parent``.
    """
    arr = _as_vectors(q, 4, "q")
    x, y, z, w = np.moveaxis(arr, -1, 0)
    norm2 = x * x + y * y + z * z + w * w
    if np.any(~(norm2 > 1e-24)):
        msg = "q holds zero-norm or non-finite quaternions; they encode no rotation"
        raise ValueError(msg)
    s = 2.0 / norm2
    xx, yy, zz = s * x * x, s * y * y, s * z * z
    xy, xz, yz = s * x * y, s * x * z, s * y * z
    wx, wy, wz = s * w * x, s * w * y, s * w * z
    rows = [
        [1.0 - (yy + zz), xy - wz, xz + wy],
        [xy + wz, 1.0 - (xx + zz), yz - wx],
        [xz - wy, yz + wx, 1.0 - (xx + yy)],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def quat_from_matrix(R: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Convert rotation matrices to unit quaternions (Shepperd's method, vectorised).

    For each matrix the largest of ``(trace, R00, R11, R22)`` picks the numerically stable
    formula, so the result is accurate for every rotation including 180° turns.

    Args:
        R: ``(..., 3, 3)`` rotation matrices.

    Returns:
        ``(..., 4)`` float64 unit quaternions ``(x, y, z, w)`` with ``w >= 0``.
    """
    m = _as_float(R, "R")
    if m.ndim < 2 or m.shape[-2:] != (3, 3):
        msg = f"R must have shape (..., 3, 3), got {m.shape}"
        raise ValueError(msg)
    r00, r11, r22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    trace = r00 + r11 + r22
    s01, s02, s12 = (
        m[..., 0, 1] + m[..., 1, 0],
        m[..., 0, 2] + m[..., 2, 0],
        m[..., 1, 2] + m[..., 2, 1],
    )
    d21, d02, d10 = (
        m[..., 2, 1] - m[..., 1, 2],
        m[..., 0, 2] - m[..., 2, 0],
        m[..., 1, 0] - m[..., 0, 1],
    )
    # Candidate quaternions (x, y, z, w), each scaled by 4 * its dominant component.
    rows = (
        (1.0 + r00 - r11 - r22, s01, s02, d21),
        (s01, 1.0 - r00 + r11 - r22, s12, d02),
        (s02, s12, 1.0 - r00 - r11 + r22, d10),
        (d21, d02, d10, 1.0 + trace),
    )
    cand = np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)  # (..., 4, 4)
    choice = np.argmax(np.stack([r00, r11, r22, trace], axis=-1), axis=-1)
    q = np.take_along_axis(cand, choice[..., None, None], axis=-2)[..., 0, :]
    q = quat_normalize(q)
    return np.where(q[..., 3:] < 0.0, -q, q)


def quat_from_yaw(yaw: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Quaternions for rotations about +z.

    Args:
        yaw: ``(...)`` angles in radians, CCW seen from above.

    Returns:
        ``(..., 4)`` float64 unit quaternions.
    """
    half = 0.5 * _as_float(yaw, "yaw")
    zero = np.zeros_like(half)
    return np.stack([zero, zero, np.sin(half), np.cos(half)], axis=-1)


def yaw_from_quat(q: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Yaw (ZYX convention) of quaternions: ``atan2(2(wz + xy), 1 - 2(y² + z²))``.

    Args:
        q: ``(..., 4)`` quaternions ``(x, y, z, w)``.

    Returns:
        ``(...)`` float64 yaw in radians, in ``[-π, π]``.
    """
    x, y, z, w = np.moveaxis(quat_normalize(q), -1, 0)
    out: npt.NDArray[np.float64] = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return out


class EulerAngles(NamedTuple):
    """ROS (ZYX) Euler angles in radians: ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.

    Attributes:
        roll: ``(...)`` rotation about body x, in ``[-π, π]``.
        pitch: ``(...)`` rotation about body y, in ``[-π/2, π/2]`` (positive = nose down).
        yaw: ``(...)`` rotation about z, in ``[-π, π]``.
    """

    roll: npt.NDArray[np.float64]
    pitch: npt.NDArray[np.float64]
    yaw: npt.NDArray[np.float64]


def quat_from_euler(
    roll: npt.ArrayLike, pitch: npt.ArrayLike, yaw: npt.ArrayLike
) -> npt.NDArray[np.float64]:
    """Quaternions from ROS (ZYX) Euler angles, ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.

    Args:
        roll: ``(...)`` radians about x.
        pitch: ``(...)`` radians about y.
        yaw: ``(...)`` radians about z. The three broadcast together.

    Returns:
        ``(..., 4)`` float64 unit quaternions.
    """
    r, p, y = np.broadcast_arrays(
        0.5 * _as_float(roll, "roll"), 0.5 * _as_float(pitch, "pitch"), 0.5 * _as_float(yaw, "yaw")
    )
    cr, sr = np.cos(r), np.sin(r)
    cp, sp = np.cos(p), np.sin(p)
    cy, sy = np.cos(y), np.sin(y)
    return np.stack(
        [
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy,
        ],
        axis=-1,
    )


def euler_from_quat(q: npt.ArrayLike) -> EulerAngles:
    """ROS (ZYX) Euler angles of quaternions (inverse of :func:`quat_from_euler`).

    Near gimbal lock (``|pitch| → π/2``) roll and yaw are not separable; the split is arbitrary
    but the composed rotation is preserved.

    Args:
        q: ``(..., 4)`` quaternions ``(x, y, z, w)``.

    Returns:
        :class:`EulerAngles` of ``(...)`` float64 arrays in radians.
    """
    x, y, z, w = np.moveaxis(quat_normalize(q), -1, 0)
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return EulerAngles(roll=roll, pitch=pitch, yaw=yaw)


def quat_angle_between(a: npt.ArrayLike, b: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Geodesic angle between rotations (sign-invariant: ``q`` and ``-q`` are the same).

    Args:
        a: ``(..., 4)`` quaternions.
        b: ``(..., 4)`` quaternions, broadcast against ``a``.

    Returns:
        ``(...)`` float64 angle in radians, in ``[0, π]``.
    """
    d = quat_multiply(quat_conjugate(quat_normalize(a)), quat_normalize(b))
    out: npt.NDArray[np.float64] = 2.0 * np.arctan2(
        np.linalg.norm(d[..., :3], axis=-1), np.abs(d[..., 3])
    )
    return out


def slerp(q0: npt.ArrayLike, q1: npt.ArrayLike, t: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Spherical linear interpolation along the shortest path.

    ``q1`` is sign-flipped where ``dot(q0, q1) < 0``. Nearly identical rotations fall back to
    normalised linear interpolation, which is exact to rounding there.

    Args:
        q0: ``(..., 4)`` start quaternions (``t = 0``).
        q1: ``(..., 4)`` end quaternions (``t = 1``).
        t: ``(...)`` interpolation fractions, broadcast against ``q0[..., 0]``.

    Returns:
        ``(..., 4)`` float64 unit quaternions.
    """
    a = quat_normalize(q0)
    b = quat_normalize(q1)
    frac = _as_float(t, "t")[..., None]
    dot = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(dot < 0.0, -b, b)
    # Angle between the 4-vectors, accurate also when it is tiny.
    theta = 2.0 * np.arctan2(
        np.linalg.norm(a - b, axis=-1, keepdims=True), np.linalg.norm(a + b, axis=-1, keepdims=True)
    )
    small = theta < _SLERP_SMALL_ANGLE
    sin_theta = np.where(small, 1.0, np.sin(theta))
    w0 = np.where(small, 1.0 - frac, np.sin((1.0 - frac) * theta) / sin_theta)
    w1 = np.where(small, frac, np.sin(frac * theta) / sin_theta)
    return quat_normalize(w0 * a + w1 * b)


# --------------------------------------------------------------------------------------------
# Pose interpolation
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class PoseSamples:
    """A batch of poses.

    Attributes:
        positions: ``(N, 3)`` float64 metres, in the frame of the inputs.
        quats: ``(N, 4)`` float64 unit quaternions ``(x, y, z, w)``, body → same frame.
    """

    positions: npt.NDArray[np.float64]
    quats: npt.NDArray[np.float64]


def interpolate_poses(
    times_ns: npt.ArrayLike,
    positions: npt.ArrayLike,
    quats: npt.ArrayLike,
    query_ns: npt.ArrayLike,
) -> PoseSamples:
    """Interpolate poses at query times: linear for positions, slerp for orientations.

    The fraction between the bracketing samples is computed in integer nanoseconds relative to
    the earlier sample, so ~1.7e18 ns stamps lose no precision. At a sample time the sample is
    returned exactly.

    Args:
        times_ns: ``(N,)`` int64 strictly increasing stamps in nanoseconds, ``N >= 2``.
        positions: ``(N, 3)`` float64 positions (any unit and frame; passed through).
        quats: ``(N, 4)`` quaternions ``(x, y, z, w)``; normalised here.
        query_ns: ``(M,)`` int64 stamps (or one scalar) inside ``[times_ns[0], times_ns[-1]]``.

    Returns:
        :class:`PoseSamples` with ``(M, 3)`` positions and ``(M, 4)`` quaternions.

    Raises:
        TypeError: When the stamps are not integers.
        ValueError: On shape mismatch, unsorted stamps or query times out of range.
    """
    t = np.asarray(times_ns)
    tq = np.atleast_1d(np.asarray(query_ns))
    for name, arr in (("times_ns", t), ("query_ns", tq)):
        if arr.dtype.kind not in "iu":
            msg = f"{name} must be integer nanoseconds (int64), got dtype {arr.dtype}"
            raise TypeError(msg)
    t = t.astype(np.int64)
    tq = tq.astype(np.int64)
    pos = _as_vectors(positions, 3, "positions")
    q = quat_normalize(quats)
    n = t.shape[0] if t.ndim == 1 else -1
    if n < 2 or pos.shape != (n, 3) or q.shape != (n, 4) or tq.ndim != 1:
        msg = (
            "expected times_ns (N,), positions (N, 3), quats (N, 4) with N >= 2 and query_ns "
            f"(M,); got {t.shape}, {pos.shape}, {q.shape}, {tq.shape}"
        )
        raise ValueError(msg)
    if np.any(np.diff(t) <= 0):
        msg = "times_ns must be strictly increasing; sort the samples and drop duplicate stamps"
        raise ValueError(msg)
    outside = (tq < t[0]) | (tq > t[-1])
    if np.any(outside):
        msg = (
            f"{int(np.count_nonzero(outside))} query time(s) in [{int(tq.min())}, "
            f"{int(tq.max())}] ns lie outside the sampled range [{int(t[0])}, {int(t[-1])}] ns; "
            "clip the queries or extend the samples"
        )
        raise ValueError(msg)
    idx = np.clip(np.searchsorted(t, tq, side="right") - 1, 0, n - 2)
    offset = tq - t[idx]  # exact int64
    span = t[idx + 1] - t[idx]
    frac = (offset / span)[:, None]
    p0, p1 = pos[idx], pos[idx + 1]
    out_pos = (1.0 - frac) * p0 + frac * p1
    q0, q1 = q[idx], q[idx + 1]
    out_q = np.where(frac == 0.0, q0, np.where(frac == 1.0, q1, slerp(q0, q1, frac[:, 0])))
    return PoseSamples(positions=out_pos, quats=out_q)


# --------------------------------------------------------------------------------------------
# Angles
# --------------------------------------------------------------------------------------------


def _wrap_period(a: npt.NDArray[np.float64], half_period: float) -> npt.NDArray[np.float64]:
    """Wrap to ``[-half_period, half_period)`` robustly (mod may round up to the period)."""
    period = 2.0 * half_period
    r = np.mod(a + half_period, period) - half_period
    return np.where(r >= half_period, r - period, r)


@overload
def wrap_angle(a: float) -> float: ...
@overload
def wrap_angle(a: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]: ...
def wrap_angle(a: float | npt.NDArray[np.float64]) -> float | npt.NDArray[np.float64]:
    """Wrap angles in radians to ``[-π, π)``.

    Args:
        a: Scalar or ``(...)`` array of angles in radians.

    Returns:
        Same shape as ``a``; a float for a scalar.
    """
    out = _wrap_period(_as_float(a, "a"), math.pi)
    return float(out) if np.ndim(a) == 0 else out


@overload
def angle_difference(a: float, b: float) -> float: ...
@overload
def angle_difference(
    a: npt.NDArray[np.float64], b: npt.NDArray[np.float64] | float
) -> npt.NDArray[np.float64]: ...
@overload
def angle_difference(a: float, b: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]: ...
def angle_difference(
    a: float | npt.NDArray[np.float64], b: float | npt.NDArray[np.float64]
) -> float | npt.NDArray[np.float64]:
    """Signed difference ``a - b`` wrapped to ``[-π, π)`` (radians, broadcasting)."""
    out = _wrap_period(_as_float(a, "a") - _as_float(b, "b"), math.pi)
    return float(out) if np.ndim(a) == 0 and np.ndim(b) == 0 else out


def unwrap_angles(a: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Remove 2π jumps along the last axis (``np.unwrap``), e.g. before interpolating yaw.

    Args:
        a: ``(..., N)`` angles in radians.

    Returns:
        ``(..., N)`` float64 continuous angles in radians.
    """
    return np.unwrap(_as_float(a, "a"), axis=-1)


def circular_mean(
    angles: npt.ArrayLike, weights: npt.ArrayLike | None = None
) -> npt.NDArray[np.float64]:
    """Weighted circular mean along the last axis.

    Args:
        angles: ``(..., N)`` angles in radians.
        weights: Optional non-negative weights broadcastable to ``angles``; equal by default.

    Returns:
        ``(...)`` float64 mean angles in ``[-π, π]`` (a 0-d array for 1-D input).

    Raises:
        ValueError: When weights are negative or sum to zero, or when the mean is undefined
            because the weighted unit vectors cancel (resultant length ~0).
    """
    a = _as_float(angles, "angles")
    if a.ndim == 0 or a.shape[-1] == 0:
        msg = f"angles must have shape (..., N) with N >= 1, got {a.shape}"
        raise ValueError(msg)
    w = (
        np.ones_like(a)
        if weights is None
        else np.broadcast_to(_as_float(weights, "weights"), a.shape)
    )
    if np.any(w < 0.0) or not np.all(np.isfinite(w)):
        msg = "weights must be finite and non-negative; got a negative or non-finite weight"
        raise ValueError(msg)
    total = np.sum(w, axis=-1)
    if np.any(total <= 0.0):
        msg = "weights sum to 0 for at least one mean; give at least one sample a positive weight"
        raise ValueError(msg)
    s = np.sum(w * np.sin(a), axis=-1)
    c = np.sum(w * np.cos(a), axis=-1)
    if np.any(np.hypot(s, c) <= _RESULTANT_TOL * total):
        msg = (
            "circular mean is undefined: the angles cancel out (resultant length ~0, e.g. 0 and "
            "π with equal weights); use a different statistic or drop opposing samples"
        )
        raise ValueError(msg)
    return np.asarray(np.arctan2(s, c), dtype=np.float64)


# --------------------------------------------------------------------------------------------
# Rigid transforms
# --------------------------------------------------------------------------------------------


def _readonly(arr: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    out = np.array(arr, dtype=np.float64, copy=True)
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)
class Pose:
    """One rigid transform ``T_parent_body``: body coordinates → parent coordinates.

    Batches of poses use the module functions on ``(N, 3)`` / ``(N, 4)`` arrays instead.

    Attributes:
        position: ``(3,)`` float64 metres, origin of the body in the parent frame.
        quat: ``(4,)`` float64 unit quaternion ``(x, y, z, w)``, body → parent. A quaternion
            within 1e-6 of unit norm is normalised; anything else is rejected.
    """

    position: npt.NDArray[np.float64]
    quat: npt.NDArray[np.float64]

    def __post_init__(self) -> None:
        position = _as_float(self.position, "position")
        quat = _as_float(self.quat, "quat")
        if position.shape != (3,) or quat.shape != (4,):
            msg = f"Pose needs position (3,) and quat (4,), got {position.shape} and {quat.shape}"
            raise ValueError(msg)
        _require_finite(position, "Pose.position")
        _require_finite(quat, "Pose.quat")
        norm = float(np.linalg.norm(quat))
        if abs(norm - 1.0) > _UNIT_TOL:
            msg = (
                f"Pose.quat must be a unit quaternion (x, y, z, w), got norm {norm:.9g} for "
                f"{quat.tolist()!r}; normalise it with quat_normalize() first"
            )
            raise ValueError(msg)
        object.__setattr__(self, "position", _readonly(position))
        object.__setattr__(self, "quat", _readonly(quat / norm))

    def __repr__(self) -> str:
        return f"Pose(position={self.position.tolist()!r}, quat={self.quat.tolist()!r})"

    @classmethod
    def identity(cls) -> Pose:
        """Return the identity transform."""
        return cls(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))

    @classmethod
    def from_xyz_rpy(cls, xyz: npt.ArrayLike, rpy: npt.ArrayLike) -> Pose:
        """Build a pose from a position (metres) and ROS ZYX ``(roll, pitch, yaw)`` in radians."""
        r, p, y = _as_vectors(rpy, 3, "rpy")
        return cls(_as_float(xyz, "xyz"), quat_from_euler(r, p, y))

    @classmethod
    def from_matrix(cls, T: npt.ArrayLike) -> Pose:
        """Build a pose from a ``(4, 4)`` homogeneous transform ``T_parent_body``.

        Raises:
            ValueError: When ``T`` is not a rigid transform (shape, last row, non-orthonormal or
                reflecting rotation block, tolerance 1e-6).
        """
        m = _as_float(T, "T")
        if m.shape != (4, 4):
            msg = f"T must be a (4, 4) homogeneous transform, got shape {m.shape}"
            raise ValueError(msg)
        _require_finite(m, "T")
        rot = m[:3, :3]
        rigid = (
            np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=_UNIT_TOL)
            and np.allclose(rot.T @ rot, np.eye(3), atol=_UNIT_TOL)
            and np.linalg.det(rot) > 0.0
        )
        if not rigid:
            msg = (
                "T is not a rigid transform: expected an orthonormal rotation block with det +1 "
                f"and last row [0, 0, 0, 1], got {m.tolist()!r}"
            )
            raise ValueError(msg)
        return cls(m[:3, 3], quat_from_matrix(rot))

    def as_matrix(self) -> npt.NDArray[np.float64]:
        """Return the ``(4, 4)`` float64 homogeneous matrix ``T_parent_body``."""
        m = np.eye(4)
        m[:3, :3] = quat_to_matrix(self.quat)
        m[:3, 3] = self.position
        return m

    def compose(self, other: Pose) -> Pose:
        """Return ``self ∘ other``: ``T_a_c = T_a_b.compose(T_b_c)``."""
        return Pose(
            self.position + quat_rotate(self.quat, other.position),
            quat_normalize(quat_multiply(self.quat, other.quat)),
        )

    def __matmul__(self, other: Pose) -> Pose:
        if not isinstance(other, Pose):
            return NotImplemented
        return self.compose(other)

    def inverse(self) -> Pose:
        """Return the inverse transform ``T_body_parent``."""
        q_inv = quat_conjugate(self.quat)
        return Pose(-quat_rotate(q_inv, self.position), q_inv)

    def apply(self, points: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Map ``(..., 3)`` points from body to parent coordinates (metres)."""
        pts = _as_vectors(points, 3, "points")
        return quat_rotate(self.quat, pts) + self.position

    @property
    def heading(self) -> float:
        """Yaw of the body x axis in the parent frame, radians CCW from +x."""
        return float(yaw_from_quat(self.quat))


# --------------------------------------------------------------------------------------------
# Projections
# --------------------------------------------------------------------------------------------


def _crs(crs: str) -> pyproj.CRS:
    """Parse a CRS string, translating pyproj errors into ConfigError."""
    if not isinstance(crs, str) or not crs.strip():
        msg = f"CRS must be a non-empty string, got {crs!r}; {_CRS_EXAMPLE}"
        raise ConfigError(msg)
    try:
        return _parse_crs(crs)
    except CRSError as err:
        msg = f"invalid CRS {crs!r} ({err}); {_CRS_EXAMPLE}"
        raise ConfigError(msg) from err


@functools.lru_cache(maxsize=64)
def _parse_crs(crs: str) -> pyproj.CRS:
    return pyproj.CRS.from_user_input(crs)


@functools.lru_cache(maxsize=64)
def _cached_transformer(first: str, second: str) -> pyproj.Transformer:
    return pyproj.Transformer.from_crs(_parse_crs(first), _parse_crs(second), always_xy=True)


def _transform(
    src: str,
    dst: str,
    x: npt.NDArray[np.float64],
    y: npt.NDArray[np.float64],
    z: npt.NDArray[np.float64] | None = None,
) -> tuple[npt.NDArray[np.float64], ...]:
    """Transform coordinate arrays ``src → dst`` and check that every output is finite.

    One cached ``always_xy`` transformer serves both directions of a CRS pair. Bad CRS strings
    raise ConfigError.
    """
    _crs(src)
    _crs(dst)
    forward = src <= dst
    tr = _cached_transformer(src, dst) if forward else _cached_transformer(dst, src)
    direction = "FORWARD" if forward else "INVERSE"
    out = (
        tr.transform(x, y, direction=direction)
        if z is None
        else tr.transform(x, y, z, direction=direction)
    )
    arrays = tuple(np.asarray(o, dtype=np.float64) for o in out)
    if not all(np.all(np.isfinite(a)) for a in arrays):
        msg = (
            f"projecting from {src!r} to {dst!r} gave non-finite coordinates; check that the "
            "points lie in the CRS's area of use and that x/y are in the CRS's axis order (x first)"
        )
        raise ValueError(msg)
    return arrays


def _require_projected(crs: str) -> None:
    if not _crs(crs).is_projected:
        msg = f"headings need a projected CRS (metric grid), got {crs!r}; {_CRS_EXAMPLE}"
        raise ConfigError(msg)


@dataclass(frozen=True, eq=False)
class Wgs84Points:
    """Geodetic coordinates on WGS84.

    Attributes:
        lat_deg: ``(N,)`` float64 latitude, degrees.
        lon_deg: ``(N,)`` float64 longitude, degrees.
        alt_m: ``(N,)`` float64 ellipsoidal height, metres.
    """

    lat_deg: npt.NDArray[np.float64]
    lon_deg: npt.NDArray[np.float64]
    alt_m: npt.NDArray[np.float64]


def utm_crs_for(lat_deg: float, lon_deg: float) -> str:
    """Return the WGS84 UTM CRS for a point: ``"EPSG:326NN"`` north, ``"EPSG:327NN"`` south.

    Uses the regular 6° zones (no Norway/Svalbard exceptions).
    """
    if not (-90.0 <= lat_deg <= 90.0 and -180.0 <= lon_deg <= 180.0):
        msg = f"lat/lon out of range: ({lat_deg!r}, {lon_deg!r}); expected degrees, lat first"
        raise ValueError(msg)
    zone = int((lon_deg + 180.0) // 6.0) % 60 + 1
    return f"EPSG:{326 if lat_deg >= 0.0 else 327}{zone:02d}"


@dataclass(frozen=True)
class WorldFrame:
    """The workspace world frame: a transverse Mercator projection centred on the origin.

    World coordinates are ``(x east, y north, z up)`` metres, with scale 1 at the origin and
    ``z = ellipsoidal height - origin_alt_m``. :attr:`proj_string` is also written into the
    OpenDRIVE ``<geoReference>``, so map coordinates equal world coordinates. The origin is
    rounded to 1e-10 degrees (about 11 µm), the precision of :attr:`proj_string`, so the fields
    and the string always describe the same frame.

    Attributes:
        origin_lat_deg: Latitude of the origin, degrees WGS84.
        origin_lon_deg: Longitude of the origin, degrees WGS84.
        origin_alt_m: Ellipsoidal height of the origin, metres.
    """

    origin_lat_deg: float
    origin_lon_deg: float
    origin_alt_m: float = 0.0

    def __post_init__(self) -> None:
        vals = (self.origin_lat_deg, self.origin_lon_deg, self.origin_alt_m)
        ok = all(
            isinstance(v, (int, float, np.floating, np.integer)) and math.isfinite(v) for v in vals
        )
        if not ok or not (-90.0 < self.origin_lat_deg < 90.0) or abs(self.origin_lon_deg) > 180.0:
            msg = (
                f"WorldFrame origin must be finite degrees with |lat| < 90 and |lon| <= 180, got "
                f"lat={self.origin_lat_deg!r}, lon={self.origin_lon_deg!r}, "
                f"alt={self.origin_alt_m!r}; pass the origin in degrees WGS84, latitude first"
            )
            raise ConfigError(msg)
        for name in ("origin_lat_deg", "origin_lon_deg"):
            object.__setattr__(self, name, round(float(getattr(self, name)), _ORIGIN_DECIMALS))
        object.__setattr__(self, "origin_alt_m", float(self.origin_alt_m))

    @classmethod
    def at_crs_point(cls, crs: str, x: float, y: float, z: float = 0.0) -> WorldFrame:
        """Put the origin at a point given in ``crs`` (e.g. the first UTM odometry sample).

        Args:
            crs: pyproj CRS string such as ``"EPSG:32632"``.
            x: First axis (easting / longitude) in the CRS unit.
            y: Second axis (northing / latitude).
            z: Ellipsoidal height, metres.
        """
        lon, lat = _transform(crs, _WGS84, np.array([x], dtype=float), np.array([y], dtype=float))
        return cls(float(lat[0]), float(lon[0]), float(z))

    @property
    def proj_string(self) -> str:
        """PROJ string of the world frame (also the OpenDRIVE ``<geoReference>``)."""
        return (
            f"+proj=tmerc +lat_0={self.origin_lat_deg:.10f} +lon_0={self.origin_lon_deg:.10f} "
            "+k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs"
        )

    def from_wgs84(
        self, lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike, alt_m: npt.ArrayLike = 0.0
    ) -> npt.NDArray[np.float64]:
        """Project WGS84 points into the world frame.

        Args:
            lat_deg: ``(N,)`` latitude, degrees.
            lon_deg: ``(N,)`` longitude, degrees.
            alt_m: ``(N,)`` ellipsoidal height, metres (broadcast).

        Returns:
            ``(N, 3)`` float64 world coordinates, metres.
        """
        lat, lon, alt = np.broadcast_arrays(
            np.atleast_1d(_as_float(lat_deg, "lat_deg")),
            np.atleast_1d(_as_float(lon_deg, "lon_deg")),
            np.atleast_1d(_as_float(alt_m, "alt_m")),
        )
        x, y = _transform(_WGS84, self.proj_string, lon, lat)
        return np.stack([x, y, alt - self.origin_alt_m], axis=-1)

    def to_wgs84(self, xyz: npt.ArrayLike) -> Wgs84Points:
        """Convert ``(N, 3)`` world points (metres) to WGS84 latitude, longitude and height."""
        pts = np.atleast_2d(_as_points(xyz, "xyz"))
        lon, lat = _transform(self.proj_string, _WGS84, pts[:, 0], pts[:, 1])
        return Wgs84Points(lat_deg=lat, lon_deg=lon, alt_m=pts[:, 2] + self.origin_alt_m)

    def from_crs(self, crs: str, xyz: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Convert ``(N, 3)`` points given in ``crs`` to ``(N, 3)`` world metres.

        ``crs`` is any pyproj CRS string, e.g. ``"EPSG:32632"`` (x easting, y northing, z
        ellipsoidal height). Axes are in x-first (``always_xy``) order.
        """
        pts = np.atleast_2d(_as_points(xyz, "xyz"))
        x, y, z = _transform(crs, self.proj_string, pts[:, 0], pts[:, 1], pts[:, 2])
        return np.stack([x, y, z - self.origin_alt_m], axis=-1)

    def to_crs(self, crs: str, xyz_world: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Convert ``(N, 3)`` world points (metres) to ``(N, 3)`` coordinates in ``crs``."""
        pts = np.atleast_2d(_as_points(xyz_world, "xyz_world"))
        x, y, z = _transform(
            self.proj_string, crs, pts[:, 0], pts[:, 1], pts[:, 2] + self.origin_alt_m
        )
        return np.stack([x, y, z], axis=-1)

    def _heading_map(
        self, src: str, dst: str, xy: npt.ArrayLike, heading: npt.ArrayLike
    ) -> npt.NDArray[np.float64]:
        """Map grid headings at points in ``src`` to grid headings in ``dst``.

        Projects two points ``_HEADING_HALF_STEP_M`` either side of each point along the heading
        (central difference) and takes the angle of the projected chord.
        """
        pts = _as_vectors(xy, 2, "xy")
        h = _as_float(heading, "heading")
        if pts.ndim != 2 or h.shape != pts.shape[:1]:
            msg = f"expected xy (N, 2) and heading (N,), got {pts.shape} and {h.shape}"
            raise ValueError(msg)
        step = _HEADING_HALF_STEP_M * np.stack([np.cos(h), np.sin(h)], axis=-1)
        ends = np.concatenate([pts - step, pts + step])
        x, y = _transform(src, dst, ends[:, 0], ends[:, 1])
        n = pts.shape[0]
        return np.arctan2(y[n:] - y[:n], x[n:] - x[:n])

    def heading_from_crs(
        self, crs: str, xy_crs: npt.ArrayLike, heading_crs: npt.ArrayLike
    ) -> npt.NDArray[np.float64]:
        """Convert headings measured on the grid of a projected ``crs`` to world headings.

        Accounts for the grid-convergence difference between the two projections (about 1.9°
        for UTM 32N vs a local frame at Munich).

        Args:
            crs: Projected CRS string, e.g. ``"EPSG:32632"``.
            xy_crs: ``(N, 2)`` positions in ``crs``.
            heading_crs: ``(N,)`` radians CCW from the ``crs`` grid +x axis.

        Returns:
            ``(N,)`` float64 world headings, radians in ``[-π, π]``.
        """
        _require_projected(crs)
        return self._heading_map(crs, self.proj_string, xy_crs, heading_crs)

    def heading_to_crs(
        self, crs: str, xy_world: npt.ArrayLike, heading_world: npt.ArrayLike
    ) -> npt.NDArray[np.float64]:
        """Convert ``(N,)`` world headings at ``(N, 2)`` world positions to ``crs`` headings."""
        _require_projected(crs)
        return self._heading_map(self.proj_string, crs, xy_world, heading_world)

    def quats_from_crs(
        self, crs: str, xy_crs: npt.ArrayLike, quats_crs: npt.ArrayLike
    ) -> npt.NDArray[np.float64]:
        """Rotate ``(N, 4)`` orientations given on the ``crs`` grid into the world frame.

        Each quaternion is left-multiplied by a rotation about +z through the local convergence
        angle at its ``(N, 2)`` position ``xy_crs``.
        """
        q = quat_normalize(quats_crs)
        n = _as_vectors(xy_crs, 2, "xy_crs").shape[0]
        gamma = self.heading_from_crs(crs, xy_crs, np.zeros(n))
        return quat_multiply(quat_from_yaw(gamma), q)

    def quats_to_crs(
        self, crs: str, xy_world: npt.ArrayLike, quats_world: npt.ArrayLike
    ) -> npt.NDArray[np.float64]:
        """Rotate ``(N, 4)`` world orientations at ``(N, 2)`` world positions onto the crs grid."""
        q = quat_normalize(quats_world)
        n = _as_vectors(xy_world, 2, "xy_world").shape[0]
        gamma = self.heading_to_crs(crs, xy_world, np.zeros(n))
        return quat_multiply(quat_from_yaw(gamma), q)


# --------------------------------------------------------------------------------------------
# CARLA boundary
# --------------------------------------------------------------------------------------------


def world_to_carla(xyz: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Convert ``(..., 3)`` world points (x east, y north, z up; metres) to CARLA (y flipped)."""
    return _as_vectors(xyz, 3, "xyz") * _FLIP_Y


def carla_to_world(xyz_carla: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Convert ``(..., 3)`` CARLA locations (left-handed, metres) to world points."""
    return _as_vectors(xyz_carla, 3, "xyz_carla") * _FLIP_Y


@overload
def heading_to_carla_yaw_deg(heading: float) -> float: ...
@overload
def heading_to_carla_yaw_deg(heading: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]: ...
def heading_to_carla_yaw_deg(
    heading: float | npt.NDArray[np.float64],
) -> float | npt.NDArray[np.float64]:
    """Convert world headings (rad, CCW) to CARLA yaw (degrees, clockwise) in ``[-180, 180)``."""
    out = _wrap_period(-np.degrees(_as_float(heading, "heading")), 180.0)
    return float(out) if np.ndim(heading) == 0 else out


@overload
def carla_yaw_deg_to_heading(yaw_deg: float) -> float: ...
@overload
def carla_yaw_deg_to_heading(yaw_deg: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]: ...
def carla_yaw_deg_to_heading(
    yaw_deg: float | npt.NDArray[np.float64],
) -> float | npt.NDArray[np.float64]:
    """Convert CARLA yaw (degrees, clockwise) to world headings (rad, CCW) in ``[-π, π)``."""
    out = _wrap_period(-np.radians(_as_float(yaw_deg, "yaw_deg")), math.pi)
    return float(out) if np.ndim(yaw_deg) == 0 else out


@dataclass(frozen=True, eq=False)
class CarlaTransform:
    """A pose in CARLA's terms (the fields of ``carla.Transform``).

    Attributes:
        location: ``(3,)`` float64 metres in CARLA's left-handed frame (y = -world y).
        pitch_deg: Nose up positive, in ``[-90, 90]``.
        yaw_deg: Clockwise seen from above, in ``[-180, 180)``.
        roll_deg: Right side down positive (UE4 ``FRotator``), in ``[-180, 180]``.
    """

    location: npt.NDArray[np.float64]
    pitch_deg: float
    yaw_deg: float
    roll_deg: float


def pose_to_carla(pose: Pose) -> CarlaTransform:
    """Convert a world pose to a CARLA transform.

    Derivation: UE4's ``FRotationMatrix(pitch p, yaw y, roll r)`` has rows forward
    ``(cp*cy, cp*sy, sp)``, right ``(sr*sp*cy - cr*sy, sr*sp*sy + cr*cy, -sr*cp)`` and up
    ``(-(cr*sp*cy + sr*sy), cy*sr - cr*sp*sy, cr*cp)`` in CARLA coordinates (UE uses row
    vectors, so the rows are the body axes). Flipping y on both the parent and the body
    (world left = -CARLA right) turns it into ``Rz(-y) @ Ry(-p) @ Rx(r)`` in the world frame.
    Hence ROS roll = UE roll, ROS pitch = -UE pitch, ROS yaw = -UE yaw.
    """
    e = euler_from_quat(pose.quat)
    return CarlaTransform(
        location=world_to_carla(pose.position),
        pitch_deg=float(-np.degrees(e.pitch)),
        yaw_deg=heading_to_carla_yaw_deg(float(e.yaw)),
        roll_deg=float(np.degrees(e.roll)),
    )


def pose_from_carla(t: CarlaTransform) -> Pose:
    """Convert a CARLA transform to a world pose (inverse of :func:`pose_to_carla`)."""
    quat = quat_from_euler(
        math.radians(t.roll_deg), -math.radians(t.pitch_deg), -math.radians(t.yaw_deg)
    )
    return Pose(carla_to_world(t.location), quat)
