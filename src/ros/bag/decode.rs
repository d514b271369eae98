//! Any container's messages into [`BagData`]: the three topics resolved (by name, or by type
//! when the name is not in the bag), their types checked, each message decoded from its wire
//! form (ROS 2's CDR, ROS 1's serialization; a message rosbag2 compressed on its own is
//! decompressed first), the wheel joints picked by name, joint angles unwrapped, every sample
//! on its header stamp (the log time where a header has none), and all of it in time order
//! from the bag's first message.

#[cfg(feature = "bag-compression")]
use super::compression::zstd_message;
use super::compression::ZSTD_MAGIC;
use super::validate::{self, Pose, Sample};
use super::{
    container_of, open_container, BagData, BagError, BagOptions, Channel, Container, JointSample,
    OdomSample, RawMessage, RosTopics, YawSample,
};
use crate::ros::msg::{cdr, ros1, types, yaw_of, Header, Imu, Odometry, WireError};
use serde::de::DeserializeOwned;
use std::collections::BTreeMap;
use std::path::Path;

/// Reads the wheel joints, IMU and odometry from the bag at `path`: a file of any format
/// odocal reads, or a rosbag2 directory.
pub fn read_bag(path: &Path, opts: &BagOptions) -> Result<BagData, BagError> {
    read_container(open_container(path)?.as_ref(), opts)
}

/// [`read_bag`] of one file's bytes in memory (`path` names them in errors).
pub fn read_bag_bytes(bytes: Vec<u8>, path: &Path, opts: &BagOptions) -> Result<BagData, BagError> {
    read_container(container_of(bytes, path)?.as_ref(), opts)
}

/// The wire forms odocal decodes, as channels name them.
const ENCODINGS: [&str; 2] = ["cdr", "ros1"];

/// Decodes one message in its channel's wire form.
pub(super) fn decode<T: DeserializeOwned>(encoding: &str, data: &[u8]) -> Result<T, WireError> {
    if encoding == "ros1" {
        Ok(ros1::decode(data)?)
    } else {
        Ok(cdr::decode(data)?)
    }
}

/// What a topic is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Role {
    Joints,
    Imu,
    Odom,
}

impl Role {
    const ALL: [Role; 3] = [Role::Joints, Role::Imu, Role::Odom];

    fn canonical(self) -> &'static str {
        match self {
            Role::Joints => types::JOINT_STATE,
            Role::Imu => types::IMU,
            Role::Odom => types::ODOMETRY,
        }
    }

    fn what(self) -> &'static str {
        match self {
            Role::Joints => "wheel joint",
            Role::Imu => "IMU",
            Role::Odom => "odometry",
        }
    }

    fn topic(self, t: &RosTopics) -> &str {
        match self {
            Role::Joints => &t.joint_states,
            Role::Imu => &t.imu,
            Role::Odom => &t.odom,
        }
    }
}

/// The message time: the header's stamp, or the log time when the header has none.
pub(super) fn stamp_or(h: &Header, log_time_ns: u64) -> f64 {
    if h.stamp.sec != 0 || h.stamp.nanosec != 0 {
        h.stamp.seconds()
    } else {
        log_time_ns as f64 * 1e-9
    }
}

/// The topics to read: as given, or — when a given topic is not in the bag and exactly one
/// channel carries the type it should — that channel (with a note saying so). Needs the
/// channels up front (rosbag2 writes a summary); without them the names are used as given.
fn resolve_topics(
    channels: Option<&[Channel]>,
    given: &RosTopics,
    notes: &mut Vec<String>,
) -> RosTopics {
    let Some(channels) = channels else {
        return given.clone();
    };
    let pick = |role: Role, notes: &mut Vec<String>| {
        let topic = role.topic(given);
        if channels.iter().any(|c| c.topic == topic) {
            return topic.to_string();
        }
        let of_type: Vec<&String> = channels
            .iter()
            .filter(|c| types::is(&c.type_name, role.canonical()))
            .map(|c| &c.topic)
            .collect();
        match of_type.as_slice() {
            [only] => {
                let what = match role {
                    Role::Joints => "wheel joints",
                    other => other.what(),
                };
                notes.push(format!("{what} from {only}: the bag has no {topic}"));
                (*only).clone()
            }
            _ => topic.to_string(),
        }
    };
    RosTopics {
        joint_states: pick(Role::Joints, notes),
        imu: pick(Role::Imu, notes),
        odom: pick(Role::Odom, notes),
    }
}

fn check_type(ch: &Channel, role: Role) -> Result<(), BagError> {
    check_channel(ch, &[role.canonical()], role.canonical())
}

/// Refuses a channel whose type is none of `accepted` or whose wire form odocal does not
/// decode, naming what it carries and what was `expected` there.
pub(super) fn check_channel(
    ch: &Channel,
    accepted: &[&str],
    expected: &'static str,
) -> Result<(), BagError> {
    if accepted.iter().any(|t| types::is(&ch.type_name, t))
        && ENCODINGS.contains(&ch.encoding.as_str())
    {
        Ok(())
    } else {
        Err(BagError::UnknownType {
            topic: ch.topic.clone(),
            type_name: ch.type_name.clone(),
            encoding: ch.encoding.clone(),
            expected,
        })
    }
}

/// Everything read so far.
#[derive(Default)]
struct Reading {
    counts: BTreeMap<&'static str, usize>,
    messages: u64,
    wheels: super::reference::WheelReader,
    imu: Vec<Sample<Option<f64>>>,
    odom: Vec<Sample<Pose>>,
    unzstd: Unzstd,
}

/// rosbag2's per-message compression undone: one zstd context and buffer for every message.
#[derive(Default)]
pub(super) struct Unzstd {
    #[cfg(feature = "bag-compression")]
    ctx: Option<zstd::bulk::Decompressor<'static>>,
    #[cfg(feature = "bag-compression")]
    buf: Vec<u8>,
}

impl Unzstd {
    /// The message's serialised bytes: its data, or what its zstd frame holds. (The channel
    /// of a message rosbag2 compressed still says `cdr`; a CDR payload starts with its
    /// encapsulation, 00 00 or 00 01, never with zstd's magic.)
    pub(super) fn payload<'a>(
        &'a mut self,
        m: &RawMessage<'a>,
        index: usize,
    ) -> Result<&'a [u8], BagError> {
        if m.channel.encoding != "cdr" || !m.data.starts_with(ZSTD_MAGIC) {
            return Ok(m.data);
        }
        let what = || format!("topic `{}` message {index}", m.channel.topic);
        #[cfg(not(feature = "bag-compression"))]
        return Err(crate::features::NotBuilt::new(
            format!("{}, compressed on its own with zstd,", what()),
            &["bag-compression"],
        )
        .into());
        #[cfg(feature = "bag-compression")]
        let err = |source| BagError::Zstd {
            what: what(),
            source,
        };
        #[cfg(feature = "bag-compression")]
        let ctx = match self.ctx.take() {
            Some(ctx) => ctx,
            None => zstd::bulk::Decompressor::new().map_err(err)?,
        };
        #[cfg(feature = "bag-compression")]
        {
            let ctx = self.ctx.insert(ctx);
            zstd_message(m.data, ctx, &mut self.buf).map_err(err)?;
            Ok(&self.buf)
        }
    }
}

impl Reading {
    fn imu(&mut self, imu: Imu, index: usize, log_ns: u64) {
        let yaw_rad = if imu.orientation_covariance[0] == -1.0 {
            None
        } else {
            yaw_of(&imu.orientation).ok()
        };
        self.imu.push(Sample {
            index,
            t: stamp_or(&imu.header, log_ns),
            value: yaw_rad,
        });
    }

    fn odom(&mut self, o: Odometry, index: usize, log_ns: u64) {
        let Ok(yaw_rad) = yaw_of(&o.pose.pose.orientation) else {
            return;
        };
        let p = &o.pose.pose.position;
        self.odom.push(Sample {
            index,
            t: stamp_or(&o.header, log_ns),
            value: (p.x, p.y, yaw_rad),
        });
    }

    fn message(
        &mut self,
        m: RawMessage<'_>,
        role: Role,
        opts: &BagOptions,
    ) -> Result<(), BagError> {
        let index = {
            let n = self.counts.entry(role.what()).or_default();
            *n += 1;
            *n - 1
        };
        self.messages += 1;
        if index == 0 {
            check_type(m.channel, role)?;
        }
        let decode_err = |source| BagError::Decode {
            topic: m.channel.topic.clone(),
            index,
            source,
        };
        // Taken out of `self` while `data` may borrow it.
        let mut unzstd = std::mem::take(&mut self.unzstd);
        let data = unzstd.payload(&m, index)?;
        let enc = m.channel.encoding.as_str();
        let result = match role {
            Role::Joints => {
                decode(enc, data).map(|js| self.wheels.push(js, index, m.log_time_ns, opts))
            }
            Role::Imu => decode(enc, data).map(|imu| self.imu(imu, index, m.log_time_ns)),
            Role::Odom => decode(enc, data).map(|o| self.odom(o, index, m.log_time_ns)),
        };
        self.unzstd = unzstd;
        result.map_err(decode_err)
    }
}

/// Reads the three topics of any container.
pub fn read_container(bag: &dyn Container, opts: &BagOptions) -> Result<BagData, BagError> {
    let mut notes = Vec::new();
    let listed = bag.channels();
    let topics = resolve_topics(listed.as_deref(), &opts.topics, &mut notes);
    let mut seen: BTreeMap<String, String> = listed
        .unwrap_or_default()
        .into_iter()
        .map(|c| (c.topic, c.type_name))
        .collect();
    let mut r = Reading::default();
    bag.messages(&mut |m| {
        crate::io::budget::charge_message(&|| format!("{} bag's messages", bag.format()))?;
        seen.entry(m.channel.topic.clone())
            .or_insert_with(|| m.channel.type_name.clone());
        match Role::ALL
            .into_iter()
            .find(|role| role.topic(&topics) == m.channel.topic)
        {
            Some(role) => r.message(m, role, opts),
            None => Ok(()),
        }
    })?;
    notes.extend(bag.notes());
    let available: Vec<(String, String)> = seen.into_iter().collect();
    let missing = |role: Role| BagError::MissingTopic {
        what: role.what(),
        topic: role.topic(&topics).to_string(),
        available: available.clone(),
    };
    let count = |role: Role| r.counts.get(role.what()).copied().unwrap_or(0);
    let joints = r
        .wheels
        .finish(&topics.joint_states, &available, &mut notes)?;
    if count(Role::Imu) == 0 {
        return Err(missing(Role::Imu));
    }
    // Each stream checked in the order the container gave it (time forward, physical, no
    // spike), which also leaves it in time order.
    let imu = validate::yaw(r.imu, &topics.imu, &mut notes)?;
    let odom = validate::odometry(r.odom, &topics.odom, &mut notes)?;
    let t0 = joints
        .first()
        .map(|s| s.t)
        .into_iter()
        .chain(imu.first().map(|s| s.t))
        .chain(odom.first().map(|s| s.t))
        .fold(f64::INFINITY, f64::min);
    Ok(BagData {
        joints: joints
            .into_iter()
            .map(|j| JointSample {
                t: j.t - t0,
                left_rad: j.value.0,
                right_rad: j.value.1,
            })
            .collect(),
        imu: imu
            .into_iter()
            .map(|y| YawSample {
                t: y.t - t0,
                yaw_rad: y.value,
            })
            .collect(),
        odom: odom
            .into_iter()
            .map(|o| OdomSample {
                t: o.t - t0,
                x_m: o.value.0,
                y_m: o.value.1,
                yaw_rad: o.value.2,
            })
            .collect(),
        topics: available,
        messages: r.messages,
        side_m: bag
            .metadata("odocal")
            .and_then(|m| m.get("side_m").and_then(|v| v.parse::<f64>().ok()))
            .filter(|s| s.is_finite() && *s > 0.0),
        heading_kind: bag
            .metadata("odocal")
            .and_then(|m| m.get("heading_kind").and_then(|v| v.parse().ok())),
        notes,
    })
}
