#!/bin/bash
# split + segment x N (shuffled) + merge against run, on the demo videos.
set -e
G=/work/main/target/release/geostride
cd /work/main
for spec in "out/demo/bridge-stream/project-c5.toml hat" "out/demo/marathon-stream/project-c2.toml crowd"; do
  set -- $spec; P=$1; L=$2
  rm -rf /tmp/ds-$L-run; $G run $P --out /tmp/ds-$L-run -q > /dev/null
  for N in 2 3 5; do
    D=/tmp/ds-$L-$N; rm -rf $D
    $G split $P --segments $N --out $D -q > /dev/null
    for i in $(seq 0 $((N-1)) | shuf --random-source=<(yes)); do $G segment $D --index $i -q > /dev/null; done
    $G merge $D -q > /dev/null
    r=""
    for f in trajectories.csv tracks_mot.txt trajectories.txt pose/poses.csv; do
      if cmp -s /tmp/ds-$L-run/$f $D/$f; then r="$r $f=same"; else r="$r $f=DIFFERENT"; fi
    done
    echo "$L N=$N:$r"
  done
done
