"""Quaternions, Euler angles, slerp and angle arithmetic."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple, overload

import numpy as np

from cam2sim.core.frames._common import (
    _CONJ,
    _RESULTANT_TOL,
    _SLERP_SMALL_ANGLE,
    _as_float,
    _as_vectors,
)

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = [
    "EulerAngles",
    "angle_difference",
    "circular_mean",
    "euler_from_quat",
    "quat_angle_between",
    "quat_conjugate",
    "quat_from_euler",
    "quat_from_matrix",
    "quat_from_rotvec",
    "quat_from_yaw",
    "quat_inverse",
    "quat_multiply",
    "quat_normalize",
    "quat_rotate",
    "quat_to_matrix",
    "rotvec_from_quat",
    "slerp",
    "unwrap_angles",
    "wrap_angle",
    "yaw_from_quat",
]

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


def rotvec_from_quat(q: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Rotation vectors (axis times angle, radians, angle in ``[0, pi]``) of quaternions.

    Args:
        q: ``(..., 4)`` quaternions ``(x, y, z, w)``.

    Returns:
        ``(..., 3)`` float64.
    """
    u = quat_normalize(q)
    u = np.where(u[..., 3:] < 0.0, -u, u)
    norm = np.linalg.norm(u[..., :3], axis=-1)
    angle = 2.0 * np.arctan2(norm, u[..., 3])
    # angle / sin(angle / 2), with its limit 2 at zero
    scale = np.where(norm > 1e-12, angle / np.maximum(norm, 1e-300), 2.0)
    out: npt.NDArray[np.float64] = u[..., :3] * scale[..., None]
    return out


def quat_from_rotvec(v: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Quaternions ``(x, y, z, w)`` of rotation vectors (inverse of :func:`rotvec_from_quat`).

    Args:
        v: ``(..., 3)`` axis times angle, radians.

    Returns:
        ``(..., 4)`` float64 unit quaternions.
    """
    r = _as_float(v, "v")
    if r.shape[-1:] != (3,):
        msg = f"v must have shape (..., 3), got {r.shape}"
        raise ValueError(msg)
    angle = np.linalg.norm(r, axis=-1)
    # sin(angle / 2) / angle, with its limit 1/2 at zero
    scale = np.where(angle > 1e-12, np.sin(0.5 * angle) / np.maximum(angle, 1e-300), 0.5)
    return np.concatenate([r * scale[..., None], np.cos(0.5 * angle)[..., None]], axis=-1)


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
