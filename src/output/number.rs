//! Fast text for numbers rounded to a fixed number of decimals, for the CSV
//! logs: plain decimal notation (never an exponent), trailing zeros removed
//! but one digit kept after the point ("1.4", "2.0", "-0.125", "0.000012"),
//! reading back to exactly the rounded value.

/// Appends `x` rounded to `decimals` (at most 9) decimal places; "-0.0" is
/// written as "0.0".
pub fn push_fixed(out: &mut Vec<u8>, x: f64, decimals: u32) {
    debug_assert!(decimals <= 9);
    let scale = 10u64.pow(decimals);
    let scaled = (x * scale as f64).round();
    if !scaled.is_finite() || scaled.abs() >= 9.0e18 {
        // Out of the fast path's range: fall back to the general form.
        out.extend_from_slice(format!("{x:?}").as_bytes());
        return;
    }
    let magnitude = scaled.abs() as u64;
    if scaled < 0.0 && magnitude != 0 {
        out.push(b'-');
    }
    let (int, mut frac) = (magnitude / scale, magnitude % scale);
    push_int(out, int);
    out.push(b'.');
    if frac == 0 {
        out.push(b'0');
        return;
    }
    let mut width = decimals as usize;
    while frac % 10 == 0 {
        frac /= 10;
        width -= 1;
    }
    let mut buf = [b'0'; 20];
    let start = write_digits(&mut buf, frac);
    let digits = buf.len() - start;
    out.extend(std::iter::repeat_n(b'0', width - digits));
    out.extend_from_slice(&buf[start..]);
}

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

/// Writes `n`'s digits at the end of `buf`; returns where they start.
fn write_digits(buf: &mut [u8; 20], mut n: u64) -> usize {
    let mut i = buf.len();
    loop {
        i -= 1;
        buf[i] = b'0' + (n % 10) as u8;
        n /= 10;
        if n == 0 {
            return i;
        }
    }
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
}
