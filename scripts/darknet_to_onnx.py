#!/usr/bin/env python3
"""Convert a darknet YOLOv3-tiny model (.cfg + .weights) to ONNX.

Usage:
    python darknet_to_onnx.py --cfg yolov3-tiny.cfg --weights yolov3-tiny.weights \
        --out yolov3-tiny.onnx [--size 416] [--names coco.names]

The produced graph:
  * input  ``images``: float32 NCHW [1, 3, size, size], RGB, values in 0..1
    (no mean subtraction; resize/letterbox is up to the caller);
  * outputs ``yolo0``, ``yolo1``, ...: the raw (undecoded, no sigmoid) outputs
    of the convolution feeding each [yolo] section, in cfg order, shape
    [1, num_mask*(5+classes), size/stride, size/stride];
  * ops: Conv (batch norm folded in), LeakyRelu(alpha=0.1), MaxPool, Concat,
    Resize (nearest, scale 2, scales given as an initializer); opset 13,
    ir_version 7 -- readable by ONNX Runtime and OpenCV >= 4.6 dnn;
  * metadata_props: ``darknet_yolo`` (JSON: anchors, masks, classes, strides,
    outputs) and ``names`` (JSON list of class names) when a names file is
    given or found next to the cfg as coco.names.

Batch norm is folded with eps = 1e-5 by default (AlexeyAB darknet uses
sqrt(var + .00001f); pjreddie darknet and OpenCV's darknet reader use ~1e-6;
the difference on the head outputs is ~1e-3, see --bn-eps).
The output bytes are deterministic for the same inputs (no timestamps).

Caveat: the official yolov3-tiny.weights were trained with the second [yolo]
mask = 1,2,3; some cfg copies say 0,1,2, which makes decoded boxes about half
size. The graph does not depend on the masks; --yolo-masks "3,4,5;1,2,3"
overrides what goes into the metadata (default: the cfg's masks).

Supported cfg sections: [net], [convolutional] (batch_normalize, filters,
size, stride, pad, activation leaky|linear), [maxpool], [route] (one or two
layers), [upsample] (stride 2), [yolo]. Anything else fails loudly.

Runtime requirements (see scripts/models-requirements.txt for the hashes):
Python 3.11, onnx==1.17.0, numpy==1.26.4, protobuf==5.29.6 (7.36.2 gives
byte-identical output). onnxruntime/opencv are only needed to verify.
"""

import argparse
import json
import os
import sys

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

OPSET = 13
IR_VERSION = 7
BN_EPS = 1e-5
LEAKY_ALPHA = 0.1
CONVERTER_VERSION = "1"


def fail(msg):
    sys.exit("darknet_to_onnx: error: " + msg)


def parse_cfg(path):
    """Return a list of (section_type, {key: value_str}) in file order."""
    sections = []
    with open(path, "r", encoding="utf-8") as f:
        for lineno, raw in enumerate(f, 1):
            line = raw.split("#", 1)[0].split(";", 1)[0].strip()
            if not line:
                continue
            if line.startswith("["):
                if not line.endswith("]"):
                    fail(f"{path}:{lineno}: bad section header {line!r}")
                sections.append((line[1:-1].strip(), {}))
            else:
                if "=" not in line or not sections:
                    fail(f"{path}:{lineno}: unexpected line {line!r}")
                key, value = line.split("=", 1)
                sections[-1][1][key.strip()] = value.strip()
    if not sections or sections[0][0] not in ("net", "network"):
        fail("cfg must start with a [net] section")
    return sections


def ints(value):
    return [int(v) for v in value.replace(" ", "").split(",") if v != ""]


class WeightReader:
    """Sequential reader over the float32 payload of a .weights file."""

    def __init__(self, path):
        with open(path, "rb") as f:
            data = f.read()
        major, minor, revision = np.frombuffer(data, dtype="<i4", count=3)
        if major > 1000 or minor > 1000:
            fail("transposed (major/minor > 1000) weights are not supported")
        seen_bytes = 8 if major * 10 + minor >= 2 else 4
        offset = 12 + seen_bytes
        payload = len(data) - offset
        if payload < 0 or payload % 4:
            fail(f"weights payload size {payload} is not a multiple of 4")
        self.header = (int(major), int(minor), int(revision))
        self.floats = np.frombuffer(data, dtype="<f4", offset=offset)
        self.pos = 0

    def take(self, n):
        if self.pos + n > self.floats.size:
            fail(f"weights file too short: need {self.pos + n} floats, "
                 f"have {self.floats.size}")
        out = self.floats[self.pos:self.pos + n].astype(np.float32)
        self.pos += n
        return out

    def check_consumed(self):
        if self.pos != self.floats.size:
            fail(f"weights file has {self.floats.size - self.pos} unread floats "
                 f"(read {self.pos} of {self.floats.size}); cfg/weights mismatch")


def build(cfg_path, weights_path, size, names, bn_eps=BN_EPS, masks=None):
    sections = parse_cfg(cfg_path)
    net = sections[0][1]
    channels = int(net.get("channels", 3))
    if channels != 3:
        fail("only 3-channel input is supported")
    if size % 32:
        fail("--size must be a multiple of 32")

    reader = WeightReader(weights_path)
    nodes, inits = [], []
    # Per darknet layer: (tensor name, channels, height, width).
    layers = []
    cur = ("images", channels, size, size)
    yolo_heads = []  # (layer index of head tensor, mask, anchors, classes, stride)

    def init(name, array):
        inits.append(numpy_helper.from_array(np.ascontiguousarray(array), name))
        return name

    for idx, (kind, p) in enumerate(sections[1:]):
        prefix = f"l{idx:03d}_{kind}"
        x, c, h, w = cur
        if kind == "convolutional":
            filters, k = int(p["filters"]), int(p.get("size", 1))
            stride = int(p.get("stride", 1))
            pad = k // 2 if int(p.get("pad", 0)) else int(p.get("padding", 0))
            if int(p.get("groups", 1)) != 1 or int(p.get("dilation", 1)) != 1:
                fail(f"layer {idx}: groups/dilation not supported")
            act = p.get("activation", "logistic")
            if act not in ("leaky", "linear"):
                fail(f"layer {idx}: activation {act!r} not supported")
            bn = int(p.get("batch_normalize", 0))
            if bn:
                beta = reader.take(filters)
                gamma = reader.take(filters)
                mean = reader.take(filters)
                var = reader.take(filters)
            else:
                bias = reader.take(filters)
            weight = reader.take(filters * c * k * k).reshape(filters, c, k, k)
            if bn:
                # y = gamma * (conv - mean) / sqrt(var + eps) + beta
                scale = gamma / np.sqrt(var + np.float32(bn_eps))
                weight = weight * scale[:, None, None, None]
                bias = beta - mean * scale
            wname = init(prefix + "_W", weight.astype(np.float32))
            bname = init(prefix + "_B", bias.astype(np.float32))
            y = prefix
            nodes.append(helper.make_node(
                "Conv", [x, wname, bname], [y], name=prefix,
                kernel_shape=[k, k], strides=[stride, stride],
                pads=[pad, pad, pad, pad], dilations=[1, 1], group=1))
            if act == "leaky":
                nodes.append(helper.make_node(
                    "LeakyRelu", [y], [y + "_leaky"], name=prefix + "_leaky",
                    alpha=LEAKY_ALPHA))
                y += "_leaky"
            h = (h + 2 * pad - k) // stride + 1
            w = (w + 2 * pad - k) // stride + 1
            cur = (y, filters, h, w)
        elif kind == "maxpool":
            k = int(p.get("size", 1))
            stride = int(p.get("stride", 1))
            padding = int(p.get("padding", k - 1))
            # darknet: out = (in + padding - size)/stride + 1, window starts at
            # -padding/2, out-of-range cells are ignored (like -inf padding).
            # So size 2 / stride 1 becomes MaxPool pads [0,0,1,1] (end only);
            # MaxPool's implicit -inf padding matches darknet, whereas a Pad op
            # with 0 would be wrong after LeakyRelu. ORT and OpenCV 4.6 agree.
            oh = (h + padding - k) // stride + 1
            ow = (w + padding - k) // stride + 1
            begin = padding // 2
            end_h = (oh - 1) * stride + k - h - begin
            end_w = (ow - 1) * stride + k - w - begin
            if min(end_h, end_w) < 0:
                fail(f"layer {idx}: maxpool geometry not supported")
            nodes.append(helper.make_node(
                "MaxPool", [x], [prefix], name=prefix,
                kernel_shape=[k, k], strides=[stride, stride],
                pads=[begin, begin, end_h, end_w]))
            cur = (prefix, c, oh, ow)
        elif kind == "route":
            refs = [r if r >= 0 else idx + r for r in ints(p["layers"])]
            if not 1 <= len(refs) <= 2 or any(not 0 <= r < idx for r in refs):
                fail(f"layer {idx}: bad route layers {p['layers']!r}")
            if int(p.get("groups", 1)) != 1:
                fail(f"layer {idx}: route groups not supported")
            srcs = [layers[r] for r in refs]
            if len(srcs) == 1:
                cur = srcs[0]
            else:
                if len({(s[2], s[3]) for s in srcs}) != 1:
                    fail(f"layer {idx}: route inputs have different sizes")
                nodes.append(helper.make_node(
                    "Concat", [s[0] for s in srcs], [prefix], name=prefix,
                    axis=1))
                cur = (prefix, sum(s[1] for s in srcs), srcs[0][2], srcs[0][3])
        elif kind == "upsample":
            stride = int(p.get("stride", 2))
            if stride != 2 or float(p.get("scale", 1)) != 1:
                fail(f"layer {idx}: only upsample stride=2 scale=1 supported")
            roi = init(prefix + "_roi", np.zeros(0, np.float32))
            scales = init(prefix + "_scales",
                          np.array([1, 1, 2, 2], np.float32))
            nodes.append(helper.make_node(
                "Resize", [x, roi, scales], [prefix], name=prefix,
                mode="nearest", coordinate_transformation_mode="asymmetric",
                nearest_mode="floor"))
            cur = (prefix, c, h * 2, w * 2)
        elif kind == "yolo":
            anchors = ints(p["anchors"])
            if len(anchors) % 2:
                fail(f"layer {idx}: odd number of anchor values")
            anchors = [anchors[i:i + 2] for i in range(0, len(anchors), 2)]
            mask = ints(p.get("mask", ",".join(map(str, range(len(anchors))))))
            classes = int(p.get("classes", 20))
            if c != len(mask) * (5 + classes):
                fail(f"layer {idx}: yolo input has {c} channels, expected "
                     f"{len(mask) * (5 + classes)}")
            if float(p.get("scale_x_y", 1)) != 1:
                fail(f"layer {idx}: scale_x_y != 1 not supported")
            yolo_heads.append((idx - 1, mask, anchors, classes, size // h))
        else:
            fail(f"layer {idx}: unsupported section [{kind}]")
        layers.append(cur)
    reader.check_consumed()

    if not yolo_heads:
        fail("cfg has no [yolo] sections")
    if len({json.dumps(hd[2]) for hd in yolo_heads}) != 1:
        fail("[yolo] sections disagree on anchors")
    if len({hd[3] for hd in yolo_heads}) != 1:
        fail("[yolo] sections disagree on classes")

    # Give each head tensor its public name (yolo0, yolo1, ...).
    outputs, rename = [], {}
    for i, (li, mask, anchors, classes, stride) in enumerate(yolo_heads):
        name, c, h, w = layers[li]
        rename[name] = f"yolo{i}"
        outputs.append(helper.make_tensor_value_info(
            f"yolo{i}", TensorProto.FLOAT, [1, c, h, w]))
    for node in nodes:
        node.input[:] = [rename.get(t, t) for t in node.input]
        node.output[:] = [rename.get(t, t) for t in node.output]

    classes = yolo_heads[0][3]
    cfg_masks = [hd[1] for hd in yolo_heads]
    if masks is None:
        masks = cfg_masks
    elif [len(m) for m in masks] != [len(m) for m in cfg_masks] or any(
            not 0 <= a < len(yolo_heads[0][2]) for m in masks for a in m):
        fail(f"--yolo-masks {masks} does not fit the cfg heads {cfg_masks}")
    if names is not None and len(names) != classes:
        fail(f"names file has {len(names)} entries, cfg has {classes} classes")

    graph = helper.make_graph(
        nodes, "darknet_yolo",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT,
                                       [1, 3, size, size])],
        outputs, initializer=inits)
    model = helper.make_model(
        graph, opset_imports=[helper.make_opsetid("", OPSET)],
        producer_name="darknet_to_onnx", producer_version=CONVERTER_VERSION,
        doc_string=(
            f"YOLO converted from darknet {os.path.basename(cfg_path)} "
            f"(weights version {'.'.join(map(str, reader.header))}). "
            f"Input 'images': float32 NCHW [1,3,{size},{size}], RGB, 0..1. "
            "Outputs yolo0..: raw head conv outputs (no sigmoid/decoding); "
            "see metadata 'darknet_yolo'. "
            f"Batch norm folded with eps={bn_eps:g}."))
    model.ir_version = IR_VERSION
    meta = {
        "anchors": yolo_heads[0][2],
        "masks": masks,
        "classes": classes,
        "strides": [hd[4] for hd in yolo_heads],
        "outputs": [f"yolo{i}" for i in range(len(yolo_heads))],
        "input": {"name": "images", "layout": "NCHW", "color": "RGB",
                  "range": [0, 1], "size": [size, size]},
    }
    props = [("darknet_yolo", json.dumps(meta, separators=(",", ":")))]
    if names is not None:
        props.append(("names", json.dumps(names, separators=(",", ":"))))
    helper.set_model_props(model, dict(props))
    onnx.checker.check_model(model, full_check=True)
    return model


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cfg", required=True)
    ap.add_argument("--weights", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--size", type=int, default=416,
                    help="square input size, multiple of 32 (default 416)")
    ap.add_argument("--names", help="class names file (default: coco.names "
                    "next to the cfg, if present)")
    ap.add_argument("--bn-eps", type=float, default=BN_EPS,
                    help="batch norm epsilon used when folding (default 1e-5)")
    ap.add_argument("--yolo-masks", help='override the metadata masks, one '
                    'group per [yolo] in cfg order, e.g. "3,4,5;1,2,3"')
    args = ap.parse_args(argv)
    masks = None
    if args.yolo_masks:
        masks = [ints(g) for g in args.yolo_masks.split(";")]

    names_path = args.names
    if names_path is None:
        guess = os.path.join(os.path.dirname(os.path.abspath(args.cfg)),
                             "coco.names")
        names_path = guess if os.path.exists(guess) else None
    names = None
    if names_path is not None:
        with open(names_path, "r", encoding="utf-8") as f:
            names = [ln.strip() for ln in f if ln.strip()]
    else:
        print("warning: no names file; 'names' metadata omitted",
              file=sys.stderr)

    model = build(args.cfg, args.weights, args.size, names, args.bn_eps, masks)
    data = model.SerializeToString(deterministic=True)
    with open(args.out, "wb") as f:
        f.write(data)
    print(f"wrote {args.out} ({len(data)} bytes, {len(model.graph.node)} "
          f"nodes, outputs {[o.name for o in model.graph.output]})")


if __name__ == "__main__":
    main()
