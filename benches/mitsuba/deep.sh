#!/usr/bin/env bash
# Lacuna's `path` beside Mitsuba 3 on deep paths (issue 30): a closed family interior
# (`lacuna family SEED`) and the Cornell box, both at max depth 65, same threads, same time,
# one reference each (`lacuna reference`, REF_SPP samples).
#
#   benches/mitsuba/deep.sh LACUNA_BINARY SECONDS OUTDIR [SEED]
#
# Environment: as side_by_side.sh (PY, THREADS, ...), plus REF_SPP (default 2048), WIDTH x
# HEIGHT of the interior (default 128x96, the issue's setting), CORNELL_SIZE (default 128) and
# SCENES (default "rooms cornell": which of the two to run).
# Run from the repository root.
set -euo pipefail
LACUNA=$1 T=$2 OUT=$3 SEED=${4:-3}
REF_SPP=${REF_SPP:-2048} W=${WIDTH:-128} H=${HEIGHT:-96} C=${CORNELL_SIZE:-128}
THREADS=${THREADS:-2}
DIR=$(dirname "$0")
mkdir -p "$OUT/scenes"
# The family scene file has no render settings: add them (Mitsuba's converter needs them).
"$LACUNA" family "$SEED" --out "$OUT/scenes" > /dev/null
room="$OUT/scenes/rooms-$SEED.json"
python3 - "$room" "$W" "$H" <<'PY'
import json, sys
path, w, h = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
scene = json.load(open(path))
scene["render"] = {"width": w, "height": h, "max_depth": 65, "integrator": "path"}
json.dump(scene, open(path, "w"), indent=1)
PY
cornell="$OUT/scenes/cornell-deep.json"
cp scenes/cornell-box/CornellBox-Original.* "$OUT/scenes/"
python3 - scenes/cornell-box/cornell-box.json "$cornell" "$C" <<'PY'
import json, sys
scene = json.load(open(sys.argv[1]))
c = int(sys.argv[3])
scene["render"] = {"width": c, "height": c, "max_depth": 65, "integrator": "path"}
json.dump(scene, open(sys.argv[2], "w"), indent=1)
PY
list=()
for s in ${SCENES:-rooms cornell}; do
  case $s in rooms) list+=("$room") ;; cornell) list+=("$cornell") ;; *) echo "unknown scene $s" >&2; exit 2 ;; esac
done
for scene in "${list[@]}"; do
  name=$(basename "$scene" .json)
  ref="$OUT/$name-reference.exr"
  if [ ! -f "$ref" ]; then
    "$LACUNA" reference "$scene" --threads "$THREADS" --spp "$REF_SPP" --out "$ref" --quiet
  fi
  echo "== $name"
  SCENE=$scene "$DIR/side_by_side.sh" "$LACUNA" "$ref" "$T" "$OUT/$name"
done
