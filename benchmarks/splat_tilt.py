"""The splat at the recorded samples, its camera tilted as the recorded car was or level.

On a hill the recorded camera pitches with the road. The splat is trained at the recorded
camera poses, so the camera a replay or a drive renders it from must lean the same way
(``stages.cameras.recorded_ground_at``); before 2026-12-02 it stood level. This scores every
``--every``-th recorded sample's render against the recorded frame (grey PSNR), both ways:

    python benchmarks/splat_tilt.py WS [--every 8]

WS is a workspace with a scenario and splat models (``cam2sim run -o WS --steps
map,scenario,splat``). docs/benchmarks.md, "KITTI 03 on one GPU, third run", has the figures
of a KITTI 03 hill stretch.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from cam2sim.core.dataset import DatasetInfo
from cam2sim.core.workspace import Workspace, dataset_paths
from cam2sim.splat.render import RenderOptions, SplatRenderer
from cam2sim.stages.cameras import camera_poses, load_run_context, recorded_tilt, run_camera


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("workspace", type=Path)
    parser.add_argument("--every", type=int, default=8, help="score every N-th sample")
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    ws = Workspace.open(args.workspace)
    sc = load_run_context(ws).scenario
    tr = sc.trajectory
    idx = np.arange(0, len(tr.frame), max(args.every, 1))
    ref = np.asarray(tr.reference, dtype=np.float64)[idx]
    heading = np.asarray(tr.heading, dtype=np.float64)[idx]
    roll, pitch = recorded_tilt(sc, idx)
    poses = {
        "tilted": camera_poses(sc, ref[:, :2], heading, ref[:, 2], roll=roll, pitch=pitch),
        "level": camera_poses(sc, ref[:, :2], heading, ref[:, 2]),
    }
    camera = run_camera(sc, None)
    frames = dataset_paths(ws.dataset_dir)
    fmt = DatasetInfo.load(frames.dataset_json).frame_format
    scores: dict[str, list[float]] = {name: [] for name in poses}
    options = RenderOptions(device=args.device)
    with SplatRenderer(ws.splat_files.models_dir, options=options) as renderer:
        for k, i in enumerate(idx.tolist()):
            real = cv2.imread(str(frames.frame_file(tr.frame[i], fmt)), cv2.IMREAD_GRAYSCALE)
            if real is None:
                continue
            for name, pose in poses.items():
                grey = cv2.cvtColor(renderer.render(pose[k], camera).rgb, cv2.COLOR_RGB2GRAY)
                scores[name].append(float(cv2.PSNR(real, grey)))
            pitch_deg = float(np.degrees(pitch[k]))
            print(f"sample {i}: pitch {pitch_deg:+.2f} deg, " + ", ".join(
                f"{name} {values[-1]:.2f} dB" for name, values in scores.items()
            ))  # fmt: skip
    for name, values in scores.items():
        print(f"{name}: mean PSNR {np.mean(values):.2f} dB over {len(values)} samples")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
