"""Benchmark of a dash camera's video as ``cam2sim import`` reads it (issue 38).

Writes a synthetic clip (``--size`` pixels, 30 fps, ``--seconds`` long, MPEG-4 part 2, a
textured scene panning sideways so that neither PNG nor the decoder gets an easy image), or
takes ``--video``, then times :func:`cam2sim.recording.video.decode_video` keeping 10 frames a
second, as PNG and as JPEG (q95): seconds, milliseconds a kept frame, and the bytes written.
The best of ``--repeat`` runs. Run from the repository root::

    PYTHONPATH=src python benchmarks/video_import.py [--size 1920x1080] [--seconds 10]
        [--video drive.mp4] [--repeat 2]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from cam2sim.recording.video import decode_video


def _clip(path: Path, width: int, height: int, seconds: float) -> Path:
    rng = np.random.default_rng(0)
    base = cv2.GaussianBlur((rng.random((height, width, 3)) * 255).astype(np.uint8), (0, 0), 3)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (width, height))
    for k in range(round(30 * seconds)):
        writer.write(np.roll(base, 4 * k, axis=1))
    writer.release()
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--size", default="1920x1080", help="WIDTHxHEIGHT of the synthetic clip")
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--video", type=Path, help="a video to read instead of the synthetic one")
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="cam2sim-video-") as tmp:
        video = args.video
        if video is None:
            width, height = (int(v) for v in args.size.lower().split("x"))
            video = _clip(Path(tmp) / "clip.mp4", width, height, args.seconds)
        print(f"{video} ({video.stat().st_size / 1e6:.1f} MB)")
        print("| frames as | kept of decoded | seconds | ms a kept frame | MB written |")
        print("| --- | --- | --- | --- | --- |")
        for fmt in ("png", "jpeg"):
            best = float("inf")
            for k in range(args.repeat):
                out = Path(tmp) / f"{fmt}{k}"
                start = time.perf_counter()
                result = decode_video(video, out, max_fps=10.0, fmt=fmt)
                best = min(best, time.perf_counter() - start)
            size = sum(f.stat().st_size for f in result.files) / 1e6
            kept = len(result.files)
            print(
                f"| {fmt} | {kept} of {result.decoded} | {best:.2f} | {1000 * best / kept:.0f} "
                f"| {size:.0f} |"
            )


if __name__ == "__main__":
    main()
