//! Plain image buffers (pure): what the simulator renders and the image adapters write.

/// An 8-bit greyscale image, row-major.
pub struct GrayImage {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<u8>,
}

/// RGB in [0, 1] from hue (turns: 0 and 1 are red), saturation and value, all in [0, 1].
pub fn hsv_to_rgb(hue: f64, s: f64, v: f64) -> [f64; 3] {
    let h6 = hue.rem_euclid(1.0) * 6.0;
    let c = v * s;
    let x = c * (1.0 - (h6 % 2.0 - 1.0).abs());
    let (r, g, b) = match h6 as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let m = v - c;
    [r + m, g + m, b + m]
}
