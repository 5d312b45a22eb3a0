//! Reading video frames (OpenCV adapter).

use std::path::Path;

use opencv::core::Mat;
use opencv::prelude::*;
use opencv::{imgproc, videoio};

/// Frames of a video file, in order, as 8-bit greyscale.
pub struct FrameReader {
    cap: videoio::VideoCapture,
    /// Frames per second as the container states it.
    pub fps: f64,
    /// The container's frame count, when it states one (it may be approximate).
    pub frame_count: Option<usize>,
    pub width: u32,
    pub height: u32,
    next: usize,
    /// The colour frame [`next_gray_reusing`](Self::next_gray_reusing) decodes into, kept so
    /// that its memory is reused.
    bgr: Mat,
}

impl FrameReader {
    pub fn open(path: &Path) -> Result<FrameReader, String> {
        if path.is_dir() {
            return Err(format!(
                "{}: is a folder; expected a video file",
                path.display()
            ));
        }
        if !path.is_file() {
            return Err(format!("{}: no such video file", path.display()));
        }
        let name = path
            .to_str()
            .ok_or_else(|| format!("{}: not a UTF-8 path", path.display()))?;
        // OpenCV opens a still image as a video of one frame.
        if opencv::imgcodecs::have_image_reader(name).unwrap_or(false) {
            return Err(format!("{}: is an image; expected a video", path.display()));
        }
        let cap = videoio::VideoCapture::from_file(name, videoio::CAP_ANY)
            .map_err(|e| format!("{}: {e}", path.display()))?;
        if !cap.is_opened().unwrap_or(false) {
            return Err(format!(
                "{}: OpenCV cannot open this video (unknown container or codec)",
                path.display()
            ));
        }
        let get = |p: i32| cap.get(p).unwrap_or(0.0);
        let fps = get(videoio::CAP_PROP_FPS);
        let count = get(videoio::CAP_PROP_FRAME_COUNT);
        let (width, height) = (
            get(videoio::CAP_PROP_FRAME_WIDTH),
            get(videoio::CAP_PROP_FRAME_HEIGHT),
        );
        if !(width >= 1.0 && height >= 1.0) {
            return Err(format!(
                "{}: the video states no frame size",
                path.display()
            ));
        }
        Ok(FrameReader {
            cap,
            fps: if fps > 0.0 && fps.is_finite() {
                fps
            } else {
                0.0
            },
            frame_count: (count >= 1.0 && count.is_finite()).then_some(count as usize),
            width: width as u32,
            height: height as u32,
            next: 0,
            bgr: Mat::default(),
        })
    }

    /// The next frame's index and its greyscale image; `None` at the end.
    pub fn next_gray(&mut self) -> Result<Option<(usize, Mat)>, String> {
        let mut frame = Mat::default();
        if !self.cap.read(&mut frame).map_err(|e| e.to_string())? || frame.empty() {
            return Ok(None);
        }
        let gray = if frame.channels() == 1 {
            frame
        } else {
            let mut g = Mat::default();
            imgproc::cvt_color_def(&frame, &mut g, imgproc::COLOR_BGR2GRAY)
                .map_err(|e| e.to_string())?;
            g
        };
        let i = self.next;
        self.next += 1;
        Ok(Some((i, gray)))
    }

    /// [`next_gray`](Self::next_gray), decoding into one colour frame kept between calls (no
    /// fresh pages to fault in for every 4K frame); the greyscale image is new each time.
    pub fn next_gray_reusing(&mut self) -> Result<Option<(usize, Mat)>, String> {
        let mut bgr = std::mem::take(&mut self.bgr);
        let read = self.read_bgr_into(&mut bgr);
        let gray = match read {
            Ok(Some(i)) => {
                let mut g = Mat::default();
                imgproc::cvt_color_def(&bgr, &mut g, imgproc::COLOR_BGR2GRAY)
                    .map_err(|e| e.to_string())
                    .map(|()| Some((i, g)))
            }
            Ok(None) => Ok(None),
            Err(e) => Err(e),
        };
        self.bgr = bgr;
        gray
    }

    /// Reads the next frame into `frame` (BGR, continuous), reusing its memory when it already
    /// has the frame's size (no fresh pages to fault in for every 4K frame); its index, or
    /// `None` at the end.
    pub fn read_bgr_into(&mut self, frame: &mut Mat) -> Result<Option<usize>, String> {
        if !self.cap.read(frame).map_err(|e| e.to_string())? || frame.empty() {
            return Ok(None);
        }
        if frame.channels() != 3 || !frame.is_continuous() {
            let Some((i, bgr)) = self.as_bgr(std::mem::take(frame))? else {
                return Ok(None);
            };
            *frame = bgr;
            return Ok(Some(i));
        }
        let i = self.next;
        self.next += 1;
        Ok(Some(i))
    }

    /// The next frame's index and its colour (BGR, continuous) image; `None` at the end.
    pub fn next_bgr(&mut self) -> Result<Option<(usize, Mat)>, String> {
        let mut frame = Mat::default();
        if !self.cap.read(&mut frame).map_err(|e| e.to_string())? || frame.empty() {
            return Ok(None);
        }
        self.as_bgr(frame)
    }

    /// A frame just read, as BGR and continuous, with the next index.
    fn as_bgr(&mut self, frame: Mat) -> Result<Option<(usize, Mat)>, String> {
        let frame = if frame.channels() == 3 {
            frame
        } else {
            let mut c = Mat::default();
            imgproc::cvt_color_def(&frame, &mut c, imgproc::COLOR_GRAY2BGR)
                .map_err(|e| e.to_string())?;
            c
        };
        let frame = if frame.is_continuous() {
            frame
        } else {
            frame.try_clone().map_err(|e| e.to_string())?
        };
        let i = self.next;
        self.next += 1;
        Ok(Some((i, frame)))
    }

    /// Moves to frame `index` (the next frame read is that one); `false` when the backend cannot.
    pub fn seek(&mut self, index: usize) -> bool {
        let ok = self
            .cap
            .set(videoio::CAP_PROP_POS_FRAMES, index as f64)
            .unwrap_or(false);
        if ok {
            self.next = index;
        }
        ok
    }

    /// The colour (BGR) frame at `index`, read from the start.
    pub fn frame_bgr(path: &Path, index: usize) -> Result<Mat, String> {
        let mut r = FrameReader::open(path)?;
        let mut frame = Mat::default();
        for i in 0..=index {
            if !r.cap.read(&mut frame).map_err(|e| e.to_string())? || frame.empty() {
                return Err(format!(
                    "{}: the video ends before frame {index} (at {i})",
                    path.display()
                ));
            }
        }
        Ok(frame)
    }

    /// [`frame_bgr`](Self::frame_bgr) as plain data for pure code: tightly packed BGR bytes,
    /// width and height.
    pub fn frame_bgr_bytes(path: &Path, index: usize) -> Result<(Vec<u8>, usize, usize), String> {
        let m = Self::frame_bgr(path, index)?;
        let m = if m.is_continuous() {
            m
        } else {
            m.try_clone().map_err(|e| e.to_string())?
        };
        let bytes = m.data_bytes().map_err(|e| e.to_string())?.to_vec();
        Ok((bytes, m.cols() as usize, m.rows() as usize))
    }
}
