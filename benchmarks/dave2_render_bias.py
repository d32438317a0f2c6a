"""What DAVE-2 answers on rendered frames of the recorded drive, against the recorded steering.

Trains DAVE-2 on a workspace as ``cam2sim run`` does (``TrainOptions.same_street``, without
the refit so that it runs in half the time; ``--blur`` sets the soft frames, 0 turns them
off), then reads a replay run's frames (``WS/runs/<replay>/frames/{splat,raster}``, every 4th)
and prints, per camera, the mean absolute error and, on straight road (|steering| < 0.5 units),
the mean error: a network that reads a render's softness as a turn shows a bias there
(docs/benchmarks.md, "KITTI 03 on one GPU")::

    python benchmarks/dave2_render_bias.py kitti03 kitti03/runs/<id>-replay-raster+splat \
        --signal steering_from_poses --blur 3
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import torch

from cam2sim.ads.dave2 import preprocess
from cam2sim.ads.train_options import TrainOptions
from cam2sim.core.table import read_table
from cam2sim.core.workspace import Workspace, dataset_paths
from cam2sim.stages.ads import train_model


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("workspace", type=Path)
    parser.add_argument("replay", type=Path, help="a replay run folder with splat/raster frames")
    parser.add_argument("--signal", default="steering")
    parser.add_argument("--blur", type=float, default=3.0)
    parser.add_argument("--fps", type=float, default=10.0, help="recorded frames a second")
    args = parser.parse_args()
    ws = Workspace.open(args.workspace)
    opts = TrainOptions.same_street(args.signal, device="cpu", refit_all=False)
    opts = replace(opts, split="tail", val_fraction=0.05, gap_s=0.0, blur_px=args.blur)
    start = time.perf_counter()
    model = train_model(ws, opts)
    net = model.model.eval()
    signal = read_table(dataset_paths(ws.dataset_dir).signal_file(args.signal))
    print(f"trained in {time.perf_counter() - start:.0f} s (blur {args.blur} px)")
    for camera in ("splat", "raster"):
        files = sorted((args.replay / "frames" / camera).glob("*.png"))[::4]
        if not files:
            continue
        images = np.stack(
            [
                preprocess(
                    cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2RGB)[None], model.info.config
                )[0]
                for f in files
            ]
        )
        with torch.inference_mode():
            pred = net(torch.from_numpy(images).float()).view(-1).numpy()
        t = np.array([int(f.stem) for f in files]) / args.fps
        label = np.interp(t, signal["t"], signal["value"])
        err = pred - label
        straight = np.abs(label) < 0.5
        print(
            f"{camera}: MAE {np.mean(np.abs(err)):.2f} units, on straight road MAE "
            f"{np.mean(np.abs(err[straight])):.2f} and bias {np.mean(err[straight]):+.2f} "
            f"({len(files)} frames)"
        )


if __name__ == "__main__":
    main()
