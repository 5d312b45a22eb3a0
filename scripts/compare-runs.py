#!/usr/bin/env python3
"""Compares two output folders of geostride (two `geostride demo` or `run` outputs) file by file,
to check that a change kept the results byte for byte.

Stage caches (`.stages/*.bin`, GSCACHE1) are compared after their key, and structure-from-motion
caches (`cache/features`, `cache/matches`, GSF2/GSM2) by their payloads, since both keys name
the build. Reports, timings and files that name their own paths differ between any two runs:
they are listed, not judged.

    scripts/compare-runs.py OLD_DIR NEW_DIR
"""
import hashlib
import os
import struct
import sys


def payload(b):
    if b[:8] == b"GSCACHE1":
        k = struct.unpack("<Q", b[16:24])[0]
        return b[24 + k:]
    if b[:4] in (b"GSF2", b"GSM2"):
        k = struct.unpack("<I", b[4:8])[0]
        return b[8 + k + 16:]
    return b


def files(root):
    out = {}
    for d, _, fs in os.walk(root):
        for f in fs:
            p = os.path.join(d, f)
            out[os.path.relpath(p, root)] = p
    return out


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    a, b = files(sys.argv[1]), files(sys.argv[2])
    # SfM caches are named by a key that names the build: compared as sets of payloads.
    sfm = lambda rel: "/cache/features/" in "/" + rel or "/cache/matches/" in "/" + rel
    digests = lambda fs: sorted(
        hashlib.sha256(payload(open(p, "rb").read())).hexdigest()
        for rel, p in fs.items() if sfm(rel))
    same, differ = 0, []
    for rel in sorted(set(a) & set(b)):
        if sfm(rel):
            continue
        x, y = open(a[rel], "rb").read(), open(b[rel], "rb").read()
        if x == y or payload(x) == payload(y):
            same += 1
        else:
            differ.append(rel)
    only_a = [r for r in set(a) - set(b) if not sfm(r)]
    only_b = [r for r in set(b) - set(a) if not sfm(r)]
    sfm_same = digests(a) == digests(b)
    print(f"{same} files the same, {len(differ)} differ, {len(only_a)} only in the first, "
          f"{len(only_b)} only in the second; SfM caches "
          f"{'the same' if sfm_same else 'differ'}")
    for r in differ:
        print("differs:", r)
    for r in sorted(only_a):
        print("only in the first:", r)
    for r in sorted(only_b):
        print("only in the second:", r)


if __name__ == "__main__":
    main()
