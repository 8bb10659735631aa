#!/usr/bin/env bash
# Table of benches/family/run.sh results: per scene, the speedup of path_skeleton and bdpt
# over path by MSE above the reference's own (lacuna compare's last column), with the scene's
# description. Usage: benches/family/table.sh OUT_DIR
set -euo pipefail
echo "| scene | openings camera-light (min) | path_skeleton | bdpt | path_skeleton precomputation (s) |"
echo "|---|---|---|---|---|"
for dir in "$1"/rooms-*; do
  s="$dir/summary.md"; [ -f "$s" ] || continue
  desc=$(cat "$dir/description.txt")
  min=$(grep -o '\[room [0-9]*, [0-9]* openings' <<<"$desc" | awk '{print $3}' | sort -n | head -1)
  col() { grep "^| $1 |" "$s" | awk -F'|' '{print $NF=="" ? $(NF-1) : $NF}' | sed 's/.*(\([0-9.]*x\).*/\1/'; }
  pre=$(grep "^| path_skeleton |" "$s" | awk -F'|' '{print $7}' | tr -d ' ')
  echo "| ${desc%%:*}:$(sed 's/^rooms:\([0-9]*\):.*/\1/' <<<"$desc") ${desc#*: } | $min | $(col path_skeleton) | $(col bdpt) | $pre |"
done
