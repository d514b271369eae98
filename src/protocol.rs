//! The serial wire protocol of `protocol/SPEC.md`: the `odocal-protocol` crate (frames, codec,
//! typed messages, wire units; `no_std` at its core), re-exported, and the conversion between
//! its parameter block and [`WheelParams`].

pub use odocal_protocol::*;

use crate::kinematics::WheelParams;
use odocal_protocol::message::ParamsBlock;
use odocal_protocol::units::{ParamsSi, UnitError};

impl From<&ParamsBlock> for WheelParams {
    fn from(b: &ParamsBlock) -> Self {
        let p = b.to_si();
        WheelParams {
            left_wheel_diameter_m: p.left_wheel_diameter_m,
            right_wheel_diameter_m: p.right_wheel_diameter_m,
            wheelbase_m: p.wheelbase_m,
            counts_per_wheel_rev: p.counts_per_wheel_rev,
        }
    }
}

impl TryFrom<&WheelParams> for ParamsBlock {
    type Error = UnitError;

    /// Rounds to the wire's resolution (1 nm, 1e-6 count); refuses what does not fit.
    fn try_from(p: &WheelParams) -> Result<Self, UnitError> {
        ParamsBlock::from_si(&ParamsSi {
            left_wheel_diameter_m: p.left_wheel_diameter_m,
            right_wheel_diameter_m: p.right_wheel_diameter_m,
            wheelbase_m: p.wheelbase_m,
            counts_per_wheel_rev: p.counts_per_wheel_rev,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn params_round_trip_within_wire_resolution() {
        let p = WheelParams {
            left_wheel_diameter_m: 0.084,
            right_wheel_diameter_m: 0.083_937_808_9,
            wheelbase_m: 0.201_232_677,
            counts_per_wheel_rev: 2796.8,
        };
        let block = ParamsBlock::try_from(&p).unwrap();
        assert_eq!(block.validate(), Ok(()));
        let back = WheelParams::from(&block);
        for (a, b) in [
            (p.left_wheel_diameter_m, back.left_wheel_diameter_m),
            (p.right_wheel_diameter_m, back.right_wheel_diameter_m),
            (p.wheelbase_m, back.wheelbase_m),
            (p.counts_per_wheel_rev, back.counts_per_wheel_rev),
        ] {
            assert!(((a - b) / a).abs() <= 1e-7, "{a} vs {b}");
        }
        let nan = WheelParams {
            wheelbase_m: f64::NAN,
            ..p
        };
        assert!(ParamsBlock::try_from(&nan).is_err());
        let huge = WheelParams {
            wheelbase_m: 5.0,
            ..p
        };
        assert!(ParamsBlock::try_from(&huge).is_err());
    }
}
