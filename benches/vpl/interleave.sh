#!/usr/bin/env bash
# Issue 36, task p36c: interleaved sampling in `vpl` at 1 s against `path` at 10 s, and the
# bias floor of each variant at 10 s. Re-run at low load: ./benches/vpl/interleave.sh OUTDIR
# References (bdpt 1024 spp, 128x96, max depth 6): the door's rebuilt in refs/door.exr with
#   target/release/lacuna reference scenes/veach-door-pg2015/veach-door-pg2015.json --width 128 --height 96 --max-depth 6 --integrator bdpt --spp 1024 --out refs/door.exr
# (the other references likewise, into refs/; DOOR_REF, AJAR_REF, TWO_ROOMS_REF override them).
set -e
cd "$(dirname "$0")/../.."
L=target/release/lacuna
O=${1:-q36}
mkdir -p "$O"
V=vpl,vpl:interleave=2,vpl:interleave=3,vpl:interleave=4,vpl:visibility=skeleton,vpl:visibility=skeleton:interleave=2,vpl:visibility=skeleton:interleave=3,vpl:visibility=skeleton:interleave=4
# Compensated (unbiased before the filter; the filter also averages the continuation).
C=vpl:compensate=true,vpl:compensate=true:interleave=2,vpl:compensate=true:interleave=4
A="--width 128 --height 96 --max-depth 6"
log() { echo "$(date -u +%H:%M:%S) load $(cut -d' ' -f1-3 /proc/loadavg) $*" | tee -a "$O/log"; }
for sc in door ajar two-rooms; do
  case $sc in
    door) S=scenes/veach-door-pg2015/veach-door-pg2015.json; R=${DOOR_REF:-refs/door.exr};;
    ajar) S=scenes/veach-ajar-bitterli/veach-ajar-bitterli.json; R=${AJAR_REF:-refs/ajar.exr};;
    two-rooms) S=two-rooms; R=${TWO_ROOMS_REF:-refs/two-rooms.exr};;
  esac
  log "$sc vpl 1 s"
  $L compare $S $A --integrators $V --time 1 --runs 3 --reference $R --out $O/1s-$sc > $O/1s-$sc.log 2>&1
  log "$sc vpl compensated 1 s"
  $L compare $S $A --integrators $C --time 1 --runs 3 --reference $R --out $O/1s-comp-$sc > $O/1s-comp-$sc.log 2>&1
  log "$sc path 10 s"
  $L compare $S $A --integrators path --time 10 --runs 2 --reference $R --out $O/10s-$sc > $O/10s-$sc.log 2>&1
  if [ $sc != two-rooms ]; then
    log "$sc vpl 10 s (bias floor)"
    $L compare $S $A --integrators $V --time 10 --runs 1 --reference $R --out $O/floor-$sc > $O/floor-$sc.log 2>&1
  fi
done
log done
