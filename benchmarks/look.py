"""Speed of the photographic look (the demo recording's and the truth camera's post-processing).

Renders ``--frames`` raster frames along the built-in street (the demo camera, 320x200) and
times :func:`cam2sim.render.look.photographic_look` on each, with the sensor noise of its pose.
``--save FILE`` writes the images' digest to FILE; ``--check FILE`` compares with one written
before (a faster look must draw the same bytes: recordings and closed-loop runs share it).

Run from the repository root::

    python benchmarks/look.py [--frames 200] [--save FILE | --check FILE]
"""

from __future__ import annotations

import argparse
import hashlib
import time
from pathlib import Path

import numpy as np

from cam2sim.demo.rig import demo_camera
from cam2sim.demo.world import demo_world
from cam2sim.render.look import frame_noise_rng, photographic_look
from cam2sim.render.raster import RasterRenderer


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--save", type=Path)
    parser.add_argument("--check", type=Path)
    args = parser.parse_args()
    world = demo_world(0)
    street = world.street
    camera = demo_camera()
    k = camera.K()
    stations = np.linspace(1.0, street.length_m - 1.0, args.frames)
    with RasterRenderer(world.raster_scene()) as renderer:
        poses = [street.camera_pose(float(s)) for s in stations]
        frames = [renderer.render(pose, camera) for pose in poses]
    digest = hashlib.sha256()
    photographic_look(frames[0].rgb, frames[0].labels, poses[0], k, rng=None)  # warm-up
    seconds = []
    for frame, pose in zip(frames, poses, strict=True):
        rng = frame_noise_rng(0, pose)
        started = time.perf_counter()
        image = photographic_look(frame.rgb, frame.labels, pose, k, rng=rng)
        seconds.append(time.perf_counter() - started)
        digest.update(image.tobytes())
    ms = 1e3 * np.asarray(seconds)
    print(
        f"photographic look, {camera.width}x{camera.height}, {len(frames)} frames: "
        f"mean {ms.mean():.2f} ms, median {np.median(ms):.2f} ms"
    )
    print(f"digest {digest.hexdigest()}")
    if args.save:
        args.save.write_text(digest.hexdigest() + "\n")
    if args.check:
        same = args.check.read_text().strip() == digest.hexdigest()
        print("the same bytes as" if same else "DIFFERENT bytes from", args.check)
        raise SystemExit(0 if same else 1)


if __name__ == "__main__":
    main()
