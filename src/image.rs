//! Plain image buffers (pure): what the simulator renders and the image adapters write.

/// An 8-bit greyscale image, row-major.
pub struct GrayImage {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<u8>,
}
