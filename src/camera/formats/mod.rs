//! Calibration files: OpenCV YAML, Agisoft Metashape XML, geostride JSON, and the Tsai
//! calibration (read only) that PETS 2009 and ETH publish their fixed cameras in.
//!
//! Conversions and the conventions they rest on are documented in `docs/formats.md`.

pub mod cvyaml;
mod json;
mod metashape;
mod opencv;
pub mod tsai;

use std::path::Path;

use super::Calibration;

/// A calibration file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// OpenCV FileStorage YAML as written by OpenCV's calibration samples.
    OpenCvYaml,
    /// Agisoft Metashape calibration XML (Metashape 1.5 and later).
    Metashape,
    /// geostride's own JSON, which carries the covariance (and a fixed camera's pose).
    Json,
    /// The Tsai calibration (XML or 19 numbers; read only): intrinsics and the camera's pose.
    Tsai,
}

impl Format {
    pub fn name(self) -> &'static str {
        match self {
            Format::OpenCvYaml => "opencv-yaml",
            Format::Metashape => "metashape-xml",
            Format::Json => "json",
            Format::Tsai => "tsai",
        }
    }

    /// The format implied by a file name: `.yaml`/`.yml`, `.xml` (Metashape), `.json`.
    pub fn from_extension(path: &Path) -> Option<Format> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "yaml" | "yml" => Some(Format::OpenCvYaml),
            "xml" => Some(Format::Metashape),
            "json" => Some(Format::Json),
            _ => None,
        }
    }

    /// The format of a file's content.
    pub fn detect(content: &str) -> Option<Format> {
        let t = content.trim_start_matches('\u{feff}').trim_start();
        if t.starts_with('{') {
            Some(Format::Json)
        } else if tsai::looks_like(t) {
            Some(Format::Tsai)
        } else if t.starts_with("<?xml") || t.starts_with('<') {
            Some(Format::Metashape)
        } else if t.starts_with("%YAML") || t.contains("!!opencv-matrix") {
            Some(Format::OpenCvYaml)
        } else {
            None
        }
    }
}

/// A calibration file that cannot be read or written.
pub type FormatError = crate::io::FileError;
pub(crate) use crate::io::FileCtx as Ctx;

/// An XML calibration's document; text that is not XML is an error at its line.
fn parse_xml<'t>(ctx: &Ctx, text: &'t str) -> Result<roxmltree::Document<'t>, FormatError> {
    roxmltree::Document::parse(text).map_err(|e| {
        ctx.err(
            Some(e.pos().row as usize),
            None,
            format!("not valid XML: {e}"),
        )
    })
}

/// The largest calibration file read: parameters and the views of a calibration fit in kilobytes.
pub const MAX_CALIBRATION_BYTES: u64 = 16 << 20;

/// Reads a calibration file, detecting its format from the content unless `format` is given.
pub fn read(path: &Path, format: Option<Format>) -> Result<Calibration, FormatError> {
    let ctx = Ctx { path };
    let text = ctx.read_small_text(
        "a YAML, XML, JSON or Tsai calibration",
        MAX_CALIBRATION_BYTES,
    )?;
    parse(path, &text, format)
}

/// Parses calibration text; `path` is used in error messages.
pub fn parse(path: &Path, text: &str, format: Option<Format>) -> Result<Calibration, FormatError> {
    let ctx = Ctx { path };
    let format = match format.or_else(|| Format::detect(text)) {
        Some(f) => f,
        None => {
            return Err(ctx.err(
                Some(1),
                None,
                "unknown calibration format: expected OpenCV YAML ('%YAML:1.0' and \
                 '!!opencv-matrix'), Metashape XML, geostride JSON or a Tsai calibration; pass \
                 --format to choose",
            ));
        }
    };
    let cal = match format {
        Format::OpenCvYaml => opencv::parse(&ctx, text),
        Format::Metashape => metashape::parse(&ctx, text),
        Format::Json => json::parse(&ctx, text),
        Format::Tsai => tsai::parse(&ctx, text),
    }?;
    cal.validate()
        .map_err(|(field, message)| ctx.err(None, Some(field), message))?;
    Ok(cal)
}

/// Renders a calibration in a format.
pub fn render(
    cal: &Calibration,
    format: Format,
    path_for_errors: &Path,
) -> Result<String, FormatError> {
    let ctx = Ctx {
        path: path_for_errors,
    };
    match format {
        Format::OpenCvYaml => Ok(opencv::render(cal)),
        Format::Metashape => metashape::render(&ctx, cal),
        Format::Json => json::render(cal).map_err(|e| ctx.err(None, None, e.to_string())),
        Format::Tsai => Err(ctx.err(
            None,
            None,
            "geostride reads Tsai calibrations but does not write them: write .json (which keeps \
             the camera's pose), .yaml or .xml",
        )),
    }
}

/// Why a calibration was not written: the calibration or the name cannot be written in a
/// format (the user's to fix), or the file system failed.
#[derive(Debug, thiserror::Error)]
pub enum WriteError {
    #[error(transparent)]
    Format(#[from] FormatError),
    #[error("{path}: cannot write: {source}")]
    Io {
        path: std::path::PathBuf,
        source: std::io::Error,
    },
}

/// The format a calibration written to `path` gets: `format`, or else the file extension.
pub fn output_format(path: &Path, format: Option<Format>) -> Result<Format, FormatError> {
    format
        .or_else(|| Format::from_extension(path))
        .ok_or_else(|| {
            Ctx { path }.err(
                None,
                None,
                "cannot tell the output format from the extension: use .yaml (OpenCV), .xml \
             (Metashape) or .json (geostride), or pass --format",
            )
        })
}

/// Writes a calibration atomically; the format follows `format` or else the file extension.
pub fn write(cal: &Calibration, path: &Path, format: Option<Format>) -> Result<Format, WriteError> {
    let format = output_format(path, format)?;
    let text = render(cal, format, path)?;
    crate::io::write_atomic(path, text.as_bytes()).map_err(|source| WriteError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(format)
}

#[cfg(test)]
mod tests;
