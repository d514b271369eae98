//! A ROS robot as a [`Base`], live through rosbridge: a drive that publishes `Twist` (or
//! `TwistStamped`) on the velocity topic and ends each leg or turn when the robot's **own
//! odometry** — its wheel joint angles integrated with the configured geometry from the YAML,
//! or the controller's `/odom` — says it is done (the paper's open loop on a ROS robot); the
//! IMU's orientation as the heading; and the controller's YAML as the parameter store,
//! optionally also set live on the running controller.
//!
//! Safety: every motion speed is limited and ramped; the drive publishes zero when a motion
//! ends, fails or is abandoned (`emergency_stop`), and it keeps publishing during a motion so
//! that the controller's own `cmd_vel_timeout` (0.5 s in `diff_drive_controller`) stops the
//! wheels when this host or the connection goes away.

use super::bag::validate::{Forward, LiveJoints, Verdict, MAX_POSITION_M};
use super::bag::RosTopics;
use super::msg::{types, yaw_of, Imu, JointState, Odometry, Twist, TwistStamped};
use super::rosbridge::{RosbridgeClient, RosbridgeError};
use super::yaml::{DiffDriveConfig, YamlStore, MULTIPLIER_KEYS};
use crate::base::drive_backend::{
    DriveBackend, DriveOpen, DriveTarget, HeadingPart, OpenDrive, StorePart,
};
use crate::base::latest::{self, Fresh, Latest, Publisher, Stamped};
use crate::base::port_spec::PortSpec;
use crate::base::{
    Achieved, Base, BaseError, ComponentInfo, Drive, Fanout, HeadingSample, HeadingSource,
    ParamStore, Preflight, SampleStream, TravelSample, Validity,
};
use crate::kinematics::{wrap_angle, Displacement, WheelParams};
use async_trait::async_trait;
use serde_json::{json, Value};
use std::sync::{Arc, RwLock};
use std::time::Duration;
use tokio::sync::watch;
use tokio::time::Instant;

mod drive;
mod heading;
mod odometry;
mod stall;
mod store;

pub use drive::*;
use heading::*;
use odometry::*;
pub use stall::*;

/// Where the drive's odometry comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum WheelSource {
    /// `sensor_msgs/JointState` wheel angles, integrated here with the YAML's geometry (so a
    /// written calibration takes effect at once, without restarting the controller).
    JointStates,
    /// The controller's `nav_msgs/Odometry` (uses the parameters the controller was started with).
    Odom,
}

/// How to reach and drive a ROS robot.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RosBaseConfig {
    /// `rosbridge://HOST:PORT` or `ws://HOST:PORT`.
    pub url: String,
    /// The controller's YAML file (required; empty until given).
    pub yaml: std::path::PathBuf,
    /// The controller's name (its YAML section and its node).
    pub controller: String,
    /// Topics read.
    pub topics: RosTopics,
    /// Velocity command topic.
    pub cmd_vel: String,
    /// Publish `TwistStamped` (newer `diff_drive_controller` releases) instead of `Twist`.
    pub twist_stamped: bool,
    /// Odometry source for ending motions.
    pub wheel_source: WheelSource,
    /// Left wheel joint (default: the YAML's first `left_wheel_names`).
    pub left_joint: Option<String>,
    /// Right wheel joint.
    pub right_joint: Option<String>,
    /// Acceleration used for ramps (m/s²).
    pub max_accel_m_s2: f64,
    /// Angular acceleration used for ramps (rad/s²).
    pub max_alpha_rad_s2: f64,
    /// Also set written multipliers on the running controller (`set_parameters`).
    pub set_live: bool,
    /// How long to wait for the first message of each topic (s).
    pub first_message_timeout_s: f64,
}

impl RosBaseConfig {
    /// The topic the drive follows the wheels on: the joint states or the odometry.
    pub fn wheel_topic(&self) -> &str {
        match self.wheel_source {
            WheelSource::JointStates => &self.topics.joint_states,
            WheelSource::Odom => &self.topics.odom,
        }
    }
}

impl Default for RosBaseConfig {
    fn default() -> Self {
        RosBaseConfig {
            url: "rosbridge://localhost:9090".into(),
            yaml: std::path::PathBuf::new(),
            controller: super::yaml::DEFAULT_CONTROLLER.into(),
            topics: RosTopics::default(),
            cmd_vel: "/cmd_vel".into(),
            twist_stamped: false,
            wheel_source: WheelSource::JointStates,
            left_joint: None,
            right_joint: None,
            max_accel_m_s2: 0.5,
            max_alpha_rad_s2: 2.0,
            set_live: false,
            first_message_timeout_s: 5.0,
        }
    }
}

/// A ROS robot through rosbridge: `rosbridge://HOST:PORT` or `ws://HOST:PORT`, with the
/// `[robot.ros]` settings ([`RosBaseConfig`]); its IMU is the heading source, the controller's
/// YAML the store.
pub const DRIVE_BACKEND: DriveBackend = DriveBackend {
    name: "rosbridge",
    what: "a ROS robot",
    form: "rosbridge://HOST:PORT",
    options: &[],
    recognise: |text| {
        (text.starts_with("rosbridge://") || text.starts_with("ws://"))
            .then(|| Ok(PortSpec::bare(text)))
    },
    bare_port: false,
    heading: HeadingPart::Own,
    store: StorePart::Own,
    settings: Some("ros"),
    check: |_| Ok(()),
    ready: |target| {
        if config_of(target)?.yaml.as_os_str().is_empty() {
            return Err(
                "a ROS robot needs the controller's ros2_control YAML (--ros-yaml, or \
                        `yaml` in the routine file's [robot.ros] table)"
                    .into(),
            );
        }
        Ok(())
    },
    place: |spec| spec.port.clone(),
    open: |how: DriveOpen| -> OpenDrive {
        Box::pin(async move { Ok(connect(&config_of(&how.target)?).await?) })
    },
    // A ROS robot's state is ROS's to show (`ros2 control list_controllers`).
    status: None,
};

/// The settings of a ROS drive's target, its URL from the drive's text.
pub fn config_of(target: &DriveTarget) -> Result<RosBaseConfig, String> {
    let settings = match &target.settings {
        Some(v) => v
            .clone()
            .try_into()
            .map_err(|e| format!("the ROS settings ([robot.ros]) cannot be read: {e}"))?,
        None => RosBaseConfig::default(),
    };
    Ok(RosBaseConfig {
        url: target.spec.port.clone(),
        ..settings
    })
}

/// Errors connecting a ROS base.
#[derive(Debug, thiserror::Error)]
pub enum RosBaseError {
    /// The rosbridge connection failed.
    #[error(transparent)]
    Rosbridge(#[from] RosbridgeError),
    /// The YAML is unusable.
    #[error(transparent)]
    Yaml(#[from] super::yaml::YamlError),
    /// A setting is unusable.
    #[error("{0}")]
    Config(String),
}

/// The section a drive integrates with: the store's, staged values included.
type Geometry = Arc<RwLock<DiffDriveConfig>>;

/// The drive.
pub struct RosDrive {
    commander: Commander,
    cfg: RosBaseConfig,
    odo: watch::Receiver<Odo>,
    witness: Witness,
    travel: Fanout<TravelSample>,
    cmd_vel_timeout_s: f64,
    /// What the topics' checks dropped, for the report.
    rejects: Rejects,
}

/// The IMU.
pub struct RosHeading {
    url: String,
    topic: String,
    latest: Latest,
    /// The drive's odometry: a reading must be no older than its newest wheel data.
    wheels: watch::Receiver<Odo>,
    streams: Fanout<HeadingSample>,
    stale: Duration,
}

/// The YAML store, optionally also set on the running controller.
pub struct RosStore {
    yaml: YamlStore,
    client: RosbridgeClient,
    controller: String,
    set_live: bool,
    running: Arc<RwLock<WheelParams>>,
}

/// The robot's clock: joint states, odometry and IMU messages carry its header stamps.
pub(super) fn robot_clock(url: &str) -> String {
    format!("ros:{url}")
}

fn drive_err(e: impl std::error::Error + Send + Sync + 'static) -> BaseError {
    BaseError::backend("drive (rosbridge)", e)
}

/// Connects to the robot and composes its base: drive and heading over rosbridge, the YAML as
/// the store. Fails with a clear message if the server is not rosbridge or a topic is silent.
pub async fn connect(cfg: &RosBaseConfig) -> Result<Base, RosBaseError> {
    let open = RosbridgeClient::connect(&cfg.url, first_message_timeout(cfg));
    connect_over(cfg, open).await
}

/// How long the connection and each stream's first message may take.
fn first_message_timeout(cfg: &RosBaseConfig) -> Duration {
    Duration::from_secs_f64(cfg.first_message_timeout_s.clamp(0.1, 60.0))
}

/// [`connect`] over the connection `open` makes (a stream of the caller's, such as an
/// in-memory peer: [`RosbridgeClient::connect_stream`]); the controller's YAML is read first,
/// so a file that cannot be used is told before anything is opened.
pub async fn connect_over(
    cfg: &RosBaseConfig,
    open: impl std::future::Future<Output = Result<RosbridgeClient, RosbridgeError>>,
) -> Result<Base, RosBaseError> {
    let yaml_cfg = DiffDriveConfig::load(&cfg.yaml, &cfg.controller)?;
    let store = YamlStore::open(&cfg.yaml, &cfg.controller)?;
    let geometry = store.shared();
    let timeout = first_message_timeout(cfg);
    let client = open.await?;
    let (left, right) = wheel_joints(cfg, &yaml_cfg);
    // Wheels: the source motions close on, and the other one for the still-robot diagnosis.
    let witness = Witness::follow(&client, cfg, (left.clone(), right.clone()))?;
    let rejects = Rejects::default();
    let (odo_rx, travel) = spawn_odometry(&client, cfg, &rejects, &geometry, (left, right))?;
    // Heading.
    let (head_rx, streams) = spawn_heading(&client, cfg, &rejects)?;
    let vel_type = if cfg.twist_stamped {
        types::TWIST_STAMPED
    } else {
        types::TWIST
    };
    client.advertise(&cfg.cmd_vel, vel_type)?;
    // The first messages, or a diagnosis.
    let first = |topic: &str| (topic.to_string(), rejects.clone(), timeout);
    wait_first(
        &client,
        &odo_rx,
        |o| o.samples > 0,
        first(cfg.wheel_topic()),
    )
    .await?;
    let imu_ok = |h: &Stamped| h.is_some();
    wait_first(&client, head_rx.receiver(), imu_ok, first(&cfg.topics.imu)).await?;
    // What the controller was started with: the file as it is now.
    let running = Arc::new(RwLock::new(yaml_cfg.effective()));
    let drive = RosDrive {
        commander: Commander {
            client: client.clone(),
            topic: cfg.cmd_vel.clone(),
            stamped: cfg.twist_stamped,
            configured: geometry.clone(),
            running: running.clone(),
        },
        cfg: cfg.clone(),
        odo: odo_rx,
        witness,
        travel,
        cmd_vel_timeout_s: yaml_cfg.cmd_vel_timeout_s.unwrap_or(0.5),
        rejects: rejects.clone(),
    };
    let heading = RosHeading {
        url: cfg.url.clone(),
        topic: cfg.topics.imu.clone(),
        latest: head_rx,
        wheels: drive.odo.clone(),
        streams,
        stale: Duration::from_millis(500),
    };
    let store = RosStore {
        yaml: store,
        client,
        controller: cfg.controller.clone(),
        set_live: cfg.set_live,
        running,
    };
    Ok(Base::new(
        Arc::new(drive),
        Arc::new(heading),
        Arc::new(store),
    ))
}

/// The left and right wheel joints: the configured ones, else the YAML's first wheel names.
fn wheel_joints(
    cfg: &RosBaseConfig,
    yaml_cfg: &DiffDriveConfig,
) -> (Option<String>, Option<String>) {
    let left = cfg
        .left_joint
        .clone()
        .or_else(|| yaml_cfg.left_wheel_names.first().cloned());
    let right = cfg
        .right_joint
        .clone()
        .or_else(|| yaml_cfg.right_wheel_names.first().cloned());
    (left, right)
}

/// Subscribes to the wheel source motions close on (joint states integrated here with the
/// YAML's geometry, or the controller's odometry) and follows it in a spawned task; returns
/// the odometry it publishes and its travel stream.
fn spawn_odometry(
    client: &RosbridgeClient,
    cfg: &RosBaseConfig,
    rejects: &Rejects,
    geometry: &Geometry,
    (left, right): (Option<String>, Option<String>),
) -> Result<(watch::Receiver<Odo>, Fanout<TravelSample>), RosbridgeError> {
    let (odo_tx, odo_rx) = watch::channel(Odo::default());
    let travel: Fanout<TravelSample> = Fanout::default();
    match cfg.wheel_source {
        WheelSource::JointStates => {
            let rx = client.subscribe(&cfg.topics.joint_states, types::JOINT_STATE)?;
            tokio::spawn(integrate_joints(
                rx,
                (cfg.topics.joint_states.clone(), rejects.clone()),
                geometry.clone(),
                left,
                right,
                odo_tx,
                travel.clone(),
            ));
        }
        WheelSource::Odom => {
            let rx = client.subscribe(&cfg.topics.odom, types::ODOMETRY)?;
            tokio::spawn(integrate_odom(
                rx,
                (cfg.topics.odom.clone(), rejects.clone()),
                geometry.clone(),
                odo_tx,
                travel.clone(),
            ));
        }
    }
    Ok((odo_rx, travel))
}

/// Subscribes to the IMU and follows it in a spawned task; returns its latest reading and its
/// heading stream.
fn spawn_heading(
    client: &RosbridgeClient,
    cfg: &RosBaseConfig,
    rejects: &Rejects,
) -> Result<(Latest, Fanout<HeadingSample>), RosbridgeError> {
    let imu_rx = client.subscribe(&cfg.topics.imu, types::IMU)?;
    let (head_tx, head_rx) = latest::channel();
    let streams: Fanout<HeadingSample> = Fanout::default();
    tokio::spawn(follow_imu(
        imu_rx,
        (cfg.topics.imu.clone(), rejects.clone()),
        head_tx,
        streams.clone(),
    ));
    Ok((head_rx, streams))
}

async fn wait_first<T>(
    client: &RosbridgeClient,
    rx: &watch::Receiver<T>,
    ready: impl Fn(&T) -> bool,
    (topic, rejects, timeout): (String, Rejects, Duration),
) -> Result<(), RosbridgeError> {
    let mut rx = rx.clone();
    // The `Ref` a wait returns holds the channel's lock: drop it here, not across the awaits
    // below (which would also make the connection's future not `Send`).
    let arrived = matches!(
        tokio::time::timeout(timeout, rx.wait_for(|v| ready(v))).await,
        Ok(Ok(_))
    );
    if arrived {
        return Ok(());
    }
    if let Some(reason) = client.closed() {
        return Err(RosbridgeError::Closed(reason));
    }
    let (n, first) = client.foreign();
    if n > 0 {
        return Err(RosbridgeError::NotRosbridge {
            url: client.url().into(),
            reason: format!(
                "{n} message(s) that are not rosbridge operations, e.g. {}",
                first.unwrap_or_default()
            ),
        });
    }
    let topics = client
        .call_service(
            "/rosapi/topics",
            "rosapi_msgs/srv/Topics",
            json!({}),
            Duration::from_secs(1),
        )
        .await
        .ok()
        .and_then(|v| v.get("topics").cloned())
        .map(|t| format!("; the robot publishes {t}"))
        .unwrap_or_default();
    if let Some(why) = rejects.describe(&topic) {
        return Err(RosbridgeError::Timeout(format!(
            "no usable message on {topic} within {}: {why}",
            crate::io::seconds(&timeout)
        )));
    }
    Err(RosbridgeError::Timeout(format!(
        "no message on {topic} within {}: is the robot's driver running and the topic \
         name right (a flag or the routine file sets it)?{topics}",
        crate::io::seconds(&timeout)
    )))
}

/// A message as its type, or why not, naming the field (`effort[1]: invalid type…`).
pub(super) fn decode<T: serde::de::DeserializeOwned>(v: &Value) -> Result<T, String> {
    serde_path_to_error::deserialize(v).map_err(|e| format!("field `{}`: {}", e.path(), e.inner()))
}

pub(super) fn stamp_of(v: &Value) -> Option<f64> {
    let s = v.get("header")?.get("stamp")?;
    let sec = s.get("sec").or_else(|| s.get("secs"))?.as_f64()?;
    let ns = s.get("nanosec").or_else(|| s.get("nsecs"))?.as_f64()?;
    Some(sec + ns * 1e-9)
}

/// The next message of a subscription, passing over a lag (a slow reader loses messages, not
/// the subscription); `None` once the connection is gone.
pub(super) async fn next_message(
    rx: &mut tokio::sync::broadcast::Receiver<Value>,
) -> Option<Value> {
    loop {
        match rx.recv().await {
            Ok(v) => return Some(v),
            Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => continue,
            Err(_) => return None,
        }
    }
}
