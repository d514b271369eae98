//! The serial wire protocol of `protocol/SPEC.md`: frames and their codec (no I/O here).
//!
//! [`frame`] owns the frame layer: sync bytes, header, CRC-16/IBM-3740, and a
//! `tokio_util::codec` decoder that resynchronises on any garbage instead of failing the stream.
//! Typed messages on top of it are still to come (issue 3).

pub mod frame;

pub use frame::{DecoderStats, Frame, FrameCodec, FrameKind, ProtocolError};
