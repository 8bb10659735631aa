#!/usr/bin/env bash
# The pilot's numbers (issue 27, task p27c): `render -v --spp 1` per scene and binary, at the
# compare's image sizes. Usage: pilot_numbers.sh OUT "name=path ..."
out=$1; bins=${2:-"new=target/release/lacuna"}
mkdir -p $out
for sc in ${SCENES:-rooms:3 rooms:17 rooms:30 door corridor}; do
  case $sc in
    door) S=scenes/veach-door-pg2015/veach-door-pg2015.json; A="--width 128 --height 64";;
    corridor) S=corridor; A="--width 128 --height 128";;
    *) S=$sc; A="--width 64 --height 48 --max-depth 65";;
  esac
  for nb in $bins; do
    b=${nb%%=*}; bin=${nb#*=}
    echo "== $(date -u +%H:%M:%S) $(cut -d' ' -f1-3 /proc/loadavg) $sc $b" >> $out/pilot.log
    $bin render $S $A --threads 2 --integrator path_skeleton -v --spp 1 --out $out/${sc/:/}-$b.exr 2>&1 \
      | grep -E "precomputation|pilot \(|scene-level|trained c_skel" | sed 's/^/  /' >> $out/pilot.log
  done
done
