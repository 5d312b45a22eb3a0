//! ONNX Runtime (adapter): the shared library loaded at run time (`ort`'s `load-dynamic`), a
//! model's session, its outputs as plain shapes and floats. `scripts/fetch-models.sh` puts the
//! library and the bundled model under `third_party/`.

use std::path::{Path, PathBuf};

use super::models::roots;
pub use super::models::{
    OVERHEAD_MODEL, YOLO_MODEL, bundled_model, given_model, named_model, overhead_model,
};

/// The ONNX Runtime version `scripts/fetch-models.sh` fetches.
pub const ORT_VERSION: &str = "1.31.1";

/// Why a model could not be used.
#[derive(Debug, thiserror::Error)]
pub enum OnnxError {
    #[error(
        "ONNX Runtime's library was not found (looked for {looked}); run ./scripts/fetch-models.sh (make test and make demo run it), or set GEOSTRIDE_ONNXRUNTIME to a libonnxruntime.so {ORT_VERSION}"
    )]
    NoLibrary { looked: String },
    #[error(
        "{}: cannot load ONNX Runtime: {message} (run ./scripts/fetch-models.sh, or set GEOSTRIDE_ONNXRUNTIME to a libonnxruntime.so {ORT_VERSION})",
        path.display()
    )]
    Library { path: PathBuf, message: String },
    #[error("{}: not an ONNX model ONNX Runtime can read: {message}", path.display())]
    Model { path: PathBuf, message: String },
    #[error("{}: {message}", path.display())]
    Run { path: PathBuf, message: String },
}

/// Where the library is: `GEOSTRIDE_ONNXRUNTIME`, else `third_party/onnxruntime/` of this
/// checkout (beside the executable's `target/` or the source tree).
pub fn library_path() -> Result<PathBuf, OnnxError> {
    if let Ok(p) = std::env::var("GEOSTRIDE_ONNXRUNTIME") {
        return Ok(PathBuf::from(p));
    }
    let name = format!("third_party/onnxruntime/libonnxruntime.so.{ORT_VERSION}");
    let mut looked = Vec::new();
    for root in roots() {
        let p = root.join(&name);
        if p.is_file() {
            return Ok(p);
        }
        looked.push(p.display().to_string());
    }
    Err(OnnxError::NoLibrary {
        looked: looked.join(", "),
    })
}

static ENV: std::sync::OnceLock<Result<ort::environment::Environment, String>> =
    std::sync::OnceLock::new();

/// The process's ONNX Runtime, loaded once.
fn environment() -> Result<&'static ort::environment::Environment, OnnxError> {
    let path = library_path()?;
    let r = ENV.get_or_init(|| {
        if !path.is_file() {
            return Err(format!("no such file: {}", path.display()));
        }
        ort::init_from(&path)
            .map_err(|e| e.to_string())?
            .with_name("geostride")
            .build()
            .map_err(|e| e.to_string())
    });
    r.as_ref().map_err(|message| OnnxError::Library {
        path,
        message: message.clone(),
    })
}

/// One output: its name, shape and values.
pub struct Output {
    pub name: String,
    pub shape: Vec<i64>,
    pub data: Vec<f32>,
}

/// A model's session.
pub struct OnnxModel {
    path: PathBuf,
    session: ort::session::Session,
    pub input_name: String,
    /// The input's shape as the model states it (-1 where free).
    pub input_shape: Vec<i64>,
    pub output_names: Vec<String>,
}

impl OnnxModel {
    /// Loads `path` with `threads` intra-op threads (0: ONNX Runtime's choice).
    pub fn load(path: &Path, threads: usize) -> Result<OnnxModel, OnnxError> {
        let env = environment()?;
        let model_err = |e: ort::Error| OnnxError::Model {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        if !path.is_file() {
            return Err(OnnxError::Model {
                path: path.to_path_buf(),
                message: "no such file".into(),
            });
        }
        let mut b = ort::session::Session::builder(env).map_err(model_err)?;
        if threads > 0 {
            b = b
                .with_intra_threads(threads)
                .map_err(|e| model_err(e.into()))?;
        }
        let session = b.commit_from_file(path).map_err(model_err)?;
        let inputs = session.inputs();
        if inputs.len() != 1 {
            return Err(OnnxError::Model {
                path: path.to_path_buf(),
                message: format!("{} inputs; an image detector has one", inputs.len()),
            });
        }
        let input_name = inputs[0].name().to_string();
        let input_shape: Vec<i64> = inputs[0]
            .dtype()
            .tensor_shape()
            .map(|s| s.iter().copied().collect())
            .unwrap_or_default();
        let output_names = session
            .outputs()
            .iter()
            .map(|o| o.name().to_string())
            .collect();
        Ok(OnnxModel {
            path: path.to_path_buf(),
            session,
            input_name,
            input_shape,
            output_names,
        })
    }

    /// A metadata entry of the model (`metadata_props`).
    pub fn metadata(&self, key: &str) -> Option<String> {
        self.session.metadata().ok()?.custom(key)
    }

    /// Runs the model on one planar float image `[1, 3, h, w]`.
    pub fn run(&mut self, input: Vec<f32>, wh: [usize; 2]) -> Result<Vec<Output>, OnnxError> {
        let err = |e: ort::Error| OnnxError::Run {
            path: self.path.clone(),
            message: e.to_string(),
        };
        let shape = vec![1i64, 3, wh[1] as i64, wh[0] as i64];
        let tensor = ort::value::Tensor::from_array((shape, input)).map_err(err)?;
        let name = self.input_name.clone();
        let path = self.path.clone();
        let outputs = self
            .session
            .run(ort::inputs![name => tensor])
            .map_err(|e| OnnxError::Run {
                path: path.clone(),
                message: e.to_string(),
            })?;
        let mut out = Vec::new();
        for (name, v) in outputs.iter() {
            let (shape, data) = v.try_extract_tensor::<f32>().map_err(|e| OnnxError::Run {
                path: path.clone(),
                message: format!("output {name}: {e}"),
            })?;
            out.push(Output {
                name: name.to_string(),
                shape: shape.iter().copied().collect(),
                data: data.to_vec(),
            });
        }
        Ok(out)
    }
}
