//! The demo: the full routine against the built-in simulated robot, served on a real
//! pseudo-terminal and opened by its path like a USB adapter, in virtual time. It wires the
//! mock device, the HAL and the routine together, which is why it lives above all three.

use crate::base::{Base, GroundTruth};
use crate::hal::{open_port, HalError};
use crate::kinematics::{Pose, WheelParams};
use crate::mock::{
    lock, spawn_pty, FaultConfig, MockConfig, MockDevice, MockError, SharedDevice, TimeMode,
};
use crate::routine::config::{RoutineConfig, WritePolicy};
use crate::routine::{run, Report, RoutineError, RoutineUi};
use crate::sim::SimError;
use std::sync::{Arc, Mutex};
use tokio_util::sync::CancellationToken;

/// Why the demo could not run.
#[derive(Debug, thiserror::Error)]
pub enum DemoError {
    /// The demo robot's settings are impossible.
    #[error("the demo robot cannot be built: {0}")]
    Robot(#[from] SimError),
    /// The mock device refused its configuration.
    #[error(transparent)]
    Mock(#[from] MockError),
    /// No pseudo-terminal could be created.
    #[error("cannot create a pseudo-terminal: {0}")]
    Pty(#[source] std::io::Error),
    /// Opening or greeting the mock device failed.
    #[error(transparent)]
    Link(#[from] HalError),
    /// The routine failed.
    #[error(transparent)]
    Routine(#[from] RoutineError),
}

/// The demo robot and routine.
#[derive(Debug, Clone, PartialEq)]
pub struct DemoOptions {
    /// True `E_b` of the simulated robot.
    pub true_e_b: f64,
    /// True `E_d` (left wheel nominal).
    pub true_e_d: f64,
    /// Nominal parameters (the controller's factory configuration).
    pub nominal: WheelParams,
    /// Compass noise per reading (deg).
    pub compass_sigma_deg: f64,
    /// Seed of the simulated robot.
    pub seed: u64,
    /// Link faults.
    pub faults: FaultConfig,
    /// How the robot's heading sensor errs.
    pub heading_model: crate::sim::sensor::HeadingModel,
    /// The routine's settings.
    pub routine: RoutineConfig,
}

impl Default for DemoOptions {
    fn default() -> Self {
        DemoOptions {
            true_e_b: 0.976,
            true_e_d: 0.992,
            nominal: WheelParams::nominal(0.15, 0.39, 4096.0),
            compass_sigma_deg: 0.37,
            seed: 1,
            faults: FaultConfig::default(),
            heading_model: Default::default(),
            routine: RoutineConfig {
                write_back: WritePolicy::Yes,
                confirm_motion: false,
                settle_s: 0.0,
                backup_dir: Some(std::env::temp_dir().join("odocal-demo")),
                ..RoutineConfig::default()
            },
        }
    }
}

/// The demo as a user sets it (with the `cli` feature, `odocal demo`'s flags, their doc
/// comments the help): the simulated robot, its link's faults, where the report goes, and the
/// routine's targets.
#[derive(Debug, Clone)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct DemoSettings {
    /// The simulated robot's true errors (checked as every mock checks them).
    #[cfg_attr(feature = "cli", command(flatten))]
    pub truth: crate::mock::options::TrueRobot,
    /// The simulated compass's noise per reading (deg; σ).
    #[cfg_attr(feature = "cli", arg(long = "heading-sigma-deg", alias = "compass-sigma-deg", default_value_t = crate::sim::sensor::SIM_HEADING_SIGMA_DEG))]
    pub compass_sigma_deg: f64,
    /// Seed of the simulated robot.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1))]
    pub seed: u64,
    /// Link faults, as for `mock-device` (e.g. "corrupt=0.01,drop=0.05").
    #[cfg_attr(feature = "cli", arg(long))]
    pub faults: Option<FaultConfig>,
    /// Where to write report.json, report.md and the plots.
    #[cfg_attr(feature = "cli", arg(long, default_value = "odocal-demo-report"))]
    pub report_dir: std::path::PathBuf,
    /// Allow parameter changes of up to 100 % (a simulated skid-steer robot, --true-eb 1.5).
    #[cfg_attr(feature = "cli", arg(long))]
    pub allow_large_change: bool,
    /// Stop each round's squares once the stated standard error of E_b is at most this (as
    /// `calibrate --target-eb-std`).
    #[cfg_attr(feature = "cli", arg(long))]
    pub target_eb_std: Option<f64>,
    /// As --target-eb-std, for E_d.
    #[cfg_attr(feature = "cli", arg(long))]
    pub target_ed_std: Option<f64>,
    /// How the simulated robot's heading sensor errs.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub sensor: crate::mock::options::SensorErrors,
}

impl DemoSettings {
    /// The demo these settings describe, checked. Its backup goes into the report directory
    /// (a second run's is `…-2`).
    pub fn options(&self) -> Result<DemoOptions, DemoError> {
        self.truth.check()?;
        let mut opts = DemoOptions {
            true_e_b: self.truth.true_eb,
            true_e_d: self.truth.true_ed,
            compass_sigma_deg: self.compass_sigma_deg,
            seed: self.seed,
            faults: self.faults.unwrap_or_default(),
            heading_model: self.sensor.model()?,
            ..DemoOptions::default()
        };
        opts.faults.seed = self.seed;
        opts.routine.backup_dir = None;
        opts.routine.report_dir = Some(self.report_dir.clone());
        if self.allow_large_change {
            opts.routine.allow_large_change = true;
            opts.routine.max_change = 1.0;
        }
        opts.routine.target_e_b_std = self.target_eb_std;
        opts.routine.target_e_d_std = self.target_ed_std;
        opts.routine.validate().map_err(RoutineError::from)?;
        Ok(opts)
    }
}

/// The mock device's simulator as ground truth.
pub struct MockTruth(pub SharedDevice);

impl GroundTruth for MockTruth {
    fn pose(&self) -> Pose {
        lock(&self.0).sim().pose()
    }
    fn true_params(&self) -> WheelParams {
        *lock(&self.0).sim().truth()
    }
}

/// Builds the demo's simulated robot.
pub fn demo_device(opts: &DemoOptions) -> Result<SharedDevice, DemoError> {
    let mut cfg = MockConfig::with_ratios(opts.nominal, opts.true_e_b, opts.true_e_d)?;
    cfg.noise.compass_sigma_rad = opts.compass_sigma_deg.to_radians();
    cfg.seed = opts.seed;
    cfg.heading_model = opts.heading_model;
    let device = MockDevice::new(cfg)?;
    Ok(Arc::new(Mutex::new(device)))
}

/// Runs the full routine against a fresh simulated robot served on a pseudo-terminal, opened
/// by its path like a USB adapter, in virtual time.
pub async fn run_demo(
    opts: &DemoOptions,
    ui: &mut dyn RoutineUi,
    cancel: &CancellationToken,
) -> Result<(Report, SharedDevice), DemoError> {
    let device = demo_device(opts)?;
    let report = run_demo_on(&device, opts, ui, cancel).await?;
    Ok((report, device))
}

/// [`run_demo`] on a device the caller built (and can inspect afterwards, whether the run
/// succeeded or not).
pub async fn run_demo_on(
    device: &SharedDevice,
    opts: &DemoOptions,
    ui: &mut dyn RoutineUi,
    cancel: &CancellationToken,
) -> Result<Report, DemoError> {
    let server =
        spawn_pty(device.clone(), TimeMode::Virtual, opts.faults).map_err(DemoError::Pty)?;
    let (client, _) = open_port(&server.path, crate::hal::DEFAULT_BAUD).await?;
    let truth = MockTruth(device.clone());
    // The simulated robot's sensor is known: said, as a user says it with --heading-kind.
    let mut base = Base::single(client);
    base.heading = std::sync::Arc::new(crate::base::adjusted::Adjusted::new(
        base.heading.clone(),
        Some(crate::mock::heading_kind(&opts.heading_model)),
        Default::default(),
    ));
    let report = run(&base, &opts.routine, Some(&truth), ui, cancel).await?;
    Ok(report)
}
