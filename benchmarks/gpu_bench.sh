#!/usr/bin/env bash
# `cam2sim bench` on a GPU machine through a local Ray instance, one GPU a world (issue 37;
# docs/benchmarks.md, "The street benchmark"). The wheels do not fit one call's 64 MiB, and the
# suite outlasts one call's 10 minutes, so it runs in several calls on one warm machine (each
# must reach it within its 30 s idle window):
#
#   PHASE=setup bash benchmarks/gpu_bench.sh        # carry .c21/a .gl .osm: wheels, gsplat build,
#                                                   # the extracts copied to /tmp/osm
#   PHASE=start bash benchmarks/gpu_bench.sh        # carry .c21/b .ray: the rest, then the suite
#                                                   # starts in the background and is watched
#   PHASE=wait bash benchmarks/gpu_bench.sh         # carry .gl: watch it (repeat as needed)
#   PHASE=collect bash benchmarks/gpu_bench.sh      # pack what is there into $OUT (also when
#                                                   # unfinished: the report covers the worlds done)
#   PHASE=slots WORLD=munich-r2 bash benchmarks/gpu_bench.sh  # after it: a finished world's
#                 # prepared scene trained again at LEVELS (default 1,3) chunks at a time, 5,000
#                 # steps each, phases timed: benchmarks/splat_concurrency.py, into $OUT/slots.json
#                 # (PREP=DIR: a prepared scene put on the machine instead of a world's)
#   PHASE=cost WORLD=munich-r2 [CHUNKS="0 1"] bash benchmarks/gpu_bench.sh  # a finished world's
#                 # trained chunks: tile/Gaussian pairs a view by depth and screen radius, and
#                 # the render and backward time at 8x8 tiles (benchmarks/splat_raster_cost.py),
#                 # into $OUT/cost-WORLD-CHUNK.json
#
# Build the carried folders here first: `bash benchmarks/carry_kit.sh demo ray osm`.
# SUITE (default benchmarks/suites/streets-gpu.yaml) names the suite; its OSM files are looked for
# in /tmp/osm by name. WORKERS=N (one-GPU machines) runs N worlds at a time on the local
# pool, sharing the GPU, instead of Ray's one GPU a world; its start call then carries .c21/b
# only. The worlds share the GPU's memory too: each trains as many splat chunks at a time as its
# share holds (one each for three or more worlds on an H100; five worlds with two each ran it
# out of memory, docs/benchmarks.md "Five worlds on one H100"). Start and wait watch until the call has run WATCH_S seconds (default 560, counted
# from the script's start, so the wheels' install of the start call is inside it), then return.
# RESULTS="DIR..." (start): folders of earlier results (DIR/worlds/LABEL/result.json, as
# docs/results/issue37-gpu-recheck/a) are put in place first, so the suite runs only the
# worlds still missing and the report covers all (a suite split over one-GPU sessions). A
# result another version of its world made (other settings or seeds: its spec_id differs) is
# set aside as result.HASH.json and that world runs again.
# A machine can be taken back mid-call ("taken back for other work"), and /tmp with it: a
# multi-world suite watched over several calls then loses every world it finished. Where that
# matters, run a world a call, starting and collecting in the same call (the one-world suites
# streets-gpu-capped-munich-r2.yaml and -r3.yaml show how), and give the next call RESULTS.
# Everything the suite reads lives in /tmp on the device: a carried folder that a later call does
# not carry again is removed there, so .osm/ vanished under the first GPU suite's running worlds.
# ENTRY=i (start) runs the suite's i-th world entry alone (streets-gpu-equal.yaml: one world a
# call from one suite); ENTRY=i,j,... keeps those entries (with WORKERS=2, two worlds at a time
# sharing the GPU and its 16 cores: twice the worlds a session, each world's time then shared).
# Measured on an H100 (2026-12-07): two worlds a call 345-375 s, three 557 s (too near the
# 600 s a call: collect may find the last world unfinished; then PHASE=wait and collect again).
# BENCH (default /tmp/bench) is the benchmark folder on the device: a second suite in the same
# session gets its own (BENCH=/tmp/bench2 for its start, wait and collect).
# CAM2SIM_SPLAT_PROFILE=1 on the start call times each training step's phases (host and device,
# cam2sim.splat.profiling); collect packs each chunk's result (phase_ms) with the worlds'.
# The LPIPS weights do not fit the start call (the splats' LPIPS is then not computed; the
# bench reads PSNR and SSIM only).
case ${PHASE:?set PHASE to setup, start, wait, collect, slots or cost} in
setup) WHEELS=.c21/a ;;
start) WHEELS=.c21/b ;;
wait | collect | slots | cost) WHEELS= ;;
*)
  echo "PHASE=$PHASE: use setup, start, wait, collect, slots or cost" >&2
  exit 2
  ;;
esac
MARKER=/tmp/.gpu_bench_setup
source "$(dirname "$0")/gpu_phase.sh"
export RAY_AUTH_MODE=disabled
bench=${BENCH:-/tmp/bench}
watch() { # until the bench process ends or the call has run WATCH_S seconds: one line a minute
  local until=${WATCH_S:-560}
  while [ $SECONDS -lt $until ]; do
    done_n=$(ls $bench/worlds/*/result.json 2>/dev/null | wc -l)
    echo "$(date +%H:%M:%S) worlds with a result: $done_n; $(nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv,noheader | tr '\n' ' ')"
    if ! pgrep -f "cam2sim bench" > /dev/null; then
      echo "the bench process has ended"
      tail -n 30 $bench.log
      return 0
    fi
    local left=$((until - SECONDS))
    sleep $((left < 60 ? (left > 0 ? left : 1) : 60))
  done
}
case $PHASE in
setup)
  python3 -c "from cam2sim.splat.raster import build_gsplat; build_gsplat()" || exit 1
  mkdir -p /tmp/osm && cp .osm/* /tmp/osm/ || exit 1
  python3 -c "import lzma, pathlib
for p in pathlib.Path('/tmp/osm').glob('*.osm.xz'):
    p.with_suffix('').write_bytes(lzma.decompress(p.read_bytes())); p.unlink()" || exit 1
  touch "$MARKER" || exit 1
  ;;
start)
  if [ -n "$WORKERS" ]; then
    pool=(--workers "$WORKERS")
  else
    tar xJf .ray/ray-slim.tar.xz -C /tmp/site || exit 1
    python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .ray/*.whl || exit 1
    pool=(--ray local)
  fi
  for done in $RESULTS; do
    for result in "$done"/worlds/*/result.json; do
      mkdir -p "$bench/worlds/$(basename "$(dirname "$result")")" || exit 1
      cp "$result" "$bench/worlds/$(basename "$(dirname "$result")")/" || exit 1
    done
  done
  [ -n "$RESULTS" ] && echo "worlds with a result already: $(ls $bench/worlds/*/result.json | wc -l)"
  suite=${SUITE:-benchmarks/suites/streets-gpu.yaml}
  sed -E 's#osm: .*/([^/]+)$#osm: /tmp/osm/\1#' "$suite" > /tmp/suite.yaml
  if [ -n "$ENTRY" ]; then # the suite's ENTRY-th world entry alone (or entries i,j,...)
    python3 -c "import sys, yaml
s = yaml.safe_load(open('/tmp/suite.yaml'))
s['worlds'] = [s['worlds'][int(i)] for i in sys.argv[1].split(',')]
yaml.safe_dump(s, open('/tmp/suite.yaml', 'w'), sort_keys=False)" "$ENTRY" || exit 1
  fi
  grep -n "osm:" /tmp/suite.yaml
  setsid nohup python3 -m cam2sim bench /tmp/suite.yaml -o $bench "${pool[@]}" \
    > $bench.log 2>&1 < /dev/null &
  sleep 5
  watch
  ;;
wait) watch ;;
slots)
  pkill -f "cam2sim bench" && sleep 5 # the GPU to itself
  steps=${STEPS:-5000}
  prep=${PREP:-$bench/worlds/${WORLD:?name a finished world, or PREP a prepared scene}/ws/splat/prep}
  python3 benchmarks/splat_gpu.py --prep "$prep" \
    --concurrency "${LEVELS:-1,3}" --max-steps "$steps" --min-steps "$steps" --set val_every=250 \
    --set profile=true --out "$out/slots.json"
  ;;
cost)
  ws=$bench/worlds/${WORLD:?name a finished world}/ws
  for chunk in ${CHUNKS:-0}; do
    python3 benchmarks/splat_raster_cost.py --prep "$ws/splat/prep" \
      --model "$ws/splat/models/chunk_$(printf %02d "$chunk").pt" --tiles 8 --views 32 \
      --out "$out/cost-$WORLD-$chunk.json" || exit 1
  done
  ;;
collect)
  tail -n 40 $bench.log
  if ! pgrep -f "cam2sim bench" > /dev/null && [ ! -f $bench/report.html ]; then
    echo "no report yet" >&2
  fi
  if pgrep -f "cam2sim bench" > /dev/null; then # unfinished: a report over the worlds done
    python3 - << 'EOF'
import os
from pathlib import Path
from cam2sim.metrics.benchmark import WorldResult, aggregate
from cam2sim.report.bench import write_bench_report
folder = Path(os.environ.get("BENCH", "/tmp/bench"))
results = [WorldResult.load(p) for p in sorted(folder.glob("worlds/*/result.json"))]
import yaml
from cam2sim.campaign.state import CampaignState
name = yaml.safe_load(Path("/tmp/suite.yaml").read_text())["name"]
state = CampaignState.load_or_new(folder / "state.json", name)
done = {r.label for r in results}
missing = {r.workspace: r.error or r.status for r in state.runs.values() if r.workspace not in done}
for world in sorted(p.name for p in folder.glob("worlds/*")):  # started, not yet ended
    if world not in done and world not in missing:
        missing[world] = "still running when the report was made"
write_bench_report(folder, results, aggregate(results), missing=missing, name=f"{name} (unfinished)")
EOF
  fi
  cp $bench.log "$out/bench.log"
  cp $bench/report.html "$out/report.html" 2>/dev/null
  tar czf "$out/bench.tgz" -C $bench summary.md aggregate.json state.json tables \
    $(cd $bench && ls worlds/*/result.json logs/*.log 2>/dev/null) \
    $(cd $bench && find worlds -path '*/models/results/chunk_*.json' 2>/dev/null)
  ls -la "$out"
  ;;
esac
