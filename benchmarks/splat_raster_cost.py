"""Where a splat training step's rasterizer time goes: tiles, channels, depth and screen size.

Loads a trained chunk model and the training views of its chunk, then renders each view as a
training step does (street and sky Gaussians joined, RGB plus the sky share: four channels),
takes an L1 loss and runs the backward pass, timing the forward and the backward pass with
CUDA events. Settings compared on the same views:

- ``tile_size``: gsplat gives each square tile one thread block and walks the tile's
  depth-sorted list of Gaussians for all its pixels; the images are the same for every size.
- ``--split-sky``: the street rendered in three channels and the sky on its own, composited
  behind it (the sky share is then ``(1 - street alpha) * sky alpha``). It equals the joined
  render when every sky Gaussian lies behind every street Gaussian; the largest difference is
  reported.

It also counts the tile/Gaussian intersections of each view (tile 16) by the Gaussian's depth
and screen radius, which is what the rasterizer's work grows with.

    python3 benchmarks/splat_raster_cost.py --prep PREP --model MODELS/chunk_01.pt \\
        --tiles 8,16,32 --split-sky --views 64 --out raster_cost.json

Needs CUDA and gsplat (``--device cpu`` runs the torch rasterizer, without the counts).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from cam2sim.core.files import write_text_atomic
from cam2sim.splat.model import gather_splats, load_chunk_model
from cam2sim.splat.raster import rasterize
from cam2sim.splat.scene import SceneRecord
from cam2sim.splat.views import load_views

DEPTH_BINS_M = (0.0, 5.0, 10.0, 25.0, 50.0, float("inf"))
RADIUS_BINS_PX = (0, 2, 4, 8, 32, 1 << 30)


def _views(prep: Path, chunk_id: int, n: int, device: str) -> Any:
    scene = SceneRecord.load(prep / "scene.json")
    chunk = next(c for c in scene.chunks if c.id == chunk_id)
    by_index = {f.index: f for f in scene.frames}
    frames = sorted(
        (by_index[i] for i in chunk.frames if not by_index[i].held_out),
        key=lambda f: (f.progress_m, f.index),
    )
    step = max(1, len(frames) // n)
    return load_views(prep, frames[::step][:n], 1, device)


def _render(model: Any, views: Any, i: int, tile: int, *, split: bool, background: Any) -> Any:
    """(rgb [H, W, 3], sky share [H, W], the backend's meta of the street render)."""
    import torch  # noqa: PLC0415

    backend = "gsplat" if views.images.is_cuda else "torch"

    campos, viewmat, K = views.campos[i : i + 1], views.viewmats[i : i + 1], views.Ks[i : i + 1]
    w, h = views.width, views.height
    if not split:
        inputs = gather_splats(model.gaussians, model.sky, campos, 3, backend=backend)
        out = rasterize(
            inputs.means, inputs.quats, inputs.scales, inputs.opacities, inputs.colors,
            viewmat, K, w, h, backgrounds=background, backend=backend, tile_size=tile,
        )  # fmt: skip
        image = out.colors[0]
        return image[..., :3], image[..., 3], out.info
    parts = []
    for part, degree, bg in ((model.gaussians, 3, None), (model.sky, 0, background[:, :3])):
        p = part.params
        out = rasterize(
            p["means"], p["quats"], torch.exp(p["scales"]), torch.sigmoid(p["opacities"]),
            part.colors(campos, degree, backend=backend), viewmat, K, w, h,
            backgrounds=bg, backend=backend, tile_size=tile,
        )  # fmt: skip
        parts.append(out)
    street, sky = parts
    behind = 1.0 - street.alphas[0]
    rgb = street.colors[0] + behind * sky.colors[0]
    return rgb, (behind * sky.alphas[0])[..., 0], street.info


def time_setting(
    model: Any, views: Any, tile: int, *, split: bool, background: Any, repeat: int
) -> dict[str, float]:
    """Mean forward and backward milliseconds per view (wall time on the CPU)."""
    import torch  # noqa: PLC0415

    cuda = views.images.is_cuda

    n = views.images.shape[0]
    targets = views.images.float() / 255.0
    fwd, bwd = [], []
    for r in range(repeat + 1):  # the first pass warms up
        for i in range(n):
            if cuda:
                torch.cuda.synchronize()
            t0 = time.perf_counter()
            rgb, share, _ = _render(model, views, i, tile, split=split, background=background)
            loss = (rgb - targets[i]).abs().mean() + 0.1 * share.mean()
            if cuda:
                torch.cuda.synchronize()
            t1 = time.perf_counter()
            loss.backward()
            if cuda:
                torch.cuda.synchronize()
            if r:
                fwd.append(1e3 * (t1 - t0))
                bwd.append(1e3 * (time.perf_counter() - t1))
            for part in (model.gaussians, model.sky):
                for p in part.params.values():
                    p.grad = None
    return {"forward_ms": float(np.mean(fwd)), "backward_ms": float(np.mean(bwd))}


def intersections(model: Any, views: Any, background: Any) -> dict[str, Any]:
    """Tile/Gaussian pairs per view (tile 16) by depth and screen radius, list lengths."""
    import torch  # noqa: PLC0415

    by_depth = np.zeros(len(DEPTH_BINS_M) - 1)
    by_radius = np.zeros(len(RADIUS_BINS_PX) - 1)
    lengths, total, visible = [], 0, 0
    with torch.no_grad():
        for i in range(views.images.shape[0]):
            _, _, info = _render(model, views, i, 16, split=False, background=background)
            gid = info["flatten_ids"].long()
            depth = info["depths"][0][gid].cpu().numpy()
            radius = info["radii"][0][gid].amax(-1).cpu().numpy()
            by_depth += np.histogram(depth, DEPTH_BINS_M)[0]
            by_radius += np.histogram(radius, RADIUS_BINS_PX)[0]
            offsets = info["isect_offsets"].flatten().cpu().numpy()
            lengths.append(np.diff(np.append(offsets, gid.numel())))
            total += gid.numel()
            visible += int((info["radii"][0].amax(-1) > 0).sum())
    n = views.images.shape[0]
    per_tile = np.concatenate(lengths)
    return {
        "pairs_per_view": total / n,
        "visible_gaussians_per_view": visible / n,
        "share_by_depth_m": {
            f"{a:g}-{b:g}": float(c / total)
            for a, b, c in zip(DEPTH_BINS_M, DEPTH_BINS_M[1:], by_depth, strict=False)
        },
        "share_by_radius_px": {
            f"{a}-{b}": float(c / total)
            for a, b, c in zip(RADIUS_BINS_PX, RADIUS_BINS_PX[1:], by_radius, strict=False)
        },
        "tile_list_mean": float(per_tile.mean()),
        "tile_list_p90": float(np.percentile(per_tile, 90)),
        "tile_list_max": int(per_tile.max()),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--prep", required=True, help="prepared scene folder (images at size)")
    parser.add_argument("--model", required=True, help="a chunk_XX.pt of that scene")
    parser.add_argument("--tiles", default="8,16,32")
    parser.add_argument("--split-sky", action="store_true", help="also time the split render")
    parser.add_argument("--views", type=int, default=64)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--device", default="cuda", help="cuda, or cpu for a smoke test")
    parser.add_argument("--out", default="raster_cost.json")
    args = parser.parse_args()
    import torch  # noqa: PLC0415

    cuda = args.device.startswith("cuda")
    model = load_chunk_model(Path(args.model), device=args.device)
    for part in (model.gaussians, model.sky):
        for p in part.params.values():
            p.requires_grad_(requires_grad=True)
    views = _views(Path(args.prep), model.header.chunk_id, args.views, args.device)
    background = torch.tensor([[*model.header.background, 0.0]], device=args.device)
    record: dict[str, Any] = {
        "model": str(args.model),
        "gaussians": len(model.gaussians),
        "sky": len(model.sky),
        "views": int(views.images.shape[0]),
        "size": [views.width, views.height],
        "device": torch.cuda.get_device_name() if cuda else "cpu",
        "intersections": intersections(model, views, background) if cuda else None,
        "settings": [],
    }
    print(json.dumps(record["intersections"], indent=1))
    with torch.no_grad():
        joined = _render(model, views, 0, 16, split=False, background=background)
        split = _render(model, views, 0, 16, split=True, background=background)
        record["split_max_abs_diff"] = {
            "rgb": float((joined[0] - split[0]).abs().max()),
            "sky_share": float((joined[1] - split[1]).abs().max()),
        }
    print("split vs joined:", record["split_max_abs_diff"])
    modes = [False, True] if args.split_sky else [False]
    for split_sky in modes:
        for tile in (int(t) for t in args.tiles.split(",")):
            t0 = time.perf_counter()
            row = time_setting(
                model, views, tile, split=split_sky, background=background, repeat=args.repeat
            )
            row.update(tile=tile, split_sky=split_sky, seconds=time.perf_counter() - t0)
            print(json.dumps(row))
            record["settings"].append(row)
    write_text_atomic(Path(args.out), json.dumps(record, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
