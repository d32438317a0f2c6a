"""Grid cells: the same cells, numbered the same way, as ``np.unique(axis=0)``."""

from __future__ import annotations

import numpy as np
import pytest

from cam2sim.core.grid import grid_cells


def _unique_rows(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    return inverse.ravel(), counts


@pytest.mark.parametrize("dims", [2, 3])
def test_the_cells_are_those_of_unique_rows(dims: int) -> None:
    rng = np.random.default_rng(dims)
    # negative and positive coordinates, spans unequal per axis, many repeats
    keys = np.floor(rng.normal(0.0, [40.0, 5.0, 300.0][:dims], (20_000, dims))).astype(np.int64)
    inverse, counts = grid_cells(keys)
    want_inverse, want_counts = _unique_rows(keys)
    np.testing.assert_array_equal(inverse, want_inverse)
    np.testing.assert_array_equal(counts, want_counts)


def test_a_grid_too_large_to_pack_gives_the_same_cells() -> None:
    keys = np.array([[2**40, 0, -(2**40)], [0, 2**40, 5], [2**40, 0, -(2**40)], [-5, 1, 1]])
    inverse, counts = grid_cells(keys)
    want_inverse, want_counts = _unique_rows(keys)
    np.testing.assert_array_equal(inverse, want_inverse)
    np.testing.assert_array_equal(counts, want_counts)


def test_no_keys_no_cells_and_a_flat_array_is_refused() -> None:
    inverse, counts = grid_cells(np.zeros((0, 3), np.int64))
    assert inverse.shape == (0,)
    assert counts.shape == (0,)
    with pytest.raises(ValueError, match=r"\(N, D\)"):
        grid_cells(np.arange(5))
