//! Offline calibration from ROS bags: read wheel joint angles, IMU yaw and the controller's
//! odometry from a bag of any container odocal knows, turn them into a
//! [`crate::calibration::recording::Recording`], find the square runs and estimate with every
//! method and the online filter.
//!
//! One room per concern:
//! - a container format ([`mcap`]) implements [`Container`]: its channels, its metadata and
//!   its messages in order — a new format is one file behind that trait, plus one line in
//!   [`open_container`];
//! - [`decode`] turns any container's messages into [`BagData`] (topics resolved by type,
//!   wheel joints picked by name, angles unwrapped, header stamps);
//! - [`mod@analyse`] infers the configured geometry, segments the runs and estimates;
//! - [`writer`] writes MCAP bags (simulated tests, converted recordings).

pub mod analyse;
pub mod decode;
pub mod mcap;
pub mod writer;

pub use analyse::{
    analyse, find_runs, infer_geometry, multipliers, BagEstimate, BagReport, BagRun,
    GeometrySource, InferredGeometry,
};
pub use decode::read_bag;

use super::msg::cdr;
use crate::kinematics::SplitConvention;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

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
    /// A file of a container format odocal reads that is not readable as one.
    #[error("{}: not a readable {format} bag: {reason}", path.display())]
    Container {
        /// The file.
        path: PathBuf,
        /// The container format it looked like.
        format: &'static str,
        /// The reader's error.
        reason: String,
    },
    /// A file of no container format odocal reads.
    #[error("{}: not a bag odocal reads (it starts {starts:?}); odocal reads MCAP", path.display())]
    NotABag {
        /// The file.
        path: PathBuf,
        /// Its first bytes, printable ones as they are.
        starts: String,
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
        source: ::mcap::McapError,
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

/// A channel of a bag: a topic and what it carries.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Channel {
    /// The topic.
    pub topic: String,
    /// The message type as the bag names it (`sensor_msgs/msg/JointState`).
    pub type_name: String,
    /// How messages are serialised (`cdr` for ROS 2).
    pub encoding: String,
}

/// One message as its container hands it out.
#[derive(Debug, Clone, Copy)]
pub struct RawMessage<'a> {
    /// Its channel.
    pub channel: &'a Channel,
    /// When it was recorded (ns on the recorder's clock).
    pub log_time_ns: u64,
    /// The serialised message.
    pub data: &'a [u8],
}

/// A bag container format: what it holds and its messages in order.
pub trait Container {
    /// The format's name, for messages (`MCAP`).
    fn format(&self) -> &'static str;
    /// Every channel, when the container lists them before its messages (an index or a
    /// summary); `None` when they are only learnt while reading.
    fn channels(&self) -> Option<Vec<Channel>>;
    /// The key-value metadata record `name`, when the container has one.
    fn metadata(&self, name: &str) -> Option<BTreeMap<String, String>>;
    /// Hands every message to `each`, in the container's order; an error of `each` ends it.
    fn messages(
        &self,
        each: &mut dyn FnMut(RawMessage<'_>) -> Result<(), BagError>,
    ) -> Result<(), BagError>;
}

/// The container of `bytes` (read from `path`), told by its content.
pub fn open_container<'a>(
    bytes: &'a [u8],
    path: &Path,
) -> Result<Box<dyn Container + 'a>, BagError> {
    if bytes.starts_with(mcap::MAGIC) {
        return Ok(Box::new(mcap::McapBag::new(bytes, path)?));
    }
    let starts: String = bytes
        .iter()
        .take(16)
        .map(|&b| {
            if b.is_ascii_graphic() || b == b' ' {
                char::from(b)
            } else {
                '.'
            }
        })
        .collect();
    // A name that promises a format gets that format's complaint.
    if path.extension().is_some_and(|e| e == "mcap") {
        return Err(BagError::Container {
            path: path.to_path_buf(),
            format: "MCAP",
            reason: format!("it does not start with MCAP's magic bytes (it starts {starts:?})"),
        });
    }
    Err(BagError::NotABag {
        path: path.to_path_buf(),
        starts,
    })
}
