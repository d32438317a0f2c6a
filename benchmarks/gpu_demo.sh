#!/usr/bin/env bash
# `cam2sim demo` on a GPU machine (docs/benchmarks.md, issues 19, 21 and 22), in two calls on
# one warm machine: the wheels the demo needs there (carla, pyproj, gsplat and 17 smaller
# packages, 72 MB) do not fit one call's 64 MiB. Build them here first with
# `bash benchmarks/carry_kit.sh demo lpips`.
#
#   PHASE=setup bash benchmarks/gpu_demo.sh                 # carry .c21/a and .gl
#   [TESTS=1] PHASE=run bash benchmarks/gpu_demo.sh [--runs 3] [--world paper] ...
#                                                           # carry .c21/b, .gl and .c19
#
# The second call must reach the machine within its idle window (30 s) after the first, or it
# finds a fresh machine and says so (exit 3). setup installs the first wheels into /tmp/site
# and builds gsplat (60-80 s); run installs the others, puts the LPIPS weights in the cache,
# runs benchmarks/demo.py (its arguments after the script's), and writes $OUT/demo_gpu.json,
# $OUT/demo.log and the demo's HTML report ($OUT/report.tgz); with TESTS=1, after the demo (so
# they do not change its timing), the CUDA training tests too ($OUT/tests.txt).
case ${PHASE:?set PHASE to setup or run} in
setup) WHEELS=.c21/a ;;
run)
  if [ ! -f /tmp/.gpu_demo_setup ]; then
    echo "this machine is fresh (the one set up went back): run PHASE=setup again first" >&2
    exit 3
  fi
  WHEELS=.c21/b
  ;;
*)
  echo "PHASE=$PHASE: use setup or run" >&2
  exit 2
  ;;
esac
source "$(dirname "$0")/gpu_env.sh"  # installs $WHEELS into /tmp/site, sets PYTHONPATH and $out
for deb in .gl/*.deb; do dpkg -x "$deb" /; done  # the EGL loader (device README)
ldconfig
export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
export CAM2SIM_CACHE=/tmp/cam2sim_cache
if [ "$PHASE" = setup ]; then
  python3 -c "from cam2sim.splat.raster import build_gsplat; build_gsplat()" || exit 1
  touch /tmp/.gpu_demo_setup || exit 1
  exit 0
fi
mkdir -p "$CAM2SIM_CACHE/lpips"
cp .c19/alexnet.ckpt "$CAM2SIM_CACHE/lpips/"
rm -rf /tmp/gdemo
python3 benchmarks/demo.py /tmp/gdemo --json "$out/demo_gpu.json" "$@" > "$out/demo.log" 2>&1
rc=$?
tar czf "$out/report.tgz" -C /tmp/gdemo/ws report 2>/dev/null
tail -n 40 "$out/demo.log"
if [ -n "$TESTS" ]; then
  python3 benchmarks/cuda_tests.py > "$out/tests.txt" 2>&1 || rc=1
  grep -E "PASSED|FAILED|SKIPPED" "$out/tests.txt"
fi
exit $rc
