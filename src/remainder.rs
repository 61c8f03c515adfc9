//! Floating-point remainders, bit for bit those of Rust's `%` and
//! `rem_euclid`, at a fraction of their cost.
//!
//! `%` on `f64` is an exact but slow long division (the compiler's own
//! `fmod`, about 80 instructions). Light schedules and angle wrapping take it
//! at every step of every car, where the quotient is a small whole number.
//! There one division, a truncation and a fused multiply-add give the same
//! exact result, and a range check proves the quotient was the right one;
//! anything else falls back to `%`.

/// `x % y`, exactly as Rust computes it (the sign of `x`, `|r| < |y|`).
pub fn fmod(x: f64, y: f64) -> f64 {
    if x.is_finite() && y.is_finite() && y > 0.0 {
        let q = (x / y).trunc();
        if q.abs() < 9.0e15 {
            // Exact when q is the true quotient: the remainder is exactly
            // representable and the fused multiply-add rounds once. A wrong q
            // lands outside the remainder's range (see the tests).
            let r = (-q).mul_add(y, x);
            let in_range = if x >= 0.0 { r >= 0.0 && r < y } else { r <= 0.0 && r > -y };
            if in_range {
                return if r == 0.0 { 0.0f64.copysign(x) } else { r };
            }
        }
    }
    x % y
}

/// `x.rem_euclid(y)`, exactly as Rust computes it.
pub fn rem_euclid(x: f64, y: f64) -> f64 {
    let r = fmod(x, y);
    if r < 0.0 {
        r + y.abs()
    } else {
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every value agrees with Rust's to the bit, on random pairs over many
    /// magnitudes, on whole multiples, and on the edge cases.
    #[test]
    fn remainders_match_rusts_bit_for_bit() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let mut checked = 0;
        let mut fast = 0;
        for _ in 0..400_000 {
            let unit = |r: u64| (r >> 11) as f64 / (1u64 << 53) as f64;
            let y = (unit(next()) * 200.0 + 1e-3) * 10f64.powi((next() % 5) as i32 - 2);
            let x = (unit(next()) - 0.3) * 10f64.powi((next() % 9) as i32 - 2);
            // Whole multiples and their neighbours, where a quotient rounds.
            let k = (next() % 40) as f64 - 10.0;
            let on = k * y;
            for x in [x, on, f64::from_bits(on.to_bits() + 1), f64::from_bits(on.to_bits().wrapping_sub(1)), -x] {
                let (want, got) = (x % y, fmod(x, y));
                assert_eq!(got.to_bits(), want.to_bits(), "{x} % {y}: {got} against {want}");
                let (want, got) = (x.rem_euclid(y), rem_euclid(x, y));
                assert_eq!(got.to_bits(), want.to_bits(), "{x} rem_euclid {y}: {got} against {want}");
                checked += 1;
                let q = (x / y).trunc();
                fast += usize::from(q.abs() < 9.0e15);
            }
        }
        assert_eq!(checked, 2_000_000);
        assert!(fast > 1_900_000, "the quick path ran for only {fast} values");
        for (x, y) in [
            (0.0, 1.0),
            (-0.0, 1.0),
            (-6.0, 3.0),
            (6.0, 3.0),
            (5.0, -3.0),
            (-5.0, -3.0),
            (f64::INFINITY, 2.0),
            (2.0, f64::INFINITY),
            (f64::NAN, 2.0),
            (2.0, 0.0),
            (1e300, 1e-300),
            (f64::MAX, 3.0),
            (std::f64::consts::PI * 7.0, 2.0 * std::f64::consts::PI),
        ] {
            assert_eq!(fmod(x, y).to_bits(), (x % y).to_bits(), "{x} % {y}");
            assert_eq!(rem_euclid(x, y).to_bits(), x.rem_euclid(y).to_bits(), "{x} rem_euclid {y}");
        }
    }
}
