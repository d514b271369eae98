//! Frames: `AA 55 | LEN | VER | KIND | SEQ | MSG | payload | CRC16-LE` (SPEC.md §2).
//!
//! The decoder implements the resynchronisation rules of SPEC.md §2.1: on a bad header (length,
//! major version, kind) or a bad CRC it drops *one* byte and rescans, so a valid frame hidden in
//! garbage or in a corrupted frame is still found; and an incomplete candidate is abandoned as
//! soon as a complete valid frame follows it, so garbage that looks like a long header never
//! holds a real frame back. It never returns an error for bad bytes —
//! `tokio_util`'s `Framed` ends the stream after the first `Err` — and counts what it dropped in
//! [`DecoderStats`].

use bytes::{Buf, BufMut, Bytes, BytesMut};
use crc::{Crc, CRC_16_IBM_3740};
use tokio_util::codec::{Decoder, Encoder};

/// The two sync bytes that start every frame.
pub const SYNC: [u8; 2] = [0xAA, 0x55];
/// Largest payload a frame may carry (bytes).
pub const MAX_PAYLOAD: usize = 240;
/// Bytes before the payload: sync (2), LEN, VER, KIND, SEQ, MSG.
pub const HEADER_LEN: usize = 7;
/// Bytes of frame overhead: header plus CRC.
pub const OVERHEAD: usize = HEADER_LEN + 2;
/// The protocol version this crate speaks: major 1, minor 0 (`VER` byte `0x10`).
pub const VERSION: u8 = 0x10;
/// The major version the decoder accepts.
pub const MAJOR: u8 = VERSION >> 4;

/// CRC-16/IBM-3740: poly 0x1021, init 0xFFFF, no reflection, xorout 0; check 0x29B1.
pub const CRC16: Crc<u16> = Crc::<u16>::new(&CRC_16_IBM_3740);

/// Errors of the frame layer. Bad bytes are never errors (they are counted and skipped).
#[derive(Debug, thiserror::Error)]
pub enum ProtocolError {
    /// The underlying byte stream failed.
    #[error("link I/O error: {0}")]
    Io(#[from] std::io::Error),
    /// A frame to encode carries more than [`MAX_PAYLOAD`] bytes.
    #[error("payload of {0} bytes exceeds the {MAX_PAYLOAD}-byte maximum")]
    PayloadTooLong(usize),
}

/// What a frame is (SPEC.md §3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FrameKind {
    /// Host to device.
    Request = 0,
    /// Device's answer to a request.
    Response = 1,
    /// Device's refusal of a request.
    Nack = 2,
    /// Unprompted device message (telemetry, motion done).
    Event = 3,
}

impl FrameKind {
    /// The kind for a `KIND` byte, if valid.
    pub fn from_byte(b: u8) -> Option<Self> {
        match b {
            0 => Some(FrameKind::Request),
            1 => Some(FrameKind::Response),
            2 => Some(FrameKind::Nack),
            3 => Some(FrameKind::Event),
            _ => None,
        }
    }
}

/// One decoded frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frame {
    /// `VER` byte (major in the high nibble).
    pub version: u8,
    /// Frame kind.
    pub kind: FrameKind,
    /// Sequence number.
    pub seq: u8,
    /// Message id.
    pub msg: u8,
    /// Payload bytes.
    pub payload: Bytes,
}

impl Frame {
    /// A frame of this crate's protocol version.
    pub fn new(kind: FrameKind, seq: u8, msg: u8, payload: impl Into<Bytes>) -> Self {
        Frame {
            version: VERSION,
            kind,
            seq,
            msg,
            payload: payload.into(),
        }
    }

    /// Appends the frame's wire bytes to `dst`.
    pub fn encode_into(&self, dst: &mut BytesMut) -> Result<(), ProtocolError> {
        let len = self.payload.len();
        if len > MAX_PAYLOAD {
            return Err(ProtocolError::PayloadTooLong(len));
        }
        dst.reserve(OVERHEAD + len);
        let start = dst.len();
        dst.put_slice(&SYNC);
        // len ≤ MAX_PAYLOAD = 240 was checked above, so it fits the LEN byte.
        dst.put_u8(len as u8);
        dst.put_u8(self.version);
        dst.put_u8(self.kind as u8);
        dst.put_u8(self.seq);
        dst.put_u8(self.msg);
        dst.put_slice(&self.payload);
        let crc = CRC16.checksum(&dst[start + 2..]);
        dst.put_u16_le(crc);
        Ok(())
    }

    /// The frame's wire bytes.
    pub fn to_bytes(&self) -> Result<Bytes, ProtocolError> {
        let mut b = BytesMut::new();
        self.encode_into(&mut b)?;
        Ok(b.freeze())
    }
}

/// Counters of what the decoder skipped (diagnostics for a noisy link).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DecoderStats {
    /// Frames decoded.
    pub frames: u64,
    /// Bytes discarded while searching for a valid frame.
    pub bytes_dropped: u64,
    /// Candidate frames rejected for an impossible header (length, version, kind).
    pub bad_headers: u64,
    /// Candidate frames rejected for a CRC mismatch.
    pub bad_crcs: u64,
    /// Incomplete candidates abandoned because a complete valid frame followed them.
    pub false_starts: u64,
}

/// The frame codec: a resynchronising decoder and an encoder.
#[derive(Debug, Clone, Default)]
pub struct FrameCodec {
    stats: DecoderStats,
}

impl FrameCodec {
    /// A codec with zeroed counters.
    pub fn new() -> Self {
        Self::default()
    }

    /// What the decoder has skipped so far.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Appends `bytes` (one read from the link) to `buf` and returns every frame now complete.
    ///
    /// Bad bytes are skipped and counted, never reported, so this cannot fail.
    pub fn feed(&mut self, buf: &mut BytesMut, bytes: &[u8]) -> Vec<Frame> {
        buf.extend_from_slice(bytes);
        let mut frames = Vec::new();
        // decode() only ever returns Ok: it has no I/O of its own.
        while let Ok(Some(f)) = self.decode(buf) {
            frames.push(f);
        }
        frames
    }

    fn drop_bytes(&mut self, src: &mut BytesMut, n: usize) {
        src.advance(n);
        self.stats.bytes_dropped += n as u64;
    }
}

/// What the bytes at the start of a buffer (beginning with the sync bytes) are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Candidate {
    /// Not enough bytes yet to decide.
    Incomplete,
    /// The header is impossible (length, major version or kind).
    BadHeader,
    /// The header is plausible but the CRC does not match.
    BadCrc,
    /// A valid frame with this payload length and kind.
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

/// Whether a complete, valid frame starts at a sync after the first byte (SPEC.md §2.1 rule 4).
fn valid_frame_follows(buf: &[u8]) -> bool {
    (1..buf.len().saturating_sub(1))
        .filter(|&i| buf[i..i + 2] == SYNC)
        .any(|i| matches!(candidate(&buf[i..]), Candidate::Valid(..)))
}

impl Decoder for FrameCodec {
    type Item = Frame;
    type Error = ProtocolError;

    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<Frame>, ProtocolError> {
        loop {
            match src.windows(2).position(|w| w == SYNC) {
                Some(0) => {}
                Some(pos) => self.drop_bytes(src, pos),
                None => {
                    // Keep a trailing 0xAA: it may be the first half of a sync.
                    let keep = usize::from(src.last() == Some(&SYNC[0]));
                    let n = src.len() - keep;
                    self.drop_bytes(src, n);
                    return Ok(None);
                }
            }
            match candidate(src) {
                Candidate::BadHeader => {
                    self.stats.bad_headers += 1;
                    self.drop_bytes(src, 1);
                }
                Candidate::BadCrc => {
                    self.stats.bad_crcs += 1;
                    self.drop_bytes(src, 1);
                }
                Candidate::Incomplete if valid_frame_follows(src) => {
                    // Garbage that looks like the header of a long frame would otherwise hold
                    // back the complete frame behind it until LEN more bytes arrive.
                    self.stats.false_starts += 1;
                    self.drop_bytes(src, 1);
                }
                Candidate::Incomplete => {
                    return Ok(None);
                }
                Candidate::Valid(len, kind) => {
                    let mut bytes = src.split_to(OVERHEAD + len);
                    let (version, seq, msg) = (bytes[3], bytes[5], bytes[6]);
                    bytes.advance(HEADER_LEN);
                    bytes.truncate(len);
                    self.stats.frames += 1;
                    return Ok(Some(Frame {
                        version,
                        kind,
                        seq,
                        msg,
                        payload: bytes.freeze(),
                    }));
                }
            }
        }
    }
}

impl Encoder<Frame> for FrameCodec {
    type Error = ProtocolError;

    fn encode(&mut self, frame: Frame, dst: &mut BytesMut) -> Result<(), ProtocolError> {
        frame.encode_into(dst)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hex(s: &str) -> Vec<u8> {
        s.split_whitespace()
            .map(|h| u8::from_str_radix(h, 16).unwrap())
            .collect()
    }

    fn decode_all(codec: &mut FrameCodec, bytes: &[u8]) -> Vec<Frame> {
        codec.feed(&mut BytesMut::new(), bytes)
    }

    #[test]
    fn crc_is_the_named_variant() {
        assert_eq!(CRC16.checksum(b"123456789"), 0x29B1);
    }

    #[test]
    fn spec_examples_encode_exactly() {
        let hello = Frame::new(FrameKind::Request, 1, 0x01, vec![1u8, 0]);
        assert_eq!(
            hello.to_bytes().unwrap()[..],
            hex("AA 55 02 10 00 01 01 01 00 1C F9")[..]
        );
        let stop = Frame::new(FrameKind::Request, 7, 0x33, Vec::new());
        assert_eq!(
            stop.to_bytes().unwrap()[..],
            hex("AA 55 00 10 00 07 33 0C 95")[..]
        );
        assert!(matches!(
            Frame::new(FrameKind::Event, 0, 0x51, vec![0u8; 241]).to_bytes(),
            Err(ProtocolError::PayloadTooLong(241))
        ));
    }

    #[test]
    fn garbage_split_reads_and_corruption_are_survived() {
        let a = Frame::new(
            FrameKind::Response,
            9,
            0x41,
            vec![1u8, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12],
        );
        let b = Frame::new(FrameKind::Event, 200, 0x51, vec![0xAAu8; 23]);
        let mut corrupted = a.to_bytes().unwrap().to_vec();
        corrupted[8] ^= 0x40;
        let mut stream = vec![0x00, 0xAA, 0xAA, 0x55, 0xFF, 0x13];
        stream.extend_from_slice(&corrupted);
        stream.extend_from_slice(&a.to_bytes().unwrap());
        stream.extend_from_slice(&b.to_bytes().unwrap());
        // Every split point of the stream into two reads gives the same two frames.
        for split in 0..=stream.len() {
            let mut codec = FrameCodec::new();
            let mut buf = BytesMut::new();
            let mut got = codec.feed(&mut buf, &stream[..split]);
            got.extend(codec.feed(&mut buf, &stream[split..]));
            assert_eq!(got, vec![a.clone(), b.clone()], "split at {split}");
            let s = codec.stats();
            assert_eq!(s.frames, 2);
            assert!(
                s.bad_crcs >= 1,
                "the corrupted copy must be rejected by its CRC"
            );
        }
    }

    #[test]
    fn impossible_headers_are_skipped_not_fatal() {
        let good = Frame::new(FrameKind::Request, 3, 0x40, Vec::new())
            .to_bytes()
            .unwrap();
        let mut codec = FrameCodec::new();
        // Oversize length, unknown major version, unknown kind; then a good frame.
        let mut stream = hex("AA 55 F1 10 00 00 00");
        stream.extend(hex("AA 55 00 20 00 00 00 00 00"));
        stream.extend(hex("AA 55 00 10 07 00 00 00 00"));
        stream.extend_from_slice(&good);
        let frames = decode_all(&mut codec, &stream);
        assert_eq!(frames.len(), 1);
        assert_eq!(frames[0].msg, 0x40);
        assert_eq!(codec.stats().bad_headers, 3);
    }

    #[test]
    fn a_false_long_header_does_not_hold_back_the_next_frame() {
        let good = Frame::new(FrameKind::Response, 3, 0x39, vec![7u8; 12]);
        // Plausible header claiming 180 payload bytes, then a complete valid frame.
        let mut stream = hex("AA 55 B4 10 02 0E EC");
        stream.extend_from_slice(&good.to_bytes().unwrap());
        let mut codec = FrameCodec::new();
        assert_eq!(decode_all(&mut codec, &stream), vec![good]);
        assert_eq!(codec.stats().false_starts, 1);
    }

    #[test]
    fn a_truncated_frame_waits_and_a_bad_crc_yields_nothing() {
        let f = Frame::new(FrameKind::Request, 4, 0x10, vec![0u8])
            .to_bytes()
            .unwrap();
        let mut codec = FrameCodec::new();
        let mut buf = BytesMut::from(&f[..f.len() - 1]);
        assert_eq!(codec.decode(&mut buf).unwrap(), None);
        assert_eq!(
            buf.len(),
            f.len() - 1,
            "a partial frame is kept, not dropped"
        );
        let mut bad = f.to_vec();
        let last = bad.len() - 1;
        bad[last] ^= 1;
        let mut codec = FrameCodec::new();
        assert!(decode_all(&mut codec, &bad).is_empty());
        assert_eq!(codec.stats().bad_crcs, 1);
    }
}
