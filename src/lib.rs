//! odocal: odometry calibration for two-wheel differential-drive robots.
//!
//! Layers, data flowing one way (each uses only those above it):
//! - [`kinematics`]: parameters, the exact pose update, sign conventions, split conventions.
//! - [`sim`]: a true robot driven open-loop by a controller with its own configured parameters.
//! - [`calibration`]: pure estimators from square tests (UMBmark, Lee, heading-only,
//!   Jung & Chung, exact) with standard errors and the Cramér–Rao bound; the online filter.
//! - [`study`]: simulated calibrate → write back → verify experiments (the paper's Sec. 3).
//! - [`dataset`]: readers for recorded runs (OptiOdom) and replay evaluation.
//! - [`protocol`]: the serial wire protocol of `protocol/SPEC.md` (the `odocal-protocol` crate).
//! - [`base`]: the seam — a drive, a heading source and a parameter store — and the one write
//!   transaction.
//! - [`hal`]: our protocol's async client over any byte stream; a [`base`] backend.
//! - [`mock`]: simulated robots behind the protocol (duplex or pseudo-terminal) and behind the
//!   seam in process.
//! - [`ros`]: ROS robots — messages, the ros2_control YAML store, bags, rosbridge.
//! - [`routine`]: the recalibration procedure, over the seam only.
//! - [`track`]: the online estimator fed from live telemetry, logs or recorded data sets.
//! - [`report`]: Markdown, plots, report files and the ROS 2 export.
//! - [`demo`]: the mock device, the HAL and the routine wired together.
//!
//! ```
//! use odocal::calibration::{estimate, Method, RunMeasurement, SquareTest};
//! use odocal::kinematics::SplitConvention;
//!
//! let run = |deg: f64| RunMeasurement {
//!     heading_error_rad: deg.to_radians(),
//!     final_xy_m: None,
//!     leg_heading_error_rad: None,
//! };
//! let test = SquareTest {
//!     side_m: 4.0,
//!     wheelbase_m: 0.39,
//!     cw: vec![run(-26.31), run(-26.92)],
//!     ccw: vec![run(-11.62), run(-12.15)],
//! };
//! let est = estimate(Method::Exact, &test, SplitConvention::LeftNominal).unwrap();
//! assert!((est.e_b - 0.976).abs() < 0.002);
//! ```

#![warn(missing_docs)]

pub mod base;
pub mod calibration;
pub mod dataset;
pub mod demo;
pub mod hal;
pub mod kinematics;
pub mod mock;
pub mod nmea;
pub mod profile;
pub mod protocol;
pub mod report;
pub mod roboclaw;
pub mod ros;
pub mod routine;
pub mod sim;
pub mod study;
pub mod track;
