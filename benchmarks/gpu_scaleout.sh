#!/usr/bin/env bash
# Issue 41 on one 4-GPU machine (docs/benchmarks.md, "Splat training across GPUs" and
# "Campaigns across GPUs"), after benchmarks/gpu_bench.sh has built the worlds on it:
#
#   SUITE=benchmarks/suites/scaleout-gpu.yaml PHASE=setup bash benchmarks/gpu_bench.sh  # carry .c21/a .gl .osm
#   SUITE=benchmarks/suites/scaleout-gpu.yaml PHASE=start bash benchmarks/gpu_bench.sh  # carry .c21/b .ray
#   PHASE=wait bash benchmarks/gpu_bench.sh            # until its 4 worlds are done (one GPU each)
#   PHASE=splat bash benchmarks/gpu_scaleout.sh        # splat training on 1, 2, 4 GPUs (GPUS):
#                                                      # the l-street world's first chunk copied
#                                                      # REPLICATE (8) times, STEPS (2000) each
#   PHASE=campaign bash benchmarks/gpu_scaleout.sh     # the 4 worlds x 3 seeds x (splat, raster)
#                                                      # with each world's DAVE-2 on LEVELS
#                                                      # (1x1,4x1,4x0.5: GPUs x a GPU a run)
#   PHASE=collect bash benchmarks/gpu_bench.sh         # the worlds' bench report
#
# Each call must reach the warm machine within its 30 s idle window. Nothing is carried for the
# two phases here: Ray and the wheels were installed into /tmp/site by gpu_bench.sh's calls.
# $OUT gets ray_scaling.json / campaign_scaling.json and their logs.
case ${PHASE:?set PHASE to splat or campaign} in
splat | campaign) ;;
*)
  echo "PHASE=$PHASE: use splat or campaign (the other phases are gpu_bench.sh's)" >&2
  exit 2
  ;;
esac
WHEELS=
MARKER=/tmp/.gpu_bench_setup
source "$(dirname "$0")/gpu_phase.sh"
export RAY_AUTH_MODE=disabled
worlds=/tmp/bench/worlds
nvidia-smi -L
case $PHASE in
splat)
  python3 benchmarks/splat_ray_scaling.py $worlds/l-street/ws/splat/prep --gpus "${GPUS:-1,2,4}" \
    --replicate "${REPLICATE:-8}" --steps "${STEPS:-2000}" --out "$out/ray_scaling.json" \
    2>&1 | tee "$out/ray_scaling.log"
  ;;
campaign)
  python3 benchmarks/campaign_gpu_scaling.py $worlds/*/ws --levels "${LEVELS:-1x1,4x1,4x0.5}" \
    --seeds 0,1,2 --cameras splat,raster --out "$out/campaign_scaling.json" \
    2>&1 | tee "$out/campaign_scaling.log"
  for level in /tmp/campaign-scaling-*/level-*; do # each level's report, summary and logs
    tar czf "$out/$(basename "$level").tgz" -C "$level" campaign/report.html \
      campaign/summary.json campaign/state.json campaign/logs
  done
  ;;
esac
