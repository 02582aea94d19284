//! Numbers in messages: at most six significant digits, like C's `%g`.
//!
//! Model: a value is rounded to six significant digits; it is written in plain decimal
//! notation when its decimal exponent is in [−4, 15), else as `MANTISSAeEXP`; trailing zeros
//! are dropped. Non-finite values are written `NaN`, `inf` and `-inf`.

/// `x` with at most six significant digits (see the module header).
pub fn sig6(x: f64) -> String {
    if x.is_nan() {
        return "NaN".into();
    }
    if x.is_infinite() {
        return if x > 0.0 { "inf".into() } else { "-inf".into() };
    }
    if x == 0.0 {
        return "0".into();
    }
    // Rounding to six digits first fixes the exponent (9.999995 becomes 1.00000e1).
    let sci = format!("{x:.5e}");
    let (mantissa, exp) = sci.split_once('e').unwrap_or((sci.as_str(), "0"));
    let exp: i32 = exp.parse().unwrap_or(0);
    if (-4..15).contains(&exp) {
        let decimals = usize::try_from(5 - exp).unwrap_or(0);
        // The rounded value, so that digits beyond the sixth of a large number are zeros.
        let rounded: f64 = sci.parse().unwrap_or(x);
        trim_zeros(&format!("{rounded:.decimals$}"))
    } else {
        format!("{}e{exp}", trim_zeros(mantissa))
    }
}

/// Drops trailing zeros after a decimal point (and the point itself if nothing is left).
fn trim_zeros(s: &str) -> String {
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::sig6;

    #[test]
    fn six_significant_digits() {
        assert_eq!(sig6(1.2345678901234), "1.23457");
        assert_eq!(sig6(5.123456789), "5.12346");
        assert_eq!(sig6(-0.000123456789), "-0.000123457");
        assert_eq!(sig6(0.1 + 0.2), "0.3");
        assert_eq!(sig6(64.0), "64");
        assert_eq!(sig6(9.999995), "10");
        assert_eq!(sig6(123456789.0), "123457000");
        assert_eq!(sig6(1e300), "1e300");
        assert_eq!(sig6(-3.4028234663852886e38), "-3.40282e38");
        assert_eq!(sig6(1.5e-7), "1.5e-7");
        assert_eq!(sig6(0.0), "0");
        assert_eq!(sig6(f64::NAN), "NaN");
        assert_eq!(sig6(f64::NEG_INFINITY), "-inf");
        // Never more than six significant digits, whatever the value.
        for k in -320..308 {
            let s = sig6(1.234567891 * 10f64.powi(k));
            let mantissa = s.split('e').next().unwrap();
            let digits: String = mantissa.chars().filter(char::is_ascii_digit).collect();
            let significant = digits.trim_start_matches('0').trim_end_matches('0');
            assert!(significant.len() <= 6, "{s}");
        }
    }
}
