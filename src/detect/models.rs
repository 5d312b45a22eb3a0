//! The bundled models and where they are (pure paths: `detect::onnx` loads them): under the
//! checkout that built the executable, by file or by short name.

use std::path::PathBuf;

/// The short names of the bundled models (`[detect] model`, `geostride detect --model`).
pub const BUNDLED_MODELS: [&str; 2] = ["overhead", "yolov3-tiny"];

/// The checkout's folders a bundled file may be under: above the executable
/// (`target/release/geostride`), then the source tree it was built from.
pub(crate) fn roots() -> Vec<PathBuf> {
    let mut r = Vec::new();
    if let Some(exe) = std::env::current_exe()
        .ok()
        .and_then(|e| e.canonicalize().ok())
    {
        for up in exe.ancestors().skip(1).take(3) {
            r.push(up.to_path_buf());
        }
    }
    r.push(PathBuf::from(env!("CARGO_MANIFEST_DIR")));
    r
}

/// The bundled person detector for views from the side (`third_party/models/yolov3-tiny.onnx`,
/// COCO), where it is.
pub fn bundled_model() -> Option<PathBuf> {
    bundled(YOLO_MODEL)
}

/// The bundled YOLOv3-tiny, from the checkout's root.
pub const YOLO_MODEL: &str = "third_party/models/yolov3-tiny.onnx";
/// geostride's own overhead person detector (scripts/train_detector.py), from the checkout's
/// root; committed with its model card (`models/overhead-person.md`).
pub const OVERHEAD_MODEL: &str = "models/overhead-person.onnx";

/// The overhead person detector, where it is.
pub fn overhead_model() -> Option<PathBuf> {
    bundled(OVERHEAD_MODEL)
}

/// A bundled model by its short name (`overhead`, `yolov3-tiny`), where it is.
pub fn named_model(name: &str) -> Option<PathBuf> {
    match name {
        "overhead" => overhead_model(),
        "yolov3-tiny" => bundled_model(),
        _ => None,
    }
}

/// The model a user named `name`: `file` (the name as a path) when it exists, else the bundled
/// model of that name (`overhead`, `yolov3-tiny`), else `file` (its error says it is missing).
pub fn given_model(name: &str, file: PathBuf) -> PathBuf {
    match named_model(name) {
        Some(p) if !file.exists() => p,
        _ => file,
    }
}

fn bundled(rel: &str) -> Option<PathBuf> {
    roots()
        .into_iter()
        .map(|r| r.join(rel))
        .find(|p| p.is_file())
}
