//! The odocal serial wire protocol of `SPEC.md`: frames, their CRC and a resynchronising
//! decoder ([`frame`]), the typed messages of SPEC.md §5 ([`message`], described once in a
//! table from which ids, lengths, encoding and decoding follow), and the conversion between SI
//! units and the wire's fixed point ([`units`]), and the device side for firmware authors
//! ([`device`]: the protocol's state machine over a small board trait).
//!
//! The core is `#![no_std]` and needs no allocator: frames live in fixed-size buffers and
//! [`frame::FrameDecoder`] resynchronises inside a buffer of the caller's size, so firmware can
//! link the same codec the host uses. Features: `std`; `tokio` (default) adds
//! [`codec::FrameCodec`], a `tokio_util` codec over `BytesMut`; `serde` (default) derives
//! serde on every message type.
//!
//! ```
//! use odocal_protocol::frame::{FrameDecoder, MAX_FRAME};
//! use odocal_protocol::message::{Packet, Request};
//!
//! let frame = Packet::request(7, Request::Stop).to_frame();
//! let mut wire = [0u8; MAX_FRAME];
//! let n = frame.encode(&mut wire).unwrap();
//! assert_eq!(wire[..n], [0xAA, 0x55, 0x00, 0x10, 0x00, 0x07, 0x33, 0x0C, 0x95]);
//!
//! let mut decoder = FrameDecoder::<256>::new();
//! let mut got = None;
//! decoder.feed(&wire[..n], |f| got = Some(Packet::from_frame(&f)));
//! assert_eq!(got, Some(Ok(Packet::request(7, Request::Stop))));
//! ```

#![no_std]
#![warn(missing_docs)]

#[cfg(feature = "std")]
extern crate std;

#[cfg(feature = "tokio")]
pub mod codec;
pub mod device;
pub mod frame;
pub mod message;
pub mod units;
mod wire;

#[cfg(feature = "tokio")]
pub use codec::FrameCodec;
pub use frame::{DecoderStats, Frame, FrameDecoder, FrameError, FrameKind};
pub use message::{Body, Event, MessageError, Nack, NackCode, Packet, Request, Response};
pub use wire::{Payload, Reader, Writer};
