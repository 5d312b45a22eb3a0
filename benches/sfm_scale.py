"""Structure from motion at survey scale (issue 40): geostride beside pycolmap 4.2.1 on simulated
survey flights of about 100, 250, 500 and 1 000 photos, in turn on the same cores.

Each flight is the footbridge site of benches/scenes/survey-flight-118.toml flown over a box
scaled to the photo count (nadir grid 30 m up, 70 % forward and 60 % side overlap, obliques
tilted 30 deg, 1200x675 photos, RTK-like centres), with 10 GCPs and 4 check points spread over
the box. Both tools get the same photos, the same held camera and the same centres (geostride
`--centres`, pycolmap's spatial matcher with them as pose priors, 8 neighbours each).

    python3 benches/sfm_scale.py OUT [--sizes 100,250,500,1000] [--pycolmap-python PY]
        [--geostride BIN] [--no-pycolmap]

Writes OUT/<n>/ (scene, simulation, models, logs), OUT/scale.csv (a row per size and tool:
seconds by stage, total, peak memory, registered, points, check points from the survey and
from the simulator's truth) and OUT/scale.svg (time
and peak memory against photos, log-log). A tool's size already in scale.csv is not run again.
Only the standard library: the plot is written by hand.
"""

import argparse
import csv
import json
import math
import os
import re
import subprocess
import sys
import time

FIELDS = [
    "photos", "tool", "registered", "points", "features_s", "matching_s", "mapping_s", "total_s",
    "peak_mb", "check_h_m", "check_v_m", "check_truth_h_m", "check_truth_v_m",
]


def scene(n, seed=17):
    """The scene file for a flight of about `n` photos (nadir grid plus obliques)."""
    # 120 x 80 m gives 110 nadir photos; the box grows with the square root of the count.
    s = math.sqrt(n / 110.0)
    w, h = 120.0 * s, 80.0 * s
    obliques = max(8, round(n / 14))
    gcps = []
    # Ten GCPs on a 5 x 2 grid over the inner box, four check points between them.
    for i, fx in enumerate([-0.4, -0.2, 0.0, 0.2, 0.4]):
        for j, fy in enumerate([-0.35, 0.35]):
            gcps.append((f"GCP{2 * i + j + 1}", fx * w, fy * h))
    for k, (fx, fy) in enumerate([(-0.3, 0.0), (0.3, 0.0), (-0.1, -0.2), (0.1, 0.2)]):
        gcps.append((f"CHK-{k + 1}", fx * w, fy * h))
    text = f"""# benches/sfm_scale.py: a survey flight of about {n} photos over {w:.0f} x {h:.0f} m.
name = "Survey flight, {n} photos"
seed = {seed}
duration_s = 0.1
fps = 10
ground_detail = 4

[site]
crs = "EPSG:3812"
origin = [654500.0, 696000.0, 52.0]

[camera]
calibration = "mini3pro"

[camera.motion]
kind = "hover"
position = [0.0, 0.0, 36.0]

[ground]
kind = "deck"
heading_deg = 90
width_m = 5.0
length_m = 80.0
height_m = 6.0
camber_m = 0.5
"""
    for name, e, nn in gcps:
        text += f'\n[[gcp]]\nname = "{name}"\nposition = [{e:.2f}, {nn:.2f}]\n'
    text += f"""
[people]
mode = "stream"
rate_per_s = 0.1

[output]
video = false
checkerboards = 0

[survey_flight]
altitude_m = 30
area = [[{-w / 2:.2f}, {-h / 2:.2f}], [{w / 2:.2f}, {h / 2:.2f}]]
forward_overlap = 0.7
side_overlap = 0.6
obliques = {obliques}
oblique_deg = 30
image_size = [1200, 675]
"""
    return text


def timed(cmd, log):
    """Runs `cmd` under /usr/bin/time -v: its stdout, wall seconds and peak memory (MB)."""
    t = time.perf_counter()
    with open(log, "w") as err:
        p = subprocess.run(["/usr/bin/time", "-v"] + cmd, stdout=subprocess.PIPE, stderr=err,
                           text=True)
    wall = time.perf_counter() - t
    text = open(log).read()
    if p.returncode != 0:
        sys.exit(f"sfm_scale: {' '.join(cmd[:2])} failed (exit {p.returncode}); see {log}")
    peak = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", text).group(1)) / 1024
    return p.stdout, wall, peak


def against_truth(report, sim):
    """RMS of the check points' model positions from the simulator's exact ones (horizontal,
    vertical, metres): their residuals from the survey less the survey's own error."""
    def table(path, name, keys):
        with open(path, encoding="utf-8-sig") as f:
            return {c[name]: [float(c[k]) for k in keys] for c in csv.DictReader(f)}
    surveyed = table(os.path.join(sim, "gcps.csv"), "Name", ["Easting", "Northing", "Elevation"])
    truth = table(os.path.join(sim, "truth", "gcps.csv"), "name",
                  ["x", "y", "ellipsoidal_height_m"])
    h, v = [], []
    for p in report["georef"]["points"]:
        if p["role"] == "check":
            n = p["name"]
            e = [p["residual_m"][i] + surveyed[n][i] - truth[n][i] for i in range(3)]
            h.append(e[0] ** 2 + e[1] ** 2)
            v.append(e[2] ** 2)
    return math.sqrt(sum(h) / len(h)), math.sqrt(sum(v) / len(v))


def run_geostride(n, d, sim, photos, names, args):
    """geostride sfm on the flight's photos: its row."""
    print(f"[{n}] geostride sfm on {len(names)} photos", flush=True)
    model = os.path.join(d, "geostride")
    stdout, wall, peak = timed(
        [args.geostride, "sfm", photos, "--camera", "mini3pro", "--gcps",
         os.path.join(sim, "gcps.csv"), "--picks", os.path.join(sim, "survey", "picks.csv"),
         "--centres", os.path.join(sim, "survey", "centres.csv"), "--neighbours", "8",
         "--out", model, "--json", "-q"],
        os.path.join(d, "geostride.log"))
    r = json.loads(stdout)
    check = r["georef"]["check_rms"]
    truth_h, truth_v = against_truth(r, sim)
    print(f"[{n}] geostride: {wall:.1f} s, {peak:.0f} MB", flush=True)
    return {
        "photos": len(names), "tool": "geostride", "registered": r["registered"],
        "points": r["points"], "features_s": r["seconds_features"],
        "matching_s": r["seconds_matching"], "mapping_s": r["seconds_reconstruction"],
        "total_s": wall, "peak_mb": peak, "check_h_m": check["horizontal_m"],
        "check_v_m": check["vertical_m"], "check_truth_h_m": truth_h, "check_truth_v_m": truth_v,
    }


def run_size(n, out, args, done):
    """The rows of the tools not yet `done` on the flight of about `n` photos."""
    d = os.path.join(out, str(n))
    os.makedirs(d, exist_ok=True)
    toml = os.path.join(d, "scene.toml")
    with open(toml, "w") as f:
        f.write(scene(n))
    sim = os.path.join(d, "sim")
    if not os.path.isdir(os.path.join(sim, "survey", "photos")):
        print(f"[{n}] simulating", flush=True)
        subprocess.run([args.geostride, "simulate", toml, "--out", sim, "-q"], check=True)
    photos = os.path.join(sim, "survey", "photos")
    names = sorted(os.listdir(photos))
    rows = []
    if "geostride" not in done:
        rows.append(run_geostride(n, d, sim, photos, names, args))
    if args.no_pycolmap or "pycolmap 4.2.1 incremental" in done:
        return rows
    # pycolmap's priors: the same centres less the site origin (one Cartesian frame, metres).
    priors = os.path.join(d, "priors.csv")
    with open(os.path.join(sim, "survey", "centres.csv")) as f, open(priors, "w") as g:
        g.write("name,x,y,z\n")
        for c in csv.DictReader(f):
            g.write(f"{c['Name']},{float(c['Easting']) - 654500.0},"
                    f"{float(c['Northing']) - 696000.0},{c['Elevation']}\n")
    fx = 861.2571875  # mini3pro at 1200 px wide: geostride's camera, held by both
    print(f"[{n}] pycolmap 4.2.1 incremental", flush=True)
    stdout, wall, peak = timed(
        [args.pycolmap_python, os.path.join(os.path.dirname(__file__), "pycolmap_sfm.py"),
         photos] + names + ["--mappers", "incremental", "--seeds", "0", "--camera",
                            f"{fx},{fx},599.5,337", "--priors", priors, "--neighbours", "8",
                            "--threads", str(os.cpu_count())],
        os.path.join(d, "pycolmap.log"))
    p = json.loads(stdout)
    run = p["runs"][0]
    rows.append({
        "photos": len(names), "tool": "pycolmap 4.2.1 incremental",
        "registered": run["registered"], "points": run.get("points", 0),
        "features_s": p["features_s"], "matching_s": p["matching_s"],
        "mapping_s": run["mapping_s"], "total_s": wall, "peak_mb": peak, "check_h_m": "",
        "check_v_m": "", "check_truth_h_m": "", "check_truth_v_m": "",
    })
    print(f"[{n}] pycolmap: {wall:.1f} s, {peak:.0f} MB", flush=True)
    return rows


def plot(rows, path):
    """Total seconds and peak MB against photos, log-log, one line per tool and measure."""
    W, H, L, B = 640, 420, 70, 50
    xs = [float(r["photos"]) for r in rows]
    ys = [float(r[k]) for r in rows for k in ("total_s", "peak_mb")]
    x0, x1 = math.log10(min(xs) / 1.2), math.log10(max(xs) * 1.2)
    y0, y1 = math.log10(min(ys) / 1.5), math.log10(max(ys) * 1.5)
    px = lambda x: L + (math.log10(x) - x0) / (x1 - x0) * (W - L - 20)
    py = lambda y: H - B - (math.log10(y) - y0) / (y1 - y0) * (H - B - 20)
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" '
           'font-family="sans-serif" font-size="12">',
           f'<rect width="{W}" height="{H}" fill="white"/>']
    for e in range(math.floor(y0), math.ceil(y1) + 1):
        for m in (1, 2, 5):
            v = m * 10 ** e
            if y0 <= math.log10(v) <= y1:
                out.append(f'<line x1="{L}" x2="{W - 20}" y1="{py(v):.1f}" y2="{py(v):.1f}" '
                           'stroke="#ddd"/>')
                out.append(f'<text x="{L - 6}" y="{py(v) + 4:.1f}" text-anchor="end">{v:g}</text>')
    for x in sorted(set(xs)):
        out.append(f'<text x="{px(x):.1f}" y="{H - B + 16}" text-anchor="middle">{x:g}</text>')
    out.append(f'<text x="{(W + L) / 2}" y="{H - 12}" text-anchor="middle">photos</text>')
    out.append(f'<text x="16" y="{(H - B) / 2}" transform="rotate(-90 16 {(H - B) / 2})" '
               'text-anchor="middle">seconds (solid, filled), peak MB (dashed, open)</text>')
    colours = {"geostride": "#c03030", "pycolmap 4.2.1 incremental": "#3060c0"}
    for i, (tool, colour) in enumerate(colours.items()):
        mine = sorted((r for r in rows if r["tool"] == tool), key=lambda r: float(r["photos"]))
        for key, dash in (("total_s", ""), ("peak_mb", ' stroke-dasharray="6 4"')):
            pts = " ".join(f"{px(float(r['photos'])):.1f},{py(float(r[key])):.1f}" for r in mine)
            if pts:
                out.append(f'<polyline points="{pts}" fill="none" stroke="{colour}" '
                           f'stroke-width="2"{dash}/>')
            for r in mine:
                fill = colour if key == "total_s" else "white"
                out.append(f'<circle cx="{px(float(r["photos"])):.1f}" '
                           f'cy="{py(float(r[key])):.1f}" r="4" fill="{fill}" '
                           f'stroke="{colour}" stroke-width="2"/>')
        out.append(f'<text x="{L + 10}" y="{30 + 16 * i}" fill="{colour}">{tool}</text>')
    out.append("</svg>")
    with open(path, "w") as f:
        f.write("\n".join(out) + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out")
    ap.add_argument("--sizes", default="100,250,500,1000")
    ap.add_argument("--geostride", default="./target/release/geostride")
    ap.add_argument("--pycolmap-python", default="out/bench-venv/bin/python")
    ap.add_argument("--no-pycolmap", action="store_true")
    args = ap.parse_args()
    args.geostride = os.path.abspath(args.geostride)
    os.makedirs(args.out, exist_ok=True)
    table = os.path.join(args.out, "scale.csv")
    rows = list(csv.DictReader(open(table))) if os.path.exists(table) else []
    for n in [int(v) for v in args.sizes.split(",")]:
        done = {r["tool"] for r in rows if r["scene"] == str(n)}
        for r in run_size(n, args.out, args, done):
            r["scene"] = str(n)
            rows.append(r)
        with open(table + ".tmp", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=["scene"] + FIELDS)
            w.writeheader()
            w.writerows(rows)
        os.replace(table + ".tmp", table)
        plot(rows, os.path.join(args.out, "scale.svg"))
    for r in rows:
        print(",".join(str(r[k]) for k in ["scene"] + FIELDS))


if __name__ == "__main__":
    main()
