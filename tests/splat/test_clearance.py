"""Clearing the drive's own path of Gaussians."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch")

import itertools

import torch
from gaussian_fixtures import model_and_adam

from cam2sim.splat.clearance import clear_path, path_distance

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _dense_distance(points: np.ndarray, path: np.ndarray) -> np.ndarray:
    """Brute force: the distance to 2,000 samples along every segment."""
    t = np.linspace(0.0, 1.0, 2000)[:, None]
    samples = np.concatenate([a + t * (b - a) for a, b in itertools.pairwise(path)])
    return np.sqrt(((points[:, None, :] - samples[None]) ** 2).sum(-1)).min(axis=1)


def test_path_distance_is_the_distance_to_the_nearest_segment() -> None:
    rng = np.random.default_rng(0)
    # A bent path with a repeated point (a stop), and points around it.
    path = np.array([[0, 0, 1.5], [0, 4, 1.5], [0, 4, 1.5], [2, 7, 1.4], [6, 8, 1.6]], float)
    points = rng.uniform([-3, -2, -1], [8, 10, 4], size=(500, 3))
    got = path_distance(torch.from_numpy(points), torch.from_numpy(path)).numpy()
    np.testing.assert_allclose(got, _dense_distance(points, path), atol=2e-3)
    one = path_distance(torch.from_numpy(points), torch.from_numpy(path[:1])).numpy()
    np.testing.assert_allclose(one, np.linalg.norm(points - path[0], axis=1), rtol=1e-12)


def test_gaussians_on_the_path_are_made_transparent_and_the_rest_kept() -> None:
    means = torch.tensor(
        [
            [0.1, 1.0, 1.5],  # on the path
            [0.0, 3.0, 1.2],  # 0.3 below it
            [0.0, 3.0, 0.0],  # the road, 1.5 below
            [2.0, 2.0, 1.5],  # beside it
            [0.0, -0.5, 1.5],  # 0.5 behind its start
        ]
    )
    model, opts = model_and_adam(means=means)
    with torch.no_grad():
        model.params["opacities"][:] = 2.0
    path = torch.tensor([[0.0, 0.0, 1.5], [0.0, 5.0, 1.5]])
    assert clear_path(model, opts, path, radius=0.75) == 3
    opacity = torch.sigmoid(model.params["opacities"].detach())
    assert float(opacity[[0, 1, 4]].max()) < 1e-12
    assert float(opacity[[2, 3]].min()) > 0.8
    moments = opts["means"].state[model.params["means"]]["exp_avg"]
    assert moments[[0, 1, 4]].abs().sum() == 0
    assert moments[[2, 3]].abs().sum() > 0
    assert clear_path(model, opts, path, radius=0.1) == 1  # the one on the line, again
