#!/usr/bin/env bash
# `env=auto` against its alternatives: `path:env=latlong` and `path:env=cube-dynamic` at equal
# time (both at once, one thread each) on the sphere scenes under every bundled map, as given
# (lat-long) and resampled to cube maps (`LAYOUT=cube`). BENCHMARKS.md, "The default env=auto".
#   benches/env_auto.sh OUTDIR            (LAYOUT=cube benches/env_auto.sh OUTDIR for the cube rows)
set -e
cd "$(dirname "$0")/.."
L=${LACUNA:-target/release/lacuna}
O=${1:-env-auto}
S=scenes/envmaps
MAPS=${MAPS:-sky studio sunset venice apartment}
mkdir -p "$O"
for obj in sphere-diffuse sphere-glossy; do
  for map in $MAPS; do
    A="--env $S/$map.exr --width 64 --height 64 --max-depth 5"
    [ -n "$LAYOUT" ] && A="$A --env-layout $LAYOUT"
    R=$O/ref-$obj-$map${LAYOUT:+-$LAYOUT}.exr
    [ -f "$R" ] || $L reference $S/$obj.json $A --integrator path:env=latlong --spp 8192 --out "$R" > /dev/null
    echo "$(date -u +%T) load $(cut -d' ' -f1 /proc/loadavg) $obj $map ${LAYOUT:-latlong}"
    $L compare $S/$obj.json $A --threads 1 --concurrent --integrators path:env=latlong,path:env=cube-dynamic \
      --time 6 --runs 2 --reference "$R" --out "$O/cmp-$obj-$map${LAYOUT:+-$LAYOUT}" \
      | grep -E '^\| path:env='
  done
done
