//! Numbers a person gives (a flag, a field typed in), checked against their documented ranges
//! with the flag named, and numbers written back as a person reads them. Every layer may use
//! it: it does no I/O.

/// Checks a numeric flag against its documented physical range (inclusive), naming the flag.
pub fn check_range(flag: &str, value: f64, lo: f64, hi: f64) -> Result<(), String> {
    if value.is_finite() && (lo..=hi).contains(&value) {
        Ok(())
    } else {
        Err(format!(
            "{flag} must be in [{lo}, {hi}], got {}",
            compact(value)
        ))
    }
}

/// A number as a person reads it: plain when moderate, in exponent form when huge or tiny
/// (1e300 is not 301 digits).
pub fn compact(v: f64) -> String {
    if v != 0.0 && v.is_finite() && !(1e-4..1e6).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// A nominal geometry typed as `--wheel-diameter-m` and `--wheelbase-m` (m): a wheel of
/// 1 mm to 5 m, a wheelbase of 1 cm to 10 m.
pub fn check_geometry(wheel_diameter_m: f64, wheelbase_m: f64) -> Result<(), String> {
    check_ranges(&[
        ("--wheel-diameter-m", wheel_diameter_m, 1e-3, 5.0),
        ("--wheelbase-m", wheelbase_m, 1e-2, 10.0),
    ])
}

/// [`check_range`] for several flags: (flag, value, lowest, highest).
pub fn check_ranges(checks: &[(&str, f64, f64, f64)]) -> Result<(), String> {
    checks
        .iter()
        .try_for_each(|&(flag, v, lo, hi)| check_range(flag, v, lo, hi))
}
