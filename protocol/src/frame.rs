//! Frames: `AA 55 | LEN | VER | KIND | SEQ | MSG | payload | CRC16-LE` (SPEC.md §2).
//!
//! The decoder implements the resynchronisation rules of SPEC.md §2.1: on a bad header (length,
//! major version, kind) or a bad CRC it drops *one* byte and rescans, so a valid frame hidden in
//! garbage or in a corrupted frame is still found; and an incomplete candidate is abandoned as
//! soon as a complete valid frame follows it, so garbage that looks like a long header never
//! holds a real frame back. It never fails on bad bytes; it counts what it dropped in
//! [`DecoderStats`]. [`scan`] is the rule set over a byte slice; [`FrameDecoder`] runs it in a
//! fixed buffer (firmware), [`crate::codec::FrameCodec`] over a `BytesMut` (hosts).

use crc::{Crc, CRC_16_IBM_3740};

/// The two sync bytes that open every frame.
pub const SYNC: [u8; 2] = [0xAA, 0x55];
/// Largest payload (bytes).
pub const MAX_PAYLOAD: usize = 240;
/// Sync, LEN, VER, KIND, SEQ, MSG.
pub const HEADER_LEN: usize = 7;
/// Header plus CRC.
pub const OVERHEAD: usize = HEADER_LEN + 2;
/// Largest frame on the wire (bytes).
pub const MAX_FRAME: usize = OVERHEAD + MAX_PAYLOAD;
/// The VER byte this implementation sends: major 1, minor 0. Every 1.x frame carries 0x10 (the
/// frame format is 1.0's; SPEC.md §6); the minor a device follows is reported by HELLO.
pub const VERSION: u8 = 0x10;
/// The major version this implementation speaks.
pub const MAJOR: u8 = VERSION >> 4;
/// The minor version of SPEC.md this implementation follows (1.1: the rules of §7).
pub const MINOR: u8 = 1;

/// CRC-16/IBM-3740 (poly 0x1021, init 0xFFFF, no reflection; check `"123456789"` → 0x29B1),
/// over LEN..payload.
pub const CRC16: Crc<u16> = Crc::<u16>::new(&CRC_16_IBM_3740);

/// Errors building or writing a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// A payload longer than [`MAX_PAYLOAD`].
    #[error("payload of {0} bytes exceeds the {MAX_PAYLOAD}-byte maximum")]
    PayloadTooLong(usize),
    /// The output buffer is smaller than the frame.
    #[error("the frame needs {need} bytes, the buffer has {have}")]
    BufferTooSmall {
        /// Bytes needed.
        need: usize,
        /// Bytes available.
        have: usize,
    },
}

/// The KIND byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum FrameKind {
    /// Host to device.
    Request = 0,
    /// Device's answer.
    Response = 1,
    /// Device's refusal.
    Nack = 2,
    /// Unprompted device message.
    Event = 3,
}

impl core::fmt::Display for FrameKind {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            FrameKind::Request => "request",
            FrameKind::Response => "response",
            FrameKind::Nack => "NACK",
            FrameKind::Event => "event",
        })
    }
}

impl FrameKind {
    /// The kind for a KIND byte, if defined.
    pub const fn from_byte(b: u8) -> Option<Self> {
        match b {
            0 => Some(FrameKind::Request),
            1 => Some(FrameKind::Response),
            2 => Some(FrameKind::Nack),
            3 => Some(FrameKind::Event),
            _ => None,
        }
    }
}

/// One frame, payload in a fixed buffer.
#[derive(Clone, Copy)]
pub struct Frame {
    /// VER byte (major in the high nibble).
    pub version: u8,
    /// KIND.
    pub kind: FrameKind,
    /// Sequence number.
    pub seq: u8,
    /// Message id.
    pub msg: u8,
    len: u8,
    buf: [u8; MAX_PAYLOAD],
}

impl Frame {
    /// A frame of this implementation's version.
    pub fn new(kind: FrameKind, seq: u8, msg: u8, payload: &[u8]) -> Result<Self, FrameError> {
        let mut buf = [0u8; MAX_PAYLOAD];
        buf.get_mut(..payload.len())
            .ok_or(FrameError::PayloadTooLong(payload.len()))?
            .copy_from_slice(payload);
        Ok(Frame {
            version: VERSION,
            kind,
            seq,
            msg,
            // payload.len() ≤ MAX_PAYLOAD = 240 was checked by the get_mut above.
            len: payload.len() as u8,
            buf,
        })
    }

    /// A frame from a payload buffer whose first `len` bytes are the payload (`len` is
    /// clamped to [`MAX_PAYLOAD`]).
    pub(crate) fn from_parts(
        kind: FrameKind,
        seq: u8,
        msg: u8,
        buf: [u8; MAX_PAYLOAD],
        len: usize,
    ) -> Self {
        Frame {
            version: VERSION,
            kind,
            seq,
            msg,
            // Clamped to MAX_PAYLOAD = 240, which fits a u8.
            len: len.min(MAX_PAYLOAD) as u8,
            buf,
        }
    }

    /// The payload.
    pub fn payload(&self) -> &[u8] {
        &self.buf[..usize::from(self.len)]
    }

    /// Bytes on the wire.
    pub fn wire_len(&self) -> usize {
        OVERHEAD + usize::from(self.len)
    }

    /// Writes the frame into `out`; returns the bytes written.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, FrameError> {
        let n = self.wire_len();
        let have = out.len();
        let dst = out
            .get_mut(..n)
            .ok_or(FrameError::BufferTooSmall { need: n, have })?;
        dst[..2].copy_from_slice(&SYNC);
        dst[2] = self.len;
        dst[3] = self.version;
        dst[4] = self.kind as u8;
        dst[5] = self.seq;
        dst[6] = self.msg;
        dst[HEADER_LEN..n - 2].copy_from_slice(self.payload());
        let crc = CRC16.checksum(&dst[2..n - 2]);
        dst[n - 2..].copy_from_slice(&crc.to_le_bytes());
        Ok(n)
    }

    /// The frame's bytes.
    #[cfg(feature = "std")]
    pub fn to_bytes(&self) -> std::vec::Vec<u8> {
        let mut out = [0u8; MAX_FRAME];
        // MAX_FRAME bytes hold any frame.
        let n = self.encode(&mut out).unwrap_or(0);
        out[..n].to_vec()
    }
}

impl PartialEq for Frame {
    fn eq(&self, other: &Self) -> bool {
        (self.version, self.kind, self.seq, self.msg)
            == (other.version, other.kind, other.seq, other.msg)
            && self.payload() == other.payload()
    }
}

impl Eq for Frame {}

impl core::fmt::Debug for Frame {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Frame")
            .field("version", &self.version)
            .field("kind", &self.kind)
            .field("seq", &self.seq)
            .field("msg", &self.msg)
            .field("payload", &self.payload())
            .finish()
    }
}

/// What the decoder skipped.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DecoderStats {
    /// Frames decoded.
    pub frames: u64,
    /// Bytes dropped while resynchronising.
    pub bytes_dropped: u64,
    /// Candidates with an impossible header.
    pub bad_headers: u64,
    /// Candidates whose CRC failed.
    pub bad_crcs: u64,
    /// Incomplete candidates abandoned because a valid frame followed (SPEC.md §2.1 rule 4).
    pub false_starts: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Candidate {
    Incomplete,
    BadHeader,
    BadCrc,
    Valid(usize, FrameKind),
}

fn candidate(buf: &[u8]) -> Candidate {
    if buf.len() < HEADER_LEN {
        return Candidate::Incomplete;
    }
    let len = usize::from(buf[2]);
    let kind = FrameKind::from_byte(buf[4]);
    let Some(kind) = kind.filter(|_| len <= MAX_PAYLOAD && buf[3] >> 4 == MAJOR) else {
        return Candidate::BadHeader;
    };
    if buf.len() < OVERHEAD + len {
        return Candidate::Incomplete;
    }
    let expected = CRC16.checksum(&buf[2..HEADER_LEN + len]);
    let got = u16::from_le_bytes([buf[HEADER_LEN + len], buf[HEADER_LEN + len + 1]]);
    if expected == got {
        Candidate::Valid(len, kind)
    } else {
        Candidate::BadCrc
    }
}

fn valid_frame_follows(buf: &[u8]) -> bool {
    (1..buf.len().saturating_sub(1))
        .filter(|&i| buf[i..i + 2] == SYNC)
        .any(|i| matches!(candidate(&buf[i..]), Candidate::Valid(..)))
}

/// The outcome of one [`scan`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Scan {
    /// Bytes at the front of the buffer that are done with (dropped, or the frame's own).
    pub consumed: usize,
    /// The frame found, if any; without one, more bytes are needed.
    pub frame: Option<Frame>,
}

/// Applies SPEC.md §2.1 to the front of `buf`: skips garbage and returns the first valid frame,
/// or how much can be dropped while waiting for more bytes. Updates `stats`.
pub fn scan(buf: &[u8], stats: &mut DecoderStats) -> Scan {
    let mut at = 0;
    loop {
        let rest = &buf[at..];
        match rest.windows(2).position(|w| w == SYNC) {
            Some(pos) => at += pos,
            None => {
                // Keep a trailing 0xAA: it may be the first half of a sync.
                let keep = usize::from(rest.last() == Some(&SYNC[0]));
                at += rest.len() - keep;
                stats.bytes_dropped += at as u64;
                return Scan {
                    consumed: at,
                    frame: None,
                };
            }
        }
        let rest = &buf[at..];
        match candidate(rest) {
            Candidate::BadHeader => {
                stats.bad_headers += 1;
                at += 1;
            }
            Candidate::BadCrc => {
                stats.bad_crcs += 1;
                at += 1;
            }
            Candidate::Incomplete if valid_frame_follows(rest) => {
                // Garbage that looks like the header of a long frame would otherwise hold
                // back the complete frame behind it until LEN more bytes arrive.
                stats.false_starts += 1;
                at += 1;
            }
            Candidate::Incomplete => {
                stats.bytes_dropped += at as u64;
                return Scan {
                    consumed: at,
                    frame: None,
                };
            }
            Candidate::Valid(len, kind) => {
                let mut payload = [0u8; MAX_PAYLOAD];
                payload[..len].copy_from_slice(&rest[HEADER_LEN..HEADER_LEN + len]);
                stats.bytes_dropped += at as u64;
                stats.frames += 1;
                return Scan {
                    consumed: at + OVERHEAD + len,
                    frame: Some(Frame {
                        version: rest[3],
                        kind,
                        seq: rest[5],
                        msg: rest[6],
                        // len ≤ MAX_PAYLOAD was checked by candidate().
                        len: len as u8,
                        buf: payload,
                    }),
                };
            }
        }
    }
}

/// A resynchronising decoder in a fixed buffer of `N` bytes (at least [`MAX_FRAME`]), for
/// firmware: no allocation, any split of the input.
#[derive(Debug, Clone)]
pub struct FrameDecoder<const N: usize> {
    buf: [u8; N],
    len: usize,
    stats: DecoderStats,
}

impl<const N: usize> Default for FrameDecoder<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> FrameDecoder<N> {
    const ROOM: () = assert!(
        N >= MAX_FRAME,
        "a FrameDecoder needs room for the longest frame"
    );

    /// An empty decoder.
    pub const fn new() -> Self {
        #[allow(clippy::let_unit_value)]
        let () = Self::ROOM;
        FrameDecoder {
            buf: [0u8; N],
            len: 0,
            stats: DecoderStats {
                frames: 0,
                bytes_dropped: 0,
                bad_headers: 0,
                bad_crcs: 0,
                false_starts: 0,
            },
        }
    }

    /// What was decoded and skipped so far.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Bytes held that are not yet a frame (the start of one, or garbage still being scanned).
    pub fn buffered(&self) -> usize {
        self.len
    }

    /// Discards the bytes held: a partial frame whose sender paused longer than the inter-byte
    /// gap of SPEC.md §2.1 (the host restarted mid-frame).
    pub fn clear(&mut self) {
        self.len = 0;
    }

    /// Feeds received bytes; calls `on_frame` for every complete valid frame, in order.
    pub fn feed(&mut self, mut bytes: &[u8], mut on_frame: impl FnMut(Frame)) {
        while !bytes.is_empty() {
            let room = N - self.len;
            let take = room.min(bytes.len());
            self.buf[self.len..self.len + take].copy_from_slice(&bytes[..take]);
            self.len += take;
            bytes = &bytes[take..];
            loop {
                let s = scan(&self.buf[..self.len], &mut self.stats);
                self.buf.copy_within(s.consumed..self.len, 0);
                self.len -= s.consumed;
                match s.frame {
                    Some(f) => on_frame(f),
                    None => break,
                }
            }
        }
    }
}
