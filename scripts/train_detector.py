#!/usr/bin/env python3
"""Trains geostride's overhead person detector on `geostride dataset` tiles (CPU, PyTorch) and
exports it to ONNX with the metadata `geostride detect` reads.

The model: a small fully convolutional network (five stride-2 stages, a top-down path back to
a quarter of the input) with a centre heatmap head (CenterNet's objects as points): per output
cell the score that a person's box centre lies there, the centre's sub-cell offset, the box's
log size and the offset from the centre to the top of the head (a share of the box's size). The
export decodes it inside the graph (3x3 max-pool peaks, top K), so the ONNX model's output is one row per candidate: score,
box centre x, y, width, height, head x, y (input pixels). Input: any size (multiples of 32), RGB,
0-1, NCHW.

Deterministic for a seed on one thread count (torch's CPU kernels); `make model` runs the
recipe the committed model came from. Python is only for training: geostride runs the model
through ONNX Runtime.
"""

import argparse
import csv
import hashlib
import json
import math
import os
import random
import sys
import time

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
from PIL import Image

STRIDE = 4
LAYOUT = "geostride-centre-heatmap-1"
# geostride's default score threshold (`[detect] min_score`, `geostride detect --min-score`).
DEFAULT_SCORE = 0.3
# Tried on the validation set: raw score thresholds, and the containment above which a box inside
# a better one is suppressed (1: never).
THRESHOLDS = (0.1, 0.15, 0.2, 0.225, 0.25, 0.275, 0.3, 0.325, 0.35, 0.4, 0.45, 0.5, 0.6)
CONTAINED = (1.0, 0.8, 0.7, 0.6, 0.5)


def read_dataset(folder):
    """The tiles' image paths and their labels: per tile an array of (x, y, w, h, hx, hy, shoulder_px, inside)."""
    meta = json.load(open(os.path.join(folder, "dataset.json")))
    tiles = {}
    with open(os.path.join(folder, "tiles.csv")) as f:
        for r in csv.DictReader(f):
            tiles[int(r["tile"])] = {"file": os.path.join(folder, r["file"]), "row": r, "labels": []}
    with open(os.path.join(folder, "labels.csv")) as f:
        for r in csv.DictReader(f):
            tiles[int(r["tile"])]["labels"].append(
                [float(r[k]) for k in ("x", "y", "w", "h", "head_x", "head_y", "shoulder_px", "inside")]
            )
    out = []
    for k in sorted(tiles):
        t = tiles[k]
        t["labels"] = np.array(t["labels"], dtype=np.float32).reshape(-1, 8)
        out.append(t)
    return meta, out


def load_image(path):
    im = np.asarray(Image.open(path).convert("RGB"), dtype=np.float32) / 255.0
    return im.transpose(2, 0, 1).copy()


def augment(img, labels, rng):
    """A random one of the eight flips and quarter turns (a view from above has no up)."""
    size = img.shape[1]
    lab = labels.copy()
    k = rng.randrange(4)
    flip = rng.random() < 0.5

    def pts(x, y):
        # Pixel centres at integers: the image spans -0.5 .. size-0.5.
        for _ in range(k):  # rot90 counter-clockwise: (x, y) -> (y, size-1-x)
            x, y = y, size - 1 - x
        if flip:
            x = size - 1 - x
        return x, y

    img = np.rot90(img, k, axes=(1, 2))
    if flip:
        img = img[:, :, ::-1]
    if len(lab):
        x0, y0 = pts(lab[:, 0], lab[:, 1])
        x1, y1 = pts(lab[:, 0] + lab[:, 2], lab[:, 1] + lab[:, 3])
        hx, hy = pts(lab[:, 4], lab[:, 5])
        lab[:, 0], lab[:, 1] = np.minimum(x0, x1), np.minimum(y0, y1)
        lab[:, 2], lab[:, 3] = np.abs(x1 - x0), np.abs(y1 - y0)
        lab[:, 4], lab[:, 5] = hx, hy
    return np.ascontiguousarray(img), lab


def gaussian_radius(w, h):
    """A heatmap radius (cells) growing with the box: about a third of its smaller side."""
    return max(0.0, 0.33 * min(w, h) / STRIDE)


def targets(labels, size):
    """Heatmap, regression targets and their mask on the output grid."""
    g = size // STRIDE
    heat = np.zeros((g, g), np.float32)
    reg = np.zeros((6, g, g), np.float32)
    mask = np.zeros((g, g), np.float32)
    ys, xs = np.mgrid[0:g, 0:g]
    for x, y, w, h, hx, hy, _, inside in labels:
        if w < 2 or h < 2:
            continue
        cx, cy = (x + w / 2) / STRIDE, (y + h / 2) / STRIDE
        ix, iy = int(cx), int(cy)
        if not (0 <= ix < g and 0 <= iy < g):
            continue
        sigma = max(0.5, gaussian_radius(w, h) / 2)
        heat = np.maximum(heat, np.exp(-((xs - cx) ** 2 + (ys - cy) ** 2) / (2 * sigma * sigma)))
        heat[iy, ix] = 1.0
        reg[:, iy, ix] = [cx - ix, cy - iy, math.log(w), math.log(h), (hx - (x + w / 2)) / w, (hy - (y + h / 2)) / h]
        mask[iy, ix] = 1.0
    return heat, reg, mask


class Block(nn.Module):
    def __init__(self, cin, cout, stride):
        super().__init__()
        self.a = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.an = nn.BatchNorm2d(cout)
        self.b = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn = nn.BatchNorm2d(cout)

    def forward(self, x):
        x = F.relu(self.an(self.a(x)))
        return F.relu(self.bn(self.b(x)))


class Net(nn.Module):
    """Five stride-2 stages (to 1/32: a person seen 40 degrees off nadir at the finest trained
    scale is some 150 px long and needs the context), a top-down path back to 1/4."""

    def __init__(self, width=1.0):
        super().__init__()
        c = [int(round(v * width)) for v in (16, 32, 64, 96, 128)]
        top = 64
        self.stem = nn.Sequential(nn.Conv2d(3, c[0], 3, 2, 1, bias=False), nn.BatchNorm2d(c[0]), nn.ReLU())
        self.s1 = Block(c[0], c[1], 2)  # 1/4
        self.s2 = Block(c[1], c[2], 2)  # 1/8
        self.s3 = Block(c[2], c[3], 2)  # 1/16
        self.s4 = Block(c[3], c[4], 2)  # 1/32
        self.l4 = nn.Conv2d(c[4], top, 1)
        self.l3 = nn.Conv2d(c[3], top, 1)
        self.l2 = nn.Conv2d(c[2], top, 1)
        self.l1 = nn.Conv2d(c[1], top, 1)
        self.mix = nn.Sequential(nn.Conv2d(top, 48, 3, 1, 1, bias=False), nn.BatchNorm2d(48), nn.ReLU())
        self.heat = nn.Conv2d(48, 1, 1)
        self.reg = nn.Conv2d(48, 6, 1)
        nn.init.constant_(self.heat.bias, -4.0)

    def forward(self, x):
        f1 = self.s1(self.stem(x))
        f2 = self.s2(f1)
        f3 = self.s3(f2)
        f4 = self.s4(f3)
        up = lambda t: F.interpolate(t, scale_factor=2.0, mode="nearest")
        p3 = self.l3(f3) + up(self.l4(f4))
        p2 = self.l2(f2) + up(p3)
        p1 = self.l1(f1) + up(p2)
        m = self.mix(p1)
        return self.heat(m), self.reg(m)


class Decoded(nn.Module):
    """The net with its decoding: the top K peaks as (score, cx, cy, w, h, head x, head y) in input pixels."""

    def __init__(self, net, k, shift=0.0):
        super().__init__()
        self.net, self.k, self.shift = net, k, shift

    def forward(self, x):
        logit, reg = self.net(x)
        # A shift of the logits (monotone: the same peaks, in the same order) puts the best
        # validation threshold at geostride's default score threshold.
        heat = torch.sigmoid(logit + self.shift)
        peaks = heat * (F.max_pool2d(heat, 3, 1, 1) == heat).float()
        n, _, gh, gw = heat.shape
        score, idx = torch.topk(peaks.reshape(n, -1), self.k, dim=1)
        gy = torch.div(idx, gw, rounding_mode="floor").float()
        gx = (idx - torch.div(idx, gw, rounding_mode="floor") * gw).float()
        r = torch.gather(reg.reshape(n, 6, -1), 2, idx.unsqueeze(1).expand(n, 6, self.k))
        cx = (gx + r[:, 0]) * STRIDE
        cy = (gy + r[:, 1]) * STRIDE
        w, h = torch.exp(r[:, 2]), torch.exp(r[:, 3])
        hx, hy = cx + r[:, 4] * w, cy + r[:, 5] * h
        return torch.stack([score, cx, cy, w, h, hx, hy], dim=2)


def focal_loss(logit, heat):
    p = torch.sigmoid(logit).clamp(1e-4, 1 - 1e-4)
    pos = heat.eq(1).float()
    neg = 1 - pos
    pos_loss = torch.log(p) * (1 - p) ** 2 * pos
    neg_loss = torch.log(1 - p) * p ** 2 * (1 - heat) ** 4 * neg
    n = pos.sum().clamp(min=1)
    return -(pos_loss.sum() + neg_loss.sum()) / n


def batches(tiles, batch, rng, augment_it=True):
    order = list(range(len(tiles)))
    rng.shuffle(order)
    for i in range(0, len(order) - batch + 1, batch):
        imgs, heats, regs, masks = [], [], [], []
        for j in order[i:i + batch]:
            t = tiles[j]
            img, lab = load_image(t["file"]), t["labels"]
            if augment_it:
                img, lab = augment(img, lab, rng)
            h, r, m = targets(lab, img.shape[1])
            imgs.append(img), heats.append(h), regs.append(r), masks.append(m)
        yield (torch.from_numpy(np.stack(imgs)), torch.from_numpy(np.stack(heats))[:, None],
               torch.from_numpy(np.stack(regs)), torch.from_numpy(np.stack(masks)))


def model_scale(gsd_m, trained_gsd_m):
    """How much geostride scales a frame of `gsd_m` metres a pixel before the model sees it: not
    at all inside the trained range, else to the range's geometric middle
    (`detect::neural::model_scale`)."""
    lo, hi = trained_gsd_m
    if lo <= gsd_m <= hi:
        return 1.0
    return gsd_m / math.sqrt(lo * hi)


def peaks(decoded, img, scale=1.0):
    """The model's top peaks, as rows (score, cx, cy, w, h, head x, head y). The image is first
    scaled by `scale` and padded to a multiple of 32 (as geostride does); boxes come back in its
    pixels."""
    x = torch.from_numpy(img)[None]
    if scale != 1.0:
        h, w = x.shape[2:]
        size = (max(1, round(h * scale)), max(1, round(w * scale)))
        x = F.interpolate(x, size=size, mode="area" if scale < 1 else "bilinear", align_corners=None if scale < 1 else False)
    h, w = x.shape[2:]
    x = F.pad(x, (0, (-w) % 32, 0, (-h) % 32), value=0.5)
    with torch.no_grad():
        rows = decoded(x)[0].numpy()
    if scale != 1.0:
        sx, sy = img.shape[2] / w, img.shape[1] / h
        rows[:, [1, 3, 5]] *= sx
        rows[:, [2, 4, 6]] *= sy
    return rows


def suppress(rows, threshold, nms_iou=0.45, contained=1.0):
    """The peaks above `threshold`, then non-maximum suppression as geostride's detector applies
    it: a box overlapping a better one by more than `nms_iou`, or lying more than `contained` of
    the smaller box's area inside it (a large person can give a second peak on a body part), is
    dropped."""
    rows = rows[rows[:, 0] >= threshold]
    rows = rows[np.argsort(-rows[:, 0])]
    kept = []
    for r in rows:
        b = (r[1] - r[3] / 2, r[2] - r[4] / 2, r[3], r[4])
        if all(iou((k[1], k[2], k[3], k[4]), b) <= nms_iou
               and (contained >= 1.0 or inside_share((k[1], k[2], k[3], k[4]), b) <= contained) for k in kept):
            kept.append(r)
    return np.array(kept, dtype=np.float32).reshape(-1, 7)


def inside_share(a, b):
    """The share of the smaller box's area inside the other (`a` centre-size, `b` corner-size)."""
    ax0, ay0, ax1, ay1 = a[0] - a[2] / 2, a[1] - a[3] / 2, a[0] + a[2] / 2, a[1] + a[3] / 2
    bx0, by0, bx1, by1 = b[0], b[1], b[0] + b[2], b[1] + b[3]
    iw, ih = max(0, min(ax1, bx1) - max(ax0, bx0)), max(0, min(ay1, by1) - max(ay0, by0))
    smaller = min(a[2] * a[3], b[2] * b[3])
    return iw * ih / smaller if smaller > 0 else 0.0


def iou(a, b):
    ax0, ay0, ax1, ay1 = a[0] - a[2] / 2, a[1] - a[3] / 2, a[0] + a[2] / 2, a[1] + a[3] / 2
    bx0, by0, bx1, by1 = b[0], b[1], b[0] + b[2], b[1] + b[3]
    iw, ih = max(0, min(ax1, bx1) - max(ax0, bx0)), max(0, min(ay1, by1) - max(ay0, by0))
    inter = iw * ih
    return inter / (a[2] * a[3] + b[2] * b[3] - inter + 1e-9)


def all_peaks(decoded, tiles, trained_gsd_m):
    """Every tile's peaks (the model runs once; thresholds and suppression are tried on them)."""
    return [peaks(decoded, load_image(t["file"]), model_scale(float(t["row"]["gsd_m"]), trained_gsd_m)) for t in tiles]


def evaluate(rows, tiles, threshold, contained=1.0, min_inside=0.5):
    """Precision and recall of the peaks `rows` (one array a tile) at `threshold`: a detection
    matches a person when its box centre lies within half the shoulder width of the person's box
    centre, or the boxes' IoU is at least 0.3 (greedy, by score). People mostly outside the tile
    (inside < min_inside) neither count as missed nor make a detection false."""
    tp = fp = fn = 0
    per = []
    head_err = []
    for t, raw in zip(tiles, rows):
        dets = suppress(raw, threshold, contained=contained)
        lab = t["labels"]
        used = set()
        pairs = []
        order = np.argsort(-dets[:, 0]) if len(dets) else []
        matched_det = 0
        false_det = 0
        for d in order:
            s, cx, cy, w, h = dets[d][:5]
            best, best_j = None, None
            for j, l in enumerate(lab):
                if j in used:
                    continue
                lcx, lcy = l[0] + l[2] / 2, l[1] + l[3] / 2
                dist = math.hypot(cx - lcx, cy - lcy)
                ok = dist <= l[6] / 2 or iou((cx, cy, w, h), l) >= 0.3
                if ok and (best is None or dist < best):
                    best, best_j = dist, j
            if best_j is not None:
                used.add(best_j)
                pairs.append((d, best_j))
                if lab[best_j][7] >= min_inside:
                    matched_det += 1
            else:
                false_det += 1
        missed = sum(1 for j, l in enumerate(lab) if j not in used and l[7] >= min_inside)
        for d, j in pairs:
            l = lab[j]
            if l[7] >= min_inside:
                head_err.append(math.hypot(dets[d][5] - l[4], dets[d][6] - l[5]) / l[6])
        tp += matched_det
        fp += false_det
        fn += missed
        per.append((t["row"], matched_det, false_det, missed))
    precision = tp / max(1, tp + fp)
    recall = tp / max(1, tp + fn)
    return precision, recall, per, head_err


def by_bucket(per, key, edges):
    """Precision and recall of the tiles whose `key` lies in each of the `edges` intervals."""
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        tp = fp = fn = 0
        for row, m, f, n in per:
            v = float(row[key])
            if lo <= v < hi:
                tp, fp, fn = tp + m, fp + f, fn + n
        out.append({"from": lo, "to": hi, "people": tp + fn, "precision": tp / max(1, tp + fp), "recall": tp / max(1, tp + fn)})
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--train", required=True, help="a `geostride dataset` folder")
    ap.add_argument("--val", required=True, help="a `geostride dataset` folder of another seed")
    ap.add_argument("--out", required=True, help="the ONNX model to write")
    ap.add_argument("--epochs", type=float, default=3.0)
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--lr", type=float, default=2e-3)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--max-steps", type=int, default=0, help="stop after this many steps (a smoke test)")
    ap.add_argument("--top-k", type=int, default=256)
    ap.add_argument("--val-all", help="a `geostride dataset` folder over a wider range of scales, scaled to the model's as "
                    "geostride does: the metrics by scale and view come from it")
    ap.add_argument("--weights", help="start from (or, with --max-steps 0 and --epochs 0, only evaluate) these weights")
    ap.add_argument("--report", help="a JSON file for the validation metrics")
    a = ap.parse_args()

    torch.manual_seed(a.seed)
    torch.set_num_threads(a.threads)
    rng = random.Random(a.seed)
    train_meta, train = read_dataset(a.train)
    val_meta, val = read_dataset(a.val)
    if train_meta["spec"]["seed"] == val_meta["spec"]["seed"]:
        sys.exit("train_detector: the validation set must be another seed than the training set")
    trained_gsd_m = train_meta["spec"]["gsd_m"]
    val_all = read_dataset(a.val_all)[1] if a.val_all else None
    net = Net()
    if a.weights:
        net.load_state_dict(torch.load(a.weights))
    opt = torch.optim.AdamW(net.parameters(), lr=a.lr, weight_decay=1e-4)
    steps_per_epoch = max(1, len(train) // a.batch)
    total = int(a.epochs * steps_per_epoch)
    if a.max_steps:
        total = min(total, a.max_steps)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=a.lr, total_steps=max(total, 1), pct_start=0.1)
    step, t0 = 0, time.time()
    net.train()
    while step < total:
        for img, heat, reg, mask in batches(train, a.batch, rng):
            logit, out = net(img)
            lh = focal_loss(logit, heat)
            m = mask[:, None]
            n = m.sum().clamp(min=1)
            lo = (F.l1_loss(out[:, 0:2], reg[:, 0:2], reduction="none") * m).sum() / n
            ls = (F.l1_loss(out[:, 2:4], reg[:, 2:4], reduction="none") * m).sum() / n
            lhd = (F.l1_loss(out[:, 4:6], reg[:, 4:6], reduction="none") * m).sum() / n
            loss = lh + lo + 0.5 * ls + lhd
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            step += 1
            if step % 20 == 0 or step == total:
                el = time.time() - t0
                print(f"step {step}/{total} loss {loss.item():.3f} (heat {lh.item():.3f} size {ls.item():.3f} head {lhd.item():.3f}) "
                      f"{el:.0f} s, {step * a.batch / el:.1f} tiles/s", flush=True)
            if step >= total:
                break
    if total:
        torch.save(net.state_dict(), a.out + ".pt")
    net.eval()
    decoded = Decoded(net, a.top_k)
    # The score threshold and the suppression's containment: the best F1 on the validation set.
    rows = all_peaks(decoded, val, trained_gsd_m)
    best = None
    for contained in CONTAINED:
        for th in THRESHOLDS:
            p, r, per, head_err = evaluate(rows, val, th, contained)
            f1 = 2 * p * r / max(1e-9, p + r)
            print(f"validation at score {th}, containment {contained}: precision {p:.3f} recall {r:.3f}", flush=True)
            if best is None or f1 > best[0]:
                best = (f1, th, contained, p, r, per, head_err)
    _, th, contained, p, r, per, head_err = best
    # Scores shifted so that the chosen threshold reads as geostride's default.
    shift = math.log(DEFAULT_SCORE / (1 - DEFAULT_SCORE)) - math.log(th / (1 - th))
    decoded = Decoded(net, a.top_k, shift)
    if val_all:
        rows = all_peaks(decoded, val_all, trained_gsd_m)
        pa, ra, per, head_err = evaluate(rows, val_all, DEFAULT_SCORE, contained)
        print(f"all scales: precision {pa:.3f} recall {ra:.3f}", flush=True)
    buckets = {
        "gsd_m": by_bucket(per, "gsd_m", [0.0, 0.008, 0.012, 0.02, 1.0]),
        "off_nadir_deg": by_bucket(per, "off_nadir_deg", [0.0, 10.0, 25.0, 90.0]),
    }
    head_median = float(np.median(head_err)) if head_err else None
    for k, rows in buckets.items():
        for b in rows:
            print(f"  {k} {b['from']}-{b['to']}: {b['people']} people, precision {b['precision']:.3f} recall {b['recall']:.3f}")
    if head_median is not None:
        print(f"  head point: median error {head_median:.3f} shoulder widths")
    size = train_meta["spec"]["size_px"]
    tmp = a.out + ".part"
    torch.onnx.export(decoded, torch.zeros(1, 3, size, size), tmp, opset_version=13,
                      input_names=["image"], output_names=["detections"],
                      dynamic_axes={"image": {2: "height", 3: "width"}})
    meta = {
        "geostride.layout": LAYOUT,
        "geostride.classes": "person",
        "geostride.input": "RGB, 0-1, NCHW, any height and width that are multiples of 32",
        "geostride.output": "detections [1, K, 7]: score, box centre x, y, width, height, head x, y (input pixels)",
        "geostride.train_size_px": str(size),
        "geostride.gsd_m": json.dumps(train_meta["spec"]["gsd_m"]),
        "geostride.score_threshold": f"{DEFAULT_SCORE}",
        "geostride.score_shift": f"{shift:.6f}",
        "geostride.nms_contained": f"{contained}",
        "geostride.train_dataset_sha256": train_meta["sha256"],
        "geostride.train_tiles": str(train_meta["tiles"]),
        "geostride.val_dataset_sha256": val_meta["sha256"],
        "geostride.val_precision": f"{p:.4f}",
        "geostride.val_recall": f"{r:.4f}",
        "geostride.recipe": json.dumps({k: v for k, v in vars(a).items() if k not in ("out", "report")}),
        "geostride.torch": torch.__version__,
    }
    try:
        import onnx
        model = onnx.load(tmp)
        for k, v in meta.items():
            e = model.metadata_props.add()
            e.key, e.value = k, v
        onnx.save(model, tmp)
    except ImportError:
        sys.exit("train_detector: the onnx package is needed to write the model's metadata")
    os.replace(tmp, a.out)
    digest = hashlib.sha256(open(a.out, "rb").read()).hexdigest()
    print(f"wrote {a.out} ({os.path.getsize(a.out) / 1e6:.2f} MB, sha256 {digest}): "
          f"validation precision {p:.3f} recall {r:.3f} at score {th}, containment {contained}")
    if a.report:
        with open(a.report, "w") as f:
            json.dump({"precision": p, "recall": r, "score_threshold": DEFAULT_SCORE, "chosen_raw_threshold": th, "nms_contained": contained,
                       "all_scales": {"precision": pa, "recall": ra} if val_all else None, "steps": step, "sha256": digest,
                       "by": buckets, "head_median_shoulders": head_median}, f, indent=2)


if __name__ == "__main__":
    main()
