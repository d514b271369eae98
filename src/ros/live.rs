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

/// The drive's odometry now.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Odo {
    /// Cumulative forward distance (m).
    distance_m: f64,
    /// Cumulative turn (rad).
    turn_rad: f64,
    /// Messages integrated.
    samples: u64,
    /// Message time of the last one (s).
    stamp_s: f64,
    /// Message time since which the wheels have not moved (s).
    still_since_s: Option<f64>,
}

/// The velocity publisher, shared by motions, stops and guards.
///
/// A motion is meant in the *configured* geometry (the store's, which a calibration changes),
/// but the running controller turns twists into wheel speeds with the geometry it was started
/// with (or last set live). The commander translates: the wheel speeds the configured geometry
/// asks for, expressed as the twist the running controller needs to produce them.
#[derive(Clone)]
struct Commander {
    client: RosbridgeClient,
    topic: String,
    stamped: bool,
    configured: Geometry,
    running: Arc<RwLock<WheelParams>>,
}

/// The section a drive integrates with: the store's, staged values included.
type Geometry = Arc<RwLock<DiffDriveConfig>>;

/// The effective parameters of the section now.
fn effective(g: &Geometry) -> WheelParams {
    g.read().unwrap_or_else(|p| p.into_inner()).effective()
}

/// The twist that makes a controller running with `running` turn its wheels as (`v`, `w`) in
/// `configured` asks.
fn translate(v: f64, w: f64, configured: &WheelParams, running: &WheelParams) -> (f64, f64) {
    let asked = Displacement {
        distance_m: v,
        turn_rad: w,
    };
    let (l, r) = asked.wheels(configured.wheelbase_m);
    // Wheel angle rates, then what the running geometry makes of them.
    let (sl, sr) = running.travel_m(
        l / configured.left_m_per_count(),
        r / configured.right_m_per_count(),
    );
    let made = Displacement::of_wheels(sl, sr, running.wheelbase_m);
    (made.distance_m, made.turn_rad)
}

impl Commander {
    fn send(&self, v: f64, w: f64) -> Result<(), RosbridgeError> {
        let (v, w) = if v == 0.0 && w == 0.0 {
            (0.0, 0.0)
        } else {
            let c = effective(&self.configured);
            let r = *self.running.read().unwrap_or_else(|p| p.into_inner());
            translate(v, w, &c, &r)
        };
        let twist = Twist::planar(v, w);
        let msg = if self.stamped {
            serde_json::to_value(TwistStamped {
                twist,
                ..TwistStamped::default()
            })
        } else {
            serde_json::to_value(twist)
        };
        self.client.publish(&self.topic, msg.unwrap_or(Value::Null))
    }
}

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn twists_are_translated_into_the_running_geometry() {
        let running = WheelParams::nominal(0.15, 0.39, std::f64::consts::TAU);
        let mut configured = running;
        configured.right_wheel_diameter_m *= 0.99;
        configured.wheelbase_m *= 0.97;
        // Same geometry: unchanged.
        let (v, w) = translate(0.3, 0.2, &running, &running);
        assert!((v - 0.3).abs() < 1e-12 && (w - 0.2).abs() < 1e-12);
        // Straight in the configured geometry: the right wheel turns faster by 1/0.99, which the
        // running controller sees as a slight left turn.
        let (v, w) = translate(0.3, 0.0, &configured, &running);
        let wl = (v - 0.5 * w * running.wheelbase_m) / running.left_m_per_count();
        let wr = (v + 0.5 * w * running.wheelbase_m) / running.right_m_per_count();
        assert!(
            (wr * configured.right_m_per_count() - wl * configured.left_m_per_count()).abs()
                < 1e-12
        );
        assert!(w > 0.0);
    }
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
    let yaml_cfg = DiffDriveConfig::load(&cfg.yaml, &cfg.controller)?;
    let store = YamlStore::open(&cfg.yaml, &cfg.controller)?;
    let geometry = store.shared();
    let timeout = Duration::from_secs_f64(cfg.first_message_timeout_s.clamp(0.1, 60.0));
    let client = RosbridgeClient::connect(&cfg.url, timeout).await?;
    let left = cfg
        .left_joint
        .clone()
        .or_else(|| yaml_cfg.left_wheel_names.first().cloned());
    let right = cfg
        .right_joint
        .clone()
        .or_else(|| yaml_cfg.right_wheel_names.first().cloned());
    // Wheels: the source motions close on, and the other one for the still-robot diagnosis.
    let witness = Witness::follow(&client, cfg, (left.clone(), right.clone()))?;
    let rejects = Rejects::default();
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
    // Heading.
    let imu_rx = client.subscribe(&cfg.topics.imu, types::IMU)?;
    let (head_tx, head_rx) = latest::channel();
    let streams: Fanout<HeadingSample> = Fanout::default();
    tokio::spawn(follow_imu(
        imu_rx,
        (cfg.topics.imu.clone(), rejects.clone()),
        head_tx,
        streams.clone(),
    ));
    let vel_type = if cfg.twist_stamped {
        types::TWIST_STAMPED
    } else {
        types::TWIST
    };
    client.advertise(&cfg.cmd_vel, vel_type)?;
    // The first messages, or a diagnosis.
    let wheel_topic = match cfg.wheel_source {
        WheelSource::JointStates => &cfg.topics.joint_states,
        WheelSource::Odom => &cfg.topics.odom,
    };
    let first = |topic: &str| (topic.to_string(), rejects.clone(), timeout);
    wait_first(&client, &odo_rx, |o| o.samples > 0, first(wheel_topic)).await?;
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

/// Messages that arrived but could not be used or were dropped, per topic and reason: how
/// many and an example, so that a silent topic and a topic whose messages odocal cannot read
/// are told apart, and a run's report counts every sample the checks dropped
/// ([`RosDrive`]'s diagnostics).
#[derive(Clone, Default)]
struct Rejects(Arc<std::sync::Mutex<std::collections::BTreeMap<String, Vec<Rejected>>>>);

struct Rejected {
    count: u64,
    reason: String,
    example: String,
}

impl Rejects {
    fn note(&self, topic: &str, reason: String, msg: &Value) {
        let mut map = self.0.lock().unwrap_or_else(|p| p.into_inner());
        let reasons = map.entry(topic.to_string()).or_default();
        match reasons.iter_mut().find(|r| r.reason == reason) {
            Some(r) => r.count += 1,
            None => reasons.push(Rejected {
                count: 1,
                reason,
                example: msg.to_string().chars().take(240).collect(),
            }),
        }
    }

    fn describe(&self, topic: &str) -> Option<String> {
        let map = self.0.lock().unwrap_or_else(|p| p.into_inner());
        let reasons = map.get(topic).filter(|r| !r.is_empty())?;
        let count: u64 = reasons.iter().map(|r| r.count).sum();
        let why: Vec<String> = reasons
            .iter()
            .map(|r| format!("{} ({})", r.reason, r.count))
            .collect();
        Some(format!(
            "{count} message(s) arrived and none could be used: {}; e.g. {}",
            why.join("; "),
            reasons[0].example
        ))
    }

    /// Every topic's drops, for a report: `{topic: [{reason, count}]}`.
    fn summary(&self) -> Value {
        let map = self.0.lock().unwrap_or_else(|p| p.into_inner());
        Value::Object(
            map.iter()
                .map(|(topic, reasons)| {
                    let list = reasons
                        .iter()
                        .map(|r| json!({ "reason": r.reason, "count": r.count }))
                        .collect();
                    (topic.clone(), Value::Array(list))
                })
                .collect(),
        )
    }
}

pub(super) fn stamp_of(v: &Value) -> Option<f64> {
    let s = v.get("header")?.get("stamp")?;
    let sec = s.get("sec").or_else(|| s.get("secs"))?.as_f64()?;
    let ns = s.get("nanosec").or_else(|| s.get("nsecs"))?.as_f64()?;
    Some(sec + ns * 1e-9)
}

fn advance(odo: &mut Odo, stamp: f64, step: Displacement) {
    let (ds, dth) = (step.distance_m, step.turn_rad);
    let dt = (stamp - odo.stamp_s).max(1e-6);
    let moving = ds.abs() / dt > 0.002 || dth.abs() / dt > 0.01;
    odo.distance_m += ds;
    odo.turn_rad += dth;
    odo.samples += 1;
    odo.stamp_s = stamp;
    odo.still_since_s = match (moving, odo.still_since_s) {
        (true, _) => None,
        (false, Some(s)) => Some(s),
        (false, None) => Some(stamp),
    };
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

async fn integrate_joints(
    mut rx: tokio::sync::broadcast::Receiver<Value>,
    (topic, rejects): (String, Rejects),
    geometry: Geometry,
    left: Option<String>,
    right: Option<String>,
    tx: watch::Sender<Odo>,
    travel: Fanout<TravelSample>,
) {
    let mut last: Option<(f64, f64)> = None;
    let mut odo = Odo::default();
    let mut check = LiveJoints::default();
    loop {
        let Some(v) = next_message(&mut rx).await else {
            return;
        };
        let js = match decode::<JointState>(&v) {
            Ok(js) => js,
            Err(why) => {
                rejects.note(&topic, why, &v);
                continue;
            }
        };
        let Some((l, r)) = js.wheel_indices(&left, &right) else {
            let want = match (&left, &right) {
                (Some(l), Some(r)) => format!("`{l}` and `{r}`"),
                _ => "one name with \"left\" and one with \"right\"".into(),
            };
            let why = format!("no wheel joints {want} among {:?}", js.name);
            rejects.note(&topic, why, &v);
            continue;
        };
        let (Some(&lp), Some(&rp)) = (js.position.get(l), js.position.get(r)) else {
            rejects.note(&topic, "fewer positions than names".into(), &v);
            continue;
        };
        let stamp = stamp_of(&v).unwrap_or(odo.stamp_s);
        // The checks a bag's joints get, one message at a time.
        let (settled, verdict) = check.check(stamp, (lp, rp));
        match settled {
            Some(Verdict::Drop(why)) => rejects.note(&topic, why.into(), &v),
            Some(Verdict::Restart) => rejects.note(
                &topic,
                "a jump that stayed (the driver reset its counts?): the step across it is not \
                 travel"
                    .into(),
                &v,
            ),
            _ => {}
        }
        match verdict {
            Verdict::Drop(why) => {
                rejects.note(&topic, why.into(), &v);
                continue;
            }
            Verdict::Hold => continue,
            Verdict::Restart if last.is_some() => {
                last = Some((lp, rp));
                odo.stamp_s = stamp;
                let _ = tx.send(odo);
                continue;
            }
            Verdict::Restart | Verdict::Keep => {}
        }
        let g = effective(&geometry);
        if let Some((l0, r0)) = last {
            let (sl, sr) = g.travel_m(
                super::msg::angle_step(l0, lp),
                super::msg::angle_step(r0, rp),
            );
            advance(
                &mut odo,
                stamp,
                Displacement::of_wheels(sl, sr, g.wheelbase_m),
            );
            travel.send(&TravelSample {
                time_s: stamp,
                left_m: sl,
                right_m: sr,
            });
        } else {
            odo.samples = 1;
            odo.stamp_s = stamp;
        }
        last = Some((lp, rp));
        let _ = tx.send(odo);
    }
}

async fn integrate_odom(
    mut rx: tokio::sync::broadcast::Receiver<Value>,
    (topic, rejects): (String, Rejects),
    geometry: Geometry,
    tx: watch::Sender<Odo>,
    travel: Fanout<TravelSample>,
) {
    let mut last: Option<(f64, f64, f64)> = None;
    let mut odo = Odo::default();
    let mut forward = Forward::default();
    loop {
        let Some(v) = next_message(&mut rx).await else {
            return;
        };
        let o = match decode::<Odometry>(&v) {
            Ok(o) => o,
            Err(why) => {
                rejects.note(&topic, why, &v);
                continue;
            }
        };
        let yaw = match yaw_of(&o.pose.pose.orientation) {
            Ok(yaw) => yaw,
            Err(why) => {
                rejects.note(&topic, format!("pose.pose.orientation: {why}"), &v);
                continue;
            }
        };
        let (x, y) = (o.pose.pose.position.x, o.pose.pose.position.y);
        if !(x.abs() <= MAX_POSITION_M && y.abs() <= MAX_POSITION_M) {
            rejects.note(
                &topic,
                format!("pose.pose.position is not a number within ±{MAX_POSITION_M:e} m"),
                &v,
            );
            continue;
        }
        let stamp = stamp_of(&v).unwrap_or(odo.stamp_s);
        if let Verdict::Drop(why) = forward.check(stamp) {
            rejects.note(&topic, why.into(), &v);
            continue;
        }
        if let Some((x0, y0, yaw0)) = last {
            let dth = wrap_angle(yaw - yaw0);
            let mid = yaw0 + 0.5 * dth;
            let step = Displacement {
                distance_m: (x - x0) * mid.cos() + (y - y0) * mid.sin(),
                turn_rad: dth,
            };
            advance(&mut odo, stamp, step);
            let (left_m, right_m) = step.wheels(effective(&geometry).wheelbase_m);
            travel.send(&TravelSample {
                time_s: stamp,
                left_m,
                right_m,
            });
        } else {
            odo.samples = 1;
            odo.stamp_s = stamp;
        }
        last = Some((x, y, yaw));
        let _ = tx.send(odo);
    }
}

async fn follow_imu(
    mut rx: tokio::sync::broadcast::Receiver<Value>,
    (topic, rejects): (String, Rejects),
    tx: Publisher,
    streams: Fanout<HeadingSample>,
) {
    let mut forward = Forward::default();
    loop {
        let Some(v) = next_message(&mut rx).await else {
            return;
        };
        let stamp = stamp_of(&v).unwrap_or(0.0);
        if let Verdict::Drop(why) = forward.check(stamp) {
            rejects.note(&topic, why.into(), &v);
            continue;
        }
        let sample = match decode::<Imu>(&v) {
            Err(e) => {
                rejects.note(&topic, e.clone(), &v);
                HeadingSample {
                    time_s: stamp,
                    heading_rad: 0.0,
                    validity: Validity::Invalid(format!("undecodable IMU message: {e}")),
                }
            }
            Ok(imu) if imu.orientation_covariance[0] == -1.0 => HeadingSample {
                time_s: stamp,
                heading_rad: 0.0,
                validity: Validity::Invalid(
                    "the IMU publishes no orientation (orientation_covariance[0] = -1)".into(),
                ),
            },
            Ok(imu) => match yaw_of(&imu.orientation) {
                Ok(yaw) => HeadingSample {
                    time_s: stamp,
                    heading_rad: yaw,
                    validity: Validity::Valid,
                },
                Err(why) => HeadingSample {
                    time_s: stamp,
                    heading_rad: 0.0,
                    validity: Validity::Invalid(why.into()),
                },
            },
        };
        streams.send(&sample);
        tx.publish(Instant::now(), sample);
    }
}

/// Which odometry quantity a motion watches.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Kind {
    Straight,
    Turn,
}

impl RosDrive {
    /// Drives until the odometry's `kind` quantity has changed by `target`, ramping at the
    /// configured acceleration and limited to `max` (m/s or rad/s).
    /// One motion closed on the odometry; a turn that ends more than [`TURN_TRIM_RAD`] off its
    /// target is trimmed by up to two slow turns in place (a tenth of the rate): the braking
    /// runs on messages that arrive late by the link's latency, and a square whose corners
    /// are not square points its legs elsewhere than the other direction's (which the methods
    /// that pair legs by azimuth rely on).
    async fn motion(
        &self,
        kind: Kind,
        target: f64,
        max: f64,
    ) -> Result<Option<Achieved>, BaseError> {
        let mut done = self.motion_once(kind, target, max, true).await?;
        if kind == Kind::Turn {
            for _ in 0..2 {
                let rest = target - done.turn_rad;
                if rest.abs() <= TURN_TRIM_RAD {
                    break;
                }
                // A trim creeps, and a wheel may stick at a creep: no stillness diagnosis.
                let trim = self.motion_once(kind, rest, 0.1 * max, false).await?;
                done.turn_rad += trim.turn_rad;
                done.distance_m += trim.distance_m;
            }
        }
        Ok(Some(done))
    }

    async fn motion_once(
        &self,
        kind: Kind,
        target: f64,
        max: f64,
        diagnose: bool,
    ) -> Result<Achieved, BaseError> {
        if !(target.is_finite() && max.is_finite() && max > 0.0) {
            return Err(BaseError::InvalidArgument {
                component: "drive (rosbridge)".into(),
                reason: format!("motion {target} at up to {max} is not a motion"),
            });
        }
        let accel = match kind {
            Kind::Straight => self.cfg.max_accel_m_s2,
            Kind::Turn => self.cfg.max_alpha_rad_s2,
        }
        .max(1e-3);
        let mut odo = self.odo.clone();
        let mut closed = self.commander.client.closed_watch();
        let start = *odo.borrow();
        let pick = |o: &Odo| match kind {
            Kind::Straight => o.distance_m,
            Kind::Turn => o.turn_rad,
        };
        let (sign, goal) = (target.signum(), target.abs());
        // Tolerance: a millimetre, or a twentieth of a degree.
        let tol = match kind {
            Kind::Straight => 0.001,
            Kind::Turn => 0.001,
        };
        let expected = goal / max + max / accel;
        let deadline = Instant::now() + Duration::from_secs_f64(3.0 * expected + 5.0);
        let mut last_cmd = 0.0f64;
        let mut last_t = Instant::now();
        let mut last_progress_t = Instant::now();
        let mut last_samples = start.samples;
        let first_command = Instant::now();
        let witnessed = self.witness.now();
        let mut moved = false;
        loop {
            let now_odo = *odo.borrow();
            let progress = sign * (pick(&now_odo) - pick(&start));
            moved |= (now_odo.distance_m - start.distance_m).abs() > STILL_M
                || (now_odo.turn_rad - start.turn_rad).abs() > STILL_RAD;
            let remaining = goal - progress;
            if remaining <= tol {
                break;
            }
            if now_odo.samples != last_samples {
                last_samples = now_odo.samples;
                last_progress_t = Instant::now();
            }
            let now = Instant::now();
            if now > deadline {
                let _ = self.commander.send(0.0, 0.0);
                return Err(BaseError::MotionTimeout {
                    after: Duration::from_secs_f64(3.0 * expected + 5.0),
                });
            }
            if now - last_progress_t > Duration::from_secs(1) {
                let _ = self.commander.send(0.0, 0.0);
                return Err(drive_err(RosbridgeError::Timeout(format!(
                    "no wheel data for 1 s during a motion (topic {}): stopped",
                    match self.cfg.wheel_source {
                        WheelSource::JointStates => &self.cfg.topics.joint_states,
                        WheelSource::Odom => &self.cfg.topics.odom,
                    }
                ))));
            }
            // Wheel data arrives (the check above) and shows no motion: nothing obeys.
            if diagnose && !moved && first_command.elapsed() > STILL_LIMIT {
                let _ = self.commander.send(0.0, 0.0);
                return Err(drive_err(self.diagnose_still(&witnessed).await));
            }
            let dt = (now - last_t).as_secs_f64().clamp(0.0, 0.1);
            last_t = now;
            // Ramp up at `accel`, brake so as to stop at the goal, never below a creep speed.
            let cmd = max
                .min((2.0 * accel * remaining).sqrt())
                .min(last_cmd + accel * dt.max(0.02))
                .max(0.05 * max);
            last_cmd = cmd;
            let (v, w) = match kind {
                Kind::Straight => (sign * cmd, 0.0),
                Kind::Turn => (0.0, sign * cmd),
            };
            self.commander.send(v, w).map_err(drive_err)?;
            tokio::select! {
                _ = odo.changed() => {}
                _ = tokio::time::sleep(Duration::from_millis(50)) => {}
                _ = closed.changed() => {
                    let reason = self.commander.client.closed().unwrap_or_default();
                    return Err(drive_err(RosbridgeError::Closed(format!(
                        "{reason} during a motion; the controller's cmd_vel_timeout ({} s) stops the wheels",
                        self.cmd_vel_timeout_s
                    ))));
                }
            }
        }
        self.commander.send(0.0, 0.0).map_err(drive_err)?;
        // Wait until the wheels have been still for 0.2 s of robot time (at most 3 s).
        let settled = tokio::time::timeout(
            Duration::from_secs(3),
            odo.wait_for(|o| o.still_since_s.is_some_and(|s| o.stamp_s - s >= 0.2)),
        )
        .await
        .map(|r| r.map(|o| *o));
        if let Ok(Err(_)) = settled {
            return Err(drive_err(RosbridgeError::Closed("wheel data ended".into())));
        }
        let end = *self.odo.borrow();
        Ok(Achieved {
            distance_m: end.distance_m - start.distance_m,
            turn_rad: end.turn_rad - start.turn_rad,
        })
    }
}

/// A robot whose odometry has not changed this long after a motion's first command is not
/// obeying: stopped and diagnosed ([`NotMoving`]).
pub const STILL_LIMIT: Duration = Duration::from_secs(1);
/// Odometry changes below these (m, rad) are not motion.
const STILL_M: f64 = 1e-4;
const STILL_RAD: f64 = 1e-4;

/// The robot did not move on a motion's command: what the other wheel source and the robot's
/// graph say about why.
#[derive(Debug, thiserror::Error)]
#[error(
    "the robot did not move within {} of the first command on {topic} ({kind}): its \
     odometry ({odometry}) did not change; {other}; {diagnosis}; stopped",
    crate::io::seconds(.after)
)]
pub struct NotMoving {
    /// The velocity topic commanded.
    pub topic: String,
    /// The message type published there.
    pub kind: String,
    /// How long it waited.
    pub after: Duration,
    /// The odometry source watched.
    pub odometry: String,
    /// What the other wheel source (the controller's odometry, or the joint states) showed
    /// meanwhile.
    pub other: String,
    /// What rosapi tells: the topic's type, its subscribers, the velocity topics that exist.
    pub diagnosis: String,
}

/// How long each rosapi question of the still-robot diagnosis may take; they are asked at
/// once, so that the diagnosis ends within a second of [`STILL_LIMIT`].
pub const DIAGNOSIS_CALL_TIMEOUT: Duration = Duration::from_millis(400);

/// A change of the other wheel source beyond this (m, rad) is motion.
const WITNESS_MOVED: f64 = 1e-3;

/// The wheel source motions do not close on, followed (ten messages a second) for the
/// still-robot diagnosis: when the watched source shows no motion, this one tells a robot that
/// does not move from a source that does not show it.
#[derive(Clone)]
struct Witness {
    topic: String,
    what: &'static str,
    /// Its latest reading: x, y (m) and yaw (rad) of the odometry, or the wheel angles (rad).
    latest: watch::Receiver<Option<Vec<f64>>>,
}

impl Witness {
    /// Subscribes to the source `cfg` does not close on; `wheels` are the joint names given.
    fn follow(
        client: &RosbridgeClient,
        cfg: &RosBaseConfig,
        wheels: (Option<String>, Option<String>),
    ) -> Result<Self, RosbridgeError> {
        let odom = cfg.wheel_source == WheelSource::JointStates;
        let (topic, kind, what) = if odom {
            (
                &cfg.topics.odom,
                types::ODOMETRY,
                "the controller's odometry",
            )
        } else {
            (
                &cfg.topics.joint_states,
                types::JOINT_STATE,
                "the joint states",
            )
        };
        let mut rx = client.subscribe_throttled(topic, kind, Duration::from_millis(100))?;
        let (tx, latest) = watch::channel(None);
        tokio::spawn(async move {
            while let Some(v) = next_message(&mut rx).await {
                let reading = if odom {
                    decode::<Odometry>(&v).ok().map(|o| {
                        let p = o.pose.pose;
                        let yaw = yaw_of(&p.orientation).unwrap_or(f64::NAN);
                        vec![p.position.x, p.position.y, yaw]
                    })
                } else {
                    decode::<JointState>(&v).ok().map(|js| {
                        match js.wheel_indices(&wheels.0, &wheels.1) {
                            Some((l, r)) => [l, r]
                                .iter()
                                .filter_map(|&i| js.position.get(i).copied())
                                .collect(),
                            None => js.position,
                        }
                    })
                };
                if reading.is_some() && tx.send(reading).is_err() {
                    return;
                }
            }
        });
        Ok(Witness {
            topic: topic.clone(),
            what,
            latest,
        })
    }

    /// Its latest reading.
    fn now(&self) -> Option<Vec<f64>> {
        self.latest.borrow().clone()
    }

    /// What it showed between `before` and now, for a robot whose `watched` source did not
    /// change.
    fn says(&self, before: &Option<Vec<f64>>, watched: &str) -> String {
        let (topic, what) = (&self.topic, self.what);
        match (before, self.now()) {
            (_, None) => format!("{topic} ({what}) sent nothing to compare with"),
            (None, Some(_)) => format!("{topic} ({what}) began only during the motion"),
            (Some(a), Some(b)) => {
                let change = a
                    .iter()
                    .zip(&b)
                    .map(|(x, y)| super::msg::angle_step(*x, *y).abs())
                    .fold(0.0, f64::max);
                if a.len() != b.len() || change > WITNESS_MOVED {
                    let hint = if what == "the joint states" {
                        format!(
                            " (is {watched} the controller's odometry, and is the controller \
                             running?)"
                        )
                    } else {
                        " (are the wheel joints named as the YAML or --left-joint/--right-joint \
                         say, and does the hardware report their positions?)"
                            .into()
                    };
                    format!(
                        "{topic} ({what}) did change: the robot moves, but {watched} does not \
                         show it{hint}"
                    )
                } else {
                    format!("{topic} ({what}) did not change either")
                }
            }
        }
    }
}

impl RosDrive {
    /// Why nothing moves: what the other wheel source showed since the first command
    /// (`witnessed` then), and rosapi's answers, asked at once, each within
    /// [`DIAGNOSIS_CALL_TIMEOUT`]: the velocity topic's type and subscribers, and the robot's
    /// topics of a velocity type.
    async fn diagnose_still(&self, witnessed: &Option<Vec<f64>>) -> NotMoving {
        let client = &self.commander.client;
        let ask = |service: &'static str, kind: &'static str, args: Value| async move {
            client
                .call_service(service, kind, args, DIAGNOSIS_CALL_TIMEOUT)
                .await
                .ok()
        };
        let topic = self.cfg.cmd_vel.clone();
        let kind = if self.cfg.twist_stamped {
            types::TWIST_STAMPED
        } else {
            types::TWIST
        };
        let (listed, subscribers, all) = tokio::join!(
            ask(
                "/rosapi/topic_type",
                "rosapi_msgs/srv/TopicType",
                json!({ "topic": topic })
            ),
            ask(
                "/rosapi/subscribers",
                "rosapi_msgs/srv/Subscribers",
                json!({ "topic": topic })
            ),
            ask("/rosapi/topics", "rosapi_msgs/srv/Topics", json!({})),
        );
        let mut notes = Vec::new();
        match listed
            .as_ref()
            .and_then(|v| v.get("type"))
            .and_then(Value::as_str)
        {
            Some(t) if !t.is_empty() && !types::is(t, kind) && !types::is(kind, t) => notes.push(
                format!("{topic} carries {t}, not the {kind} published (--twist-stamped)"),
            ),
            _ => {}
        }
        let subscribers = subscribers
            .and_then(|v| v.get("subscribers").cloned())
            .and_then(|v| serde_json::from_value::<Vec<String>>(v).ok());
        match subscribers {
            Some(s) if s.is_empty() => notes.push(format!("nothing subscribes to {topic}")),
            Some(s) => notes.push(format!("{topic} is subscribed by {}", s.join(", "))),
            None => notes.push("rosapi did not say who subscribes".into()),
        }
        let pairs: Vec<(String, String)> = all
            .as_ref()
            .and_then(|v| {
                let t: Vec<String> = serde_json::from_value(v.get("topics")?.clone()).ok()?;
                let k: Vec<String> = serde_json::from_value(v.get("types")?.clone()).ok()?;
                Some(t.into_iter().zip(k).collect())
            })
            .unwrap_or_default();
        let velocity: Vec<String> = pairs
            .iter()
            .filter(|(t, k)| {
                *t != topic && (types::is(k, types::TWIST) || types::is(k, types::TWIST_STAMPED))
            })
            .map(|(t, k)| format!("{t} ({k})"))
            .collect();
        if !velocity.is_empty() {
            notes.push(format!(
                "velocity topics on this robot: {} (give the controller's with --cmd-vel, and \
                 --twist-stamped for TwistStamped)",
                velocity.join(", ")
            ));
        }
        let odometry = match self.cfg.wheel_source {
            WheelSource::JointStates => self.cfg.topics.joint_states.clone(),
            WheelSource::Odom => self.cfg.topics.odom.clone(),
        };
        NotMoving {
            topic,
            kind: kind.into(),
            after: STILL_LIMIT,
            other: self.witness.says(witnessed, &odometry),
            odometry,
            diagnosis: notes.join("; "),
        }
    }
}

/// A turn that ends further than this from its target (rad; 0.2°) by the odometry is trimmed.
pub const TURN_TRIM_RAD: f64 = 0.2 * std::f64::consts::PI / 180.0;

#[async_trait]
impl Drive for RosDrive {
    fn info(&self) -> ComponentInfo {
        ComponentInfo {
            kind: "rosbridge".into(),
            id: self.cfg.url.clone(),
            details: json!({
                "cmd_vel": self.cfg.cmd_vel,
                "twist_stamped": self.cfg.twist_stamped,
                "wheel_source": self.cfg.wheel_source,
                "topics": self.cfg.topics,
            }),
        }
    }

    fn diagnostics(&self) -> Value {
        // Every message a topic's checks dropped (not a number, not physical, stamped back, a
        // spike), by topic and reason: none is used silently.
        json!({ "dropped": self.rejects.summary() })
    }

    async fn preflight(&self) -> Result<Preflight, BaseError> {
        let mut out = Preflight::default();
        if let Some(reason) = self.commander.client.closed() {
            out.faults
                .push(format!("the rosbridge connection closed: {reason}"));
        }
        if self.odo.borrow().samples == 0 {
            out.faults.push("no wheel data yet".into());
        }
        Ok(out)
    }

    async fn arm_watchdog(&self, _timeout: Duration) -> Result<Option<Duration>, BaseError> {
        // The dead-man is the controller's cmd_vel_timeout: it is configured on the robot, and
        // the drive publishes at least every 50 ms during a motion to stay inside it.
        Ok(Some(Duration::from_secs_f64(
            self.cmd_vel_timeout_s.clamp(0.01, 60.0),
        )))
    }

    async fn move_straight(
        &self,
        distance_m: f64,
        max_speed_m_s: f64,
    ) -> Result<Option<Achieved>, BaseError> {
        self.motion(Kind::Straight, distance_m, max_speed_m_s).await
    }

    async fn turn_in_place(
        &self,
        angle_rad: f64,
        max_rate_rad_s: f64,
    ) -> Result<Option<Achieved>, BaseError> {
        self.motion(Kind::Turn, angle_rad, max_rate_rad_s).await
    }

    async fn stop(&self) -> Result<(), BaseError> {
        self.commander.send(0.0, 0.0).map_err(drive_err)
    }

    fn emergency_stop(&self) {
        let _ = self.commander.send(0.0, 0.0);
    }

    async fn travel(
        &self,
        _period: Duration,
    ) -> Result<Option<SampleStream<TravelSample>>, BaseError> {
        Ok(Some(self.travel.subscribe()))
    }

    fn clock(&self) -> Option<String> {
        Some(robot_clock(&self.cfg.url))
    }
}

impl Drop for RosDrive {
    fn drop(&mut self) {
        // Leaving: whatever happened, the last word on the velocity topic is zero.
        let _ = self.commander.send(0.0, 0.0);
    }
}

#[async_trait]
impl HeadingSource for RosHeading {
    fn info(&self) -> ComponentInfo {
        ComponentInfo {
            kind: "rosbridge-imu".into(),
            id: format!("{}{}", self.url, self.topic),
            details: Value::Null,
        }
    }

    async fn read(&self) -> Result<HeadingSample, BaseError> {
        // Robot time of the newest wheel data: the reading must be at least as new, so that a
        // heading "at rest" is never one taken before the wheels stopped (messages of the two
        // topics can be processed at different paces).
        // And it must arrive after this call: the newest cached message returned to every read
        // would make ten readings at rest one reading ten times (a noise of zero, an average of
        // one sample).
        let newest = self.wheels.borrow().stamp_s;
        let asked = Instant::now();
        let fresh = self
            .latest
            .read_after(asked, self.stale, |s| s.time_s >= newest);
        match fresh.await {
            Fresh::Got(sample) => Ok(sample),
            Fresh::Closed => Err(BaseError::HeadingInvalid {
                reason: format!("{} ended", self.topic),
            }),
            Fresh::Stale(last) => Ok(HeadingSample {
                time_s: last.as_ref().map_or(0.0, |s| s.time_s),
                heading_rad: last.as_ref().map_or(0.0, |s| s.heading_rad),
                validity: Validity::Invalid(format!(
                    "stale: no new {} message as new as the wheel data ({newest:.3} s) within {}",
                    self.topic,
                    crate::io::seconds(&self.stale)
                )),
            }),
        }
    }

    async fn stream(
        &self,
        _period: Duration,
    ) -> Result<Option<SampleStream<HeadingSample>>, BaseError> {
        Ok(Some(self.streams.subscribe()))
    }

    fn clock(&self) -> Option<String> {
        Some(robot_clock(&self.url))
    }
}

#[async_trait]
impl ParamStore for RosStore {
    fn info(&self) -> ComponentInfo {
        let mut info = self.yaml.info();
        info.details["set_live"] = json!(self.set_live);
        info
    }

    async fn read(&self) -> Result<WheelParams, BaseError> {
        self.yaml.read().await
    }

    async fn write(&self, params: &WheelParams) -> Result<WheelParams, BaseError> {
        self.yaml.write(params).await
    }

    async fn commit(&self) -> Result<(), BaseError> {
        // The multipliers the file will hold after this commit.
        let staged = self.yaml.read().await?;
        self.yaml.commit().await?;
        if self.set_live {
            let cfg = self.yaml.on_disk()?;
            let m = cfg.multipliers_for(&staged);
            let values = [
                m.wheel_separation_multiplier,
                m.left_wheel_radius_multiplier,
                m.right_wheel_radius_multiplier,
            ];
            let service = self.service("set_parameters");
            let refused = self
                .set_multipliers(&service, values)
                .await
                .map_err(|e| BaseError::backend("store (live)", e))?;
            if !refused.is_empty() {
                // Not `Refused`: the file was replaced already, so the commit happened and a
                // rollback must put the file back too.
                return Err(BaseError::backend(
                    "store (live)",
                    std::io::Error::other(format!(
                        "the file was written, but the running controller refused {service}: {}",
                        refused.join("; ")
                    )),
                ));
            }
            *self.running.write().unwrap_or_else(|p| p.into_inner()) = staged;
        }
        Ok(())
    }

    async fn read_committed(&self) -> Result<Option<WheelParams>, BaseError> {
        self.yaml.read_committed().await
    }

    fn resolution(&self) -> WheelParams {
        self.yaml.resolution()
    }

    fn file(&self) -> Option<std::path::PathBuf> {
        self.yaml.file()
    }

    async fn check_write(&self, params: &WheelParams) -> Result<(), BaseError> {
        self.yaml.check_write(params).await?;
        if self.set_live {
            self.check_live().await?;
        }
        Ok(())
    }
}

impl RosStore {
    /// `/<controller>/<name>`, one of the controller node's services.
    fn service(&self, name: &str) -> String {
        format!("/{}/{name}", self.controller)
    }

    /// Calls the controller's `set_parameters` with the three multipliers (in
    /// [`MULTIPLIER_KEYS`] order); the reasons of those it refused.
    async fn set_multipliers(
        &self,
        service: &str,
        values: [f64; 3],
    ) -> Result<Vec<String>, RosbridgeError> {
        let parameters: Vec<Value> = MULTIPLIER_KEYS
            .iter()
            .zip(values)
            .map(|(name, v)| json!({"name": name, "value": {"type": 3, "double_value": v}}))
            .collect();
        let answer = self
            .client
            .call_service(
                service,
                "rcl_interfaces/srv/SetParameters",
                json!({ "parameters": parameters }),
                Duration::from_secs(3),
            )
            .await?;
        let results = answer.get("results").and_then(Value::as_array);
        Ok(match results {
            Some(r) if r.len() == MULTIPLIER_KEYS.len() => MULTIPLIER_KEYS
                .iter()
                .zip(r)
                .filter(|(_, x)| x.get("successful").and_then(Value::as_bool) != Some(true))
                .map(|(name, x)| {
                    let why = x.get("reason").and_then(Value::as_str).unwrap_or("");
                    format!("{name}: {}", if why.is_empty() { "refused" } else { why })
                })
                .collect(),
            _ => vec![format!(
                "the answer has no result for each of the three parameters: {answer}"
            )],
        })
    }

    /// Proves, before the robot moves, that the running controller can take the multipliers
    /// live: its `get_parameters` answers with a double for each, its `describe_parameters`
    /// says each is a double and not read-only, and its `set_parameters` accepts each at the
    /// value it has now (a write that changes nothing, so that a parameter callback that
    /// refuses sets, or a node that answers no sets, is found before the robot moves).
    async fn check_live(&self) -> Result<(), BaseError> {
        let unwritable = |why: String| BaseError::Unwritable {
            component: "store (live)".into(),
            source: format!("--ros-set-live: {why}").into(),
        };
        let call = |service: String, kind: &'static str, args: Value| async move {
            self.client
                .call_service(&service, kind, args, Duration::from_secs(3))
                .await
                .map_err(|e| {
                    unwritable(format!(
                        "{service} failed ({e}); is the controller running under that name?"
                    ))
                })
        };
        let names = json!({ "names": MULTIPLIER_KEYS });
        let service = self.service("get_parameters");
        let answer = call(
            service.clone(),
            "rcl_interfaces/srv/GetParameters",
            names.clone(),
        )
        .await?;
        let list = |answer: &Value, field: &str| {
            answer
                .get(field)
                .and_then(Value::as_array)
                .cloned()
                .unwrap_or_default()
        };
        let values = list(&answer, "values");
        let now: Vec<f64> = values
            .iter()
            .filter(|v| v.get("type").and_then(Value::as_u64) == Some(3))
            .filter_map(|v| v.get("double_value").and_then(Value::as_f64))
            .collect();
        let Ok(now) = <[f64; 3]>::try_from(now) else {
            return Err(unwritable(format!(
                "the running controller does not declare {} as doubles with a value ({service} \
                 gave {} value(s)): a controller without them cannot take a calibration live",
                MULTIPLIER_KEYS.join(", "),
                values.len()
            )));
        };
        let service = self.service("describe_parameters");
        let answer = call(
            service.clone(),
            "rcl_interfaces/srv/DescribeParameters",
            names,
        )
        .await?;
        let descriptors = list(&answer, "descriptors");
        for name in MULTIPLIER_KEYS {
            let Some(d) = descriptors
                .iter()
                .find(|d| d.get("name").and_then(Value::as_str) == Some(name))
            else {
                return Err(unwritable(format!("{service} does not describe {name}")));
            };
            if d.get("read_only").and_then(Value::as_bool) != Some(false) {
                return Err(unwritable(format!(
                    "{service} says {name} is read-only: the running controller cannot take it \
                     live (without --ros-set-live the YAML is written, and the controller reads \
                     it when it is restarted)"
                )));
            }
            if d.get("type").and_then(Value::as_u64) != Some(3) {
                return Err(unwritable(format!(
                    "{service} says {name} is of type {}, not a double (3)",
                    d.get("type").unwrap_or(&Value::Null)
                )));
            }
        }
        let service = self.service("set_parameters");
        let refused = self
            .set_multipliers(&service, now)
            .await
            .map_err(|e| unwritable(format!("{service} failed ({e})")))?;
        if !refused.is_empty() {
            return Err(unwritable(format!(
                "{service} refused the multipliers at the values they have now ({}): it would \
                 refuse the calibration too",
                refused.join("; ")
            )));
        }
        Ok(())
    }
}
