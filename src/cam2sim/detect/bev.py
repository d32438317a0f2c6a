"""The LiDAR bird's-eye density of a whole drive: where the scans hit something above the ground.

Every scan of ``WS/dataset/lidar/`` is moved into the world frame with its sensor pose from
``lidar.csv`` and its points are counted in a 2D grid (x east, y north) over the route's extent
plus a margin. Only points in a height band around the sensor count: with the default band
``z_band_m = (-1.6, 1.0)`` and a roof sensor about 1.8 m above the road, that is roughly 0.2 m to
2.8 m above the ground, which keeps kerbs and car bodies and drops the road surface, whose
returns would otherwise swamp the image. The band is relative to each scan's sensor height, so a
drive over hills keeps it near the local ground.

Scans are streamed one by one (memory stays bounded by the grid); a drive with more than
``max_scans`` scans is subsampled evenly. The editor (``cam2sim refine``) draws the density under
the parked-vehicle boxes; :func:`load_or_build_bev` caches it as ``WS/detections/bev.png`` plus
``bev.json``, keyed by the dataset's inputs, so re-opening the editor does not recompute it.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pydantic

from cam2sim.core.errors import SchemaVersionError, WorkspaceError
from cam2sim.core.files import file_fingerprint, write_bytes_atomic
from cam2sim.core.frames.rotation import quat_to_matrix
from cam2sim.core.schema import Artifact
from cam2sim.core.table import read_table
from cam2sim.core.workspace import dataset_paths, hash_inputs
from cam2sim.recording.pointcloud import xyz_from_points

if TYPE_CHECKING:
    from pathlib import Path

    import numpy.typing as npt

    from cam2sim.core.workspace import Workspace

__all__ = [
    "BEV_JSON",
    "BEV_PNG",
    "BevExtent",
    "BevInfo",
    "LidarBev",
    "bev_from_dataset",
    "load_or_build_bev",
]

logger = logging.getLogger(__name__)

BEV_PNG = "bev.png"
BEV_JSON = "bev.json"
_DEFAULT_MAX_CELLS = 16_000_000  # 64 MB of uint32 counts; an 800 x 800 m drive at 0.2 m
_MAX_SIDE_PX = 8192  # browsers draw images up to this size everywhere


@dataclass(frozen=True)
class BevExtent:
    """The world rectangle an image covers, metres (x east, y north)."""

    x_min: float
    y_min: float
    x_max: float
    y_max: float


@dataclass(frozen=True, eq=False)
class LidarBev:
    """Point counts of a whole drive on a north-up grid.

    Attributes:
        counts: ``(H, W) uint32`` points per cell. Row 0 is the northern edge and column 0 the
            western one: ``counts[r, c]`` covers ``x`` in ``[x_min + c * res, x_min + (c+1) * res)``
            and ``y`` in ``[y_max - (r+1) * res, y_max - r * res)``, so the array is an image
            with north up.
        origin: World ``(x_min, y_min)`` of the grid's south-west corner, metres.
        resolution_m: Cell side, metres.
        scans_used: Scans accumulated (after subsampling).
        scans_total: Scans the dataset holds.
    """

    counts: npt.NDArray[np.uint32]
    origin: tuple[float, float]
    resolution_m: float
    scans_used: int
    scans_total: int

    @property
    def extent(self) -> BevExtent:
        """The world rectangle the grid covers."""
        h, w = self.counts.shape
        x0, y0 = self.origin
        return BevExtent(x0, y0, x0 + w * self.resolution_m, y0 + h * self.resolution_m)

    def to_rgba(self) -> npt.NDArray[np.uint8]:
        """Return the ``(H, W, 4) uint8`` RGBA image: log-scaled grey, transparent where empty.

        Counts are scaled by ``log1p`` and normalised at their 99.5th percentile, so a few very
        dense cells (a wall beside a long stop) do not wash out the rest.
        """
        counts = self.counts
        rgba = np.zeros((*counts.shape, 4), dtype=np.uint8)
        hit = counts > 0
        if not hit.any():
            return rgba
        level = np.log1p(counts[hit].astype(np.float64))
        top = max(float(np.percentile(level, 99.5)), 1e-9)
        v = np.clip(level / top, 0.0, 1.0)
        grey = (255.0 * (0.35 + 0.65 * v)).astype(np.uint8)
        rgba[hit, 0] = grey
        rgba[hit, 1] = grey
        rgba[hit, 2] = np.minimum(255, grey.astype(np.int32) + 20).astype(np.uint8)
        rgba[hit, 3] = (255.0 * (0.35 + 0.65 * v)).astype(np.uint8)
        return rgba

    def png_bytes(self) -> bytes:
        """Encode :meth:`to_rgba` as PNG."""
        import cv2  # noqa: PLC0415

        rgba = self.to_rgba()
        ok, buf = cv2.imencode(".png", cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA))
        if not ok:  # pragma: no cover - cv2 encodes any uint8 BGRA image
            msg = "OpenCV could not encode the LiDAR overview as PNG"
            raise RuntimeError(msg)
        return bytes(buf.tobytes())

    def save_png(self, path: Path) -> None:
        """Write :meth:`png_bytes` to ``path`` atomically."""
        write_bytes_atomic(path, self.png_bytes())


class BevInfo(Artifact):
    """``WS/detections/bev.json``: where ``bev.png`` lies in the world, what it was built from."""

    inputs_hash: str = pydantic.Field(description="dataset inputs and parameters it was built from")
    x_min: float
    y_min: float
    x_max: float
    y_max: float
    resolution_m: float = pydantic.Field(gt=0)
    width_px: int = pydantic.Field(ge=1)
    height_px: int = pydantic.Field(ge=1)
    z_band_m: tuple[float, float] = pydantic.Field(description="height band around the sensor")
    scans_used: int = pydantic.Field(ge=0)
    scans_total: int = pydantic.Field(ge=0)

    @property
    def extent(self) -> BevExtent:
        """The world rectangle ``bev.png`` covers."""
        return BevExtent(self.x_min, self.y_min, self.x_max, self.y_max)


def _route_xy(dataset_dir: Path, lidar_xy: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """The driven positions that fix the grid's extent (trajectory, poses, or the scans)."""
    paths = dataset_paths(dataset_dir)
    for table in (paths.trajectory_csv, paths.poses_csv):
        if table.is_file():
            cols = read_table(table)
            xy = np.column_stack([cols["x"], cols["y"]]).astype(np.float64)
            if len(xy):
                return np.concatenate([xy, lidar_xy])
    return lidar_xy


def _grid(
    xy: npt.NDArray[np.float64], *, resolution_m: float, margin_m: float, max_cells: int
) -> tuple[tuple[float, float], float, tuple[int, int]]:
    """South-west origin, (possibly coarsened) resolution and ``(H, W)`` of the grid."""
    lo = np.floor((xy.min(axis=0) - margin_m) / resolution_m) * resolution_m
    hi = xy.max(axis=0) + margin_m
    res = resolution_m
    w, h = (math.ceil(float(v)) for v in (hi - lo) / res)
    if w * h > max_cells or max(w, h) > _MAX_SIDE_PX:
        res = resolution_m * max(math.sqrt(w * h / max_cells), max(w, h) / _MAX_SIDE_PX)
        while True:
            w, h = (math.ceil(float(v)) for v in (hi - lo) / res)
            if w * h <= max_cells and max(w, h) <= _MAX_SIDE_PX:
                break
            res *= 1.02
        logger.info(
            "LiDAR overview: %.0f x %.0f m at %.2f m would be too large; using %.3f m cells",
            *(hi - lo),
            resolution_m,
            res,
        )
    return (float(lo[0]), float(lo[1])), res, (max(h, 1), max(w, 1))


def bev_from_dataset(
    dataset_dir: Path,
    *,
    resolution_m: float = 0.2,
    margin_m: float = 20.0,
    z_band_m: tuple[float, float] = (-1.6, 1.0),
    max_range_m: float = 60.0,
    max_scans: int = 3000,
    max_cells: int = _DEFAULT_MAX_CELLS,
) -> LidarBev | None:
    """Accumulate every LiDAR scan of a dataset into a world-frame density grid.

    Args:
        dataset_dir: ``WS/dataset`` (or a dataset folder being built).
        resolution_m: Cell side in metres; coarsened (and logged) when the grid over the route
            would exceed ``max_cells`` cells or 8192 cells on a side.
        margin_m: Margin around the route's bounding box, metres.
        z_band_m: Height band ``(low, high)`` relative to each scan's sensor height, metres;
            points outside it (the road surface, tree tops) are not counted.
        max_range_m: Horizontal distance from the sensor beyond which points are dropped (sparse
            and imprecise), metres.
        max_scans: Scans used at most; more are subsampled evenly over the drive.
        max_cells: Cells of the grid at most.

    Returns:
        The density, or None when the dataset has no LiDAR scans.

    Raises:
        ValueError: A parameter is out of range.
        WorkspaceError: ``lidar.csv`` is malformed.
    """
    if not (resolution_m > 0 and margin_m >= 0 and max_scans >= 1 and max_cells >= 1):
        msg = (
            f"resolution_m={resolution_m!r}, margin_m={margin_m!r}, max_scans={max_scans!r}, "
            f"max_cells={max_cells!r}; give a positive resolution, margin >= 0 and limits >= 1"
        )
        raise ValueError(msg)
    if not z_band_m[0] < z_band_m[1]:
        msg = f"z_band_m={z_band_m!r}; give (low, high) with low < high, metres"
        raise ValueError(msg)
    paths = dataset_paths(dataset_dir)
    if not paths.lidar_csv.is_file():
        return None
    scans = read_table(paths.lidar_csv)
    total = len(scans["scan"])
    if total == 0:
        return None
    pick = np.unique(np.linspace(0, total - 1, min(total, max_scans)).round().astype(np.int64))
    t_world = np.column_stack([scans["x"], scans["y"], scans["z"]]).astype(np.float64)
    quats = np.column_stack([scans[k] for k in ("qx", "qy", "qz", "qw")]).astype(np.float64)
    rotations = quat_to_matrix(quats)
    origin, res, (h, w) = _grid(
        _route_xy(dataset_dir, t_world[:, :2]),
        resolution_m=resolution_m,
        margin_m=margin_m,
        max_cells=max_cells,
    )
    flat = np.zeros(h * w, dtype=np.uint32)
    used = 0
    for i in pick:
        scan_file = paths.lidar_file(int(scans["scan"][i]))
        if not scan_file.is_file():
            continue
        xyz = xyz_from_points(np.load(scan_file))
        world = xyz @ rotations[i].T + t_world[i]
        rel = world - t_world[i]
        keep = (
            np.isfinite(world).all(axis=1)
            & (rel[:, 2] >= z_band_m[0])
            & (rel[:, 2] <= z_band_m[1])
            & (rel[:, 0] ** 2 + rel[:, 1] ** 2 <= max_range_m**2)
        )
        col = np.floor((world[keep, 0] - origin[0]) / res).astype(np.int64)
        row = h - 1 - np.floor((world[keep, 1] - origin[1]) / res).astype(np.int64)
        inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
        np.add.at(flat, row[inside] * w + col[inside], np.uint32(1))
        used += 1
    logger.info("LiDAR overview: %d of %d scans, %d x %d cells of %.2f m", used, total, w, h, res)
    return LidarBev(flat.reshape(h, w), origin, res, used, total)


def _bev_key(ws: Workspace, params: dict[str, object]) -> str:
    paths = dataset_paths(ws.dataset_dir)
    record = ws.stage_record("extract")
    return hash_inputs(
        {
            "extract": record.inputs_hash if record is not None else None,
            "lidar_csv": file_fingerprint(paths.lidar_csv),
            "params": params,
        }
    )


def load_or_build_bev(
    ws: Workspace,
    *,
    resolution_m: float = 0.2,
    z_band_m: tuple[float, float] = (-1.6, 1.0),
    max_scans: int = 3000,
) -> BevInfo | None:
    """Return the cached LiDAR overview of a workspace, building it when missing or stale.

    The cache is ``WS/detections/bev.png`` and ``bev.json``; it is keyed by the extract stage's
    inputs hash, ``lidar.csv``'s fingerprint and the parameters, so a new dataset or other
    parameters rebuild it.

    Returns:
        The record of ``bev.png`` (its world extent), or None when the dataset has no LiDAR.
    """
    paths = dataset_paths(ws.dataset_dir)
    if not paths.lidar_csv.is_file():
        return None
    params: dict[str, object] = {
        "resolution_m": resolution_m,
        "z_band_m": list(z_band_m),
        "max_scans": max_scans,
    }
    key = _bev_key(ws, params)
    json_path = ws.detections_dir / BEV_JSON
    png_path = ws.detections_dir / BEV_PNG
    if json_path.is_file() and png_path.is_file():
        try:
            cached = BevInfo.load(json_path)
        except (WorkspaceError, SchemaVersionError) as err:
            logger.info("LiDAR overview cache unreadable (%s); rebuilding it", err)
        else:
            if cached.inputs_hash == key:
                return cached
    bev = bev_from_dataset(
        ws.dataset_dir, resolution_m=resolution_m, z_band_m=z_band_m, max_scans=max_scans
    )
    if bev is None:
        return None
    ext = bev.extent
    info = BevInfo(
        inputs_hash=key,
        x_min=ext.x_min,
        y_min=ext.y_min,
        x_max=ext.x_max,
        y_max=ext.y_max,
        resolution_m=bev.resolution_m,
        width_px=int(bev.counts.shape[1]),
        height_px=int(bev.counts.shape[0]),
        z_band_m=z_band_m,
        scans_used=bev.scans_used,
        scans_total=bev.scans_total,
    )
    bev.save_png(png_path)
    info.save(json_path)
    return info
