#!/usr/bin/env bash
# One call on a GPU machine (docs/benchmarks.md, issues 19 and 22): install the carried wheels,
# build gsplat, and train and score the 1,500-frame route (benchmarks/splat_route.py) with
# today's defaults; with CLASSIC=1 and a second GPU, the same without the antialiasing filter
# beside it (the same-call baseline); with TESTS=1 the CUDA training tests too (called directly:
# the tests' conftest needs packages the GPU image lacks), and benchmarks/adam_guard.py (what
# the NaN guard costs an optimizer step on a million Gaussians): on a third and a fourth GPU
# beside the routes, or on GPU 0 after them where the machine has fewer (so they do not share
# a GPU with a route and change its timing).
#
#   WHEELS=.c19w ROUTE=.carry/route400tri CKPT=.c19/alexnet.ckpt CLASSIC=1 TESTS=1 \
#       bash benchmarks/gpu_route.sh          # carry .c19w, .c19/alexnet.ckpt, .carry/route400tri
#
# Writes $OUT/route_default.json (and route_classic.json, tests.txt) and their logs. About
# 285 s of training a run on an H100, plus the build (60-80 s) and the resize of 1,500 frames.
: "${ROUTE:?set ROUTE to the prepared route}"
source "$(dirname "$0")/gpu_env.sh"
python3 -c "from cam2sim.splat.raster import build_gsplat; build_gsplat()" || exit 1
gpus=$(python3 -c "import torch; print(torch.cuda.device_count())")
lpips=(--no-lpips)
if [ -n "$CKPT" ]; then lpips=(--lpips-weights "$CKPT"); fi
route() {  # NAME GPU [--set KEY=VALUE ...]
  local name=$1 gpu=$2
  shift 2
  CUDA_VISIBLE_DEVICES=$gpu python3 benchmarks/splat_gpu.py --prep "$ROUTE" --resize 480x300 \
    --resized-dir "/tmp/r400_$name" "${lpips[@]}" --fps-frames 0 --no-offsets \
    --models "/tmp/models_$name" --max-steps 6500 --min-steps 6000 --set val_every=1000 \
    --clock-every 1000 --out "$out/route_$name.json" "$@" > "$out/route_$name.log" 2>&1
}
route default 0 &
if [ -n "$CLASSIC" ] && [ "$gpus" -ge 2 ]; then route classic 1 --set antialiased=false & fi
cuda_tests() {  # GPU: the CUDA training tests
  CUDA_VISIBLE_DEVICES=$1 python3 benchmarks/cuda_tests.py > "$out/tests.txt" 2>&1
}
guard() {  # GPU: what the trainer's NaN guard costs a step
  CUDA_VISIBLE_DEVICES=$1 python3 benchmarks/adam_guard.py --gaussians 1000000 --device cuda \
    --out "$out/adam_guard.json" > "$out/adam_guard.log" 2>&1
}
if [ -n "$TESTS" ] && [ "$gpus" -ge 3 ]; then cuda_tests 2 & fi
if [ -n "$TESTS" ] && [ "$gpus" -ge 4 ]; then guard 3 & fi
wait
if [ -n "$TESTS" ] && [ "$gpus" -lt 3 ]; then cuda_tests 0; fi
if [ -n "$TESTS" ] && [ "$gpus" -lt 4 ]; then guard 0; fi
tail -n 3 "$out"/route_*.log
[ -f "$out/adam_guard.json" ] && cat "$out/adam_guard.json"
[ -f "$out/tests.txt" ] && grep -E "PASSED|FAILED|SKIPPED" "$out/tests.txt"
exit 0
