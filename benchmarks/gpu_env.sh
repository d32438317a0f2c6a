# Sourced by the GPU scripts (gpu_sweep.sh, gpu_route.sh, gpu_demo.sh, gpu_phase.sh): install
# the carried wheels ($WHEELS) into /tmp/site, put them and src/ on PYTHONPATH, and make $out (the call's $OUT).
set -o pipefail
export PYTHONUNBUFFERED=1 MAX_JOBS=${MAX_JOBS:-16}
: "${WHEELS:?set WHEELS to the folder of wheels}"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
  --target /tmp/site "$WHEELS"/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD/src
out=${OUT:-/tmp/out}
mkdir -p "$out"
