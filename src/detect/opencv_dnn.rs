//! OpenCV's dnn module running an ONNX model (adapter): the oracle and benchmark peer of the
//! ONNX Runtime path (`detect::onnx`), on the same planar float input.

use std::path::{Path, PathBuf};

use opencv::core::{Mat, Vector};
use opencv::prelude::*;

use super::onnx::{OnnxError, Output};

/// A model read by OpenCV's dnn.
pub struct OpenCvNet {
    path: PathBuf,
    net: opencv::dnn::Net,
    outputs: Vector<String>,
}

impl OpenCvNet {
    pub fn load(path: &Path) -> Result<OpenCvNet, OnnxError> {
        let err = |e: opencv::Error| OnnxError::Model {
            path: path.to_path_buf(),
            message: format!("OpenCV dnn: {e}"),
        };
        let net = opencv::dnn::read_net_from_onnx(path.to_string_lossy().as_ref()).map_err(err)?;
        let outputs = net.get_unconnected_out_layers_names().map_err(err)?;
        Ok(OpenCvNet {
            path: path.to_path_buf(),
            net,
            outputs,
        })
    }

    /// Runs the model on one planar float image `[1, 3, h, w]`.
    pub fn run(&mut self, input: Vec<f32>, wh: [usize; 2]) -> Result<Vec<Output>, OnnxError> {
        let err = |e: opencv::Error| OnnxError::Run {
            path: self.path.clone(),
            message: format!("OpenCV dnn: {e}"),
        };
        let dims = [1i32, 3, wh[1] as i32, wh[0] as i32];
        let flat = Mat::from_slice(&input).map_err(err)?;
        let blob = flat
            .reshape_nd(1, &dims)
            .map_err(err)?
            .try_clone()
            .map_err(err)?;
        self.net
            .set_input(&blob, "", 1.0, opencv::core::Scalar::default())
            .map_err(err)?;
        let mut outs: Vector<Mat> = Vector::new();
        self.net.forward(&mut outs, &self.outputs).map_err(err)?;
        let mut result = Vec::new();
        for (name, m) in self.outputs.iter().zip(outs.iter()) {
            let shape: Vec<i64> = m.mat_size().iter().map(|&d| d as i64).collect();
            let m = if m.is_continuous() {
                m
            } else {
                m.try_clone().map_err(err)?
            };
            let data = m.data_typed::<f32>().map_err(err)?.to_vec();
            result.push(Output { name, shape, data });
        }
        Ok(result)
    }
}
