"""Pack a prepared scene small enough to carry to a GPU machine (64 MiB a call).

Resizes ``WS/splat/prep`` to ``--size`` (area averaging; :func:`splat_gpu.resize_prep`) and
stores its images as lossless WebP (about 45 MB for 300 frames at 480x360 against 110 MB of
PNG); masks and sky masks stay PNG. On the GPU machine, ``resize_prep`` turns the WebP back
into PNG (it reads any image OpenCV reads and writes PNG), so the trained-on pixels are the same:

    python benchmarks/pack_scene.py WS/splat/prep .u22/curves --size 480x360
    # there:
    python3 -c "import sys; sys.path.insert(0, 'benchmarks'); from pathlib import Path; \\
        from splat_gpu import resize_prep; \\
        resize_prep(Path('.u22/curves'), Path('/tmp/r_curves'), (480, 360))"
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from splat_gpu import resize_prep


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("prep", help="prepared scene (WS/splat/prep)")
    parser.add_argument("out", help="folder to write (an ignored folder of the repo, to carry)")
    parser.add_argument("--size", default="480x360", help="WxH")
    args = parser.parse_args()
    w, h = (int(v) for v in args.size.lower().split("x"))
    out = Path(args.out)
    with tempfile.TemporaryDirectory() as tmp:
        resized = resize_prep(Path(args.prep), Path(tmp) / "resized", (w, h))
        (out / "images").mkdir(parents=True, exist_ok=True)
        for path in sorted((resized / "images").iterdir()):
            image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            ok, data = cv2.imencode(".webp", image, [cv2.IMWRITE_WEBP_QUALITY, 101])  # lossless
            if not ok or not np.array_equal(cv2.imdecode(data, cv2.IMREAD_UNCHANGED), image):
                print(f"{path}: WebP did not round-trip losslessly", file=sys.stderr)
                return 1
            (out / "images" / f"{path.stem}.webp").write_bytes(data.tobytes())
        for sub in ("masks", "sky"):
            if (resized / sub).is_dir():
                shutil.copytree(resized / sub, out / sub, dirs_exist_ok=True)
        for name in ("points.npz", "scene.json"):
            shutil.copy2(resized / name, out / name)
    size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    print(f"{out}: {size / 2**20:.1f} MiB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
