//! Number parsing straight from byte slices, without allocation.

/// Exact powers of ten representable in an f64.
const POW10: [f64; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
];

/// Parses a finite decimal number such as `-0000004.938700`, `20`, `.5` or `1.5e3`.
///
/// Plain decimals with at most 15 significant digits take an exact fast path (the mantissa and
/// the power of ten are both exact, so one division rounds correctly); anything else goes to
/// the standard library parser. Infinities and NaN are refused.
pub(crate) fn parse_f64(s: &[u8]) -> Option<f64> {
    let (neg, digits) = match s.split_first() {
        Some((b'-', rest)) => (true, rest),
        Some((b'+', rest)) => (false, rest),
        _ => (false, s),
    };
    let mut mant: u64 = 0;
    let mut significant = 0u32;
    let mut frac = 0usize;
    let mut dot = false;
    let mut any = false;
    for &b in digits {
        match b {
            b'0'..=b'9' => {
                any = true;
                if dot {
                    frac += 1;
                }
                let d = u64::from(b - b'0');
                if mant != 0 || d != 0 {
                    significant += 1;
                    if significant > 15 {
                        return parse_slow(s);
                    }
                    mant = mant * 10 + d;
                }
            }
            b'.' if !dot => dot = true,
            _ => return parse_slow(s),
        }
    }
    if !any {
        return None;
    }
    let Some(&p) = POW10.get(frac) else {
        return parse_slow(s);
    };
    let v = mant as f64 / p;
    Some(if neg { -v } else { v })
}

fn parse_slow(s: &[u8]) -> Option<f64> {
    let v: f64 = std::str::from_utf8(s).ok()?.parse().ok()?;
    v.is_finite().then_some(v)
}

/// Parses a non-negative integer such as `000100`; `23.0` is accepted too.
pub(crate) fn parse_u64(s: &[u8]) -> Option<u64> {
    let digits = match s.split_first() {
        Some((b'+', rest)) => rest,
        _ => s,
    };
    if !digits.is_empty() && digits.iter().all(u8::is_ascii_digit) {
        let mut v: u64 = 0;
        for &b in digits {
            v = v.checked_mul(10)?.checked_add(u64::from(b - b'0'))?;
        }
        return Some(v);
    }
    let f = parse_f64(s)?;
    (f >= 0.0 && f.fract() == 0.0 && f <= 9.007_199_254_740_992e15).then_some(f as u64)
}

/// Parses a signed integer such as `-12`; `1.0` is accepted too.
pub(crate) fn parse_i64(s: &[u8]) -> Option<i64> {
    match s.split_first() {
        Some((b'-', rest)) => {
            let v = parse_u64(rest)?;
            if v == 1u64 << 63 {
                Some(i64::MIN)
            } else {
                i64::try_from(v).ok().map(|v| -v)
            }
        }
        _ => i64::try_from(parse_u64(s)?).ok(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decimals() {
        for s in [
            "0",
            "-0",
            "20.0",
            "3984.00122",
            "-0000004.938700",
            "00000019.920006",
            "0.005",
            "-0.00010",
            ".5",
            "5.",
            "1e3",
            "-1.5E-3",
            "123456789012345678",
            "0.1",
            "1.7976931348623157e308",
            "+7",
        ] {
            let want: f64 = s.parse().unwrap();
            assert_eq!(parse_f64(s.as_bytes()), Some(want), "{s}");
        }
        for s in [
            "", "-", ".", "abc", "1.2.3", "1,2", "inf", "NaN", "1e999", "--1",
        ] {
            assert_eq!(parse_f64(s.as_bytes()), None, "{s}");
        }
    }

    #[test]
    fn integers() {
        assert_eq!(parse_u64(b"000100"), Some(100));
        assert_eq!(parse_u64(b"23.0"), Some(23));
        assert_eq!(parse_u64(b"23.5"), None);
        assert_eq!(parse_u64(b"-1"), None);
        assert_eq!(parse_u64(b"99999999999999999999999"), None);
        assert_eq!(parse_i64(b"-12"), Some(-12));
        assert_eq!(parse_i64(b"-9223372036854775808"), Some(i64::MIN));
        assert_eq!(parse_i64(b"9223372036854775808"), None);
    }
}
