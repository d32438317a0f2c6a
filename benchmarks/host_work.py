"""The host work beside the GPU in `cam2sim run`, on one thread against on worker threads.

On a GPU machine the KITTI run (docs/benchmarks.md, "fifth run") spent minutes on work the
GPU waits for: reading, undistorting and writing the splat's views, encoding three PNGs a
replay frame, scoring and writing the splat's held-out renders. This script times each of them
on real frames the way the pipeline does it now (:class:`cam2sim.core.background.BackgroundJobs`)
and the way it did before (one thread). (DAVE-2's recovery warp, NumPy per pixel before, now
one torch implementation on the batch's device, was timed by this script at commit 9a896ab.)

    PYTHONPATH=src python benchmarks/host_work.py FRAMES_DIR [--frames 200] [--workers N]

FRAMES_DIR holds the frames (PNG or JPEG; KITTI 03's 1242x375 grey frames for the figures in
docs/benchmarks.md). Prints milliseconds per frame and the speed-up; the
work stands in for the GPU's renders with the frames themselves.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from cam2sim.core.background import BackgroundJobs
from cam2sim.core.images import read_rgb, write_rgb
from cam2sim.core.machine import available_cpus
from cam2sim.splat.scores import score_pair
from cam2sim.stages.cameras import write_png
from cam2sim.stages.runs import side_by_side


def _timed(
    label: str,
    before: float,
    after: float,
    n: int,
    names: tuple[str, str] = ("one thread", "workers"),
) -> None:
    print(
        f"{label:<30} {names[0]} {1000 * before / n:7.1f} ms   "
        f"{names[1]} {1000 * after / n:7.1f} ms   x{before / after:4.1f}"
    )


def _replay_writes(images: list[np.ndarray], out: Path, workers: int) -> tuple[float, float]:
    """Three PNGs a frame (raster, splat, side by side), as the replay writes them."""

    def frame(k: int, im: np.ndarray, jobs: BackgroundJobs[None] | None) -> None:
        sbs = side_by_side([im, im, im])
        for name, image in (("raster", im), ("splat", im), ("sbs", sbs)):
            path = out / name / f"{k:06d}.png"
            if jobs is None:
                write_png(path, image)
            else:
                jobs.submit(write_png, path, image)

    start = time.perf_counter()
    for k, im in enumerate(images):
        frame(k, im, None)
    serial = time.perf_counter() - start
    start = time.perf_counter()
    with BackgroundJobs[None](workers) as jobs:
        for k, im in enumerate(images):
            frame(k, im, jobs)
    return serial, time.perf_counter() - start


def _eval_scores(images: list[np.ndarray], out: Path, workers: int) -> tuple[float, float]:
    """A held-out frame's work beside its renders: two scores and a lossless WebP."""
    shifted = [np.roll(im, 2, axis=1) for im in images]  # a render that is not the frame

    def job(k: int, real: np.ndarray, sim: np.ndarray) -> float | None:
        write_rgb(out / f"{k:06d}.webp", sim)
        score_pair(real, sim, None, None)
        return score_pair(real, real // 2 + sim // 2, None, None).ssim

    start = time.perf_counter()
    for k, (a, b) in enumerate(zip(images, shifted, strict=True)):
        job(k, a, b)
    serial = time.perf_counter() - start
    start = time.perf_counter()
    with BackgroundJobs[float | None](workers) as jobs:
        for k, (a, b) in enumerate(zip(images, shifted, strict=True)):
            jobs.submit(job, k, a, b)
    return serial, time.perf_counter() - start


def _views(files: list[Path], out: Path, workers: int) -> tuple[float, float]:
    """The splat's views: read, undistort (a remap), sky mask, three PNGs."""
    import cv2  # noqa: PLC0415

    from cam2sim.splat import masks  # noqa: PLC0415

    h, w = read_rgb(files[0]).shape[:2]
    mx, my = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    mx = mx + 0.5 * np.sin(my / 40.0).astype(np.float32)

    def view(k: int, file: Path) -> None:
        image = cv2.remap(read_rgb(file), mx, my, cv2.INTER_LINEAR)
        sky = masks.sky_mask_classical(image)
        cv2.imwrite(str(out / f"i{k:06d}.png"), image[..., ::-1])
        cv2.imwrite(str(out / f"m{k:06d}.png"), np.full((h, w), 255, np.uint8))
        cv2.imwrite(str(out / f"s{k:06d}.png"), np.where(sky, 255, 0).astype(np.uint8))

    start = time.perf_counter()
    for k, f in enumerate(files):
        view(k, f)
    serial = time.perf_counter() - start
    start = time.perf_counter()
    with BackgroundJobs[None](workers) as jobs:
        for k, f in enumerate(files):
            jobs.submit(view, k, f)
    return serial, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("frames", type=Path)
    parser.add_argument("--frames", dest="n", type=int, default=200)
    parser.add_argument("--workers", type=int, default=None)
    args = parser.parse_args()
    files = sorted(p for p in args.frames.iterdir() if p.suffix.lower() in {".png", ".jpg"})
    files = files[: args.n]
    if not files:
        parser.error(f"no PNG or JPEG frames in {args.frames}")
    workers = args.workers or available_cpus()
    images = [read_rgb(f) for f in files]
    h, w = images[0].shape[:2]
    print(f"{len(files)} frames of {w}x{h}, {workers} worker threads, {available_cpus()} CPUs")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        _timed("splat views (read..write)", *_views(files, out, workers), len(files))
        _timed("replay writes (3 PNGs)", *_replay_writes(images, out, workers), len(files))
        _timed("splat eval (2 scores, WebP)", *_eval_scores(images, out, workers), len(files))


if __name__ == "__main__":
    main()
