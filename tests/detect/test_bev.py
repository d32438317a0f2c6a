"""The LiDAR bird's-eye density: world-frame accumulation, height band, PNG and cache."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import cv2
import numpy as np
import pytest
from editor_fixtures import ROUTE_Y, SCAN_X, VEHICLES, make_workspace, write_lidar

from cam2sim.core.files import file_fingerprint
from cam2sim.detect import bev as bev_module
from cam2sim.detect.bev import BevInfo, bev_from_dataset, load_or_build_bev


def _reference(world: np.ndarray, bev: bev_module.LidarBev) -> np.ndarray:
    """np.histogram2d of the in-band points over the same grid, flipped to north-up."""
    h, w = bev.counts.shape
    x0, y0 = bev.origin
    res = bev.resolution_m
    hist, _, _ = np.histogram2d(
        world[:, 0],
        world[:, 1],
        bins=[w, h],
        range=[[x0, x0 + w * res], [y0, y0 + h * res]],
    )
    out: np.ndarray = np.flipud(hist.T).astype(np.int64)
    return out


def test_bev_counts_match_a_histogram_of_the_world_points_in_the_height_band(
    tmp_path: Path,
) -> None:
    ws = make_workspace(tmp_path / "ws", lidar=False, road_map=False, vehicles=None)
    truth = write_lidar(ws)
    bev = bev_from_dataset(ws.dataset_dir, resolution_m=0.3)  # no cell edge on a car side
    assert bev is not None
    assert (bev.scans_used, bev.scans_total) == (len(SCAN_X), len(SCAN_X))
    world = np.concatenate(truth.world)
    in_band = world[:, 2] > 0.1  # car sides; the road (z = 0) is 1.8 m below the sensor
    np.testing.assert_array_equal(bev.counts.astype(np.int64), _reference(world[in_band], bev))
    assert int(bev.counts.sum()) == int(in_band.sum())
    ext = bev.extent
    assert ext.x_min <= -20.0
    assert ext.x_max >= 100.0
    assert ext.y_min <= ROUTE_Y - 20.0
    assert ext.y_max >= ROUTE_Y + 20.0


def test_bev_puts_the_density_on_the_parked_cars(tmp_path: Path) -> None:
    ws = make_workspace(tmp_path / "ws", road_map=False)
    bev = bev_from_dataset(ws.dataset_dir)
    assert bev is not None
    x0, y0 = bev.origin
    h = bev.counts.shape[0]

    def cell(x: float, y: float) -> tuple[int, int]:
        return h - 1 - int((y - y0) / bev.resolution_m), int((x - x0) / bev.resolution_m)

    for v in VEHICLES:  # the side of each car facing +y
        r, c = cell(v.position[0], v.position[1] + 0.9)
        assert bev.counts[r - 1 : r + 2, c - 8 : c + 8].sum() > 0, v.id
    r, c = cell(40.0, ROUTE_Y)  # the road under the car: no counts (height band)
    assert bev.counts[r - 3 : r + 4, c - 20 : c + 20].sum() == 0


def test_bev_subsamples_scans_and_coarsens_a_too_large_grid(tmp_path: Path) -> None:
    ws = make_workspace(tmp_path / "ws", road_map=False)
    bev = bev_from_dataset(ws.dataset_dir, max_scans=3, max_cells=10_000)
    assert bev is not None
    assert (bev.scans_used, bev.scans_total) == (3, len(SCAN_X))
    assert bev.counts.size <= 10_000
    assert bev.resolution_m > 0.2


def test_bev_png_is_grey_and_transparent_where_nothing_was_seen(tmp_path: Path) -> None:
    ws = make_workspace(tmp_path / "ws", road_map=False)
    bev = bev_from_dataset(ws.dataset_dir)
    assert bev is not None
    path = tmp_path / "bev.png"
    bev.save_png(path)
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert image is not None
    assert image.shape == (*bev.counts.shape, 4)
    alpha = image[:, :, 3]
    np.testing.assert_array_equal(alpha > 0, bev.counts > 0)
    assert image[bev.counts > 0, :3].min() >= 80


def test_bev_is_none_without_lidar(tmp_path: Path) -> None:
    ws = make_workspace(tmp_path / "ws", lidar=False, road_map=False)
    assert bev_from_dataset(ws.dataset_dir) is None
    assert load_or_build_bev(ws) is None
    assert not (ws.detections_dir / "bev.png").exists()


def test_bev_cache_is_reused_until_the_dataset_changes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ws = make_workspace(tmp_path / "ws", road_map=False)
    info = load_or_build_bev(ws)
    assert info is not None
    assert BevInfo.load(ws.detections_dir / "bev.json") == info
    png = ws.detections_dir / "bev.png"
    assert png.is_file()
    before = file_fingerprint(png)

    def fail(*_: object, **__: object) -> None:
        pytest.fail("the cached overview should have been reused")

    monkeypatch.setattr(bev_module, "bev_from_dataset", fail)
    assert load_or_build_bev(ws) == info
    monkeypatch.undo()
    ws.record_stage(
        "extract", state="done", started=dt.datetime.now(dt.UTC), inputs_hash="sha256:dataset-2"
    )
    rebuilt = load_or_build_bev(ws, resolution_m=0.5)
    assert rebuilt is not None
    assert rebuilt.inputs_hash != info.inputs_hash
    assert rebuilt.resolution_m == 0.5
    assert file_fingerprint(png) != before


def test_bev_rejects_an_empty_height_band(tmp_path: Path) -> None:
    ws = make_workspace(tmp_path / "ws", road_map=False)
    with pytest.raises(ValueError, match="low < high"):
        bev_from_dataset(ws.dataset_dir, z_band_m=(1.0, -1.0))
