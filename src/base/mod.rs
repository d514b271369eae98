//! The seam between the calibration routine and a robot: a [`Base`] is a [`Drive`], a
//! [`HeadingSource`] and a [`ParamStore`], each of which may be a different device or file.
//!
//! Everything crossing the seam is in SI units on the conventions of [`crate::kinematics`]
//! (x forward, y left, headings counter-clockwise positive in radians wrapped to (−π, π]).
//! A backend converts its own units (encoder counts, compass azimuths, wire fixed point) on
//! its side. The routine ([`crate::routine`]) sees nothing but these traits, so a new robot
//! is one new backend: implement the three traits (or the ones it provides and compose the
//! rest from other devices or files) and hand a [`Base`] to the routine.
//!
//! Parameters are written only through a [`transaction::Transaction`]: backup, write, read
//! back, commit, read back the committed copy, and roll back on any failure.

pub mod adjusted;
pub mod drive_backend;
pub mod error;
pub mod fanout;
pub mod file_store;
pub mod guard;
pub mod heading_backend;
pub mod latest;
pub mod port_spec;
pub mod restore;
pub mod store_backend;
pub mod transaction;
pub mod write;

pub use error::BaseError;
pub use fanout::Fanout;
pub use file_store::{FileStore, ParamFile};
pub use guard::MotionGuard;

use crate::kinematics::{Pose, WheelParams};
pub use crate::samples::{
    Clocks, HeadingKind, HeadingSample, ReferencePose, TravelSample, Validity,
};
use async_trait::async_trait;
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::mpsc;

/// Most samples a stream buffers for a slow reader; beyond it samples are dropped (and a
/// backend says so in its diagnostics), so a reader that stalls cannot exhaust memory.
pub const STREAM_CAPACITY: usize = 1 << 16;

/// Samples from a drive or heading source, in the order they were taken.
pub type SampleStream<T> = mpsc::Receiver<T>;

/// What a component says about itself, for reports and backups.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ComponentInfo {
    /// The kind of backend (`odocal-protocol`, `simulated`, `ros2-yaml`, …).
    pub kind: String,
    /// Which one: a port, a file path, a serial number.
    pub id: String,
    /// Anything else worth keeping in a report (firmware, versions, limits).
    pub details: serde_json::Value,
}

/// What a drive's own odometry (with the parameters it is configured with) saw of one motion.
pub type Achieved = crate::kinematics::Displacement;

/// What the routine learns from a drive's pre-flight check.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Preflight {
    /// Problems that forbid moving (faults, encoders not answering).
    pub faults: Vec<String>,
    /// Observations worth a warning (no watchdog, low battery).
    pub warnings: Vec<String>,
}

/// The part of a robot that moves: open-loop motions computed from the parameters the robot
/// is configured with, and the wheel travel its encoders report.
///
/// Motions **move the robot**. Each motion call returns when the motion has finished (or
/// fails); dropping its future must not leave the robot driving for longer than the device's
/// watchdog — callers wrap motions in a [`MotionGuard`], which calls [`Drive::emergency_stop`].
#[async_trait]
pub trait Drive: Send + Sync {
    /// Describes the drive.
    fn info(&self) -> ComponentInfo;

    /// Whether the drive executes every motion as wheel targets in whole encoder counts, as
    /// the parameters convert them (so each motion is off by up to half a count, the same
    /// way every time: the plan counts it). A drive that follows velocity commands for a time
    /// does not.
    fn rounds_to_counts(&self) -> bool {
        false
    }

    /// Checks the drive can move: encoders answer, no faults.
    async fn preflight(&self) -> Result<Preflight, BaseError>;

    /// Arms the device's dead-man timer so the base stops by itself if the host goes away.
    /// Returns the timeout applied, or `None` when the device has no such timer.
    async fn arm_watchdog(&self, timeout: Duration) -> Result<Option<Duration>, BaseError>;

    /// **Moves the robot**: straight by `distance_m` (negative backwards) at most
    /// `max_speed_m_s`; returns when the drive reports the motion finished, with what its own
    /// odometry saw when that can differ from the command (`None`: executed to the drive's
    /// resolution, as a controller that counts wheel targets does).
    async fn move_straight(
        &self,
        distance_m: f64,
        max_speed_m_s: f64,
    ) -> Result<Option<Achieved>, BaseError>;

    /// **Moves the robot**: turns in place by `angle_rad` (counter-clockwise positive) at most
    /// `max_rate_rad_s`; returns as [`Drive::move_straight`] does.
    async fn turn_in_place(
        &self,
        angle_rad: f64,
        max_rate_rad_s: f64,
    ) -> Result<Option<Achieved>, BaseError>;

    /// Stops the base and waits for the drive to acknowledge.
    async fn stop(&self) -> Result<(), BaseError>;

    /// Tells the base to stop at once, without waiting: safe from `Drop` and signal handlers.
    fn emergency_stop(&self);

    /// Wheel travel from now on, sampled about every `period` (the drive may choose another
    /// rate), or `None` when the drive cannot stream.
    async fn travel(
        &self,
        period: Duration,
    ) -> Result<Option<SampleStream<TravelSample>>, BaseError>;

    /// Link or device health worth keeping in a report.
    fn diagnostics(&self) -> serde_json::Value {
        serde_json::Value::Null
    }

    /// The clock [`TravelSample::time_s`] is on ([`HeadingSource::clock`] explains); `None`:
    /// a clock of its own.
    fn clock(&self) -> Option<String> {
        None
    }
}

/// An external reference of where a frame on the robot is (a localization, motion capture):
/// the reference beside the heading that also observes the wheels' absolute scale. Its poses
/// follow [`crate::calibration::pose_reference`]'s conventions (the reference frame's pose in
/// a fixed world frame, the frame's mounting on the robot unknown).
#[async_trait]
pub trait PoseSource: Send + Sync {
    /// Describes the source.
    fn info(&self) -> ComponentInfo;

    /// Poses from now on, as the reference gives them.
    async fn stream(&self) -> Result<SampleStream<ReferencePose>, BaseError>;

    /// The clock the poses are stamped on, by name ([`HeadingSource::clock`] explains).
    fn clock(&self) -> Option<String> {
        None
    }
}

/// A compass, IMU or any sensor of absolute heading.
#[async_trait]
pub trait HeadingSource: Send + Sync {
    /// Describes the source.
    fn info(&self) -> ComponentInfo;

    /// A reading taken after the call, never one an earlier call returned (averaging at rest
    /// counts distinct readings: a cached message returned twice would halve the noise it
    /// reports); an invalid one is returned as such, not as an error.
    async fn read(&self) -> Result<HeadingSample, BaseError>;

    /// Readings from now on, about every `period`, or `None` when the source cannot stream.
    async fn stream(
        &self,
        period: Duration,
    ) -> Result<Option<SampleStream<HeadingSample>>, BaseError>;

    /// What the sensor measures (a compass may deviate, a gyro's scale enters `E_b`); a
    /// backend that cannot know says [`HeadingKind::Unknown`], and the user can declare it
    /// ([`adjusted::Adjusted`]).
    fn kind(&self) -> HeadingKind {
        HeadingKind::Unknown
    }

    /// The clock [`HeadingSample::time_s`] is on, by name: a drive and a heading source that
    /// name the same clock stamp comparable times (one device; header stamps of one robot;
    /// [`HOST_CLOCK`] for devices this host stamps). `None`: a clock of its own, known to no
    /// other component.
    fn clock(&self) -> Option<String> {
        None
    }
}

/// The name of the clock [`host_time_s`] reads.
pub const HOST_CLOCK: &str = "host";

/// Seconds on this host's clock, one epoch for the whole process: what backends that stamp
/// samples on arrival (a compass on a serial line, a controller that is polled) use, so that
/// their streams share a clock.
pub fn host_time_s() -> f64 {
    static EPOCH: std::sync::OnceLock<tokio::time::Instant> = std::sync::OnceLock::new();
    EPOCH
        .get_or_init(tokio::time::Instant::now)
        .elapsed()
        .as_secs_f64()
}

/// Where the robot keeps its wheel parameters: device memory with a committed copy, or a file.
///
/// `write` changes what the robot uses now (device RAM; for a file, the staged content);
/// `commit` makes it survive a restart (device storage; for a file, the atomic replace).
/// Write through the write service ([`mod@write`]) rather than these calls directly: it backs up
/// first, reads back, and undoes the write on failure.
#[async_trait]
pub trait ParamStore: Send + Sync {
    /// Describes the store (its `id` names backups).
    fn info(&self) -> ComponentInfo;

    /// The parameters in use now.
    async fn read(&self) -> Result<WheelParams, BaseError>;

    /// Sets the parameters in use; returns them as the store holds them (rounded to its
    /// resolution).
    async fn write(&self, params: &WheelParams) -> Result<WheelParams, BaseError>;

    /// Makes the parameters in use persistent.
    async fn commit(&self) -> Result<(), BaseError>;

    /// The persistent copy, or `None` when nothing was ever committed.
    async fn read_committed(&self) -> Result<Option<WheelParams>, BaseError>;

    /// Smallest difference the store can represent, per field (diameters and wheelbase in
    /// metres, counts per revolution): read-backs are compared to this.
    fn resolution(&self) -> WheelParams;

    /// Proves, changing nothing, that `params` could be written and committed, so that a store
    /// that cannot take them is refused before the robot moves ([`BaseError::Unwritable`]). A
    /// file store renders them into its text in memory and checks that its directory takes
    /// new files; a device has nothing to prove ahead (the default).
    async fn check_write(&self, params: &WheelParams) -> Result<(), BaseError> {
        let _ = params;
        Ok(())
    }

    /// The file the parameters live in, for a store that is a file (a robot profile, a
    /// controller's YAML): its backups and a run's partial reports are named after it
    /// ([`transaction::store_prefix`]), and a command that writes it alone keeps its backup
    /// beside it ([`transaction::backup_dir_for`]). `None` for a device (the default).
    fn file(&self) -> Option<std::path::PathBuf> {
        None
    }

    /// For a store that is a file, the keys whose lines a write changes
    /// ([`file_store::ParamFile::written_keys`]); none for a device (the default).
    fn written_keys(&self) -> &'static [&'static str] {
        &[]
    }
}

/// Where the robot truly is: known only in simulation, where it gives reports true end points,
/// `E_max,sys` and true paths. Real bases do not implement it.
pub trait GroundTruth: Send + Sync {
    /// The robot's true pose now.
    fn pose(&self) -> Pose;
    /// The robot's true parameters.
    fn true_params(&self) -> WheelParams;
}

/// Opens the parameter store afresh after the link to it was lost (a device that reset or
/// vanished, a cable re-plugged): the routine calls it once when a rollback failed, so that
/// it can restore the backup, or at least say truthfully what the store holds.
pub type Reconnect = Arc<
    dyn Fn() -> std::pin::Pin<
            Box<dyn std::future::Future<Output = Result<Arc<dyn ParamStore>, BaseError>> + Send>,
        > + Send
        + Sync,
>;

/// A robot as the routine sees it: one drive, one heading source, one parameter store.
#[derive(Clone)]
pub struct Base {
    /// What moves and counts wheel travel.
    pub drive: Arc<dyn Drive>,
    /// What measures the heading.
    pub heading: Arc<dyn HeadingSource>,
    /// Where the parameters live.
    pub store: Arc<dyn ParamStore>,
    /// How to reach the store again after its link was lost, when the backend can.
    pub reconnect: Option<Reconnect>,
}

/// The three components' descriptions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BaseInfo {
    /// The drive.
    pub drive: ComponentInfo,
    /// The heading source.
    pub heading: ComponentInfo,
    /// The parameter store.
    pub store: ComponentInfo,
}

/// "drive KIND ID; heading KIND ID; parameters in KIND ID": what connected, in a line.
impl std::fmt::Display for BaseInfo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (d, h, s) = (&self.drive, &self.heading, &self.store);
        write!(
            f,
            "drive {} {}; heading {} {}; parameters in {} {}",
            d.kind, d.id, h.kind, h.id, s.kind, s.id
        )
    }
}

impl Base {
    /// Composes a base from three components (which may be one device, several, or files).
    pub fn new(
        drive: Arc<dyn Drive>,
        heading: Arc<dyn HeadingSource>,
        store: Arc<dyn ParamStore>,
    ) -> Self {
        Base {
            drive,
            heading,
            store,
            reconnect: None,
        }
    }

    /// The same base, able to reopen its store after the link was lost (see [`Reconnect`]).
    pub fn with_reconnect(mut self, reconnect: Reconnect) -> Self {
        self.reconnect = Some(reconnect);
        self
    }

    /// A base whose one device is drive, heading source and store at once.
    pub fn single<T>(device: T) -> Self
    where
        T: Drive + HeadingSource + ParamStore + 'static,
    {
        let d = Arc::new(device);
        Base {
            drive: d.clone(),
            heading: d.clone(),
            store: d,
            reconnect: None,
        }
    }

    /// How the drive's travel and the heading source's readings are stamped: on one clock
    /// when both name it, else each on its own.
    pub fn clocks(&self) -> Clocks {
        match (self.drive.clock(), self.heading.clock()) {
            (Some(a), Some(b)) if a == b => Clocks::Shared,
            _ => Clocks::StartedTogether,
        }
    }

    /// How the drive's travel and a pose reference's poses are stamped ([`Base::clocks`]).
    pub fn clocks_with(&self, poses: &dyn PoseSource) -> Clocks {
        match (self.drive.clock(), poses.clock()) {
            (Some(a), Some(b)) if a == b => Clocks::Shared,
            _ => Clocks::StartedTogether,
        }
    }

    /// The components' descriptions.
    pub fn info(&self) -> BaseInfo {
        BaseInfo {
            drive: self.drive.info(),
            heading: self.heading.info(),
            store: self.store.info(),
        }
    }
}

/// Equal within a store's resolution, field by field.
pub fn same_within(a: &WheelParams, b: &WheelParams, resolution: &WheelParams) -> bool {
    // One full step, not half: the store rounds, and the conversion back may add an ulp.
    let close = |x: f64, y: f64, r: f64| (x - y).abs() <= r + 1e-12 * x.abs().max(1.0);
    close(
        a.left_wheel_diameter_m,
        b.left_wheel_diameter_m,
        resolution.left_wheel_diameter_m,
    ) && close(
        a.right_wheel_diameter_m,
        b.right_wheel_diameter_m,
        resolution.right_wheel_diameter_m,
    ) && close(a.wheelbase_m, b.wheelbase_m, resolution.wheelbase_m)
        && close(
            a.counts_per_wheel_rev,
            b.counts_per_wheel_rev,
            resolution.counts_per_wheel_rev,
        )
}
