#!/usr/bin/env python3
"""A top view of a run's trajectories beside the PETS 2009 world truth (standard library only).

    python3 scripts/pets-plot.py GT.txt TRAJECTORIES.csv OUT.png [LAST_FRAME]

GT.txt: the MOTChallenge 3D truth (frame from 1, id, box, x, y in metres on the ground).
The truth is drawn in black, each geostride track in its own colour, a grid line every 5 m
(north up, east right); frames after LAST_FRAME (default 399) are left out of both.
"""
import csv
import struct
import sys
import zlib

PX_PER_M = 24
MARGIN_M = 2.0
PALETTE = [(230, 25, 75), (60, 180, 75), (0, 130, 200), (245, 130, 48), (145, 30, 180),
           (70, 200, 200), (240, 50, 230), (150, 150, 0), (0, 128, 128), (170, 110, 40),
           (128, 0, 0), (0, 0, 128), (128, 128, 0), (255, 180, 0)]


def read_truth(path, last):
    tracks = {}
    for row in csv.reader(open(path)):
        frame = int(float(row[0])) - 1
        if frame > last:
            continue
        tracks.setdefault(int(float(row[1])), []).append((frame, float(row[7]), float(row[8])))
    return tracks


def read_run(path, last):
    tracks = {}
    for row in csv.DictReader(open(path)):
        frame = int(row["frame"])
        if frame > last:
            continue
        tracks.setdefault(int(row["id"]), []).append((frame, float(row["e_m"]), float(row["n_m"])))
    return tracks


def write_png(path, width, height, pixels):
    raw = b"".join(b"\x00" + bytes(pixels[y * width * 3:(y + 1) * width * 3]) for y in range(height))

    def chunk(kind, data):
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)

    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n")
        f.write(chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)))
        f.write(chunk(b"IDAT", zlib.compress(raw, 9)))
        f.write(chunk(b"IEND", b""))


def main():
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    last = int(sys.argv[4]) if len(sys.argv) > 4 else 399
    truth = read_truth(sys.argv[1], last)
    run = read_run(sys.argv[2], last)
    xs = [p[1] for t in truth.values() for p in t]
    ys = [p[2] for t in truth.values() for p in t]
    x0, x1 = min(xs) - MARGIN_M, max(xs) + MARGIN_M
    y0, y1 = min(ys) - MARGIN_M, max(ys) + MARGIN_M
    width, height = int((x1 - x0) * PX_PER_M), int((y1 - y0) * PX_PER_M)
    pixels = bytearray([255] * (width * height * 3))

    def put(x, y, colour):
        if 0 <= x < width and 0 <= y < height:
            i = (y * width + x) * 3
            pixels[i:i + 3] = bytes(colour)

    def to_px(e, n):
        return (e - x0) * PX_PER_M, (y1 - n) * PX_PER_M

    def line(a, b, colour, thick):
        (ax, ay), (bx, by) = a, b
        steps = int(max(abs(bx - ax), abs(by - ay))) + 1
        for k in range(steps + 1):
            t = k / steps
            x, y = ax + (bx - ax) * t, ay + (by - ay) * t
            for dx in range(-thick, thick + 1):
                for dy in range(-thick, thick + 1):
                    put(int(round(x)) + dx, int(round(y)) + dy, colour)

    grid = (225, 225, 225)
    for g in range(int(x0 // 5) * 5, int(x1) + 1, 5):
        line(to_px(g, y0), to_px(g, y1), grid, 0)
    for g in range(int(y0 // 5) * 5, int(y1) + 1, 5):
        line(to_px(x0, g), to_px(x1, g), grid, 0)

    def draw(tracks, colour_of, thick):
        for tid, points in sorted(tracks.items()):
            points.sort()
            for p, q in zip(points, points[1:]):
                if q[0] - p[0] <= 3:
                    line(to_px(p[1], p[2]), to_px(q[1], q[2]), colour_of(tid), thick)

    draw(truth, lambda _: (0, 0, 0), 0)
    draw(run, lambda tid: PALETTE[tid % len(PALETTE)], 1)
    write_png(sys.argv[3], width, height, pixels)
    print(f"{sys.argv[3]}: {width}x{height}, {len(truth)} true tracks, {len(run)} estimated, "
          f"{PX_PER_M} px/m, east {x0:.1f} to {x1:.1f} m, north {y0:.1f} to {y1:.1f} m")


if __name__ == "__main__":
    main()
