"""Rigid transforms (SE(3) poses) and pose interpolation over time."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from cam2sim.core.frames._common import _UNIT_TOL, _as_float, _as_vectors, _require_finite
from cam2sim.core.frames.rotation import (
    quat_conjugate,
    quat_from_euler,
    quat_from_matrix,
    quat_multiply,
    quat_normalize,
    quat_rotate,
    quat_to_matrix,
    slerp,
    yaw_from_quat,
)

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = [
    "Pose",
    "PoseSamples",
    "camera_poses",
    "interpolate_poses",
]

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


def camera_poses(
    position: npt.ArrayLike,
    quat: npt.ArrayLike,
    mount_translation: npt.ArrayLike,
    mount_quat: npt.ArrayLike,
) -> npt.NDArray[np.float64]:
    """Camera poses ``T_world_cam = T_world_body o T_body_camera``: the one place this is done.

    Args:
        position: ``(N, 3)`` body positions, world metres.
        quat: ``(N, 4)`` body orientations ``(x, y, z, w)``, body -> world.
        mount_translation: ``(3,)`` camera position in the body frame, metres.
        mount_quat: ``(4,)`` camera orientation ``(x, y, z, w)``, camera -> body.

    Returns:
        ``(N, 4, 4)`` float64, camera -> world.
    """
    pos = np.asarray(position, dtype=np.float64).reshape(-1, 3)
    q = quat_normalize(np.asarray(quat, dtype=np.float64).reshape(-1, 4))
    T_body_cam = Pose(np.asarray(mount_translation), np.asarray(mount_quat)).as_matrix()
    T_world_body = np.tile(np.eye(4), (pos.shape[0], 1, 1))
    T_world_body[:, :3, :3] = quat_to_matrix(q)
    T_world_body[:, :3, 3] = pos
    out: npt.NDArray[np.float64] = T_world_body @ T_body_cam
    return out
