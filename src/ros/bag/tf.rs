//! The TF tree as a pose reference: `base_link`'s pose in a fixed frame (`map`, `world`, a
//! motion-capture frame), from `/tf` and `/tf_static` (`tf2_msgs/TFMessage`), beside the wheel
//! joints, as the [`PoseRecording`] `odocal fit` takes.
//!
//! The chain is found by walking from the base frame up its parents to the fixed frame. Its
//! samples are taken at the stamps of its slowest moving link — typically the localization's
//! `map → odom`, stamped with the scan it came from — and every other moving link (the
//! controller's `odom → base_link`, published faster) is interpolated there: position linearly,
//! yaw along the shorter way. At those stamps the chain is the localization's own estimate of
//! the base; between them it would only be the controller's odometry, which must not be taken
//! for a reference. Static links are composed as they are. Planar: x, y and yaw of each link.

use super::decode::{check_channel, decode, stamp_or, Unzstd};
use super::reference::{on_one_clock, WheelReader};
use super::{open_container, BagError, BagOptions, Container, RawMessage};
use crate::calibration::pose_reference::{Pose2, PoseRecording, ReferencePose};
use crate::kinematics::wrap_angle;
use crate::ros::msg::{types, yaw_of, TfMessage};
use std::collections::BTreeMap;
use std::path::Path;

/// The TF topics read.
pub const TF_TOPICS: [&str; 2] = ["/tf", "/tf_static"];

/// A link's samples: time (s) and the child's pose in the parent.
type Link = Vec<(f64, Pose2)>;

/// A drive with the TF chain as its reference.
#[derive(Debug, Clone, PartialEq)]
pub struct TfDrive {
    /// The wheels and the chain's poses, on one clock.
    pub recording: PoseRecording,
    /// The chain, fixed frame first.
    pub chain: Vec<String>,
    /// Choices made while reading.
    pub notes: Vec<String>,
}

/// Reads the wheel joints and the chain from `fixed` to `base` from the bag at `path`.
pub fn read_tf_drive(
    path: &Path,
    opts: &BagOptions,
    fixed: &str,
    base: &str,
) -> Result<TfDrive, BagError> {
    read_tf_container(open_container(path)?.as_ref(), opts, fixed, base)
}

/// [`read_tf_drive`] of an open container.
pub fn read_tf_container(
    bag: &dyn Container,
    opts: &BagOptions,
    fixed: &str,
    base: &str,
) -> Result<TfDrive, BagError> {
    let mut notes = Vec::new();
    let joints_topic = opts.topics.joint_states.clone();
    let mut reader = TfReader::default();
    bag.messages(&mut |m| {
        crate::io::budget::charge_message(&|| format!("{} bag's messages", bag.format()))?;
        reader.take(m, &joints_topic, opts)
    })?;
    let TfReader {
        seen,
        wheels,
        links,
        statics,
        tf_messages,
        ..
    } = reader;
    notes.extend(bag.notes());
    let available: Vec<(String, String)> = seen.into_iter().collect();
    let wheels = wheels.finish(&joints_topic, &available, &mut notes)?;
    if tf_messages == 0 {
        return Err(BagError::MissingTopic {
            what: "TF",
            topic: "/tf".into(),
            available,
        });
    }
    let (chain, edges) = find_chain(&links, &statics, fixed, base)?;
    let moving = moving_links(&edges, &links);
    let stamps = moved_stamps(&moving, &chain, &mut notes)?;
    let poses = chain_poses(&stamps, &edges, &statics, &moving);
    let (mut recording, t0) = on_one_clock(wheels, poses.first().map(|p| p.0));
    for (t, p) in poses {
        recording.poses.push(ReferencePose {
            time_s: t - t0,
            x_m: p.x,
            y_m: p.y,
            yaw_rad: Some(wrap_angle(p.theta)),
            stated_std: None,
        });
    }
    Ok(TfDrive {
        recording,
        chain,
        notes,
    })
}

/// A link's key: its parent frame and its child frame.
type LinkKey = (String, String);

/// A chain's links, fixed frame first, each with whether it is static.
type Edges = Vec<(LinkKey, bool)>;

/// What reading a bag's messages gathers: the topics seen, the wheels and the TF links.
#[derive(Default)]
struct TfReader {
    /// Topic → type of every topic seen.
    seen: BTreeMap<String, String>,
    /// Undoes rosbag2's per-message compression.
    unzstd: Unzstd,
    /// The wheel joints.
    wheels: WheelReader,
    /// (parent, child) → samples of the moving links.
    links: BTreeMap<LinkKey, Link>,
    /// (parent, child) → pose of the static links; they keep their last value.
    statics: BTreeMap<LinkKey, Pose2>,
    /// Messages seen on the TF topics.
    tf_messages: usize,
}

impl TfReader {
    /// Takes one message: joints and TF messages are read, every topic is noted as seen.
    fn take(
        &mut self,
        m: RawMessage<'_>,
        joints_topic: &str,
        opts: &BagOptions,
    ) -> Result<(), BagError> {
        self.seen
            .entry(m.channel.topic.clone())
            .or_insert_with(|| m.channel.type_name.clone());
        let is_joints = m.channel.topic == joints_topic;
        let is_tf = TF_TOPICS.contains(&m.channel.topic.as_str());
        if !is_joints && !is_tf {
            return Ok(());
        }
        let index = if is_joints {
            self.wheels.messages
        } else {
            self.tf_messages
        };
        // Two TF topics share one count: every message's channel is checked (a comparison).
        let expected = if is_joints {
            types::JOINT_STATE
        } else {
            types::TF_MESSAGE
        };
        check_channel(m.channel, &[expected], expected)?;
        let data = self.unzstd.payload(&m, index)?;
        if is_joints {
            return self.wheels.add(&m, data, index, opts);
        }
        self.tf_messages += 1;
        let tf: TfMessage =
            decode(&m.channel.encoding, data).map_err(|source| BagError::Decode {
                topic: m.channel.topic.clone(),
                index,
                source,
            })?;
        let is_static = m.channel.topic == "/tf_static";
        self.add_transforms(tf, is_static, m.log_time_ns);
        Ok(())
    }

    /// Files a TF message's planar transforms as static or moving links (transforms whose
    /// rotation is not one are skipped).
    fn add_transforms(&mut self, tf: TfMessage, is_static: bool, log_time_ns: u64) {
        for t in tf.transforms {
            let Ok(yaw) = yaw_of(&t.transform.rotation) else {
                continue;
            };
            let pose = Pose2 {
                x: t.transform.translation.x,
                y: t.transform.translation.y,
                theta: yaw,
            };
            let key = (
                t.header.frame_id.trim_start_matches('/').to_string(),
                t.child_frame_id.trim_start_matches('/').to_string(),
            );
            if is_static {
                self.statics.insert(key, pose);
            } else {
                self.links
                    .entry(key)
                    .or_default()
                    .push((stamp_or(&t.header, log_time_ns), pose));
            }
        }
    }
}

/// The chain from `fixed` to `base` (fixed frame first) and its links, found by walking from
/// the base up its parents; an error when a frame has no parent or the tree has a loop.
fn find_chain(
    links: &BTreeMap<LinkKey, Link>,
    statics: &BTreeMap<LinkKey, Pose2>,
    fixed: &str,
    base: &str,
) -> Result<(Vec<String>, Edges), BagError> {
    // Walk from the base up its parents to the fixed frame.
    let parent_of = |child: &str| -> Option<(String, bool)> {
        links
            .keys()
            .find(|(_, c)| c == child)
            .map(|(p, _)| (p.clone(), false))
            .or_else(|| {
                statics
                    .keys()
                    .find(|(_, c)| c == child)
                    .map(|(p, _)| (p.clone(), true))
            })
    };
    let (fixed, base) = (fixed.trim_start_matches('/'), base.trim_start_matches('/'));
    let mut chain = vec![base.to_string()];
    let mut edges: Edges = Vec::new();
    while chain.last().map(String::as_str) != Some(fixed) {
        let child = chain.last().cloned().unwrap_or_default();
        let Some((parent, is_static)) = parent_of(&child) else {
            return Err(BagError::Inference(format!(
                "no TF chain from {fixed} to {base}: {child} has no parent in /tf or /tf_static \
                 (the bag's links: {}); give the fixed frame with --reference tf:FRAME, and \
                 record /tf_static with transient-local durability so that its links are kept",
                listed_links(links.keys().chain(statics.keys()))
            )));
        };
        if chain.contains(&parent) || chain.len() > 64 {
            return Err(BagError::Inference(format!(
                "the TF tree has a loop through {parent}; it is not a tree"
            )));
        }
        edges.push(((parent.clone(), child), is_static));
        chain.push(parent);
    }
    chain.reverse();
    edges.reverse();
    Ok((chain, edges))
}

/// Links named in an error at most: a tree of thousands of frames must not make a message of
/// thousands of lines.
const LINKS_LISTED: usize = 12;

/// The first [`LINKS_LISTED`] links as `parent → child`, and how many more there are.
fn listed_links<'k>(keys: impl Iterator<Item = &'k LinkKey>) -> String {
    let mut listed = Vec::new();
    let mut more = 0usize;
    for (p, c) in keys {
        if listed.len() < LINKS_LISTED {
            listed.push(format!("{p} → {c}"));
        } else {
            more += 1;
        }
    }
    if more > 0 {
        listed.push(format!("and {more} more"));
    }
    listed.join(", ")
}

/// Each moving link of the chain with its samples in time order, one per stamp.
fn moving_links<'e>(
    edges: &'e [(LinkKey, bool)],
    links: &BTreeMap<LinkKey, Link>,
) -> Vec<(&'e LinkKey, Link)> {
    let mut moving: Vec<(&LinkKey, Link)> = Vec::new();
    for (key, is_static) in edges {
        if !is_static {
            let mut s = links.get(key).cloned().unwrap_or_default();
            s.sort_by(|a, b| a.0.total_cmp(&b.0));
            s.dedup_by(|b, a| b.0 == a.0);
            moving.push((key, s));
        }
    }
    moving
}

/// The stamps the chain is sampled at: those where its slowest moving link moved, with a note
/// saying so; an error when every link of the chain is static.
fn moved_stamps(
    moving: &[(&LinkKey, Link)],
    chain: &[String],
    notes: &mut Vec<String>,
) -> Result<Vec<f64>, BagError> {
    // The slowest moving link's stamps are the samples.
    let Some(slowest) = moving.iter().min_by_key(|(_, s)| s.len()).map(|(k, _)| *k) else {
        return Err(BagError::Inference(format!(
            "the TF chain {} never moves (every link is static): it is no reference",
            chain.join(" → ")
        )));
    };
    // Only the stamps where the slowest link moved: a localization republishes its last
    // correction (slam_toolbox at a fixed rate, AMCL on every scan while its filter waits for
    // motion), and the chain at a republished stamp is the controller's own odometry.
    let (mut stamps, mut repeated) = (Vec::new(), 0usize);
    if let Some((_, s)) = moving.iter().find(|(k, _)| *k == slowest) {
        let mut last: Option<Pose2> = None;
        for (t, p) in s {
            if last.is_some_and(|q| q == *p) {
                repeated += 1;
                continue;
            }
            last = Some(*p);
            stamps.push(*t);
        }
    }
    notes.push(format!(
        "reference: the TF chain {} at the stamps where {} → {} moved ({} samples{}); a \
         localization's pose topic (/amcl_pose) is stamped at its scan and is the surer \
         reference where the bag has one",
        chain.join(" → "),
        slowest.0,
        slowest.1,
        stamps.len(),
        if repeated > 0 {
            format!(", {repeated} republished unchanged left out")
        } else {
            String::new()
        }
    ));
    Ok(stamps)
}

/// The chain's pose at each of `stamps`, its static links composed as they are and its moving
/// ones interpolated; stamps outside a moving link's samples are left out.
fn chain_poses(
    stamps: &[f64],
    edges: &[(LinkKey, bool)],
    statics: &BTreeMap<LinkKey, Pose2>,
    moving: &[(&LinkKey, Link)],
) -> Vec<(f64, Pose2)> {
    let mut poses = Vec::with_capacity(stamps.len());
    'stamp: for &t in stamps {
        let mut pose = Pose2::default();
        for (key, is_static) in edges {
            let link = if *is_static {
                statics.get(key).copied().unwrap_or_default()
            } else {
                let Some(s) = moving.iter().find(|(k, _)| *k == key).map(|(_, s)| s) else {
                    continue 'stamp;
                };
                match interpolate(s, t) {
                    Some(p) => p,
                    None => continue 'stamp,
                }
            };
            pose = pose.compose(&link);
        }
        poses.push((t, pose));
    }
    poses
}

/// A link's pose at `t`, between its samples; `None` outside them.
fn interpolate(s: &Link, t: f64) -> Option<Pose2> {
    let i = s.partition_point(|(ts, _)| *ts <= t);
    if i == 0 {
        return None;
    }
    let (ta, a) = s[i - 1];
    if ta == t || i == s.len() {
        return (ta == t).then_some(a);
    }
    let (tb, b) = s[i];
    let f = (t - ta) / (tb - ta);
    Some(Pose2 {
        x: a.x + f * (b.x - a.x),
        y: a.y + f * (b.y - a.y),
        theta: a.theta + f * wrap_angle(b.theta - a.theta),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_error_lists_a_dozen_links_of_a_large_tree_and_counts_the_rest() {
        let keys: Vec<LinkKey> = (0..10_000)
            .map(|i| ("world".to_string(), format!("frame_{i}")))
            .collect();
        let text = listed_links(keys.iter());
        assert!(text.ends_with(", and 9988 more"), "{text}");
        assert_eq!(text.matches(" → ").count(), LINKS_LISTED);
        let two = listed_links(keys[..2].iter());
        assert_eq!(two, "world → frame_0, world → frame_1");
    }
}
