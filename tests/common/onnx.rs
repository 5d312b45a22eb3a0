//! A minimal ONNX model written for tests (protobuf by hand): one image input `[1, 3, H, W]`
//! and one output, a constant of a chosen shape and value (NaN, say): a model that loads and
//! runs but whose outputs a detector must refuse.
#![allow(dead_code)]

fn varint(mut v: u64, out: &mut Vec<u8>) {
    loop {
        let b = (v & 0x7F) as u8;
        v >>= 7;
        if v == 0 {
            out.push(b);
            return;
        }
        out.push(b | 0x80);
    }
}

fn key(field: u64, wire: u64, out: &mut Vec<u8>) {
    varint(field << 3 | wire, out);
}

fn int(field: u64, v: u64, out: &mut Vec<u8>) {
    key(field, 0, out);
    varint(v, out);
}

fn bytes(field: u64, b: &[u8], out: &mut Vec<u8>) {
    key(field, 2, out);
    varint(b.len() as u64, out);
    out.extend_from_slice(b);
}

/// A float tensor's ValueInfoProto (name, shape).
fn value_info(name: &str, shape: &[i64]) -> Vec<u8> {
    let mut dims = Vec::new();
    for &d in shape {
        let mut dim = Vec::new();
        int(1, d as u64, &mut dim);
        bytes(1, &dim, &mut dims);
    }
    let mut tensor = Vec::new();
    int(1, 1, &mut tensor); // elem_type FLOAT
    bytes(2, &dims, &mut tensor);
    let mut ty = Vec::new();
    bytes(1, &tensor, &mut ty);
    let mut vi = Vec::new();
    bytes(1, name.as_bytes(), &mut vi);
    bytes(2, &ty, &mut vi);
    vi
}

/// The model's bytes: input `images` `[1, 3, h, w]`, output `output` of `shape` filled with
/// `value`, and `metadata` (key, value) pairs.
pub fn constant_model(
    h: i64,
    w: i64,
    shape: &[i64],
    value: f32,
    metadata: &[(&str, &str)],
) -> Vec<u8> {
    let n: i64 = shape.iter().product();
    let mut tensor = Vec::new();
    for &d in shape {
        int(1, d as u64, &mut tensor);
    }
    int(2, 1, &mut tensor); // FLOAT
    let raw: Vec<u8> = (0..n).flat_map(|_| value.to_le_bytes()).collect();
    bytes(9, &raw, &mut tensor);
    let mut attr = Vec::new();
    bytes(1, b"value", &mut attr);
    bytes(5, &tensor, &mut attr);
    int(20, 4, &mut attr); // AttributeType TENSOR
    let mut node = Vec::new();
    bytes(2, b"output", &mut node);
    bytes(3, b"constant", &mut node);
    bytes(4, b"Constant", &mut node);
    bytes(5, &attr, &mut node);
    let mut graph = Vec::new();
    bytes(1, &node, &mut graph);
    bytes(2, b"test", &mut graph);
    bytes(11, &value_info("images", &[1, 3, h, w]), &mut graph);
    bytes(12, &value_info("output", shape), &mut graph);
    let mut model = Vec::new();
    int(1, 8, &mut model); // ir_version
    bytes(2, b"geostride-tests", &mut model);
    bytes(7, &graph, &mut model);
    let mut opset = Vec::new();
    bytes(1, b"", &mut opset);
    int(2, 13, &mut opset);
    bytes(8, &opset, &mut model);
    for (k, v) in metadata {
        let mut e = Vec::new();
        bytes(1, k.as_bytes(), &mut e);
        bytes(2, v.as_bytes(), &mut e);
        bytes(14, &e, &mut model);
    }
    model
}
