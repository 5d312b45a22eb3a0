#!/usr/bin/env bash
# Checks that a split run gives run's bytes: `geostride run PROJECT`, then for each N
# `geostride split PROJECT --segments N`, the segments in a shuffled order, `geostride merge`,
# and the outputs compared byte for byte.
#
#   scripts/check-split.sh PROJECT.toml [N ...]     (N: 2 3 5 by default)
#
# Example, after `make demo` (a 30 s video in chunks of 5 s, so 6 chunks):
#   sed 's/^chunk_s = 10.0/chunk_s = 5.0/' out/demo/bridge-stream/project.toml \
#     > out/demo/bridge-stream/project-c5.toml
#   scripts/check-split.sh out/demo/bridge-stream/project-c5.toml 2 3 5
set -euo pipefail
project=$1
shift
sizes=("$@")
[ $# -eq 0 ] && sizes=(2 3 5)
here=$(cd "$(dirname "$0")/.." && pwd)
g=${GEOSTRIDE:-$here/target/release/geostride}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
"$g" run "$project" --out "$work/run" -q > /dev/null
status=0
for n in "${sizes[@]}"; do
  d=$work/split-$n
  "$g" split "$project" --segments "$n" --out "$d" -q > /dev/null
  order=$(seq 0 $((n - 1)) | shuf)
  for i in $order; do
    "$g" segment "$d" --index "$i" -q > /dev/null
  done
  "$g" merge "$d" -q > /dev/null
  line="N=$n (segments run in the order $(echo $order | tr '\n' ' ')):"
  for f in trajectories.csv tracks_mot.txt trajectories.txt pose/poses.csv; do
    if [ -f "$work/run/$f" ] && cmp -s "$work/run/$f" "$d/$f"; then
      line="$line $f same"
    else
      line="$line $f DIFFERENT"
      status=1
    fi
  done
  echo "$line"
done
exit $status
