//! A drive with a pose reference from a bag of any container: the wheel joints and one pose
//! topic — `geometry_msgs/PoseStamped`, `geometry_msgs/PoseWithCovarianceStamped` (`/amcl_pose`)
//! or `nav_msgs/Odometry` (motion capture, visual odometry, GNSS) — each on its header stamp,
//! checked as [`super::validate`] checks every stream, on one clock from the first sample, as
//! the [`PoseRecording`] `odocal fit` takes. A message's covariance, where it states one, gives
//! its sample's standard deviations (x, y and yaw from the diagonal).

use super::decode::{check_channel, decode, stamp_or, Unzstd};
use super::validate::{self, Sample};
use super::{open_container, BagError, BagOptions, Channel, Container, RawMessage};
use crate::calibration::pose_reference::{PoseRecording, ReferencePose, WheelAngles};
use crate::ros::msg::{
    types, yaw_of, Covariance36, Header, JointState, Odometry, Pose, PoseStamped,
    PoseWithCovarianceStamped,
};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The types a pose reference may have.
pub const REFERENCE_TYPES: [&str; 3] = [
    types::POSE_STAMPED,
    types::POSE_WITH_COVARIANCE_STAMPED,
    types::ODOMETRY,
];

/// A drive read from a bag.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseDrive {
    /// The wheels and the reference, on one clock (s from the first sample).
    pub recording: PoseRecording,
    /// The reference topic's type.
    pub reference_type: String,
    /// The wheel joints' topic.
    pub joints_topic: String,
    /// Choices made while reading, and samples dropped.
    pub notes: Vec<String>,
}

/// A drive with a pose reference from a bag, as a user names it (with the `cli` feature,
/// `odocal fit`'s flags).
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct BagDriveSettings {
    /// A ROS bag (any format `odocal bag` reads) with the wheel joints and --reference.
    #[cfg_attr(feature = "cli", arg(long, requires = "reference"))]
    pub bag: Option<PathBuf>,
    /// The bag's pose reference: a geometry_msgs/PoseStamped, PoseWithCovarianceStamped
    /// (/amcl_pose) or nav_msgs/Odometry topic (its covariance, when it states one, weights the
    /// samples), or `tf:FRAME` for the TF chain from FRAME (map, world) to --base-frame.
    #[cfg_attr(feature = "cli", arg(long, requires = "bag"))]
    pub reference: Option<String>,
    /// The robot's frame at the end of a `tf:` chain.
    #[cfg_attr(feature = "cli", arg(long, default_value = "base_link"))]
    pub base_frame: String,
    /// The bag's sensor_msgs/JointState topic.
    #[cfg_attr(feature = "cli", arg(long, default_value = "/joint_states"))]
    pub joint_states_topic: String,
    /// Left wheel joint [default: the one joint name containing "left"].
    #[cfg_attr(feature = "cli", arg(long))]
    pub left_joint: Option<String>,
    /// Right wheel joint [default: the one joint name containing "right"].
    #[cfg_attr(feature = "cli", arg(long))]
    pub right_joint: Option<String>,
}

impl BagDriveSettings {
    /// The drive, named `BAG REFERENCE`, with notes on what was read; `None` when no bag was
    /// given.
    pub fn read(&self) -> Result<Option<(String, PoseRecording, Vec<String>)>, BagError> {
        let (Some(bag), Some(reference)) = (&self.bag, &self.reference) else {
            return Ok(None);
        };
        let opts = BagOptions {
            topics: super::RosTopics {
                joint_states: self.joint_states_topic.clone(),
                ..Default::default()
            },
            left_joint: self.left_joint.clone(),
            right_joint: self.right_joint.clone(),
            ..Default::default()
        };
        let (recording, notes) = read_reference_drive(bag, &opts, reference, &self.base_frame)?;
        Ok(Some((
            format!("{} {reference}", bag.display()),
            recording,
            notes,
        )))
    }
}

/// The drive against `reference` in the bag at `path`: a pose topic (as [`read_pose_drive`])
/// or `tf:FRAME`, the TF chain from FRAME (map, world) to `base_frame` (as
/// [`super::tf::read_tf_drive`]); with the notes on what was read.
pub fn read_reference_drive(
    path: &Path,
    opts: &BagOptions,
    reference: &str,
    base_frame: &str,
) -> Result<(PoseRecording, Vec<String>), BagError> {
    Ok(match reference.strip_prefix("tf:") {
        Some(fixed) => {
            let d = super::tf::read_tf_drive(path, opts, fixed, base_frame)?;
            (d.recording, d.notes)
        }
        None => {
            let d = read_pose_drive(path, opts, reference)?;
            (d.recording, d.notes)
        }
    })
}

/// Reads the wheel joints (`opts.topics.joint_states`, joints by `opts`' names) and the pose
/// reference on `reference` from the bag at `path`.
pub fn read_pose_drive(
    path: &Path,
    opts: &BagOptions,
    reference: &str,
) -> Result<PoseDrive, BagError> {
    read_pose_container(open_container(path)?.as_ref(), opts, reference)
}

/// The standard deviations of x, y and yaw a pose message's covariance states, when it states
/// usable ones (positive and finite; AMCL's, a motion-capture bridge's).
pub(crate) fn stated_std(c: &Covariance36) -> Option<[f64; 3]> {
    let s = [c.0[0], c.0[7], c.0[35]].map(f64::sqrt);
    s.iter().all(|v| v.is_finite() && *v > 0.0).then_some(s)
}

/// The wheel joints as a reader meets them: the wheels found by name in the first message
/// that names them, later messages of other joint groups skipped.
#[derive(Default)]
pub(super) struct WheelReader {
    /// Messages seen on the joints' topic.
    pub(super) messages: usize,
    names: Option<(String, String)>,
    seen_names: Vec<String>,
    samples: Vec<Sample<(f64, f64)>>,
}

impl WheelReader {
    /// Reads one joints message (`data`, its decompressed payload).
    pub(super) fn add(
        &mut self,
        m: &super::RawMessage<'_>,
        data: &[u8],
        index: usize,
        opts: &BagOptions,
    ) -> Result<(), BagError> {
        let js: JointState =
            decode(&m.channel.encoding, data).map_err(|source| BagError::Decode {
                topic: m.channel.topic.clone(),
                index,
                source,
            })?;
        self.push(js, index, m.log_time_ns, opts);
        Ok(())
    }

    /// Takes one decoded joints message, the `index`-th on its topic, logged at `log_ns`.
    pub(super) fn push(&mut self, js: JointState, index: usize, log_ns: u64, opts: &BagOptions) {
        self.messages += 1;
        let ix = match &self.names {
            Some((ln, rn)) => js
                .name
                .iter()
                .position(|n| n == ln)
                .zip(js.name.iter().position(|n| n == rn)),
            None => match js.wheel_indices(&opts.left_joint, &opts.right_joint) {
                Some((l, r)) => {
                    self.names = Some((js.name[l].clone(), js.name[r].clone()));
                    Some((l, r))
                }
                None => {
                    self.seen_names.clone_from(&js.name);
                    None
                }
            },
        };
        if let Some((l, r)) = ix {
            if let (Some(&lp), Some(&rp)) = (js.position.get(l), js.position.get(r)) {
                self.samples.push(Sample {
                    index,
                    t: stamp_or(&js.header, log_ns),
                    value: (lp, rp),
                });
            }
        }
    }

    /// The wheel samples, checked and unwrapped ([`validate::joints`]), or why there are none.
    pub(super) fn finish(
        self,
        topic: &str,
        available: &[(String, String)],
        notes: &mut Vec<String>,
    ) -> Result<Vec<Sample<(f64, f64)>>, BagError> {
        if self.messages == 0 {
            return Err(BagError::MissingTopic {
                what: "wheel joint",
                topic: topic.to_string(),
                available: available.to_vec(),
            });
        }
        if self.samples.is_empty() {
            return Err(BagError::Joints {
                topic: topic.to_string(),
                names: self.seen_names,
            });
        }
        validate::joints(self.samples, topic, notes)
    }
}

/// The wheels on a clock that starts at the first wheel sample or `first_reference_s`,
/// whichever is earlier (stamps that do not increase are left out); returns that start.
pub(super) fn on_one_clock(
    wheels: Vec<Sample<(f64, f64)>>,
    first_reference_s: Option<f64>,
) -> (PoseRecording, f64) {
    let t0 = wheels
        .first()
        .map(|s| s.t)
        .into_iter()
        .chain(first_reference_s)
        .fold(f64::INFINITY, f64::min);
    let mut recording = PoseRecording::default();
    for j in wheels {
        if recording
            .wheels
            .last()
            .is_some_and(|w| j.t - t0 <= w.time_s)
        {
            continue;
        }
        recording.wheels.push(WheelAngles {
            time_s: j.t - t0,
            left_rad: j.value.0,
            right_rad: j.value.1,
        });
    }
    (recording, t0)
}

/// [`read_pose_drive`] of an open container.
pub fn read_pose_container(
    bag: &dyn Container,
    opts: &BagOptions,
    reference: &str,
) -> Result<PoseDrive, BagError> {
    let mut notes = Vec::new();
    let listed = bag.channels().unwrap_or_default();
    let joints_topic = joints_topic_of(&listed, opts, &mut notes);
    // A reference topic the bag lists with another type is refused before reading.
    if let Some(c) = listed.iter().find(|c| c.topic == reference) {
        check_channel(c, &REFERENCE_TYPES, EXPECTED_REFERENCE)?;
    }
    let seen: BTreeMap<String, String> = listed
        .iter()
        .map(|c| (c.topic.clone(), c.type_name.clone()))
        .collect();
    let mut reader = PoseReader {
        seen,
        ..PoseReader::default()
    };
    bag.messages(&mut |m| {
        crate::io::budget::charge_message(&|| format!("{} bag's messages", bag.format()))?;
        reader.take(m, &joints_topic, reference, opts)
    })?;
    let PoseReader {
        seen,
        ref_msgs,
        wheels,
        poses,
        stated,
        ref_type,
        ..
    } = reader;
    notes.extend(bag.notes());
    let available: Vec<(String, String)> = seen.into_iter().collect();
    let wheels = wheels.finish(&joints_topic, &available, &mut notes)?;
    if ref_msgs == 0 {
        return Err(BagError::MissingTopic {
            what: "pose reference",
            topic: reference.to_string(),
            available,
        });
    }
    let poses = validate::odometry(poses, reference, &mut notes)?;
    let recording = pose_recording(wheels, poses, &stated, reference, &mut notes);
    Ok(PoseDrive {
        recording,
        reference_type: ref_type,
        joints_topic,
        notes,
    })
}

/// The types a pose reference may have, as an error names them.
const EXPECTED_REFERENCE: &str =
    "geometry_msgs/PoseStamped, geometry_msgs/PoseWithCovarianceStamped or nav_msgs/Odometry";

/// The wheel joints' topic: `opts`' one, or the bag's one `JointState` topic when it does not
/// list that (with a note saying so).
fn joints_topic_of(listed: &[Channel], opts: &BagOptions, notes: &mut Vec<String>) -> String {
    let mut joints_topic = opts.topics.joint_states.clone();
    if !listed.iter().any(|c| c.topic == joints_topic) {
        let of_type: Vec<&str> = listed
            .iter()
            .filter(|c| types::is(&c.type_name, types::JOINT_STATE))
            .map(|c| c.topic.as_str())
            .collect();
        if let [only] = of_type.as_slice() {
            notes.push(format!(
                "wheel joints from {only}: the bag has no {joints_topic}"
            ));
            joints_topic = (*only).to_string();
        }
    }
    joints_topic
}

/// What reading a bag's messages gathers: the topics seen, the wheels and the reference's
/// poses.
#[derive(Default)]
struct PoseReader {
    /// Topic → type of every topic listed or seen.
    seen: BTreeMap<String, String>,
    /// Undoes rosbag2's per-message compression.
    unzstd: Unzstd,
    /// Messages seen on the reference topic.
    ref_msgs: usize,
    /// The wheel joints.
    wheels: WheelReader,
    /// The reference's poses (x, y, yaw), each indexed into `stated`.
    poses: Vec<Sample<(f64, f64, f64)>>,
    /// The standard deviations each pose's covariance states, if any.
    stated: Vec<Option<[f64; 3]>>,
    /// The reference topic's type.
    ref_type: String,
}

impl PoseReader {
    /// Takes one message: joints and reference messages are read, every topic is noted as
    /// seen.
    fn take(
        &mut self,
        m: RawMessage<'_>,
        joints_topic: &str,
        reference: &str,
        opts: &BagOptions,
    ) -> Result<(), BagError> {
        self.seen
            .entry(m.channel.topic.clone())
            .or_insert_with(|| m.channel.type_name.clone());
        let is_joints = m.channel.topic == joints_topic;
        let is_ref = m.channel.topic == reference;
        if !is_joints && !is_ref {
            return Ok(());
        }
        let index = if is_joints {
            self.wheels.messages
        } else {
            self.ref_msgs
        };
        if index == 0 {
            if is_joints {
                check_channel(m.channel, &[types::JOINT_STATE], types::JOINT_STATE)?;
            } else {
                check_channel(m.channel, &REFERENCE_TYPES, EXPECTED_REFERENCE)?;
            }
        }
        let data = self.unzstd.payload(&m, index)?;
        if is_joints {
            return self.wheels.add(&m, data, index, opts);
        }
        self.ref_msgs += 1;
        self.ref_type.clone_from(&m.channel.type_name);
        let (header, pose, cov) = decode_reference(&m, data, index)?;
        // A quaternion that is not a rotation (all zero) is a message without a pose.
        let Ok(yaw) = yaw_of(&pose.orientation) else {
            return Ok(());
        };
        self.poses.push(Sample {
            index: self.stated.len(),
            t: stamp_or(&header, m.log_time_ns),
            value: (pose.position.x, pose.position.y, yaw),
        });
        self.stated.push(cov.as_ref().and_then(stated_std));
        Ok(())
    }
}

/// A reference message's header, pose and covariance (`None` for a `PoseStamped`), decoded by
/// its type from `data`, the `index`-th message on its topic.
fn decode_reference(
    m: &RawMessage<'_>,
    data: &[u8],
    index: usize,
) -> Result<(Header, Pose, Option<Covariance36>), BagError> {
    let enc = m.channel.encoding.as_str();
    let err = |source| BagError::Decode {
        topic: m.channel.topic.clone(),
        index,
        source,
    };
    Ok(if types::is(&m.channel.type_name, types::POSE_STAMPED) {
        let p: PoseStamped = decode(enc, data).map_err(err)?;
        (p.header, p.pose, None)
    } else if types::is(&m.channel.type_name, types::POSE_WITH_COVARIANCE_STAMPED) {
        let p: PoseWithCovarianceStamped = decode(enc, data).map_err(err)?;
        (p.header, p.pose.pose, Some(p.pose.covariance))
    } else {
        let o: Odometry = decode(enc, data).map_err(err)?;
        (o.header, o.pose.pose, Some(o.pose.covariance))
    })
}

/// The wheels and the checked poses on one clock, poses that do not follow the one before in
/// time left out (with a note saying how many).
fn pose_recording(
    wheels: Vec<Sample<(f64, f64)>>,
    poses: Vec<Sample<(f64, f64, f64)>>,
    stated: &[Option<[f64; 3]>],
    reference: &str,
    notes: &mut Vec<String>,
) -> PoseRecording {
    let (mut recording, t0) = on_one_clock(wheels, poses.first().map(|p| p.t));
    let mut repeated = 0;
    for p in poses {
        if recording.poses.last().is_some_and(|q| p.t - t0 <= q.time_s) {
            repeated += 1;
            continue;
        }
        recording.poses.push(ReferencePose {
            time_s: p.t - t0,
            x_m: p.value.0,
            y_m: p.value.1,
            yaw_rad: Some(p.value.2),
            stated_std: stated.get(p.index).copied().flatten(),
        });
    }
    if repeated > 0 {
        notes.push(format!(
            "{reference}: {repeated} pose(s) with the stamp of the one before left out"
        ));
    }
    recording
}
