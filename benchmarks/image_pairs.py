"""Seconds a pair of ``evaluate_image_folders`` (PSNR, SSIM; LPIPS off), decoding included.

Takes the first ``--pairs`` frames of a folder (e.g. an imported workspace's
``dataset/frames``), writes them and a blurred copy (Gaussian 5x5, sigma 1) as PNG to a
temporary folder, and times the scoring: the pairs are read and scored in ``available_cpus()``
threads (docs/benchmarks.md, "Image pairs scored in threads")::

    python benchmarks/image_pairs.py kitti03/dataset/frames --pairs 160
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import cv2

from cam2sim.core.machine import available_cpus
from cam2sim.metrics.image_quality import ImageQualityOptions, evaluate_image_folders


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("frames", type=Path, help="a folder of frames (PNG or JPEG)")
    parser.add_argument("--pairs", type=int, default=160)
    args = parser.parse_args()
    frames = sorted(p for p in args.frames.iterdir() if p.suffix.lower() in {".png", ".jpg"})
    frames = frames[: args.pairs]
    with tempfile.TemporaryDirectory() as tmp:
        real, sim = Path(tmp) / "real", Path(tmp) / "sim"
        real.mkdir()
        sim.mkdir()
        for i, f in enumerate(frames):
            image = cv2.imread(str(f))
            cv2.imwrite(str(real / f"{i:06d}.png"), image)
            cv2.imwrite(str(sim / f"{i:06d}.png"), cv2.GaussianBlur(image, (5, 5), 1.0))
        h, w = image.shape[:2]
        start = time.perf_counter()
        evaluate_image_folders(real, sim, options=ImageQualityOptions(lpips_net=None))
        seconds = time.perf_counter() - start
    print(
        f"{len(frames)} pairs {w}x{h}: {seconds:.1f} s, {1000 * seconds / len(frames):.0f} ms a "
        f"pair; {available_cpus()} threads, {os.cpu_count()} CPUs"
    )


if __name__ == "__main__":
    main()
