#!/usr/bin/env bash
# Issue 36, task p36e: skeleton visibility with map sites (`vpl:sites=K`) against node maps,
# 1 s x 3 runs, with `path` 10 s x 2 runs in the same session, then the bias floors at 10 s
# (1 run), on the door, the ajar door and the two rooms. ./benches/vpl/sites.sh OUTDIR
# References (bdpt 1024 spp, 128x96, max depth 6): DOOR_REF, AJAR_REF and TWO_ROOMS_REF
# override refs/door.exr, refs/ajar.exr and refs/two-rooms.exr.
set -e
cd "$(dirname "$0")/../.."
L=target/release/lacuna
O=${1:-q36e}
mkdir -p "$O"
K=vpl:visibility=skeleton
V=$K,$K:sites=4,$K:sites=8,$K:sites=16,$K:sites=8:shadow_res=32,$K:compensate=true:interleave=4:light_samples=8,$K:sites=8:compensate=true:interleave=4:light_samples=8
F=$K,$K:sites=4,$K:sites=8
A="--width 128 --height 96 --max-depth 6"
log() { echo "$(date -u +%H:%M:%S) load $(cut -d' ' -f1-3 /proc/loadavg) $*" | tee -a "$O/log"; }
for sc in door ajar two-rooms; do
  case $sc in
    door) S=scenes/veach-door-pg2015/veach-door-pg2015.json; R=${DOOR_REF:-refs/door.exr};;
    ajar) S=scenes/veach-ajar-bitterli/veach-ajar-bitterli.json; R=${AJAR_REF:-refs/ajar.exr};;
    two-rooms) S=two-rooms; R=${TWO_ROOMS_REF:-refs/two-rooms.exr};;
  esac
  log "$sc 1 s"
  $L compare $S $A --integrators $V --time 1 --runs 3 --reference $R --out $O/1s-$sc > $O/1s-$sc.log 2>&1
  log "$sc path 10 s"
  $L compare $S $A --integrators path --time 10 --runs 2 --reference $R --out $O/10s-$sc > $O/10s-$sc.log 2>&1
  if [ -z "$NO_FLOOR" ]; then
    log "$sc floors 10 s"
    $L compare $S $A --integrators $F --time 10 --runs 1 --reference $R --out $O/floor-$sc > $O/floor-$sc.log 2>&1
  fi
done
log done
