#!/usr/bin/env bash
# Issue 36, task p36d: `vpl` at 1 s (passes sized to the budget) against `path` at 10 s on the
# door and the ajar door, 3 runs / 2 runs. ./benches/vpl/budget.sh OUTDIR
# References (bdpt 1024 spp, 128x96, max depth 6), as in benches/vpl/interleave.sh; DOOR_REF
# and AJAR_REF override refs/door.exr and refs/ajar.exr.
set -e
cd "$(dirname "$0")/../.."
L=target/release/lacuna
O=${1:-q36d}
mkdir -p "$O"
V=vpl,vpl:light_samples=8,vpl:compensate=true:interleave=4:light_samples=16,vpl:visibility=skeleton:compensate=true:interleave=4:light_samples=8,vpl:compensate=true,vpl:compensate=true:interleave=4,vpl:visibility=skeleton,vpl:visibility=skeleton:interleave=3
A="--width 128 --height 96 --max-depth 6"
log() { echo "$(date -u +%H:%M:%S) load $(cut -d' ' -f1-3 /proc/loadavg) $*" | tee -a "$O/log"; }
for sc in door ajar; do
  case $sc in
    door) S=scenes/veach-door-pg2015/veach-door-pg2015.json; R=${DOOR_REF:-refs/door.exr};;
    ajar) S=scenes/veach-ajar-bitterli/veach-ajar-bitterli.json; R=${AJAR_REF:-refs/ajar.exr};;
  esac
  log "$sc vpl 1 s"
  $L compare $S $A --integrators $V --time 1 --runs 3 --reference $R --out $O/1s-$sc > $O/1s-$sc.log 2>&1
  log "$sc path 10 s"
  $L compare $S $A --integrators path --time 10 --runs 2 --reference $R --out $O/10s-$sc > $O/10s-$sc.log 2>&1
done
log done
