//! What a user sets on a mock server, checked and turned into that mock's configuration: the
//! true robot, the simulated heading sensor's errors, the extra NMEA compass, and the options
//! of `mock-device`, `mock-rosbridge` and `mock-roboclaw`. With the `cli` feature these structs
//! are the command line's flags (their doc comments are its help); without it a program fills
//! them in itself. Every range a mock cannot simulate is refused here, by the flag's name.

#[cfg(feature = "odocal-protocol")]
use super::device::{CompassConvention, MockConfig};
use super::nmea::{LineEnd, MockCompassConfig};
#[cfg(feature = "roboclaw")]
use super::roboclaw::MockRoboClawConfig;
#[cfg(feature = "ros")]
use super::rosbridge::{EffortStyle, MockLocalization, MockRosConfig};
#[cfg(feature = "odocal-protocol")]
use super::serve::{FaultConfig, TimeMode};
use super::MockError;
#[cfg(feature = "ros")]
use crate::calibration::pose_reference::Pose2;
#[cfg(feature = "odocal-protocol")]
use crate::kinematics::WheelParams;
use crate::ranges::check_range;
#[cfg(any(feature = "odocal-protocol", feature = "ros", feature = "roboclaw"))]
use crate::ranges::check_ranges;
#[cfg(feature = "roboclaw")]
use crate::roboclaw::profile::{Channel, Profile};
#[cfg(feature = "ros")]
use crate::ros::yaml::DiffDriveConfig;
#[cfg(feature = "odocal-protocol")]
use std::path::PathBuf;

pub use crate::sim::options::{SensorErrors, TrueRobot};
pub use crate::sim::sensor::SIM_HEADING_SIGMA_DEG;

/// A setting a mock cannot simulate (the message names the flag and its range).
fn setting(message: String) -> MockError {
    MockError::Setting(message)
}

/// A mock NMEA compass on the simulated robot of a mock server (`--nmea`): a second sensor on a
/// pseudo-terminal of its own, printed as `nmea:PATH` on the line after the server's own.
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct ExtraCompass {
    /// Also serve an NMEA 0183 compass on the robot, on a pseudo-terminal of its own (printed
    /// as nmea:PATH on the next line): a second sensor, the true heading with its own noise,
    /// sharing none of the robot's own heading sensor's errors.
    #[cfg_attr(feature = "cli", arg(long))]
    pub nmea: bool,
    /// Sentences per second of robot time of the --nmea compass.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 10.0))]
    pub nmea_hz: f64,
    /// Noise per sentence of the --nmea compass (deg).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.2))]
    pub nmea_sigma_deg: f64,
    /// How the --nmea compass ends its sentences: crlf (NMEA), lf or cr.
    #[cfg_attr(feature = "cli", arg(long, default_value = "crlf"))]
    pub nmea_line_end: LineEnd,
}

impl ExtraCompass {
    /// The compass's configuration on a robot whose time runs `time_scale` times the wall
    /// clock's, or `None` when none was asked for.
    pub fn config(&self, time_scale: f64) -> Result<Option<MockCompassConfig>, MockError> {
        if !self.nmea {
            return Ok(None);
        }
        check_range("--nmea-hz", self.nmea_hz, 0.1, 100.0).map_err(setting)?;
        check_range("--nmea-sigma-deg", self.nmea_sigma_deg, 0.0, 10.0).map_err(setting)?;
        Ok(Some(MockCompassConfig {
            hz: self.nmea_hz,
            sigma_rad: self.nmea_sigma_deg.to_radians(),
            time_scale,
            line_end: self.nmea_line_end,
            ..Default::default()
        }))
    }
}

#[cfg(feature = "odocal-protocol")]
/// `mock-device`: a controller of our protocol on the simulated robot.
#[derive(Debug, Clone)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct DeviceOptions {
    /// The simulated robot's true errors.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub truth: TrueRobot,
    /// Factory wheel diameter (m).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.15))]
    pub wheel_diameter_m: f64,
    /// Factory wheelbase (m).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.39))]
    pub wheelbase_m: f64,
    /// Encoder counts per wheel revolution.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 4096.0))]
    pub counts_per_rev: f64,
    /// The simulated compass's noise per reading (deg; σ).
    #[cfg_attr(feature = "cli", arg(long = "heading-sigma-deg", alias = "compass-sigma-deg", default_value_t = SIM_HEADING_SIGMA_DEG))]
    pub compass_sigma_deg: f64,
    /// Constant compass bias (deg).
    #[cfg_attr(
        feature = "cli",
        arg(long, default_value_t = 0.0, allow_hyphen_values = true)
    )]
    pub compass_bias_deg: f64,
    /// Report headings clockwise-positive (a misconfigured firmware) instead of as the spec says.
    #[cfg_attr(feature = "cli", arg(long))]
    pub clockwise_compass: bool,
    /// Seed of the device's random draws.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1))]
    pub seed: u64,
    /// Run the device's clock this many times faster than the wall clock (1: real time, what
    /// `conformance` needs) instead of in virtual time (motions end the moment they are
    /// accepted; what `calibrate` on the mock is quickest with).
    #[cfg_attr(feature = "cli", arg(long = "time-scale", alias = "real-time"))]
    pub real_time: Option<f64>,
    /// Keep the non-volatile parameter copy in this file (survives restarts).
    #[cfg_attr(feature = "cli", arg(long))]
    pub storage: Option<PathBuf>,
    /// Faults, e.g. "corrupt=0.01,drop=0.05,latency-ms=5,disconnect-after=200,busy-every=7".
    #[cfg_attr(feature = "cli", arg(long))]
    pub faults: Option<FaultConfig>,
    /// How the robot's own heading sensor errs.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub sensor: SensorErrors,
}

#[cfg(feature = "odocal-protocol")]
impl DeviceOptions {
    /// The device's configuration and how its clock runs.
    pub fn config(&self) -> Result<(MockConfig, TimeMode), MockError> {
        let nominal =
            WheelParams::nominal(self.wheel_diameter_m, self.wheelbase_m, self.counts_per_rev);
        self.truth.check()?;
        let mut cfg = MockConfig::with_ratios(nominal, self.truth.true_eb, self.truth.true_ed)?;
        cfg.noise.compass_sigma_rad = self.compass_sigma_deg.to_radians();
        cfg.noise.compass_bias_rad = self.compass_bias_deg.to_radians();
        cfg.heading_model = self.sensor.model()?;
        cfg.seed = self.seed;
        cfg.storage_path.clone_from(&self.storage);
        if self.clockwise_compass {
            cfg.compass = CompassConvention::Clockwise;
        }
        let time = match self.real_time {
            Some(scale) if scale.is_finite() && scale > 0.0 => TimeMode::RealTime { scale },
            Some(scale) => return Err(setting(format!("--time-scale must be > 0, got {scale}"))),
            None => TimeMode::Virtual,
        };
        Ok((cfg, time))
    }
}

#[cfg(feature = "ros")]
/// `mock-rosbridge`: a ROS 2 robot with diff_drive_controller behind a rosbridge server.
#[derive(Debug, Clone)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct RosOptions {
    /// The simulated robot's true errors.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub truth: TrueRobot,
    /// The simulated heading sensor's (IMU's) noise per reading (deg; σ).
    #[cfg_attr(feature = "cli", arg(long = "heading-sigma-deg", alias = "compass-sigma-deg", default_value_t = SIM_HEADING_SIGMA_DEG))]
    pub compass_sigma_deg: f64,
    /// Robot seconds per wall-clock second (1: real time).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1.0))]
    pub time_scale: f64,
    /// Velocity topic the controller obeys.
    #[cfg_attr(feature = "cli", arg(long, default_value = "/cmd_vel"))]
    pub cmd_vel: String,
    /// The controller expects geometry_msgs/TwistStamped there (Jazzy's default), not Twist.
    #[cfg_attr(
        feature = "cli",
        arg(long = "twist-stamped", alias = "cmd-vel-stamped")
    )]
    pub cmd_vel_stamped: bool,
    /// How /joint_states carries `effort`, as real robots send it: empty, zero, null (NaN as
    /// rosbridge writes it in a variable-length array) or nan (the bare token NaN, also in the
    /// IMU's fixed-size covariance: rosbridge_suite #916).
    #[cfg_attr(feature = "cli", arg(long, default_value = "empty"))]
    pub effort: EffortStyle,
    /// Also publish a localization on this topic (geometry_msgs/PoseWithCovarianceStamped, as
    /// AMCL's /amcl_pose): 10 Hz, 3 mm and 0.3° of noise, 1 % jumps, in a world frame of its
    /// own; for `odocal track --reference` and `odocal fit`.
    #[cfg_attr(feature = "cli", arg(long))]
    pub localization: Option<String>,
    /// Where the localized frame sits on the robot: X_M,Y_M,YAW_DEG in base_link (a
    /// motion-capture body's markers, a lidar) [default: base_link itself].
    #[cfg_attr(
        feature = "cli",
        arg(long, requires = "localization", allow_hyphen_values = true)
    )]
    pub localization_mount: Option<String>,
    /// How the robot's own heading sensor errs.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub sensor: SensorErrors,
}

#[cfg(feature = "ros")]
impl RosOptions {
    /// Every setting in its range (before the controller's file is read).
    pub fn check(&self) -> Result<(), MockError> {
        self.truth.check()?;
        check_ranges(&[
            ("--heading-sigma-deg", self.compass_sigma_deg, 0.0, 10.0),
            ("--time-scale", self.time_scale, 0.01, 100.0),
        ])
        .map_err(setting)
    }

    /// The mock's configuration for a robot whose controller is configured as `controller`.
    pub fn config(&self, controller: DiffDriveConfig) -> Result<MockRosConfig, MockError> {
        self.check()?;
        let mut cfg =
            MockRosConfig::with_ratios(controller, self.truth.true_eb, self.truth.true_ed)
                .map_err(|e| setting(e.to_string()))?;
        cfg.noise.compass_sigma_rad = self.compass_sigma_deg.to_radians();
        cfg.heading_model = self.sensor.model()?;
        cfg.time_scale = self.time_scale;
        cfg.cmd_vel.clone_from(&self.cmd_vel);
        cfg.cmd_vel_stamped = self.cmd_vel_stamped;
        cfg.effort = self.effort;
        if let Some(topic) = &self.localization {
            let mut loc = MockLocalization::amcl();
            loc.topic.clone_from(topic);
            if let Some(m) = &self.localization_mount {
                loc.mount = mount(m)?;
            }
            cfg.localization = Some(loc);
        }
        Ok(cfg)
    }
}

#[cfg(feature = "ros")]
/// `--localization-mount X_M,Y_M,YAW_DEG`, checked.
fn mount(text: &str) -> Result<Pose2, MockError> {
    let bad = || {
        setting(format!(
            "--localization-mount {text:?}: expected X_M,Y_M,YAW_DEG"
        ))
    };
    let v: Vec<f64> = text
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| bad())?;
    let [x, y, yaw] = v[..] else {
        return Err(bad());
    };
    check_ranges(&[
        ("--localization-mount x", x, -5.0, 5.0),
        ("--localization-mount y", y, -5.0, 5.0),
        ("--localization-mount yaw", yaw, -180.0, 180.0),
    ])
    .map_err(setting)?;
    Ok(Pose2 {
        x,
        y,
        theta: yaw.to_radians(),
    })
}

#[cfg(feature = "roboclaw")]
/// `mock-roboclaw`: a RoboClaw and an NMEA compass of one simulated robot.
#[derive(Debug, Clone)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct RoboClawOptions {
    /// The simulated robot's true errors.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub truth: TrueRobot,
    /// The simulated compass's noise per sentence (deg; σ).
    #[cfg_attr(feature = "cli", arg(long = "heading-sigma-deg", alias = "compass-sigma-deg", default_value_t = SIM_HEADING_SIGMA_DEG))]
    pub compass_sigma_deg: f64,
    /// Compass sentences per second.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 10.0))]
    pub compass_hz: f64,
    /// Compass talker id (two letters).
    #[cfg_attr(feature = "cli", arg(long, default_value = "HC"))]
    pub talker: String,
    /// Robot seconds per wall-clock second.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1.0))]
    pub time_scale: f64,
    /// Answer only this packet address (128–135), as a controller on a shared TTL serial bus
    /// [default: every address, as a RoboClaw on USB].
    #[cfg_attr(feature = "cli", arg(long, value_parser = clap::value_parser!(u8).range(128..=135)))]
    pub address: Option<u8>,
    /// Probability that a write's acknowledgement is lost.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.0))]
    pub lose_ack_rate: f64,
    /// Every answer leaves this many milliseconds late (a slow USB adapter, a busy controller).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0))]
    pub answer_delay_ms: u64,
    /// Probability of a compass sentence with a bad checksum.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.0))]
    pub bad_checksum_rate: f64,
    /// How the robot's own heading sensor errs.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub sensor: SensorErrors,
}

#[cfg(feature = "roboclaw")]
impl RoboClawOptions {
    /// Every setting in its range (before the profile is read).
    pub fn check(&self) -> Result<(), MockError> {
        self.truth.check()?;
        check_ranges(&[
            ("--heading-sigma-deg", self.compass_sigma_deg, 0.0, 10.0),
            ("--compass-hz", self.compass_hz, 0.1, 100.0),
            ("--time-scale", self.time_scale, 0.01, 100.0),
            ("--lose-ack-rate", self.lose_ack_rate, 0.0, 1.0),
            ("--bad-checksum-rate", self.bad_checksum_rate, 0.0, 1.0),
        ])
        .map_err(setting)?;
        if self.talker.len() != 2 || !self.talker.chars().all(|c| c.is_ascii_uppercase()) {
            return Err(setting(format!(
                "--talker {:?}: two capital letters",
                self.talker
            )));
        }
        if let Some(a) = self.address.filter(|a| !(128..=135).contains(a)) {
            return Err(setting(format!("--address {a}: a RoboClaw's is 128-135")));
        }
        Ok(())
    }

    /// The mock's configuration for the robot `profile` describes (its geometry is the
    /// configured one, its wiring the mock's).
    pub fn config(&self, profile: &Profile) -> Result<MockRoboClawConfig, MockError> {
        self.check()?;
        let truth = self.truth.params(&profile.params())?;
        let mut cfg = MockRoboClawConfig::new(truth);
        cfg.left_on_m1 = profile.wiring.left_channel == Channel::M1;
        cfg.left_encoder_sign = profile.wiring.left_encoder_sign;
        cfg.right_encoder_sign = profile.wiring.right_encoder_sign;
        cfg.noise.compass_sigma_rad = self.compass_sigma_deg.to_radians();
        cfg.heading_model = self.sensor.model()?;
        cfg.compass_hz = self.compass_hz;
        cfg.compass_talker.clone_from(&self.talker);
        cfg.time_scale = self.time_scale;
        cfg.lose_ack_rate = self.lose_ack_rate;
        cfg.answer_delay = std::time::Duration::from_millis(self.answer_delay_ms.min(10_000));
        cfg.address = self.address;
        cfg.bad_checksum_rate = self.bad_checksum_rate;
        Ok(cfg)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::sensor::SensorKind;

    #[cfg(feature = "odocal-protocol")]
    fn device() -> DeviceOptions {
        DeviceOptions {
            truth: TrueRobot::default(),
            wheel_diameter_m: 0.15,
            wheelbase_m: 0.39,
            counts_per_rev: 4096.0,
            compass_sigma_deg: SIM_HEADING_SIGMA_DEG,
            compass_bias_deg: 0.0,
            clockwise_compass: false,
            seed: 1,
            real_time: None,
            storage: None,
            faults: None,
            sensor: SensorErrors::default(),
        }
    }

    fn refusal(e: MockError) -> String {
        match e {
            MockError::Setting(m) | MockError::Sim(crate::sim::SimError::Setting(m)) => m,
            other => panic!("not a refused setting: {other}"),
        }
    }

    #[cfg(feature = "odocal-protocol")]
    #[test]
    fn a_device_takes_its_settings_and_refuses_what_it_cannot_simulate() {
        let mut o = device();
        o.clockwise_compass = true;
        o.real_time = Some(2.0);
        o.sensor.heading_sensor = "gyro".into();
        o.sensor.gyro_scale_error = 0.01;
        let (cfg, time) = o.config().unwrap();
        assert_eq!(cfg.compass, CompassConvention::Clockwise);
        assert_eq!(time, TimeMode::RealTime { scale: 2.0 });
        assert_eq!(cfg.heading_model.kind, SensorKind::Gyro);
        let ratio = cfg.truth.wheelbase_m / cfg.factory.wheelbase_m;
        assert!((ratio - 0.976).abs() < 1e-12, "true E_b {ratio}");

        o.real_time = Some(0.0);
        assert!(refusal(o.config().unwrap_err()).contains("--time-scale"));
        let mut o = device();
        o.truth.true_eb = 3.0;
        assert!(refusal(o.config().unwrap_err()).contains("--true-eb"));
        let mut o = device();
        o.sensor.heading_sensor = "sonar".into();
        assert!(refusal(o.config().unwrap_err()).contains("--heading-sensor"));
        o.sensor.heading_sensor = "compass".into();
        o.sensor.heading_loss = 2.0;
        assert!(refusal(o.config().unwrap_err()).contains("out of range"));
    }

    #[test]
    fn an_extra_compass_is_made_only_when_asked_for_and_in_range() {
        let mut c = ExtraCompass {
            nmea: false,
            nmea_hz: 10.0,
            nmea_sigma_deg: 0.2,
            nmea_line_end: LineEnd::Lf,
        };
        assert_eq!(c.config(1.0).unwrap(), None);
        c.nmea = true;
        let cfg = c.config(3.0).unwrap().unwrap();
        assert_eq!(
            (cfg.hz, cfg.time_scale, cfg.line_end),
            (10.0, 3.0, LineEnd::Lf)
        );
        c.nmea_hz = 1000.0;
        assert!(refusal(c.config(1.0).unwrap_err()).contains("--nmea-hz"));
    }

    #[cfg(feature = "roboclaw")]
    #[test]
    fn a_roboclaw_mock_refuses_a_talker_or_rate_it_cannot_simulate() {
        let o = RoboClawOptions {
            truth: TrueRobot::default(),
            compass_sigma_deg: SIM_HEADING_SIGMA_DEG,
            compass_hz: 10.0,
            talker: "HC".into(),
            time_scale: 1.0,
            address: Some(128),
            lose_ack_rate: 0.0,
            answer_delay_ms: 0,
            bad_checksum_rate: 0.0,
            sensor: SensorErrors::default(),
        };
        o.check().unwrap();
        let lower = RoboClawOptions {
            talker: "hc".into(),
            ..o.clone()
        };
        assert!(refusal(lower.check().unwrap_err()).contains("--talker"));
        let lossy = RoboClawOptions {
            lose_ack_rate: 1.5,
            ..o.clone()
        };
        assert!(refusal(lossy.check().unwrap_err()).contains("--lose-ack-rate"));
        let address = RoboClawOptions {
            address: Some(7),
            ..o
        };
        assert!(refusal(address.check().unwrap_err()).contains("--address"));
    }

    #[cfg(feature = "ros")]
    #[test]
    fn a_localization_mount_is_three_numbers_in_range() {
        let p = mount("0.1, -0.05, 90").unwrap();
        assert!((p.x - 0.1).abs() < 1e-12 && (p.y + 0.05).abs() < 1e-12);
        assert!((p.theta - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        for bad in ["0.1,0.2", "a,b,c", "0,0,0,0"] {
            assert!(
                refusal(mount(bad).unwrap_err()).contains("X_M,Y_M,YAW_DEG"),
                "{bad}"
            );
        }
        assert!(refusal(mount("9,0,0").unwrap_err()).contains("--localization-mount x"));
    }
}
