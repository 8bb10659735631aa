#!/usr/bin/env bash
# Blender Cycles (CPU) with and without Open PGL path guiding beside Lacuna's `path` and
# `path_skeleton` (and `bdpt`), each alone on the machine for the same time, in turn (A B C D A B C D), on
# family scenes against Lacuna references (`lacuna reference rooms:SEED ...`, path, the same
# size and depth). Usage:
#   PY=VENV/bin/python REFS=DIR benches/cycles/guiding.sh OUT TIME RUNS SEED...
# REFS/ref-SEED.exr is each scene's reference (made here when missing: 4096 spp). PY is a
# Python with `bpy` (PyPI) and `OpenEXR`. WIDTH/HEIGHT (64x48), MAX_DEPTH (65), THREADS (2),
# LACUNA (target/release/lacuna), CONTENDERS (cycles cycles-guided path path_skeleton bdpt:
# Lacuna integrators by name). Writes OUT/errors.txt (benches/cycles/errors.py per image).
# Lacuna's runs use seeds 101, 102, ...: a reference of seed 0 renders its halves with seeds 0
# and 1, and a run that reused one would replay the reference's own samples.
set -euo pipefail
out=$1; time=$2; runs=$3; shift 3
here=$(cd "$(dirname "$0")" && pwd)
W=${WIDTH:-64}; H=${HEIGHT:-48}; D=${MAX_DEPTH:-65}; T=${THREADS:-2}
L=${LACUNA:-target/release/lacuna}; PY=${PY:-python3}; REFS=${REFS:-$out}
mkdir -p "$out" "$REFS"
log() { echo "$(date -u +%H:%M:%S) load $(cut -d' ' -f1-3 /proc/loadavg) $*" | tee -a "$out/log"; }
for seed in "$@"; do
  ref="$REFS/ref-$seed.exr"
  [ -f "$ref" ] || "$L" reference "rooms:$seed" --width "$W" --height "$H" --max-depth "$D" \
    --threads "$T" --spp 4096 --out "$ref" --quiet
  "$L" family "$seed" --out "$out/scene-$seed" > /dev/null
  for run in $(seq 1 "$runs"); do
    for c in ${CONTENDERS:-cycles cycles-guided path path_skeleton bdpt}; do
      img="$out/$seed-$c-$run.exr"
      log "rooms:$seed $c run $run"
      case $c in
        cycles) "$PY" "$here/render.py" "$out/scene-$seed/rooms-$seed.json" "$img" --time "$time" \
          --width "$W" --height "$H" --max-depth "$D" --threads "$T" --seed "$run" > "$img.log" 2>&1;;
        cycles-guided) "$PY" "$here/render.py" "$out/scene-$seed/rooms-$seed.json" "$img" --guiding \
          --time "$time" --width "$W" --height "$H" --max-depth "$D" --threads "$T" --seed "$run" \
          > "$img.log" 2>&1;;
        *) "$L" render "rooms:$seed" --integrator "$c" --width "$W" --height "$H" --max-depth "$D" \
          --threads "$T" --time "$time" --seed $((100 + run)) --out "$img" > "$img.log" 2>&1;;
      esac
    done
  done
  "$PY" "$here/errors.py" "$ref" "$out/$seed"-*.exr | tee -a "$out/errors.txt"
done
log done
