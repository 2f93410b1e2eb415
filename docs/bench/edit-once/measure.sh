#!/usr/bin/env bash
# Instructions per edit of the `edit_cost` driver (resecta-session/examples/edit_cost.rs) under
# callgrind: each workload runs with N1 and N2 steps, REPEAT times each; per step =
# (Ir(N2) - Ir(N1)) / (N2 - N1), which leaves out the set-up (phantom, anatomy, first resection).
# Usage: measure.sh <edit_cost binary> <label> [N1 N2 REPEAT]   (prints TSV rows)
set -euo pipefail
bin=$1 label=$2 n1=${3:-50} n2=${4:-450} repeat=${5:-3}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
ir() {
  valgrind --tool=callgrind --callgrind-out-file="$tmp/out" "$bin" "$@" 2>"$tmp/log" >/dev/null
  sed -n 's/.*Collected : \([0-9]*\).*/\1/p' "$tmp/log"
}
for path in service planner; do
  for op in drag undo-redo; do
    for r in $(seq "$repeat"); do
      a=$(ir "$path" "$op" "$n1")
      b=$(ir "$path" "$op" "$n2")
      printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$label" "$path" "$op" "$r" "$n1" "$a" "$n2" "$b" \
        | awk -F'\t' -v OFS='\t' '{print $0, int(($8 - $6) / ($7 - $5))}'
    done
  done
done
