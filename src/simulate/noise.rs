//! Deterministic hashing and value noise for procedural textures and image noise (pure). The
//! same inputs give the same numbers on every machine and in any thread order.

/// A 64-bit mix (SplitMix64's finaliser).
pub(crate) fn hash64(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// Hash of several integers.
pub(crate) fn hash(parts: &[u64]) -> u64 {
    parts
        .iter()
        .fold(0x1234_5678_9ABC_DEF0, |h, &p| hash64(h ^ p))
}

/// Uniform in [0, 1) from a hash.
pub fn unit(h: u64) -> f64 {
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Value noise in [0, 1] at (x, y) (lattice units), smoothly interpolated.
pub(crate) fn value_noise(seed: u64, x: f64, y: f64) -> f64 {
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (ix, iy) = (x0 as i64 as u64, y0 as i64 as u64);
    let v = |dx: u64, dy: u64| unit(hash(&[seed, ix.wrapping_add(dx), iy.wrapping_add(dy)]));
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let (sx, sy) = (s(fx), s(fy));
    let top = v(0, 0) * (1.0 - sx) + v(1, 0) * sx;
    let bottom = v(0, 1) * (1.0 - sx) + v(1, 1) * sx;
    top * (1.0 - sy) + bottom * sy
}

/// Fractal value noise: `octaves` octaves from `scale_m` metres down, each half the size and
/// half the amplitude; in [0, 1].
pub(crate) fn fbm(seed: u64, x_m: f64, y_m: f64, scale_m: f64, octaves: u32) -> f64 {
    let (mut sum, mut amp, mut norm, mut f) = (0.0, 1.0, 0.0, 1.0 / scale_m);
    for o in 0..octaves {
        sum += amp * value_noise(seed.wrapping_add(u64::from(o) * 7919), x_m * f, y_m * f);
        norm += amp;
        amp *= 0.5;
        f *= 2.0;
    }
    sum / norm
}

/// An approximately normal deviate (Irwin–Hall: the sum of four uniforms, variance-corrected),
/// from one hash: its four 16-bit quarters are the uniforms.
pub(crate) fn gaussian(h: u64) -> f64 {
    let h = hash64(h);
    let u: f64 = (0..4)
        .map(|k| (((h >> (16 * k)) & 0xFFFF) as f64 + 0.5) / 65536.0)
        .sum();
    (u - 2.0) * (3.0f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_is_deterministic_bounded_and_continuous() {
        assert_eq!(hash(&[1, 2, 3]), hash(&[1, 2, 3]));
        assert_ne!(hash(&[1, 2, 3]), hash(&[1, 2, 4]));
        for i in 0..1000 {
            let x = i as f64 * 0.37;
            let v = fbm(5, x, -x * 0.5, 2.0, 4);
            assert!((0.0..=1.0).contains(&v));
            let w = fbm(5, x + 1e-6, -x * 0.5, 2.0, 4);
            assert!((v - w).abs() < 1e-4);
        }
        let g: Vec<f64> = (0..20_000).map(|i| gaussian(hash(&[9, i]))).collect();
        let m = g.iter().sum::<f64>() / g.len() as f64;
        let sd = (g.iter().map(|x| (x - m).powi(2)).sum::<f64>() / g.len() as f64).sqrt();
        assert!(m.abs() < 0.03 && (sd - 1.0).abs() < 0.03, "{m} {sd}");
    }
}
