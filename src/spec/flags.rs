//! The flags that say where a robot is, shared by `calibrate`, `track`, `record`, `heading`,
//! `swing` and `spin` (with the `cli` feature they are the command line's, their doc comments
//! the help): they become a [`RobotSection`] laid over a routine file's, and that the spec.

use super::{BaseSpec, RobotSection, SpecError};
use crate::base::{Base, HeadingSource, PoseSource};
#[cfg(feature = "ros")]
use crate::ros::live::{RosBaseConfig, WheelSource};
use std::path::PathBuf;
use std::sync::Arc;

/// Where the robot is.
#[derive(Debug, Clone, Default, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct RobotFlags {
    /// Serial port of a motor controller that speaks odocal's protocol.
    #[cfg_attr(feature = "cli", arg(long, conflicts_with = "base"))]
    pub port: Option<String>,
    /// The drive: rosbridge://HOST:PORT (a ROS robot; needs --ros-yaml),
    /// 'roboclaw:PORT?address=128&baud=38400' (needs --heading and --profile), or
    /// odocal:PORT?baud=115200. Quote it: a shell ends the command at `&`.
    #[cfg_attr(feature = "cli", arg(long))]
    pub base: Option<String>,
    /// Baud rate of a drive on a serial port whose spec gives none [default: the drive's:
    /// 115200 for odocal's protocol, 38400 for a RoboClaw].
    #[cfg_attr(feature = "cli", arg(long))]
    pub baud: Option<u32>,
    /// The heading source, when it is not the drive's own: nmea:PORT[?baud=4800].
    #[cfg_attr(feature = "cli", arg(long))]
    pub heading: Option<String>,
    /// The robot profile of a drive that keeps no parameters (a RoboClaw): geometry, wiring,
    /// limits; written back.
    #[cfg_attr(feature = "cli", arg(long))]
    pub profile: Option<PathBuf>,
    /// What the heading sensor is: magnetic (a compass; deviation possible), gyro
    /// (integrated; its scale error enters E_b), reference (ground truth) or unknown
    /// [default: what the backend says; a ROS IMU is unknown].
    #[cfg_attr(feature = "cli", arg(long))]
    pub heading_kind: Option<String>,
    /// A compass deviation to remove from every reading, A1,B1,A2,B2 in degrees
    /// (d(ψ) = A1·sin ψ + B1·cos ψ + A2·sin 2ψ + B2·cos 2ψ, as `odocal swing` prints it).
    #[cfg_attr(feature = "cli", arg(long, allow_hyphen_values = true))]
    pub compass_deviation_deg: Option<String>,
    /// The ROS settings of `--base rosbridge://…`.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub ros: RosFlags,
}

impl RobotFlags {
    /// The rosbridge URL of a ROS robot (`--base rosbridge://…`), if that is the base.
    pub fn rosbridge_url(&self) -> Option<&str> {
        #[cfg(not(feature = "ros"))]
        return None;
        #[cfg(feature = "ros")]
        self.base
            .as_deref()
            .filter(|b| (crate::ros::live::DRIVE_BACKEND.recognise)(b).is_some())
    }
}

impl RobotFlags {
    /// **Connects to** the pose topic `topic` of the ROS robot these flags name (`track
    /// --reference`), waiting up to 5 s for the topic; refused for another robot, and named
    /// with its feature in a build without `ros`.
    pub async fn pose_source(&self, topic: &str) -> Result<Box<dyn PoseSource>, SpecError> {
        #[cfg(not(feature = "ros"))]
        return Err(
            crate::features::NotBuilt::new(format!("--reference {topic}"), &["ros"]).into(),
        );
        #[cfg(feature = "ros")]
        {
            let url = self.rosbridge_url().ok_or_else(|| {
                SpecError::Combination(
                    "--reference reads a ROS topic: give --base rosbridge://HOST:PORT (for a \
                     recording, use odocal fit, or track --poses with --wheels)"
                        .into(),
                )
            })?;
            let timeout = std::time::Duration::from_secs(5);
            let source = crate::ros::pose_source::RosPoseSource::connect(url, topic, timeout)
                .await
                .map_err(|e| SpecError::Drive(Box::new(e)))?;
            Ok(Box::new(source))
        }
    }
}

/// ROS settings of `--base rosbridge://…` (a routine file's `[robot.ros]` table holds the same
/// keys).
#[derive(Debug, Clone, Default, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct RosFlags {
    /// The controller's ros2_control YAML: the geometry is read from it and the calibrated
    /// multipliers are written into it (backed up first, into the run's report directory).
    #[cfg_attr(feature = "cli", arg(long))]
    pub ros_yaml: Option<PathBuf>,
    /// The diff_drive_controller's name, `ns/name` to pick one namespace's [default:
    /// diff_drive_controller].
    #[cfg_attr(feature = "cli", arg(long))]
    pub controller: Option<String>,
    /// Velocity topic [default: /cmd_vel; newer setups use /diff_drive_controller/cmd_vel].
    #[cfg_attr(feature = "cli", arg(long))]
    pub cmd_vel: Option<String>,
    /// Publish geometry_msgs/TwistStamped instead of Twist.
    #[cfg_attr(feature = "cli", arg(long))]
    pub twist_stamped: bool,
    /// Where the drive's odometry comes from: joint-states or odom [default: joint-states].
    #[cfg_attr(feature = "cli", arg(long))]
    pub wheel_source: Option<String>,
    /// Joint states topic [default: /joint_states].
    #[cfg_attr(feature = "cli", arg(long))]
    pub joint_states_topic: Option<String>,
    /// IMU topic [default: /imu].
    #[cfg_attr(feature = "cli", arg(long))]
    pub imu_topic: Option<String>,
    /// Odometry topic [default: /odom].
    #[cfg_attr(feature = "cli", arg(long))]
    pub odom_topic: Option<String>,
    /// Also set the written multipliers on the running controller (set_parameters).
    #[cfg_attr(feature = "cli", arg(long))]
    pub ros_set_live: bool,
}

impl RosFlags {
    /// Whether any ROS flag was given.
    fn any(&self) -> bool {
        self.ros_yaml.is_some()
            || self.controller.is_some()
            || self.cmd_vel.is_some()
            || self.twist_stamped
            || self.wheel_source.is_some()
            || self.joint_states_topic.is_some()
            || self.imu_topic.is_some()
            || self.odom_topic.is_some()
            || self.ros_set_live
    }

    /// `c` with the flags given laid over it.
    #[cfg(feature = "ros")]
    fn apply(&self, mut c: RosBaseConfig) -> Result<RosBaseConfig, SpecError> {
        if let Some(y) = &self.ros_yaml {
            c.yaml = y.clone();
        }
        if let Some(v) = &self.controller {
            c.controller = v.clone();
        }
        if let Some(v) = &self.cmd_vel {
            c.cmd_vel = v.clone();
        }
        c.twist_stamped |= self.twist_stamped;
        c.set_live |= self.ros_set_live;
        if let Some(v) = &self.wheel_source {
            c.wheel_source = match v.as_str() {
                "joint-states" => WheelSource::JointStates,
                "odom" => WheelSource::Odom,
                other => {
                    return Err(SpecError::Flag(format!(
                        "--wheel-source {other}: use joint-states or odom"
                    )))
                }
            };
        }
        if let Some(v) = &self.joint_states_topic {
            c.topics.joint_states = v.clone();
        }
        if let Some(v) = &self.imu_topic {
            c.topics.imu = v.clone();
        }
        if let Some(v) = &self.odom_topic {
            c.topics.odom = v.clone();
        }
        Ok(c)
    }
}

impl RobotFlags {
    /// A heading sensor to read without opening the robot (`odocal heading`): `--heading`, or
    /// `--port` (a heading spec, or an odocal-protocol controller) when there is no `--base`;
    /// with its baud rate.
    pub fn heading_alone(&self) -> Option<(String, u32)> {
        let baud = self.baud.unwrap_or(super::ODOCAL_BAUD);
        match (&self.heading, &self.port, &self.base) {
            (Some(h), _, _) => Some((h.clone(), baud)),
            (None, Some(p), None) => Some((p.clone(), baud)),
            _ => None,
        }
    }

    /// The heading source these flags name, read alone when they allow it
    /// ([`Self::heading_alone`]), else the whole robot's, which comes along (kept open while
    /// its sensor is read).
    pub async fn open_heading(&self) -> Result<(Arc<dyn HeadingSource>, Option<Base>), SpecError> {
        if let Some((text, baud)) = self.heading_alone() {
            let source = self.section().open_heading_alone(&text, baud).await?;
            return Ok((source, None));
        }
        let base = self.spec(RobotSection::default())?.open().await?;
        Ok((base.heading.clone(), Some(base)))
    }

    /// The robot section of these flags alone (no routine file).
    pub fn section(&self) -> RobotSection {
        RobotSection {
            drive: self.port.clone().or_else(|| self.base.clone()),
            baud: self.baud,
            heading: self.heading.clone(),
            store: None,
            profile: self.profile.clone(),
            ros: None,
            heading_kind: self.heading_kind.clone(),
            compass_deviation_deg: self.compass_deviation_deg.clone(),
        }
    }

    /// The robot: a routine file's section (if any) with these flags laid over it.
    pub fn spec(&self, file: RobotSection) -> Result<BaseSpec, SpecError> {
        #[cfg(feature = "ros")]
        let ros = match (file.ros.clone(), self.ros.any()) {
            (Some(c), _) => Some(self.ros.apply(c)?),
            (None, true) => Some(self.ros.apply(RosBaseConfig::default())?),
            (None, false) => None,
        };
        // Without `ros` no drive takes them: given, they are refused by the drive's name.
        #[cfg(not(feature = "ros"))]
        let ros = match self.ros.any() {
            true => Some(super::RosSettings::default()),
            false => file.ros.clone(),
        };
        let flags = RobotSection {
            ros,
            ..self.section()
        };
        file.over(flags).spec()
    }
}

#[cfg(all(test, feature = "odocal-protocol", feature = "ros"))]
mod tests {
    use super::*;

    #[test]
    fn a_heading_is_read_alone_unless_a_base_is_given() {
        let port = RobotFlags {
            port: Some("/dev/ttyUSB0".into()),
            ..RobotFlags::default()
        };
        let baud = crate::hal::DEFAULT_BAUD;
        assert_eq!(port.heading_alone(), Some(("/dev/ttyUSB0".into(), baud)));
        assert_eq!(port.section().drive.as_deref(), Some("/dev/ttyUSB0"));
        let base = RobotFlags {
            base: Some("rosbridge://127.0.0.1:9090".into()),
            ..RobotFlags::default()
        };
        assert_eq!(base.heading_alone(), None);
        assert_eq!(base.rosbridge_url(), Some("rosbridge://127.0.0.1:9090"));
        let compass = RobotFlags {
            heading: Some("nmea:/dev/ttyUSB1".into()),
            baud: Some(4800),
            ..base
        };
        assert_eq!(
            compass.heading_alone(),
            Some(("nmea:/dev/ttyUSB1".into(), 4800))
        );
    }

    #[test]
    fn ros_flags_lay_over_a_configuration_and_refuse_an_unknown_wheel_source() {
        assert!(!RosFlags::default().any());
        let flags = RosFlags {
            cmd_vel: Some("/diff_drive_controller/cmd_vel".into()),
            wheel_source: Some("odom".into()),
            twist_stamped: true,
            ..RosFlags::default()
        };
        assert!(flags.any());
        let c = flags.apply(RosBaseConfig::default()).unwrap();
        assert_eq!(c.cmd_vel, "/diff_drive_controller/cmd_vel");
        assert_eq!(c.wheel_source, WheelSource::Odom);
        assert!(c.twist_stamped);
        assert_eq!(
            c.topics,
            RosBaseConfig::default().topics,
            "topics not given stay"
        );
        let bad = RosFlags {
            wheel_source: Some("gps".into()),
            ..RosFlags::default()
        };
        let e = bad.apply(RosBaseConfig::default()).unwrap_err();
        assert!(e.to_string().contains("joint-states or odom"), "{e}");
    }
}
