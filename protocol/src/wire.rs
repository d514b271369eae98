//! Little-endian payload fields: the [`Payload`] trait, implemented for the primitive field
//! types here and for every message struct by the table in [`crate::message`], so a payload's
//! length, encoding and decoding all follow from its field list.

use crate::message::MessageError;

/// Writes fields into a fixed buffer; past its end it records the overflow instead of
/// panicking (a message table bug, never input-dependent: every payload fits 240 bytes).
pub struct Writer<'a> {
    buf: &'a mut [u8],
    pos: usize,
    overflow: bool,
}

impl<'a> Writer<'a> {
    /// A writer at the start of `buf`.
    pub fn new(buf: &'a mut [u8]) -> Self {
        Writer {
            buf,
            pos: 0,
            overflow: false,
        }
    }

    /// Appends raw bytes.
    pub fn bytes(&mut self, b: &[u8]) {
        match self.buf.get_mut(self.pos..self.pos + b.len()) {
            Some(dst) => {
                dst.copy_from_slice(b);
                self.pos += b.len();
            }
            None => self.overflow = true,
        }
    }

    /// Bytes written.
    pub fn len(&self) -> usize {
        self.pos
    }

    /// Whether nothing was written.
    pub fn is_empty(&self) -> bool {
        self.pos == 0
    }

    /// Whether a write did not fit.
    pub fn overflowed(&self) -> bool {
        self.overflow
    }
}

/// Reads fields from a payload, counting them so an undefined value can be NACKed with its
/// field's index (SPEC.md §3.1).
pub struct Reader<'a> {
    msg: u8,
    buf: &'a [u8],
    pos: usize,
    field: u8,
}

impl<'a> Reader<'a> {
    /// A reader over message `msg`'s payload.
    pub fn new(msg: u8, buf: &'a [u8]) -> Self {
        Reader {
            msg,
            buf,
            pos: 0,
            field: 0,
        }
    }

    /// The next `N` bytes as one field.
    pub fn bytes<const N: usize>(&mut self) -> Result<[u8; N], MessageError> {
        let end = self.pos + N;
        let out = self
            .buf
            .get(self.pos..end)
            .and_then(|s| <[u8; N]>::try_from(s).ok())
            .ok_or(MessageError::BadLength {
                msg: self.msg,
                need: end,
                got: self.buf.len(),
            })?;
        self.pos = end;
        self.field = self.field.saturating_add(1);
        Ok(out)
    }

    /// The error for an undefined value in the field just read.
    pub fn out_of_range(&self, value: u64) -> MessageError {
        MessageError::OutOfRange {
            msg: self.msg,
            field: self.field.saturating_sub(1),
            value,
        }
    }
}

/// A fixed-length little-endian payload or field.
pub trait Payload: Sized {
    /// Length on the wire (bytes).
    const LEN: usize;
    /// Appends the encoding.
    fn put(&self, w: &mut Writer<'_>);
    /// Reads it back; undefined values are [`MessageError::OutOfRange`].
    fn get(r: &mut Reader<'_>) -> Result<Self, MessageError>;
}

macro_rules! int_payload {
    ($($t:ty),*) => {$(
        impl Payload for $t {
            const LEN: usize = core::mem::size_of::<$t>();
            fn put(&self, w: &mut Writer<'_>) {
                w.bytes(&self.to_le_bytes());
            }
            fn get(r: &mut Reader<'_>) -> Result<Self, MessageError> {
                r.bytes().map(<$t>::from_le_bytes)
            }
        }
    )*};
}
int_payload!(u8, i16, u16, i32, u32, u64);

impl Payload for bool {
    const LEN: usize = 1;
    fn put(&self, w: &mut Writer<'_>) {
        w.bytes(&[u8::from(*self)]);
    }
    fn get(r: &mut Reader<'_>) -> Result<Self, MessageError> {
        match r.bytes::<1>()?[0] {
            0 => Ok(false),
            1 => Ok(true),
            b => Err(r.out_of_range(u64::from(b))),
        }
    }
}
