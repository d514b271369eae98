//! SI units to and from the wire's fixed point (SPEC.md §4): the one place that knows that
//! distances travel in µm, angles in µrad, speeds in mm/s, rates in mrad/s, times in ms, and
//! parameters in nm and millionths of a count. Every conversion to the wire rounds to the
//! nearest step and refuses what does not fit, rather than saturating.

use crate::message::ParamsBlock;

/// A value that cannot be carried by its wire field.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error("{quantity} {value} does not fit the wire field ({unit})")]
pub struct UnitError {
    /// What was converted (`distance`, `speed`, …).
    pub quantity: &'static str,
    /// The SI value.
    pub value: f64,
    /// The wire unit and type.
    pub unit: &'static str,
}

fn fit(
    quantity: &'static str,
    unit: &'static str,
    value: f64,
    scale: f64,
    lo: f64,
    hi: f64,
) -> Result<f64, UnitError> {
    let r = libm::round(value * scale);
    if r.is_finite() && r >= lo && r <= hi {
        Ok(r)
    } else {
        Err(UnitError {
            quantity,
            value,
            unit,
        })
    }
}

/// Metres to µm (`i32`).
pub fn m_to_um(quantity: &'static str, m: f64) -> Result<i32, UnitError> {
    fit(
        quantity,
        "µm, i32",
        m,
        1e6,
        f64::from(i32::MIN),
        f64::from(i32::MAX),
    )
    .map(|v| v as i32)
}

/// µm to metres.
pub fn um_to_m(um: i32) -> f64 {
    f64::from(um) / 1e6
}

/// Radians to µrad (`i32`).
pub fn rad_to_urad(quantity: &'static str, rad: f64) -> Result<i32, UnitError> {
    fit(
        quantity,
        "µrad, i32",
        rad,
        1e6,
        f64::from(i32::MIN),
        f64::from(i32::MAX),
    )
    .map(|v| v as i32)
}

/// µrad to radians (not wrapped).
pub fn urad_to_rad(urad: i32) -> f64 {
    f64::from(urad) / 1e6
}

/// m/s to mm/s (`u16`, a speed limit).
pub fn m_s_to_mm_s(quantity: &'static str, m_s: f64) -> Result<u16, UnitError> {
    fit(quantity, "mm/s, u16", m_s, 1e3, 0.0, f64::from(u16::MAX)).map(|v| v as u16)
}

/// Signed m/s to mm/s (`i16`, a wheel speed).
pub fn m_s_to_mm_s_signed(quantity: &'static str, m_s: f64) -> Result<i16, UnitError> {
    fit(
        quantity,
        "mm/s, i16",
        m_s,
        1e3,
        f64::from(i16::MIN),
        f64::from(i16::MAX),
    )
    .map(|v| v as i16)
}

/// mm/s to m/s.
pub fn mm_s_to_m_s(mm_s: i32) -> f64 {
    f64::from(mm_s) / 1e3
}

/// rad/s to mrad/s (`u16`, a rate limit).
pub fn rad_s_to_mrad_s(quantity: &'static str, rad_s: f64) -> Result<u16, UnitError> {
    fit(
        quantity,
        "mrad/s, u16",
        rad_s,
        1e3,
        0.0,
        f64::from(u16::MAX),
    )
    .map(|v| v as u16)
}

/// mrad/s to rad/s.
pub fn mrad_s_to_rad_s(mrad_s: u16) -> f64 {
    f64::from(mrad_s) / 1e3
}

/// Seconds to ms (`u16`, periods and timeouts).
pub fn s_to_ms(quantity: &'static str, s: f64) -> Result<u16, UnitError> {
    fit(quantity, "ms, u16", s, 1e3, 0.0, f64::from(u16::MAX)).map(|v| v as u16)
}

/// µs to seconds.
pub fn us_to_s(us: u64) -> f64 {
    us as f64 / 1e6
}

/// Metres to nm (`u32`, parameter lengths).
pub fn m_to_nm(quantity: &'static str, m: f64) -> Result<u32, UnitError> {
    fit(quantity, "nm, u32", m, 1e9, 0.0, f64::from(u32::MAX)).map(|v| v as u32)
}

/// nm to metres. Dividing (not multiplying by 1e-9) is correctly rounded: 150 000 000 nm is
/// exactly the double nearest 0.15.
pub fn nm_to_m(nm: u32) -> f64 {
    f64::from(nm) / 1e9
}

/// Counts per revolution to millionths (`u64`).
pub fn counts_to_micro(quantity: &'static str, counts: f64) -> Result<u64, UnitError> {
    // 2^64 as f64; anything at or above it does not fit a u64.
    fit(
        quantity,
        "1e-6 count, u64",
        counts,
        1e6,
        0.0,
        18_446_744_073_709_549_568.0,
    )
    .map(|v| v as u64)
}

/// Millionths of a count to counts.
pub fn micro_to_counts(micro: u64) -> f64 {
    micro as f64 / 1e6
}

/// Wheel parameters in SI units, as the parameter block carries them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParamsSi {
    /// Left wheel diameter (m).
    pub left_wheel_diameter_m: f64,
    /// Right wheel diameter (m).
    pub right_wheel_diameter_m: f64,
    /// Wheelbase (m).
    pub wheelbase_m: f64,
    /// Encoder counts per wheel revolution.
    pub counts_per_wheel_rev: f64,
}

impl ParamsBlock {
    /// The block for `p`, rounded to the wire resolution (1 nm, 1e-6 count).
    pub fn from_si(p: &ParamsSi) -> Result<Self, UnitError> {
        Ok(ParamsBlock {
            left_wheel_diameter_nm: m_to_nm("left wheel diameter", p.left_wheel_diameter_m)?,
            right_wheel_diameter_nm: m_to_nm("right wheel diameter", p.right_wheel_diameter_m)?,
            wheelbase_nm: m_to_nm("wheelbase", p.wheelbase_m)?,
            counts_per_wheel_rev_micro: counts_to_micro(
                "counts per revolution",
                p.counts_per_wheel_rev,
            )?,
        })
    }

    /// The parameters in SI units.
    pub fn to_si(&self) -> ParamsSi {
        ParamsSi {
            left_wheel_diameter_m: nm_to_m(self.left_wheel_diameter_nm),
            right_wheel_diameter_m: nm_to_m(self.right_wheel_diameter_nm),
            wheelbase_m: nm_to_m(self.wheelbase_nm),
            counts_per_wheel_rev: micro_to_counts(self.counts_per_wheel_rev_micro),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conversions_round_and_refuse_what_does_not_fit() {
        assert_eq!(m_to_um("d", 1.2345674), Ok(1_234_567));
        assert_eq!(m_to_um("d", -0.0000015), Ok(-2));
        assert!(m_to_um("d", 5000.0).is_err());
        assert!(m_to_um("d", f64::NAN).is_err());
        assert_eq!(m_s_to_mm_s("v", 0.2), Ok(200));
        assert!(m_s_to_mm_s("v", -0.1).is_err());
        assert_eq!(s_to_ms("t", 0.5), Ok(500));
        assert_eq!(nm_to_m(150_000_000), 0.15);
        let p = ParamsSi {
            left_wheel_diameter_m: 0.084,
            right_wheel_diameter_m: 0.083_937_808_9,
            wheelbase_m: 0.201_232_677,
            counts_per_wheel_rev: 2796.8,
        };
        let back = ParamsBlock::from_si(&p).unwrap().to_si();
        assert!((back.right_wheel_diameter_m - p.right_wheel_diameter_m).abs() <= 0.5e-9);
        assert!((back.counts_per_wheel_rev - 2796.8).abs() < 1e-9);
        assert!(ParamsBlock::from_si(&ParamsSi {
            wheelbase_m: 5.0,
            ..p
        })
        .is_err());
    }
}
