//! The frame decoder as a `tokio_util` codec over `BytesMut`, for hosts.
//!
//! Its `decode` never returns an error for bad bytes — `tokio_util`'s `Framed` ends the stream
//! after the first `Err` — so a noisy line never kills a connection.

use crate::frame::{scan, DecoderStats, Frame};
use bytes::{Buf, BytesMut};
use std::vec::Vec;
use tokio_util::codec::{Decoder, Encoder};

/// The resynchronising decoder (and trivial encoder) of SPEC.md §2 over `BytesMut`.
#[derive(Debug, Clone, Default)]
pub struct FrameCodec {
    stats: DecoderStats,
}

impl FrameCodec {
    /// A fresh codec.
    pub fn new() -> Self {
        Self::default()
    }

    /// What was decoded and skipped so far.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Appends `bytes` to `buf` and returns every complete frame; for reads that arrive in
    /// arbitrary pieces.
    pub fn feed(&mut self, buf: &mut BytesMut, bytes: &[u8]) -> Vec<Frame> {
        buf.extend_from_slice(bytes);
        let mut frames = Vec::new();
        while let Ok(Some(f)) = self.decode(buf) {
            frames.push(f);
        }
        frames
    }
}

impl Decoder for FrameCodec {
    type Item = Frame;
    type Error = std::io::Error;

    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<Frame>, std::io::Error> {
        let s = scan(src, &mut self.stats);
        src.advance(s.consumed);
        Ok(s.frame)
    }
}

impl Encoder<Frame> for FrameCodec {
    type Error = std::io::Error;

    fn encode(&mut self, frame: Frame, dst: &mut BytesMut) -> Result<(), std::io::Error> {
        dst.extend_from_slice(&frame.to_bytes());
        Ok(())
    }
}
