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

/// Parse every whitespace-separated number of `line` onto `out`, in one pass
/// over the bytes: the values of `tokens(line)` each through
/// [`parse_decimal`], bit for bit. On a token that is not a number, returns
/// it (the numbers before it stay in `out`).
pub(crate) fn parse_numbers<'a>(line: &'a [u8], out: &mut Vec<f64>) -> Result<(), &'a [u8]> {
    const POW10: [f64; 19] = [
        1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
        1e17, 1e18,
    ];
    let n = line.len();
    let mut i = 0;
    loop {
        while i < n && line[i].is_ascii_whitespace() {
            i += 1;
        }
        if i == n {
            return Ok(());
        }
        let start = i;
        let neg = line[i] == b'-';
        if neg || line[i] == b'+' {
            i += 1;
        }
        // The fast path of `parse_decimal`, fused with finding the token's end.
        let (mut mantissa, mut digits, mut frac, mut dot) = (0u64, 0usize, 0usize, false);
        let mut fast = true;
        while i < n {
            let c = line[i];
            if c.is_ascii_digit() {
                mantissa = mantissa.wrapping_mul(10).wrapping_add(u64::from(c - b'0'));
                digits += 1;
                frac += usize::from(dot);
            } else if c == b'.' && !dot {
                dot = true;
            } else if c.is_ascii_whitespace() {
                break;
            } else {
                fast = false;
            }
            i += 1;
        }
        let token = &line[start..i];
        if fast && digits > 0 && digits <= 18 && (mantissa as f64) < 9.007_199_254_740_992e15 {
            let v = mantissa as f64 / POW10[frac];
            out.push(if neg { -v } else { v });
        } else {
            out.push(parse_decimal(token).ok_or(token)?);
        }
    }
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

    #[test]
    fn a_line_of_numbers_parses_as_its_tokens_do() {
        for line in [
            "1 2 3",
            "  -30.1003\t.0083333 +7 0 -0  ",
            "12345678901234567890 1.5 3.14159265358979323846264",
            "9007199254740993 1e3 -1.5E-2 nan inf",
            "",
            "   ",
            "0.000000000000000001 123456789012345678",
        ] {
            let want: Vec<f64> = tokens(line.as_bytes())
                .map(|t| parse_decimal(t).unwrap())
                .collect();
            let mut got = Vec::new();
            parse_numbers(line.as_bytes(), &mut got).unwrap();
            assert_eq!(want.len(), got.len(), "{line}");
            for (a, b) in want.iter().zip(&got) {
                assert!(
                    a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()),
                    "{line}"
                );
            }
        }
        for (line, bad) in [
            ("1 2.3.4 5", "2.3.4"),
            ("1 - 2", "-"),
            ("x", "x"),
            ("1 .", "."),
        ] {
            let mut got = Vec::new();
            assert_eq!(
                parse_numbers(line.as_bytes(), &mut got),
                Err(bad.as_bytes())
            );
            assert_eq!(got, [1.0][..got.len()].to_vec(), "{line}");
        }
    }
}
