//! ROS 1 serialization as a serde format, read-only: the wire form of every message in a ROS 1
//! bag. Little-endian, no alignment and no encapsulation header; a string is its `u32` byte
//! length then its bytes (no NUL), a variable array its `u32` element count then the elements,
//! a fixed array (`float64[9]`) just its elements. The message structs are the ROS 2 ones of
//! [`super`]: the one difference that matters, `std_msgs/Header`'s leading `uint32 seq`, is read
//! and dropped here, and a ROS 1 `time` (`u32 secs, u32 nsecs`) fills [`super::Time`].

use serde::de::{self, DeserializeOwned, DeserializeSeed, SeqAccess, Visitor};

/// A ROS 1 payload that does not decode as the expected type.
#[derive(Debug, thiserror::Error)]
pub enum Ros1Error {
    /// The payload ends before the message does.
    #[error("ROS 1 message ends at byte {len}, {needed} more bytes were needed")]
    Short {
        /// The payload's length.
        len: usize,
        /// Bytes missing.
        needed: usize,
    },
    /// A string that is not UTF-8.
    #[error("ROS 1 string at byte {at} is not UTF-8")]
    Utf8 {
        /// Where it starts.
        at: usize,
    },
    /// A length prefix longer than what is left of the payload.
    #[error("ROS 1 array of {count} elements at byte {at} is longer than the message")]
    Count {
        /// The count read.
        count: u32,
        /// Where it was read.
        at: usize,
    },
    /// A type the ROS 1 wire form cannot hold (maps, options, enums): a bug in a message struct.
    #[error("ROS 1 serialization has no {0}")]
    Unsupported(&'static str),
    /// A field's value was refused by the message struct.
    #[error("{0}")]
    Message(String),
}

impl de::Error for Ros1Error {
    fn custom<T: std::fmt::Display>(msg: T) -> Self {
        Ros1Error::Message(msg.to_string())
    }
}

/// Decodes a ROS 1-serialized message (trailing bytes, e.g. fields of a newer definition, are
/// left unread).
pub fn decode<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, Ros1Error> {
    T::deserialize(&mut Reader { bytes, pos: 0 })
}

/// The name serde's derive gives [`super::Header`], whose ROS 1 form leads with a sequence
/// number.
const HEADER: &str = "Header";

struct Reader<'de> {
    bytes: &'de [u8],
    pos: usize,
}

impl<'de> Reader<'de> {
    fn take(&mut self, n: usize) -> Result<&'de [u8], Ros1Error> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.bytes.len());
        let Some(end) = end else {
            return Err(Ros1Error::Short {
                len: self.bytes.len(),
                needed: n - (self.bytes.len() - self.pos),
            });
        };
        let out = &self.bytes[self.pos..end];
        self.pos = end;
        Ok(out)
    }

    fn array<const N: usize>(&mut self) -> Result<[u8; N], Ros1Error> {
        let mut out = [0; N];
        out.copy_from_slice(self.take(N)?);
        Ok(out)
    }

    fn u32(&mut self) -> Result<u32, Ros1Error> {
        Ok(u32::from_le_bytes(self.array()?))
    }

    /// A `u32` count of what follows, each of at least `min_size` bytes: refused when the
    /// payload cannot hold that many, before anything is allocated for them.
    fn count(&mut self, min_size: usize) -> Result<usize, Ros1Error> {
        let at = self.pos;
        let count = self.u32()?;
        let left = self.bytes.len() - self.pos;
        let n = count as usize;
        if n.saturating_mul(min_size.max(1)) > left {
            return Err(Ros1Error::Count { count, at });
        }
        Ok(n)
    }

    fn str(&mut self) -> Result<&'de str, Ros1Error> {
        let n = self.count(1)?;
        let at = self.pos;
        std::str::from_utf8(self.take(n)?).map_err(|_| Ros1Error::Utf8 { at })
    }
}

/// `n` elements read one after the other.
struct Elements<'a, 'de> {
    reader: &'a mut Reader<'de>,
    left: usize,
}

impl<'de> SeqAccess<'de> for Elements<'_, 'de> {
    type Error = Ros1Error;

    fn next_element_seed<T: DeserializeSeed<'de>>(
        &mut self,
        seed: T,
    ) -> Result<Option<T::Value>, Ros1Error> {
        if self.left == 0 {
            return Ok(None);
        }
        self.left -= 1;
        seed.deserialize(&mut *self.reader).map(Some)
    }

    fn size_hint(&self) -> Option<usize> {
        Some(self.left)
    }
}

macro_rules! number {
    ($method:ident, $visit:ident, $t:ty) => {
        fn $method<V: Visitor<'de>>(self, v: V) -> Result<V::Value, Ros1Error> {
            v.$visit(<$t>::from_le_bytes(self.array()?))
        }
    };
}

impl<'de> de::Deserializer<'de> for &mut Reader<'de> {
    type Error = Ros1Error;

    fn deserialize_any<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Ros1Error> {
        Err(Ros1Error::Unsupported("self-describing values"))
    }

    fn deserialize_bool<V: Visitor<'de>>(self, v: V) -> Result<V::Value, Ros1Error> {
        v.visit_bool(self.array::<1>()?[0] != 0)
    }

    number!(deserialize_i8, visit_i8, i8);
    number!(deserialize_i16, visit_i16, i16);
    number!(deserialize_i32, visit_i32, i32);
    number!(deserialize_i64, visit_i64, i64);
    number!(deserialize_u8, visit_u8, u8);
    number!(deserialize_u16, visit_u16, u16);
    number!(deserialize_u32, visit_u32, u32);
    number!(deserialize_u64, visit_u64, u64);
    number!(deserialize_f32, visit_f32, f32);
    number!(deserialize_f64, visit_f64, f64);

    fn deserialize_char<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Ros1Error> {
        Err(Ros1Error::Unsupported("char"))
    }

    fn deserialize_str<V: Visitor<'de>>(self, v: V) -> Result<V::Value, Ros1Error> {
        v.visit_borrowed_str(self.str()?)
    }

    fn deserialize_string<V: Visitor<'de>>(self, v: V) -> Result<V::Value, Ros1Error> {
        self.deserialize_str(v)
    }

    fn deserialize_bytes<V: Visitor<'de>>(self, v: V) -> Result<V::Value, Ros1Error> {
        let n = self.count(1)?;
        v.visit_borrowed_bytes(self.take(n)?)
    }

    fn deserialize_byte_buf<V: Visitor<'de>>(self, v: V) -> Result<V::Value, Ros1Error> {
        self.deserialize_bytes(v)
    }

    fn deserialize_option<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Ros1Error> {
        Err(Ros1Error::Unsupported("optional fields"))
    }

    fn deserialize_unit<V: Visitor<'de>>(self, v: V) -> Result<V::Value, Ros1Error> {
        v.visit_unit()
    }

    fn deserialize_unit_struct<V: Visitor<'de>>(
        self,
        _: &'static str,
        v: V,
    ) -> Result<V::Value, Ros1Error> {
        v.visit_unit()
    }

    fn deserialize_newtype_struct<V: Visitor<'de>>(
        self,
        _: &'static str,
        v: V,
    ) -> Result<V::Value, Ros1Error> {
        v.visit_newtype_struct(self)
    }

    fn deserialize_seq<V: Visitor<'de>>(self, v: V) -> Result<V::Value, Ros1Error> {
        let left = self.count(1)?;
        v.visit_seq(Elements { reader: self, left })
    }

    fn deserialize_tuple<V: Visitor<'de>>(self, len: usize, v: V) -> Result<V::Value, Ros1Error> {
        v.visit_seq(Elements {
            reader: self,
            left: len,
        })
    }

    fn deserialize_tuple_struct<V: Visitor<'de>>(
        self,
        _: &'static str,
        len: usize,
        v: V,
    ) -> Result<V::Value, Ros1Error> {
        self.deserialize_tuple(len, v)
    }

    fn deserialize_map<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Ros1Error> {
        Err(Ros1Error::Unsupported("maps"))
    }

    fn deserialize_struct<V: Visitor<'de>>(
        self,
        name: &'static str,
        fields: &'static [&'static str],
        v: V,
    ) -> Result<V::Value, Ros1Error> {
        if name == HEADER {
            // ROS 1's header starts with a sequence number ROS 2 dropped.
            self.u32()?;
        }
        self.deserialize_tuple(fields.len(), v)
    }

    fn deserialize_enum<V: Visitor<'de>>(
        self,
        _: &'static str,
        _: &'static [&'static str],
        _: V,
    ) -> Result<V::Value, Ros1Error> {
        Err(Ros1Error::Unsupported("enums"))
    }

    fn deserialize_identifier<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Ros1Error> {
        Err(Ros1Error::Unsupported("field names"))
    }

    fn deserialize_ignored_any<V: Visitor<'de>>(self, _: V) -> Result<V::Value, Ros1Error> {
        Err(Ros1Error::Unsupported("skipped values"))
    }

    fn is_human_readable(&self) -> bool {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ros::msg::{Imu, JointState, Odometry, Time};

    fn string(out: &mut Vec<u8>, s: &str) {
        out.extend((s.len() as u32).to_le_bytes());
        out.extend(s.as_bytes());
    }

    fn header(out: &mut Vec<u8>, seq: u32, sec: u32, nsec: u32, frame: &str) {
        out.extend(seq.to_le_bytes());
        out.extend(sec.to_le_bytes());
        out.extend(nsec.to_le_bytes());
        string(out, frame);
    }

    fn f64s(out: &mut Vec<u8>, values: &[f64]) {
        for v in values {
            out.extend(v.to_le_bytes());
        }
    }

    /// A JointState as roscpp writes it: 105 bytes for two joints, no effort, no frame (the
    /// size `rosbags` writes, too).
    fn joint_state() -> Vec<u8> {
        let mut b = Vec::new();
        header(&mut b, 7, 1_700_000_000, 5, "");
        b.extend(2u32.to_le_bytes());
        string(&mut b, "left_wheel_joint");
        string(&mut b, "right_wheel_joint");
        b.extend(2u32.to_le_bytes());
        f64s(&mut b, &[1.5, -2.25]);
        b.extend(2u32.to_le_bytes());
        f64s(&mut b, &[0.5, 0.25]);
        b.extend(0u32.to_le_bytes());
        b
    }

    #[test]
    fn a_joint_state_reads_with_the_header_sequence_dropped() {
        let b = joint_state();
        assert_eq!(b.len(), 105);
        let js: JointState = decode(&b).unwrap();
        assert_eq!(
            js.header.stamp,
            Time {
                sec: 1_700_000_000,
                nanosec: 5
            }
        );
        assert_eq!(js.name, ["left_wheel_joint", "right_wheel_joint"]);
        assert_eq!(js.position, [1.5, -2.25]);
        assert_eq!(js.velocity, [0.5, 0.25]);
        assert!(js.effort.is_empty());
    }

    #[test]
    fn imu_and_odometry_have_their_ros1_sizes() {
        // Imu: header, quaternion, 9 covariances, vector, 9, vector, 9: 320 bytes with the
        // frame `imu_link`.
        let mut b = Vec::new();
        header(&mut b, 1, 2, 3, "imu_link");
        f64s(&mut b, &[0.0, 0.0, 0.5, 0.75]);
        f64s(&mut b, &[0.0; 9]);
        f64s(&mut b, &[0.0, 0.0, 0.125]);
        f64s(&mut b, &[0.0; 9]);
        f64s(&mut b, &[0.0, 0.0, 9.81]);
        f64s(&mut b, &[-1.0; 9]);
        assert_eq!(b.len(), 320);
        let imu: Imu = decode(&b).unwrap();
        assert_eq!((imu.orientation.z, imu.orientation.w), (0.5, 0.75));
        assert_eq!(imu.angular_velocity.z, 0.125);
        assert_eq!(imu.linear_acceleration_covariance, [-1.0; 9]);
        // Odometry: header, child frame, pose (point, quaternion, 36), twist (2 vectors, 36):
        // 713 bytes with frames `odom` and `base_link`.
        let mut b = Vec::new();
        header(&mut b, 1, 2, 3, "odom");
        string(&mut b, "base_link");
        f64s(&mut b, &[1.0, 2.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
        f64s(&mut b, &[0.25; 36]);
        f64s(&mut b, &[0.2, 0.0, 0.0, 0.0, 0.0, 0.1]);
        f64s(&mut b, &[0.0; 36]);
        assert_eq!(b.len(), 713);
        let o: Odometry = decode(&b).unwrap();
        assert_eq!(o.child_frame_id, "base_link");
        assert_eq!((o.pose.pose.position.x, o.pose.pose.position.y), (1.0, 2.0));
        assert_eq!(o.pose.covariance.0, [0.25; 36]);
        assert_eq!(o.twist.twist.angular.z, 0.1);
    }

    #[test]
    fn short_or_lying_payloads_are_errors_not_panics() {
        let b = joint_state();
        for cut in 0..b.len() {
            assert!(decode::<JointState>(&b[..cut]).is_err(), "cut at {cut}");
        }
        // A name count of four billion: refused before anything is allocated.
        let mut lying = b.clone();
        lying[16..20].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(
            decode::<JointState>(&lying),
            Err(Ros1Error::Count { at: 16, .. })
        ));
        // A name that is not UTF-8.
        let mut bad = b;
        bad[24] = 0xFF;
        assert!(matches!(
            decode::<JointState>(&bad),
            Err(Ros1Error::Utf8 { at: 24 })
        ));
    }
}
