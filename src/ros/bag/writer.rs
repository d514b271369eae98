//! Writing ROS 2 bags (MCAP, CDR) with the topics odocal reads: simulated square tests and
//! recorded OptiOdom sets, so a user can see what to record and tests can check `odocal bag`.

use super::{BagError, RosTopics};
use crate::calibration::pose_reference::{PoseRecording, ReferencePose};
use crate::calibration::recording::Recording;
use crate::calibration::HeadingKind;
use crate::kinematics::{wrap_angle, Direction, WheelParams};
use crate::ros::msg::{
    cdr, types, Header, Imu, JointState, Odometry, PoseStamped, PoseWithCovarianceStamped,
    Quaternion, Time,
};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Writes ROS 2 bags (MCAP, CDR) with the topics odocal reads.
pub struct BagWriter {
    path: PathBuf,
    writer: mcap::Writer<std::io::BufWriter<std::fs::File>>,
    channels: BTreeMap<&'static str, u16>,
    /// Channels added by topic ([`Self::add_topic`]).
    topics: BTreeMap<String, u16>,
    sequence: u32,
}

impl BagWriter {
    /// Creates `path` (which must not exist yet).
    pub fn create(path: &Path, topics: &RosTopics) -> Result<Self, BagError> {
        let file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(path)
            .map_err(|source| BagError::Io {
                path: path.to_path_buf(),
                source,
            })?;
        let werr = |source| BagError::Write {
            path: path.to_path_buf(),
            source,
        };
        let mut writer = mcap::WriteOptions::new()
            .profile("ros2")
            .create(std::io::BufWriter::new(file))
            .map_err(werr)?;
        let mut channels = BTreeMap::new();
        for (kind, topic) in [
            (types::JOINT_STATE, &topics.joint_states),
            (types::IMU, &topics.imu),
            (types::ODOMETRY, &topics.odom),
        ] {
            let schema = writer
                .add_schema(kind, "ros2msg", types::definition(kind).as_bytes())
                .map_err(werr)?;
            let ch = writer
                .add_channel(schema, topic, "cdr", &BTreeMap::new())
                .map_err(werr)?;
            channels.insert(kind, ch);
        }
        Ok(BagWriter {
            path: path.to_path_buf(),
            writer,
            channels,
            topics: BTreeMap::new(),
            sequence: 0,
        })
    }

    /// Adds `topic` carrying `kind` (a [`types`] name).
    pub fn add_topic(&mut self, kind: &'static str, topic: &str) -> Result<(), BagError> {
        let ch = self.channel(kind, topic)?;
        self.topics.insert(topic.to_string(), ch);
        Ok(())
    }

    /// Writes `msg` at `t` on a topic added by [`Self::add_topic`].
    pub fn write_topic<T: Serialize>(
        &mut self,
        topic: &str,
        t: f64,
        msg: &T,
    ) -> Result<(), BagError> {
        let Some(&channel_id) = self.topics.get(topic) else {
            return Err(BagError::Inference(format!(
                "topic {topic} was not added to the bag being written"
            )));
        };
        self.write_channel(channel_id, topic, t, msg)
    }

    fn write<T: Serialize>(&mut self, kind: &'static str, t: f64, msg: &T) -> Result<(), BagError> {
        let channel_id = self.channels[kind];
        self.write_channel(channel_id, kind, t, msg)
    }

    fn write_channel<T: Serialize>(
        &mut self,
        channel_id: u16,
        kind: &str,
        t: f64,
        msg: &T,
    ) -> Result<(), BagError> {
        let data = cdr::encode(msg).map_err(|source| BagError::Decode {
            topic: kind.into(),
            index: self.sequence as usize,
            source: source.into(),
        })?;
        let ns = (t.max(0.0) * 1e9) as u64;
        self.sequence += 1;
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time: ns,
            publish_time: ns,
        };
        self.writer
            .write_to_known_channel(&header, &data)
            .map_err(|source| BagError::Write {
                path: self.path.clone(),
                source,
            })
    }

    /// Adds a pose reference's topic of type `kind` (`PoseStamped`, `PoseWithCovarianceStamped`
    /// or `Odometry`, [`types`]) to a new writer; `Odometry` replaces the odometry's own topic.
    pub fn add_reference(&mut self, kind: &'static str, topic: &str) -> Result<(), BagError> {
        let ch = self.channel(kind, topic)?;
        self.channels.insert(kind, ch);
        Ok(())
    }

    /// A new channel for `topic` carrying `kind`, with its schema.
    fn channel(&mut self, kind: &'static str, topic: &str) -> Result<u16, BagError> {
        let werr = |source| BagError::Write {
            path: self.path.clone(),
            source,
        };
        let schema = self
            .writer
            .add_schema(kind, "ros2msg", types::definition(kind).as_bytes())
            .map_err(werr)?;
        self.writer
            .add_channel(schema, topic, "cdr", &BTreeMap::new())
            .map_err(werr)
    }

    /// Writes one reference pose on the topic of `kind` added by [`Self::add_reference`], in
    /// `frame` (its stated standard deviations, if any, as the covariance's diagonal).
    pub fn reference(
        &mut self,
        kind: &'static str,
        frame: &str,
        p: &ReferencePose,
    ) -> Result<(), BagError> {
        let header = Header {
            stamp: Time::from_seconds(p.time_s),
            frame_id: frame.into(),
        };
        let mut pose = crate::ros::msg::Pose::default();
        pose.position.x = p.x_m;
        pose.position.y = p.y_m;
        pose.orientation = Quaternion::from_yaw(p.yaw_rad.unwrap_or(0.0));
        let mut covariance = crate::ros::msg::Covariance36::default();
        if let Some([sx, sy, syaw]) = p.stated_std {
            covariance.0[0] = sx * sx;
            covariance.0[7] = sy * sy;
            covariance.0[35] = syaw * syaw;
        }
        match kind {
            types::POSE_STAMPED => self.write(kind, p.time_s, &PoseStamped { header, pose }),
            types::POSE_WITH_COVARIANCE_STAMPED => {
                let msg = PoseWithCovarianceStamped {
                    header,
                    pose: crate::ros::msg::PoseWithCovariance { pose, covariance },
                };
                self.write(kind, p.time_s, &msg)
            }
            _ => {
                let mut msg = Odometry {
                    header,
                    child_frame_id: "base_link".into(),
                    ..Odometry::default()
                };
                msg.pose.pose = pose;
                msg.pose.covariance = covariance;
                self.write(types::ODOMETRY, p.time_s, &msg)
            }
        }
    }

    /// Writes wheel joint angles (rad) at `t` (s).
    pub fn joints(&mut self, t: f64, left_rad: f64, right_rad: f64) -> Result<(), BagError> {
        let msg = JointState {
            header: Header {
                stamp: Time::from_seconds(t),
                frame_id: String::new(),
            },
            name: vec!["left_wheel_joint".into(), "right_wheel_joint".into()],
            position: vec![left_rad, right_rad],
            velocity: vec![],
            effort: vec![],
        };
        self.write(types::JOINT_STATE, t, &msg)
    }

    /// Writes an IMU yaw (rad) at `t`.
    pub fn imu(&mut self, t: f64, yaw_rad: f64) -> Result<(), BagError> {
        let msg = Imu {
            header: Header {
                stamp: Time::from_seconds(t),
                frame_id: "imu_link".into(),
            },
            orientation: Quaternion::from_yaw(yaw_rad),
            ..Imu::default()
        };
        self.write(types::IMU, t, &msg)
    }

    /// Writes the controller's odometry pose at `t`.
    pub fn odom(&mut self, t: f64, x_m: f64, y_m: f64, yaw_rad: f64) -> Result<(), BagError> {
        let mut msg = Odometry {
            header: Header {
                stamp: Time::from_seconds(t),
                frame_id: "odom".into(),
            },
            child_frame_id: "base_link".into(),
            ..Odometry::default()
        };
        msg.pose.pose.position.x = x_m;
        msg.pose.pose.position.y = y_m;
        msg.pose.pose.orientation = Quaternion::from_yaw(yaw_rad);
        self.write(types::ODOMETRY, t, &msg)
    }

    /// Records what `odocal bag` cannot find in the messages, in the metadata record `odocal`:
    /// the square side (`side_m`) and what the IMU's yaw is (`heading_kind`: magnetic, gyro or
    /// reference), which decides the default method as it does for `calibrate` and `replay`.
    pub fn describe(
        &mut self,
        side_m: Option<f64>,
        heading_kind: crate::calibration::HeadingKind,
    ) -> Result<(), BagError> {
        let mut record = BTreeMap::from([("heading_kind".to_string(), heading_kind.to_string())]);
        if let Some(side_m) = side_m {
            record.insert("side_m".to_string(), format!("{side_m}"));
        }
        let metadata = mcap::records::Metadata {
            name: "odocal".into(),
            metadata: record,
        };
        self.writer
            .write_metadata(&metadata)
            .map_err(|source| BagError::Write {
                path: self.path.clone(),
                source,
            })
    }

    /// Finishes the file (summary, indexes).
    pub fn finish(mut self) -> Result<(), BagError> {
        self.writer.finish().map_err(|source| BagError::Write {
            path: self.path.clone(),
            source,
        })?;
        Ok(())
    }
}

/// Rates and speeds of a simulated square-test bag.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimulatedBag {
    /// Square side (m).
    pub side_m: f64,
    /// Runs per direction.
    pub runs: usize,
    /// Leg speed (m/s).
    pub speed_m_s: f64,
    /// Turn rate (rad/s).
    pub rate_rad_s: f64,
    /// Joint state and odometry rate (Hz).
    pub joint_hz: f64,
    /// IMU rate (Hz); a multiple of `joint_hz`.
    pub imu_hz: f64,
    /// Rest before and after each square (s).
    pub rest_s: f64,
}

impl Default for SimulatedBag {
    fn default() -> Self {
        SimulatedBag {
            side_m: 2.0,
            runs: 5,
            speed_m_s: 0.3,
            rate_rad_s: 0.8,
            joint_hz: 50.0,
            imu_hz: 100.0,
            rest_s: 1.5,
        }
    }
}

/// Drives `sim` (whose parameters count wheel angles in radians: counts per revolution 2π)
/// through `cfg.runs` squares each way and writes what a ROS robot would publish: joint
/// angles, IMU yaw (the simulator's compass, with its noise) and the controller's odometry.
pub fn write_simulated_bag(
    path: &Path,
    sim: &mut crate::sim::Simulator,
    cfg: &SimulatedBag,
    topics: &RosTopics,
) -> Result<u64, BagError> {
    let mut w = BagWriter::create(path, topics)?;
    w.describe(Some(cfg.side_m), sim.heading_model().kind.into())?;
    let configured = *sim.configured();
    let sub = (cfg.imu_hz / cfg.joint_hz).round().max(1.0) as u64;
    let dt = 1.0 / (cfg.joint_hz * sub as f64);
    let mut t = 0.0;
    let mut step = 0u64;
    let mut odo = crate::kinematics::Pose::default();
    let mut last = sim.encoder_counts();
    let mut messages = 0u64;
    // One time step: IMU every step, joints and odometry every `sub` steps.
    let mut emit =
        |w: &mut BagWriter, sim: &mut crate::sim::Simulator, t: f64| -> Result<(), BagError> {
            // The sensor's clock is the bag's: a late sensor shows the robot `latency` ago, a
            // lost reading is a message not written.
            sim.set_time(t);
            if let Some(yaw) = sim.heading_reading() {
                w.imu(t, yaw)?;
                messages += 1;
            }
            if step.is_multiple_of(sub) {
                let (l, r) = sim.encoder_counts();
                odo = configured.odometry_step(&odo, l - last.0, r - last.1);
                last = (l, r);
                w.joints(t, l, r)?;
                w.odom(t, odo.x_m, odo.y_m, odo.heading_rad)?;
                messages += 2;
            }
            step += 1;
            Ok(())
        };
    for direction in [Direction::Cw, Direction::Ccw] {
        for _ in 0..cfg.runs {
            for _ in 0..(cfg.rest_s / dt).round() as u64 {
                emit(&mut w, sim, t)?;
                t += dt;
            }
            for motion in crate::sim::Simulator::square_motions(cfg.side_m, direction) {
                let duration = match motion {
                    crate::sim::Motion::Straight { distance_m } => distance_m.abs() / cfg.speed_m_s,
                    crate::sim::Motion::TurnInPlace { angle_rad } => {
                        angle_rad.abs() / cfg.rate_rad_s
                    }
                    crate::sim::Motion::Wheels { .. } => 0.0,
                };
                let plan = sim.plan(&motion).map_err(|e| {
                    BagError::Inference(format!("the simulator refused a motion: {e}"))
                })?;
                let n = (duration / dt).ceil().max(1.0) as u64;
                for k in 0..n {
                    sim.advance_plan(&plan, k as f64 / n as f64, (k + 1) as f64 / n as f64);
                    t += dt;
                    emit(&mut w, sim, t)?;
                }
                // A short pause between motions, as a controller brakes.
                for _ in 0..(0.2 / dt).round() as u64 {
                    t += dt;
                    emit(&mut w, sim, t)?;
                }
            }
        }
    }
    for _ in 0..(cfg.rest_s / dt).round() as u64 {
        t += dt;
        emit(&mut w, sim, t)?;
    }
    w.finish()?;
    Ok(messages)
}

/// Writes a recording as a ROS 2 bag: its wheel travel as wheel joint angles (under the
/// `configured` wheels, which the travel was counted with), its headings as the IMU (of
/// `kind`), and the controller's odometry integrated with `configured`, all in the time order
/// of the recording's samples (one clock: [`Recording::clocks`] must be shared). `odocal bag`
/// on the result calibrates as the recording does. `side_m` is the square's side, when the
/// recording is of squares. Returns the messages written.
pub fn write_recording_bag(
    path: &Path,
    (recording, configured): (&Recording, &WheelParams),
    (side_m, kind): (Option<f64>, HeadingKind),
    topics: &RosTopics,
) -> Result<u64, BagError> {
    let mut w = BagWriter::create(path, topics)?;
    w.describe(side_m, kind)?;
    let (left_rad_per_m, right_rad_per_m) = (
        2.0 / configured.left_wheel_diameter_m,
        2.0 / configured.right_wheel_diameter_m,
    );
    let (mut l, mut r) = (0.0, 0.0);
    let mut odo = crate::kinematics::Pose::default();
    let mut messages = 0u64;
    let mut headings = recording.headings.iter().peekable();
    for t in &recording.travel {
        // Headings up to this travel sample's time go first (the merged order).
        while let Some(h) = headings.next_if(|h| h.time_s <= t.time_s) {
            w.imu(h.time_s, wrap_angle(h.heading_rad))?;
            messages += 1;
        }
        l += t.left_m * left_rad_per_m;
        r += t.right_m * right_rad_per_m;
        odo = odo.advance(t.left_m, t.right_m, configured.wheelbase_m);
        w.joints(t.time_s, l, r)?;
        w.odom(t.time_s, odo.x_m, odo.y_m, odo.heading_rad)?;
        messages += 2;
    }
    for h in headings {
        w.imu(h.time_s, wrap_angle(h.heading_rad))?;
        messages += 1;
    }
    w.finish()?;
    Ok(messages)
}

/// Writes a drive with a pose reference as a ROS 2 bag (MCAP): the wheels on
/// `/joint_states`, the reference on `topic` as `kind` (a [`types`] name) stamped `t0_s` later
/// than the recording's times (a ROS clock does not start at zero).
pub fn write_pose_drive_bag(
    path: &Path,
    recording: &PoseRecording,
    kind: &'static str,
    topic: &str,
    t0_s: f64,
) -> Result<(), BagError> {
    let topics = RosTopics {
        odom: if kind == types::ODOMETRY {
            topic.to_string()
        } else {
            RosTopics::default().odom
        },
        ..RosTopics::default()
    };
    let mut w = BagWriter::create(path, &topics)?;
    if kind != types::ODOMETRY {
        w.add_reference(kind, topic)?;
    }
    let (mut wi, mut pi) = (0, 0);
    let (wheels, poses) = (&recording.wheels, &recording.poses);
    // Both streams in time order, as a recorder writes them.
    while wi < wheels.len() || pi < poses.len() {
        let wheel_first =
            pi >= poses.len() || (wi < wheels.len() && wheels[wi].time_s <= poses[pi].time_s);
        if wheel_first {
            let s = &wheels[wi];
            w.joints(t0_s + s.time_s, s.left_rad, s.right_rad)?;
            wi += 1;
        } else {
            let p = ReferencePose {
                time_s: t0_s + poses[pi].time_s,
                ..poses[pi]
            };
            w.reference(kind, "map", &p)?;
            pi += 1;
        }
    }
    w.finish()
}

/// Writes a drive under a localization as a ROS 2 bag (MCAP), as AMCL leaves one: the wheels
/// on `/joint_states`, the controller's odometry `odom → base_link` on `/tf` at every wheel
/// sample (integrated with `controller`), at every reference stamp the localization's
/// correction `map → odom` on `/tf` (so that the chain `map → base_link` there is the
/// reference's pose) and the pose itself on `/amcl_pose` (`PoseWithCovarianceStamped`), and a
/// static `base_link → laser` on `/tf_static`; stamps `t0_s` later than the recording's times.
pub fn write_localization_bag(
    path: &Path,
    recording: &PoseRecording,
    controller: crate::calibration::pose_reference::Geometry,
    t0_s: f64,
) -> Result<(), BagError> {
    use crate::calibration::pose_reference::{Odometry as Dead, Pose2};
    use crate::ros::msg::{TfMessage, Transform, TransformStamped, Vector3};
    let mut w = BagWriter::create(path, &RosTopics::default())?;
    w.add_reference(types::POSE_WITH_COVARIANCE_STAMPED, "/amcl_pose")?;
    w.add_topic(types::TF_MESSAGE, "/tf")?;
    w.add_topic(types::TF_MESSAGE, "/tf_static")?;
    let tf = |t: f64, parent: &str, child: &str, p: Pose2| TfMessage {
        transforms: vec![TransformStamped {
            header: Header {
                stamp: Time::from_seconds(t),
                frame_id: parent.into(),
            },
            child_frame_id: child.into(),
            transform: Transform {
                translation: Vector3 {
                    x: p.x,
                    y: p.y,
                    z: 0.0,
                },
                rotation: Quaternion::from_yaw(wrap_angle(p.theta)),
            },
        }],
    };
    let laser = Pose2 {
        x: 0.2,
        y: 0.0,
        theta: 0.0,
    };
    w.write_topic("/tf_static", t0_s, &tf(t0_s, "base_link", "laser", laser))?;
    let odo = Dead::integrate(&recording.wheels, controller);
    let (wheels, poses) = (&recording.wheels, &recording.poses);
    let (mut wi, mut pi, mut hint) = (0, 0, 0);
    while wi < wheels.len() || pi < poses.len() {
        let wheel_first =
            pi >= poses.len() || (wi < wheels.len() && wheels[wi].time_s <= poses[pi].time_s);
        if wheel_first {
            let s = &wheels[wi];
            let t = t0_s + s.time_s;
            w.joints(t, s.left_rad, s.right_rad)?;
            w.write_topic("/tf", t, &tf(t, "odom", "base_link", odo.poses()[wi]))?;
            wi += 1;
        } else {
            let p = &poses[pi];
            pi += 1;
            // The controller's odometry at the reference's stamp, as a TF listener would
            // interpolate it; outside the wheels' span there is no correction to publish.
            let Some(o) = odo.at(p.time_s, &mut hint) else {
                continue;
            };
            let correction = p.pose2().compose(&o.between(&Pose2::default()));
            let t = t0_s + p.time_s;
            w.write_topic("/tf", t, &tf(t, "map", "odom", correction))?;
            let stamped = ReferencePose { time_s: t, ..*p };
            w.reference(types::POSE_WITH_COVARIANCE_STAMPED, "map", &stamped)?;
        }
    }
    w.finish()
}
