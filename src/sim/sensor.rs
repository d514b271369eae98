//! How a simulated heading sensor errs, as real ones do: a magnetic compass with a deviation
//! curve (hard and soft iron: motors, battery, steel) and a field that follows the motor
//! currents, or a gyro-integrated heading with a scale error and a drifting bias; for both,
//! noise, quantisation, latency and lost readings. Every mock reads its robot's heading through
//! one [`HeadingSensor`], so the same defects can be given to our protocol's device, the RoboClaw's
//! compass, the ROS robot's IMU and the in-process base. Every term is off by default: the
//! default sensor is the ideal one of [`super::NoiseModel`] (noise and bias only).
//!
//! Sign conventions: headings counter-clockwise positive (as everywhere in the crate); the
//! deviation is what a compass adds to the true heading, `reading = ψ + d(ψ)`, with
//! `d(ψ) = A₁·sin ψ + B₁·cos ψ + A₂·sin 2ψ + B₂·cos 2ψ` (marine practice's B, C, D, E; its
//! constant A is [`super::NoiseModel::compass_bias_rad`]); a gyro's scale error `s` makes it
//! read `(1 + s)` times every turn.

use crate::kinematics::wrap_angle;
use rand::RngExt;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

/// What kind of heading sensor is simulated.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SensorKind {
    /// An absolute, magnetic heading (a compass, a 9-axis IMU's fused yaw).
    #[default]
    Compass,
    /// A heading integrated from a gyro (a 6-axis IMU, a BNO055 in IMU mode).
    Gyro,
}

/// The simulated heading sensor's noise per reading (deg, σ) every mock and simulation starts
/// with unless told otherwise: a real compass's at rest (`--heading-sigma-deg`).
pub const SIM_HEADING_SIGMA_DEG: f64 = 0.37;

pub use crate::kinematics::Deviation;

/// How the heading sensor errs; every term off by default.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct HeadingModel {
    /// The sensor's kind.
    pub kind: SensorKind,
    /// A compass's deviation curve.
    pub deviation: Deviation,
    /// A compass's offset while the wheels drive (the motor currents' field, rad).
    pub motor_offset_rad: f64,
    /// A gyro's scale error (0.01: it reads 1 % more turn than there was).
    pub gyro_scale_error: f64,
    /// A gyro's constant bias (rad/s).
    pub gyro_bias_rad_s: f64,
    /// A gyro bias's random walk (rad/s per √s).
    pub gyro_bias_walk: f64,
    /// Readings rounded to this step (rad; 0: none).
    pub quantum_rad: f64,
    /// Readings show the heading this long ago (s).
    pub latency_s: f64,
    /// Probability that a reading is lost.
    pub loss: f64,
}

impl HeadingModel {
    /// Checks every term is physical; names the first that is not.
    pub fn validate(&self) -> Result<(), (&'static str, f64)> {
        for (name, v, lo, hi) in [
            ("motor_offset_rad", self.motor_offset_rad, -0.5, 0.5),
            ("gyro_scale_error", self.gyro_scale_error, -0.2, 0.2),
            ("gyro_bias_rad_s", self.gyro_bias_rad_s, -0.1, 0.1),
            ("gyro_bias_walk", self.gyro_bias_walk, 0.0, 0.1),
            ("quantum_rad", self.quantum_rad, 0.0, 0.5),
            ("latency_s", self.latency_s, 0.0, 5.0),
            ("loss", self.loss, 0.0, 0.99),
        ] {
            if !(v.is_finite() && (lo..=hi).contains(&v)) {
                return Err((name, v));
            }
        }
        if self
            .deviation
            .0
            .iter()
            .any(|c| !(c.is_finite() && c.abs() <= 0.8))
        {
            return Err(("deviation", self.deviation.amplitude()));
        }
        Ok(())
    }
}

/// Heading values kept for the latency (a second more than it, at most this many).
const HISTORY: usize = 1 << 16;

/// The state of a simulated heading sensor: what it has integrated (a gyro), its bias now, and
/// the recent readings a latency looks back into.
#[derive(Debug, Clone)]
pub struct HeadingSensor {
    model: HeadingModel,
    time_s: f64,
    /// The true turn since the sensor started (rad, unwrapped), as the robot turned.
    turned_rad: f64,
    /// The true turn and the gyro's reading at its first reading.
    gyro: Option<(f64, f64)>,
    bias_rad_s: f64,
    bias_integral_rad: f64,
    driving_until_s: f64,
    history: VecDeque<(f64, f64)>,
}

impl HeadingSensor {
    /// A sensor of `model` at time 0.
    pub fn new(model: HeadingModel) -> Self {
        HeadingSensor {
            model,
            time_s: 0.0,
            turned_rad: 0.0,
            gyro: None,
            bias_rad_s: model.gyro_bias_rad_s,
            bias_integral_rad: 0.0,
            driving_until_s: f64::NEG_INFINITY,
            history: VecDeque::new(),
        }
    }

    /// The model.
    pub fn model(&self) -> &HeadingModel {
        &self.model
    }

    /// Time passes to `t_s` (a clock that goes back is ignored): a gyro's bias integrates and
    /// walks.
    pub fn advance_to(&mut self, t_s: f64, rng: &mut ChaCha8Rng) {
        let dt = t_s - self.time_s;
        if !(dt > 0.0 && dt.is_finite()) {
            return;
        }
        if self.model.kind == SensorKind::Gyro {
            if self.model.gyro_bias_walk > 0.0 {
                let step = Normal::new(0.0, self.model.gyro_bias_walk * dt.sqrt())
                    .map(|n| n.sample(rng))
                    .unwrap_or(0.0);
                self.bias_rad_s += step;
            }
            self.bias_integral_rad += self.bias_rad_s * dt;
        }
        self.time_s = t_s;
    }

    /// The wheels drove just now (the motor field is on for a tenth of a second after) and
    /// turned the robot by `turn_rad` (truly): a gyro integrates every turn, however seldom it
    /// is read.
    pub fn moved(&mut self, turn_rad: f64) {
        self.driving_until_s = self.time_s + 0.1;
        self.turned_rad += turn_rad;
    }

    /// The sensor's value now for a robot whose true heading is `true_heading_rad`, before
    /// noise and latency.
    fn value(&mut self, true_heading_rad: f64) -> f64 {
        match self.model.kind {
            SensorKind::Compass => {
                let motor = if self.time_s <= self.driving_until_s {
                    self.model.motor_offset_rad
                } else {
                    0.0
                };
                true_heading_rad + self.model.deviation.at(true_heading_rad) + motor
            }
            SensorKind::Gyro => {
                let turned = self.turned_rad;
                let (start_turn, start_read) = *self.gyro.get_or_insert((turned, true_heading_rad));
                start_read
                    + (1.0 + self.model.gyro_scale_error) * (turned - start_turn)
                    + self.bias_integral_rad
            }
        }
    }

    /// A reading now of a robot whose true heading is `true_heading_rad`, with `noise`
    /// (rad, drawn by the caller) added: `None` when the reading is lost.
    pub fn read(
        &mut self,
        true_heading_rad: f64,
        noise_rad: f64,
        rng: &mut ChaCha8Rng,
    ) -> Option<f64> {
        let v = self.value(true_heading_rad);
        let shown = if self.model.latency_s > 0.0 {
            self.history.push_back((self.time_s, v));
            let oldest = self.time_s - self.model.latency_s;
            while self.history.len() > HISTORY
                || self.history.get(1).is_some_and(|(t, _)| *t <= oldest)
            {
                self.history.pop_front();
            }
            self.history.front().map_or(v, |(_, old)| *old)
        } else {
            v
        };
        if self.model.loss > 0.0 && rng.random_bool(self.model.loss) {
            return None;
        }
        let mut r = shown + noise_rad;
        if self.model.quantum_rad > 0.0 {
            r = (r / self.model.quantum_rad).round() * self.model.quantum_rad;
        }
        Some(wrap_angle(r))
    }
}

/// What a simulated sensor measures, as a backend would report it.
impl From<SensorKind> for crate::samples::HeadingKind {
    fn from(kind: SensorKind) -> Self {
        match kind {
            SensorKind::Compass => crate::samples::HeadingKind::Magnetic,
            SensorKind::Gyro => crate::samples::HeadingKind::Gyro,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn a_deviation_is_removed_and_its_amplitude_read() {
        let d: Deviation = "2.2,0,0,0.7".parse().unwrap();
        for deg in [-170.0f64, -90.0, 0.0, 37.0, 135.0] {
            let psi = deg.to_radians();
            let r = psi + d.at(psi);
            assert!((d.remove(r) - psi).abs() < 1e-6, "{deg}");
        }
        assert!((d.amplitude().to_degrees() - 2.9).abs() < 0.1);
        assert!("1,2,3".parse::<Deviation>().is_err());
    }

    #[test]
    fn a_gyro_reads_its_scale_and_a_latency_shows_the_past() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut g = HeadingSensor::new(HeadingModel {
            kind: SensorKind::Gyro,
            gyro_scale_error: 0.01,
            ..HeadingModel::default()
        });
        g.read(0.0, 0.0, &mut rng).unwrap();
        // A whole turn between two readings still counts.
        g.moved(std::f64::consts::TAU);
        let total = g.read(0.0, 0.0, &mut rng).unwrap();
        // One full turn reads 1 % more: 3.6° past the start.
        assert!(
            (total.to_degrees() - 3.6).abs() < 1e-6,
            "{}",
            total.to_degrees()
        );
        let mut c = HeadingSensor::new(HeadingModel {
            latency_s: 0.3,
            ..HeadingModel::default()
        });
        let mut last = 0.0;
        for k in 0..100 {
            c.advance_to(0.01 * f64::from(k), &mut rng);
            last = c.read(0.01 * f64::from(k), 0.0, &mut rng).unwrap();
        }
        // At 0.99 s it shows the heading of 0.69 s.
        assert!((last - 0.69).abs() < 0.011, "{last}");
    }
}
