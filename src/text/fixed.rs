//! Numbers to a fixed number of decimals, the bytes `format!("{v:.D$}")` gives, faster: the
//! standard library falls back to exact big-number arithmetic (Dragon4) for many values, which
//! made formatting a fifth of a merge's time.

use std::fmt;

/// `v` with `D` decimals: `format!("{}", Fixed::<4>(v)) == format!("{v:.4}")` for every `v`.
#[derive(Clone, Copy, Debug)]
pub struct Fixed<const D: usize>(pub f64);

impl<const D: usize> fmt::Display for Fixed<D> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let v = self.0;
        match rounded::<D>(v) {
            Some(r) => {
                let scale = 10u64.pow(D as u32);
                let sign = if v.is_sign_negative() { "-" } else { "" };
                if D == 0 {
                    write!(f, "{sign}{r}")
                } else {
                    write!(f, "{sign}{}.{:0D$}", r / scale, r % scale)
                }
            }
            None => write!(f, "{v:.D$}"),
        }
    }
}

/// |v|·10^D rounded to the nearest whole number, when the product computed in floating point
/// cannot round differently from the exact one (it is well away from a half); else None.
fn rounded<const D: usize>(v: f64) -> Option<u64> {
    if D > 15 || !v.is_finite() {
        return None;
    }
    let m = v.abs() * 10f64.powi(D as i32);
    // Below 2^52 the fraction is held; the product is within half an ulp of the exact one.
    if m >= 4_503_599_627_370_496.0 {
        return None;
    }
    let whole = m.floor();
    let frac = m - whole;
    let margin = 4.0 * f64::EPSILON * m.max(1.0);
    if (frac - 0.5).abs() <= margin {
        return None;
    }
    Some(if frac > 0.5 {
        whole as u64 + 1
    } else {
        whole as u64
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check<const D: usize>(v: f64) {
        assert_eq!(
            format!("{}", Fixed::<D>(v)),
            format!("{v:.D$}"),
            "{v:e} to {D}"
        );
    }

    fn all(v: f64) {
        check::<0>(v);
        check::<1>(v);
        check::<2>(v);
        check::<3>(v);
        check::<4>(v);
        check::<6>(v);
        check::<9>(v);
    }

    #[test]
    fn same_bytes_as_the_standard_library() {
        let special = [
            0.0,
            -0.0,
            0.5,
            1.5,
            2.5,
            -0.5,
            0.125,
            0.00005,
            0.00015,
            -0.00001,
            1e-12,
            -1e-12,
            0.045,
            1.005,
            2.675,
            1e15,
            4.5e15,
            1e20,
            -1e20,
            123456.78905,
            f64::MAX,
            f64::MIN,
            f64::MIN_POSITIVE,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            5710000.12345,
            699000.99995,
            0.99995,
            9.99999999995,
        ];
        for v in special {
            all(v);
        }
        // A deterministic spread of magnitudes and of exact halves at each precision.
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        for k in 0..200_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let unit = (x >> 11) as f64 / (1u64 << 53) as f64;
            let exp = (k % 24) as i32 - 8;
            let v = (unit - 0.5) * 10f64.powi(exp);
            all(v);
            // Halves: n + 0.5 at D decimals, and their neighbours.
            let half = ((x % 2_000_000) as f64 + 0.5) / 10f64.powi((k % 5) as i32);
            for h in [
                half,
                f64::from_bits(half.to_bits() + 1),
                f64::from_bits(half.to_bits() - 1),
            ] {
                all(h);
                all(-h);
            }
        }
    }
}
