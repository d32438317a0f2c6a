#!/usr/bin/env bash
# Splat training across the GPUs of one machine through a local Ray instance (issue 41;
# docs/benchmarks.md, "Splat training across GPUs"): benchmarks/splat_ray_scaling.py on the
# prepared scene carried in .rs/prep, its first chunk copied REPLICATE times (default 8), each
# trained STEPS steps (default 5000) on 1, 2 (, 4) GPUs (GPUS, default 1,2). The wheels, Ray and
# the scene do not fit one call's 64 MiB, so three calls on one warm machine, each within the
# 30 s idle window of the one before:
#
#   PHASE=setup bash benchmarks/gpu_ray_scaling.sh   # carry .c21/a .gl: wheels, gsplat build
#   PHASE=scene bash benchmarks/gpu_ray_scaling.sh   # carry .rs: the scene, copied to /tmp/prep
#   PHASE=run bash benchmarks/gpu_ray_scaling.sh     # carry .c21/b .ray: Ray, then the levels;
#                                                    # $OUT/ray_scaling.json and the log
#
# Build the carried folders here first: `bash benchmarks/carry_kit.sh demo ray`, and put a
# prepared scene in .rs/prep (e.g. `cp -r WS/splat/prep .rs/prep` after `cam2sim demo`;
# .rs/ must be in .git/info/exclude).
case ${PHASE:?set PHASE to setup, scene or run} in
setup) WHEELS=.c21/a ;;
run) WHEELS=.c21/b ;;
scene) WHEELS= ;;
*)
  echo "PHASE=$PHASE: use setup, scene or run" >&2
  exit 2
  ;;
esac
MARKER=/tmp/.gpu_ray_scaling_setup
source "$(dirname "$0")/gpu_phase.sh"
export RAY_AUTH_MODE=disabled
case $PHASE in
setup)
  python3 -c "from cam2sim.splat.raster import build_gsplat; build_gsplat()" || exit 1
  touch "$MARKER"
  ;;
scene)
  rm -rf /tmp/prep && cp -r .rs/prep /tmp/prep && ls /tmp/prep && nvidia-smi -L
  ;;
run)
  tar xJf .ray/ray-slim.tar.xz -C /tmp/site || exit 1
  python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .ray/*.whl || exit 1
  python3 benchmarks/splat_ray_scaling.py /tmp/prep --gpus "${GPUS:-1,2}" \
    --replicate "${REPLICATE:-8}" --steps "${STEPS:-5000}" --out "$out/ray_scaling.json" \
    2>&1 | tee "$out/ray_scaling.log"
  ;;
esac
