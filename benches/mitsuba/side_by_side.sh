#!/usr/bin/env bash
# Lacuna and Mitsuba 3 on the same scene, same threads, same time, one reference.
#
#   benches/mitsuba/side_by_side.sh LACUNA_BINARY REFERENCE.exr SECONDS [OUTDIR]
#
# Environment: PY (default /work/mitsuba-venv/bin/python), SCENE (default
# scenes/cornell-box/cornell-box.json), THREADS (2), SEED (1), MTS_SAMPLER (independent),
# MTS_PASS_SPP (16), LACUNA_FACTOR (3: Lacuna's compare runs LACUNA_FACTOR x SECONDS so that
# its curve reaches Mitsuba's error), LACUNA_INTEGRATOR (path; e.g. path:rr_depth=auto). Run from the repository root. Prints both renderers'
# summary lines, their errors against the reference, and Lacuna's MAE after Mitsuba's seconds
# (within half a pass of SECONDS) and its
# time to reach Mitsuba's MAE (from its compare curve).
set -euo pipefail
LACUNA=$1 REF=$2 T=$3 OUT=${4:-/tmp/side_by_side}
PY=${PY:-/work/mitsuba-venv/bin/python}
SCENE=${SCENE:-scenes/cornell-box/cornell-box.json}
THREADS=${THREADS:-2} SEED=${SEED:-1} FACTOR=${LACUNA_FACTOR:-3}
INTEGRATOR=${LACUNA_INTEGRATOR:-path}
export DRJIT_LIBLLVM_PATH=${DRJIT_LIBLLVM_PATH:-/usr/lib/x86_64-linux-gnu/libLLVM-19.so}
DIR=$(dirname "$0")
mkdir -p "$OUT"
"$PY" "$DIR/convert.py" "$SCENE" "$OUT/mitsuba-scene" > /dev/null
echo "load before: $(cut -d' ' -f1-3 /proc/loadavg)"
"$PY" "$DIR/render.py" "$OUT/mitsuba-scene/scene.xml" "$OUT/mitsuba.exr" --time "$T" \
    --threads "$THREADS" --seed "$SEED" --sampler "${MTS_SAMPLER:-independent}" \
    --pass-spp "${MTS_PASS_SPP:-16}" | tee "$OUT/mitsuba.log"
MTS_SECONDS=$(sed 's/.* path in \([0-9.]*\) s:.*/\1/' "$OUT/mitsuba.log")
"$LACUNA" render "$SCENE" --integrator "$INTEGRATOR" --time "$T" --threads "$THREADS" --seed "$SEED" --quiet --out "$OUT/lacuna.exr"
"$LACUNA" compare "$SCENE" --integrators "$INTEGRATOR" --time "$(awk "BEGIN { print $T * $FACTOR }")" --runs 1 \
    --threads "$THREADS" --seed "$SEED" --reference "$REF" --out "$OUT/compare" --quiet > "$OUT/compare.log"
echo "load after: $(cut -d' ' -f1-3 /proc/loadavg)"
"$PY" "$DIR/mae.py" "$REF" "$OUT/mitsuba.exr" "$OUT/lacuna.exr" | tee "$OUT/mae.txt"
MTS_MAE=$(grep "mitsuba.exr" "$OUT/mae.txt" | sed 's/.*MAE \([^ ]*\) .*/\1/')
echo "Lacuna (compare curve, $FACTOR x $T s), at Mitsuba's $MTS_SECONDS s and to Mitsuba's MAE:"
"$PY" "$DIR/crossing.py" "$OUT/compare/curves.csv" "$MTS_SECONDS" "$MTS_MAE" "$INTEGRATOR"
