#!/usr/bin/env bash
# Equal-time comparison of path, path_skeleton and bdpt on family scenes rooms:SEED.
# Usage: benches/family/run.sh OUT_DIR TIME_SECONDS RUNS SEED...
# Environment: WIDTH, HEIGHT (default 128x96), REF_SPP (default 8192), MAX_DEPTH (default 65),
# THREADS (default 2), LACUNA (default target/release/lacuna), INTEGRATORS (default
# path,path_skeleton,bdpt), CONCURRENT=1 (run the integrators of each run at the same time, so
# that all meet the same machine load: `lacuna compare --concurrent`).
# For each seed: a reference (`lacuna reference`, path), then `lacuna compare` with
# --reference; OUT_DIR/rooms-SEED/summary.md holds the MSE per contender. Collect the table
# with benches/family/table.sh OUT_DIR.
set -euo pipefail
out=$1; time=$2; runs=$3; shift 3
W=${WIDTH:-128}; H=${HEIGHT:-96}; REF=${REF_SPP:-8192}; D=${MAX_DEPTH:-65}; T=${THREADS:-2}
L=${LACUNA:-target/release/lacuna}
INTEGRATORS=${INTEGRATORS:-path,path_skeleton,bdpt}
schedule=(); [ "${CONCURRENT:-0}" = 1 ] && schedule=(--concurrent)
mkdir -p "$out"
for seed in "$@"; do
  dir="$out/rooms-$seed"; mkdir -p "$dir"
  "$L" family "$seed" > "$dir/description.txt"
  ref="$dir/reference.exr"
  if [ ! -f "$ref" ]; then
    "$L" reference "rooms:$seed" --width "$W" --height "$H" --max-depth "$D" --threads "$T" \
      --spp "$REF" --out "$ref" --quiet > "$dir/reference.log" 2>&1
  fi
  "$L" compare "rooms:$seed" --width "$W" --height "$H" --max-depth "$D" --threads "$T" \
    --integrators "$INTEGRATORS" --time "$time" --runs "$runs" --reference "$ref" \
    "${schedule[@]}" --out "$dir" --quiet > "$dir/compare.log" 2>&1
  echo "rooms:$seed done"
done
