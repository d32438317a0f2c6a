"""Camera pose refinement while training: a small rigid correction per training view.

Recorded poses (odometry, GNSS) and images-only SfM poses both carry error: a few centimetres or
a tenth of a degree on a bend is a pixel at the far end of a street, and the splat then blurs
what it cannot place. Each training view gets a learned correction ``delta = (omega, t)`` (an
axis-angle rotation and a translation, in the camera frame, scene units) applied on the left of
its world-to-camera matrix, ``V' = exp(delta) V`` (as gsplat's ``simple_trainer`` pose
optimisation does). The corrections start at zero, learn with Adam and a small weight decay,
and are reported (:func:`correction_sizes`) and written back into the chunk's view records.

A held-out view (scored, never trained on) lies between training views along the drive, and its
recorded pose carries the same slowly varying error as theirs: the evaluation corrects it with
the neighbours' corrections interpolated by frame index (:func:`interpolated_correction`), as
it takes their colour transforms; it never fits the held-out image itself.

The corrections and the model can move together (shift every camera and every Gaussian alike and
the images stay the same): left free, the chunk's model drifts away from the recorded poses, and
the closed loop, which renders at uncorrected poses, sees it shifted. After each step the
corrections lose the part one rigid motion of the whole scene would explain
(:func:`remove_common_motion`): the model stays where the recorded poses put it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy as np
    import numpy.typing as npt
    import torch

__all__ = [
    "corrected_pose",
    "correction_sizes",
    "interpolated_correction",
    "remove_common_motion",
    "se3_exp",
]


def _skew(v: torch.Tensor) -> torch.Tensor:
    """``[N, 3, 3]`` cross-product matrices of ``[N, 3]`` vectors."""
    import torch  # noqa: PLC0415

    zero = torch.zeros_like(v[:, 0])
    x, y, z = v.unbind(dim=1)
    return torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=1).view(-1, 3, 3)


def se3_exp(delta: torch.Tensor) -> torch.Tensor:
    """``[N, 4, 4]`` rigid transforms of ``[N, 6]`` corrections ``(omega, t)``.

    The rotation is Rodrigues' formula (with its Taylor series near zero, so the gradient at the
    start, ``delta = 0``, is exact); the translation is ``t`` as is.
    """
    import torch  # noqa: PLC0415

    omega, t = delta[:, :3], delta[:, 3:]
    theta2 = (omega * omega).sum(dim=1)
    theta = theta2.clamp(min=1e-12).sqrt()
    small = theta2 < 1e-8
    a = torch.where(small, 1.0 - theta2 / 6.0, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24.0, (1.0 - torch.cos(theta)) / theta2.clamp(min=1e-12))
    w = _skew(omega)
    eye = torch.eye(3, dtype=delta.dtype, device=delta.device).expand_as(w)
    rot = eye + a[:, None, None] * w + b[:, None, None] * (w @ w)
    out = torch.eye(4, dtype=delta.dtype, device=delta.device).repeat(len(delta), 1, 1)
    out[:, :3, :3] = rot
    out[:, :3, 3] = t
    return out


def correction_sizes(delta: npt.ArrayLike) -> tuple[float, float, float, float]:
    """Mean and largest translation (scene units) and rotation (degrees) of the corrections.

    ``delta``: ``[N, 6]`` corrections ``(omega, t)``, as an array or a CPU tensor.
    """
    import numpy as np  # noqa: PLC0415

    rows = np.asarray(delta, dtype=np.float64).reshape(-1, 6)
    if len(rows) == 0:
        return 0.0, 0.0, 0.0, 0.0
    rot = np.degrees(np.linalg.norm(rows[:, :3], axis=1))
    shift = np.linalg.norm(rows[:, 3:], axis=1)
    return float(shift.mean()), float(shift.max()), float(rot.mean()), float(rot.max())


def interpolated_correction(
    index: int, views: Sequence[tuple[int, Sequence[float]]]
) -> npt.NDArray[np.float64] | None:
    """The correction of frame ``index`` from the training views' ``(index, correction)``.

    Linear in the frame index between the nearest training views before and after it (the
    nearest one's beyond the ends); None when no view carries a correction.
    """
    import numpy as np  # noqa: PLC0415

    if not views:
        return None
    order = sorted(views, key=lambda v: v[0])
    idx = np.array([v[0] for v in order], dtype=np.float64)
    deltas = np.array([list(v[1]) for v in order], dtype=np.float64)
    return np.array([np.interp(float(index), idx, deltas[:, k]) for k in range(6)])


def corrected_pose(
    T_world_cam: npt.NDArray[np.float64], delta: npt.NDArray[np.float64] | None
) -> npt.NDArray[np.float64]:
    """Camera poses with their corrections applied, ``T exp(delta)^-1``; unchanged for None.

    ``T_world_cam`` is one ``(4, 4)`` pose with a ``(6,)`` correction, or ``(N, 4, 4)`` poses
    with ``(N, 6)`` corrections (the correction acts on world -> camera, hence the inverse).
    """
    import numpy as np  # noqa: PLC0415
    import torch  # noqa: PLC0415

    if delta is None:
        return T_world_cam
    d = torch.as_tensor(np.asarray(delta, dtype=np.float64)).reshape(-1, 6)
    fix = se3_exp(d).numpy().reshape(np.shape(T_world_cam))
    out: npt.NDArray[np.float64] = np.asarray(T_world_cam, dtype=np.float64) @ np.linalg.inv(fix)
    return out


def remove_common_motion(delta: torch.Tensor, viewmats: torch.Tensor) -> None:
    """Remove in place the part of the corrections that moving the whole scene would explain.

    Moving every camera by one rigid motion of the scene (a turn ``w`` about the cameras'
    centroid and a shift ``g``, world frame) changes no image: to first order it is, on view
    ``i`` (world -> camera rotation ``R``, centre ``d`` from the centroid), the correction
    ``omega = -R w``, ``t = -R (w x d + g)``. The ``(w, g)`` that explains the corrections best
    (least squares in the world frame) is subtracted; what is left is each view's own error,
    and what all views share in the camera frame (a mounting error) where the centres' spread
    tells it from a turn of the scene.

    Args:
        delta: ``[N, 6]`` corrections ``(omega, t)`` (a parameter: changed under no_grad).
        viewmats: ``[N, 4, 4]`` the views' world -> camera matrices as recorded.
    """
    import torch  # noqa: PLC0415

    with torch.no_grad():
        rot = viewmats[:, :3, :3]
        centres = -torch.einsum("nji,nj->ni", rot, viewmats[:, :3, 3])
        d = centres - centres.mean(dim=0)
        parts = delta.view(-1, 2, 3)
        world = torch.einsum("nji,ncj->nci", rot, parts)  # R^T x per view
        a, b = world[:, 0], world[:, 1]  # the turn and shift parts, world frame
        cross = _skew(d)  # [d]x: [d]x w = d x w
        # a = -w, b = [d]x w - g; with the centres about their mean, g = -mean(b) and
        # (N I + sum [d]x^T [d]x) w = -sum a + sum [d]x^T b.
        n = float(len(d))
        lhs = n * torch.eye(3, dtype=delta.dtype, device=delta.device) + torch.einsum(
            "nji,njk->ik", cross, cross
        )
        rhs = -a.sum(dim=0) + torch.einsum("nji,nj->i", cross, b)
        w = torch.linalg.solve(lhs, rhs)
        g = -b.mean(dim=0)
        shared = torch.stack([-w.expand_as(a), torch.einsum("nij,j->ni", cross, w) - g], dim=1)
        parts.sub_(torch.einsum("nij,ncj->nci", rot, shared))
