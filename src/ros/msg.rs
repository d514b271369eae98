//! The ROS message types odocal reads and writes, field for field as ROS 2 defines them, so one
//! serde derive serves rosbridge's JSON, a ROS 2 bag's CDR ([`cdr`]) and a ROS 1 bag's
//! serialization ([`ros1`]). ROS 1 JSON (rosbridge on ROS 1) is read too: `secs`/`nsecs` stamps
//! and the header's `seq` are accepted.
//!
//! Sign conventions are ROS's (REP 103), which are ours: x forward, y left, yaw
//! counter-clockwise positive. [`yaw_of`] is the one place a quaternion becomes a heading.

use crate::kinematics::wrap_angle;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

pub mod ros1;

/// A message that does not decode from, or encode to, its wire form.
#[derive(Debug, thiserror::Error)]
pub enum WireError {
    /// ROS 2's CDR.
    #[error(transparent)]
    Cdr(#[from] cdr::CdrError),
    /// ROS 1 serialization.
    #[error(transparent)]
    Ros1(#[from] ros1::Ros1Error),
}

/// `builtin_interfaces/Time`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Time {
    /// Seconds.
    #[serde(alias = "secs")]
    pub sec: i32,
    /// Nanoseconds.
    #[serde(alias = "nsecs")]
    pub nanosec: u32,
}

impl Time {
    /// Seconds as a float.
    pub fn seconds(&self) -> f64 {
        f64::from(self.sec) + f64::from(self.nanosec) * 1e-9
    }

    /// The stamp for `t` seconds (clamped to the representable range).
    pub fn from_seconds(t: f64) -> Self {
        let t = if t.is_finite() { t.max(0.0) } else { 0.0 };
        let sec = t.floor().min(f64::from(i32::MAX));
        Time {
            sec: sec as i32,
            nanosec: (((t - sec) * 1e9).round() as u32).min(999_999_999),
        }
    }
}

/// `std_msgs/Header`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// Time of the measurement.
    pub stamp: Time,
    /// Frame (odocal does not use it).
    #[serde(default, deserialize_with = "lenient::unused")]
    pub frame_id: String,
}

/// `geometry_msgs/Vector3` (also `Point`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    /// x.
    #[serde(deserialize_with = "lenient::float")]
    pub x: f64,
    /// y.
    #[serde(deserialize_with = "lenient::float")]
    pub y: f64,
    /// z.
    #[serde(deserialize_with = "lenient::float")]
    pub z: f64,
}

/// `geometry_msgs/Quaternion`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    /// x.
    #[serde(deserialize_with = "lenient::float")]
    pub x: f64,
    /// y.
    #[serde(deserialize_with = "lenient::float")]
    pub y: f64,
    /// z.
    #[serde(deserialize_with = "lenient::float")]
    pub z: f64,
    /// w.
    #[serde(deserialize_with = "lenient::float")]
    pub w: f64,
}

impl Default for Quaternion {
    fn default() -> Self {
        Quaternion::from_yaw(0.0)
    }
}

impl Quaternion {
    /// A rotation about z by `yaw_rad`.
    pub fn from_yaw(yaw_rad: f64) -> Self {
        Quaternion {
            x: 0.0,
            y: 0.0,
            z: (0.5 * yaw_rad).sin(),
            w: (0.5 * yaw_rad).cos(),
        }
    }
}

/// The yaw (rad, counter-clockwise positive, wrapped to (−π, π]) of an orientation, or why it
/// has none: not finite, not a rotation (norm far from 1), or pointing up or down so that yaw
/// is undefined. Wrap-safe: the result never jumps by 2π for orientations near ±π.
pub fn yaw_of(q: &Quaternion) -> Result<f64, &'static str> {
    let n2 = q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w;
    if !n2.is_finite() {
        return Err("orientation is not finite");
    }
    if (n2 - 1.0).abs() > 0.1 {
        return Err("orientation is not a unit quaternion");
    }
    let siny = 2.0 * (q.w * q.z + q.x * q.y);
    let cosy = n2 - 2.0 * (q.y * q.y + q.z * q.z);
    if siny.hypot(cosy) < 1e-6 {
        return Err("orientation is vertical: yaw is undefined");
    }
    Ok(wrap_angle(siny.atan2(cosy)))
}

/// The change of a wheel angle between two joint-state samples, unwrapped: drivers that
/// publish continuous joints wrapped to (−π, π] jump by 2π once a turn, which no wheel turns
/// in one sample.
pub fn angle_step(from: f64, to: f64) -> f64 {
    let d = to - from;
    if d.abs() > std::f64::consts::PI {
        d - std::f64::consts::TAU * (d / std::f64::consts::TAU).round()
    } else {
        d
    }
}

/// A fixed array of 36 covariances (serde's derives stop at 32).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Covariance36(pub [f64; 36]);

impl Default for Covariance36 {
    fn default() -> Self {
        Covariance36([0.0; 36])
    }
}

impl Serialize for Covariance36 {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeTuple;
        let mut t = s.serialize_tuple(36)?;
        for v in &self.0 {
            t.serialize_element(v)?;
        }
        t.end()
    }
}

impl<'de> Deserialize<'de> for Covariance36 {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> serde::de::Visitor<'de> for V {
            type Value = Covariance36;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("36 numbers")
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                mut a: A,
            ) -> Result<Covariance36, A::Error> {
                let mut out = [0.0; 36];
                for (i, v) in out.iter_mut().enumerate() {
                    *v = a
                        .next_element::<lenient::Float>()?
                        .ok_or_else(|| serde::de::Error::invalid_length(i, &self))?
                        .0;
                }
                Ok(Covariance36(out))
            }
        }
        d.deserialize_tuple(36, V)
    }
}

/// `sensor_msgs/JointState`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct JointState {
    /// Header.
    pub header: Header,
    /// Joint names.
    pub name: Vec<String>,
    /// Positions (rad for revolute joints).
    #[serde(deserialize_with = "lenient::floats")]
    pub position: Vec<f64>,
    /// Velocities (rad/s).
    #[serde(default, deserialize_with = "lenient::unused_floats")]
    pub velocity: Vec<f64>,
    /// Efforts (joint_state_broadcaster fills them with NaN for wheels without an effort
    /// interface; odocal does not use them).
    #[serde(default, deserialize_with = "lenient::unused_floats")]
    pub effort: Vec<f64>,
}

impl JointState {
    /// The indices of the left and right wheel joints: the names given, or else the one name
    /// containing "left" and the one containing "right" (case ignored); `None` when either
    /// is missing or ambiguous, or both are one joint.
    pub fn wheel_indices(
        &self,
        left: &Option<String>,
        right: &Option<String>,
    ) -> Option<(usize, usize)> {
        let find = |given: &Option<String>, side: &str| match given {
            Some(g) => self.name.iter().position(|n| n == g),
            None => {
                let mut hits = (0..self.name.len())
                    .filter(|&i| self.name[i].to_ascii_lowercase().contains(side));
                match (hits.next(), hits.next()) {
                    (Some(i), None) => Some(i),
                    _ => None,
                }
            }
        };
        let (l, r) = (find(left, "left")?, find(right, "right")?);
        (l != r).then_some((l, r))
    }
}

/// `sensor_msgs/Imu`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Imu {
    /// Header.
    pub header: Header,
    /// Orientation.
    pub orientation: Quaternion,
    /// Orientation covariance; element 0 = −1 means "no orientation" (REP 145).
    #[serde(deserialize_with = "lenient::floats9")]
    pub orientation_covariance: [f64; 9],
    /// Angular velocity (rad/s; odocal does not use it).
    #[serde(default, deserialize_with = "lenient::unused")]
    pub angular_velocity: Vector3,
    /// Its covariance (unused).
    #[serde(default, deserialize_with = "lenient::unused_floats9")]
    pub angular_velocity_covariance: [f64; 9],
    /// Linear acceleration (m/s²; unused).
    #[serde(default, deserialize_with = "lenient::unused")]
    pub linear_acceleration: Vector3,
    /// Its covariance (unused).
    #[serde(default, deserialize_with = "lenient::unused_floats9")]
    pub linear_acceleration_covariance: [f64; 9],
}

/// `geometry_msgs/Pose`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// Position.
    pub position: Vector3,
    /// Orientation.
    pub orientation: Quaternion,
}

/// `geometry_msgs/PoseWithCovariance`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct PoseWithCovariance {
    /// Pose.
    pub pose: Pose,
    /// Covariance, row-major over (x, y, z, roll, pitch, yaw): a pose reference's samples are
    /// weighted by its x, y and yaw variances.
    #[serde(default, deserialize_with = "lenient::unused")]
    pub covariance: Covariance36,
}

/// `geometry_msgs/PoseStamped`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PoseStamped {
    /// Header.
    pub header: Header,
    /// Pose.
    pub pose: Pose,
}

/// `geometry_msgs/PoseWithCovarianceStamped` (e.g. `/amcl_pose`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PoseWithCovarianceStamped {
    /// Header.
    pub header: Header,
    /// Pose and its covariance.
    pub pose: PoseWithCovariance,
}

/// `geometry_msgs/Transform`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Transform {
    /// Translation (m).
    pub translation: Vector3,
    /// Rotation.
    pub rotation: Quaternion,
}

/// `geometry_msgs/TransformStamped`: the pose of `child_frame_id` in `header.frame_id`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TransformStamped {
    /// Header: the stamp and the parent frame.
    pub header: Header,
    /// The child frame.
    pub child_frame_id: String,
    /// The child's pose in the parent.
    pub transform: Transform,
}

/// `tf2_msgs/TFMessage` (`/tf`, `/tf_static`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TfMessage {
    /// The transforms.
    pub transforms: Vec<TransformStamped>,
}

/// `geometry_msgs/Twist`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Twist {
    /// Linear velocity (m/s).
    pub linear: Vector3,
    /// Angular velocity (rad/s).
    pub angular: Vector3,
}

impl Twist {
    /// Forward speed `v` and yaw rate `w` of a planar base.
    pub fn planar(v_m_s: f64, w_rad_s: f64) -> Self {
        Twist {
            linear: Vector3 {
                x: v_m_s,
                ..Vector3::default()
            },
            angular: Vector3 {
                z: w_rad_s,
                ..Vector3::default()
            },
        }
    }

    /// Whether every component is zero (a stop command).
    pub fn is_zero(&self) -> bool {
        [
            self.linear.x,
            self.linear.y,
            self.linear.z,
            self.angular.x,
            self.angular.y,
            self.angular.z,
        ]
        .iter()
        .all(|v| *v == 0.0)
    }
}

/// `geometry_msgs/TwistWithCovariance`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct TwistWithCovariance {
    /// Twist.
    pub twist: Twist,
    /// Covariance.
    pub covariance: Covariance36,
}

/// `geometry_msgs/TwistStamped`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TwistStamped {
    /// Header.
    pub header: Header,
    /// Twist.
    pub twist: Twist,
}

/// `nav_msgs/Odometry`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Odometry {
    /// Header.
    pub header: Header,
    /// Child frame (unused).
    #[serde(default, deserialize_with = "lenient::unused")]
    pub child_frame_id: String,
    /// Pose in the odometry frame.
    pub pose: PoseWithCovariance,
    /// Twist in the child frame (odocal ends motions on the pose; unused).
    #[serde(default, deserialize_with = "lenient::unused")]
    pub twist: TwistWithCovariance,
}

/// Floats as rosbridge really sends them in JSON: a NaN or infinite scalar, or element of a
/// variable-length array, as `null`; elements of fixed-size arrays (covariances) as the bare
/// tokens `NaN`, `Infinity`, `-Infinity` (rosbridge_suite #916), which [`lenient::json`]
/// turns into strings first; integers where floats are meant. Binary formats (CDR, ROS 1) are
/// read as they are: these only apply to self-describing input.
pub mod lenient {
    use serde::de::{Deserialize, DeserializeOwned, Deserializer, Error, Visitor};
    use std::borrow::Cow;
    use std::fmt;

    /// One float as rosbridge sends it.
    #[derive(Debug, Clone, Copy, PartialEq)]
    pub struct Float(pub f64);

    struct FloatVisitor;

    impl<'de> Visitor<'de> for FloatVisitor {
        type Value = Float;
        fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            f.write_str("a number, null, or NaN/Infinity/-Infinity")
        }
        fn visit_f64<E: Error>(self, v: f64) -> Result<Float, E> {
            Ok(Float(v))
        }
        fn visit_i64<E: Error>(self, v: i64) -> Result<Float, E> {
            Ok(Float(v as f64))
        }
        fn visit_u64<E: Error>(self, v: u64) -> Result<Float, E> {
            Ok(Float(v as f64))
        }
        fn visit_unit<E: Error>(self) -> Result<Float, E> {
            Ok(Float(f64::NAN))
        }
        fn visit_none<E: Error>(self) -> Result<Float, E> {
            Ok(Float(f64::NAN))
        }
        fn visit_str<E: Error>(self, v: &str) -> Result<Float, E> {
            match v {
                "NaN" | "nan" => Ok(Float(f64::NAN)),
                "Infinity" | "inf" => Ok(Float(f64::INFINITY)),
                "-Infinity" | "-inf" => Ok(Float(f64::NEG_INFINITY)),
                _ => Err(E::invalid_value(serde::de::Unexpected::Str(v), &self)),
            }
        }
    }

    impl<'de> Deserialize<'de> for Float {
        fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Float, D::Error> {
            if d.is_human_readable() {
                d.deserialize_any(FloatVisitor)
            } else {
                f64::deserialize(d).map(Float)
            }
        }
    }

    /// A float field.
    pub fn float<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Float::deserialize(d).map(|f| f.0)
    }

    /// A variable-length float array.
    pub fn floats<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<f64>, D::Error> {
        Vec::<Float>::deserialize(d).map(|v| v.into_iter().map(|f| f.0).collect())
    }

    /// A `float64[9]`.
    pub fn floats9<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 9], D::Error> {
        <[Float; 9]>::deserialize(d).map(|a| a.map(|f| f.0))
    }

    /// A field odocal does not use (with `#[serde(default)]`, so that it may be missing): in
    /// JSON, read when it is well formed and else its default, so that a driver's odd value
    /// there (another shape, another length, text) never costs the message; in binary formats
    /// read as it is, since its bytes have to be passed over.
    pub fn unused<'de, D: Deserializer<'de>, T: Default + DeserializeOwned>(
        d: D,
    ) -> Result<T, D::Error> {
        unused_as(d, |v| T::deserialize(v))
    }

    /// A float array odocal does not use ([`unused`], its floats read as [`Float`]s).
    pub fn unused_floats<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<f64>, D::Error> {
        unused_as(d, floats)
    }

    /// A `float64[9]` odocal does not use ([`unused`], its floats read as [`Float`]s).
    pub fn unused_floats9<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 9], D::Error> {
        unused_as(d, floats9)
    }

    /// [`unused`], its JSON read by `json`.
    fn unused_as<'de, D: Deserializer<'de>, T: Default + DeserializeOwned>(
        d: D,
        json: impl FnOnce(serde_json::Value) -> Result<T, serde_json::Error>,
    ) -> Result<T, D::Error> {
        if !d.is_human_readable() {
            return T::deserialize(d);
        }
        Ok(json(serde_json::Value::deserialize(d)?).unwrap_or_default())
    }

    /// JSON text as rosbridge writes it, made valid: the bare tokens `NaN`, `Infinity` and
    /// `-Infinity` (outside strings) become the strings `"NaN"`, `"Infinity"`, `"-Infinity"`,
    /// which the float fields above read. Text without them is returned as it is.
    pub fn json(text: &str) -> Cow<'_, str> {
        let bytes = text.as_bytes();
        if !(text.contains("NaN") || text.contains("Infinity")) {
            return Cow::Borrowed(text);
        }
        let mut out = String::with_capacity(text.len() + 16);
        let (mut i, mut start, mut in_string) = (0, 0, false);
        while i < bytes.len() {
            let b = bytes[i];
            if in_string {
                match b {
                    b'\\' => i += 1,
                    b'"' => in_string = false,
                    _ => {}
                }
                i += 1;
                continue;
            }
            if b == b'"' {
                in_string = true;
                i += 1;
                continue;
            }
            let token = ["-Infinity", "Infinity", "NaN"]
                .into_iter()
                .find(|t| bytes[i..].starts_with(t.as_bytes()));
            match token {
                Some(t) => {
                    out.push_str(&text[start..i]);
                    out.push('"');
                    out.push_str(t);
                    out.push('"');
                    i += t.len();
                    start = i;
                }
                None => i += 1,
            }
        }
        out.push_str(&text[start..]);
        Cow::Owned(out)
    }
}

/// ROS 2 type names and message definitions (the `ros2msg` schema text a bag stores).
pub mod types {
    /// `sensor_msgs/msg/JointState`.
    pub const JOINT_STATE: &str = "sensor_msgs/msg/JointState";
    /// `sensor_msgs/msg/Imu`.
    pub const IMU: &str = "sensor_msgs/msg/Imu";
    /// `nav_msgs/msg/Odometry`.
    pub const ODOMETRY: &str = "nav_msgs/msg/Odometry";
    /// `geometry_msgs/msg/Twist`.
    pub const TWIST: &str = "geometry_msgs/msg/Twist";
    /// `geometry_msgs/msg/PoseStamped`.
    pub const POSE_STAMPED: &str = "geometry_msgs/msg/PoseStamped";
    /// `tf2_msgs/msg/TFMessage`.
    pub const TF_MESSAGE: &str = "tf2_msgs/msg/TFMessage";
    /// `geometry_msgs/msg/PoseWithCovarianceStamped`.
    pub const POSE_WITH_COVARIANCE_STAMPED: &str = "geometry_msgs/msg/PoseWithCovarianceStamped";
    /// `geometry_msgs/msg/TwistStamped`.
    pub const TWIST_STAMPED: &str = "geometry_msgs/msg/TwistStamped";

    /// Whether `name` is `pkg/msg/Type` or the ROS 1 form `pkg/Type` of `canonical`.
    pub fn is(name: &str, canonical: &str) -> bool {
        name == canonical || name == canonical.replacen("/msg/", "/", 1)
    }

    const HEADER: &str =
        "================================================================================\n\
MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n\
================================================================================\n\
MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n";

    /// The `ros2msg` definition of a type we write, with its dependencies.
    pub fn definition(name: &str) -> String {
        let sep =
            "================================================================================\n";
        match name {
            JOINT_STATE => format!(
                "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n{HEADER}"
            ),
            IMU => format!(
                "std_msgs/Header header\ngeometry_msgs/Quaternion orientation\nfloat64[9] orientation_covariance\n\
geometry_msgs/Vector3 angular_velocity\nfloat64[9] angular_velocity_covariance\n\
geometry_msgs/Vector3 linear_acceleration\nfloat64[9] linear_acceleration_covariance\n{HEADER}\
{sep}MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n\
{sep}MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n"
            ),
            ODOMETRY => format!(
                "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\n\
geometry_msgs/TwistWithCovariance twist\n{HEADER}\
{sep}MSG: geometry_msgs/PoseWithCovariance\ngeometry_msgs/Pose pose\nfloat64[36] covariance\n\
{sep}MSG: geometry_msgs/Pose\ngeometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n\
{sep}MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n\
{sep}MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n\
{sep}MSG: geometry_msgs/TwistWithCovariance\ngeometry_msgs/Twist twist\nfloat64[36] covariance\n\
{sep}MSG: geometry_msgs/Twist\ngeometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n\
{sep}MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n"
            ),
            POSE_STAMPED => format!(
                "std_msgs/Header header\ngeometry_msgs/Pose pose\n{HEADER}\
{sep}MSG: geometry_msgs/Pose\ngeometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n\
{sep}MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n\
{sep}MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"
            ),
            POSE_WITH_COVARIANCE_STAMPED => format!(
                "std_msgs/Header header\ngeometry_msgs/PoseWithCovariance pose\n{HEADER}\
{sep}MSG: geometry_msgs/PoseWithCovariance\ngeometry_msgs/Pose pose\nfloat64[36] covariance\n\
{sep}MSG: geometry_msgs/Pose\ngeometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n\
{sep}MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n\
{sep}MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"
            ),
            TF_MESSAGE => format!(
                "geometry_msgs/TransformStamped[] transforms\n\
{sep}MSG: geometry_msgs/TransformStamped\nstd_msgs/Header header\nstring child_frame_id\n\
geometry_msgs/Transform transform\n{HEADER}\
{sep}MSG: geometry_msgs/Transform\ngeometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n\
{sep}MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n\
{sep}MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n"
            ),
            _ => String::new(),
        }
    }
}

/// CDR as ROS 2 puts it on the wire and in bags: a 4-byte encapsulation header, then the
/// message, little- or big-endian as the header says.
pub mod cdr {
    use serde::de::DeserializeOwned;
    use serde::Serialize;

    /// A CDR payload that cannot be read or written.
    #[derive(Debug, thiserror::Error)]
    pub enum CdrError {
        /// Shorter than the encapsulation header.
        #[error("CDR payload of {0} bytes has no encapsulation header")]
        Short(usize),
        /// An encapsulation this reader does not handle (e.g. XCDR2, parameter lists).
        #[error("unsupported CDR encapsulation 0x{0:04X}")]
        Encapsulation(u16),
        /// The body does not decode as the expected type.
        #[error("{0}")]
        Body(#[from] cdr_encoding::Error),
    }

    /// Decodes a CDR-encapsulated message.
    pub fn decode<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, CdrError> {
        let head = bytes.get(..4).ok_or(CdrError::Short(bytes.len()))?;
        let kind = u16::from_be_bytes([head[0], head[1]]);
        let body = &bytes[4..];
        match kind {
            0x0001 => Ok(cdr_encoding::from_bytes::<T, byteorder::LittleEndian>(body)?.0),
            0x0000 => Ok(cdr_encoding::from_bytes::<T, byteorder::BigEndian>(body)?.0),
            other => Err(CdrError::Encapsulation(other)),
        }
    }

    /// Encodes a message as little-endian CDR with its encapsulation header.
    pub fn encode<T: Serialize>(value: &T) -> Result<Vec<u8>, CdrError> {
        let mut out = vec![0x00, 0x01, 0x00, 0x00];
        out.extend(cdr_encoding::to_vec::<T, byteorder::LittleEndian>(value)?);
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn yaw_is_wrap_safe_and_rejects_what_is_not_a_heading() {
        for yaw in [0.0, 1.0, -2.5, PI - 1e-9, -PI + 1e-9, PI] {
            let got = yaw_of(&Quaternion::from_yaw(yaw)).unwrap();
            assert!(wrap_angle(got - yaw).abs() < 1e-12, "{yaw} → {got}");
        }
        // -q is the same rotation.
        let q = Quaternion::from_yaw(3.0);
        let neg = Quaternion {
            x: -q.x,
            y: -q.y,
            z: -q.z,
            w: -q.w,
        };
        assert!((yaw_of(&neg).unwrap() - 3.0).abs() < 1e-12);
        assert!(yaw_of(&Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 0.0
        })
        .is_err());
        assert!(yaw_of(&Quaternion {
            x: f64::NAN,
            y: 0.0,
            z: 0.0,
            w: 1.0
        })
        .is_err());
        // Pitched 90°: yaw undefined.
        let s = std::f64::consts::FRAC_1_SQRT_2;
        assert!(yaw_of(&Quaternion {
            x: 0.0,
            y: s,
            z: 0.0,
            w: s
        })
        .is_err());
    }

    #[test]
    fn wheel_angle_steps_unwrap() {
        assert!((angle_step(3.0, -3.0) - (2.0 * PI - 6.0)).abs() < 1e-12);
        assert!((angle_step(-3.0, 3.0) + (2.0 * PI - 6.0)).abs() < 1e-12);
        assert_eq!(angle_step(1.0, 1.5), 0.5);
        assert_eq!(angle_step(100.0, 100.25), 0.25);
    }

    #[test]
    fn cdr_round_trips_and_matches_the_ros2_layout() {
        let js = JointState {
            header: Header {
                stamp: Time {
                    sec: 12,
                    nanosec: 5,
                },
                frame_id: "base".into(),
            },
            name: vec!["left_wheel_joint".into(), "right_wheel_joint".into()],
            position: vec![1.5, -2.25],
            velocity: vec![],
            effort: vec![],
        };
        let bytes = cdr::encode(&js).unwrap();
        // Encapsulation, then sec = 12, nanosec = 5, frame_id "base\0" (length 5).
        assert_eq!(&bytes[..4], &[0, 1, 0, 0]);
        assert_eq!(&bytes[4..8], &12i32.to_le_bytes());
        assert_eq!(&bytes[8..12], &5u32.to_le_bytes());
        assert_eq!(&bytes[12..16], &5u32.to_le_bytes());
        assert_eq!(&bytes[16..21], b"base\0");
        assert_eq!(cdr::decode::<JointState>(&bytes).unwrap(), js);
        let odom = Odometry {
            pose: PoseWithCovariance {
                pose: Pose {
                    position: Vector3 {
                        x: 1.0,
                        y: 2.0,
                        z: 0.0,
                    },
                    orientation: Quaternion::from_yaw(0.3),
                },
                covariance: Covariance36([0.5; 36]),
            },
            ..Odometry::default()
        };
        assert_eq!(
            cdr::decode::<Odometry>(&cdr::encode(&odom).unwrap()).unwrap(),
            odom
        );
        assert!(cdr::decode::<JointState>(&[0, 1]).is_err());
    }

    #[test]
    fn ros1_and_ros2_json_both_read() {
        let ros1: JointState = serde_json::from_str(
            r#"{"header":{"seq":3,"stamp":{"secs":1,"nsecs":2},"frame_id":""},
                "name":["l","r"],"position":[0.1,0.2],"velocity":[],"effort":[]}"#,
        )
        .unwrap();
        assert_eq!(ros1.header.stamp, Time { sec: 1, nanosec: 2 });
        let ros2: JointState = serde_json::from_str(
            r#"{"header":{"stamp":{"sec":1,"nanosec":2},"frame_id":""},"name":["l"],"position":[0.1]}"#,
        )
        .unwrap();
        assert_eq!(ros2.position, vec![0.1]);
    }

    /// Joint states and IMU messages as rosbridge servers send them (the raw text): NaN as
    /// `null` or as bare tokens, integers for floats, fields odocal does not know, `effort`
    /// empty, null, NaN or nonsense — every one is read, and the wheel positions are intact.
    #[test]
    fn messages_as_rosbridge_sends_them_are_read() {
        let read = |text: &str| -> serde_json::Value {
            serde_json::from_str(&lenient::json(text)).unwrap_or_else(|e| panic!("{text}: {e}"))
        };
        let head = r#""header":{"stamp":{"sec":1700000000,"nanosec":5},"frame_id":""},"name":["left_wheel_joint","right_wheel_joint"],"position":[1.5,-2],"velocity":[0.1,0]"#;
        for effort in [
            r#""effort":[null,null]"#,
            r#""effort":[NaN,NaN]"#,
            r#""effort":[]"#,
            r#""effort":null"#,
            r#""effort":[Infinity,-Infinity]"#,
            r#""effort":["n/a",1]"#,
            r#""extra":{"a":[1,2]},"effort":[0,0]"#,
        ] {
            let text = format!("{{{head},{effort}}}");
            let js: JointState =
                serde_json::from_value(read(&text)).unwrap_or_else(|e| panic!("{text}: {e}"));
            assert_eq!(js.position, vec![1.5, -2.0], "{text}");
        }
        // A NaN wheel position is read as NaN (and refused by whoever uses it), not an error.
        let js: JointState = serde_json::from_value(read(
            r#"{"header":{"stamp":{"sec":1,"nanosec":0}},"name":["l","r"],"position":[null,NaN]}"#,
        ))
        .unwrap();
        assert!(js.position.iter().all(|p| p.is_nan()));
        // rosbridge_suite #916: bare NaN in a fixed-size covariance; "NaN" inside a string is
        // left alone.
        let imu: Imu = serde_json::from_value(read(
            r#"{"header":{"stamp":{"sec":1,"nanosec":0},"frame_id":"NaN Infinity"},
                "orientation":{"x":0,"y":0,"z":0,"w":1},
                "orientation_covariance":[NaN,0,0,0,Infinity,0,0,0,-Infinity],
                "angular_velocity":{"x":null,"y":0,"z":0},
                "angular_velocity_covariance":[0,0,0,0,0,0,0,0,0],
                "linear_acceleration":{"x":0,"y":0,"z":9.8},
                "linear_acceleration_covariance":[0,0,0,0,0,0,0,0,0]}"#,
        ))
        .unwrap();
        assert_eq!(imu.header.frame_id, "NaN Infinity");
        assert!(imu.orientation_covariance[0].is_nan());
        assert_eq!(imu.orientation_covariance[4], f64::INFINITY);
        assert_eq!(imu.orientation_covariance[8], f64::NEG_INFINITY);
        assert_eq!(imu.orientation.w, 1.0);
        // A field odocal does use, broken, is an error that names it.
        let bad = read(
            r#"{"header":{"stamp":{"sec":1,"nanosec":0}},"name":["l","r"],"position":[1,"x"]}"#,
        );
        let err = serde_path_to_error::deserialize::<_, JointState>(&bad).unwrap_err();
        assert_eq!(err.path().to_string(), "position[1]");
        // CDR is untouched by the leniency.
        let js = JointState {
            name: vec!["l".into(), "r".into()],
            position: vec![1.0, 2.0],
            effort: vec![f64::NAN, 0.5],
            ..JointState::default()
        };
        let back: JointState = cdr::decode(&cdr::encode(&js).unwrap()).unwrap();
        assert_eq!(back.position, js.position);
        assert!(back.effort[0].is_nan() && back.effort[1] == 0.5);
    }

    /// Every field odocal does not use, malformed or missing in the raw text, costs nothing:
    /// the IMU's angular velocity, linear acceleration and their covariances, the odometry's
    /// covariances, twist and frames. The fields it uses stay strict and name themselves.
    #[test]
    fn unused_fields_never_cost_a_message_and_used_ones_stay_strict() {
        let read = |text: &str| -> serde_json::Value {
            serde_json::from_str(&lenient::json(text)).unwrap_or_else(|e| panic!("{text}: {e}"))
        };
        let head = r#""header":{"stamp":{"sec":1700000000,"nanosec":5},"frame_id":"imu"}"#;
        let orientation = r#""orientation":{"x":0,"y":0,"z":0.25881904510252074,"w":0.9659258262890683},"orientation_covariance":[0,0,0,0,0,0,0,0,0.01]"#;
        for rest in [
            // Missing altogether.
            "",
            // Another shape, another length, text, null, NaN tokens.
            r#","angular_velocity":"n/a","angular_velocity_covariance":[0,0,0,0,0,0,0,0]"#,
            r#","angular_velocity":[1,2,3],"linear_acceleration":null"#,
            r#","linear_acceleration":{"x":"fast","y":0,"z":9.8},"linear_acceleration_covariance":"unknown""#,
            r#","angular_velocity_covariance":[NaN,NaN,NaN,NaN,NaN,NaN,NaN,NaN,NaN,NaN]"#,
            r#","angular_velocity":{"x":1},"linear_acceleration_covariance":{"0":1}"#,
        ] {
            let text = format!("{{{head},{orientation}{rest}}}");
            let imu: Imu = serde_path_to_error::deserialize(&read(&text))
                .unwrap_or_else(|e| panic!("{text}: {e}"));
            assert!((yaw_of(&imu.orientation).unwrap() - 30f64.to_radians()).abs() < 1e-12);
            assert_eq!(imu.orientation_covariance[8], 0.01, "{text}");
        }
        let pose = r#""pose":{"pose":{"position":{"x":1.5,"y":-2,"z":0},"orientation":{"x":0,"y":0,"z":0,"w":1}}"#;
        for (frames, covariance, twist) in [
            (r#""header":{"stamp":{"sec":1,"nanosec":0}}"#, "", ""),
            (
                r#""header":{"stamp":{"sec":1,"nanosec":0},"frame_id":null},"child_frame_id":5"#,
                r#","covariance":[0,0,0]"#,
                r#","twist":null"#,
            ),
            (
                r#""header":{"stamp":{"sec":1,"nanosec":0},"frame_id":"odom"},"child_frame_id":"base""#,
                r#","covariance":"none""#,
                r#","twist":{"twist":{"linear":{"x":"?"}},"covariance":[1]}"#,
            ),
            (
                r#""header":{"stamp":{"sec":1,"nanosec":0}}"#,
                r#","covariance":[NaN,1,2,3,4,5,6,7,8,9,10,11,12,13,14,15,16,17,18,19,20,21,22,23,24,25,26,27,28,29,30,31,32,33,34,35,36]"#,
                r#","twist":{"twist":{"linear":{"x":0.5,"y":0,"z":0},"angular":{"x":0,"y":0,"z":0}}}"#,
            ),
        ] {
            let text = format!("{{{frames},{pose}{covariance}}}{twist}}}");
            let o: Odometry = serde_path_to_error::deserialize(&read(&text))
                .unwrap_or_else(|e| panic!("{text}: {e}"));
            assert_eq!(
                (o.pose.pose.position.x, o.pose.pose.position.y),
                (1.5, -2.0),
                "{text}"
            );
            assert_eq!(o.header.stamp, Time { sec: 1, nanosec: 0 });
        }
        // What odocal uses, broken: an error naming the field.
        for (text, path) in [
            (
                format!(
                    r#"{{{head},"orientation":"level","orientation_covariance":[0,0,0,0,0,0,0,0,0]}}"#
                ),
                "orientation",
            ),
            (
                format!(r#"{{{head},{}}}"#, orientation.replace("0.01", "\"x\"")),
                "orientation_covariance[8]",
            ),
            (
                format!(r#"{{"header":{{"frame_id":"imu"}},{orientation}}}"#),
                "header",
            ),
        ] {
            let err = serde_path_to_error::deserialize::<_, Imu>(&read(&text)).unwrap_err();
            assert!(err.path().to_string().starts_with(path), "{text}: {err}");
        }
        let text = format!(r#"{{"header":{{"stamp":{{"sec":1,"nanosec":0}}}},{pose}}}}}"#)
            .replace("1.5", "\"x\"");
        let err = serde_path_to_error::deserialize::<_, Odometry>(&read(&text)).unwrap_err();
        assert_eq!(err.path().to_string(), "pose.pose.position.x", "{text}");
        // Binary forms read every field as it is.
        let imu = Imu {
            angular_velocity: Vector3 {
                x: 0.5,
                y: 0.0,
                z: -0.25,
            },
            linear_acceleration_covariance: [2.0; 9],
            ..Imu::default()
        };
        assert_eq!(
            cdr::decode::<Imu>(&cdr::encode(&imu).unwrap()).unwrap(),
            imu
        );
    }
}
