#!/usr/bin/env bash
# Issue 36, task p36g: skeleton visibility at 1 s with lazy maps and `probe_maps=true`, against
# `path` at 10 s (2 runs) in the same session, on the door, the ajar door and the two rooms.
# ./benches/vpl/one_second.sh OUTDIR. References (bdpt 1024 spp, 128x96, max depth 6): DOOR_REF,
# AJAR_REF and TWO_ROOMS_REF override refs/door.exr, refs/ajar.exr and refs/two-rooms.exr, made by
#   lacuna reference SCENE --width 128 --height 96 --max-depth 6 --integrator bdpt --spp 1024 --out REF
# INTEGRATORS (a comma-separated contender list) overrides the 1-s contenders below.
set -e
cd "$(dirname "$0")/../.."
L=target/release/lacuna
O=${1:-q36g}
mkdir -p "$O"
K=vpl:visibility=skeleton
C=compensate=true:interleave=4:light_samples=8
V=${INTEGRATORS:-$K,$K:probe_maps=true,$K:$C,$K:$C:probe_maps=true,$K:sites=8:$C,$K:sites=8:$C:probe_maps=true,$K:sites=16:$C:probe_maps=true}
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
done
log done
