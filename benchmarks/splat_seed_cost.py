"""What a street's starting Gaussians cost gsplat's rasterizer: tile/Gaussian pairs a view.

A training step's device time grows with the tile/Gaussian pairs of its view (gsplat gives each
tile one thread block that walks the tile's whole depth-sorted list: `splat_raster_cost.py`,
docs/benchmarks.md "The route in 4.7 minutes"). This counts them on the CPU, before any
training, for the GPU demo preset's starting Gaussians: each chunk of each workspace is seeded
as training seeds it (:class:`~cam2sim.splat.chunk_trainer.ChunkTrainer`), its street and sky
Gaussians are projected into ``--views`` of its training views
(:func:`~cam2sim.splat.raster_torch.project_gaussians`, gsplat's projection and radii) and
each visible Gaussian's box is counted in ``--tile`` pixel tiles, as gsplat's tile intersection
does. The pairs are split into sky and street Gaussians by depth. Trained models have more
Gaussians (densification), so this compares streets, not absolute costs.

Each workspace needs the GPU preset's prepared scene (``python benchmarks/splat_seeding.py WS``
makes it). Run from the repository root::

    PYTHONPATH=src python benchmarks/splat_seed_cost.py WS [WS ...] --views 24 --out cost.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np

from cam2sim.core.files import write_text_atomic
from cam2sim.core.workspace import Workspace
from cam2sim.splat.chunk_trainer import ChunkTrainer
from cam2sim.splat.raster import GSPLAT_TILE
from cam2sim.splat.scene import SceneRecord, load_points
from cam2sim.stages.splat import SplatStageOptions

DEPTH_BINS_M = (0.0, 5.0, 10.0, 25.0, 50.0, float("inf"))


def tile_pairs(means2d: Any, radii: Any, width: int, height: int, tile: int) -> Any:
    """Tiles each Gaussian's box covers (0 for culled ones), as gsplat's intersection counts."""
    import torch  # noqa: PLC0415

    from cam2sim.splat.raster_torch import tile_boxes  # noqa: PLC0415

    tiles_x, tiles_y = -(-width // tile), -(-height // tile)
    x0, x1, y0, y1 = tile_boxes(means2d, radii, tiles_x, tiles_y, tile)
    visible = (radii > 0).all(dim=-1)
    return torch.where(visible, (x1 - x0).clamp(min=0) * (y1 - y0).clamp(min=0), 0)


def chunk_cost(trainer: ChunkTrainer, n_views: int, tile: int) -> dict[str, Any]:
    """Mean pairs a view of one seeded chunk, by part and depth."""
    import torch  # noqa: PLC0415

    from cam2sim.splat.raster_torch import project_gaussians  # noqa: PLC0415

    views = trainer.levels[0][0]
    n = views.viewmats.shape[0]
    picks = np.linspace(0, n - 1, min(n_views, n)).round().astype(int)
    parts = {"street": trainer.street, "sky": trainer.sky}
    by_depth = np.zeros(len(DEPTH_BINS_M) - 1)
    sums = {"street": 0.0, "sky": 0.0, "street_visible": 0.0, "radius_px_p90": 0.0}
    with torch.no_grad():
        for i in picks:
            for name, part in parts.items():
                p = part.params
                proj = project_gaussians(
                    p["means"], p["quats"], torch.exp(p["scales"]), torch.sigmoid(p["opacities"]),
                    views.viewmats[i : i + 1], views.Ks[i : i + 1], views.width, views.height,
                )  # fmt: skip
                pairs = tile_pairs(proj.means2d[0], proj.radii[0], views.width, views.height, tile)
                sums[name] += float(pairs.sum())
                if name == "street":
                    seen = pairs > 0
                    sums["street_visible"] += float(seen.sum())
                    radius = proj.radii[0][seen].amax(-1).double().numpy()
                    sums["radius_px_p90"] += float(np.percentile(radius, 90)) if radius.size else 0
                    depths, weights = proj.depths[0].double().numpy(), pairs.double().numpy()
                    by_depth += np.histogram(depths, DEPTH_BINS_M, weights=weights)[0]
    k = len(picks)
    return {
        "chunk": trainer.chunk.id,
        "street_gaussians": len(trainer.street),
        "views": k,
        "pairs_street": sums["street"] / k,
        "pairs_sky": sums["sky"] / k,
        "street_visible": sums["street_visible"] / k,
        "street_radius_px_p90": sums["radius_px_p90"] / k,
        "street_pairs_by_depth_m": {
            f"{lo:g}-{hi:g}": v / k
            for lo, hi, v in zip(DEPTH_BINS_M, DEPTH_BINS_M[1:], by_depth, strict=False)
        },
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("workspaces", type=Path, nargs="+")
    parser.add_argument("--views", type=int, default=24, help="training views a chunk")
    parser.add_argument("--tile", type=int, default=GSPLAT_TILE, help="tile side, pixels")
    parser.add_argument(
        "--max-points",
        type=int,
        help="start from about this many points a chunk, thinned with"
        " distance (TrainOptions.max_init_points; default: the preset's)",
    )
    parser.add_argument("--out", type=Path, help="also write the rows as JSON")
    args = parser.parse_args()
    preset = SplatStageOptions.demo(cuda=True)
    assert preset.train is not None
    options = dataclasses.replace(preset.train, device="cpu", backend="torch")
    if args.max_points is not None:
        options = dataclasses.replace(options, max_init_points=args.max_points)
    rows = []
    for root in args.workspaces:
        prep = Workspace.open(root).root / "splat" / "prep"
        if not (prep / "scene.json").is_file():
            parser.error(f"{prep} has no prepared scene: run benchmarks/splat_seeding.py {root}")
        scene = SceneRecord.load(prep / "scene.json")
        points = load_points(prep / "points.npz")[:2]
        for chunk in scene.chunks:
            trainer = ChunkTrainer(chunk, scene, prep, points, options, "cpu", "torch", 300.0)
            row = {"workspace": str(root), **chunk_cost(trainer, args.views, args.tile)}
            rows.append(row)
            by_depth = row["street_pairs_by_depth_m"].items()
            depth = ", ".join(f"{k} m {v / 1e3:.0f}k" for k, v in by_depth)
            print(
                f"{root} chunk {row['chunk']}: {row['street_gaussians']} street Gaussians, "
                f"{row['street_visible'] / 1e3:.0f}k seen a view (p90 radius "
                f"{row['street_radius_px_p90']:.0f} px); pairs a view: street "
                f"{row['pairs_street'] / 1e3:.0f}k ({depth}), sky {row['pairs_sky'] / 1e3:.0f}k",
                flush=True,
            )
    if args.out:
        write_text_atomic(args.out, json.dumps({"tile": args.tile, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
