#!/bin/sh
# PETS 2009 S2L1 View_001, frames 0-399, against its world ground truth (a real video of people
# seen by a fixed camera 7 m up at a shallow angle): geostride with the bundled detector (on the
# tiles it chooses, and on whole frames), with the benchmark's public ACF boxes, and the ACF
# boxes' own projection, scored at the standard 1 m.
#
#   GEOSTRIDE_DATA=../shared/data scripts/pets-benchmark.sh [OUT]
#
# Writes OUT/<run>/ (the runs), OUT/*.json (geostride evaluate --json) and OUT/table.md.
# Frames 400-794 are kept back as an independent check and are not processed.
set -eu

GEOSTRIDE=${GEOSTRIDE:-./target/release/geostride}
DATA=${GEOSTRIDE_DATA:?GEOSTRIDE_DATA is not set: the folder holding pets2009-s2l1/ and video/}
OUT=${1:-out/pets-benchmark}
PETS="$DATA/pets2009-s2l1"
VIDEO="$DATA/video/vtest_480x360_h264.avi"
GT="$PETS/gt_frames_0000-0399.txt"
for f in "$PETS/View_001.xml" "$VIDEO" "$GT" "$PETS/acf_det_frames_0000-0399.txt"; do
    [ -f "$f" ] || { echo "pets-benchmark: $f is missing" >&2; exit 2; }
done
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)

# The ACF boxes are in the original 768x576 pixels and carry ACF's raw scores (about -1 to 140):
# scaled to the video's 480x360 (x 0.625) and the scores to [0, 1] (/ 100, clipped).
awk -F, 'BEGIN { OFS = "," } {
    s = $7 / 100; if (s < 0) s = 0; if (s > 1) s = 1
    print $1, -1, $3 * 0.625, $4 * 0.625, $5 * 0.625, $6 * 0.625, s
}' "$PETS/acf_det_frames_0000-0399.txt" > "$OUT/acf_480x360.txt"
# Their own projection (the file's world x, y from each box's bottom), every box its own id.
awk -F, 'BEGIN { print "frame,id,e_m,n_m" } { print $1 - 1 "," NR "," $8 "," $9 }' \
    "$PETS/acf_det_frames_0000-0399.txt" > "$OUT/acf_own.csv"

# One project per detector: the camera and its pose from the Tsai calibration, no GCPs, the
# plaza a plane at 0 m, 400 frames (the file says 10 frames a second), KLT tracking with the gaps
# of a fixed camera's occlusions (2 s) and a gate for people walking at 25 m (0.6 m).
project() { # name, [detect] body
    cat > "$OUT/$1.toml" <<EOF
name = "PETS 2009 S2L1 View_001, frames 0-399 ($1)"
[camera]
calibration = "$PETS/View_001.xml"
[video]
path = "$VIDEO"
duration_s = 40
[pose]
kind = "fixed"
[ground]
kind = "plane"
height_m = 0.0
[detect]
$2
[track]
kind = "klt"
max_gap_s = 2.0
gate_m = 0.6
[export]
formats = ["csv", "detections"]
EOF
}
# The model's input is 416 px: by default the 480x360 frames are cut into two tiles of 360 px
# (enlarged x 1.16 for the model); whole, a frame is shrunk (x 0.87).
project bundled 'kind = "onnx"'
project bundled-whole 'kind = "onnx"
tile = 0'
project acf "kind = \"boxes\"
boxes = \"$OUT/acf_480x360.txt\""

for run in bundled bundled-whole acf; do
    echo "pets-benchmark: $run" >&2
    "$GEOSTRIDE" run "$OUT/$run.toml" --out "$OUT/$run" -q > /dev/null
    "$GEOSTRIDE" evaluate --truth "$GT" --truth-format mot --threshold 1 --truth-sd 0.13 \
        --tracks "$OUT/$run/trajectories.csv" --json > "$OUT/$run-tracking.json"
    "$GEOSTRIDE" evaluate --truth "$GT" --truth-format mot --threshold 1 --ignore-ids \
        --tracks "$OUT/$run/trajectories.csv" --json > "$OUT/$run-positions.json"
done
"$GEOSTRIDE" evaluate --truth "$GT" --truth-format mot --threshold 1 --ignore-ids \
    --tracks "$OUT/acf_own.csv" --json > "$OUT/acf-own-positions.json"

python3 - "$OUT" <<'EOF' | tee "$OUT/table.md"
import json, sys
out = sys.argv[1]
j = lambda name: json.load(open(f"{out}/{name}.json"))
print("| input | mean error, per frame (m) | recall | precision | MOTA | MOTP (m) | IDF1 | ID switches | tracks / people | 95 % ellipse (truth σ 0.13 m) |")
print("|---|---|---|---|---|---|---|---|---|---|")
for run, name in [("bundled", "bundled detector (YOLOv3-tiny), its tiles"), ("bundled-whole", "bundled detector, whole frames (`tile = 0`)"), ("acf", "ACF boxes through geostride")]:
    p, t = j(f"{run}-positions"), j(f"{run}-tracking")
    rec = p["matches"] / p["truth_positions"]
    prec = p["matches"] / max(p["estimated_positions"], 1)
    u = t.get("uncertainty", {}).get("inside_95", float("nan"))
    print(f"| {name} | {p['mean_error_m']:.3f} | {rec:.3f} | {prec:.3f} | {t['mota']:.3f} | {t['motp_m']:.3f} | {t['idf1']:.3f} | {t['id_switches']} | {t['estimated_tracks']} / {t['truth_tracks']} | {100 * u:.1f} % |")
p = j("acf-own-positions")
print(f"| ACF boxes' own projection (no tracking) | {p['mean_error_m']:.3f} | {p['matches'] / p['truth_positions']:.3f} | {p['matches'] / max(p['estimated_positions'], 1):.3f} | | | | | | |")
EOF
