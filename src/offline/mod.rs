//! What works without a robot: recorded data sets with ground truth ([`dataset`]), recording
//! logs ([`log`]), the wheels and poses files of `odocal fit` ([`pose_csv`]) and simulated
//! studies ([`study`]). Each recorded input converts into a
//! [`crate::calibration::recording::Recording`] and goes through the one pipeline from there.

pub mod dataset;
pub mod drive_study;
pub mod log;
pub mod pose_csv;
pub mod study;
pub mod track_replay;
