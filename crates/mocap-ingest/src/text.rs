//! Small, fast text helpers shared by the BVH and AMC readers.

/// Whitespace-separated tokens of a line.
pub(crate) fn tokens(line: &[u8]) -> impl Iterator<Item = &[u8]> + Clone {
    line.split(|b| b.is_ascii_whitespace())
        .filter(|t| !t.is_empty())
}

/// Parse a decimal number. Plain `[-+]digits[.digits]` with at most 18
/// digits is computed exactly as `integer / 10^k` (one correctly rounded
/// division); anything else (exponents, `nan`, `inf`, long mantissas) goes
/// through the standard library parser. `None` if it is not a number.
pub(crate) fn parse_decimal(t: &[u8]) -> Option<f64> {
    const POW10: [f64; 19] = [
        1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
        1e17, 1e18,
    ];
    let (neg, digits) = match t.first() {
        Some(b'-') => (true, &t[1..]),
        Some(b'+') => (false, &t[1..]),
        _ => (false, t),
    };
    let mut mantissa: u64 = 0;
    let mut n_digits = 0;
    let mut frac_digits = 0;
    let mut seen_dot = false;
    let mut fast = !digits.is_empty();
    for &c in digits {
        match c {
            b'0'..=b'9' => {
                mantissa = mantissa * 10 + u64::from(c - b'0');
                n_digits += 1;
                frac_digits += usize::from(seen_dot);
            }
            b'.' if !seen_dot => seen_dot = true,
            _ => {
                fast = false;
                break;
            }
        }
        if n_digits > 18 {
            fast = false;
            break;
        }
    }
    if fast && n_digits > 0 && (mantissa as f64) < 9.007_199_254_740_992e15 {
        let v = mantissa as f64 / POW10[frac_digits];
        return Some(if neg { -v } else { v });
    }
    std::str::from_utf8(t).ok()?.parse::<f64>().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decimals_parse_exactly() {
        for t in [
            "0", "-0", "12.5", "-30.1003", ".0083333", "+7", "1e3", "-1.5E-2", "nan", "inf",
        ] {
            let want: f64 = t.parse().unwrap();
            let got = parse_decimal(t.as_bytes()).unwrap();
            assert!(
                got == want || (got.is_nan() && want.is_nan()),
                "{t}: {got} != {want}"
            );
        }
        for t in ["", "-", ".", "1.2.3", "abc", "1,5"] {
            assert_eq!(parse_decimal(t.as_bytes()), None, "{t}");
        }
        // Mantissas too long for the exact path fall back to the std parser.
        let long = "3.14159265358979323846264";
        assert_eq!(parse_decimal(long.as_bytes()), long.parse().ok());
    }
}
