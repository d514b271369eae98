//! A mock rosbridge server on a loopback socket, backed by the simulator: a ROS 2 robot with
//! `diff_drive_controller` as seen through `rosbridge_server`, speaking the rosbridge v2
//! protocol to any client (`conn.rs`) and answering rosapi and the controller's parameter
//! services (`services.rs`).
//!
//! The controller turns each `cmd_vel` twist into wheel speeds with its **configured** geometry
//! (from the YAML), ramps them at its acceleration limits and stops them after
//! `cmd_vel_timeout` without a command; the **true** robot moves those wheel rotations with its
//! true geometry. It publishes `/joint_states` (wheel angles), `/odom` (the controller's
//! odometry, configured geometry) and `/imu` (true yaw with noise) at their rates, stamped with
//! the wall clock at start plus robot time (which can run faster than the wall clock), and on
//! request a localization's pose topic ([`MockLocalization`]).
//! [`MockRosbridge::vanish`] drops every connection and stops listening while the robot keeps
//! running, as a crashed `rosbridge_server` would.
//!
//! What real robots send is reproduced on request ([`EffortStyle`]): joint_state_broadcaster
//! fills `effort` with NaN for wheels without an effort interface, which rosbridge writes as
//! `null`, or as the bare token `NaN` inside fixed-size arrays (rosbridge_suite #916).

mod conn;
mod localization;
mod services;

pub use localization::MockLocalization;
pub use services::ParamValue;

use crate::kinematics::{Displacement, Pose, WheelParams};
use crate::ros::msg::{Header, Imu, JointState, Odometry, Quaternion, Time, Twist};
use crate::ros::yaml::DiffDriveConfig;
use crate::sim::sensor::HeadingModel;
use crate::sim::{NoiseModel, Simulator};
use serde_json::Value;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;
use tokio::sync::broadcast;
use tokio::task::JoinHandle;

/// Everything that defines a mock ROS robot.
#[derive(Debug, Clone)]
pub struct MockRosConfig {
    /// The controller's section as its YAML has it (the configured geometry).
    pub controller: DiffDriveConfig,
    /// The robot's true effective parameters (wheel angles in radians).
    pub truth: WheelParams,
    /// IMU noise (the simulator's compass).
    pub noise: NoiseModel,
    /// How the IMU's heading errs (a gyro's scale and drift, latency, loss…).
    pub heading_model: HeadingModel,
    /// Seed of the simulator.
    pub seed: u64,
    /// Robot seconds per wall-clock second.
    pub time_scale: f64,
    /// Joint state and odometry rate (Hz).
    pub joint_hz: f64,
    /// IMU rate (Hz); a multiple of `joint_hz`.
    pub imu_hz: f64,
    /// The controller's linear acceleration limit (m/s²).
    pub accel_limit_m_s2: f64,
    /// The controller's angular acceleration limit (rad/s²).
    pub alpha_limit_rad_s2: f64,
    /// Velocity topic it obeys.
    pub cmd_vel: String,
    /// The velocity message type it expects there: `TwistStamped` (Jazzy's default) or
    /// `Twist`.
    pub cmd_vel_stamped: bool,
    /// How the joint states' `effort` and the IMU's unknown covariances come out.
    pub effort: EffortStyle,
    /// Delay before each message leaves (wall clock).
    pub latency: Duration,
    /// Stop publishing `/joint_states` after this much robot time (a failing driver).
    pub joint_states_stop_after_s: Option<f64>,
    /// Publish `/joint_states` whose wheel positions never change while the robot moves
    /// (ros2_control's mock hardware without position feedback).
    pub frozen_joint_states: bool,
    /// Every this many `/joint_states` messages, one whose left wheel angle is 3 rad off (an
    /// encoder glitch on a noisy bus), and the message after it stamped 0.1 s before it (a
    /// clock step on the driver's host).
    pub joint_glitch_every: Option<u64>,
    /// Controller parameters declared read-only: `describe_parameters` says so and a set of
    /// them is refused with rclcpp's reason.
    pub read_only_parameters: Vec<String>,
    /// A parameter callback of the controller that refuses every set with this reason.
    pub refuse_parameter_sets: Option<String>,
    /// A localization publishing the robot's pose ([`MockLocalization`]); none by default.
    pub localization: Option<MockLocalization>,
}

impl MockRosConfig {
    /// A robot with true ratios `e_b`, `e_d` (left wheel nominal) to the controller's geometry.
    pub fn with_ratios(
        controller: DiffDriveConfig,
        e_b: f64,
        e_d: f64,
    ) -> Result<Self, crate::kinematics::KinematicsError> {
        let truth = WheelParams::from_ratios(
            &controller.effective(),
            e_b,
            e_d,
            &crate::kinematics::SplitConvention::LeftNominal,
        )?;
        Ok(MockRosConfig {
            controller,
            truth,
            noise: NoiseModel::default(),
            heading_model: HeadingModel::default(),
            seed: 1,
            time_scale: 1.0,
            joint_hz: 50.0,
            imu_hz: 100.0,
            accel_limit_m_s2: 1.0,
            alpha_limit_rad_s2: 4.0,
            cmd_vel: "/cmd_vel".into(),
            cmd_vel_stamped: false,
            effort: EffortStyle::Empty,
            latency: Duration::from_millis(2),
            joint_states_stop_after_s: None,
            frozen_joint_states: false,
            joint_glitch_every: None,
            read_only_parameters: Vec::new(),
            refuse_parameter_sets: None,
            localization: None,
        })
    }
}

/// How a robot's joint states carry `effort` (odocal never uses it), as real drivers and
/// rosbridge put it on the wire.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum EffortStyle {
    /// `"effort": []`.
    #[default]
    Empty,
    /// `"effort": [0.0, 0.0]`.
    Zero,
    /// NaN written as rosbridge writes a NaN in a variable-length array: `[null, null]`.
    Null,
    /// NaN as the bare token `NaN` (`[NaN, NaN]`, not JSON), and the IMU's fixed-size
    /// `angular_velocity_covariance` likewise (rosbridge_suite #916).
    BareNan,
}

impl std::str::FromStr for EffortStyle {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "empty" => Ok(EffortStyle::Empty),
            "zero" => Ok(EffortStyle::Zero),
            "null" => Ok(EffortStyle::Null),
            "nan" => Ok(EffortStyle::BareNan),
            other => Err(format!("{other:?}: use empty, zero, null or nan")),
        }
    }
}

/// What a test can read back.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MockRosCounters {
    /// Velocity commands received.
    pub commands: u64,
    /// Of those, zero twists.
    pub zero_commands: u64,
    /// The last command (v, w).
    pub last_command: (f64, f64),
    /// Connections accepted.
    pub connections: u64,
    /// `set_parameters` calls answered.
    pub parameter_sets: u64,
    /// Messages received that were not rosbridge operations, or operations refused.
    pub bad_requests: u64,
    /// Status messages sent.
    pub status_sent: u64,
}

/// The simulated robot and controller.
pub struct MockRosState {
    sim: Simulator,
    controller: DiffDriveConfig,
    /// Robot time (s).
    pub time_s: f64,
    cmd: (f64, f64),
    last_cmd_s: f64,
    wheel_speed: (f64, f64),
    odo: Pose,
    angles: (f64, f64),
    /// The controller node's parameters, as `get_parameters` reads them.
    params: std::collections::BTreeMap<String, ParamValue>,
    /// Topics clients advertised, with their types: in the graph from then on.
    advertised: std::collections::BTreeMap<String, String>,
    /// Wall-clock seconds since the epoch when robot time was 0.
    epoch_s: f64,
    /// Counters.
    pub counters: MockRosCounters,
}

impl MockRosState {
    /// The robot's true pose.
    pub fn true_pose(&self) -> Pose {
        self.sim.pose()
    }

    /// The robot's true parameters.
    pub fn true_params(&self) -> WheelParams {
        *self.sim.truth()
    }

    /// Wheel speeds now (rad/s): zero when the robot stands.
    pub fn wheel_speeds(&self) -> (f64, f64) {
        self.wheel_speed
    }

    /// The geometry the running controller uses.
    pub fn configured(&self) -> WheelParams {
        self.controller.effective()
    }

    /// The controller node's parameter `name`, as `get_parameters` would answer.
    pub fn parameter(&self, name: &str) -> Option<&ParamValue> {
        self.params.get(name)
    }

    /// The wall-clock stamp of robot time `t` (s since the epoch).
    fn stamp(&self, t: f64) -> f64 {
        self.epoch_s + t
    }
}

/// A running mock server.
pub struct MockRosbridge {
    addr: SocketAddr,
    cfg: MockRosConfig,
    out: broadcast::Sender<Outgoing>,
    state: Arc<Mutex<MockRosState>>,
    listener: JoinHandle<()>,
    physics: JoinHandle<()>,
    connections: Arc<Mutex<Vec<JoinHandle<()>>>>,
}

/// A message for subscribers: topic, content, when it was made.
type Outgoing = (String, Value, tokio::time::Instant);

fn lock(s: &Mutex<MockRosState>) -> MutexGuard<'_, MockRosState> {
    s.lock().unwrap_or_else(|p| p.into_inner())
}

/// Serves one client's connection (a TCP stream or an in-memory one) in a task of its own,
/// kept with the others so that the mock ends them all when it ends.
fn serve_connection(
    wire: crate::io::transport::BoxTransport,
    cfg: &MockRosConfig,
    state: &Arc<Mutex<MockRosState>>,
    out: &broadcast::Sender<Outgoing>,
    connections: &Mutex<Vec<JoinHandle<()>>>,
) {
    let serve = conn::serve(wire, cfg.clone(), state.clone(), out.subscribe());
    let task = tokio::spawn(serve);
    connections
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .push(task);
}

impl MockRosbridge {
    /// Serves on `addr` (use port 0 for any free loopback port).
    pub async fn spawn(cfg: MockRosConfig, addr: SocketAddr) -> std::io::Result<Self> {
        if !addr.ip().is_loopback() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "the mock serves on loopback addresses only",
            ));
        }
        let configured = cfg.controller.effective();
        let sim = Simulator::new(cfg.truth, configured, cfg.noise, cfg.seed)
            .and_then(|s| s.with_heading_model(cfg.heading_model))
            .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e))?;
        let epoch_s = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0.0, |d| d.as_secs_f64());
        let state = Arc::new(Mutex::new(MockRosState {
            sim,
            params: services::controller_parameters(&cfg.controller, cfg.cmd_vel_stamped),
            advertised: Default::default(),
            epoch_s,
            controller: cfg.controller.clone(),
            time_s: 0.0,
            cmd: (0.0, 0.0),
            last_cmd_s: f64::NEG_INFINITY,
            wheel_speed: (0.0, 0.0),
            odo: Pose::default(),
            angles: (0.0, 0.0),
            counters: MockRosCounters::default(),
        }));
        let (out, _) = broadcast::channel::<Outgoing>(1 << 14);
        let listener = tokio::net::TcpListener::bind(addr).await?;
        let addr = listener.local_addr()?;
        let physics = tokio::spawn(physics(cfg.clone(), state.clone(), out.clone()));
        let connections: Arc<Mutex<Vec<JoinHandle<()>>>> = Arc::default();
        let (st, conns, topics, c) = (state.clone(), connections.clone(), out.clone(), cfg.clone());
        let listener = tokio::spawn(async move {
            while let Ok((tcp, _)) = listener.accept().await {
                serve_connection(Box::new(tcp), &c, &st, &topics, &conns);
            }
        });
        Ok(MockRosbridge {
            addr,
            cfg,
            out,
            state,
            listener,
            physics,
            connections,
        })
    }

    /// A client's connection without a socket: the client's end of an in-memory duplex, served
    /// as a TCP client is, WebSocket handshake and all
    /// ([`crate::ros::rosbridge::RosbridgeClient::connect_stream`] takes it).
    pub fn connect_in_memory(&self) -> tokio::io::DuplexStream {
        let (client, server) = crate::io::transport::pair(1 << 16);
        let (cfg, state, out) = (&self.cfg, &self.state, &self.out);
        serve_connection(Box::new(server), cfg, state, out, &self.connections);
        client
    }

    /// `rosbridge://127.0.0.1:PORT`.
    pub fn url(&self) -> String {
        format!("rosbridge://{}", self.addr)
    }

    /// The simulated robot and controller.
    pub fn state(&self) -> MutexGuard<'_, MockRosState> {
        lock(&self.state)
    }

    /// A second sensor on the robot (the `--nmea` compass beside its IMU): the true heading, to
    /// which the compass adds only its own noise; it shares none of the IMU's errors.
    pub fn separate_compass(&self) -> super::nmea::HeadingFn {
        let state = self.state.clone();
        Arc::new(move || Some(lock(&state).sim.pose().heading_rad))
    }

    /// rosbridge crashes: every connection drops and nothing listens; the robot keeps running.
    pub fn vanish(&self) {
        self.listener.abort();
        for h in self
            .connections
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .drain(..)
        {
            h.abort();
        }
    }
}

impl Drop for MockRosbridge {
    fn drop(&mut self) {
        self.vanish();
        self.physics.abort();
    }
}

fn header(t: f64, frame: &str) -> Header {
    Header {
        stamp: Time::from_seconds(t),
        frame_id: frame.into(),
    }
}

/// Advances the robot in robot time, as fast as `time_scale` asks, and publishes.
async fn physics(
    cfg: MockRosConfig,
    state: Arc<Mutex<MockRosState>>,
    out: broadcast::Sender<Outgoing>,
) {
    let dt = 1.0 / cfg.imu_hz.max(1.0);
    let every = (cfg.imu_hz / cfg.joint_hz).round().max(1.0) as u64;
    let timeout = cfg.controller.cmd_vel_timeout_s.unwrap_or(0.5);
    let start = tokio::time::Instant::now();
    let mut tick = tokio::time::interval(Duration::from_millis(1));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut step: u64 = 0;
    let mut localizer = cfg
        .localization
        .clone()
        .map(|l| localization::Localizer::new(l, cfg.seed));
    loop {
        tick.tick().await;
        let wall_target = start.elapsed().as_secs_f64() * cfg.time_scale.max(1e-3);
        let mut batch = Vec::new();
        {
            let mut s = lock(&state);
            // At most 50 ms of robot time per tick: under load the robot's clock slows instead
            // of one long batch holding the state (and flooding subscribers).
            let target = wall_target.min(s.time_s + 0.05);
            while s.time_s + dt <= target {
                s.time_s += dt;
                let t = s.time_s;
                let (twist, wheels) = drive_step(&mut s, &cfg, dt, timeout, t);
                let stamp = s.stamp(t);
                if let Some(loc) = localizer.as_mut() {
                    let truth = s.sim.pose();
                    if let Some((topic, msg)) = loc.at(t, &truth, |u| s.stamp(u)) {
                        batch.push((topic, serde_json::to_value(msg).unwrap_or(Value::Null)));
                    }
                }
                // A reading the sensor lost is a message not sent.
                if let Some(imu) = imu_message(&mut s, &cfg, stamp) {
                    batch.push(imu);
                }
                if step.is_multiple_of(every) {
                    let n = step / every;
                    if let Some(joints) = joint_state_message(&s, &cfg, t, stamp, n, wheels) {
                        batch.push(joints);
                    }
                    batch.push(odom_message(&s, stamp, twist));
                }
                step += 1;
            }
        }
        let at = tokio::time::Instant::now();
        for (topic, msg) in batch {
            let _ = out.send((topic, msg, at));
        }
    }
}

/// Moves `now` toward `want` by at most `lim * dt`, landing exactly on `want` once within reach.
fn ramp(now: f64, want: f64, lim: f64, dt: f64) -> f64 {
    // A ramp lands exactly on its target once the rest is within one step (plus rounding):
    // counting down by `lim * dt` in floating point can otherwise leave a 1e-16 residue for one
    // tick, a robot that is "still" but not at zero.
    let rest = want - now;
    let max = lim * dt;
    if rest.abs() <= max * (1.0 + 1e-9) {
        want
    } else {
        now + rest.clamp(-max, max)
    }
}

/// Runs the controller and the robot for one step at robot time `t`; returns the ramped twist
/// (v, w) and the wheel speeds (rad/s).
fn drive_step(
    s: &mut MockRosState,
    cfg: &MockRosConfig,
    dt: f64,
    timeout: f64,
    t: f64,
) -> ((f64, f64), (f64, f64)) {
    let g = s.controller.effective();
    // The controller: commands time out; wheel speeds from the configured geometry, ramped at
    // the acceleration limits.
    let (v, w) = if t - s.last_cmd_s > timeout {
        (0.0, 0.0)
    } else {
        s.cmd
    };
    let (sl, sr) = g.travel_m(s.wheel_speed.0, s.wheel_speed.1);
    let now = Displacement::of_wheels(sl, sr, g.wheelbase_m);
    let (v1, w1) = (
        ramp(now.distance_m, v, cfg.accel_limit_m_s2, dt),
        ramp(now.turn_rad, w, cfg.alpha_limit_rad_s2, dt),
    );
    let (l1, r1) = Displacement {
        distance_m: v1,
        turn_rad: w1,
    }
    .wheels(g.wheelbase_m);
    let (wl, wr) = (l1 / g.left_m_per_count(), r1 / g.right_m_per_count());
    s.wheel_speed = (wl, wr);
    let (dl, dr) = (wl * dt, wr * dt);
    s.sim.step_counts(dl, dr);
    s.angles.0 += dl;
    s.angles.1 += dr;
    s.odo = g.odometry_step(&s.odo, dl, dr);
    s.sim.set_time(t);
    ((v1, w1), (wl, wr))
}

/// The `/imu` message stamped `stamp`, or none when the sensor lost the reading.
fn imu_message(s: &mut MockRosState, cfg: &MockRosConfig, stamp: f64) -> Option<(String, Value)> {
    let yaw = s.sim.heading_reading()?;
    let unknown = if cfg.effort == EffortStyle::BareNan {
        [f64::NAN; 9]
    } else {
        [0.0; 9]
    };
    Some((
        "/imu".to_string(),
        serde_json::to_value(Imu {
            header: header(stamp, "imu_link"),
            orientation: Quaternion::from_yaw(yaw),
            angular_velocity_covariance: unknown,
            ..Imu::default()
        })
        .unwrap_or(Value::Null),
    ))
}

/// The `n`th `/joint_states` message at robot time `t`, with the configured glitches and
/// effort; none once the driver has stopped publishing.
fn joint_state_message(
    s: &MockRosState,
    cfg: &MockRosConfig,
    t: f64,
    stamp: f64,
    n: u64,
    (wl, wr): (f64, f64),
) -> Option<(String, Value)> {
    let names = (
        s.controller
            .left_wheel_names
            .first()
            .cloned()
            .unwrap_or("left_wheel_joint".into()),
        s.controller
            .right_wheel_names
            .first()
            .cloned()
            .unwrap_or("right_wheel_joint".into()),
    );
    let publishing = cfg.joint_states_stop_after_s.is_none_or(|stop| t < stop);
    if !publishing {
        return None;
    }
    let glitch = cfg.joint_glitch_every.filter(|&g| g > 0);
    let spike = glitch.is_some_and(|g| n % g == g - 1);
    let back = glitch.is_some_and(|g| n.is_multiple_of(g) && n > 0);
    let stamp = if back { s.stamp(t - 0.1) } else { stamp };
    let effort = match cfg.effort {
        EffortStyle::Empty => vec![],
        EffortStyle::Zero => vec![0.0, 0.0],
        EffortStyle::Null | EffortStyle::BareNan => vec![f64::NAN; 2],
    };
    Some((
        "/joint_states".to_string(),
        serde_json::to_value(JointState {
            header: header(stamp, ""),
            name: vec![names.0, names.1],
            position: if cfg.frozen_joint_states {
                vec![0.0, 0.0]
            } else if spike {
                vec![s.angles.0 + 3.0, s.angles.1]
            } else {
                vec![s.angles.0, s.angles.1]
            },
            velocity: vec![wl, wr],
            effort,
        })
        .unwrap_or(Value::Null),
    ))
}

/// The controller's `/odom` message stamped `stamp`, moving at the twist (v, w).
fn odom_message(s: &MockRosState, stamp: f64, (v1, w1): (f64, f64)) -> (String, Value) {
    let mut o = Odometry {
        header: header(stamp, "odom"),
        child_frame_id: "base_link".into(),
        ..Odometry::default()
    };
    o.pose.pose.position.x = s.odo.x_m;
    o.pose.pose.position.y = s.odo.y_m;
    o.pose.pose.orientation = Quaternion::from_yaw(s.odo.heading_rad);
    o.twist.twist = Twist::planar(v1, w1);
    (
        "/odom".to_string(),
        serde_json::to_value(o).unwrap_or(Value::Null),
    )
}
