"""Geographic projections: WGS84 / any pyproj CRS <-> the workspace world frame."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from cam2sim.core.errors import ConfigError
from cam2sim.core.frames._common import (
    _CRS_EXAMPLE,
    _HEADING_HALF_STEP_M,
    _ORIGIN_DECIMALS,
    _WGS84,
    _as_float,
    _as_points,
    _as_vectors,
)
from cam2sim.core.frames.rotation import quat_from_yaw, quat_multiply, quat_normalize

if TYPE_CHECKING:
    import numpy.typing as npt
    import pyproj

__all__ = [
    "GridFrame",
    "Wgs84Points",
    "WorldFrame",
    "utm_crs_for",
]

# --------------------------------------------------------------------------------------------
# Projections
# --------------------------------------------------------------------------------------------


def _crs(crs: str) -> pyproj.CRS:
    """Parse a CRS string, translating pyproj errors into ConfigError."""
    from pyproj.exceptions import CRSError  # noqa: PLC0415 -- lazy: pyproj takes ~65 ms to import

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
    import pyproj  # noqa: PLC0415 -- lazy: pyproj takes ~65 ms to import

    return pyproj.CRS.from_user_input(crs)


@functools.lru_cache(maxsize=64)
def _cached_transformer(first: str, second: str) -> pyproj.Transformer:
    import pyproj  # noqa: PLC0415 -- lazy: pyproj takes ~65 ms to import

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


def wgs84_from_ecef(xyz: npt.ArrayLike) -> Wgs84Points:
    """Geodetic coordinates of Earth-centred, Earth-fixed points (EPSG:4978, metres).

    Raises:
        ValueError: ``xyz`` is not ``(N, 3)`` finite metres near the Earth's surface.
    """
    pts = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    radius = np.linalg.norm(pts, axis=1)
    if not np.all(np.isfinite(radius)) or np.any(np.abs(radius - 6.371e6) > 1e5):
        msg = "ECEF positions must be metres from the Earth's centre (about 6,371 km)"
        raise ValueError(msg)
    lon, lat, alt = _transform("EPSG:4978", "EPSG:4979", pts[:, 0], pts[:, 1], pts[:, 2])
    return Wgs84Points(lat_deg=lat, lon_deg=lon, alt_m=alt)


def enu_from_ecef_rotation(
    lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike
) -> npt.NDArray[np.float64]:
    """``(..., 3, 3)`` rotations taking ECEF vectors into the local east-north-up frame."""
    lat, lon = np.radians(np.asarray(lat_deg, float)), np.radians(np.asarray(lon_deg, float))
    sl, cl, sp, cp = np.sin(lon), np.cos(lon), np.sin(lat), np.cos(lat)
    zero = np.zeros_like(sl)
    rows = ((-sl, cl, zero), (-sp * cl, -sp * sl, cp), (cp * cl, cp * sl, sp))
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


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
class GridFrame:
    """A CRS's own grid, shifted so that ``origin`` (in the CRS) is ``(0, 0)``.

    The frame a ground-truth world is described in (x along the grid's easting, y along its
    northing, z up): unlike :class:`WorldFrame` it keeps the grid's scale and convergence, as
    UTM odometry does.

    Attributes:
        crs: pyproj CRS string with metre axes, e.g. ``"EPSG:32632"``.
        origin: ``(x, y)`` of the frame's origin in ``crs``.
    """

    crs: str
    origin: tuple[float, float]

    @classmethod
    def utm_at(cls, lat_deg: float, lon_deg: float) -> GridFrame:
        """The UTM zone's grid of a point, with the origin at that point rounded to 1 m."""
        crs = utm_crs_for(lat_deg, lon_deg)
        x, y = _transform(_WGS84, crs, np.array([lon_deg]), np.array([lat_deg]))
        return cls(crs, (float(np.round(x[0])), float(np.round(y[0]))))

    def from_wgs84(
        self, lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike, alt_m: npt.ArrayLike = 0.0
    ) -> npt.NDArray[np.float64]:
        """Project WGS84 points into the frame: ``(N, 3)`` metres (z is ``alt_m``)."""
        lat, lon, alt = np.broadcast_arrays(
            np.atleast_1d(_as_float(lat_deg, "lat_deg")),
            np.atleast_1d(_as_float(lon_deg, "lon_deg")),
            np.atleast_1d(_as_float(alt_m, "alt_m")),
        )
        x, y = _transform(_WGS84, self.crs, lon, lat)
        return np.stack([x - self.origin[0], y - self.origin[1], alt], axis=-1)

    def to_wgs84(self, xy: npt.ArrayLike) -> Wgs84Points:
        """Convert ``(N, 2)`` (or ``(N, 3)``) frame points to WGS84."""
        pts = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        lon, lat = _transform(
            self.crs, _WGS84, pts[:, 0] + self.origin[0], pts[:, 1] + self.origin[1]
        )
        alt = pts[:, 2] if pts.shape[1] > 2 else np.zeros(len(pts))
        return Wgs84Points(lat_deg=lat, lon_deg=lon, alt_m=alt)


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
