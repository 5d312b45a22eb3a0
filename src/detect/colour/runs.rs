//! Hat-coloured runs of pixels per row, found through the palette's table.

use super::*;

/// A frame's size, pixels.
pub(super) struct Size {
    pub(super) width: usize,
    pub(super) height: usize,
}

/// A horizontal run of foreground pixels `[x0, x1)` in row `y`.
#[derive(Clone, Copy, Debug)]
pub(super) struct Run {
    pub(super) y: usize,
    pub(super) x0: usize,
    pub(super) x1: usize,
}

pub(super) fn find(parent: &mut [usize], mut i: usize) -> usize {
    while parent[i] != i {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    i
}

/// The colours that could be a hat whatever the palette: a hue within the tolerance plus 30°
/// of the target's and at least 15 % of its chroma (shaded and blurred hat edges included). A
/// hat colour must also be in this set, so that frames can be screened before the palette is
/// learnt.
pub(super) fn permissive_table(s: &ColourSettings) -> Vec<u64> {
    let (th, tc) = hue_chroma(&lab(s.target_rgb));
    let mut table = vec![0u64; (1 << 18) / 64];
    table.par_iter_mut().enumerate().for_each(|(i, word)| {
        for bit in 0..64 {
            let (h, c) = hue_chroma(&lab(bin_rgb(i * 64 + bit)));
            if hue_difference(h, th) <= s.max_hue_difference_deg + 30.0 && c >= 0.15 * tc {
                *word |= 1 << bit;
            }
        }
    });
    table
}

/// Whether the 6-bit colour `i` is in a bit table.
#[inline]
pub(super) fn has_colour(table: &[u64], i: usize) -> bool {
    table[i >> 6] >> (i & 63) & 1 == 1
}

#[inline]
pub(super) fn in_table(table: &[u64], px: &[u8]) -> bool {
    has_colour(table, index_bgr(px[0], px[1], px[2]))
}

/// Hat radius in pixels.
pub(super) fn hat_radius_px(s: &ColourSettings) -> f64 {
    0.5 * s.hat_diameter_m * s.px_per_m
}

/// Runs of the rows `ys` whose colours are in `table`, each row scanned over the column ranges
/// `[x0, x1)` that `ranges` gives for it (ascending, apart).
pub(super) fn runs_in<I: Iterator<Item = (usize, usize)>>(
    f: &FrameView,
    table: &[u64],
    ys: std::ops::Range<usize>,
    ranges: impl Fn(usize) -> I,
) -> Vec<Run> {
    let mut runs = Vec::new();
    for y in ys {
        let row = &f.bgr[3 * y * f.width..3 * (y + 1) * f.width];
        for (x0, x1) in ranges(y) {
            let mut start: Option<usize> = None;
            for x in x0..x1 {
                match (in_table(table, &row[3 * x..3 * x + 3]), start) {
                    (true, None) => start = Some(x),
                    (false, Some(s)) => {
                        runs.push(Run { y, x0: s, x1: x });
                        start = None;
                    }
                    _ => {}
                }
            }
            if let Some(s) = start {
                runs.push(Run { y, x0: s, x1 });
            }
        }
    }
    runs
}

/// Runs of a frame's colours in `table`, row by row. When hats span many pixels, a grid of every
/// `step`-th pixel of every `step`-th row (half the hat's radius: a whole hat holds a dozen grid
/// points, an edge-cut or half-hidden one several) is classified first, and only tiles near a
/// hit (and their neighbours, which hold any fringe of the same blob) are scanned in full: a 4K
/// frame of a few dozen hats costs a fraction of a full pass, with the same runs.
pub(super) fn table_runs(f: &FrameView, table: &[u64], r_hat_px: f64) -> Vec<Run> {
    let step = (r_hat_px / 2.0).floor().max(1.0) as usize;
    if step == 1 {
        return runs_in(f, table, 0..f.height, |_| std::iter::once((0, f.width)));
    }
    let tile = (2 * step).max(16);
    let (tw, th) = (f.width.div_ceil(tile), f.height.div_ceil(tile));
    let mut hit = vec![false; tw * th];
    for y in (step / 2..f.height).step_by(step) {
        let row = &f.bgr[3 * y * f.width..3 * (y + 1) * f.width];
        for x in (step / 2..f.width).step_by(step) {
            if in_table(table, &row[3 * x..3 * x + 3]) {
                hit[(y / tile) * tw + x / tile] = true;
            }
        }
    }
    // Flagged: a hit in the tile or in one of its eight neighbours.
    let mut spans: Vec<Vec<(usize, usize)>> = vec![Vec::new(); th];
    for (ty, row_spans) in spans.iter_mut().enumerate() {
        let mut open: Option<usize> = None;
        for tx in 0..=tw {
            let flagged = tx < tw
                && (ty.saturating_sub(1)..(ty + 2).min(th))
                    .any(|yy| (tx.saturating_sub(1)..(tx + 2).min(tw)).any(|xx| hit[yy * tw + xx]));
            match (flagged, open) {
                (true, None) => open = Some(tx),
                (false, Some(t0)) => {
                    row_spans.push((t0 * tile, (tx * tile).min(f.width)));
                    open = None;
                }
                _ => {}
            }
        }
    }
    runs_in(f, table, 0..f.height, |y| spans[y / tile].iter().copied())
}
