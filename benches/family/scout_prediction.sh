#!/usr/bin/env bash
# The training's prediction on the scout's paths (training_paths=16384, no pilot) and the
# full training's, per scene. Usage: scout_prediction.sh BIN SPEC-SUFFIX
bin=$1; suf=$2
for sc in ${SCENES:-rooms:3 rooms:17 rooms:30 door corridor}; do
  case $sc in
    door) S=scenes/veach-door-pg2015/veach-door-pg2015.json; A="--width 128 --height 64";;
    corridor) S=corridor; A="--width 128 --height 128";;
    *) S=$sc; A="--width 64 --height 48 --max-depth 65";;
  esac
  echo "== $sc $suf"
  $bin render $S $A --threads 2 --integrator path_skeleton$suf -v --spp 1 --out "$(mktemp --suffix .exr)" 2>&1 | grep -E "pilot \(|scene-level|trained c_skel" | sed 's/^path_skeleton: /  /'
done
