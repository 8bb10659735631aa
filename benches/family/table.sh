#!/usr/bin/env bash
# Table of benches/family/run.sh results: per scene, the speedup of path_skeleton and bdpt
# over path by MSE above the reference's own, and each integrator's brightest pixel over the
# reference's (median over runs), with the scene's description. Columns of summary.md are found
# by their header, so summaries of older binaries (without the largest-pixel column) still read.
# Usage: benches/family/table.sh OUT_DIR
set -euo pipefail
echo "| scene | openings camera-light (min) | path_skeleton | bdpt | path_skeleton precomputation (s) | largest pixel / reference's: path, path_skeleton, bdpt |"
echo "|---|---|---|---|---|---|"
for dir in "$1"/rooms-*; do
  s="$dir/summary.md"; [ -f "$s" ] || continue
  desc=$(cat "$dir/description.txt")
  min=$(grep -o '\[room [0-9]*, [0-9]* openings' <<<"$desc" | awk '{print $3}' | sort -n | head -1)
  # Cell of row $1 under the header cell named $2, whole, or "-".
  cell() {
    awk -F'|' -v row="$1" -v name="$2" '
      /^\| integrator \|/ { for (i = 2; i < NF; i++) { h = $i; gsub(/^ +| +$/, "", h); if (h == name) col = i } }
      $2 == " " row " " && col { v = $col; gsub(/^ +| +$/, "", v); print v; found = 1 }
      END { if (!found) print "-" }' "$s"
  }
  first() { cut -d' ' -f1; }
  # The speedup in "MSE above the reference's (speedup)": "E [..] (1.23x [..])" -> 1.23x.
  speedup() { cell "$1" "MSE above the reference's (speedup)" | grep -o '([0-9.]*x' | tr -d '(' || echo "-"; }
  pre=$(cell path_skeleton "precomputation (s)" | first)
  lp() { cell "$1" "largest pixel / reference's" | first; }
  largest="$(lp path), $(lp path_skeleton), $(lp bdpt)"
  echo "| ${desc%%:*}:$(sed 's/^rooms:\([0-9]*\):.*/\1/' <<<"$desc") ${desc#*: } | $min | $(speedup path_skeleton) | $(speedup bdpt) | $pre | $largest |"
done
