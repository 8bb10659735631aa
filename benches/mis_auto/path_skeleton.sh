#!/usr/bin/env bash
# path_skeleton:mis=auto at equal time against path_skeleton's default, path and path:mis=auto
# (issue 33; BENCHMARKS.md, "Automatic MIS for path_skeleton").
# Usage: benches/mis_auto/path_skeleton.sh OUT TIME RUNS
# Environment: LACUNA (default target/release/lacuna), REFS (door.exr, ajar.exr, corridor.exr,
# roomsS.exr for S = 3, 17, 30, 18, 6; default /work/lead/refs). A missing family reference is
# made first (64x48, depth 65, 8192 spp).
set -euo pipefail
out=$1; t=$2; runs=$3
L=${LACUNA:-target/release/lacuna}
S=scenes
R=${REFS:-/work/lead/refs}
I=${INTEGRATORS:-path,path_skeleton,path_skeleton:mis=auto,path:mis=auto}
SCENES=${SCENES:-door ajar corridor rooms:3 rooms:17 rooms:30 rooms:18 rooms:6}
mkdir -p "$out"
for sc in $SCENES; do
  case $sc in
    door) F=$S/veach-door-pg2015/veach-door-pg2015.json; A="--width 128 --height 64"; ref=$R/door.exr;;
    ajar) F=$S/veach-ajar-bitterli/veach-ajar-bitterli.json; A="--width 128 --height 96 --max-depth 6"; ref=$R/ajar.exr;;
    corridor) F=corridor; A="--width 128 --height 128"; ref=$R/corridor.exr;;
    *) F=$sc; A="--width 64 --height 48 --max-depth 65"; ref=$R/rooms${sc#rooms:}.exr
       [ -f "$ref" ] || "$L" reference "$sc" $A --spp 8192 --threads 2 --out "$ref" --quiet;;
  esac
  d=$out/${sc/:/}; mkdir -p "$d"
  echo "$(date -u +%H:%M:%S) $(cut -d' ' -f1-3 /proc/loadavg) $sc" >> "$out/log"
  "$L" compare "$F" $A --threads 2 --integrators "$I" --time "$t" --runs "$runs" \
    --reference "$ref" --out "$d" > "$d/compare.log" 2>&1
  # What the guide did (pilot, scene-level switch, the mixture's c).
  "$L" render "$F" $A --spp 1 --threads 2 --integrator path_skeleton:mis=auto -v \
    --out "$d/guide.exr" > "$d/guide.log" 2>&1
done
echo "$(date -u +%H:%M:%S) $(cut -d' ' -f1-3 /proc/loadavg) done" >> "$out/log"
