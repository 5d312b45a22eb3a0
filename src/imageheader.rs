//! An image's pixel size read from its file header (pure: std only), so that a file claiming a
//! huge image is refused before any decoder allocates for it. JPEG, PNG, TIFF (and BigTIFF),
//! BMP, WebP and PNM are read; another format gives `None` and is left to the decoder (whose
//! own limit, `OPENCV_IO_MAX_IMAGE_PIXELS`, `main` sets to the same bound).

use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

use crate::camera::MAX_IMAGE_SIDE;

/// The most pixels geostride decodes in one image: a 151-megapixel medium-format photo fits. Decoded
/// in colour that is 480 MB, about a quarter of the 2 GB any command may use.
pub const MAX_IMAGE_PIXELS: u64 = 160_000_000;

/// A format whose header names the image's size.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Jpeg,
    Png,
    Tiff,
    Bmp,
    WebP,
    Pnm,
}

/// Why an image file is refused before decoding.
#[derive(Debug, thiserror::Error)]
pub enum HeaderError {
    #[error(
        "its header claims {width}x{height} pixels: geostride reads images up to {MAX_IMAGE_SIDE} pixels on a side and {} megapixels in all; reduce the image or give a smaller one",
        MAX_IMAGE_PIXELS / 1_000_000
    )]
    TooLarge { width: u64, height: u64 },
    #[error("its header claims an image of {width}x{height} pixels: not an image")]
    Empty { width: u64, height: u64 },
    #[error("{0}")]
    Io(#[from] std::io::Error),
}

/// The size stated by the header of an image in `r` (its start at the reader's position 0):
/// `None` where the format is not one of [`Format`] or the header is cut short.
pub fn read_size<R: Read + Seek>(r: &mut R) -> std::io::Result<Option<(Format, u64, u64)>> {
    let mut head = [0u8; 32];
    let n = read_up_to(r, &mut head)?;
    let head = &head[..n];
    let le16 = |b: &[u8]| u16::from_le_bytes([b[0], b[1]]) as u64;
    let be32 = |b: &[u8]| u32::from_be_bytes([b[0], b[1], b[2], b[3]]) as u64;
    let le32 = |b: &[u8]| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as u64;
    if head.starts_with(&[0xFF, 0xD8]) {
        return Ok(jpeg_size(r)?.map(|(w, h)| (Format::Jpeg, w, h)));
    }
    if head.starts_with(b"\x89PNG\r\n\x1a\n") && head.len() >= 24 && &head[12..16] == b"IHDR" {
        return Ok(Some((Format::Png, be32(&head[16..]), be32(&head[20..]))));
    }
    if head.starts_with(b"II") || head.starts_with(b"MM") {
        return Ok(tiff_size(r, head.starts_with(b"II"))?.map(|(w, h)| (Format::Tiff, w, h)));
    }
    if head.starts_with(b"BM") && head.len() >= 26 {
        let w = le32(&head[18..]) as u32 as i32;
        let h = le32(&head[22..]) as u32 as i32;
        return Ok(Some((
            Format::Bmp,
            w.unsigned_abs() as u64,
            h.unsigned_abs() as u64,
        )));
    }
    if head.len() == 32 && head.starts_with(b"RIFF") && &head[8..12] == b"WEBP" {
        let size = match &head[12..16] {
            b"VP8X" => Some((
                (le32(&head[24..]) & 0xFF_FFFF) + 1,
                (le32(&head[27..]) & 0xFF_FFFF) + 1,
            )),
            b"VP8L" => {
                let bits = le32(&head[21..]);
                Some(((bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1))
            }
            b"VP8 " => Some((le16(&head[26..]) & 0x3FFF, le16(&head[28..]) & 0x3FFF)),
            _ => None,
        };
        return Ok(size.map(|(w, h)| (Format::WebP, w, h)));
    }
    if head.len() >= 2 && head[0] == b'P' && (b'1'..=b'6').contains(&head[1]) {
        return Ok(pnm_size(r)?.map(|(w, h)| (Format::Pnm, w, h)));
    }
    Ok(None)
}

/// Reads `buf.len()` bytes from the start, or as many as there are.
fn read_up_to<R: Read + Seek>(r: &mut R, buf: &mut [u8]) -> std::io::Result<usize> {
    r.seek(SeekFrom::Start(0))?;
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..])? {
            0 => break,
            k => n += k,
        }
    }
    Ok(n)
}

fn read_exact_or_none<R: Read>(r: &mut R, buf: &mut [u8]) -> std::io::Result<bool> {
    match r.read_exact(buf) {
        Ok(()) => Ok(true),
        Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => Ok(false),
        Err(e) => Err(e),
    }
}

/// A JPEG's size from its first start-of-frame marker, walking the segments after SOI.
fn jpeg_size<R: Read + Seek>(r: &mut R) -> std::io::Result<Option<(u64, u64)>> {
    r.seek(SeekFrom::Start(2))?;
    // A file of empty segments could hold millions; a real header has tens.
    for _ in 0..100_000 {
        let mut b = [0u8; 1];
        if !read_exact_or_none(r, &mut b)? {
            return Ok(None);
        }
        if b[0] != 0xFF {
            return Ok(None);
        }
        let mut marker = 0xFFu8;
        while marker == 0xFF {
            if !read_exact_or_none(r, &mut b)? {
                return Ok(None);
            }
            marker = b[0];
        }
        match marker {
            // Markers without a length: TEM, RSTn, a stray SOI.
            0x01 | 0xD0..=0xD8 => continue,
            // End of image or start of scan before any frame header.
            0xD9 | 0xDA => return Ok(None),
            _ => {}
        }
        let mut len = [0u8; 2];
        if !read_exact_or_none(r, &mut len)? {
            return Ok(None);
        }
        let len = u16::from_be_bytes(len) as i64;
        if len < 2 {
            return Ok(None);
        }
        let is_frame = matches!(marker, 0xC0..=0xCF) && !matches!(marker, 0xC4 | 0xC8 | 0xCC);
        if is_frame {
            let mut f = [0u8; 5];
            if !read_exact_or_none(r, &mut f)? {
                return Ok(None);
            }
            let h = u16::from_be_bytes([f[1], f[2]]) as u64;
            let w = u16::from_be_bytes([f[3], f[4]]) as u64;
            return Ok(Some((w, h)));
        }
        r.seek(SeekFrom::Current(len - 2))?;
    }
    Ok(None)
}

/// A TIFF's (or BigTIFF's) size from the first image directory's width and length tags.
fn tiff_size<R: Read + Seek>(r: &mut R, little: bool) -> std::io::Result<Option<(u64, u64)>> {
    let u16_of = |b: &[u8]| {
        if little {
            u16::from_le_bytes([b[0], b[1]])
        } else {
            u16::from_be_bytes([b[0], b[1]])
        }
    };
    let u32_of = |b: &[u8]| {
        let a = [b[0], b[1], b[2], b[3]];
        if little {
            u32::from_le_bytes(a)
        } else {
            u32::from_be_bytes(a)
        }
    };
    let u64_of = |b: &[u8]| {
        let a: [u8; 8] = b[..8].try_into().expect("8 bytes");
        if little {
            u64::from_le_bytes(a)
        } else {
            u64::from_be_bytes(a)
        }
    };
    let mut head = [0u8; 16];
    if read_up_to(r, &mut head)? < 8 {
        return Ok(None);
    }
    let big = match u16_of(&head[2..]) {
        42 => false,
        43 => true,
        _ => return Ok(None),
    };
    let ifd = if big {
        u64_of(&head[8..])
    } else {
        u32_of(&head[4..]) as u64
    };
    r.seek(SeekFrom::Start(ifd))?;
    let entries = if big {
        let mut n = [0u8; 8];
        if !read_exact_or_none(r, &mut n)? {
            return Ok(None);
        }
        u64_of(&n)
    } else {
        let mut n = [0u8; 2];
        if !read_exact_or_none(r, &mut n)? {
            return Ok(None);
        }
        u16_of(&n) as u64
    };
    let (mut width, mut height) = (None, None);
    let entry_len = if big { 20 } else { 12 };
    for _ in 0..entries.min(4096) {
        let mut e = [0u8; 20];
        if !read_exact_or_none(r, &mut e[..entry_len])? {
            return Ok(None);
        }
        let tag = u16_of(&e);
        let kind = u16_of(&e[2..]);
        let at = if big { 12 } else { 8 };
        let value = match kind {
            3 => u16_of(&e[at..]) as u64,
            4 => u32_of(&e[at..]) as u64,
            16 if big => u64_of(&e[at..]),
            _ => continue,
        };
        match tag {
            256 => width = Some(value),
            257 => height = Some(value),
            _ => {}
        }
        if let (Some(w), Some(h)) = (width, height) {
            return Ok(Some((w, h)));
        }
    }
    Ok(None)
}

/// A PNM's size: the two numbers after the magic, comments skipped.
fn pnm_size<R: Read + Seek>(r: &mut R) -> std::io::Result<Option<(u64, u64)>> {
    let mut head = [0u8; 512];
    let n = read_up_to(r, &mut head)?;
    let mut numbers = Vec::new();
    let mut i = 2;
    while numbers.len() < 2 && i < n {
        let c = head[i];
        if c == b'#' {
            while i < n && head[i] != b'\n' {
                i += 1;
            }
        } else if c.is_ascii_digit() {
            let mut v = 0u64;
            while i < n && head[i].is_ascii_digit() {
                v = v.saturating_mul(10).saturating_add((head[i] - b'0') as u64);
                i += 1;
            }
            if i == n {
                // Cut short: the number may go on.
                return Ok(None);
            }
            numbers.push(v);
            continue;
        } else if !c.is_ascii_whitespace() {
            return Ok(None);
        }
        i += 1;
    }
    Ok((numbers.len() == 2).then(|| (numbers[0], numbers[1])))
}

/// Checks a size against geostride's limits.
pub fn check_size(width: u64, height: u64) -> Result<(), HeaderError> {
    if width == 0 || height == 0 {
        return Err(HeaderError::Empty { width, height });
    }
    if width > MAX_IMAGE_SIDE as u64
        || height > MAX_IMAGE_SIDE as u64
        || width.saturating_mul(height) > MAX_IMAGE_PIXELS
    {
        return Err(HeaderError::TooLarge { width, height });
    }
    Ok(())
}

/// The size an image file's header states, checked against geostride's limits before any
/// decoding; `None` for a format whose header is not read here (the decoder decides).
pub fn check_file(path: &Path) -> Result<Option<(u32, u32)>, HeaderError> {
    let mut f = std::io::BufReader::with_capacity(4096, std::fs::File::open(path)?);
    match read_size(&mut f)? {
        Some((_, w, h)) => {
            check_size(w, h)?;
            Ok(Some((w as u32, h as u32)))
        }
        None => Ok(None),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Cursor;

    fn size(bytes: &[u8]) -> Option<(Format, u64, u64)> {
        read_size(&mut Cursor::new(bytes)).unwrap()
    }

    /// A JPEG header: SOI, an APP1 segment, then a baseline frame of `w`x`h`.
    fn jpeg(w: u16, h: u16, app_len: usize) -> Vec<u8> {
        let mut b = vec![0xFF, 0xD8, 0xFF, 0xE1];
        b.extend(((app_len + 2) as u16).to_be_bytes());
        b.extend(vec![0u8; app_len]);
        b.extend([0xFF, 0xFF, 0xC0, 0, 17, 8]);
        b.extend(h.to_be_bytes());
        b.extend(w.to_be_bytes());
        b.extend([3u8; 12]);
        b
    }

    #[test]
    fn sizes_are_read_from_each_header() {
        assert_eq!(
            size(&jpeg(4000, 3000, 60_000)),
            Some((Format::Jpeg, 4000, 3000))
        );
        let mut png = b"\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR".to_vec();
        png.extend(640u32.to_be_bytes());
        png.extend(480u32.to_be_bytes());
        png.extend([8, 2, 0, 0, 0]);
        assert_eq!(size(&png), Some((Format::Png, 640, 480)));
        // Little-endian TIFF, one directory of two LONG tags.
        let mut tiff = b"II*\0".to_vec();
        tiff.extend(8u32.to_le_bytes());
        tiff.extend(2u16.to_le_bytes());
        for (tag, v) in [(256u16, 32000u32), (257, 32000)] {
            tiff.extend(tag.to_le_bytes());
            tiff.extend(4u16.to_le_bytes());
            tiff.extend(1u32.to_le_bytes());
            tiff.extend(v.to_le_bytes());
        }
        assert_eq!(size(&tiff), Some((Format::Tiff, 32000, 32000)));
        let mut bmp = b"BM".to_vec();
        bmp.extend([0u8; 16]);
        bmp.extend(100i32.to_le_bytes());
        bmp.extend((-50i32).to_le_bytes());
        assert_eq!(size(&bmp), Some((Format::Bmp, 100, 50)));
        assert_eq!(
            size(b"P5\n# a comment\n 1920 1080\n255\n"),
            Some((Format::Pnm, 1920, 1080))
        );
        assert_eq!(size(b"GIF89a...."), None);
        assert_eq!(size(&[0xFF, 0xD8, 0xFF, 0xDA, 0, 2]), None);
    }

    #[test]
    fn a_header_claiming_a_huge_image_is_refused_and_a_real_one_kept() {
        assert!(matches!(
            check_size(32000, 32000),
            Err(HeaderError::TooLarge { .. })
        ));
        assert!(matches!(check_size(0, 10), Err(HeaderError::Empty { .. })));
        assert!(check_size(14_204, 10_652).is_ok());
        assert!(check_size(40_000, 10).is_err());
    }

    #[test]
    fn cut_or_hostile_headers_end_without_a_panic() {
        let full = jpeg(4000, 3000, 100);
        for cut in 0..full.len() {
            let _ = size(&full[..cut]);
        }
        // A segment length below 2, a directory beyond the end, many empty segments.
        assert_eq!(size(&[0xFF, 0xD8, 0xFF, 0xE0, 0, 1]), None);
        let mut tiff = b"MM\0*".to_vec();
        tiff.extend(u32::MAX.to_be_bytes());
        assert_eq!(size(&tiff), None);
        let mut many = vec![0xFF, 0xD8];
        for _ in 0..200_000 {
            many.extend([0xFF, 0xE2, 0, 2]);
        }
        assert_eq!(size(&many), None);
    }
}
