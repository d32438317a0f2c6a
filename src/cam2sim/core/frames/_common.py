"""Constants and input checks shared by the frames modules."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import numpy.typing as npt

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
