//! Flags several commands share (a leaf: it uses no other file of the binary): the split
//! convention, a mock's true robot, its heading sensor's errors and its extra NMEA compass,
//! and how a mock server is stopped.

use odocal::kinematics::SplitConvention;
use odocal::ranges::{check_range as in_range, check_ranges as in_ranges};

/// Convention flags shared by the subcommands that estimate.
#[derive(Debug, Clone, clap::Args)]
pub struct ConventionArgs {
    /// Diameter split for estimation and write-back: left-nominal, mean-preserving or
    /// measured-scale:COMMANDED_M,MEASURED_M.
    #[arg(long, default_value = "left-nominal")]
    convention: SplitConvention,
    /// Straight-line scale check: distance commanded (m). With --straight-measured-m, fixes
    /// the absolute wheel scale (overrides --convention).
    #[arg(long, requires = "straight_measured_m")]
    straight_commanded_m: Option<f64>,
    /// Straight-line scale check: distance measured start to end with a tape (m).
    #[arg(long, requires = "straight_commanded_m")]
    straight_measured_m: Option<f64>,
}

impl ConventionArgs {
    /// The library convention these flags select.
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

/// A mock NMEA compass on the simulated robot of a mock server (`--nmea`): its terminal is
/// printed as `nmea:PATH` on the line after the server's own.
#[derive(Debug, Clone, clap::Args)]
pub struct MockCompassArgs {
    /// Also serve an NMEA 0183 compass on the robot, on a pseudo-terminal of its own (printed
    /// as nmea:PATH on the next line): a second sensor, the true heading with its own noise,
    /// sharing none of the robot's own heading sensor's errors.
    #[arg(long)]
    nmea: bool,
    /// Sentences per second of robot time of the --nmea compass.
    #[arg(long, default_value_t = 10.0)]
    nmea_hz: f64,
    /// Noise per sentence of the --nmea compass (deg).
    #[arg(long, default_value_t = 0.2)]
    nmea_sigma_deg: f64,
    /// How the --nmea compass ends its sentences: crlf (NMEA), lf or cr.
    #[arg(long, default_value = "crlf")]
    nmea_line_end: odocal::mock::nmea::LineEnd,
}

impl MockCompassArgs {
    /// Starts the compass if asked for and prints its spec; keep the handle while serving.
    pub fn spawn(
        &self,
        heading: odocal::mock::nmea::HeadingFn,
        time_scale: f64,
    ) -> Result<Option<odocal::mock::PtyServer<()>>, Box<dyn std::error::Error>> {
        if !self.nmea {
            return Ok(None);
        }
        in_range("--nmea-hz", self.nmea_hz, 0.1, 100.0)?;
        in_range("--nmea-sigma-deg", self.nmea_sigma_deg, 0.0, 10.0)?;
        let cfg = odocal::mock::nmea::MockCompassConfig {
            hz: self.nmea_hz,
            sigma_rad: self.nmea_sigma_deg.to_radians(),
            time_scale,
            line_end: self.nmea_line_end,
            ..Default::default()
        };
        let pty = odocal::mock::nmea::spawn_pty(cfg, heading)?;
        println!("nmea:{}", pty.path);
        Ok(Some(pty))
    }
}

/// The simulated heading sensor's noise per reading (deg, σ) every mock and simulation starts
/// with unless told otherwise: a real compass's at rest (`--heading-sigma-deg`).
pub const SIM_HEADING_SIGMA_DEG: f64 = 0.37;

/// The true errors of a mock's simulated robot.
#[derive(Debug, Clone, clap::Args)]
pub struct TrueRobotArgs {
    /// True E_b of the simulated robot (relative to its configured parameters).
    #[arg(long, default_value_t = 0.976)]
    pub true_eb: f64,
    /// True E_d of the simulated robot (left wheel nominal).
    #[arg(long, default_value_t = 0.992)]
    pub true_ed: f64,
}

impl TrueRobotArgs {
    /// Checks both against what a mock can simulate.
    pub fn check(&self) -> Result<(), String> {
        in_ranges(&[
            ("--true-eb", self.true_eb, 0.5, 2.0),
            ("--true-ed", self.true_ed, 0.8, 1.25),
        ])
    }
}

/// How a mock's heading sensor errs (all off by default: an ideal sensor with the mock's noise).
#[derive(Debug, Clone, clap::Args)]
pub struct HeadingModelArgs {
    /// The simulated heading sensor: compass (absolute, magnetic) or gyro (integrated).
    #[arg(long, default_value = "compass", value_parser = ["compass", "gyro"])]
    heading_sensor: String,
    /// A compass's deviation curve A1,B1,A2,B2 (deg): d(ψ) = A1 sin ψ + B1 cos ψ + A2 sin 2ψ +
    /// B2 cos 2ψ.
    #[arg(long, allow_hyphen_values = true)]
    deviation_deg: Option<odocal::sim::sensor::Deviation>,
    /// A compass's offset while the wheels drive (the motor currents' field, deg).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    motor_offset_deg: f64,
    /// A gyro's scale error (0.01: it reads 1 % more turn).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    gyro_scale_error: f64,
    /// A gyro's bias (deg/s).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    gyro_bias_deg_s: f64,
    /// A gyro bias's random walk (deg/s per √s).
    #[arg(long, default_value_t = 0.0)]
    gyro_bias_walk_deg_s: f64,
    /// Readings rounded to this step (deg; 0: none).
    #[arg(long, default_value_t = 0.0)]
    heading_quantum_deg: f64,
    /// Readings show the heading this long ago (s).
    #[arg(long, default_value_t = 0.0)]
    heading_latency_s: f64,
    /// Probability that a reading is lost.
    #[arg(long, default_value_t = 0.0)]
    heading_loss: f64,
}

impl HeadingModelArgs {
    /// The model these flags describe, checked.
    pub fn model(&self) -> Result<odocal::sim::sensor::HeadingModel, String> {
        use odocal::sim::sensor::{HeadingModel, SensorKind};
        let m = HeadingModel {
            kind: if self.heading_sensor == "gyro" {
                SensorKind::Gyro
            } else {
                SensorKind::Compass
            },
            deviation: self.deviation_deg.unwrap_or_default(),
            motor_offset_rad: self.motor_offset_deg.to_radians(),
            gyro_scale_error: self.gyro_scale_error,
            gyro_bias_rad_s: self.gyro_bias_deg_s.to_radians(),
            gyro_bias_walk: self.gyro_bias_walk_deg_s.to_radians(),
            quantum_rad: self.heading_quantum_deg.to_radians(),
            latency_s: self.heading_latency_s,
            loss: self.heading_loss,
        };
        m.validate()
            .map_err(|(name, value)| format!("heading sensor: {name} = {value} is out of range"))?;
        Ok(m)
    }
}

/// Waits until Ctrl-C, or until stdin closes unless `ignore_stdin` (how a test or a script
/// that started a mock server stops it).
pub async fn serve_until_stopped(ignore_stdin: bool) {
    let stdin_closed = async {
        if ignore_stdin {
            std::future::pending::<()>().await;
        }
        let mut sink = Vec::new();
        let _ = tokio::io::AsyncReadExt::read_to_end(&mut tokio::io::stdin(), &mut sink).await;
    };
    tokio::select! {
        _ = tokio::signal::ctrl_c() => {}
        () = stdin_closed => {}
    }
}
