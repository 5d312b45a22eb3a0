//! Binary morphology and connected components on small masks (pure): the clean-up of a colour
//! blob in its region of interest.

/// A binary mask.
#[derive(Clone, Debug, PartialEq)]
pub struct Mask {
    pub width: usize,
    pub height: usize,
    pub data: Vec<bool>,
}

/// A connected component: its pixels' count, first moments and second central moments.
#[derive(Clone, Debug, PartialEq)]
pub struct Component {
    pub area: usize,
    /// Mean x, y.
    pub centroid: (f64, f64),
    /// Central second moments (xx, xy, yy), px².
    pub moments: (f64, f64, f64),
    /// Inclusive bounds: x0, y0, x1, y1.
    pub bounds: (usize, usize, usize, usize),
    pub touches_border: bool,
}

impl Component {
    /// Ratio of the principal axes' lengths (1 for a disc).
    pub fn elongation(&self) -> f64 {
        let (xx, xy, yy) = self.moments;
        let tr = xx + yy;
        let det = xx * yy - xy * xy;
        let disc = (tr * tr / 4.0 - det).max(0.0).sqrt();
        let (l1, l2) = (tr / 2.0 + disc, tr / 2.0 - disc);
        if l2 > 0.0 {
            (l1 / l2).sqrt()
        } else {
            f64::INFINITY
        }
    }
}

/// Half-widths of a disc of radius `r` pixels, row by row from `-r` to `r`.
fn disc_half_widths(r: usize) -> Vec<usize> {
    let r = r as isize;
    (-r..=r)
        .map(|dy| {
            (0..=r)
                .rev()
                .find(|dx| dx * dx + dy * dy <= r * r + r / 2)
                .unwrap_or(0) as usize
        })
        .collect()
}

/// Offsets of a disc of radius `r` pixels (the definition the span form must match).
#[cfg(test)]
fn disc(r: usize) -> Vec<(isize, isize)> {
    let r = r as isize;
    let mut v = Vec::new();
    for dy in -r..=r {
        for dx in -r..=r {
            if dx * dx + dy * dy <= r * r + r / 2 {
                v.push((dx, dy));
            }
        }
    }
    v
}

impl Mask {
    pub fn new(width: usize, height: usize) -> Mask {
        Mask {
            width,
            height,
            data: vec![false; width * height],
        }
    }

    pub fn get(&self, x: isize, y: isize) -> bool {
        x >= 0
            && y >= 0
            && (x as usize) < self.width
            && (y as usize) < self.height
            && self.data[y as usize * self.width + x as usize]
    }

    pub fn set(&mut self, x: usize, y: usize, v: bool) {
        self.data[y * self.width + x] = v;
    }

    pub fn count(&self) -> usize {
        self.data.iter().filter(|&&b| b).count()
    }

    /// Dilation by a disc (outside the mask counts as background).
    pub fn dilate(&self, r: usize) -> Mask {
        self.by_disc(r, |count, _| count > 0)
    }

    /// Erosion by a disc (outside the mask counts as background).
    pub fn erode(&self, r: usize) -> Mask {
        self.by_disc(r, |count, len| count == len)
    }

    /// A pixel is set when `keep(ones, span)` holds for every row of the disc centred on it
    /// (dilation: any row has a one; erosion: every row is full), the disc taken as one span of
    /// columns per row offset; ones in a span are counted from per-row prefix sums, so the cost
    /// is the disc's height per pixel, not its area.
    fn by_disc(&self, r: usize, keep: impl Fn(usize, usize) -> bool) -> Mask {
        if r == 0 {
            return self.clone();
        }
        let (w, h) = (self.width, self.height);
        let half = disc_half_widths(r);
        let dilating = keep(1, usize::MAX);
        if w <= 64 && r < 64 {
            return self.by_disc_bits(&half, dilating);
        }
        let mut prefix = vec![0u32; (w + 1) * h];
        for y in 0..h {
            let p = &mut prefix[y * (w + 1)..(y + 1) * (w + 1)];
            for x in 0..w {
                p[x + 1] = p[x] + u32::from(self.data[y * w + x]);
            }
        }
        let mut out = Mask::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let mut any = false;
                let mut all = true;
                for (k, &hw) in half.iter().enumerate() {
                    let yy = y as isize + k as isize - r as isize;
                    let (x0, x1) = (x as isize - hw as isize, x as isize + hw as isize + 1);
                    let len = 2 * hw + 1;
                    let ones = if yy < 0 || yy >= h as isize {
                        0
                    } else {
                        let p = &prefix[yy as usize * (w + 1)..(yy as usize + 1) * (w + 1)];
                        let (c0, c1) = (x0.max(0) as usize, (x1.min(w as isize)) as usize);
                        (p[c1] - p[c0]) as usize
                    };
                    if keep(ones, len) {
                        any = true;
                        if dilating {
                            break;
                        }
                    } else {
                        all = false;
                        if !dilating {
                            break;
                        }
                    }
                }
                out.data[y * w + x] = if dilating { any } else { all };
            }
        }
        out
    }

    /// `by_disc` on a mask at most 64 pixels wide: each row a bit set, a span of ones found by
    /// shifting (a hat's window at 4K fits, and costs a few operations per row).
    fn by_disc_bits(&self, half: &[usize], dilating: bool) -> Mask {
        let (w, h) = (self.width, self.height);
        let r = half.len() / 2;
        let full = if w == 64 { u64::MAX } else { (1u64 << w) - 1 };
        let rows: Vec<u64> = (0..h)
            .map(|y| (0..w).fold(0u64, |b, x| b | (u64::from(self.data[y * w + x]) << x)))
            .collect();
        // Per row and half-width: where a span centred there has any one, or only ones.
        let span = |b: u64, k: usize| -> u64 {
            (1..=k).fold(b, |acc, s| {
                if dilating {
                    acc | (b << s) | (b >> s)
                } else {
                    acc & (b << s) & (b >> s)
                }
            })
        };
        let mut out = Mask::new(w, h);
        for y in 0..h {
            let mut acc = if dilating { 0 } else { full };
            for (k, &hw) in half.iter().enumerate() {
                let yy = y as isize + k as isize - r as isize;
                let row = if yy < 0 || yy >= h as isize {
                    0
                } else {
                    span(rows[yy as usize], hw)
                };
                if dilating {
                    acc |= row;
                } else {
                    acc &= row;
                }
            }
            acc &= full;
            for x in 0..w {
                out.data[y * w + x] = acc >> x & 1 == 1;
            }
        }
        out
    }

    /// Opening: removes parts thinner than the disc (lines, specks).
    pub fn open(&self, r: usize) -> Mask {
        self.erode(r).dilate(r)
    }

    /// Closing: bridges gaps narrower than the disc. The mask is padded so that a blob at the
    /// edge is not eaten.
    pub fn close(&self, r: usize) -> Mask {
        if r == 0 {
            return self.clone();
        }
        let pad = r + 1;
        let mut big = Mask::new(self.width + 2 * pad, self.height + 2 * pad);
        for y in 0..self.height {
            for x in 0..self.width {
                big.data[(y + pad) * big.width + x + pad] = self.data[y * self.width + x];
            }
        }
        let c = big.dilate(r).erode(r);
        let mut out = Mask::new(self.width, self.height);
        for y in 0..self.height {
            for x in 0..self.width {
                out.data[y * self.width + x] = c.data[(y + pad) * c.width + x + pad];
            }
        }
        out
    }

    /// Fills the holes: background not connected to the border becomes foreground.
    pub fn fill_holes(&self) -> Mask {
        let (w, h) = (self.width, self.height);
        let mut outside = vec![false; w * h];
        let mut stack = Vec::new();
        for x in 0..w {
            stack.push((x, 0));
            stack.push((x, h.saturating_sub(1)));
        }
        for y in 0..h {
            stack.push((0, y));
            stack.push((w.saturating_sub(1), y));
        }
        while let Some((x, y)) = stack.pop() {
            let i = y * w + x;
            if self.data[i] || outside[i] {
                continue;
            }
            outside[i] = true;
            if x > 0 {
                stack.push((x - 1, y));
            }
            if x + 1 < w {
                stack.push((x + 1, y));
            }
            if y > 0 {
                stack.push((x, y - 1));
            }
            if y + 1 < h {
                stack.push((x, y + 1));
            }
        }
        Mask {
            width: w,
            height: h,
            data: (0..w * h).map(|i| self.data[i] || !outside[i]).collect(),
        }
    }

    /// 8-connected components.
    pub fn components(&self) -> Vec<Component> {
        self.components_with_pixels()
            .into_iter()
            .map(|(c, _)| c)
            .collect()
    }

    /// 8-connected components with their pixels `(x, y)`.
    pub fn components_with_pixels(&self) -> Vec<(Component, Vec<(usize, usize)>)> {
        let (w, h) = (self.width, self.height);
        let mut seen = vec![false; w * h];
        let mut out = Vec::new();
        let mut stack = Vec::new();
        for start in 0..w * h {
            if !self.data[start] || seen[start] {
                continue;
            }
            seen[start] = true;
            stack.push(start);
            let (mut n, mut sx, mut sy, mut sxx, mut sxy, mut syy) =
                (0usize, 0.0, 0.0, 0.0, 0.0, 0.0);
            let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
            let mut pixels = Vec::new();
            while let Some(i) = stack.pop() {
                let (x, y) = (i % w, i / w);
                pixels.push((x, y));
                n += 1;
                let (fx, fy) = (x as f64, y as f64);
                sx += fx;
                sy += fy;
                sxx += fx * fx;
                sxy += fx * fy;
                syy += fy * fy;
                (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
                for dy in -1isize..=1 {
                    for dx in -1isize..=1 {
                        let (u, v) = (x as isize + dx, y as isize + dy);
                        if u >= 0 && v >= 0 && (u as usize) < w && (v as usize) < h {
                            let j = v as usize * w + u as usize;
                            if self.data[j] && !seen[j] {
                                seen[j] = true;
                                stack.push(j);
                            }
                        }
                    }
                }
            }
            let nf = n as f64;
            let (mx, my) = (sx / nf, sy / nf);
            out.push((
                Component {
                    area: n,
                    centroid: (mx, my),
                    moments: (sxx / nf - mx * mx, sxy / nf - mx * my, syy / nf - my * my),
                    bounds: (x0, y0, x1, y1),
                    touches_border: x0 == 0 || y0 == 0 || x1 + 1 == w || y1 + 1 == h,
                },
                pixels,
            ));
        }
        out
    }
}

/// Splits a blob's pixels into `k` compact parts (k-means on the coordinates, seeded along the
/// principal axis): two or three touching hats become two or three. Returns each part's pixel
/// count, centroid and bounds.
pub fn split(pixels: &[(usize, usize)], k: usize) -> Vec<Component> {
    let n = pixels.len() as f64;
    let (mx, my) = pixels
        .iter()
        .fold((0.0, 0.0), |a, p| (a.0 + p.0 as f64, a.1 + p.1 as f64));
    let (mx, my) = (mx / n, my / n);
    let (mut xx, mut xy, mut yy) = (0.0, 0.0, 0.0);
    for p in pixels {
        let (dx, dy) = (p.0 as f64 - mx, p.1 as f64 - my);
        xx += dx * dx;
        xy += dx * dy;
        yy += dy * dy;
    }
    // Principal direction.
    let angle = 0.5 * (2.0 * xy).atan2(xx - yy);
    let (ux, uy) = (angle.cos(), angle.sin());
    let proj: Vec<f64> = pixels
        .iter()
        .map(|p| (p.0 as f64 - mx) * ux + (p.1 as f64 - my) * uy)
        .collect();
    let (lo, hi) = proj
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |a, &t| {
            (a.0.min(t), a.1.max(t))
        });
    let mut centres: Vec<(f64, f64)> = (0..k)
        .map(|i| {
            let t = lo + (hi - lo) * (i as f64 + 0.5) / k as f64;
            (mx + t * ux, my + t * uy)
        })
        .collect();
    let mut label = vec![0usize; pixels.len()];
    for _ in 0..50 {
        let mut changed = false;
        for (l, p) in label.iter_mut().zip(pixels) {
            let d = |c: &(f64, f64)| (p.0 as f64 - c.0).powi(2) + (p.1 as f64 - c.1).powi(2);
            let best = (0..k)
                .min_by(|&a, &b| d(&centres[a]).total_cmp(&d(&centres[b])))
                .expect("k ≥ 1");
            if *l != best {
                *l = best;
                changed = true;
            }
        }
        let mut sums = vec![(0.0, 0.0, 0usize); k];
        for (l, p) in label.iter().zip(pixels) {
            sums[*l].0 += p.0 as f64;
            sums[*l].1 += p.1 as f64;
            sums[*l].2 += 1;
        }
        for (c, s) in centres.iter_mut().zip(&sums) {
            if s.2 > 0 {
                *c = (s.0 / s.2 as f64, s.1 / s.2 as f64);
            }
        }
        if !changed {
            break;
        }
    }
    (0..k)
        .filter_map(|i| {
            let part: Vec<(usize, usize)> = pixels
                .iter()
                .zip(&label)
                .filter(|(_, l)| **l == i)
                .map(|(p, _)| *p)
                .collect();
            if part.is_empty() {
                return None;
            }
            let m = part.len() as f64;
            let (cx, cy) = part
                .iter()
                .fold((0.0, 0.0), |a, p| (a.0 + p.0 as f64, a.1 + p.1 as f64));
            let (cx, cy) = (cx / m, cy / m);
            let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
            for p in &part {
                let (dx, dy) = (p.0 as f64 - cx, p.1 as f64 - cy);
                sxx += dx * dx;
                sxy += dx * dy;
                syy += dy * dy;
            }
            let b = part.iter().fold((usize::MAX, usize::MAX, 0, 0), |a, p| {
                (a.0.min(p.0), a.1.min(p.1), a.2.max(p.0), a.3.max(p.1))
            });
            Some(Component {
                area: part.len(),
                centroid: (cx, cy),
                moments: (sxx / m, sxy / m, syy / m),
                bounds: b,
                touches_border: false,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn span_morphology_equals_the_disc_definition() {
        for (w, h) in [(37, 29), (64, 20), (90, 17)] {
            check_span_morphology(w, h);
        }
    }

    fn check_span_morphology(w: usize, h: usize) {
        let mut m = Mask::new(w, h);
        let mut state = 12345u64;
        for v in m.data.iter_mut() {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            *v = !(state >> 33).is_multiple_of(3);
        }
        for r in 1..5 {
            let se = disc(r);
            let (mut dil, mut ero) = (Mask::new(w, h), Mask::new(w, h));
            for y in 0..h {
                for x in 0..w {
                    let at = |&(dx, dy): &(isize, isize)| m.get(x as isize + dx, y as isize + dy);
                    dil.data[y * w + x] = se.iter().any(at);
                    ero.data[y * w + x] = se.iter().all(at);
                }
            }
            assert_eq!(m.dilate(r), dil, "dilation, r = {r}");
            assert_eq!(m.erode(r), ero, "erosion, r = {r}");
        }
    }

    fn disc_mask(w: usize, h: usize, cx: f64, cy: f64, r: f64) -> Mask {
        let mut m = Mask::new(w, h);
        for y in 0..h {
            for x in 0..w {
                m.set(
                    x,
                    y,
                    (x as f64 - cx).powi(2) + (y as f64 - cy).powi(2) <= r * r,
                );
            }
        }
        m
    }

    #[test]
    fn cleans_a_ragged_disc_and_measures_it() {
        let mut m = disc_mask(40, 40, 20.3, 18.7, 9.0);
        // A hole, a gap, a thin line and a speck.
        for (x, y) in [(20, 18), (21, 18), (20, 19), (21, 19)] {
            m.set(x, y, false);
        }
        for y in 10..28 {
            m.set(24, y, false);
        }
        for x in 0..40 {
            m.set(x, 35, true);
        }
        m.set(2, 2, true);
        let clean = m.fill_holes().close(2).open(2);
        let comps = clean.components();
        assert_eq!(comps.len(), 1, "{comps:?}");
        let c = &comps[0];
        assert!(
            (c.centroid.0 - 20.3).abs() < 0.3 && (c.centroid.1 - 18.7).abs() < 0.3,
            "{:?}",
            c.centroid
        );
        assert!(
            (c.area as f64 - std::f64::consts::PI * 81.0).abs() < 30.0,
            "{}",
            c.area
        );
        assert!(c.elongation() < 1.1);
        assert!(!c.touches_border);
    }

    #[test]
    fn two_touching_discs_split_into_their_centres() {
        let mut m = disc_mask(60, 40, 20.0, 20.0, 8.0);
        let b = disc_mask(60, 40, 36.0, 21.0, 8.0);
        for i in 0..m.data.len() {
            m.data[i] |= b.data[i];
        }
        let (_, pixels) = &m.components_with_pixels()[0];
        let parts = split(pixels, 2);
        assert_eq!(parts.len(), 2);
        for (cx, cy) in [(20.0, 20.0), (36.0, 21.0)] {
            let d = parts
                .iter()
                .map(|p| (p.centroid.0 - cx).hypot(p.centroid.1 - cy))
                .fold(f64::INFINITY, f64::min);
            assert!(d < 0.5, "{d}");
        }
    }

    #[test]
    fn elongation_of_a_bar() {
        let mut m = Mask::new(30, 10);
        for y in 4..6 {
            for x in 5..25 {
                m.set(x, y, true);
            }
        }
        assert!(m.components()[0].elongation() > 5.0);
    }
}
