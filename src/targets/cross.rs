//! Cross targets (a white cross, bars about a fifth of the side wide, on a black square), whose
//! centre is no saddle: a ring response over an image pyramid finds candidates (a ring around
//! the centre crosses four white arms: its fourth harmonic strong, its first and second weak),
//! then each is measured along its diagonals (bar width and side) and placed where the image is
//! most alike under a half and a quarter turn about the centre, its σ from that fit.

use nalgebra::{Matrix2, Vector2};

use super::Gray;
use super::detect::{Candidate, Rejected, Smoothed, TargetSettings, examine_seeds, pyramid_seeds};

/// Ring radius of the response at every pyramid level, pixels of that level.
const RING_PX: f64 = 4.0;

/// cos θ, sin θ, cos 2θ, sin 2θ of the 16 angles round the ring.
type Trig = [[f32; 4]; 16];

fn ring_trig() -> Trig {
    std::array::from_fn(|k| {
        let a = k as f32 * std::f32::consts::TAU / 16.0;
        [a.cos(), a.sin(), (2.0 * a).cos(), (2.0 * a).sin()]
    })
}

/// The first and second harmonics' amplitudes of 16 samples round a ring.
fn low_harmonics(s: &[f32; 16], trig: &Trig) -> (f32, f32) {
    let (mut c1, mut s1, mut c2, mut s2) = (0.0f32, 0.0f32, 0.0f32, 0.0f32);
    for (v, t) in s.iter().zip(trig) {
        c1 += v * t[0];
        s1 += v * t[1];
        c2 += v * t[2];
        s2 += v * t[3];
    }
    (c1.hypot(s1), c2.hypot(s2))
}

/// The cross response at `(x, y)` of `img` from its ring `s` (0 below `threshold`).
fn cross_response(
    img: &Gray,
    s: &[f32; 16],
    x: usize,
    y: usize,
    threshold: f32,
    trig: &Trig,
) -> f32 {
    // cos and sin of k·90°: the fourth harmonic exactly, and first, since the response is at
    // most it.
    let c4 = s[0] - s[2] + s[4] - s[6] + s[8] - s[10] + s[12] - s[14];
    let s4 = s[1] - s[3] + s[5] - s[7] + s[9] - s[11] + s[13] - s[15];
    let a4 = c4.hypot(s4);
    if a4 < threshold {
        return 0.0;
    }
    let (a1, a2) = low_harmonics(s, trig);
    let ring_mean = s.iter().sum::<f32>() / 16.0;
    // A white cross: its middle brighter than the ring, which is mostly black.
    let centre = img.at(x, y) - ring_mean;
    // The second harmonic only in part: a cross seen obliquely has arms off square.
    if centre > 0.0 {
        a4 - 0.5 * a2 - 2.0 * a1
    } else {
        0.0
    }
}

/// The cross targets in `img`: those found, and the candidates refused with why.
pub fn find_crosses(img: &Gray, s: &TargetSettings) -> (Vec<Candidate>, Vec<Rejected>) {
    // An ideal cross of contrast C gives a fourth harmonic of 4–6 C.
    let threshold = (2.0 * s.min_contrast) as f32;
    let trig = ring_trig();
    let seeds = pyramid_seeds(img, s, (RING_PX, 0.3), threshold, |level, ring, x, y| {
        cross_response(level, ring, x, y, threshold, &trig)
    });
    examine_seeds(seeds, |smoothed, uv0, scale| {
        examine(img, smoothed, uv0, scale, s)
    })
}

/// One candidate measured, checked and placed at full resolution.
fn examine(
    img: &Gray,
    smoothed: &mut Smoothed,
    start: Vector2<f64>,
    scale: usize,
    s: &TargetSettings,
) -> Result<Candidate, String> {
    // Its image made as far as the diagonals may look, and the centre wander.
    let reach = 0.75 * s.max_size_px + 8.0 * (3 * scale + 2) as f64;
    let near = smoothed.by(img, scale, start, reach);
    let (uv, _) = symmetric_centre(near, start, (3 * scale + 2) as f64, None)?;
    let arms = arm_angles(near, &uv, 3.0 * scale as f64);
    let shape = diagonals(near, &uv, &arms, s.max_size_px)?;
    let contrast = shape.white - shape.black;
    if contrast < s.min_contrast {
        return Err(format!(
            "low contrast: {contrast:.0} grey levels between the cross and its square, at least {:.0} needed",
            s.min_contrast
        ));
    }
    let size_px = shape.side_px;
    if !(s.min_size_px..=s.max_size_px).contains(&size_px) {
        return Err(format!(
            "size {size_px:.0} px, outside {:.0}–{:.0} px",
            s.min_size_px, s.max_size_px
        ));
    }
    let share = shape.bar_px / size_px;
    if !(0.08..=0.4).contains(&share) {
        return Err(format!(
            "not a cross: bars {:.0} % of the side wide (a cross target's are 10–35 %)",
            100.0 * share
        ));
    }
    // Every arm white out to near the square's edge.
    let mid = 0.5 * (shape.white + shape.black);
    for a in arms {
        let p = uv + 0.3 * size_px * Vector2::new(a.cos(), a.sin());
        if f64::from(near.sample(p.x, p.y)) < mid {
            return Err("not a cross: an arm is not white to the square's edge".into());
        }
    }
    let blur = ((size_px / 16.0).round() as usize).clamp(1, 8);
    let fine = smoothed.by(img, blur, uv, 0.5 * size_px + 8.0 * (blur + 3) as f64);
    let (uv, fit_sigma) = symmetric_centre(fine, uv, 0.45 * size_px, None)?;
    // The fit's σ takes the differences as independent; they are not (texture, aliasing,
    // the smoothing). The centre's spread when each eighth of the window is left out in turn
    // (a jackknife) sees that.
    let parts: Vec<Vector2<f64>> = (0..SECTORS)
        .filter_map(|k| symmetric_centre(fine, uv, 0.45 * size_px, Some(k)).ok())
        .map(|(c, _)| c)
        .collect();
    if parts.len() < SECTORS {
        return Err("no stable centre: leaving out a part of the window loses it".into());
    }
    let n = SECTORS as f64;
    let mean = parts.iter().sum::<Vector2<f64>>() / n;
    let spread = parts.iter().map(|c| (c - mean).norm_squared()).sum::<f64>();
    let sigma_px = fit_sigma.max(((n - 1.0) / n * spread / 2.0).sqrt());
    if sigma_px > s.max_sigma_px {
        return Err(format!(
            "the centre is not sharp: σ {sigma_px:.2} px, at most {:.2}",
            s.max_sigma_px
        ));
    }
    Ok(Candidate {
        uv,
        sigma_px,
        contrast,
        size_px,
        white_angle_rad: arms[0],
    })
}

/// The window's parts a jackknife leaves out in turn: sectors of the half-plane of offsets.
const SECTORS: usize = 8;

/// The point about which the image within `half` pixels is most alike under a half turn, by
/// Gauss–Newton on the differences, with its σ per axis; without the offsets of sector `skip`
/// when given.
fn symmetric_centre(
    img: &Gray,
    start: Vector2<f64>,
    half: f64,
    skip: Option<usize>,
) -> Result<(Vector2<f64>, f64), String> {
    let n = half.round().max(2.0) as isize;
    let margin = half + 3.0;
    let inside = |c: &Vector2<f64>| {
        c.x >= margin
            && c.y >= margin
            && c.x <= img.width as f64 - 1.0 - margin
            && c.y <= img.height as f64 - 1.0 - margin
    };
    let grad = |p: Vector2<f64>| {
        Vector2::new(
            f64::from(img.sample(p.x + 0.5, p.y) - img.sample(p.x - 0.5, p.y)),
            f64::from(img.sample(p.x, p.y + 0.5) - img.sample(p.x, p.y - 0.5)),
        )
    };
    let mut c = start;
    let mut last = (Matrix2::zeros(), 0.0, 0usize);
    for _ in 0..10 {
        if !inside(&c) {
            return Err("too near the image's edge".into());
        }
        let (mut jtj, mut jtr, mut rr, mut count) = (Matrix2::zeros(), Vector2::zeros(), 0.0, 0);
        for dy in -n..=n {
            for dx in -n..=n {
                let d = Vector2::new(dx as f64, dy as f64);
                if d.norm() > half || (dy, dx) <= (0, 0) {
                    continue;
                }
                let sector = ((d.y.atan2(d.x) / std::f64::consts::PI * SECTORS as f64) as usize)
                    .min(SECTORS - 1);
                if skip == Some(sector) {
                    continue;
                }
                // A half turn: I(c + d) = I(c − d), which a view from aside keeps (a quarter
                // turn it does not).
                let (a, p) = (c + d, c - d);
                let r = f64::from(img.sample(a.x, a.y) - img.sample(p.x, p.y));
                let j = grad(a) - grad(p);
                jtj += j * j.transpose();
                jtr += j * r;
                rr += r * r;
                count += 1;
            }
        }
        let Some(inv) = jtj.try_inverse() else {
            return Err("no centre: the window is flat".into());
        };
        let step = -inv * jtr;
        last = (inv, rr, count);
        c += step.map(|v| v.clamp(-2.0, 2.0));
        if step.norm() < 0.005 {
            break;
        }
    }
    if (c - start).norm() > half.max(3.0) {
        return Err("no centre of symmetry near here".into());
    }
    let (inv, rr, count) = last;
    let s2 = rr / (count as f64 - 2.0).max(1.0);
    let cov = inv * s2;
    Ok((c, (0.5 * cov.trace()).max(0.0).sqrt()))
}

/// The directions of the four arms (radians, image x toward y), in turn: each the brightest
/// of a ring of radius `r` within 30° of where the ring's fourth harmonic puts it (seen from
/// aside, the arms are not square to each other).
fn arm_angles(img: &Gray, c: &Vector2<f64>, r: f64) -> [f64; 4] {
    const N: usize = 128;
    let ring: Vec<f64> = (0..N)
        .map(|k| {
            let a = k as f64 * std::f64::consts::TAU / N as f64;
            f64::from(img.sample(c.x + r * a.cos(), c.y + r * a.sin()))
        })
        .collect();
    let (mut cs, mut sn) = (0.0, 0.0);
    for (k, v) in ring.iter().enumerate() {
        let a = k as f64 * std::f64::consts::TAU / N as f64;
        cs += v * (4.0 * a).cos();
        sn += v * (4.0 * a).sin();
    }
    let first = sn.atan2(cs) / 4.0;
    std::array::from_fn(|k| {
        let centre = first + k as f64 * std::f64::consts::FRAC_PI_2;
        let span = (N / 12) as isize;
        let at = (centre / std::f64::consts::TAU * N as f64).round() as isize;
        let best = (at - span..=at + span)
            .max_by(|a, b| {
                let v = |i: isize| ring[i.rem_euclid(N as isize) as usize];
                v(*a).total_cmp(&v(*b))
            })
            .unwrap_or(at);
        best as f64 * std::f64::consts::TAU / N as f64
    })
}

struct Shape {
    white: f64,
    black: f64,
    bar_px: f64,
    side_px: f64,
}

/// Along the four diagonals (between the arms): white to the bars' corner, black to the
/// square's corner. Their medians give the bar width and the side.
fn diagonals(
    img: &Gray,
    c: &Vector2<f64>,
    arms: &[f64; 4],
    max_side: f64,
) -> Result<Shape, String> {
    let reach = (0.75 * max_side).ceil() as usize;
    let profiles: Vec<Vec<f64>> = (0..4)
        .map(|k| {
            // The bisector of two neighbouring arms.
            let next = arms[(k + 1) % 4] + if k == 3 { std::f64::consts::TAU } else { 0.0 };
            let a = 0.5 * (arms[k] + next);
            (0..reach)
                .map(|t| {
                    let p = c + t as f64 * Vector2::new(a.cos(), a.sin());
                    f64::from(img.sample(p.x, p.y))
                })
                .collect()
        })
        .collect();
    let white = f64::from(img.sample(c.x, c.y));
    let mut blacks: Vec<f64> = profiles
        .iter()
        .map(|p| p.iter().copied().fold(f64::INFINITY, f64::min))
        .collect();
    blacks.sort_by(f64::total_cmp);
    let black = 0.5 * (blacks[1] + blacks[2]);
    let mid = 0.5 * (white + black);
    let mut bars = Vec::new();
    let mut sides = Vec::new();
    for p in &profiles {
        let Some(t1) = p.iter().position(|&v| v < mid) else {
            return Err("not a cross: a diagonal never turns dark".into());
        };
        let Some(t2) = p[t1..].iter().position(|&v| v > mid).map(|t| t + t1) else {
            return Err("not a cross: a diagonal stays dark beyond the largest target".into());
        };
        bars.push(t1 as f64 * std::f64::consts::SQRT_2);
        sides.push(t2 as f64 * std::f64::consts::SQRT_2);
    }
    let (lo, hi) = sides
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(l, h), &v| (l.min(v), h.max(v)));
    if hi > 1.8 * lo {
        return Err(format!(
            "not a square: its corners {lo:.0}–{hi:.0} px from the centre's diagonals"
        ));
    }
    bars.sort_by(f64::total_cmp);
    sides.sort_by(f64::total_cmp);
    Ok(Shape {
        white,
        black,
        bar_px: 0.5 * (bars[1] + bars[2]),
        side_px: 0.5 * (sides[1] + sides[2]),
    })
}
