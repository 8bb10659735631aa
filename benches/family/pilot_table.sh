#!/usr/bin/env bash
# Table of pilot_ab.sh results: per scene and binary, spp path / path_skeleton, path_skeleton's
# precomputation and its MSE above the reference's against path's (median [min, max]).
# Usage: pilot_table.sh OUT
for d in $1/*/*/compare.log; do
  b=$(echo $d | awk -F/ '{print $(NF-2)}'); sc=$(echo $d | awk -F/ '{print $(NF-1)}')
  p=$(grep '^| path |' $d); s=$(grep '^| path_skeleton |' $d)
  spp_p=$(echo "$p" | awk -F'|' '{gsub(/ /,"",$6); print $6}')
  spp_s=$(echo "$s" | awk -F'|' '{gsub(/ /,"",$6); print $6}')
  pre=$(echo "$s" | awk -F'|' '{print $7}' | awk '{print $1}')
  mse=$(echo "$s" | awk -F'|' '{print $11}' | grep -o '([0-9.]*x \[[0-9., ]*\])')
  echo "| $sc | $b | $spp_p / $spp_s | $pre | $mse |"
done
