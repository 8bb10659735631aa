#!/usr/bin/env bash
# Five-scene A/B for issue 27 (task p27c), both contenders at once.
# Usage: pilot_ab.sh OUT TIME RUNS [BINS]   BINS: space-separated "name=path" pairs, run in turn per scene
# (default: new=target/release/lacuna).
out=$1; t=$2; runs=$3
bins=${4:-"new=target/release/lacuna"}
R=${REFS:-refs}
for sc in ${SCENES:-rooms:3 rooms:17 rooms:30 door corridor}; do
  case $sc in
    door) S=scenes/veach-door-pg2015/veach-door-pg2015.json; A="--width 128 --height 64"; ref=$R/door.exr;;
    corridor) S=corridor; A="--width 128 --height 128"; ref=$R/corridor.exr;;
    *) S=$sc; A="--width 64 --height 48 --max-depth 65"; ref=$R/rooms${sc#rooms:}.exr;;
  esac
  for nb in $bins; do
    b=${nb%%=*}; bin=${nb#*=}
    d=$out/$b/${sc/:/}; mkdir -p $d
    echo "$(date -u +%H:%M:%S) $(cut -d' ' -f1-3 /proc/loadavg) $sc $b" >> $out/log
    $bin compare $S $A --threads 2 --integrators path,path_skeleton --time $t --runs $runs --concurrent --reference $ref --out $d > $d/compare.log 2>&1
  done
done
echo "$(date -u +%H:%M:%S) $(cut -d' ' -f1-3 /proc/loadavg) done" >> $out/log
