#!/usr/bin/env bash
# The pure core: geostride built and tested with no adapter feature (no OpenCV, GDAL, PROJ,
# ONNX Runtime, HDF5 or SQLite), then every test binary of that build checked with ldd: none may
# link one of those libraries. Called by `make test`.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo=${CARGO:-cargo}
$cargo test --release --locked --no-default-features
bins=$($cargo test --release --locked --no-default-features --no-run --message-format=json 2>/dev/null |
  grep -o '"executable":"[^"]*"' | sed 's/^"executable":"//; s/"$//')
if [ -z "$bins" ]; then
  echo "check-pure: the pure build gave no test binaries" >&2
  exit 1
fi
libs='libopencv|libgdal|libproj|onnxruntime|libhdf5|libsqlite3'
# The check must be able to fail: the full binary, when built, links OpenCV.
if [ -x target/release/geostride ] && ! ldd target/release/geostride | grep -Eq "$libs"; then
  echo "check-pure: ldd shows no adapter library even in target/release/geostride" >&2
  exit 1
fi
bad=0
n=0
for b in $bins; do
  n=$((n + 1))
  if ldd "$b" | grep -E "$libs"; then
    echo "check-pure: $b links an adapter's library" >&2
    bad=1
  fi
done
if [ $bad -ne 0 ]; then
  exit 1
fi
echo "check-pure: $n test binaries built without features; none links libopencv, libgdal, libproj, onnxruntime, libhdf5 or libsqlite3"
