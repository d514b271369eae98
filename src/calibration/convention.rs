//! The diameter split a user chooses for estimation and write-back: by name, or fixed by a
//! straight-line check (a distance commanded and the one measured with a tape), which then
//! wins. With the `cli` feature these are the flags of every command that estimates.

use crate::kinematics::SplitConvention;

/// The split convention as chosen.
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct ConventionChoice {
    /// Diameter split for estimation and write-back: left-nominal, mean-preserving or
    /// measured-scale:COMMANDED_M,MEASURED_M.
    #[cfg_attr(feature = "cli", arg(long, default_value = "left-nominal"))]
    pub convention: SplitConvention,
    /// Straight-line scale check: distance commanded (m). With --straight-measured-m, fixes
    /// the absolute wheel scale (overrides --convention).
    #[cfg_attr(feature = "cli", arg(long, requires = "straight_measured_m"))]
    pub straight_commanded_m: Option<f64>,
    /// Straight-line scale check: distance measured start to end with a tape (m).
    #[cfg_attr(feature = "cli", arg(long, requires = "straight_commanded_m"))]
    pub straight_measured_m: Option<f64>,
}

impl Default for ConventionChoice {
    fn default() -> Self {
        ConventionChoice {
            convention: SplitConvention::LeftNominal,
            straight_commanded_m: None,
            straight_measured_m: None,
        }
    }
}

impl ConventionChoice {
    /// The convention chosen: the straight-line check's when both distances are given.
    pub fn convention(&self) -> SplitConvention {
        match (self.straight_commanded_m, self.straight_measured_m) {
            (Some(commanded_m), Some(measured_m)) => SplitConvention::MeasuredScale {
                commanded_m,
                measured_m,
            },
            _ => self.convention,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_straight_line_check_wins_over_the_named_convention() {
        let named = ConventionChoice {
            convention: SplitConvention::MeanPreserving,
            ..ConventionChoice::default()
        };
        assert_eq!(named.convention(), SplitConvention::MeanPreserving);
        let half = ConventionChoice {
            straight_commanded_m: Some(2.0),
            ..named.clone()
        };
        assert_eq!(
            half.convention(),
            SplitConvention::MeanPreserving,
            "one distance is not a check"
        );
        let checked = ConventionChoice {
            straight_measured_m: Some(2.03),
            ..half
        };
        assert_eq!(
            checked.convention(),
            SplitConvention::MeasuredScale {
                commanded_m: 2.0,
                measured_m: 2.03
            }
        );
    }
}
