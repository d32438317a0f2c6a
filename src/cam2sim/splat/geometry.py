"""Route geometry for splat preparation: frame selection, chunks, camera poses, undistortion."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from cam2sim.core import frames as fr
from cam2sim.core.camera import DistortionModel, PinholeCamera
from cam2sim.core.grid import grid_cells
from cam2sim.splat.scene import ChunkRecord

if TYPE_CHECKING:
    from collections.abc import Sequence

    from cam2sim.core.dataset import MountRecord


__all__ = [
    "Undistorter",
    "apply_similarity",
    "camera_poses",
    "chunk_membership",
    "chunks_by_distance",
    "distance_travelled",
    "interpolated_corrections",
    "on_route_ground",
    "recorded_to_model",
    "select_by_distance",
    "similarity_from_poses",
    "smoothed_corrections",
    "undistort_camera",
    "undistorter",
    "voxel_downsample",
]

logger = logging.getLogger(__name__)


# --------------------------------------------------------------------------------------------
# Geometry helpers (pure, vectorised)
# --------------------------------------------------------------------------------------------


def distance_travelled(positions: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Cumulative path length along ``(N, 3)`` positions: ``(N,)`` metres, starting at 0."""
    p = np.asarray(positions, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        msg = f"positions must be (N, 3), got {p.shape}"
        raise ValueError(msg)
    steps = np.linalg.norm(np.diff(p, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def select_by_distance(positions: npt.ArrayLike, spacing_m: float) -> npt.NDArray[np.int64]:
    """Pick one frame every ``spacing_m`` metres of distance travelled.

    For each multiple ``k * spacing_m`` of the path length the first frame at or beyond it is
    taken (so frames while standing still are skipped, and a fast stretch with fewer frames than
    targets keeps every frame once).

    Args:
        positions: ``(N, 3)`` positions in recording order, metres.
        spacing_m: Spacing, metres; 0 keeps every frame.

    Returns:
        ``(M,)`` int64 sorted unique indices into ``positions`` (the first frame always).
    """
    s = distance_travelled(positions)
    if spacing_m <= 0 or s.shape[0] == 0:
        return np.arange(s.shape[0], dtype=np.int64)
    targets = np.arange(0.0, s[-1] + 1e-9, spacing_m)
    idx = np.searchsorted(s, targets - 1e-9, side="left")
    return np.unique(np.clip(idx, 0, s.shape[0] - 1)).astype(np.int64)


def chunks_by_distance(
    progress_m: npt.ArrayLike,
    positions: npt.ArrayLike,
    *,
    chunk_length_m: float,
    overlap_m: float,
) -> list[ChunkRecord]:
    """Split a route into overlapping chunks of equal length by distance travelled.

    The route is cut into as few chunks as keep each at most ``chunk_length_m`` long, a
    remainder of up to ``overlap_m`` absorbed: ``n = 1 + ceil((length - chunk_length_m -
    overlap_m) / (chunk_length_m - overlap_m))`` (at least 1). All ``n`` get the same length
    ``(length + (n - 1) * overlap_m) / n`` (at most ``chunk_length_m + overlap_m / n``), and
    consecutive ones overlap by ``overlap_m``. Cut at a fixed length instead, a route 0.7 m
    longer than three steps got a fourth chunk of 30 m lying wholly inside the third, trained
    for as many steps as the others on a fifth of their frames (Munich route 0, 391 m), and a
    184 m route a 150 m chunk and a 64 m one. A frame belongs to every chunk whose span contains
    it: one or two (``overlap_m`` is less than half a chunk). Chunks without frames (a gap in
    the recording) are dropped.

    Args:
        progress_m: ``(N,)`` non-decreasing distance travelled at each frame, metres.
        positions: ``(N, 3)`` camera positions (for each chunk's centre), metres.
        chunk_length_m: Longest chunk, metres (but for the absorbed remainder).
        overlap_m: Overlap, metres, ``0 <= overlap_m < chunk_length_m / 2``.

    Returns:
        Chunks with consecutive ids, each listing its frame indices.
    """
    s = np.asarray(progress_m, dtype=np.float64)
    p = np.asarray(positions, dtype=np.float64)
    if s.ndim != 1 or p.shape != (s.shape[0], 3) or s.shape[0] == 0:
        msg = f"need progress (N,) and positions (N, 3) with N >= 1, got {s.shape}, {p.shape}"
        raise ValueError(msg)
    if not (chunk_length_m > 0 and 0 <= overlap_m < chunk_length_m / 2):
        msg = "need chunk_length_m > 0 and 0 <= overlap_m < chunk_length_m / 2, got "
        msg += f"{chunk_length_m!r}, {overlap_m!r}"
        raise ValueError(msg)
    start, total = float(s[0]), float(s[-1])
    length = total - start
    step = chunk_length_m - overlap_m
    n = 1 + max(0, math.ceil((length - chunk_length_m - overlap_m) / step - 1e-9))
    each = (length + (n - 1) * overlap_m) / n
    starts = start + (each - overlap_m) * np.arange(n)
    ends = np.minimum(starts + each, total)
    ends[-1] = total
    member = (s[None, :] >= starts[:, None] - 1e-9) & (s[None, :] <= ends[:, None] + 1e-9)
    chunks: list[ChunkRecord] = []
    for k in np.flatnonzero(member.any(axis=1)):
        idx = np.flatnonzero(member[k])
        chunks.append(
            ChunkRecord(
                id=len(chunks),
                start_m=float(starts[k]),
                end_m=float(ends[k]),
                frames=[int(i) for i in idx],
                center=[float(v) for v in p[idx].mean(axis=0)],
            )
        )
    return chunks


def chunk_membership(chunks: list[ChunkRecord]) -> dict[int, list[int]]:
    """Frame index -> the ids of the chunks it belongs to (overlapping chunks share frames)."""
    member: dict[int, list[int]] = {}
    for chunk in chunks:
        for i in chunk.frames:
            member.setdefault(i, []).append(chunk.id)
    return member


def camera_poses(
    position: npt.ArrayLike, quat: npt.ArrayLike, mount: MountRecord
) -> npt.NDArray[np.float64]:
    """Camera poses of body poses with a dataset's mount (:func:`cam2sim.core.frames.camera_poses`).

    Args:
        position: ``(N, 3)`` body positions, world metres.
        quat: ``(N, 4)`` body orientations ``(x, y, z, w)``, body -> world.
        mount: The camera mount ``T_body_camera`` (optical axes).

    Returns:
        ``(N, 4, 4)`` float64, camera (optical) -> world.
    """
    return fr.camera_poses(position, quat, mount.translation_m, mount.quat_xyzw)


def voxel_downsample(
    xyz: npt.ArrayLike, rgb: npt.ArrayLike, voxel_m: float
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.uint8]]:
    """Average points and colours per voxel.

    Args:
        xyz: ``(N, 3)`` positions, metres.
        rgb: ``(N, 3)`` uint8 colours.
        voxel_m: Voxel edge, metres.

    Returns:
        ``(M, 3)`` float64 voxel means and ``(M, 3)`` uint8 mean colours, ``M <= N``.
    """
    p = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    c = np.asarray(rgb).reshape(-1, 3)
    if p.shape[0] == 0:
        return p, c.astype(np.uint8)
    keys = np.floor(p / voxel_m).astype(np.int64)
    inverse, counts = grid_cells(keys)
    m = counts.shape[0]
    out_p = np.stack([np.bincount(inverse, p[:, i], minlength=m) for i in range(3)], 1)
    out_c = np.stack([np.bincount(inverse, c[:, i].astype(np.float64), m) for i in range(3)], 1)
    return out_p / counts[:, None], np.round(out_c / counts[:, None]).astype(np.uint8)


@dataclass(frozen=True, eq=False)
class Undistorter:
    """Undistortion of one camera to a pinhole camera of the same size.

    Attributes:
        recorded: The recorded camera (with its distortion).
        camera: The distortion-free camera of the undistorted images.
        maps: OpenCV remap tables, or None when there is no distortion (identity).
    """

    recorded: PinholeCamera
    camera: PinholeCamera
    maps: tuple[npt.NDArray[Any], npt.NDArray[Any]] | None  # cv2 map dtypes vary (int16/float)

    @property
    def K(self) -> npt.NDArray[np.float64]:
        """``(3, 3)`` recorded intrinsics."""
        return self.recorded.K()

    @property
    def K_new(self) -> npt.NDArray[np.float64]:
        """``(3, 3)`` intrinsics of the undistorted images."""
        return self.camera.K()

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)`` pixels."""
        return self.camera.size

    def apply(self, image: npt.NDArray[Any], *, nearest: bool = False) -> npt.NDArray[Any]:
        """Undistort an image or mask (``nearest`` for masks); out-of-view pixels become 0."""
        import cv2  # noqa: PLC0415

        if self.maps is None:
            return image
        interp = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
        out: npt.NDArray[Any] = cv2.remap(
            image, self.maps[0], self.maps[1], interp, borderMode=cv2.BORDER_CONSTANT
        )
        return out


def undistort_camera(camera: PinholeCamera) -> Undistorter:
    """Build the undistortion of a camera (alpha = 0: every output pixel sees the scene).

    The undistorted camera is :meth:`PinholeCamera.undistorted`; this adds the remap tables.
    """
    import cv2  # noqa: PLC0415

    new = camera.undistorted()
    dist = np.asarray(camera.distortion, dtype=np.float64)
    if dist.size == 0 or not np.any(dist):
        return Undistorter(camera, new, None)
    K, K_new, size = camera.K(), new.K(), camera.size
    if camera.distortion_model == "equidistant":
        d4 = np.zeros(4)
        d4[: min(4, dist.size)] = dist[:4]
        maps = cv2.fisheye.initUndistortRectifyMap(K, d4, np.eye(3), K_new, size, cv2.CV_16SC2)
    else:
        maps = cv2.initUndistortRectifyMap(K, dist, None, K_new, size, cv2.CV_16SC2)
    return Undistorter(camera, new, (maps[0], maps[1]))


def undistorter(
    K: npt.ArrayLike,
    distortion: Sequence[float],
    size: tuple[int, int],
    *,
    model: str = "plumb_bob",
) -> Undistorter:
    """Build the undistortion of a camera given as a matrix (see :func:`undistort_camera`).

    Args:
        K: ``(3, 3)`` intrinsics, pixels.
        distortion: plumb-bob ``(k1, k2, p1, p2[, k3, ...])`` or equidistant ``(k1..k4)``.
        size: ``(width, height)`` pixels.
        model: ``plumb_bob`` or ``equidistant``.

    Returns:
        The new intrinsics and remap tables.
    """
    kind: DistortionModel = "equidistant" if model == "equidistant" else "plumb_bob"
    camera = PinholeCamera.from_K(
        K, size[0], size[1], tuple(float(v) for v in distortion), distortion_model=kind
    )
    return undistort_camera(camera)


def similarity_from_poses(
    T_src: npt.ArrayLike, T_dst: npt.ArrayLike, *, with_scale: bool = True
) -> npt.NDArray[np.float64]:
    """Least-squares similarity ``S`` with ``S o T_src ~ T_dst`` for corresponding poses.

    The rotation is the chordal mean of ``R_dst R_src^T`` (so camera centres on a straight
    line, where a fit to the centres alone leaves the roll about that line free, still give a
    unique answer); scale and translation then fit the camera centres.

    Args:
        T_src: ``(N, 4, 4)`` poses ``T_world_cam`` in the source frame, ``N >= 1``.
        T_dst: ``(N, 4, 4)`` the same cameras in the destination frame.
        with_scale: Estimate the scale (else ``s = 1``; also when the centres coincide).

    Returns:
        ``(4, 4)`` float64 ``[[s R, t], [0, 1]]`` mapping source points to destination points.

    Raises:
        ValueError: Shapes differ or are not ``(N, 4, 4)``.
    """
    a = np.asarray(T_src, dtype=np.float64)
    b = np.asarray(T_dst, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 3 or a.shape[1:] != (4, 4) or a.shape[0] < 1:
        msg = f"need two (N >= 1, 4, 4) pose stacks of one shape, got {a.shape} and {b.shape}"
        raise ValueError(msg)
    u, _, vt = np.linalg.svd((b[:, :3, :3] @ np.swapaxes(a[:, :3, :3], 1, 2)).sum(axis=0))
    rot = u @ np.diag([1.0, 1.0, float(np.linalg.det(u @ vt))]) @ vt
    ca, cb = a[:, :3, 3], b[:, :3, 3]
    da = (ca - ca.mean(0)) @ rot.T
    db = cb - cb.mean(0)
    var = float((da**2).sum())
    scale = float((da * db).sum() / var) if with_scale and var > 1e-12 else 1.0
    T = np.eye(4)
    T[:3, :3] = scale * rot
    T[:3, 3] = cb.mean(0) - scale * rot @ ca.mean(0)
    return T


def apply_similarity(S: npt.ArrayLike, T_world_cam: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Map ``(N, 4, 4)`` poses through a similarity ``S`` (rotation turned, centre moved/scaled)."""
    Sm = np.asarray(S, dtype=np.float64)
    T = np.asarray(T_world_cam, dtype=np.float64)
    scale = float(np.cbrt(np.linalg.det(Sm[:3, :3])))
    out = T.copy()
    out[..., :3, :3] = (Sm[:3, :3] / scale) @ T[..., :3, :3]
    out[..., :3, 3] = T[..., :3, 3] @ Sm[:3, :3].T + Sm[:3, 3]
    return out


def interpolated_corrections(
    recorded: npt.ArrayLike, adjusted: npt.ArrayLike, fitted: npt.ArrayLike
) -> npt.NDArray[np.float64]:
    """Adjusted poses where ``fitted``; elsewhere the recorded pose with its neighbours' correction.

    A fitted frame's correction is ``C = T_recorded^-1 T_adjusted`` (in its camera frame). An
    unfitted frame (a held-out view kept out of a bundle adjustment, so its pose is never
    fitted to its own image) takes the correction of the fitted frames before and after it,
    interpolated by frame number (rotation by slerp, translation linearly); beyond the ends,
    the nearest one's.

    Args:
        recorded: ``(N, 4, 4)`` recorded poses ``T_world_cam``.
        adjusted: ``(N, 4, 4)`` the adjusted poses (only the fitted rows are read).
        fitted: ``(N,)`` bool, True where ``adjusted`` holds a fitted pose (at least one).

    Returns:
        ``(N, 4, 4)`` float64 poses.

    Raises:
        ValueError: Shapes differ, or no frame is fitted.
    """
    rec = np.asarray(recorded, dtype=np.float64)
    adj = np.asarray(adjusted, dtype=np.float64)
    mask = np.asarray(fitted, dtype=bool)
    if rec.shape != adj.shape or rec.ndim != 3 or rec.shape[1:] != (4, 4):
        msg = f"need two (N, 4, 4) pose stacks of one shape, got {rec.shape} and {adj.shape}"
        raise ValueError(msg)
    if mask.shape != (rec.shape[0],) or not mask.any():
        msg = f"fitted must be ({rec.shape[0]},) bools with at least one True"
        raise ValueError(msg)
    out = adj.copy()
    if mask.all():
        return out
    known = np.flatnonzero(mask)
    corr = np.linalg.inv(rec[known]) @ adj[known]
    quat = fr.quat_from_matrix(corr[:, :3, :3])
    todo = np.flatnonzero(~mask)
    after = np.minimum(np.searchsorted(known, todo), len(known) - 1)
    before = np.maximum(after - 1, 0)
    span = (known[after] - known[before]).astype(np.float64)
    t = np.clip((todo - known[before]) / np.where(span > 0, span, 1.0), 0.0, 1.0)
    C = np.tile(np.eye(4), (len(todo), 1, 1))
    C[:, :3, :3] = fr.quat_to_matrix(fr.slerp(quat[before], quat[after], t))
    C[:, :3, 3] = (1 - t)[:, None] * corr[before, :3, 3] + t[:, None] * corr[after, :3, 3]
    out[todo] = rec[todo] @ C
    return out


def smoothed_corrections(
    recorded: npt.ArrayLike,
    adjusted: npt.ArrayLike,
    progress_m: npt.ArrayLike,
    use: npt.ArrayLike,
    *,
    sigma_m: float,
    step_m: float = 0.25,
) -> npt.NDArray[np.float64]:
    """Each frame's correction from its recorded pose to its adjusted one, smoothed along the route.

    A frame's correction is ``D = T_recorded^-1 T_adjusted`` (in its camera frame), written as
    ``(rotation vector, translation)``; the corrections of the frames in ``use`` are averaged
    with a Gaussian of ``sigma_m`` metres of route progress (through a grid of ``step_m``) and
    read at every frame. What a bundle adjustment corrects slowly (a GPS drift, a heading taken
    from motion that misses the car's slip in a turn) stays; a recorded pose's frame-to-frame
    jitter, which a pose on a smooth path (the closed loop's) does not have, is averaged out.

    Args:
        recorded: ``(N, 4, 4)`` recorded poses ``T_world_cam``.
        adjusted: ``(N, 4, 4)`` adjusted poses.
        progress_m: ``(N,)`` route progress of each frame, metres.
        use: ``(N,)`` bool, the frames whose corrections count (say, not the held-out ones).
        sigma_m: Smoothing, metres of progress.
        step_m: Grid spacing, metres.

    Returns:
        ``(N, 6)`` float64 rows ``(rx, ry, rz, tx, ty, tz)``: see :func:`recorded_to_model`.

    Raises:
        ValueError: Shapes differ, or no frame is used.
    """
    from scipy.ndimage import gaussian_filter1d  # noqa: PLC0415 -- lazy: scipy is heavy

    rec = np.asarray(recorded, dtype=np.float64)
    adj = np.asarray(adjusted, dtype=np.float64)
    s = np.asarray(progress_m, dtype=np.float64).reshape(-1)
    mask = np.asarray(use, dtype=bool).reshape(-1)
    if rec.shape != adj.shape or rec.ndim != 3 or rec.shape[1:] != (4, 4) or s.shape != mask.shape:
        msg = (
            f"need (N, 4, 4) poses, (N,) progress and use; got {rec.shape}, {adj.shape}, {s.shape}"
        )
        raise ValueError(msg)
    if s.shape[0] != rec.shape[0] or not mask.any():
        msg = f"need {rec.shape[0]} progress values and use flags, at least one used"
        raise ValueError(msg)
    corr = np.linalg.inv(rec[mask]) @ adj[mask]
    rows = np.concatenate(
        [fr.rotvec_from_quat(fr.quat_from_matrix(corr[:, :3, :3])), corr[:, :3, 3]], 1
    )
    order = np.argsort(s[mask], kind="stable")
    known_s, rows = s[mask][order], rows[order]
    grid = np.arange(s.min(), s.max() + step_m, step_m)
    on_grid = np.stack([np.interp(grid, known_s, rows[:, k]) for k in range(6)], -1)
    smooth = gaussian_filter1d(on_grid, sigma_m / step_m, axis=0, mode="nearest")
    return np.stack([np.interp(s, grid, smooth[:, k]) for k in range(6)], -1)


def recorded_to_model(
    T_world_cam: npt.ArrayLike, correction: npt.ArrayLike
) -> npt.NDArray[np.float64]:
    """Poses with a :func:`smoothed_corrections` row applied: ``T exp(D)``.

    ``T_world_cam`` is ``(4, 4)`` with a ``(6,)`` row or ``(N, 4, 4)`` with ``(N, 6)`` rows.
    """
    T = np.asarray(T_world_cam, dtype=np.float64)
    rows = np.asarray(correction, dtype=np.float64).reshape(-1, 6)
    D = np.tile(np.eye(4), (len(rows), 1, 1))
    D[:, :3, :3] = fr.quat_to_matrix(fr.quat_from_rotvec(rows[:, :3]))
    D[:, :3, 3] = rows[:, 3:]
    out: npt.NDArray[np.float64] = (T.reshape(-1, 4, 4) @ D).reshape(T.shape)
    return out


def _level_rotation(heading: float) -> npt.NDArray[np.float64]:
    """Camera (optical: x right, y down, z forward) -> world (z up) of a level camera."""
    c, s = math.cos(heading), math.sin(heading)
    return np.array([[s, 0.0, c], [-c, 0.0, s], [0.0, -1.0, 0.0]])


def on_route_ground(
    T_world_cam: npt.ArrayLike,
    z: float,
    forward: npt.ArrayLike,
    down: npt.ArrayLike | None,
) -> npt.NDArray[np.float64]:
    """A planar vehicle's camera pose given the recorded camera's height and tilt at its place.

    A closed-loop vehicle moves in the plane: of its camera pose only the position across the
    ground and the heading are its own. Height, pitch and roll are the road's and the car's at
    that place, which the training views know best (a GPS altitude jitters by decimetres, a
    pitch taken from the grade is smoothed; either moves the horizon the policy sees). The
    result keeps ``T_world_cam``'s ``x, y`` and heading (the azimuth of its optical axis) and
    takes world height ``z`` and the tilt of a camera looking along ``forward`` with image-down
    ``down`` (its rotation relative to a level camera of its own heading); with ``down`` None
    only the height is taken.

    Args:
        T_world_cam: ``(4, 4)`` camera (OpenCV optical axes) -> world (z up), metres.
        z: World height of the camera, metres.
        forward: ``(3,)`` optical axis of the camera whose tilt is taken (need not be unit).
        down: ``(3,)`` its image-down axis, or None.

    Returns:
        ``(4, 4)`` float64.
    """
    out = np.array(T_world_cam, dtype=np.float64)
    out[2, 3] = z
    if down is None:
        return out
    f = np.asarray(forward, dtype=np.float64)
    f = f / np.linalg.norm(f)
    d = np.asarray(down, dtype=np.float64)
    d = d - (d @ f) * f
    d = d / np.linalg.norm(d)
    tilted = np.column_stack([np.cross(d, f), d, f])
    tilt = _level_rotation(math.atan2(f[1], f[0])).T @ tilted
    own = math.atan2(out[1, 2], out[0, 2])
    out[:3, :3] = _level_rotation(own) @ tilt
    return out


# --------------------------------------------------------------------------------------------
# Known poses
# --------------------------------------------------------------------------------------------
