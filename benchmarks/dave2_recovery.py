"""How much does a DAVE-2 steer back when it sees the road from beside the recorded path?

A closed loop stays on the road only if the policy corrects an offset. This script measures the
correction a trained network has learned: on every ``--every``-th frame of a workspace's
dataset it shows the network the frame as seen ``--lateral`` metres to the left and to the
right of the recorded camera (and turned ``--yaw`` degrees; the same ground-plane views as
training, :func:`cam2sim.ads.recovery.recovery_views`), and compares the difference of its
answers with the difference of the recovery labels (:func:`cam2sim.ads.recovery.recovery_label`,
with the model's own look-ahead, or ``--lookahead``). A ratio of 1 is the correction the
labels ask for; 0 is a network that ignores where it is.

Usage:
    PYTHONPATH=src python benchmarks/dave2_recovery.py WS MODEL.onnx [--signal NAME]
        [--lateral 0.5] [--yaw 0] [--every 4] [--lookahead 10] [--json out.json]

Prints the ratio over all frames, on straights (``|steering| <`` the median) and in turns,
and the mean answer on the recorded frames against the signal (MAE).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from cam2sim.ads.dave2 import METADATA_KEY, Dave2Config
from cam2sim.ads.recovery import recovery_label, recovery_views
from cam2sim.ads.train import assemble
from cam2sim.ads.train_options import TrainOptions
from cam2sim.core.backends import onnx_session
from cam2sim.core.dataset import Calibration, DatasetInfo
from cam2sim.core.workspace import Workspace, dataset_paths
from cam2sim.stages.ads import recovery_geometry


def _answers(session: Any, x: np.ndarray) -> np.ndarray:
    name = session.get_inputs()[0].name
    out = [session.run(None, {name: x[i : i + 1].astype(np.float32)})[0] for i in range(len(x))]
    return np.asarray(out, dtype=np.float64).reshape(-1)


def main() -> int:
    """Measure, print, write."""
    import torch  # noqa: PLC0415

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("workspace", type=Path)
    parser.add_argument("model", type=Path)
    parser.add_argument("--signal", default="steering_from_poses")
    parser.add_argument("--lateral", type=float, default=0.5)
    parser.add_argument("--yaw", type=float, default=0.0)
    parser.add_argument("--every", type=int, default=4)
    parser.add_argument("--lookahead", type=float, default=None)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()

    ws = Workspace.open(args.workspace)
    session = onnx_session(args.model, "the DAVE-2 model")
    meta = session.get_modelmeta().custom_metadata_map.get(METADATA_KEY)
    paths = dataset_paths(ws.dataset_dir)
    if meta is not None:
        config = Dave2Config.from_json(meta)
    else:
        camera = Calibration.load(paths.calibration_json).camera
        assert camera is not None
        config = Dave2Config.for_camera(camera.width, camera.height)
    info = json.loads((ws.ads_dir / "dave2.json").read_text(encoding="utf-8"))
    lookahead = args.lookahead or (info.get("recovery") or {}).get("lookahead_m", 10.0)
    opts = TrainOptions(signal=args.signal, config=config)
    data = assemble(paths, DatasetInfo.load(paths.dataset_json).frame_format, opts)
    data = data.take(np.arange(0, len(data.t), args.every))
    geometry = recovery_geometry(ws)
    assert geometry is not None, "the workspace's camera geometry is needed"
    x = torch.from_numpy(data.images).float()
    n = len(data.t)
    yaw = math.radians(args.yaw)
    seen = {}
    for side in (-1.0, 1.0):
        lat = np.full(n, side * args.lateral)
        views = recovery_views(x, geometry, config, lat, np.full(n, side * yaw))
        seen[side] = _answers(session, views.numpy())
    centre = _answers(session, data.images.astype(np.float32))
    y = data.steering.astype(np.float64)
    lab = {
        s: recovery_label(
            y,
            np.full(n, s * args.lateral),
            np.full(n, s * yaw),
            lookahead_m=lookahead,
            curvature_per_unit=geometry.curvature_per_unit,
        )
        for s in (-1.0, 1.0)
    }
    asked = lab[1.0] - lab[-1.0]
    given = seen[1.0] - seen[-1.0]
    straight = np.abs(y) < np.median(np.abs(y))
    result: dict[str, Any] = {
        "workspace": str(ws.root),
        "model": str(args.model),
        "frames": n,
        "lateral_m": args.lateral,
        "yaw_deg": args.yaw,
        "lookahead_m": lookahead,
        "label_difference": float(asked.mean()),
        "ratio_all": float(given.mean() / asked.mean()),
        "ratio_straights": float(given[straight].mean() / asked[straight].mean()),
        "ratio_turns": float(given[~straight].mean() / asked[~straight].mean()),
        "right_direction_share": float(np.mean(np.sign(given) == np.sign(asked))),
        "mae_on_recorded": float(np.mean(np.abs(centre - y))),
    }
    for key, value in result.items():
        print(f"{key}: {value}")
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
