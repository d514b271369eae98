//! Offline calibration from ROS bags: read wheel joint angles, IMU yaw and the controller's
//! odometry from a bag of any container odocal knows, turn them into a
//! [`crate::calibration::recording::Recording`], find the square runs and estimate with every
//! method and the online filter.
//!
//! One room per concern:
//! - a container format implements [`Container`]: its channels, its metadata and its messages
//!   in order. A file's format is told by its first bytes ([`FILE_FORMATS`]: [`mcap`], the
//!   ROS 2 default from Iron on; [`sqlite3`], `.db3` up to Humble; [`ros1`], ROS 1 `.bag`
//!   v2.0); [`rosbag2`] is the directory `ros2 bag record` makes, its split files read in
//!   order, each through [`open_file`]. A new format is one file behind that trait plus one
//!   line in [`FILE_FORMATS`];
//! - [`compression`] undoes zstd where rosbag2 puts it: whole files (`.db3.zstd`,
//!   `.mcap.zstd`) and single messages, and whole files in LZ4 frames (`.lz4`), as a stream
//!   and always within the budgets of [`crate::io::budget`];
//! - [`decode`] turns any container's messages into [`BagData`] (topics resolved by type,
//!   wheel joints picked by name, angles unwrapped, header stamps, CDR or ROS 1 wire form);
//! - [`validate`] checks each stream as `track --log` checks a log: time forward, samples
//!   physical, spikes dropped, each drop counted;
//! - [`mod@analyse`] infers the configured geometry, segments the runs and estimates;
//! - [`mod@reference`] reads a drive with a pose reference (the wheels and a pose topic) for
//!   `odocal fit`, and [`tf`] one whose reference is the TF chain to `base_link`;
//! - [`writer`] writes MCAP bags (simulated tests, converted recordings).

pub mod analyse;
pub mod compression;
pub mod decode;
pub mod mcap;
pub mod reference;
pub mod ros1;
pub mod rosbag2;
pub mod session;
#[cfg(feature = "bag-sqlite")]
pub mod sqlite3;
pub mod tf;
pub mod validate;
pub mod writer;

pub use analyse::{
    analyse, find_runs, heading_kind, infer_geometry, multipliers, pool, BagEstimate, BagReport,
    BagRun, GeometrySource, InferredGeometry, PooledBags,
};
pub use decode::{read_bag, read_bag_bytes};

use super::msg::WireError;
use crate::kinematics::SplitConvention;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// What odocal reads, for messages that must say so.
pub const READS: &str = "MCAP (plain, zstd or lz4 chunks), sqlite3 (.db3), rosbag2 \
directories (metadata.yaml and its split files), ROS 1 .bag v2.0 (plain, bz2 or lz4 chunks), \
and any of these files compressed whole with zstd (.zstd) or lz4 (.lz4)";

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
    /// A file of a container format odocal reads that is not readable as one, as our own
    /// reader finds (a record's layout, a missing field).
    #[error("{}: not a readable {format} bag: {reason}", path.display())]
    Container {
        /// The file.
        path: PathBuf,
        /// The container format it looked like.
        format: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// An MCAP file the `mcap` reader refuses.
    #[error("{}: not a readable MCAP bag: {source}", path.display())]
    Mcap {
        /// The file.
        path: PathBuf,
        /// The reader's error.
        #[source]
        source: ::mcap::McapError,
    },
    /// A bag of a format or compression this build of odocal leaves out.
    #[error(transparent)]
    NotBuilt(#[from] crate::features::NotBuilt),
    #[cfg(feature = "bag-sqlite")]
    /// A sqlite3 file SQLite refuses, or one without rosbag2's tables.
    #[error("{}: not a readable sqlite3 bag: {source}", path.display())]
    Sqlite {
        /// The file.
        path: PathBuf,
        /// SQLite's error.
        #[source]
        source: rusqlite::Error,
    },
    /// A ROS 1 chunk that does not decompress to the size its header gives.
    #[error("{}: not a readable ROS 1 bag: the {compression} chunk at byte {at}: {source}", path.display())]
    Ros1Chunk {
        /// The file.
        path: PathBuf,
        /// Where the chunk's record starts.
        at: usize,
        /// Its compression.
        compression: String,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// A zstd-compressed file or message that does not decompress within the size bound.
    #[error("{what}: zstd: {source}")]
    Zstd {
        /// The file, or the topic and message.
        what: String,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// A run's budget exceeded (the error names the budget and the flag that raises it).
    #[error(transparent)]
    Budget(#[from] crate::io::budget::Exceeded),
    /// A file of LZ4 frames that does not decompress within the size bound.
    #[error("{}: lz4: {source}", path.display())]
    Lz4 {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// A rosbag2 directory whose `metadata.yaml` is not YAML, or nests deeper or holds more
    /// values than any metadata does (aliases are followed, never expanded).
    #[error("{}: {source}", path.display())]
    MetadataYaml {
        /// The `metadata.yaml`.
        path: PathBuf,
        /// The parser's error, or the bound passed.
        #[source]
        source: crate::ros::yaml::TreeError,
    },
    /// A rosbag2 directory whose `metadata.yaml` odocal cannot follow.
    #[error("{}: {reason}", path.display())]
    Metadata {
        /// The `metadata.yaml`.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// A directory that is not a rosbag2 directory.
    #[error("{}: a directory without metadata.yaml and without .db3 or .mcap files is not a \
rosbag2 bag; odocal reads {READS}", path.display())]
    NotABagDirectory {
        /// The directory.
        path: PathBuf,
    },
    /// A file of no container format odocal reads.
    #[error("{}: not a bag odocal reads: it starts {starts:?}{}; odocal reads {READS}",
        path.display(), looks_like.map(|l| format!(" ({l})")).unwrap_or_default())]
    NotABag {
        /// The file.
        path: PathBuf,
        /// Its first bytes, printable ones as they are.
        starts: String,
        /// What those bytes say it is, when they say.
        looks_like: Option<&'static str>,
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
    #[error(
        "topic `{topic}` carries `{type_name}` ({encoding}); odocal reads {expected} in CDR or \
ROS 1 serialization"
    )]
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
        source: WireError,
    },
    /// No bag was given to pool.
    #[error("no bag given")]
    NoBags,
    /// The bags' estimates could not be pooled or applied.
    #[error("pooling the bags: {0}")]
    Pool(#[from] crate::calibration::CalibrationError),
    /// A pooled estimate makes no physical parameters.
    #[error("pooling the bags: {0}")]
    Params(#[from] crate::kinematics::KinematicsError),
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
    /// A topic whose time goes back more than rarely: a recording in the wrong order.
    #[error(
        "topic `{topic}` goes back in time at message {index} (stamped {t_s:.3} s, at or \
before message {before}'s {before_s:.3} s), {count} of {total} messages in all: the recording is \
in the wrong order (split files listed out of order or twice, stamps reversed); give a bag \
whose messages go forward, or each run's files in order"
    )]
    TimeBackwards {
        /// The topic.
        topic: String,
        /// The first message that goes back (0-based on its topic).
        index: usize,
        /// Its time (s, the bag's clock).
        t_s: f64,
        /// The message kept before it.
        before: usize,
        /// That message's time (s).
        before_s: f64,
        /// How many messages go back.
        count: usize,
        /// Messages on the topic.
        total: usize,
    },
    /// A time range is not usable.
    #[error("time range {0}")]
    Range(String),
    /// A setting is out of its range (the flag is named).
    #[error("{0}")]
    Setting(String),
    /// The controller's YAML could not be used.
    #[error(transparent)]
    Yaml(#[from] crate::ros::yaml::YamlError),
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
    /// `odocal.heading_kind` from the bag's metadata, if a tool of ours wrote it.
    pub heading_kind: Option<crate::calibration::HeadingKind>,
    /// Choices made while reading (a topic found by its type).
    pub notes: Vec<String>,
}

/// A channel of a bag: a topic and what it carries.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Channel {
    /// The topic.
    pub topic: String,
    /// The message type as the bag names it (`sensor_msgs/msg/JointState`, or ROS 1's
    /// `sensor_msgs/JointState`).
    pub type_name: String,
    /// How messages are serialised: `cdr` (ROS 2) or `ros1`.
    pub encoding: String,
}

/// One message as its container hands it out.
#[derive(Debug, Clone, Copy)]
pub struct RawMessage<'a> {
    /// Its channel.
    pub channel: &'a Channel,
    /// When it was recorded (ns on the recorder's clock).
    pub log_time_ns: u64,
    /// The serialised message (a zstd frame when rosbag2 compressed it by message).
    pub data: &'a [u8],
}

/// A bag container format: what it holds and its messages in order.
pub trait Container {
    /// The format's name, for messages (`MCAP`).
    fn format(&self) -> &'static str;
    /// Every channel, when the container lists them before its messages (an index or a
    /// summary); `None` when they are only learnt while reading.
    fn channels(&self) -> Option<Vec<Channel>>;
    /// The key-value metadata record `name`, when the container has one (most have none).
    fn metadata(&self, _name: &str) -> Option<BTreeMap<String, String>> {
        None
    }
    /// Hands every message to `each`, in the container's order; an error of `each` ends it.
    fn messages(
        &self,
        each: &mut dyn FnMut(RawMessage<'_>) -> Result<(), BagError>,
    ) -> Result<(), BagError>;
    /// Choices made and things worth knowing about the container, once its messages are read
    /// (files found without metadata, data a reader leaves out).
    fn notes(&self) -> Vec<String> {
        Vec::new()
    }
}

/// An open bag of any container.
pub type Opened = Result<Box<dyn Container>, BagError>;

/// A container format a single file holds, told by its first bytes.
pub struct FileFormat {
    /// Its name, for messages.
    pub name: &'static str,
    /// The bytes every file of it starts with.
    pub magic: &'static [u8],
    /// The extension its files have (without the dot).
    pub extension: &'static str,
    /// Opens a file of it from its bytes (`path` names it in errors).
    pub open: fn(Vec<u8>, &Path) -> Opened,
    /// Opens a plain file of it where it lies (SQLite's pages, MCAP's and ROS 1's records as
    /// a stream).
    pub open_in_place: fn(&Path) -> Opened,
    /// Opens a file of it compressed whole, decompressed as it is read (into a temporary file
    /// for SQLite).
    pub open_whole: fn(&Path, compression::Whole) -> Opened,
}

/// Every single-file container format odocal reads.
pub const FILE_FORMATS: &[FileFormat] = &[
    FileFormat {
        name: "MCAP",
        magic: mcap::MAGIC,
        extension: "mcap",
        open: mcap::open,
        open_in_place: mcap::open_in_place,
        open_whole: mcap::open_whole,
    },
    #[cfg(feature = "bag-sqlite")]
    FileFormat {
        name: "sqlite3",
        magic: sqlite3::MAGIC,
        extension: "db3",
        open: sqlite3::open,
        open_in_place: sqlite3::open_in_place,
        open_whole: sqlite3::open_whole,
    },
    FileFormat {
        name: "ROS 1",
        magic: ros1::MAGIC,
        extension: "bag",
        open: ros1::open,
        open_in_place: ros1::open_in_place,
        open_whole: ros1::open_whole,
    },
];

/// The file formats this build leaves out, told by their first bytes: what each is and the
/// features it needs.
const NOT_BUILT: &[(&[u8], &str, &[&str])] = &[
    #[cfg(not(feature = "bag-sqlite"))]
    (
        b"SQLite format 3\0",
        "a sqlite3 bag (.db3)",
        &["bag-sqlite"],
    ),
];

/// The bag at `path`: a rosbag2 directory, or a single file of any format odocal reads (told
/// by its content), compressed whole (zstd, lz4) or not.
pub fn open_container(path: &Path) -> Result<Box<dyn Container>, BagError> {
    let meta = std::fs::metadata(path).map_err(|source| BagError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    if meta.is_dir() {
        return Ok(Box::new(rosbag2::Rosbag2Dir::open(path)?));
    }
    open_file(path)
}

/// One bag file (a regular file within [`crate::io::budget::BAG_FILE`]) opened as the format
/// its first bytes say: where it lies, or compressed whole (zstd, lz4) decompressed as it is
/// read. Never read into memory whole.
pub fn open_file(path: &Path) -> Result<Box<dyn Container>, BagError> {
    use std::io::Read;
    let io = |source| BagError::Io {
        path: path.to_path_buf(),
        source,
    };
    // Enough to tell a format by, and what a file that is none looks like.
    const HEAD: u64 = 512;
    let mut head = Vec::new();
    crate::io::open_bounded(path, crate::io::budget::BAG_FILE.get())
        .map_err(io)?
        .take(HEAD)
        .read_to_end(&mut head)
        .map_err(io)?;
    if let Some(format) = FILE_FORMATS.iter().find(|f| head.starts_with(f.magic)) {
        return (format.open_in_place)(path);
    }
    if let Some(whole) = compression::Whole::of(&head) {
        let inner = compression::head(path, whole, HEAD)?;
        if let Some(format) = FILE_FORMATS.iter().find(|f| inner.starts_with(f.magic)) {
            return (format.open_whole)(path, whole);
        }
        head = inner;
    }
    Err(unknown(&head, path))
}

/// The container of `bytes` (read from `path`, already decompressed), told by its content.
pub fn container_of(bytes: Vec<u8>, path: &Path) -> Result<Box<dyn Container>, BagError> {
    if let Some(format) = FILE_FORMATS.iter().find(|f| bytes.starts_with(f.magic)) {
        return (format.open)(bytes, path);
    }
    Err(unknown(&bytes, path))
}

/// The error for a file whose (decompressed) content starts with `bytes` and is no bag odocal
/// reads: what it looks like, and what its name promised.
fn unknown(bytes: &[u8], path: &Path) -> BagError {
    if let Some((_, what, features)) = NOT_BUILT.iter().find(|(m, ..)| bytes.starts_with(m)) {
        let what = format!("{}, {what},", path.display());
        return crate::features::NotBuilt::new(what, features).into();
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
    let name = path.file_name().map(|n| n.to_string_lossy().to_lowercase());
    let name = name.as_deref().unwrap_or_default();
    let name = [".zstd", ".lz4"]
        .iter()
        .find_map(|c| name.strip_suffix(c))
        .unwrap_or(name);
    if let Some(format) = FILE_FORMATS
        .iter()
        .find(|f| name.rsplit_once('.').is_some_and(|(_, e)| e == f.extension))
    {
        return BagError::Container {
            path: path.to_path_buf(),
            format: format.name,
            reason: format!(
                "it does not start with {}'s magic bytes (it starts {starts:?}{})",
                format.name,
                looks_like(bytes)
                    .map(|l| format!(", {l}"))
                    .unwrap_or_default()
            ),
        };
    }
    BagError::NotABag {
        path: path.to_path_buf(),
        starts,
        looks_like: looks_like(bytes),
    }
}

/// What a file that is no bag odocal reads looks like, by its first bytes.
fn looks_like(bytes: &[u8]) -> Option<&'static str> {
    const KNOWN: [(&[u8], &str); 7] = [
        (
            b"#ROSBAG V1.",
            "a ROS 1 bag of format 1.x: `rosbag fix` converts it to 2.0",
        ),
        (b"#ROSBAG V", "a ROS 1 bag of a format other than 2.0"),
        (&[0x1F, 0x8B], "gzip: decompress it first"),
        (b"BZh", "bzip2: decompress it first"),
        (
            &[0xFD, b'7', b'z', b'X', b'Z', 0],
            "xz: decompress it first",
        ),
        (b"PK\x03\x04", "a zip archive: extract it first"),
        (
            b"rosbag2_bagfile_information",
            "a rosbag2 metadata.yaml: give its directory",
        ),
    ];
    if bytes.is_empty() {
        return Some("an empty file");
    }
    if let Some((_, what)) = KNOWN.iter().find(|(magic, _)| bytes.starts_with(magic)) {
        return Some(what);
    }
    let head = &bytes[..bytes.len().min(512)];
    head.iter()
        .all(|&b| b.is_ascii_graphic() || b.is_ascii_whitespace())
        .then_some("text")
}
