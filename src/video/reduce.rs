//! Reducing a gray frame by pixel area.
//!
//! OpenCV 4.6's area reduction by a whole odd factor (a 4K frame to the KLT tracker's 1280 px
//! working copy) runs a generic loop: 2.3 ms a frame on one core, a twentieth of a crowd scan.
//! The box sum below gives the same pixels (an odd block has no halves to round) in about a
//! quarter of the time; every other factor goes to OpenCV.

use opencv::core::{CV_8UC1, Mat, Size, ToInputArray};
use opencv::imgproc;
use opencv::prelude::*;

/// `from` (8-bit, one channel) reduced to `size` by pixel area into `to` (or copied when the
/// sizes agree): the pixels of OpenCV's `INTER_AREA`.
pub(crate) fn area_reduce(
    from: &(impl MatTraitConst + ToInputArray),
    to: &mut Mat,
    size: Size,
) -> Result<(), opencv::Error> {
    let (w, h) = (from.cols(), from.rows());
    if from.size()? == size {
        return from.copy_to(to);
    }
    let f = if size.width > 0 { w / size.width } else { 0 };
    let whole_odd = f >= 3
        && f % 2 == 1
        && f <= 15
        && w == f * size.width
        && h == f * size.height
        && from.typ() == CV_8UC1;
    if !whole_odd {
        return imgproc::resize(from, to, size, 0.0, 0.0, imgproc::INTER_AREA);
    }
    if to.size()? != size || to.typ() != CV_8UC1 || !to.is_continuous() {
        *to = Mat::new_size_with_default(size, CV_8UC1, 0.into())?;
    }
    let step = from.step1_def()?;
    // A view into a wider image is read row by row: its bytes up to its last pixel.
    let len = step * (h as usize - 1) + w as usize;
    // SAFETY: an 8-bit one-channel Mat of `h` rows of `step` bytes holds `len` bytes from `data`.
    let src = unsafe { std::slice::from_raw_parts(from.data(), len) };
    let dst = to.data_bytes_mut()?;
    box_reduce(
        src,
        step,
        (size.width as usize, size.height as usize),
        f as usize,
        dst,
    );
    Ok(())
}

/// Means of `f` × `f` blocks (f odd, so no mean is a half; column sums of f ≤ 15 fit u16):
/// `src` rows of `step` bytes, `dst` `out_w` × `out_h` continuous.
fn box_reduce(src: &[u8], step: usize, out: (usize, usize), f: usize, dst: &mut [u8]) {
    // The common factors with the block size known to the compiler (unrolled, divided by a
    // constant).
    match f {
        3 => box_reduce_by::<3>(src, step, out, dst),
        5 => box_reduce_by::<5>(src, step, out, dst),
        _ => box_reduce_any(src, step, out, f, dst),
    }
}

fn box_reduce_by<const F: usize>(
    src: &[u8],
    step: usize,
    (out_w, out_h): (usize, usize),
    dst: &mut [u8],
) {
    let in_w = out_w * F;
    let area = (F * F) as u32;
    let mut column = vec![0u16; in_w];
    for (y, out_row) in dst.chunks_exact_mut(out_w).take(out_h).enumerate() {
        let first = y * F * step;
        for (c, &p) in column.iter_mut().zip(&src[first..first + in_w]) {
            *c = u16::from(p);
        }
        for r in 1..F {
            let start = first + r * step;
            for (c, &p) in column.iter_mut().zip(&src[start..start + in_w]) {
                *c += u16::from(p);
            }
        }
        for (o, block) in out_row.iter_mut().zip(column.chunks_exact(F)) {
            let block: &[u16; F] = block.try_into().expect("F wide");
            let sum: u32 = block.iter().map(|&v| u32::from(v)).sum();
            *o = ((sum + area / 2) / area) as u8;
        }
    }
}

fn box_reduce_any(
    src: &[u8],
    step: usize,
    (out_w, out_h): (usize, usize),
    f: usize,
    dst: &mut [u8],
) {
    let in_w = out_w * f;
    let area = (f * f) as u32;
    let mut column = vec![0u16; in_w];
    for (y, out_row) in dst.chunks_exact_mut(out_w).take(out_h).enumerate() {
        column.fill(0);
        for r in 0..f {
            let start = (y * f + r) * step;
            for (c, &p) in column.iter_mut().zip(&src[start..start + in_w]) {
                *c += u16::from(p);
            }
        }
        for (o, block) in out_row.iter_mut().zip(column.chunks_exact(f)) {
            let sum: u32 = block.iter().map(|&v| u32::from(v)).sum();
            *o = ((sum + area / 2) / area) as u8;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use opencv::core::{Rect, Scalar};

    fn noise(w: i32, h: i32, seed: u64) -> Mat {
        let mut m = Mat::new_rows_cols_with_default(h, w, CV_8UC1, Scalar::all(0.0)).unwrap();
        let mut s = seed;
        for p in m.data_bytes_mut().unwrap() {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            *p = (s >> 56) as u8;
        }
        m
    }

    #[test]
    fn odd_whole_factors_give_opencvs_area_pixels() {
        for (w, h, f, seed) in [
            (30, 21, 3, 1),
            (3840, 2160, 3, 2),
            (75, 50, 5, 3),
            (63, 35, 7, 4),
        ] {
            let from = noise(w, h, seed);
            let size = Size::new(w / f, h / f);
            let (mut ours, mut theirs) = (Mat::default(), Mat::default());
            area_reduce(&from, &mut ours, size).unwrap();
            imgproc::resize(&from, &mut theirs, size, 0.0, 0.0, imgproc::INTER_AREA).unwrap();
            assert_eq!(ours.size().unwrap(), size);
            assert_eq!(
                ours.data_bytes().unwrap(),
                theirs.data_bytes().unwrap(),
                "{w}x{h} by {f}"
            );
        }
    }

    #[test]
    fn a_view_into_a_wider_image_and_other_factors() {
        // A region of interest: rows longer than the block rows read.
        let big = noise(100, 40, 5);
        let view = Mat::roi(&big, Rect::new(7, 3, 90, 36)).unwrap();
        let (mut ours, mut theirs) = (Mat::default(), Mat::default());
        for size in [
            Size::new(30, 12),
            Size::new(45, 18),
            Size::new(60, 24),
            Size::new(90, 36),
        ] {
            area_reduce(&view, &mut ours, size).unwrap();
            imgproc::resize(&view, &mut theirs, size, 0.0, 0.0, imgproc::INTER_AREA).unwrap();
            assert_eq!(
                ours.data_bytes().unwrap(),
                theirs.data_bytes().unwrap(),
                "{size:?}"
            );
        }
    }
}
