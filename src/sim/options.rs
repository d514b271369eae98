//! The simulated robot's settings a command line gives: its true errors ([`TrueRobot`]) and
//! how its heading sensor errs ([`SensorErrors`]), checked into the simulator's own types.
//! Every mock takes them, and so does `odocal simulate`, which needs no mock.

use super::sensor::{HeadingModel, SensorKind};
use super::SimError;
use crate::kinematics::{Deviation, SplitConvention, WheelParams};
use crate::ranges::check_ranges;

/// A setting the simulator cannot simulate (the message names the flag and its range).
fn setting(message: String) -> SimError {
    SimError::Setting(message)
}

/// The true errors of a mock's simulated robot.
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct TrueRobot {
    /// True E_b of the simulated robot (relative to its configured parameters).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.976))]
    pub true_eb: f64,
    /// True E_d of the simulated robot (left wheel nominal).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.992))]
    pub true_ed: f64,
}

impl Default for TrueRobot {
    fn default() -> Self {
        TrueRobot {
            true_eb: 0.976,
            true_ed: 0.992,
        }
    }
}

impl TrueRobot {
    /// Checks both against what a mock can simulate.
    pub fn check(&self) -> Result<(), SimError> {
        check_ranges(&[
            ("--true-eb", self.true_eb, 0.5, 2.0),
            ("--true-ed", self.true_ed, 0.8, 1.25),
        ])
        .map_err(setting)
    }

    /// The true parameters of a robot configured with `configured` (left wheel nominal).
    pub fn params(&self, configured: &WheelParams) -> Result<WheelParams, SimError> {
        self.check()?;
        WheelParams::from_ratios(
            configured,
            self.true_eb,
            self.true_ed,
            &SplitConvention::LeftNominal,
        )
        .map_err(|e| setting(e.to_string()))
    }
}

/// How a mock's heading sensor errs (all off by default: an ideal sensor with the mock's noise).
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct SensorErrors {
    /// The simulated heading sensor: compass (absolute, magnetic) or gyro (integrated).
    #[cfg_attr(feature = "cli", arg(long, default_value = "compass", value_parser = ["compass", "gyro"]))]
    pub heading_sensor: String,
    /// A compass's deviation curve A1,B1,A2,B2 (deg): d(ψ) = A1 sin ψ + B1 cos ψ + A2 sin 2ψ +
    /// B2 cos 2ψ.
    #[cfg_attr(feature = "cli", arg(long, allow_hyphen_values = true))]
    pub deviation_deg: Option<Deviation>,
    /// A compass's offset while the wheels drive (the motor currents' field, deg).
    #[cfg_attr(
        feature = "cli",
        arg(long, default_value_t = 0.0, allow_hyphen_values = true)
    )]
    pub motor_offset_deg: f64,
    /// A gyro's scale error (0.01: it reads 1 % more turn).
    #[cfg_attr(
        feature = "cli",
        arg(long, default_value_t = 0.0, allow_hyphen_values = true)
    )]
    pub gyro_scale_error: f64,
    /// A gyro's bias (deg/s).
    #[cfg_attr(
        feature = "cli",
        arg(long, default_value_t = 0.0, allow_hyphen_values = true)
    )]
    pub gyro_bias_deg_s: f64,
    /// A gyro bias's random walk (deg/s per √s).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.0))]
    pub gyro_bias_walk_deg_s: f64,
    /// Readings rounded to this step (deg; 0: none).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.0))]
    pub heading_quantum_deg: f64,
    /// Readings show the heading this long ago (s).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.0))]
    pub heading_latency_s: f64,
    /// Probability that a reading is lost.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.0))]
    pub heading_loss: f64,
}

impl Default for SensorErrors {
    fn default() -> Self {
        SensorErrors {
            heading_sensor: "compass".into(),
            deviation_deg: None,
            motor_offset_deg: 0.0,
            gyro_scale_error: 0.0,
            gyro_bias_deg_s: 0.0,
            gyro_bias_walk_deg_s: 0.0,
            heading_quantum_deg: 0.0,
            heading_latency_s: 0.0,
            heading_loss: 0.0,
        }
    }
}

impl SensorErrors {
    /// The model these settings describe, checked.
    pub fn model(&self) -> Result<HeadingModel, SimError> {
        let kind = match self.heading_sensor.as_str() {
            "compass" => SensorKind::Compass,
            "gyro" => SensorKind::Gyro,
            other => {
                return Err(setting(format!(
                    "--heading-sensor {other:?}: compass or gyro"
                )))
            }
        };
        let m = HeadingModel {
            kind,
            deviation: self.deviation_deg.unwrap_or_default(),
            motor_offset_rad: self.motor_offset_deg.to_radians(),
            gyro_scale_error: self.gyro_scale_error,
            gyro_bias_rad_s: self.gyro_bias_deg_s.to_radians(),
            gyro_bias_walk: self.gyro_bias_walk_deg_s.to_radians(),
            quantum_rad: self.heading_quantum_deg.to_radians(),
            latency_s: self.heading_latency_s,
            loss: self.heading_loss,
        };
        m.validate().map_err(|(name, value)| {
            setting(format!("heading sensor: {name} = {value} is out of range"))
        })?;
        Ok(m)
    }
}
