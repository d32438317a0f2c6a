#!/usr/bin/env bash
# KITTI odometry 03 end to end on one GPU (issue 38; docs/real-recordings.md): import the 801
# grey frames with their poses and K, then `cam2sim run` (map from the driven path, splat on
# the GPU, DAVE-2, Real / splat / Sim drives, report). The frames (217 MB as PNG) do not fit
# one call's 64 MiB, so they travel as JPEG (quality 90, 106 MB) in three parts, each copied to
# /tmp/kitti03 on the device; the calls must follow each other within the 30 s idle window:
#
#   PHASE=setup bash benchmarks/gpu_kitti.sh     # carry .c21/a .gl: wheels, gsplat build
#   PHASE=frames bash benchmarks/gpu_kitti.sh    # carry .k03/a (then again with .k03/b, and
#                                                # with .k03/p: the pycolmap wheel); .c19
#                                                # beside .k03/a brings the LPIPS weights
#                                                # (without them the report has no LPIPS)
#   PHASE=run bash benchmarks/gpu_kitti.sh       # carry .c21/k .k03/c: the rest, then the run
#                                                # in the background, watched WATCH_S seconds
#                                                # (`cam2sim -v`: the log also has each chunk
#                                                # worker's set-up times and DAVE-2's epochs)
#                                                # (RUN_ARGS: more `cam2sim run` options, e.g.
#                                                # --recorded-speed, the default for KITTI)
#                                                # (POSES=gps: KITTI's poses as GPS fixes,
#                                                # benchmarks/gps_fixes.py, imported as a
#                                                # GPS logger's CSV: no orientation)
#   PHASE=wait bash benchmarks/gpu_kitti.sh      # watch it (repeat as needed; COLLECT=1:
#                                                # collect as well once it has ended)
#   PHASE=collect bash benchmarks/gpu_kitti.sh   # $OUT: the log, report.html, the workspace's
#                                                # JSON records (kitti.tgz), the closed
#                                                # loop's frames and drives (loop.tgz),
#                                                # the splat tilted vs level (tilt.txt)
#   PHASE=prep bash benchmarks/gpu_kitti.sh --config run:densify.strategy=mcmc,...
#                                                # instead of run (carry .c21/k .k03/c): import
#                                                # and prepare the scene only (BUNDLE=1, the
#                                                # default: bundle-adjusted as `run
#                                                # --bundle-adjust`; 0: as recorded), then the
#                                                # sweep below on it, in one call
#   PHASE=sweep bash benchmarks/gpu_kitti.sh --config base: --config mcmc:densify.strategy=mcmc
#                                                # after a run: splat_sweep.py on one chunk of
#                                                # the run's prepared scene (CHUNK, default 0;
#                                                # STEPS, EVALS; LIMIT seconds, default 480),
#                                                # settings side by side, $OUT/sweep.json
#
# Build the carried folders here first: `bash benchmarks/carry_kit.sh demo kitti` (kitti needs
# the sequence: KITTI03=/path/with/images bash benchmarks/carry_kit.sh kitti). KITTI is
# CC BY-NC-SA 3.0: .k03/ stays out of git (.git/info/exclude).
case ${PHASE:?set PHASE to setup, frames, run, prep, wait, collect or sweep} in
setup) WHEELS=.c21/a ;;
run | prep) WHEELS=.c21/k ;;
frames | wait | collect | sweep) WHEELS= ;;
*)
  echo "PHASE=$PHASE: use setup, frames, run, prep, wait, collect or sweep" >&2
  exit 2
  ;;
esac
MARKER=/tmp/.gpu_kitti_setup
source "$(dirname "$0")/gpu_phase.sh"
ws=/tmp/kitti_ws
watch() { # until the run ends (checked every 5 s) or WATCH_S passes: one line a minute
  local until=$((SECONDS + ${WATCH_S:-560})) next=0
  while [ $SECONDS -lt $until ]; do
    if ! pgrep -f "cam2sim.* run -o" > /dev/null; then
      echo "the run has ended"
      tail -n 40 /tmp/kitti.log
      return 0
    fi
    if [ $SECONDS -ge $next ]; then
      echo "$(date +%H:%M:%S) $(tail -n 1 /tmp/kitti.log)"
      next=$((SECONDS + 60))
    fi
    sleep 5
  done
}
collect() { # $OUT: the log, the report, the records, the closed loop, the tilt
  tail -n 60 /tmp/kitti.log
  cp /tmp/kitti.log "$out/kitti.log"
  cp $ws/report/report.html "$out/report.html" 2>/dev/null
  tar czf "$out/kitti.tgz" -C $ws workspace.json map/map_report.json splat/eval.json \
    ads/train_report.json report/drive/metrics.json report/drive/behaviour.md \
    $(cd $ws && ls splat/models/*.json report/tables/* report/images/*/steering.json \
      report/images/*/images.json 2>/dev/null)
  # What the closed loop saw and did: every 8th replay frame of each camera (JPEG), each
  # drive's steering, trajectory and events, and the network, to study DAVE-2 here.
  mkdir -p "$out/loop" && cp $ws/ads/dave2.onnx $ws/ads/dave2.json "$out/loop/"
  python3 - "$ws" "$out/loop" << 'PY'
import shutil, sys
from pathlib import Path
import cv2
ws, dst = Path(sys.argv[1]), Path(sys.argv[2])
for run in sorted((ws / "runs").iterdir()):
    for name in ("steering.csv", "trajectory.csv", "events.json"):
        if (run / name).is_file():
            (dst / run.name).mkdir(exist_ok=True)
            shutil.copy(run / name, dst / run.name / name)
    for cam in sorted((run / "frames").glob("*")) if "replay" in run.name else []:
        (dst / "replay" / cam.name).mkdir(parents=True, exist_ok=True)
        for f in sorted(cam.glob("*.png"))[::8]:
            img = cv2.imread(str(f))
            cv2.imwrite(str(dst / "replay" / cam.name / f"{f.stem}.jpg"), img,
                        [cv2.IMWRITE_JPEG_QUALITY, 90])
PY
  tar czf "$out/loop.tgz" -C "$out" loop && rm -rf "$out/loop"
  # The splat at every 8th recorded sample, its camera tilted as recorded or level (the hill);
  # TILT=0 leaves it out (about 40 s of device time).
  if [ "${TILT:-1}" != 0 ]; then
    python3 benchmarks/splat_tilt.py $ws --device cuda > "$out/tilt.txt" 2>&1
    tail -n 2 "$out/tilt.txt"
  fi
  ls -la "$out"
}
case $PHASE in
setup)
  python3 -c "from cam2sim.splat.raster import build_gsplat; build_gsplat()" || exit 1
  mkdir -p /tmp/kitti03/images && touch "$MARKER"
  ;;
frames)
  for part in .k03/*/; do cp "$part"images/* /tmp/kitti03/images/ 2>/dev/null; done
  if [ -f .c19/alexnet.ckpt ]; then
    mkdir -p "$CAM2SIM_CACHE/lpips" && cp .c19/alexnet.ckpt "$CAM2SIM_CACHE/lpips/"
  fi
  for wheel in .k03/*/*.whl; do
    [ -f "$wheel" ] && python3 -m pip install -q --no-index --no-deps --no-compile \
      --no-cache-dir --upgrade --target /tmp/site "$wheel"
  done
  ls /tmp/kitti03/images | wc -l
  python3 -c "import pycolmap; print('pycolmap', pycolmap.__version__)" 2>&1 | tail -1
  ;;
run)
  cp .k03/c/images/* /tmp/kitti03/images/ && cp .k03/c/poses.txt .k03/c/K.txt /tmp/kitti03/ || exit 1
  echo "frames: $(ls /tmp/kitti03/images | wc -l) (801 wanted)"
  poses=/tmp/kitti03/poses.txt
  if [ "${POSES:-kitti}" = gps ]; then # KITTI's poses as a GPS logger's fixes (no orientation)
    python3 benchmarks/gps_fixes.py --poses $poses --out /tmp/kitti03/gps.csv || exit 1
    poses=/tmp/kitti03/gps.csv
  fi
  setsid nohup bash -c "time (python3 -m cam2sim import $ws --images /tmp/kitti03/images \
    --poses $poses --calibration /tmp/kitti03/K.txt --fps 10 \
    --pose-offset fit,0,1.65 && python3 -m cam2sim -v run -o $ws ${RUN_ARGS:-})" > /tmp/kitti.log 2>&1 < /dev/null &
  sleep 5
  watch
  ;;
wait) # COLLECT=1: collect too once the run has ended (saves a call)
  watch
  if [ -n "${COLLECT:-}" ] && ! pgrep -f "cam2sim.* run -o" > /dev/null; then collect; fi
  ;;
collect) collect ;;
prep)
  cp .k03/c/images/* /tmp/kitti03/images/ && cp .k03/c/poses.txt .k03/c/K.txt /tmp/kitti03/ || exit 1
  python3 -m cam2sim import $ws --images /tmp/kitti03/images --poses /tmp/kitti03/poses.txt \
    --calibration /tmp/kitti03/K.txt --fps 10 --pose-offset fit,0,1.65 > /tmp/kitti.log 2>&1 || exit 1
  python3 - "$ws" "${BUNDLE:-1}" << 'PY' 2>&1 | tail -n 8
import sys, time
from cam2sim.core.workspace import Workspace
from cam2sim.splat.prepare import PrepareOptions, prepare_scene
start = time.perf_counter()
scene = prepare_scene(Workspace.open(sys.argv[1]),
                      options=PrepareOptions(triangulate=True, refine_poses=sys.argv[2] == "1"))
print(f"prepared in {time.perf_counter() - start:.0f} s:", *scene.notes, sep="\n  ")
PY
  [ -f $ws/splat/prep/scene.json ] || exit 1
  python3 benchmarks/splat_sweep.py --prep $ws/splat/prep --chunk "${CHUNK:-0}" \
    --steps "${STEPS:-10000}" --eval-at "${EVALS:-5000,10000}" \
    --deadline "${LIMIT:-300}" --work /tmp/kitti_sweep --out "$out/sweep.json" "$@"
  ;;
sweep)
  [ -f $ws/splat/prep/scene.json ] || { echo "no prepared scene in $ws: PHASE=run first" >&2; exit 1; }
  python3 benchmarks/splat_sweep.py --prep $ws/splat/prep --chunk "${CHUNK:-0}" \
    --steps "${STEPS:-12000}" --eval-at "${EVALS:-4000,7000,10000,12000}" \
    --deadline "${LIMIT:-480}" --work /tmp/kitti_sweep --out "$out/sweep.json" "$@"
  ;;
esac
