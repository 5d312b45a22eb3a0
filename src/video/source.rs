//! Reading video frames (OpenCV adapter).

use std::path::{Path, PathBuf};

use opencv::core::Mat;
use opencv::prelude::*;
use opencv::{imgproc, videoio};

/// Why a video could not be read.
#[derive(Debug, thiserror::Error)]
pub enum VideoError {
    /// Not a video geostride can read: a folder, a missing file, an image, an unknown codec.
    #[error("{}: {reason}", path.display())]
    Unreadable { path: PathBuf, reason: String },
    /// The video ends before the frame asked for.
    #[error("{}: the video ends before frame {index} (at {at})", path.display())]
    Ended {
        path: PathBuf,
        index: usize,
        at: usize,
    },
    /// No codec could write a video here.
    #[error("OpenCV cannot write video here (tried {})", tried.join(", "))]
    NoWriter { tried: Vec<&'static str> },
    /// A written video reads back shorter than written (a full disk, say).
    #[error("{}: the video was cut short ({readable} of {written} frames readable; is the disk full?)", path.display())]
    CutShort {
        path: PathBuf,
        readable: f64,
        written: usize,
    },
    /// Moving the finished video into place failed.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// OpenCV failed while decoding, encoding or converting a frame.
    #[error(transparent)]
    OpenCv(#[from] opencv::Error),
}

fn unreadable(path: &Path, reason: &str) -> VideoError {
    VideoError::Unreadable {
        path: path.to_path_buf(),
        reason: reason.to_string(),
    }
}

/// Images handed to other threads, each one's memory reused once every other thread let it
/// go (a 4K frame is 25 MB of fresh pages).
#[derive(Default)]
pub struct MatPool {
    mats: Vec<std::sync::Arc<Mat>>,
}

impl MatPool {
    /// A free buffer filled by `fill`, and what `fill` returned.
    pub fn fill<T, E>(
        &mut self,
        fill: impl FnOnce(&mut Mat) -> Result<T, E>,
    ) -> Result<(std::sync::Arc<Mat>, T), E> {
        let mut m = match self
            .mats
            .iter()
            .position(|m| std::sync::Arc::strong_count(m) == 1)
        {
            Some(k) => self.mats.swap_remove(k),
            None => std::sync::Arc::new(Mat::default()),
        };
        let out = fill(std::sync::Arc::get_mut(&mut m).expect("only the pool holds it"));
        self.mats.push(m.clone());
        Ok((m, out?))
    }
}

/// Decoded frames handed to worker threads, in reused buffers.
#[derive(Default)]
pub struct FramePool {
    pool: MatPool,
}

impl FramePool {
    /// The next frame of `reader` (BGR, continuous) in a free buffer; `None` at the end.
    pub fn read(
        &mut self,
        reader: &mut FrameReader,
    ) -> Result<Option<std::sync::Arc<Mat>>, VideoError> {
        let (bgr, next) = self.pool.fill(|m| reader.read_bgr_into(m))?;
        Ok(next.map(|_| bgr))
    }
}

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
    /// The colour frame a checked seek reads into, kept so that its memory is reused.
    bgr: Mat,
}

impl FrameReader {
    pub fn open(path: &Path) -> Result<FrameReader, VideoError> {
        if path.is_dir() {
            return Err(unreadable(path, "is a folder; expected a video file"));
        }
        if !path.is_file() {
            return Err(unreadable(path, "no such video file"));
        }
        let name = path
            .to_str()
            .ok_or_else(|| unreadable(path, "not a UTF-8 path"))?;
        // OpenCV opens a still image as a video of one frame.
        if opencv::imgcodecs::have_image_reader(name).unwrap_or(false) {
            return Err(unreadable(path, "is an image; expected a video"));
        }
        let cap = videoio::VideoCapture::from_file(name, videoio::CAP_ANY)
            .map_err(|e| unreadable(path, &e.to_string()))?;
        if !cap.is_opened().unwrap_or(false) {
            return Err(unreadable(
                path,
                "OpenCV cannot open this video (unknown container or codec)",
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
            return Err(unreadable(path, "the video states no frame size"));
        }
        crate::imageheader::check_size(width as u64, height as u64)
            .map_err(|e| unreadable(path, &format!("frames: {e}")))?;
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
    pub fn next_gray(&mut self) -> Result<Option<(usize, Mat)>, VideoError> {
        let mut frame = Mat::default();
        if !self.cap.read(&mut frame)? || frame.empty() {
            return Ok(None);
        }
        let gray = if frame.channels() == 1 {
            frame
        } else {
            let mut g = Mat::default();
            imgproc::cvt_color_def(&frame, &mut g, imgproc::COLOR_BGR2GRAY)?;
            g
        };
        let i = self.next;
        self.next += 1;
        Ok(Some((i, gray)))
    }

    /// Reads the next frame into `frame` (BGR, continuous), reusing its memory when it already
    /// has the frame's size (no fresh pages to fault in for every 4K frame); its index, or
    /// `None` at the end.
    pub fn read_bgr_into(&mut self, frame: &mut Mat) -> Result<Option<usize>, VideoError> {
        if !self.cap.read(frame)? || frame.empty() {
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
    pub(crate) fn next_bgr(&mut self) -> Result<Option<(usize, Mat)>, VideoError> {
        let mut frame = Mat::default();
        if !self.cap.read(&mut frame)? || frame.empty() {
            return Ok(None);
        }
        self.as_bgr(frame)
    }

    /// A frame just read, as BGR and continuous, with the next index.
    fn as_bgr(&mut self, frame: Mat) -> Result<Option<(usize, Mat)>, VideoError> {
        let frame = if frame.channels() == 3 {
            frame
        } else {
            let mut c = Mat::default();
            imgproc::cvt_color_def(&frame, &mut c, imgproc::COLOR_GRAY2BGR)?;
            c
        };
        let frame = if frame.is_continuous() {
            frame
        } else {
            frame.try_clone()?
        };
        let i = self.next;
        self.next += 1;
        Ok(Some((i, frame)))
    }

    /// [`next_bgr`](Self::next_bgr) as plain data for pure code: the index, tightly packed BGR
    /// bytes, width and height.
    pub fn next_bgr_bytes(&mut self) -> Result<Option<(usize, Vec<u8>, usize, usize)>, VideoError> {
        let Some((i, m)) = self.next_bgr()? else {
            return Ok(None);
        };
        let bytes = m.data_bytes()?.to_vec();
        Ok(Some((i, bytes, m.cols() as usize, m.rows() as usize)))
    }

    /// Moves to frame `index` (the next frame read is that one); `false` when the backend cannot.
    pub(crate) fn seek(&mut self, index: usize) -> bool {
        let ok = self
            .cap
            .set(videoio::CAP_PROP_POS_FRAMES, index as f64)
            .unwrap_or(false);
        if ok {
            self.next = index;
        }
        ok
    }

    /// Moves so that the next frame read is `index`, and checks that it did: OpenCV's seeking
    /// is inexact for some codecs, so the frame before `index` is read after the seek and its
    /// timestamp must be that frame's. When the check fails (or the backend cannot seek) the
    /// video is read from the start instead. Returns whether the seek was used.
    pub(crate) fn seek_checked(&mut self, path: &Path, index: usize) -> Result<bool, VideoError> {
        if index == self.next {
            return Ok(false);
        }
        if index > 0 && self.fps > 0.0 && self.seek(index - 1) {
            let mut bgr = std::mem::take(&mut self.bgr);
            let read = self.cap.read(&mut bgr).unwrap_or(false) && !bgr.empty();
            self.bgr = bgr;
            let msec = self.cap.get(videoio::CAP_PROP_POS_MSEC).unwrap_or(-1.0);
            let at = msec * self.fps / 1000.0;
            if read && msec >= 0.0 && (at - (index - 1) as f64).abs() < 0.25 {
                self.next = index;
                return Ok(true);
            }
        }
        // From the start: exact whatever the codec.
        let fresh = FrameReader::open(path)?;
        *self = fresh;
        let mut bgr = std::mem::take(&mut self.bgr);
        for at in 0..index {
            if !self.cap.read(&mut bgr)? || bgr.empty() {
                return Err(VideoError::Ended {
                    path: path.to_path_buf(),
                    index,
                    at,
                });
            }
        }
        self.bgr = bgr;
        self.next = index;
        Ok(false)
    }

    /// Calls `visit(index, bgr, width, height)` with each of the frames `indices` (ascending),
    /// as tightly packed BGR bytes: frames close together are read on, far ones reached by a
    /// checked seek ([`seek_checked`](Self::seek_checked)).
    pub(crate) fn visit_frames(
        path: &Path,
        indices: &[usize],
        mut visit: impl FnMut(usize, &[u8], usize, usize),
    ) -> Result<(), VideoError> {
        let mut r = FrameReader::open(path)?;
        let mut bgr = Mat::default();
        for &f in indices {
            if f < r.next || f > r.next + 30 {
                r.seek_checked(path, f)?;
            }
            while r.next <= f {
                if r.read_bgr_into(&mut bgr)?.is_none() {
                    return Err(VideoError::Ended {
                        path: path.to_path_buf(),
                        index: f,
                        at: r.next,
                    });
                }
            }
            visit(
                f,
                bgr.data_bytes()?,
                bgr.cols() as usize,
                bgr.rows() as usize,
            );
        }
        Ok(())
    }

    /// The colour (BGR) frame at `index`, read from the start.
    pub(crate) fn frame_bgr(path: &Path, index: usize) -> Result<Mat, VideoError> {
        let mut r = FrameReader::open(path)?;
        let mut frame = Mat::default();
        for i in 0..=index {
            if !r.cap.read(&mut frame)? || frame.empty() {
                return Err(VideoError::Ended {
                    path: path.to_path_buf(),
                    index,
                    at: i,
                });
            }
        }
        Ok(frame)
    }

    /// [`frame_bgr`](Self::frame_bgr) as plain data for pure code: tightly packed BGR bytes,
    /// width and height.
    pub fn frame_bgr_bytes(
        path: &Path,
        index: usize,
    ) -> Result<(Vec<u8>, usize, usize), VideoError> {
        let m = Self::frame_bgr(path, index)?;
        let m = if m.is_continuous() { m } else { m.try_clone()? };
        let bytes = m.data_bytes()?.to_vec();
        Ok((bytes, m.cols() as usize, m.rows() as usize))
    }
}
