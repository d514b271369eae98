//! odocal: odometry calibration for two-wheel differential-drive robots.
//!
//! Layers, data flowing one way (each uses only those above it; `docs/architecture.md` has
//! the whole map and `tests/architecture.rs` checks it):
//! - [`kinematics`]: parameters, the exact pose update, the odometry's displacement, sign
//!   conventions, split conventions.
//! - [`sim`]: a true robot driven open-loop by a controller with its own configured parameters.
//! - [`calibration`]: pure estimators from square tests (UMBmark, Lee, heading-only,
//!   Jung & Chung, exact, legs) with standard errors and the Cramér–Rao bound; the one
//!   recording pipeline every input converts into; the online filter and its tracker.
//! - [`io`]: bounded reads, atomic writes, backups, serial ports.
//! - [`protocol`]: the serial wire protocol of `protocol/SPEC.md` (the `odocal-protocol` crate).
//! - [`base`]: the seam — a drive, a heading source and a parameter store — the one write
//!   transaction, and the file store every file format plugs into.
//! - Backends, one folder each: [`hal`] (our protocol), [`ros`] (rosbridge, bags, the
//!   ros2_control YAML), [`roboclaw`] (with its robot profile), [`nmea`] (compasses).
//! - [`spec`]: where a robot is — drive, heading and store specs, any drive with any heading
//!   source; the one list of backends.
//! - [`routine`]: the recalibration procedure and live tracking, over the seam only.
//! - [`offline`]: recorded data sets, recording logs and simulated studies.
//! - [`mock`]: simulated robots behind each protocol (duplex, pseudo-terminal, loopback) and
//!   behind the seam in process.
//! - [`report`]: Markdown, plots, report files and the ROS 2 export.
//! - [`demo`]: the mock device, the HAL and the routine wired together.
//!
//! Each backend is a Cargo feature, all on by default: `odocal-protocol` ([`hal`],
//! [`protocol`]), `ros` (with `bag-sqlite` and `bag-compression` for those bags), `roboclaw`,
//! `nmea`, `mock` and `conformance`; `cli` is the command line. With `default-features =
//! false` the library is the core: kinematics, simulation, calibration, the seam, the routine,
//! recordings, reports and the spec parser, which names the feature a backend it was given
//! needs ([`features::NotBuilt`]).
//!
//! ```
//! use odocal::calibration::{estimate, Method, RunMeasurement, SquareTest};
//! use odocal::kinematics::SplitConvention;
//!
//! let run = |deg: f64| RunMeasurement::heading(deg.to_radians());
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
#[cfg(all(feature = "mock", feature = "odocal-protocol"))]
pub mod demo;
pub mod features;
#[cfg(feature = "odocal-protocol")]
pub mod hal;
pub mod io;
pub mod kinematics;
#[cfg(feature = "mock")]
pub mod mock;
#[cfg(any(feature = "nmea", feature = "mock"))]
pub mod nmea;
pub mod offline;
#[cfg(feature = "odocal-protocol")]
pub mod protocol;
pub mod ranges;
pub mod report;
#[cfg(feature = "roboclaw")]
pub mod roboclaw;
#[cfg(feature = "ros")]
pub mod ros;
pub mod routine;
pub mod samples;
pub mod sim;
pub mod spec;
