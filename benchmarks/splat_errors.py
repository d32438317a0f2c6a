"""Where a splat model's error is (issue 22): per frame, by image third, fine against coarse.

Renders frames of a prepared scene (training and held-out ones) from trained chunk models and
compares each with the recorded frame:

* ``psnr``: as rendered (the renderer's own colour transform);
* ``psnr_affine``: after the best per-image affine colour fit (least squares): what exposure
  and white balance alone would still give;
* ``psnr_blur2``: both images blurred with a Gaussian of 2 px sigma after that fit: the error
  left at coarse scale (a large gain = the error is fine detail: texture, edges, misregistered
  lines);
* the squared error by image third (top: sky line and trees; middle: horizon, cars,
  vegetation; bottom: road) and on the sky mask.

By class of region (classical rules, no segmentation weights): ``sky`` (the prepared sky
mask), ``sky_line`` (a 6-pixel band below the sky's edge: branches and roofs against the light),
``green`` (green vegetation: excess green of the chromaticity, ``(2g - r - b) / (r + g + b) >
0.08``, outside the sky; dry brush and dark conifers fall in ``other``), ``road`` (the lower
40 % of the image where it is grey, ``max - min < 0.1``, and not green) and ``other`` (the rest:
trunks, dry or dark foliage, buildings, cars, poles; oncoming cars would need a detector's
weights to be told apart). For each class its PSNR and its share of the frame's squared error.
Per frame against the path: the camera's turn rate (degrees per metre of progress, from the
neighbouring frames' optical axes) and the Pearson correlation of the frames' PSNR with it.

``--montage`` writes recorded | render (fitted) | error map | region classes for the frames it
names.

    python3 benchmarks/splat_errors.py --prep /tmp/r_curves --models WS/splat/models \\
        --every 6 --montage 36,120,156,216,264 --out errors/

Prints means for training and held-out frames; writes ``errors.json`` (and ``errors.jpg``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from cam2sim.core.files import write_text_atomic
from cam2sim.core.images import read_mask, read_rgb
from cam2sim.splat.render import RenderOptions, SplatRenderer
from cam2sim.splat.scene import SceneRecord


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(-10.0 * np.log10(np.mean((a - b) ** 2) + 1e-12))


def frame_errors(real: np.ndarray, render: np.ndarray, sky: np.ndarray | None) -> dict[str, Any]:
    """The scores of one frame (``real`` and ``render`` float RGB in ``[0, 1]``)."""
    h, w = real.shape[:2]
    x = np.concatenate([render.reshape(-1, 3), np.ones((h * w, 1), np.float32)], axis=1)
    a, *_ = np.linalg.lstsq(x, real.reshape(-1, 3), rcond=None)
    fit = (x @ a).reshape(real.shape).astype(np.float32)
    err = ((fit - real) ** 2).mean(axis=-1)

    def blur(im: np.ndarray) -> np.ndarray:
        return np.asarray(cv2.GaussianBlur(im, (0, 0), 2.0))

    return {
        "psnr": _psnr(render, real),
        "psnr_affine": _psnr(fit, real),
        "psnr_blur2": _psnr(blur(fit), blur(real)),
        "mse_top": float(err[: h // 3].mean()),
        "mse_middle": float(err[h // 3 : 2 * h // 3].mean()),
        "mse_bottom": float(err[2 * h // 3 :].mean()),
        "sky_share": float(sky.mean()) if sky is not None else 0.0,
        "mse_sky": float(err[sky].mean()) if sky is not None and sky.any() else None,
        "_fit": fit,
        "_err": err,
    }


CLASSES = ("sky", "sky_line", "green", "road", "other")
CLASS_BGR = {  # the montage's colours
    "sky": (235, 206, 135),
    "sky_line": (0, 215, 255),
    "green": (60, 160, 40),
    "road": (128, 128, 128),
    "other": (60, 60, 200),
}


def region_classes(real: np.ndarray, sky: np.ndarray | None) -> dict[str, np.ndarray]:
    """Boolean ``[H, W]`` masks of the region classes of one frame (see the module doc)."""
    h, w = real.shape[:2]
    sky = np.zeros((h, w), bool) if sky is None else sky.astype(bool)
    grown = cv2.dilate(sky.astype(np.uint8), np.ones((13, 13), np.uint8)).astype(bool)
    line = grown & ~sky
    r, g, b = real[..., 0], real[..., 1], real[..., 2]
    total = r + g + b
    # Excess green of the chromaticity (shaded foliage is dark, but still green for its light).
    exg = (2.0 * g - r - b) / np.maximum(total, 1e-6)
    green = (exg > 0.08) & (total > 0.06) & ~sky & ~line
    chroma = real.max(axis=-1) - real.min(axis=-1)
    low = np.zeros((h, w), bool)
    low[int(0.6 * h) :] = True
    road = low & (chroma < 0.1) & ~green & ~sky & ~line
    other = ~(sky | line | green | road)
    return {"sky": sky, "sky_line": line, "green": green, "road": road, "other": other}


def class_errors(err: np.ndarray, classes: dict[str, np.ndarray]) -> dict[str, Any]:
    """Per class: pixel share, PSNR and share of the frame's squared error."""
    total = float(err.sum()) or 1e-12
    out = {}
    for name, mask in classes.items():
        n = int(mask.sum())
        out[name] = {
            "pixels": n / mask.size,
            "psnr": float(-10 * np.log10(err[mask].mean() + 1e-12)) if n else None,
            "error_share": float(err[mask].sum()) / total,
            "_sse": float(err[mask].sum()),
            "_n": n,
        }
    return out


def turn_rates(frames: list[Any]) -> dict[int, float]:
    """Degrees of heading change per metre of progress at each frame (central differences)."""
    order = sorted(frames, key=lambda f: f.progress_m)
    forward = np.array([f.T()[:3, 2] for f in order])
    progress = np.array([f.progress_m for f in order])
    rates = {}
    for i, f in enumerate(order):
        a, b = max(0, i - 1), min(len(order) - 1, i + 1)
        cos = float(np.clip(forward[a] @ forward[b], -1.0, 1.0))
        span = max(progress[b] - progress[a], 1e-9)
        rates[f.index] = float(np.degrees(np.arccos(cos)) / span)
    return rates


def class_map(classes: dict[str, np.ndarray]) -> np.ndarray:
    """BGR picture of the classes."""
    h, w = next(iter(classes.values())).shape
    out = np.zeros((h, w, 3), np.uint8)
    for name, mask in classes.items():
        out[mask] = CLASS_BGR[name]
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--prep", required=True, help="prepared scene (WS/splat/prep)")
    parser.add_argument("--models", required=True, help="trained models (WS/splat/models)")
    parser.add_argument("--every", type=int, default=6, help="every n-th frame of the scene")
    parser.add_argument("--montage", default="", help="frame indices for the picture, e.g. 36,120")
    parser.add_argument("--device", default="auto")
    parser.add_argument("--out", default="errors", help="output folder")
    args = parser.parse_args()
    prep, out = Path(args.prep), Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scene = SceneRecord.load(prep / "scene.json")
    wanted = {int(v) for v in args.montage.split(",") if v.strip()}
    rows: list[dict[str, Any]] = []
    tiles = []
    rates = turn_rates(scene.frames)
    with SplatRenderer(  # at the scene's own poses
        Path(args.models), options=RenderOptions(device=args.device, pose_frame="model")
    ) as renderer:
        for frame in scene.frames[:: args.every]:
            real = read_rgb(prep / "images" / f"{frame.index:06d}.png").astype(np.float32) / 255
            rgb = renderer.render(frame.T(), frame.camera()).rgb
            sky_file = prep / "sky" / f"{frame.index:06d}.png"
            sky = read_mask(sky_file) if sky_file.is_file() else None
            scores = frame_errors(real, rgb.astype(np.float32) / 255, sky)
            fit, err = scores.pop("_fit"), scores.pop("_err")
            classes = region_classes(real, sky)
            by_class = class_errors(err, classes)
            rows.append(
                {
                    "index": frame.index,
                    "held_out": frame.held_out,
                    "turn_deg_per_m": rates[frame.index],
                    **scores,
                    "classes": by_class,
                }
            )
            if frame.index in wanted:
                heat = np.clip(np.sqrt(err) * 4 * 255, 0, 255).astype(np.uint8)
                tiles.append(
                    np.concatenate(
                        [
                            (real[..., ::-1] * 255).astype(np.uint8),
                            (np.clip(fit, 0, 1)[..., ::-1] * 255).astype(np.uint8),
                            cv2.applyColorMap(heat, cv2.COLORMAP_MAGMA),
                            class_map(classes),
                        ],
                        axis=1,
                    )
                )
    summary: dict[str, Any] = {}
    for group, held in (("training", False), ("held_out", True)):
        picked = [r for r in rows if r["held_out"] == held]
        if not picked:
            continue
        mse = np.mean([[r["mse_top"], r["mse_middle"], r["mse_bottom"]] for r in picked], axis=0)
        mean = {k: float(np.mean([r[k] for r in picked])) for k in ("psnr", "psnr_affine")}
        mean["psnr_blur2"] = float(np.mean([r["psnr_blur2"] for r in picked]))
        thirds = (-10 * np.log10(mse)).tolist()
        by_class = {}
        total = sum(c["_sse"] for r in picked for c in r["classes"].values()) or 1e-12
        for name in CLASSES:
            sse = sum(r["classes"][name]["_sse"] for r in picked)
            n = sum(r["classes"][name]["_n"] for r in picked)
            by_class[name] = {
                "pixels": n / sum(c["_n"] for r in picked for c in r["classes"].values()),
                "psnr": float(-10 * np.log10(sse / n + 1e-12)) if n else None,
                "error_share": sse / total,
            }
        turn = np.array([r["turn_deg_per_m"] for r in picked])
        psnr = np.array([r["psnr"] for r in picked])
        corr = (
            float(np.corrcoef(turn, psnr)[0, 1])
            if len(picked) > 2 and turn.std() > 0 and psnr.std() > 0
            else None
        )
        summary[group] = {
            "frames": len(picked),
            **mean,
            "psnr_by_third": dict(zip(("top", "middle", "bottom"), thirds, strict=True)),
            "by_class": by_class,
            "psnr_vs_turn_rate_r": corr,
        }
        print(group, json.dumps(summary[group]))
    for r in rows:  # the sums were for the summary only
        for c in r["classes"].values():
            c.pop("_sse"), c.pop("_n")
    write_text_atomic(
        out / "errors.json", json.dumps({"summary": summary, "frames": rows}, indent=1)
    )
    if tiles:
        cv2.imwrite(
            str(out / "errors.jpg"), np.concatenate(tiles, axis=0), [cv2.IMWRITE_JPEG_QUALITY, 85]
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
