"""Pose corrections: the exponential map, and a render that recovers a misplaced camera."""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from cam2sim.splat.pose_refine import correction_sizes, remove_common_motion, se3_exp


def test_zero_is_the_identity_and_its_gradient_is_exact() -> None:
    delta = torch.zeros(2, 6, dtype=torch.float64, requires_grad=True)
    out = se3_exp(delta)
    assert torch.equal(out.detach(), torch.eye(4, dtype=torch.float64).repeat(2, 1, 1))
    # d(R x)/d(omega) at zero is -[x]_x: the rotation's first-order term.
    x = torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)
    (out[0, :3, :3] @ x)[0].backward()
    assert delta.grad is not None
    assert torch.allclose(delta.grad[0, :3], torch.tensor([0.0, 3.0, -2.0], dtype=torch.float64))


def test_rotations_match_scipy_and_translations_pass_through() -> None:
    rng = np.random.default_rng(0)
    omega = rng.normal(size=(5, 3)) * np.array([[0.5], [1e-3], [1e-6], [1.0], [2.0]])
    t = rng.normal(size=(5, 3))
    out = se3_exp(torch.tensor(np.hstack([omega, t]))).numpy()
    assert np.allclose(out[:, :3, :3], Rotation.from_rotvec(omega).as_matrix(), atol=1e-12)
    assert np.allclose(out[:, :3, 3], t)
    assert np.allclose(out[:, 3], [0, 0, 0, 1])


def test_correction_sizes_in_scene_units_and_degrees() -> None:
    delta = torch.tensor([[0.0, 0.0, math.radians(2.0), 0.3, 0.4, 0.0], [0.0] * 6])
    mean_t, max_t, mean_r, max_r = correction_sizes(delta)
    assert math.isclose(mean_t, 0.25, rel_tol=1e-6)
    assert math.isclose(max_t, 0.5, rel_tol=1e-6)
    assert math.isclose(max_r, 2.0, rel_tol=1e-5)
    assert math.isclose(mean_r, 1.0, rel_tol=1e-5)


def test_held_out_frames_take_their_neighbours_corrections() -> None:
    from cam2sim.splat.pose_refine import corrected_pose, interpolated_correction

    views = [(0, [0.0] * 6), (8, [0.0, 0.0, 0.08, 0.8, 0.0, 0.0]), (16, [0.0] * 6)]
    mid = interpolated_correction(4, views)
    assert mid is not None
    assert np.allclose(mid, [0.0, 0.0, 0.04, 0.4, 0.0, 0.0])
    assert np.allclose(interpolated_correction(20, views), 0.0)  # the last view's beyond the end
    assert interpolated_correction(3, []) is None
    T = np.eye(4)
    T[:3, 3] = [5.0, 1.0, 2.0]
    assert corrected_pose(T, None) is T
    moved = corrected_pose(T, np.array([0.0, 0.0, 0.0, 0.4, 0.0, 0.0]))
    # World -> camera gained +0.4 along camera x, so the camera centre moved by -0.4 along it.
    assert np.allclose(moved[:3, 3], [4.6, 1.0, 2.0])
    assert np.allclose(moved[:3, :3], np.eye(3))


def _bend(n: int = 9) -> torch.Tensor:
    """World -> camera matrices of cameras along a 90-degree bend, far from the origin."""
    angles = np.linspace(0.0, np.pi / 2, n)
    mats = []
    for a in angles:
        centre = np.array([100.0 + 3.0 * np.cos(a), 50.0 + 3.0 * np.sin(a), 0.2 * a])
        cam_to_world = Rotation.from_euler("z", a + np.pi / 2).as_matrix()
        v = np.eye(4)
        v[:3, :3] = cam_to_world.T
        v[:3, 3] = -cam_to_world.T @ centre
        mats.append(v)
    return torch.tensor(np.stack(mats))


def _scene_motion(viewmats: torch.Tensor, turn: np.ndarray, shift: np.ndarray) -> torch.Tensor:
    """The exact corrections ``log(V G^-1 V^-1)`` of moving the scene by ``G`` (first order)."""
    g = np.eye(4)
    g[:3, :3] = Rotation.from_rotvec(turn).as_matrix()
    g[:3, 3] = shift
    rows = []
    for v in viewmats.numpy():
        e = v @ np.linalg.inv(g) @ np.linalg.inv(v)
        rows.append(np.concatenate([Rotation.from_matrix(e[:3, :3]).as_rotvec(), e[:3, 3]]))
    return torch.tensor(np.stack(rows))


def test_a_motion_of_the_whole_scene_is_left_to_the_model() -> None:
    views = _bend()
    moved = _scene_motion(views, np.array([0.0, 0.002, 0.004]), np.array([0.05, -0.03, 0.01]))
    delta = moved.clone()
    remove_common_motion(delta, views)
    # Nothing an image could tell is left (to first order in the 4 mrad turn).
    assert delta.abs().max() < 1e-3 * moved.abs().max()
    again = delta.clone()
    remove_common_motion(again, views)
    assert torch.allclose(again, delta, atol=1e-12)  # a second pass takes nothing more


def test_each_views_own_error_and_a_mounting_error_stay() -> None:
    views = _bend()
    rng = np.random.default_rng(1)
    own = torch.tensor(rng.normal(scale=1e-3, size=(9, 6)))
    remove_common_motion(own, views)  # what the scene's motion cannot explain
    kept = own.clone()
    remove_common_motion(kept, views)
    assert torch.allclose(kept, own, atol=1e-12)
    # The camera pitched 0.3 degrees on its mount, the same in every view: no motion of the
    # scene turns every camera about its own centre, so most of it stays a correction.
    mount = torch.zeros(9, 6, dtype=torch.float64)
    mount[:, 0] = np.radians(0.3)
    left = mount.clone()
    remove_common_motion(left, views)
    assert float(torch.linalg.norm(left)) > 0.5 * float(torch.linalg.norm(mount))
