//! Video I/O and feature tracking (OpenCV adapters).

pub mod klt;
pub mod reduce;
pub mod source;

use std::path::{Path, PathBuf};

use opencv::core::{CV_8UC3, Mat, Size};
use opencv::prelude::*;
use opencv::{imgproc, videoio};

pub use source::VideoError;

/// Writes RGB frames to a video: H.264 in MP4 when OpenCV's backend can encode it, else MJPEG in
/// AVI. Frames go to a temporary file renamed when finished, so an interrupted run leaves none.
pub struct VideoSink {
    writer: videoio::VideoWriter,
    tmp: PathBuf,
    pub path: PathBuf,
    pub codec: &'static str,
    width: i32,
    height: i32,
    frames: usize,
}

impl VideoSink {
    /// `stem` is the output path without extension; the chosen one is added.
    pub fn create(
        stem: &Path,
        width: u32,
        height: u32,
        fps: f64,
        prefer_h264: bool,
    ) -> Result<VideoSink, VideoError> {
        let size = Size::new(width as i32, height as i32);
        let mut tried = Vec::new();
        let options: &[(&str, [char; 4], &str)] = if prefer_h264 {
            &[
                ("H.264", ['a', 'v', 'c', '1'], "mp4"),
                ("MJPEG", ['M', 'J', 'P', 'G'], "avi"),
            ]
        } else {
            &[("MJPEG", ['M', 'J', 'P', 'G'], "avi")]
        };
        for (codec, cc, ext) in options {
            let path = stem.with_extension(ext);
            let tmp = crate::io::temp_path(&path, &format!(".{ext}"));
            let fourcc = videoio::VideoWriter::fourcc(cc[0], cc[1], cc[2], cc[3])?;
            // OpenCV may print warnings for codecs it lacks; the result decides.
            if let Ok(writer) =
                videoio::VideoWriter::new(tmp.to_str().unwrap_or_default(), fourcc, fps, size, true)
                && writer.is_opened().unwrap_or(false)
            {
                return Ok(VideoSink {
                    writer,
                    tmp,
                    path,
                    codec,
                    width: size.width,
                    height: size.height,
                    frames: 0,
                });
            }
            let _ = std::fs::remove_file(&tmp);
            tried.push(*codec);
        }
        Err(VideoError::NoWriter { tried })
    }

    /// Appends a frame of 8-bit RGB, row-major.
    pub fn write_rgb(&mut self, rgb: &[u8]) -> Result<(), VideoError> {
        let mat = Mat::new_rows_cols_with_data(self.height, self.width * 3, rgb)?;
        let mat = mat.reshape(3, self.height)?;
        debug_assert_eq!(mat.typ(), CV_8UC3);
        let mut bgr = Mat::default();
        imgproc::cvt_color_def(&mat, &mut bgr, imgproc::COLOR_RGB2BGR)?;
        self.writer.write(&bgr)?;
        self.frames += 1;
        Ok(())
    }

    /// Appends a frame of 8-bit BGR of the sink's size.
    pub(crate) fn write_bgr(&mut self, bgr: &Mat) -> Result<(), VideoError> {
        debug_assert_eq!(bgr.typ(), CV_8UC3);
        self.writer.write(bgr)?;
        self.frames += 1;
        Ok(())
    }

    /// Finishes the file and moves it into place.
    pub fn finish(mut self) -> Result<PathBuf, VideoError> {
        self.writer.release()?;
        // OpenCV reports no write errors (a full disk): the file must open with every frame.
        let frames = videoio::VideoCapture::from_file(
            self.tmp.to_str().unwrap_or_default(),
            videoio::CAP_ANY,
        )
        .and_then(|c| c.get(videoio::CAP_PROP_FRAME_COUNT))
        .unwrap_or(0.0);
        if frames < self.frames as f64 {
            return Err(VideoError::CutShort {
                path: self.path.clone(),
                readable: frames,
                written: self.frames,
            });
        }
        crate::io::commit_temp(&self.tmp, &self.path).map_err(|source| VideoError::Io {
            path: self.path.clone(),
            source,
        })?;
        Ok(self.path.clone())
    }
}

/// Where annotated frames go: FFmpeg's command-line encoder (x264's `veryfast` preset: the
/// annotated video of 100 4K frames in 3.7 s instead of 5.9 s with OpenCV's writer, whose FFmpeg
/// backend takes no encoder options in 4.6), or OpenCV's writer when `ffmpeg` is missing.
pub enum FrameSink {
    Ffmpeg(FfmpegSink),
    OpenCv(VideoSink),
}

/// Raw BGR frames piped into `ffmpeg`, writing a temporary file moved into place when whole.
pub struct FfmpegSink {
    child: Option<std::process::Child>,
    tmp: PathBuf,
    path: PathBuf,
    frames: usize,
    size: (i32, i32),
}

impl FrameSink {
    /// An H.264 MP4 at `stem`.mp4 (or what [`VideoSink`] can write).
    pub fn create(stem: &Path, width: u32, height: u32, fps: f64) -> Result<FrameSink, VideoError> {
        let path = stem.with_extension("mp4");
        let tmp = crate::io::temp_path(&path, ".mp4");
        let spawned = std::process::Command::new("ffmpeg")
            .args([
                "-hide_banner",
                "-loglevel",
                "error",
                "-y",
                "-f",
                "rawvideo",
                "-pix_fmt",
                "bgr24",
            ])
            .args([
                "-s",
                &format!("{width}x{height}"),
                "-r",
                &format!("{fps}"),
                "-i",
                "-",
                "-an",
            ])
            .args([
                "-c:v", "libx264", "-preset", "veryfast", "-crf", "23", "-pix_fmt", "yuv420p",
            ])
            .args(["-movflags", "+faststart", "-f", "mp4"])
            .arg(&tmp)
            .stdin(std::process::Stdio::piped())
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn();
        match spawned {
            Ok(child) => Ok(FrameSink::Ffmpeg(FfmpegSink {
                child: Some(child),
                tmp,
                path,
                frames: 0,
                size: (width as i32, height as i32),
            })),
            Err(_) => Ok(FrameSink::OpenCv(VideoSink::create(
                stem, width, height, fps, true,
            )?)),
        }
    }

    /// Which encoder writes: for the report.
    pub fn encoder(&self) -> &'static str {
        match self {
            FrameSink::Ffmpeg(_) => "ffmpeg libx264",
            FrameSink::OpenCv(s) => s.codec,
        }
    }

    /// Appends a frame of 8-bit BGR of the sink's size.
    pub(crate) fn write_bgr(&mut self, bgr: &Mat) -> Result<(), VideoError> {
        let f = match self {
            FrameSink::OpenCv(s) => return s.write_bgr(bgr),
            FrameSink::Ffmpeg(f) => f,
        };
        use std::io::Write as _;
        if (bgr.cols(), bgr.rows()) != f.size || bgr.typ() != CV_8UC3 {
            return Err(VideoError::Unreadable {
                path: f.path.clone(),
                reason: "a frame of another size".into(),
            });
        }
        let copy;
        let bytes = if bgr.is_continuous() {
            bgr.data_bytes()?
        } else {
            copy = bgr.try_clone()?;
            copy.data_bytes()?
        };
        let stdin = f
            .child
            .as_mut()
            .and_then(|c| c.stdin.as_mut())
            .expect("piped until finished");
        stdin.write_all(bytes).map_err(|source| VideoError::Io {
            path: f.path.clone(),
            source,
        })?;
        f.frames += 1;
        Ok(())
    }

    /// Finishes the file, checks that every frame reads back, and moves it into place.
    pub fn finish(self) -> Result<PathBuf, VideoError> {
        let mut f = match self {
            FrameSink::OpenCv(s) => return s.finish(),
            FrameSink::Ffmpeg(f) => f,
        };
        let mut child = f.child.take().expect("running until finished");
        drop(child.stdin.take());
        let failed = |reason: String| VideoError::Unreadable {
            path: f.path.clone(),
            reason,
        };
        match child.wait_with_output() {
            Ok(o) if o.status.success() => {}
            Ok(o) => {
                return Err(failed(format!(
                    "ffmpeg failed: {}",
                    String::from_utf8_lossy(&o.stderr).trim()
                )));
            }
            Err(e) => return Err(failed(format!("ffmpeg failed: {e}"))),
        }
        // ffmpeg may stop early without saying so (a full disk): every frame must read back.
        let readable =
            videoio::VideoCapture::from_file(f.tmp.to_str().unwrap_or_default(), videoio::CAP_ANY)
                .and_then(|c| c.get(videoio::CAP_PROP_FRAME_COUNT))
                .unwrap_or(0.0);
        if readable < f.frames as f64 {
            return Err(VideoError::CutShort {
                path: f.path.clone(),
                readable,
                written: f.frames,
            });
        }
        crate::io::commit_temp(&f.tmp, &f.path).map_err(|source| VideoError::Io {
            path: f.path.clone(),
            source,
        })?;
        Ok(f.path.clone())
    }
}

impl Drop for FfmpegSink {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
        // Gone once moved into place; a half-written one is removed.
        let _ = std::fs::remove_file(&self.tmp);
    }
}

impl Drop for VideoSink {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.tmp);
    }
}
