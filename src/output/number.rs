//! Fast text for numbers rounded to a fixed number of decimals, for the CSV
//! logs: plain decimal notation (never an exponent), trailing zeros removed
//! but one digit kept after the point ("1.4", "2.0", "-0.125", "0.000012"),
//! reading back to exactly the rounded value.

/// Appends `x` rounded to `decimals` (at most 9) decimal places; "-0.0" is
/// written as "0.0". The text is built right to left in a buffer on the
/// stack and appended at once (the logs format millions of numbers).
pub fn push_fixed(out: &mut Vec<u8>, x: f64, decimals: u32) {
    debug_assert!(decimals <= 9);
    // The logs' column widths, each with its scale a constant, so that the
    // divisions by it compile to multiplications (the poses' numbers are
    // most of a poses-only run's writing).
    match decimals {
        3 => push_scaled(out, x, 3, 1_000),
        4 => push_scaled(out, x, 4, 10_000),
        6 => push_scaled(out, x, 6, 1_000_000),
        _ => push_scaled(out, x, decimals, POWERS_OF_TEN[decimals as usize]),
    }
}

/// [`push_fixed`] with `scale` = 10^`decimals`.
#[inline(always)]
fn push_scaled(out: &mut Vec<u8>, x: f64, decimals: u32, scale: u64) {
    let scaled = (x * scale as f64).round();
    if !scaled.is_finite() || scaled.abs() >= 9.0e18 {
        // Out of the fast path's range: fall back to the general form.
        out.extend_from_slice(format!("{x:?}").as_bytes());
        return;
    }
    let magnitude = scaled.abs() as u64;
    let (int, mut frac) = (magnitude / scale, magnitude % scale);
    // Sign, 19 integer digits, the point and 9 decimals at most.
    let mut buf = [0u8; 32];
    let mut i = buf.len();
    if frac == 0 {
        i -= 1;
        buf[i] = b'0';
    } else {
        // The decimals without their trailing zeros, then the leading zeros.
        let mut width = decimals as usize;
        while frac % 10 == 0 {
            frac /= 10;
            width -= 1;
        }
        let end = i - width;
        i = write_digits(&mut buf[..i], frac);
        while i > end {
            i -= 1;
            buf[i] = b'0';
        }
    }
    i -= 1;
    buf[i] = b'.';
    i = write_digits(&mut buf[..i], int);
    if scaled < 0.0 && magnitude != 0 {
        i -= 1;
        buf[i] = b'-';
    }
    out.extend_from_slice(&buf[i..]);
}

/// 10 to the power of a number of decimals.
const POWERS_OF_TEN: [u64; 10] =
    [1, 10, 100, 1_000, 10_000, 100_000, 1_000_000, 10_000_000, 100_000_000, 1_000_000_000];

/// The value that `push_fixed(x, decimals)`'s text reads back as, so that
/// other files can repeat a logged number exactly.
pub fn logged_value(x: f64, decimals: u32) -> f64 {
    let scale = 10u64.pow(decimals) as f64;
    (x * scale).round() / scale + 0.0
}

/// Appends an unsigned integer.
pub fn push_int(out: &mut Vec<u8>, n: u64) {
    let mut buf = [0u8; 20];
    let start = write_digits(&mut buf, n);
    out.extend_from_slice(&buf[start..]);
}

/// Pairs of decimal digits "00" to "99".
const DIGIT_PAIRS: &[u8; 200] = b"0001020304050607080910111213141516171819\
2021222324252627282930313233343536373839\
4041424344454647484950515253545556575859\
6061626364656667686970717273747576777879\
8081828384858687888990919293949596979899";

/// Writes `n`'s digits at the end of `buf` (two at a time); returns where
/// they start.
fn write_digits(buf: &mut [u8], mut n: u64) -> usize {
    let mut i = buf.len();
    while n >= 100 {
        let pair = (n % 100) as usize * 2;
        n /= 100;
        i -= 2;
        buf[i..i + 2].copy_from_slice(&DIGIT_PAIRS[pair..pair + 2]);
    }
    if n >= 10 {
        let pair = n as usize * 2;
        i -= 2;
        buf[i..i + 2].copy_from_slice(&DIGIT_PAIRS[pair..pair + 2]);
    } else {
        i -= 1;
        buf[i] = b'0' + n as u8;
    }
    i
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plain_shortest_decimals_that_read_back_exactly() {
        for &(x, d, text) in &[
            (1.4, 3, "1.4"),
            (2.0, 3, "2.0"),
            (-0.125, 3, "-0.125"),
            (-0.0001, 3, "0.0"),
            (12.3456789, 4, "12.3457"),
            (1.234_567_8, 6, "1.234568"),
            (-1.234_567_8, 6, "-1.234568"),
            (511.5, 3, "511.5"),
            (0.000012, 6, "0.000012"),
            (1023.9995, 3, "1024.0"),
            (-40.05, 4, "-40.05"),
        ] {
            let mut out = Vec::new();
            push_fixed(&mut out, x, d);
            let got = String::from_utf8(out).unwrap();
            assert_eq!(got, text, "{x} to {d}");
            let f = 10f64.powi(d as i32);
            assert_eq!(got.parse::<f64>().unwrap(), (x * f).round() / f + 0.0);
        }
        let mut out = Vec::new();
        push_int(&mut out, 1234567890);
        assert_eq!(out, b"1234567890");
    }

    /// The text Rust's own formatting gives (`format!("{:.d$}")` of the
    /// rounded value, trailing zeros trimmed to one), for many values of
    /// every size and sign at every number of decimals.
    #[test]
    fn matches_rusts_formatting_of_the_rounded_value() {
        let mut checked = 0;
        let mut state = 0x2545_f491_4f6c_dd1du64;
        for k in 0..200_000u64 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let unit = (state >> 11) as f64 / (1u64 << 53) as f64;
            let x = (unit - 0.5) * 10f64.powi((k % 13) as i32 - 3);
            let d = (k % 10) as u32;
            if (x * 10f64.powi(d as i32)).abs() >= 1e15 {
                // Beyond where the reference's division is exact.
                continue;
            }
            let mut out = Vec::new();
            push_fixed(&mut out, x, d);
            let f = 10f64.powi(d as i32);
            let rounded = (x * f).round() / f + 0.0;
            let mut expected = format!("{:.*}", d as usize, rounded);
            if expected.contains('.') {
                expected = expected.trim_end_matches('0').to_string();
                if expected.ends_with('.') {
                    expected.push('0');
                }
            } else {
                expected.push_str(".0");
            }
            if expected == "-0.0" {
                expected = "0.0".to_string();
            }
            assert_eq!(String::from_utf8(out).unwrap(), expected, "{x:e} to {d}");
            checked += 1;
        }
        assert!(checked > 150_000, "{checked} values checked");
        for n in [0u64, 9, 10, 99, 100, 101, 999, 1000, 12_345, u64::MAX] {
            let mut out = Vec::new();
            push_int(&mut out, n);
            assert_eq!(String::from_utf8(out).unwrap(), n.to_string());
        }
    }
}
