//! Heading at rest: circular means of repeated readings and the noise of a sensor at rest.
//!
//! The noise is pooled over every rest of a calibration ([`NoisePool`]): ten readings at
//! pre-flight alone state σ within ±30 % only four times in five, and the Cramér–Rao bound and
//! the convergence rule are built on it.

use super::RoutineError;
use crate::base::{BaseError, HeadingSource};
use crate::kinematics::wrap_angle;

/// The circular mean of `angles` (rad), wrapped to (−π, π].
pub fn circular_mean(angles: &[f64]) -> f64 {
    crate::kinematics::circular_mean(angles.iter().copied()).unwrap_or(0.0)
}

/// The sample standard deviation of `angles` about their circular mean (rad); 0 for fewer
/// than two.
pub fn circular_std(angles: &[f64]) -> f64 {
    NoisePool::of(angles).std_rad()
}

/// The heading at rest as `odocal heading` reads it: the circular mean of readings and, of two
/// or more, their spread (the noise per reading `odocal plan --heading-sigma-deg` wants).
#[derive(Debug, Clone, PartialEq)]
pub struct HeadingReading {
    /// Circular mean (rad, counter-clockwise positive, wrapped to (−π, π]).
    pub mean_rad: f64,
    /// Readings averaged.
    pub samples: usize,
    /// Their sample standard deviation (rad), of two or more.
    pub sigma_rad: Option<f64>,
}

impl HeadingReading {
    /// `n` readings of `source`, averaged.
    pub async fn read(source: &dyn HeadingSource, n: usize) -> Result<Self, RoutineError> {
        let all = readings(source, n).await?;
        Ok(HeadingReading {
            mean_rad: circular_mean(&all),
            samples: all.len(),
            sigma_rad: (all.len() > 1).then(|| circular_std(&all)),
        })
    }

    /// The reading as JSON (radians and degrees).
    pub fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "heading_rad": self.mean_rad,
            "heading_deg": self.mean_rad.to_degrees(),
            "samples": self.samples,
            "sigma_rad": self.sigma_rad,
            "sigma_deg": self.sigma_rad.map(f64::to_degrees),
        })
    }
}

impl std::fmt::Display for HeadingReading {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "heading {:.3}° ({:.6} rad, counter-clockwise positive, mean of {})",
            self.mean_rad.to_degrees(),
            self.mean_rad,
            self.samples
        )?;
        if let Some(s) = self.sigma_rad {
            write!(
                f,
                "; σ {:.3}° per reading (odocal plan --heading-sigma-deg)",
                s.to_degrees()
            )?;
        }
        Ok(())
    }
}

/// The spread of readings at rest pooled over several rests: each rest's squared deviations
/// about its own circular mean, so that a heading that differs from rest to rest (the robot
/// turned) adds nothing.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct NoisePool {
    /// Σ of squared deviations from each rest's mean (rad²).
    pub sum_sq_rad2: f64,
    /// Degrees of freedom: Σ (readings − 1) over the rests.
    pub dof: usize,
}

impl NoisePool {
    /// The spread of one rest's readings.
    pub fn of(angles: &[f64]) -> Self {
        if angles.len() < 2 {
            return NoisePool::default();
        }
        let mean = circular_mean(angles);
        NoisePool {
            sum_sq_rad2: angles.iter().map(|h| wrap_angle(h - mean).powi(2)).sum(),
            dof: angles.len() - 1,
        }
    }

    /// Both pools together.
    pub fn plus(self, other: NoisePool) -> Self {
        NoisePool {
            sum_sq_rad2: self.sum_sq_rad2 + other.sum_sq_rad2,
            dof: self.dof + other.dof,
        }
    }

    /// Whether this rest's spread could come from the same noise as `reference` (the
    /// pre-flight's readings): the ratio of their variances within the 99.9 % point of
    /// F(dof, reference dof) (Paulson's approximation), so a reference that by chance came out
    /// low flags nothing extra. A rest beyond it was not at rest (the robot still settling, a
    /// bump); its readings say nothing about the sensor.
    pub fn consistent_with(&self, reference: &NoisePool) -> bool {
        let sigma = reference.std_rad();
        if self.dof == 0 || reference.dof == 0 || sigma.is_nan() || sigma <= 0.0 {
            return true;
        }
        let ratio = self.std_rad().powi(2) / (sigma * sigma);
        ratio <= f_quantile_999(self.dof as f64, reference.dof as f64)
    }

    /// The pooled standard deviation of one reading (rad); 0 without degrees of freedom.
    pub fn std_rad(&self) -> f64 {
        if self.dof == 0 {
            0.0
        } else {
            (self.sum_sq_rad2 / self.dof as f64).sqrt()
        }
    }
}

/// The 99.9 % point of the F distribution with `d1` and `d2` degrees of freedom, by
/// Paulson's normal approximation of F^(1/3) (a few per cent high from d1 = 2 on, so a rest
/// is flagged a little less often than one in a thousand, never more).
fn f_quantile_999(d1: f64, d2: f64) -> f64 {
    const Z2: f64 = 3.090_232 * 3.090_232;
    let (c1, c2) = (2.0 / (9.0 * d1), 2.0 / (9.0 * d2));
    let (a, b) = (1.0 - c2, 1.0 - c1);
    let qa = a * a - Z2 * c2;
    let disc = (a * b).powi(2) - qa * (b * b - Z2 * c1);
    if qa <= 0.0 || disc < 0.0 {
        return f64::INFINITY;
    }
    ((a * b + disc.sqrt()) / qa).powi(3)
}

/// The heading at rest: the circular mean of its readings and their spread.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rest {
    /// Circular mean (rad).
    pub mean_rad: f64,
    /// The readings' spread about it.
    pub noise: NoisePool,
}

/// At least `min` and at most `max` valid readings, as many as arrive within `budget` once
/// `min` are in: the pre-flight's noise at rest, precise on a fast sensor and not slow on a
/// slow one.
pub async fn readings_within(
    source: &dyn HeadingSource,
    min: usize,
    max: usize,
    budget: std::time::Duration,
) -> Result<Vec<f64>, RoutineError> {
    let start = tokio::time::Instant::now();
    let mut out = readings(source, min).await?;
    while out.len() < max && start.elapsed() < budget {
        out.extend(readings(source, 1).await?);
    }
    Ok(out)
}

/// Invalid readings in a row that are taken as lost samples, not a failed sensor, whatever
/// the time they took: a sensor that drops 5 % of its samples loses three in a row about once
/// in 8000 readings, ten practically never.
pub const LOST_IN_A_ROW: usize = 10;

/// How long a sensor may go without one valid reading (once two in a row were invalid) before
/// it is taken as failed: a compass that stopped sending is named within seconds, not after
/// [`LOST_IN_A_ROW`] of its own staleness waits.
pub const SILENT_FOR: std::time::Duration = std::time::Duration::from_secs(2);

/// `n` (at least 1) valid readings. An invalid reading is a lost sample and is skipped (the
/// average is thinner, not wrong); the sensor is taken as failed, with the last reason, after
/// [`LOST_IN_A_ROW`] invalid readings in a row, or two in a row with no valid reading for
/// [`SILENT_FOR`].
pub async fn readings(source: &dyn HeadingSource, n: usize) -> Result<Vec<f64>, RoutineError> {
    let mut out = Vec::with_capacity(n.max(1));
    let mut in_a_row = 0usize;
    let mut last_valid = tokio::time::Instant::now();
    while out.len() < n.max(1) {
        let h = source.read().await?;
        match h.validity {
            crate::base::Validity::Valid if h.heading_rad.is_finite() => {
                in_a_row = 0;
                last_valid = tokio::time::Instant::now();
                out.push(h.heading_rad);
            }
            validity => {
                in_a_row += 1;
                if in_a_row >= LOST_IN_A_ROW
                    || (in_a_row >= 2 && last_valid.elapsed() >= SILENT_FOR)
                {
                    let reason = match validity {
                        crate::base::Validity::Invalid(reason) => reason,
                        crate::base::Validity::Valid => "the reading is not a number".into(),
                    };
                    return Err(BaseError::HeadingInvalid {
                        reason: format!("{reason} ({in_a_row} invalid readings in a row)"),
                    }
                    .into());
                }
            }
        }
    }
    Ok(out)
}

/// The circular mean of `n` valid readings at rest (rad).
pub async fn mean_heading(source: &dyn HeadingSource, n: usize) -> Result<f64, RoutineError> {
    Ok(at_rest(source, n).await?.mean_rad)
}

/// `n` valid readings at rest: their circular mean and spread.
pub async fn at_rest(source: &dyn HeadingSource, n: usize) -> Result<Rest, RoutineError> {
    let r = readings(source, n).await?;
    Ok(Rest {
        mean_rad: circular_mean(&r),
        noise: NoisePool::of(&r),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::{ComponentInfo, HeadingSample, SampleStream, Validity};
    use std::f64::consts::PI;
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::time::Duration;

    /// A sensor whose `k`-th reading (from 0) is valid when `valid(k)`, each taking `took`.
    struct Scripted {
        valid: fn(usize) -> bool,
        took: Duration,
        reads: AtomicUsize,
    }

    impl Scripted {
        fn new(valid: fn(usize) -> bool, took: Duration) -> Self {
            Scripted {
                valid,
                took,
                reads: AtomicUsize::new(0),
            }
        }
    }

    #[async_trait::async_trait]
    impl HeadingSource for Scripted {
        fn info(&self) -> ComponentInfo {
            ComponentInfo {
                kind: "scripted".into(),
                id: String::new(),
                details: serde_json::Value::Null,
            }
        }
        async fn read(&self) -> Result<HeadingSample, BaseError> {
            tokio::time::sleep(self.took).await;
            let k = self.reads.fetch_add(1, Ordering::Relaxed);
            Ok(HeadingSample {
                time_s: k as f64,
                heading_rad: 0.1 * k as f64,
                validity: if (self.valid)(k) {
                    Validity::Valid
                } else {
                    Validity::Invalid("lost".into())
                },
            })
        }
        async fn stream(
            &self,
            _period: Duration,
        ) -> Result<Option<SampleStream<HeadingSample>>, BaseError> {
            Ok(None)
        }
    }

    fn failure(r: Result<Vec<f64>, RoutineError>) -> String {
        match r {
            Err(RoutineError::Base(BaseError::HeadingInvalid { reason })) => reason,
            other => panic!("expected an invalid heading, got {other:?}"),
        }
    }

    /// Lost readings are skipped, however many, while valid ones keep coming; ten lost in a
    /// row fail with the sensor's reason; so do two when no valid one came for 2 s.
    #[tokio::test(start_paused = true)]
    async fn lost_readings_thin_the_average_and_a_silent_sensor_fails_in_time() {
        let every_third = Scripted::new(|k| k % 3 == 2, Duration::from_millis(10));
        let got = readings(&every_third, 4).await.unwrap();
        assert_eq!(got.len(), 4);
        assert!(
            (got[0] - 0.2).abs() < 1e-12 && (got[3] - 1.1).abs() < 1e-12,
            "{got:?}"
        );

        let dead = Scripted::new(|_| false, Duration::from_millis(1));
        let why = failure(readings(&dead, 3).await);
        assert!(why.contains("lost") && why.contains("10 invalid"), "{why}");
        assert_eq!(dead.reads.load(Ordering::Relaxed), LOST_IN_A_ROW);

        let slow_and_dead = Scripted::new(|k| k == 0, Duration::from_millis(1500));
        let why = failure(readings(&slow_and_dead, 3).await);
        assert!(why.contains("2 invalid"), "{why}");
        assert_eq!(slow_and_dead.reads.load(Ordering::Relaxed), 3);
    }

    #[test]
    fn the_mean_of_headings_across_the_seam_stays_near_pi() {
        let m = circular_mean(&[PI - 0.01, -PI + 0.01, PI - 0.02, -PI + 0.02]);
        assert!((m.abs() - PI).abs() < 1e-12, "{m}");
        let s = circular_std(&[PI - 0.01, -PI + 0.01]);
        assert!((s - 0.01 * 2f64.sqrt()).abs() < 1e-12, "{s}");
    }

    #[test]
    fn pooled_noise_ignores_where_each_rest_points() {
        // Two rests 90° apart, each ±0.01 rad about its own mean: σ is 0.01·√2 from each, and
        // the same pooled; a rest of one reading adds nothing.
        let a = NoisePool::of(&[PI - 0.01, -PI + 0.01]);
        let b = NoisePool::of(&[1.0 - 0.01, 1.0 + 0.01]);
        let pooled = a.plus(b).plus(NoisePool::of(&[0.3]));
        assert_eq!(pooled.dof, 2);
        assert!((pooled.std_rad() - 0.01 * 2f64.sqrt()).abs() < 1e-12);
        assert_eq!(NoisePool::default().std_rad(), 0.0);
    }

    #[test]
    fn a_rest_that_moved_is_told_from_one_that_is_noisy() {
        let sigma = 0.01;
        let known = |dof: usize| NoisePool {
            sum_sq_rad2: sigma * sigma * dof as f64,
            dof,
        };
        // Four readings at ±σ: consistent; the same rest drifting 6σ across is not.
        let quiet = NoisePool::of(&[0.5 - sigma, 0.5 + sigma, 0.5 - sigma, 0.5 + sigma]);
        assert!(quiet.consistent_with(&known(49)));
        let drifting =
            NoisePool::of(&[0.5, 0.5 + 2.0 * sigma, 0.5 + 4.0 * sigma, 0.5 + 6.0 * sigma]);
        assert!(!drifting.consistent_with(&known(49)));
        // Against a σ known exactly, the 99.9 % point of χ²₄/4 (18.47/4): just inside, just
        // outside; against 49 readings, F(4, 49)'s (about 5.5) lets the second through.
        let inside = NoisePool {
            sum_sq_rad2: 18.3 * sigma * sigma,
            dof: 4,
        };
        let outside = NoisePool {
            sum_sq_rad2: 19.0 * sigma * sigma,
            dof: 4,
        };
        let exact = known(1_000_000);
        assert!(inside.consistent_with(&exact) && !outside.consistent_with(&exact));
        assert!(outside.consistent_with(&known(49)));
        let beyond = NoisePool {
            sum_sq_rad2: 25.0 * sigma * sigma,
            dof: 4,
        };
        assert!(!beyond.consistent_with(&known(49)));
    }

    #[test]
    fn f_quantiles_are_close_to_the_tables() {
        // Printed tables' 99.9 % points: F(8, 40) 4.00, F(4, 40) 5.70, F(4, 60) 5.31,
        // F(2, 120) 7.32, and F(8, ∞) = χ²₈/8 = 3.27.
        for (d1, d2, want) in [
            (8.0, 40.0, 4.00),
            (4.0, 40.0, 5.70),
            (4.0, 60.0, 5.31),
            (2.0, 120.0, 7.32),
            (8.0, 1e7, 3.27),
        ] {
            let got = f_quantile_999(d1, d2);
            // High by up to 6 % (F(8, 40)), never low: a rest is flagged a little less often.
            let r = got / want;
            assert!(
                (0.99..1.07).contains(&r),
                "F({d1}, {d2}) = {got}, table {want}"
            );
        }
    }
}

#[cfg(test)]
mod reading_tests {
    use super::*;

    #[test]
    fn a_reading_says_its_mean_and_its_spread_in_degrees() {
        let one = HeadingReading {
            mean_rad: std::f64::consts::FRAC_PI_2,
            samples: 1,
            sigma_rad: None,
        };
        assert_eq!(
            one.to_string(),
            "heading 90.000° (1.570796 rad, counter-clockwise positive, mean of 1)"
        );
        let many = HeadingReading {
            samples: 50,
            sigma_rad: Some(0.5f64.to_radians()),
            ..one
        };
        assert!(many
            .to_string()
            .ends_with("; σ 0.500° per reading (odocal plan --heading-sigma-deg)"));
        let v = many.json();
        assert!((v["sigma_deg"].as_f64().unwrap() - 0.5).abs() < 1e-12);
        assert_eq!(v["samples"], 50);
    }
}
