//! The serial wire protocol of `protocol/SPEC.md`: frames and their codec (no I/O here).
//!
//! [`frame`] owns the frame layer: sync bytes, header, CRC-16/IBM-3740, and a
//! `tokio_util::codec` decoder that resynchronises on any garbage instead of failing the stream.
//! [`message`] owns the typed messages of SPEC.md §5 and their payload layouts.

pub mod frame;
pub mod message;

pub use frame::{DecoderStats, Frame, FrameCodec, FrameKind, ProtocolError};
pub use message::{Body, Event, MessageError, Nack, NackCode, Packet, Request, Response};
