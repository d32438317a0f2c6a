# Sourced by the GPU scripts that run in phases on one warm machine (gpu_bench.sh, gpu_kitti.sh),
# after they set PHASE, WHEELS (the carried wheels to install this call; empty: none) and MARKER
# (the file their setup phase leaves on the machine). Refuses a fresh machine past setup, puts
# the installed wheels and src/ on PYTHONPATH, unpacks the EGL loader (device README), sets the
# cache; $out is the call's $OUT.
if [ "$PHASE" != setup ] && [ ! -f "$MARKER" ]; then
  echo "this machine is fresh (the one set up went back): run PHASE=setup again first" >&2
  exit 3
fi
export PYTHONUNBUFFERED=1 MAX_JOBS=${MAX_JOBS:-16}
if [ -n "$WHEELS" ]; then
  source "$(dirname "${BASH_SOURCE[0]}")/gpu_env.sh" # installs $WHEELS into /tmp/site, sets $out
else
  export PYTHONPATH=/tmp/site:$PWD/src
  out=${OUT:-/tmp/out}
  mkdir -p "$out"
fi
for deb in .gl/*.deb; do [ -f "$deb" ] && dpkg -x "$deb" /; done
ldconfig
export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
export CAM2SIM_CACHE=/tmp/cam2sim_cache
