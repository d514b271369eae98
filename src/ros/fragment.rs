//! rosbridge v2 fragments (ROSBRIDGE_PROTOCOL.md §3.1): a message too large for a peer's
//! `fragment_size` travels as `{"op": "fragment", "id", "data", "num", "total"}` pieces of its
//! JSON text, `num` counting from 0. Splitting is the server's (the mock's); both ends
//! reassemble, within bounds, since a peer may send fragments it was never asked for.

use serde_json::{json, Value};
use std::collections::{BTreeMap, HashMap};
use std::time::Duration;
use tokio::time::Instant;

/// Messages being reassembled at once; the oldest is dropped beyond it.
pub const MAX_IN_FLIGHT: usize = 32;
/// The largest reassembled message (bytes of JSON text).
pub const MAX_MESSAGE_BYTES: usize = 16 << 20;
/// The most fragments one message may have.
pub const MAX_FRAGMENTS: usize = 1 << 18;
/// What each fragment counts against [`MAX_MESSAGE_BYTES`] besides its data (an empty piece
/// still costs its keeping).
const PIECE_OVERHEAD: usize = 64;
/// A message whose next fragment does not come within this is dropped.
pub const FRAGMENT_TIMEOUT: Duration = Duration::from_secs(10);

/// The `fragment` operations that carry `text` in pieces of at most `size` characters (at
/// least 1), under the message id `id`.
pub fn split(text: &str, size: usize, id: &str) -> Vec<Value> {
    let chars: Vec<char> = text.chars().collect();
    let pieces: Vec<String> = chars
        .chunks(size.max(1))
        .map(|c| c.iter().collect())
        .collect();
    let total = pieces.len();
    pieces
        .into_iter()
        .enumerate()
        .map(|(num, data)| {
            json!({"op": "fragment", "id": id, "data": data, "num": num, "total": total})
        })
        .collect()
}

/// One message being put together.
#[derive(Debug)]
struct Partial {
    total: usize,
    pieces: BTreeMap<usize, String>,
    bytes: usize,
    last: Instant,
}

/// Why a fragment was not used.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FragmentError {
    /// A field is missing or of the wrong type.
    #[error("a fragment without a valid {0:?}")]
    Field(&'static str),
    /// `num` is not below `total`, or `total` differs from the message's first fragment.
    #[error("fragment {num} of {total} does not fit its message of {expected} fragments")]
    Mismatch {
        /// The fragment's number.
        num: usize,
        /// The total it states.
        total: usize,
        /// The total of the message so far.
        expected: usize,
    },
    /// The message would be larger than [`MAX_MESSAGE_BYTES`].
    #[error("a fragmented message larger than {MAX_MESSAGE_BYTES} bytes")]
    TooLarge,
}

/// Reassembles fragmented messages, bounded in number, size and time.
#[derive(Debug, Default)]
pub struct Defragmenter {
    partial: HashMap<String, Partial>,
}

impl Defragmenter {
    /// Takes one `fragment` operation; the whole message's text once its last piece is in.
    pub fn feed(&mut self, op: &Value) -> Result<Option<String>, FragmentError> {
        let id = match op.get("id") {
            Some(Value::String(s)) => s.clone(),
            Some(v @ Value::Number(_)) => v.to_string(),
            _ => return Err(FragmentError::Field("id")),
        };
        let data = op
            .get("data")
            .and_then(Value::as_str)
            .ok_or(FragmentError::Field("data"))?;
        // rosbridge_suite long computed `total` with Python 3's true division
        // (`(len - 1) / size + 1`, 2.99 for two pieces): a number's whole part is the count.
        let index = |key: &'static str| {
            op.get(key)
                .and_then(|v| match v.as_u64() {
                    Some(n) => Some(n),
                    None => v
                        .as_f64()
                        .filter(|f| f.is_finite() && *f >= 0.0 && *f < 1e15)
                        .map(|f| f.floor() as u64),
                })
                .and_then(|n| usize::try_from(n).ok())
                .ok_or(FragmentError::Field(key))
        };
        let (num, total) = (index("num")?, index("total")?);
        if total == 0 || total > MAX_FRAGMENTS {
            return Err(FragmentError::Field("total"));
        }
        let now = Instant::now();
        self.partial
            .retain(|_, p| now.duration_since(p.last) < FRAGMENT_TIMEOUT);
        if !self.partial.contains_key(&id) && self.partial.len() >= MAX_IN_FLIGHT {
            if let Some(oldest) = self
                .partial
                .iter()
                .min_by_key(|(_, p)| p.last)
                .map(|(k, _)| k.clone())
            {
                self.partial.remove(&oldest);
            }
        }
        let partial = self.partial.entry(id.clone()).or_insert(Partial {
            total,
            pieces: BTreeMap::new(),
            bytes: 0,
            last: now,
        });
        if num >= total || total != partial.total {
            let expected = partial.total;
            if partial.pieces.is_empty() {
                self.partial.remove(&id);
            }
            return Err(FragmentError::Mismatch {
                num,
                total,
                expected,
            });
        }
        let before = partial
            .pieces
            .get(&num)
            .map_or(0, |p| p.len() + PIECE_OVERHEAD);
        let bytes = partial.bytes - before + data.len() + PIECE_OVERHEAD;
        if bytes > MAX_MESSAGE_BYTES {
            self.partial.remove(&id);
            return Err(FragmentError::TooLarge);
        }
        partial.pieces.insert(num, data.to_string());
        partial.bytes = bytes;
        partial.last = now;
        if partial.pieces.len() < partial.total {
            return Ok(None);
        }
        Ok(self
            .partial
            .remove(&id)
            .map(|p| p.pieces.into_values().collect()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn pieces_in_any_order_make_the_message_and_bad_ones_are_named() {
        let text = r#"{"op":"publish","topic":"/imu","msg":{"x":"αβγ"}}"#;
        let mut pieces = split(text, 7, "m1");
        assert!(pieces.len() > 3);
        assert!(pieces
            .iter()
            .all(|p| p["data"].as_str().unwrap().chars().count() <= 7));
        pieces.reverse();
        let mut d = Defragmenter::default();
        let last = pieces.pop().unwrap();
        for p in &pieces {
            assert_eq!(d.feed(p).unwrap(), None);
        }
        assert_eq!(d.feed(&last).unwrap().as_deref(), Some(text));
        assert!(d.partial.is_empty());
        assert_eq!(
            d.feed(&json!({"op": "fragment", "id": "x", "data": "a", "num": 2, "total": 2})),
            Err(FragmentError::Mismatch {
                num: 2,
                total: 2,
                expected: 2
            })
        );
        assert_eq!(
            d.feed(&json!({"op": "fragment", "id": "x", "num": 0, "total": 2})),
            Err(FragmentError::Field("data"))
        );
        assert_eq!(
            d.feed(&json!({"op": "fragment", "id": "y", "data": "", "num": 0, "total": 1e12})),
            Err(FragmentError::Field("total"))
        );
    }

    /// A message that would outgrow [`MAX_MESSAGE_BYTES`] is dropped with its pieces, and
    /// its id starts afresh.
    #[tokio::test]
    async fn a_message_too_large_is_refused_and_forgotten() {
        let mut d = Defragmenter::default();
        let half = "x".repeat(MAX_MESSAGE_BYTES / 2);
        let piece = |num: usize| json!({"op": "fragment", "id": "big", "data": half, "num": num, "total": 3});
        assert_eq!(d.feed(&piece(0)).unwrap(), None);
        assert_eq!(d.feed(&piece(1)), Err(FragmentError::TooLarge));
        assert!(d.partial.is_empty());
        let small = json!({"op": "fragment", "id": "big", "data": "ok", "num": 0, "total": 1});
        assert_eq!(d.feed(&small).unwrap().as_deref(), Some("ok"));
    }

    /// rosbridge_suite under Python 3 wrote `total` as a float (2.99 for two pieces).
    #[tokio::test]
    async fn a_float_total_counts_its_whole_part() {
        let mut d = Defragmenter::default();
        let piece = |num: usize, data: &str| json!({"op": "fragment", "id": "f", "data": data, "num": num, "total": 2.99});
        assert_eq!(d.feed(&piece(1, "def")).unwrap(), None);
        assert_eq!(d.feed(&piece(0, "abc")).unwrap().as_deref(), Some("abcdef"));
    }

    #[tokio::test(start_paused = true)]
    async fn a_message_left_unfinished_is_dropped_in_time_and_in_number() {
        let mut d = Defragmenter::default();
        for i in 0..(MAX_IN_FLIGHT + 5) {
            let p = json!({"op": "fragment", "id": i, "data": "a", "num": 0, "total": 2});
            assert_eq!(d.feed(&p).unwrap(), None);
        }
        assert_eq!(d.partial.len(), MAX_IN_FLIGHT);
        tokio::time::advance(FRAGMENT_TIMEOUT).await;
        let p = json!({"op": "fragment", "id": "new", "data": "a", "num": 0, "total": 2});
        assert_eq!(d.feed(&p).unwrap(), None);
        assert_eq!(d.partial.len(), 1);
    }
}
