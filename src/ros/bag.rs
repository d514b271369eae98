//! Offline calibration from a ROS 2 bag (MCAP): read wheel joint angles, IMU yaw and the
//! controller's odometry, find the square runs in the data, and estimate with every method and
//! the online filter. [`super::bag_writer`] writes such bags (simulated tests, converted
//! recordings).
//!
//! Square runs are found from the wheels, not from timing: each joint sample is at rest,
//! driving straight or turning in place (by the robot's own odometry with the configured
//! geometry); a run is a stretch between two rests of at least `min_rest_s` whose odometry
//! turns about ±360° in four ±90° turns between four legs. Its heading error is the IMU's yaw
//! change (circular means over the rests before and after) minus the odometry's turn over the
//! run — a real run does not turn exactly ±360°, so this removes the controller's execution
//! error, as `replay` does for recorded sets. Writing bags is [`super::bag_writer`]'s job.

use super::msg::{cdr, types, yaw_of, Header, Imu, JointState, Odometry};
use super::yaml::RAD_PER_REV;
use crate::calibration::online::{
    Excitation, GateStats, OnlineConfig, OnlineEstimate, OnlineEstimator, ScaleSource,
};
use crate::calibration::time_offset::{estimate_time_offset, TimeOffset};
use crate::calibration::{estimate_all, Estimate, Method, RunMeasurement, SquareTest};
use crate::kinematics::{wrap_angle, Direction, SplitConvention, WheelParams};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Largest bag read into memory (4 GiB); larger ones need splitting (`ros2 bag convert`).
pub const MAX_BAG_BYTES: u64 = 4 << 30;

/// Errors reading or analysing a bag.
#[derive(Debug, thiserror::Error)]
pub enum BagError {
    /// The file cannot be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// Not a readable MCAP file.
    #[error("{}: not a readable MCAP bag: {source}", path.display())]
    Mcap {
        /// The file.
        path: PathBuf,
        /// The reader's error.
        #[source]
        source: mcap::McapError,
    },
    /// A topic odocal needs is not in the bag.
    #[error(
        "the bag has no {what} topic `{topic}`; its topics are: {}",
        list_topics(available)
    )]
    MissingTopic {
        /// What the topic is for.
        what: &'static str,
        /// The topic looked for.
        topic: String,
        /// (topic, type) of every channel in the bag.
        available: Vec<(String, String)>,
    },
    /// A needed topic carries a type odocal does not decode.
    #[error("topic `{topic}` carries `{type_name}` ({encoding}); odocal reads {expected} in CDR")]
    UnknownType {
        /// The topic.
        topic: String,
        /// Its schema name.
        type_name: String,
        /// Its message encoding.
        encoding: String,
        /// What odocal reads on it.
        expected: &'static str,
    },
    /// A message does not decode.
    #[error("topic `{topic}` message {index}: {source}")]
    Decode {
        /// The topic.
        topic: String,
        /// 0-based message index on the topic.
        index: usize,
        /// Why.
        #[source]
        source: cdr::CdrError,
    },
    /// The wheel joints cannot be identified.
    #[error("cannot tell the wheel joints in `{topic}` (names: {}); give them (--left-joint/--right-joint or the YAML's left/right_wheel_names)", names.join(", "))]
    Joints {
        /// The topic.
        topic: String,
        /// The joint names seen.
        names: Vec<String>,
    },
    /// The configured geometry cannot be inferred.
    #[error("cannot infer the configured geometry: {0}; give the controller's YAML")]
    Inference(String),
    /// A time range is not usable.
    #[error("time range {0}")]
    Range(String),
    /// Writing a bag failed.
    #[error("writing {}: {source}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: mcap::McapError,
    },
}

fn list_topics(t: &[(String, String)]) -> String {
    if t.is_empty() {
        return "none".into();
    }
    t.iter()
        .map(|(n, ty)| format!("{n} ({ty})"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Topic names (ROS defaults).
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
#[serde(default)]
pub struct RosTopics {
    /// `sensor_msgs/JointState` with the wheel joints.
    pub joint_states: String,
    /// `sensor_msgs/Imu` with an orientation.
    pub imu: String,
    /// `nav_msgs/Odometry` from the controller.
    pub odom: String,
}

impl Default for RosTopics {
    fn default() -> Self {
        RosTopics {
            joint_states: "/joint_states".into(),
            imu: "/imu".into(),
            odom: "/odom".into(),
        }
    }
}

/// How to read and segment a bag.
#[derive(Debug, Clone, PartialEq)]
pub struct BagOptions {
    /// Topics.
    pub topics: RosTopics,
    /// Left wheel joint (default: the one name containing "left").
    pub left_joint: Option<String>,
    /// Right wheel joint (default: the one name containing "right").
    pub right_joint: Option<String>,
    /// Shortest rest that separates runs (s).
    pub min_rest_s: f64,
    /// Explicit runs as (start, end) seconds from the bag's first message; empty: find them.
    pub ranges: Vec<(f64, f64)>,
    /// Square side (m); `None`: the mean leg length by odometry (or the bag's metadata).
    pub side_m: Option<f64>,
    /// Split convention for `E_b`.
    pub convention: SplitConvention,
}

impl Default for BagOptions {
    fn default() -> Self {
        BagOptions {
            topics: RosTopics::default(),
            left_joint: None,
            right_joint: None,
            min_rest_s: 0.5,
            ranges: Vec::new(),
            side_m: None,
            convention: SplitConvention::LeftNominal,
        }
    }
}

/// Wheel angles at one time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointSample {
    /// Time (s from the bag's first message).
    pub t: f64,
    /// Left wheel angle (rad).
    pub left_rad: f64,
    /// Right wheel angle (rad).
    pub right_rad: f64,
}

/// An IMU yaw reading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct YawSample {
    /// Time (s).
    pub t: f64,
    /// Yaw (rad), or `None` when the message carries no usable orientation.
    pub yaw_rad: Option<f64>,
}

/// A controller odometry reading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OdomSample {
    /// Time (s).
    pub t: f64,
    /// x (m).
    pub x_m: f64,
    /// y (m).
    pub y_m: f64,
    /// Yaw (rad).
    pub yaw_rad: f64,
}

/// What odocal reads from a bag.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BagData {
    /// Wheel joints, in time order.
    pub joints: Vec<JointSample>,
    /// IMU yaw, in time order.
    pub imu: Vec<YawSample>,
    /// Controller odometry, in time order (may be empty).
    pub odom: Vec<OdomSample>,
    /// Every channel: (topic, type).
    pub topics: Vec<(String, String)>,
    /// Messages read on the three topics.
    pub messages: u64,
    /// `odocal.side_m` from the bag's metadata, if a tool of ours wrote it.
    pub side_m: Option<f64>,
    /// Choices made while reading (a topic found by its type).
    pub notes: Vec<String>,
}

fn stamp_or(h: &Header, log_time_ns: u64) -> f64 {
    if h.stamp.sec != 0 || h.stamp.nanosec != 0 {
        h.stamp.seconds()
    } else {
        log_time_ns as f64 * 1e-9
    }
}

fn pick_joint(names: &[String], given: &Option<String>, side: &str) -> Option<usize> {
    match given {
        Some(g) => names.iter().position(|n| n == g),
        None => {
            let hits: Vec<usize> = names
                .iter()
                .enumerate()
                .filter(|(_, n)| n.to_ascii_lowercase().contains(side))
                .map(|(i, _)| i)
                .collect();
            (hits.len() == 1).then(|| hits[0])
        }
    }
}

/// Reads the wheel joints, IMU and odometry from a bag.
pub fn read_bag(path: &Path, opts: &BagOptions) -> Result<BagData, BagError> {
    let io = |source| BagError::Io {
        path: path.to_path_buf(),
        source,
    };
    let bytes = crate::base::files::read_bounded_bytes(path, MAX_BAG_BYTES).map_err(io)?;
    read_bag_bytes(&bytes, path, opts)
}

fn check_type(
    topic: &str,
    ch: &mcap::Channel<'_>,
    canonical: &'static str,
) -> Result<(), BagError> {
    let name = ch
        .schema
        .as_ref()
        .map(|s| s.name.clone())
        .unwrap_or_default();
    if types::is(&name, canonical) && ch.message_encoding == "cdr" {
        Ok(())
    } else {
        Err(BagError::UnknownType {
            topic: topic.into(),
            type_name: name,
            encoding: ch.message_encoding.clone(),
            expected: canonical,
        })
    }
}

/// [`read_bag`] from bytes in memory.
pub fn read_bag_bytes(bytes: &[u8], path: &Path, opts: &BagOptions) -> Result<BagData, BagError> {
    let mcap_err = |source| BagError::Mcap {
        path: path.to_path_buf(),
        source,
    };
    let mut notes = Vec::new();
    let topics = resolve_topics(bytes, &opts.topics, &mut notes);
    let t = &topics;
    let mut data = BagData::default();
    let mut channels: BTreeMap<String, String> = BTreeMap::new();
    let mut counts = [0usize; 3];
    let mut wheel_names: Option<(String, String)> = None;
    let mut seen_names: Vec<String> = Vec::new();
    let mut t0: Option<f64> = None;
    let mut raw_joints = Vec::new();
    let mut raw_imu = Vec::new();
    let mut raw_odom = Vec::new();
    for m in mcap::MessageStream::new(bytes).map_err(mcap_err)? {
        let m = m.map_err(mcap_err)?;
        let topic = m.channel.topic.as_str();
        if !channels.contains_key(topic) {
            let ty = m
                .channel
                .schema
                .as_ref()
                .map(|s| s.name.clone())
                .unwrap_or_default();
            channels.insert(topic.to_string(), ty);
        }
        let which = if topic == t.joint_states {
            0
        } else if topic == t.imu {
            1
        } else if topic == t.odom {
            2
        } else {
            continue;
        };
        let index = counts[which];
        counts[which] += 1;
        data.messages += 1;
        let decode_err = |source| BagError::Decode {
            topic: topic.to_string(),
            index,
            source,
        };
        match which {
            0 => {
                if index == 0 {
                    check_type(topic, &m.channel, types::JOINT_STATE)?;
                }
                let js: JointState = cdr::decode(&m.data).map_err(decode_err)?;
                // The wheels are found by name once; a message of another joint group (one
                // that does not name them) is skipped.
                let ix = match &wheel_names {
                    Some((ln, rn)) => js
                        .name
                        .iter()
                        .position(|n| n == ln)
                        .zip(js.name.iter().position(|n| n == rn)),
                    None => {
                        let l = pick_joint(&js.name, &opts.left_joint, "left");
                        let r = pick_joint(&js.name, &opts.right_joint, "right");
                        match (l, r) {
                            (Some(l), Some(r)) if l != r => {
                                wheel_names = Some((js.name[l].clone(), js.name[r].clone()));
                                Some((l, r))
                            }
                            _ => {
                                seen_names.clone_from(&js.name);
                                None
                            }
                        }
                    }
                };
                if let Some((l, r)) = ix {
                    if let (Some(&lp), Some(&rp)) = (js.position.get(l), js.position.get(r)) {
                        if lp.is_finite() && rp.is_finite() {
                            // Unwrapped against the previous sample (a wrapping driver).
                            let (ul, ur) = match raw_joints.last() {
                                Some(&(_, l0, r0, pl, pr)) => (
                                    l0 + super::msg::angle_step(pl, lp),
                                    r0 + super::msg::angle_step(pr, rp),
                                ),
                                None => (lp, rp),
                            };
                            raw_joints.push((stamp_or(&js.header, m.log_time), ul, ur, lp, rp));
                        }
                    }
                }
            }
            1 => {
                if index == 0 {
                    check_type(topic, &m.channel, types::IMU)?;
                }
                let imu: Imu = cdr::decode(&m.data).map_err(decode_err)?;
                let yaw = if imu.orientation_covariance[0] == -1.0 {
                    None
                } else {
                    yaw_of(&imu.orientation).ok()
                };
                raw_imu.push((stamp_or(&imu.header, m.log_time), yaw));
            }
            _ => {
                if index == 0 {
                    check_type(topic, &m.channel, types::ODOMETRY)?;
                }
                let o: Odometry = cdr::decode(&m.data).map_err(decode_err)?;
                if let Ok(yaw) = yaw_of(&o.pose.pose.orientation) {
                    raw_odom.push((
                        stamp_or(&o.header, m.log_time),
                        o.pose.pose.position.x,
                        o.pose.pose.position.y,
                        yaw,
                    ));
                }
            }
        }
        let first = match which {
            0 => raw_joints.last().map(|j: &(f64, f64, f64, f64, f64)| j.0),
            1 => raw_imu.last().map(|j| j.0),
            _ => raw_odom.last().map(|j| j.0),
        };
        if let Some(f) = first {
            t0 = Some(t0.map_or(f, |t0: f64| t0.min(f)));
        }
    }
    data.topics = channels.into_iter().collect();
    let missing = |what, topic: &str| BagError::MissingTopic {
        what,
        topic: topic.into(),
        available: data.topics.clone(),
    };
    if counts[0] == 0 {
        return Err(missing("wheel joint", &t.joint_states));
    }
    if raw_joints.is_empty() {
        return Err(BagError::Joints {
            topic: t.joint_states.clone(),
            names: seen_names,
        });
    }
    if counts[1] == 0 {
        return Err(missing("IMU", &t.imu));
    }
    let t0 = t0.unwrap_or(0.0);
    let by_time = |a: &f64, b: &f64| a.total_cmp(b);
    raw_joints.sort_by(|a, b| by_time(&a.0, &b.0));
    raw_imu.sort_by(|a, b| by_time(&a.0, &b.0));
    raw_odom.sort_by(|a, b| by_time(&a.0, &b.0));
    data.joints = raw_joints
        .into_iter()
        .map(|(t, l, r, _, _)| JointSample {
            t: t - t0,
            left_rad: l,
            right_rad: r,
        })
        .collect();
    data.imu = raw_imu
        .into_iter()
        .map(|(t, yaw_rad)| YawSample { t: t - t0, yaw_rad })
        .collect();
    data.odom = raw_odom
        .into_iter()
        .map(|(t, x_m, y_m, yaw_rad)| OdomSample {
            t: t - t0,
            x_m,
            y_m,
            yaw_rad,
        })
        .collect();
    data.side_m = read_side_metadata(bytes);
    data.notes = notes;
    Ok(data)
}

/// The topics to read: as given, or — when a given topic is not in the bag and exactly one
/// channel carries the type it should — that channel (with a note saying so). Needs the bag's
/// summary (rosbag2 writes one); without it the names are used as given.
fn resolve_topics(bytes: &[u8], given: &RosTopics, notes: &mut Vec<String>) -> RosTopics {
    let Ok(Some(summary)) = mcap::read::Summary::read(bytes) else {
        return given.clone();
    };
    let channels: Vec<(String, String)> = summary
        .channels
        .values()
        .map(|c| {
            (
                c.topic.clone(),
                c.schema
                    .as_ref()
                    .map(|s| s.name.clone())
                    .unwrap_or_default(),
            )
        })
        .collect();
    let pick = |topic: &String, canonical: &str, what: &str, notes: &mut Vec<String>| {
        if channels.iter().any(|(t, _)| t == topic) {
            return topic.clone();
        }
        let of_type: Vec<&String> = channels
            .iter()
            .filter(|(_, ty)| types::is(ty, canonical))
            .map(|(t, _)| t)
            .collect();
        match of_type.as_slice() {
            [only] => {
                notes.push(format!("{what} from {only}: the bag has no {topic}"));
                (*only).clone()
            }
            _ => topic.clone(),
        }
    };
    RosTopics {
        joint_states: pick(
            &given.joint_states,
            types::JOINT_STATE,
            "wheel joints",
            notes,
        ),
        imu: pick(&given.imu, types::IMU, "IMU", notes),
        odom: pick(&given.odom, types::ODOMETRY, "odometry", notes),
    }
}

/// `odocal.side_m` from a bag's metadata records, if present.
fn read_side_metadata(bytes: &[u8]) -> Option<f64> {
    let mut side = None;
    for rec in mcap::read::LinearReader::new(bytes).ok()? {
        if let Ok(mcap::records::Record::Metadata(m)) = rec {
            if m.name == "odocal" {
                side = m.metadata.get("side_m").and_then(|v| v.parse().ok());
            }
        }
    }
    side.filter(|s: &f64| s.is_finite() && *s > 0.0)
}

/// Configured geometry inferred from the controller's `/odom` against the wheel joints.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct InferredGeometry {
    /// Wheel radius (m), one for both wheels (what `diff_drive_controller` configures).
    pub wheel_radius_m: f64,
    /// Wheel separation (m).
    pub wheel_separation_m: f64,
    /// Odometry intervals used.
    pub intervals: usize,
}

impl InferredGeometry {
    /// As parameters (wheel angles in radians as counts).
    pub fn params(&self) -> WheelParams {
        WheelParams {
            left_wheel_diameter_m: 2.0 * self.wheel_radius_m,
            right_wheel_diameter_m: 2.0 * self.wheel_radius_m,
            wheelbase_m: self.wheel_separation_m,
            counts_per_wheel_rev: RAD_PER_REV,
        }
    }
}

/// Joint angles interpolated at `t` (the samples must cover it).
fn joints_at(j: &[JointSample], t: f64) -> Option<(f64, f64)> {
    let i = j.partition_point(|s| s.t < t);
    let b = j.get(i)?;
    if i == 0 {
        return (b.t == t).then_some((b.left_rad, b.right_rad));
    }
    let a = &j[i - 1];
    let f = if b.t > a.t {
        (t - a.t) / (b.t - a.t)
    } else {
        0.0
    };
    Some((
        a.left_rad + f * (b.left_rad - a.left_rad),
        a.right_rad + f * (b.right_rad - a.right_rad),
    ))
}

/// Infers the wheel radius and separation the controller's odometry uses: between consecutive
/// `/odom` messages, the distance it reports against the mean wheel angle change (radius), and
/// the turn it reports against the wheel angle difference (separation). Least squares.
pub fn infer_geometry(data: &BagData) -> Result<InferredGeometry, BagError> {
    if data.odom.len() < 10 {
        return Err(BagError::Inference(format!(
            "{} odometry messages (need the controller's odometry topic)",
            data.odom.len()
        )));
    }
    let (mut sxy, mut sxx, mut n) = (0.0, 0.0, 0usize);
    let mut turns = Vec::new();
    for w in data.odom.windows(2) {
        let (Some(a), Some(b)) = (
            joints_at(&data.joints, w[0].t),
            joints_at(&data.joints, w[1].t),
        ) else {
            continue;
        };
        let (dl, dr) = (b.0 - a.0, b.1 - a.1);
        let dyaw = wrap_angle(w[1].yaw_rad - w[0].yaw_rad);
        // Forward distance along the mean heading (sign from the wheels).
        let mean_yaw = w[0].yaw_rad + 0.5 * dyaw;
        let ds = (w[1].x_m - w[0].x_m) * mean_yaw.cos() + (w[1].y_m - w[0].y_m) * mean_yaw.sin();
        let phi = 0.5 * (dl + dr);
        sxy += ds * phi;
        sxx += phi * phi;
        turns.push((dr - dl, dyaw));
        n += 1;
    }
    if sxx < 1e-6 {
        return Err(BagError::Inference(
            "the wheels barely turned while /odom was recorded".into(),
        ));
    }
    let r = sxy / sxx;
    // dyaw = r (dr − dl) / b  ⇒  b = r Σ(dφ)² / Σ(dφ·dyaw).
    let (num, den) = turns.iter().fold((0.0, 0.0), |(a, b), (dphi, dyaw)| {
        (a + dphi * dphi, b + dphi * dyaw)
    });
    if den.abs() < 1e-9 || !(r.is_finite() && r > 0.0) {
        return Err(BagError::Inference(
            "the robot did not turn while /odom was recorded".into(),
        ));
    }
    let b = r * num / den;
    if !(b.is_finite() && b > 0.0) {
        return Err(BagError::Inference(format!("separation came out as {b} m")));
    }
    Ok(InferredGeometry {
        wheel_radius_m: r,
        wheel_separation_m: b,
        intervals: n,
    })
}

use crate::calibration::legs::{classify, Phase};

/// A square run found in (or assigned to) the bag.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BagRun {
    /// Direction (from the odometry's turn).
    pub direction: Direction,
    /// Start (s from the bag's first message).
    pub start_s: f64,
    /// End (s).
    pub end_s: f64,
    /// Legs' mean length by odometry (m), when four legs were found.
    pub mean_leg_m: Option<f64>,
    /// Odometry turn over the run (rad, unwrapped).
    pub odometry_turn_rad: f64,
    /// IMU yaw change over the run (rad; at-rest means before and after).
    pub imu_turn_rad: f64,
    /// Heading error: IMU turn minus odometry turn (rad, wrapped).
    pub heading_error_rad: f64,
    /// IMU readings averaged at rest (before, after).
    pub rest_readings: [usize; 2],
    /// Heading error from the middle of the first leg to the middle of the last (rad), when
    /// four legs were found ([`crate::calibration::legs`]).
    pub leg_heading_error_rad: Option<f64>,
}

/// Integrated odometry per joint interval: forward travel and turn.
fn increments(j: &[JointSample], p: &WheelParams) -> Vec<(f64, f64, f64, f64)> {
    let (rl, rr) = (p.left_m_per_count(), p.right_m_per_count());
    j.windows(2)
        .map(|w| {
            let sl = (w[1].left_rad - w[0].left_rad) * rl;
            let sr = (w[1].right_rad - w[0].right_rad) * rr;
            (w[0].t, w[1].t, 0.5 * (sl + sr), (sr - sl) / p.wheelbase_m)
        })
        .collect()
}

/// Circular mean of valid IMU yaws with `t` in `[a, b]`, and how many.
fn mean_yaw(imu: &[YawSample], a: f64, b: f64) -> (Option<f64>, usize) {
    let lo = imu.partition_point(|s| s.t < a);
    let (mut s, mut c, mut n) = (0.0, 0.0, 0);
    for y in imu[lo..].iter().take_while(|y| y.t <= b) {
        if let Some(v) = y.yaw_rad {
            s += v.sin();
            c += v.cos();
            n += 1;
        }
    }
    ((n > 0).then(|| s.atan2(c)), n)
}

/// Finds the square runs (or uses `opts.ranges`) and measures each.
pub fn find_runs(
    data: &BagData,
    configured: &WheelParams,
    opts: &BagOptions,
) -> Result<(Vec<BagRun>, Vec<String>), BagError> {
    let inc = increments(&data.joints, configured);
    let mut skipped = Vec::new();
    // Episodes: [start, end) intervals of motion between rests of at least min_rest_s.
    let mut episodes: Vec<(usize, usize)> = Vec::new();
    if opts.ranges.is_empty() {
        let phases: Vec<Phase> = inc
            .iter()
            .map(|&(a, b, ds, dth)| classify(ds, dth, b - a, configured.wheelbase_m))
            .collect();
        let mut i = 0;
        let mut start: Option<usize> = None;
        while i < inc.len() {
            if phases[i] == Phase::Rest {
                let j = (i..inc.len())
                    .find(|&k| phases[k] != Phase::Rest)
                    .unwrap_or(inc.len());
                let rest_s = inc[j.min(inc.len()) - 1].1 - inc[i].0;
                if rest_s >= opts.min_rest_s || j == inc.len() {
                    if let Some(s) = start.take() {
                        episodes.push((s, i));
                    }
                }
                i = j;
            } else {
                if start.is_none() {
                    start = Some(i);
                }
                i += 1;
            }
        }
        if let Some(s) = start {
            skipped.push(format!(
                "motion from {:.1} s to the end of the bag: no rest after it",
                inc[s].0
            ));
        }
    } else {
        for &(a, b) in &opts.ranges {
            if !(a.is_finite() && b.is_finite() && b > a) {
                return Err(BagError::Range(format!("{a}..{b} is empty or not finite")));
            }
            let s = inc.partition_point(|x| x.0 < a);
            let e = inc.partition_point(|x| x.1 <= b);
            if e <= s {
                return Err(BagError::Range(format!("{a}..{b} s holds no wheel data")));
            }
            episodes.push((s, e));
        }
    }
    let mut runs = Vec::new();
    for (s, e) in episodes {
        let (t_start, t_end) = (inc[s].0, inc[e - 1].1);
        let turn: f64 = inc[s..e].iter().map(|x| x.3).sum();
        let direction = if (turn + 2.0 * std::f64::consts::PI).abs() < std::f64::consts::FRAC_PI_4 {
            Direction::Cw
        } else if (turn - 2.0 * std::f64::consts::PI).abs() < std::f64::consts::FRAC_PI_4 {
            Direction::Ccw
        } else {
            skipped.push(format!(
                "{t_start:.1}–{t_end:.1} s: turns {:.0}°, not a square (±360°)",
                turn.to_degrees()
            ));
            continue;
        };
        // Legs and turns, merging consecutive intervals of one kind (rests inside split them).
        let mut legs = Vec::new();
        let mut turns = Vec::new();
        let mut cur: Option<(Phase, f64)> = None;
        for &(a, b, ds, dth) in &inc[s..e] {
            let p = classify(ds, dth, b - a, configured.wheelbase_m);
            let amount = if p == Phase::Turn { dth } else { ds };
            match cur {
                Some((q, acc)) if q == p => cur = Some((q, acc + amount)),
                _ => {
                    match cur {
                        Some((Phase::Straight, acc)) if acc.abs() > 0.05 => legs.push(acc),
                        Some((Phase::Turn, acc)) if acc.abs() > 0.2 => turns.push(acc),
                        _ => {}
                    }
                    cur = Some((p, amount));
                }
            }
        }
        match cur {
            Some((Phase::Straight, acc)) if acc.abs() > 0.05 => legs.push(acc),
            Some((Phase::Turn, acc)) if acc.abs() > 0.2 => turns.push(acc),
            _ => {}
        }
        let mean_leg_m = (legs.len() == 4 && turns.len() == 4)
            .then(|| legs.iter().map(|l| l.abs()).sum::<f64>() / 4.0);
        if mean_leg_m.is_none() && opts.side_m.is_none() && data.side_m.is_none() {
            skipped.push(format!(
                "{t_start:.1}–{t_end:.1} s: {} legs and {} turns, not four of each (give --side-m to use it anyway)",
                legs.len(),
                turns.len()
            ));
            continue;
        }
        // Rests around the run: up to 1 s before its start and after its end.
        let (before, nb) = mean_yaw(&data.imu, t_start - 1.0, t_start);
        let (after, na) = mean_yaw(&data.imu, t_end, t_end + 1.0);
        let (Some(before), Some(after)) = (before, after) else {
            skipped.push(format!(
                "{t_start:.1}–{t_end:.1} s: no valid IMU yaw at rest before or after"
            ));
            continue;
        };
        let imu_turn = wrap_angle(after - before - turn) + turn;
        let leg_heading_error_rad = legs_of(&inc[s..e], &data.imu, configured.wheelbase_m);
        runs.push(BagRun {
            direction,
            start_s: t_start,
            end_s: t_end,
            mean_leg_m,
            odometry_turn_rad: turn,
            imu_turn_rad: imu_turn,
            heading_error_rad: wrap_angle(imu_turn - turn),
            rest_readings: [nb, na],
            leg_heading_error_rad,
        });
    }
    Ok((runs, skipped))
}

/// The heading error along the legs of a run's increments, with the IMU's newest valid yaw at
/// each wheel sample (unwrapped) against the odometry's turn.
fn legs_of(inc: &[(f64, f64, f64, f64)], imu: &[YawSample], wheelbase_m: f64) -> Option<f64> {
    use crate::calibration::legs::{leg_heading_error, LegSample};
    let yaw_at = |t: f64| -> Option<f64> {
        let i = imu.partition_point(|y| y.t <= t);
        imu[..i].iter().rev().find_map(|y| y.yaw_rad)
    };
    let first = inc.first()?;
    let mut prev = yaw_at(first.0)?;
    let (mut imu_turn, mut odo_turn) = (0.0, 0.0);
    let mut out = vec![LegSample {
        t: first.0,
        ds: 0.0,
        dth: 0.0,
        error_rad: 0.0,
    }];
    for &(_, t1, ds, dth) in inc {
        let y = yaw_at(t1)?;
        imu_turn += wrap_angle(y - prev);
        prev = y;
        odo_turn += dth;
        out.push(LegSample {
            t: t1,
            ds,
            dth,
            error_rad: imu_turn - odo_turn,
        });
    }
    leg_heading_error(&out, wheelbase_m)
}

/// Where the configured geometry came from.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "snake_case", tag = "source")]
pub enum GeometrySource {
    /// The controller's YAML.
    Yaml {
        /// The file.
        file: PathBuf,
        /// The controller.
        controller: String,
    },
    /// Inferred from `/odom` against the joints.
    Inferred(InferredGeometry),
}

/// One method's result with the multipliers it would write.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BagEstimate {
    /// The estimate.
    #[serde(flatten)]
    pub estimate: Estimate,
    /// The multipliers it implies on the configured nominal values.
    pub multipliers: super::yaml::Multipliers,
}

/// Everything `odocal bag` reports.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BagReport {
    /// The bag.
    pub file: PathBuf,
    /// Messages read on the needed topics.
    pub messages: u64,
    /// Every topic in the bag.
    pub topics: Vec<(String, String)>,
    /// Configured (effective) parameters.
    pub configured: WheelParams,
    /// Where they came from.
    pub geometry: GeometrySource,
    /// Square side used (m) and where it came from.
    pub side_m: f64,
    /// `flag`, `metadata` or `legs`.
    pub side_source: &'static str,
    /// Runs found.
    pub runs: Vec<BagRun>,
    /// Stretches of motion that were not used, and why.
    pub skipped: Vec<String>,
    /// Choices made while reading the bag.
    pub notes: Vec<String>,
    /// Every square method's estimate.
    pub estimates: Vec<BagEstimate>,
    /// Methods without an estimate, and why.
    pub failures: Vec<(Method, String)>,
    /// The online filter over the whole bag.
    pub online: Option<OnlineEstimate>,
    /// Mean heading NIS of the online filter.
    pub online_nis: Option<f64>,
    /// What the online filter's heading gate rejected.
    pub online_gate: Option<GateStats>,
    /// Which parameters the bag's driving observed.
    pub online_excitation: Option<Excitation>,
    /// Clock offset between the joint states and the IMU, when it could be estimated
    /// (corrected before the online filter when significant).
    pub time_offset: Option<TimeOffset>,
}

/// The ros2_control multipliers that make `nominal` (wheel radius, separation; m) into `p`.
pub fn multipliers(p: &WheelParams, nominal: (f64, f64)) -> super::yaml::Multipliers {
    super::yaml::Multipliers {
        wheel_separation_multiplier: p.wheelbase_m / nominal.1,
        left_wheel_radius_multiplier: p.left_wheel_diameter_m / (2.0 * nominal.0),
        right_wheel_radius_multiplier: p.right_wheel_diameter_m / (2.0 * nominal.0),
    }
}

/// Analyses a bag: runs, every square method, the online filter. `nominal` gives the nominal
/// wheel radius and separation the multipliers are relative to.
pub fn analyse(
    path: &Path,
    data: &BagData,
    configured: WheelParams,
    geometry: GeometrySource,
    nominal: (f64, f64),
    opts: &BagOptions,
) -> Result<BagReport, BagError> {
    let (runs, skipped) = find_runs(data, &configured, opts)?;
    let legs: Vec<f64> = runs.iter().filter_map(|r| r.mean_leg_m).collect();
    let (side_m, side_source) = match (opts.side_m, data.side_m) {
        (Some(s), _) => (s, "flag"),
        (None, Some(s)) => (s, "metadata"),
        (None, None) if !legs.is_empty() => (legs.iter().sum::<f64>() / legs.len() as f64, "legs"),
        _ => (f64::NAN, "none"),
    };
    let mut test = SquareTest {
        side_m,
        wheelbase_m: configured.wheelbase_m,
        cw: Vec::new(),
        ccw: Vec::new(),
    };
    for r in &runs {
        let m = RunMeasurement {
            heading_error_rad: r.heading_error_rad,
            final_xy_m: None,
            leg_heading_error_rad: r.leg_heading_error_rad,
        };
        match r.direction {
            Direction::Cw => test.cw.push(m),
            Direction::Ccw => test.ccw.push(m),
        }
    }
    let (mut estimates, mut failures) = (Vec::new(), Vec::new());
    match estimate_all(&test, opts.convention) {
        Ok(all) => {
            for (method, result) in all {
                match result.and_then(|e| {
                    let p = e.correction.apply(&configured)?;
                    Ok((e, p))
                }) {
                    Ok((estimate, p)) => estimates.push(BagEstimate {
                        multipliers: multipliers(&p, nominal),
                        estimate,
                    }),
                    Err(e) => failures.push((method, e.to_string())),
                }
            }
        }
        Err(e) => failures.push((Method::Exact, e.to_string())),
    }
    let online = online_over(data, &configured, opts.convention);
    Ok(BagReport {
        file: path.to_path_buf(),
        messages: data.messages,
        topics: data.topics.clone(),
        configured,
        geometry,
        side_m,
        side_source,
        runs,
        skipped,
        notes: data.notes.clone(),
        estimates,
        failures,
        online: online.estimate,
        online_nis: online.nis,
        online_gate: online.gate,
        online_excitation: online.excitation,
        time_offset: online.time_offset,
    })
}

/// What the online filter made of a bag.
struct OnlineOver {
    estimate: Option<OnlineEstimate>,
    nis: Option<f64>,
    gate: Option<GateStats>,
    excitation: Option<Excitation>,
    time_offset: Option<TimeOffset>,
}

/// The IMU's yaw as last read at or before each joint sample.
fn yaw_at_joints(joints: &[JointSample], imu: &[YawSample]) -> Vec<Option<f64>> {
    let mut k = 0;
    let mut last = None;
    joints
        .iter()
        .map(|j| {
            while k < imu.len() && imu[k].t <= j.t {
                last = imu[k].yaw_rad.or(last);
                k += 1;
            }
            last
        })
        .collect()
}

/// The online filter over the whole bag: joint increments predict, IMU yaw updates. A clock
/// offset between the two streams is looked for first and, when significant, the IMU's stamps
/// are corrected by it.
fn online_over(
    data: &BagData,
    configured: &WheelParams,
    convention: SplitConvention,
) -> OnlineOver {
    let mut out = OnlineOver {
        estimate: None,
        nis: None,
        gate: None,
        excitation: None,
        time_offset: None,
    };
    let mut cfg = OnlineConfig::new(*configured);
    // Wheel angles are radians: quantisation of a 4096-count encoder.
    cfg.count_noise = RAD_PER_REV / 4096.0;
    let Ok(mut f) = OnlineEstimator::new(cfg) else {
        return out;
    };
    let times: Vec<f64> = data.joints.iter().map(|j| j.t).collect();
    // The turn over each joint interval, at the sample that ends it.
    let odo: Vec<f64> = std::iter::once(0.0)
        .chain(
            increments(&data.joints, configured)
                .into_iter()
                .map(|i| i.3),
        )
        .take(times.len())
        .collect();
    out.time_offset = estimate_time_offset(
        &times,
        &odo,
        &yaw_at_joints(&data.joints, &data.imu),
        crate::track::MAX_TIME_OFFSET_S,
    );
    let shift = out
        .time_offset
        .filter(TimeOffset::significant)
        .map_or(0.0, |o| o.offset_s);
    let imu: Vec<YawSample> = data
        .imu
        .iter()
        .map(|y| YawSample {
            t: y.t - shift,
            ..*y
        })
        .collect();
    let mut k = 0;
    for w in data.joints.windows(2) {
        while k < imu.len() && imu[k].t <= w[0].t {
            if let Some(y) = imu[k].yaw_rad {
                f.update_heading(y);
            }
            k += 1;
        }
        f.predict_counts(
            w[1].left_rad - w[0].left_rad,
            w[1].right_rad - w[0].right_rad,
        );
    }
    let (nis, n) = f.nis_mean();
    let scale = ScaleSource::Convention(convention);
    out.estimate = f.estimate(scale).ok().filter(|_| f.distance_m() > 1.0);
    out.nis = (n > 0).then_some(nis);
    out.gate = Some(f.gate_stats());
    out.excitation = f.excitation(scale).ok();
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ros::bag_writer::{write_simulated_bag, SimulatedBag};
    use crate::sim::{NoiseModel, Simulator};

    fn robot(noise: NoiseModel) -> (Simulator, WheelParams) {
        let configured = WheelParams::nominal(0.15, 0.39, RAD_PER_REV);
        let truth =
            WheelParams::from_ratios(&configured, 0.976, 0.992, &SplitConvention::LeftNominal)
                .unwrap();
        (
            Simulator::new(truth, configured, noise, 4).unwrap(),
            configured,
        )
    }

    #[test]
    fn wrapped_joint_angles_are_unwrapped_and_topics_are_found_by_type() {
        use crate::ros::bag_writer::BagWriter;
        let dir = std::env::temp_dir().join(format!("odocal-bag-wrap-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("wrapped.mcap");
        let topics = RosTopics {
            imu: "/imu/data".into(),
            ..RosTopics::default()
        };
        let mut w = BagWriter::create(&path, &topics).unwrap();
        // Wheels turning forward 0.3 rad per sample, published wrapped to (−π, π].
        for k in 0..100 {
            let a = 0.3 * f64::from(k);
            let wrapped = crate::kinematics::wrap_angle(a);
            w.joints(0.02 * f64::from(k), wrapped, wrapped).unwrap();
            w.imu(0.02 * f64::from(k), 0.0).unwrap();
        }
        w.finish().unwrap();
        let data = read_bag(&path, &BagOptions::default()).unwrap();
        assert_eq!(
            data.notes,
            vec!["IMU from /imu/data: the bag has no /imu".to_string()]
        );
        let last = data.joints.last().unwrap();
        assert!((last.left_rad - 0.3 * 99.0).abs() < 1e-9, "{last:?}");
        assert!(data
            .joints
            .windows(2)
            .all(|w| w[1].left_rad > w[0].left_rad));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_simulated_bag_gives_back_the_simulated_robot() {
        let dir = std::env::temp_dir().join(format!("odocal-bag-unit-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("sim.mcap");
        let (mut sim, configured) = robot(NoiseModel::default());
        let cfg = SimulatedBag {
            runs: 2,
            ..SimulatedBag::default()
        };
        write_simulated_bag(&path, &mut sim, &cfg, &RosTopics::default()).unwrap();
        let opts = BagOptions::default();
        let data = read_bag(&path, &opts).unwrap();
        assert_eq!(data.side_m, Some(2.0));
        // The geometry inferred from /odom is the configured one.
        let g = infer_geometry(&data).unwrap();
        assert!((g.wheel_radius_m - 0.075).abs() < 1e-9, "{g:?}");
        assert!((g.wheel_separation_m - 0.39).abs() < 1e-9, "{g:?}");
        let report = analyse(
            &path,
            &data,
            configured,
            GeometrySource::Inferred(g),
            (0.075, 0.39),
            &opts,
        )
        .unwrap();
        assert_eq!(report.runs.len(), 4, "{:?}", report.skipped);
        for r in &report.runs {
            assert!((r.mean_leg_m.unwrap() - 2.0).abs() < 1e-9, "{r:?}");
        }
        let exact = report
            .estimates
            .iter()
            .find(|e| e.estimate.method == Method::Exact)
            .unwrap();
        assert!((exact.estimate.e_b - 0.976).abs() < 1e-6, "{exact:?}");
        assert!((exact.estimate.e_d - 0.992).abs() < 1e-6, "{exact:?}");
        assert!((exact.multipliers.wheel_separation_multiplier - 0.976).abs() < 1e-6);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
