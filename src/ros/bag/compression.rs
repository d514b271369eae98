//! zstd where rosbag2 puts it: a whole storage file (`compression_mode: FILE`, one streamed
//! frame, `<file>.zstd`) and each message on its own (`MESSAGE`, one frame per message, the
//! storage file itself plain); and a whole file in LZ4 frames (`<file>.lz4`, what the `lz4`
//! tool makes of a bag: rosbag2 itself compresses with zstd only). Output never exceeds
//! [`crate::io::MAX_BAG_FILE`]: a frame that would grow past it is an error, not an
//! allocation. (MCAP's own chunk compression, zstd or lz4, is the `mcap` crate's; ROS 1 chunks
//! are [`super::ros1`]'s.)

use super::BagError;
use std::io::Read;
use std::path::Path;

/// The first bytes of every zstd frame.
pub const ZSTD_MAGIC: &[u8] = &[0x28, 0xB5, 0x2F, 0xFD];

/// Decompresses a whole zstd file (`path` names it in errors).
pub fn zstd_file(bytes: &[u8], path: &Path) -> Result<Vec<u8>, BagError> {
    let mut out = Vec::new();
    stream(bytes, &mut out, crate::io::MAX_BAG_FILE, FILE).map_err(|source| BagError::Zstd {
        what: path.display().to_string(),
        source,
    })?;
    Ok(out)
}

/// The first 16 bytes the zstd file at `path` decompresses to (what format it holds), if it
/// decompresses at all.
pub fn zstd_head(path: &Path) -> Option<Vec<u8>> {
    let file = crate::io::open_bounded(path, crate::io::MAX_BAG_FILE).ok()?;
    let mut head = Vec::new();
    zstd::stream::read::Decoder::new(file)
        .ok()?
        .take(16)
        .read_to_end(&mut head)
        .ok()?;
    Some(head)
}

/// A reader that fails once more than `left` bytes came through it (a file compressed whole
/// that decompresses past its bound).
struct Bounded<R> {
    inner: R,
    left: u64,
}

impl<R: Read> Read for Bounded<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.left = self
            .left
            .checked_sub(n as u64)
            .ok_or_else(|| too_large(crate::io::MAX_BAG_FILE + 1, crate::io::MAX_BAG_FILE, FILE))?;
        Ok(n)
    }
}

/// The zstd file at `path` as a stream of what it decompresses to, failing past
/// [`crate::io::MAX_BAG_FILE`]: for a container read as a stream, in memory near its largest
/// record whatever the file's size.
pub fn zstd_stream(path: &Path) -> Result<Box<dyn Read>, BagError> {
    let file =
        crate::io::open_bounded(path, crate::io::MAX_BAG_FILE).map_err(|source| BagError::Io {
            path: path.to_path_buf(),
            source,
        })?;
    let decoder = zstd::stream::read::Decoder::new(file).map_err(|source| BagError::Zstd {
        what: path.display().to_string(),
        source,
    })?;
    Ok(Box::new(Bounded {
        inner: decoder,
        left: crate::io::MAX_BAG_FILE,
    }))
}

/// The first bytes of every LZ4 frame.
pub const LZ4_MAGIC: &[u8] = &[0x04, 0x22, 0x4D, 0x18];

/// Decompresses a whole file of LZ4 frames (`path` names it in errors): every frame of it,
/// each read to its end (a frame cut short is an error, not a shorter bag).
pub fn lz4_file(bytes: &[u8], path: &Path) -> Result<Vec<u8>, BagError> {
    let error = |source| BagError::Lz4 {
        path: path.to_path_buf(),
        source,
    };
    let mut out = Vec::new();
    let mut rest = bytes;
    // The decoder stops at the end of a frame; the format allows several back to back.
    while !rest.is_empty() {
        let mut decoder = lz4::Decoder::new(rest).map_err(error)?;
        bounded(&mut decoder, &mut out, crate::io::MAX_BAG_FILE, FILE).map_err(error)?;
        let (left, done) = decoder.finish();
        done.map_err(|_| {
            error(std::io::Error::new(
                std::io::ErrorKind::UnexpectedEof,
                format!("a frame is cut short after {} bytes", out.len()),
            ))
        })?;
        rest = left;
    }
    Ok(out)
}

/// Decompresses one message's frame into `out` (cleared first), reusing `ctx` between
/// messages: a frame that records its size (rosbag2 compresses each message in one call, which
/// records it) is decompressed in one step into exactly that much room. Neither may pass
/// [`crate::io::MAX_BAG_MESSAGE`]: a frame that says it would is refused before a byte is
/// decompressed, one that does not say stops there.
pub fn zstd_message(
    frame: &[u8],
    ctx: &mut zstd::bulk::Decompressor<'static>,
    out: &mut Vec<u8>,
) -> std::io::Result<()> {
    out.clear();
    let bound = crate::io::MAX_BAG_MESSAGE;
    match zstd::zstd_safe::get_frame_content_size(frame) {
        Ok(Some(n)) if n <= bound => {
            out.reserve(usize::try_from(n).map_err(|_| too_large(n, bound, MESSAGE))?);
            let written = ctx.decompress_to_buffer(frame, out)?;
            if written as u64 != n {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::InvalidData,
                    format!("the frame says {n} bytes and holds {written}"),
                ));
            }
            Ok(())
        }
        Ok(Some(n)) => Err(too_large(n, bound, MESSAGE)),
        _ => stream(frame, out, bound, MESSAGE),
    }
}

const FILE: &str = "a bag file";
const MESSAGE: &str = "a message on these topics";

/// Streams every frame of `bytes` into `out`, stopping with an error past `bound`.
fn stream(bytes: &[u8], out: &mut Vec<u8>, bound: u64, what: &str) -> std::io::Result<()> {
    bounded(
        &mut zstd::stream::read::Decoder::with_buffer(bytes)?,
        out,
        bound,
        what,
    )
}

/// Appends what a decoder gives to `out`, stopping with an error once `out` would pass
/// `bound`.
fn bounded(
    decoder: &mut impl Read,
    out: &mut Vec<u8>,
    bound: u64,
    what: &str,
) -> std::io::Result<()> {
    let room = (bound + 1).saturating_sub(out.len() as u64);
    decoder.take(room).read_to_end(out)?;
    if out.len() as u64 > bound {
        return Err(too_large(out.len() as u64, bound, what));
    }
    Ok(())
}

fn too_large(n: u64, bound: u64, what: &str) -> std::io::Error {
    std::io::Error::new(
        std::io::ErrorKind::InvalidData,
        format!(
            "decompresses to {n} bytes or more, past the {} {what} may have (io::SIZE_BOUNDS)",
            crate::io::bytes(bound)
        ),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn files_and_messages_decompress_and_garbage_is_an_error() {
        let text = b"the same bytes, over and over ".repeat(100);
        let frame = zstd::bulk::compress(&text, 3).unwrap();
        assert!(frame.starts_with(ZSTD_MAGIC));
        let mut ctx = zstd::bulk::Decompressor::new().unwrap();
        let mut out = vec![1, 2, 3];
        zstd_message(&frame, &mut ctx, &mut out).unwrap();
        assert_eq!(out, text);
        // A streamed frame (no recorded size) and two frames back to back, as a file.
        let mut streamed = Vec::new();
        let mut enc = zstd::stream::write::Encoder::new(&mut streamed, 3).unwrap();
        std::io::Write::write_all(&mut enc, &text).unwrap();
        enc.finish().unwrap();
        zstd_message(&streamed, &mut ctx, &mut out).unwrap();
        assert_eq!(out, text);
        let two = [frame.clone(), streamed].concat();
        assert_eq!(
            zstd_file(&two, Path::new("x.db3.zstd")).unwrap(),
            [text.clone(), text].concat()
        );
        // Cut short, or a lying header: errors.
        for cut in [4, frame.len() / 2, frame.len() - 1] {
            assert!(zstd_message(&frame[..cut], &mut ctx, &mut out).is_err());
            assert!(matches!(
                zstd_file(&frame[..cut], Path::new("x.db3.zstd")),
                Err(BagError::Zstd { .. })
            ));
        }
        assert!(zstd_message(&[0x28, 0xB5, 0x2F, 0xFD, 0xFF], &mut ctx, &mut out).is_err());
    }

    #[test]
    fn lz4_files_decompress_and_garbage_is_an_error() {
        let text = b"the same bytes, over and over ".repeat(100);
        let mut enc = lz4::EncoderBuilder::new().build(Vec::new()).unwrap();
        std::io::Write::write_all(&mut enc, &text).unwrap();
        let (frame, done) = enc.finish();
        done.unwrap();
        assert!(frame.starts_with(LZ4_MAGIC));
        let two = [frame.clone(), frame.clone()].concat();
        let path = Path::new("x.mcap.lz4");
        assert_eq!(lz4_file(&two, path).unwrap(), [text.clone(), text].concat());
        for cut in [4, frame.len() / 2, frame.len() - 1] {
            assert!(
                matches!(lz4_file(&frame[..cut], path), Err(BagError::Lz4 { .. })),
                "cut at {cut}"
            );
        }
    }
}
