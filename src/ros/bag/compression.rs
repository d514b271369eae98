//! zstd where rosbag2 puts it: a whole storage file (`compression_mode: FILE`, one streamed
//! frame, `<file>.zstd`) and each message on its own (`MESSAGE`, one frame per message, the
//! storage file itself plain); and a whole file in LZ4 frames (`<file>.lz4`, what the `lz4`
//! tool makes of a bag: rosbag2 itself compresses with zstd only). A file compressed whole is
//! decompressed as it is read ([`stream`]), never into memory; what comes out counts against
//! the run's budget ([`crate::io::budget::RUN_BYTES`]) and may not pass
//! [`crate::io::budget::BAG_FILE`]; a message, [`crate::io::budget::BAG_MESSAGE`]. (MCAP's own
//! chunk compression is [`super::mcap`]'s; ROS 1 chunks are [`super::ros1`]'s.)

use super::BagError;
#[cfg(feature = "bag-compression")]
use crate::io::budget;
use std::io::Read;
use std::path::Path;
#[cfg(feature = "bag-compression")]
use std::path::PathBuf;

/// The first bytes of every zstd frame.
pub const ZSTD_MAGIC: &[u8] = &[0x28, 0xB5, 0x2F, 0xFD];

/// The first bytes of every LZ4 frame.
pub const LZ4_MAGIC: &[u8] = &[0x04, 0x22, 0x4D, 0x18];

/// How a whole file is compressed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Whole {
    /// zstd frames (`.zstd`: rosbag2's `compression_mode: FILE`).
    Zstd,
    /// LZ4 frames (`.lz4`).
    Lz4,
}

impl Whole {
    /// How a file starting with `head` is compressed whole, if it is.
    pub fn of(head: &[u8]) -> Option<Whole> {
        if head.starts_with(ZSTD_MAGIC) {
            Some(Whole::Zstd)
        } else if head.starts_with(LZ4_MAGIC) {
            Some(Whole::Lz4)
        } else {
            None
        }
    }

    /// The error `source` met decompressing the file at `path`.
    pub fn error(self, path: &Path, source: std::io::Error) -> BagError {
        match self {
            Whole::Zstd => BagError::Zstd {
                what: path.display().to_string(),
                source,
            },
            Whole::Lz4 => BagError::Lz4 {
                path: path.to_path_buf(),
                source,
            },
        }
    }
}

#[cfg(feature = "bag-compression")]
/// A reader that fails once more than [`budget::BAG_FILE`] bytes came through it, and counts
/// what does against the run's budget.
struct Bounded<R> {
    inner: R,
    read: u64,
    path: PathBuf,
}

#[cfg(feature = "bag-compression")]
impl<R: Read> Read for Bounded<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.read += n as u64;
        let what = || format!("{} (compressed whole)", self.path.display());
        if self.read > budget::BAG_FILE.get() {
            return Err(budget::BAG_FILE.exceeded(self.read, what()).into());
        }
        budget::charge_bytes(n as u64, &what)?;
        Ok(n)
    }
}

#[cfg(feature = "bag-compression")]
/// LZ4 frames back to back, as one stream: each frame read to its end (a frame cut short is
/// an error, not a shorter bag), then the next if bytes follow.
struct Lz4Frames<R: Read> {
    decoder: Option<lz4::Decoder<R>>,
}

#[cfg(feature = "bag-compression")]
impl<R: std::io::BufRead> Read for Lz4Frames<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        loop {
            let Some(decoder) = self.decoder.as_mut() else {
                return Ok(0);
            };
            let n = decoder.read(buf)?;
            if n > 0 || buf.is_empty() {
                return Ok(n);
            }
            let Some(decoder) = self.decoder.take() else {
                return Ok(0);
            };
            let (mut rest, done) = decoder.finish();
            done.map_err(|_| {
                std::io::Error::new(
                    std::io::ErrorKind::UnexpectedEof,
                    "a frame is cut short (a file copied or written in part?)",
                )
            })?;
            if !rest.fill_buf()?.is_empty() {
                self.decoder = Some(lz4::Decoder::new(rest)?);
            }
        }
    }
}

#[cfg(feature = "bag-compression")]
/// The file at `path`, compressed whole, as a stream of what it decompresses to (failing past
/// [`budget::BAG_FILE`]): for a container read as a stream, in memory near its largest record
/// whatever the file's size.
pub fn stream(path: &Path, whole: Whole) -> Result<Box<dyn Read>, BagError> {
    let file =
        crate::io::open_bounded(path, budget::BAG_FILE.get()).map_err(|source| BagError::Io {
            path: path.to_path_buf(),
            source,
        })?;
    let inner: Box<dyn Read> = match whole {
        Whole::Zstd => {
            Box::new(zstd::stream::read::Decoder::new(file).map_err(|e| whole.error(path, e))?)
        }
        Whole::Lz4 => Box::new(Lz4Frames {
            decoder: Some(
                lz4::Decoder::new(std::io::BufReader::new(file))
                    .map_err(|e| whole.error(path, e))?,
            ),
        }),
    };
    Ok(Box::new(Bounded {
        inner,
        read: 0,
        path: path.to_path_buf(),
    }))
}

/// Without the `bag-compression` feature, a file compressed whole is refused by name.
#[cfg(not(feature = "bag-compression"))]
pub fn stream(path: &Path, whole: Whole) -> Result<Box<dyn Read>, BagError> {
    let how = match whole {
        Whole::Zstd => "zstd",
        Whole::Lz4 => "lz4",
    };
    let what = format!("{}, compressed whole with {how},", path.display());
    Err(crate::features::NotBuilt::new(what, &["bag-compression"]).into())
}

/// The first `n` bytes the file at `path` decompresses to (what format it holds).
pub fn head(path: &Path, whole: Whole, n: u64) -> Result<Vec<u8>, BagError> {
    let mut head = Vec::new();
    stream(path, whole)?
        .take(n)
        .read_to_end(&mut head)
        .map_err(|e| whole.error(path, e))?;
    Ok(head)
}

#[cfg(feature = "bag-compression")]
/// Decompresses one message's frame into `out` (cleared first), reusing `ctx` between
/// messages: a frame that records its size (rosbag2 compresses each message in one call, which
/// records it) is decompressed in one step into exactly that much room. Neither may pass
/// [`budget::BAG_MESSAGE`]: a frame that says it would is refused before a byte is
/// decompressed, one that does not say stops there. What comes out counts against the run's
/// budget.
pub fn zstd_message(
    frame: &[u8],
    ctx: &mut zstd::bulk::Decompressor<'static>,
    out: &mut Vec<u8>,
) -> std::io::Result<()> {
    const WHAT: &str = "one compressed message";
    out.clear();
    let bound = budget::BAG_MESSAGE.get();
    match zstd::zstd_safe::get_frame_content_size(frame) {
        Ok(Some(n)) if n <= bound => {
            out.reserve(usize::try_from(n).map_err(|_| budget::BAG_MESSAGE.exceeded(n, WHAT))?);
            let written = ctx.decompress_to_buffer(frame, out)?;
            if written as u64 != n {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::InvalidData,
                    format!("the frame says {n} bytes and holds {written}"),
                ));
            }
        }
        Ok(Some(n)) => return Err(budget::BAG_MESSAGE.exceeded(n, WHAT).into()),
        _ => {
            zstd::stream::read::Decoder::with_buffer(frame)?
                .take(bound + 1)
                .read_to_end(out)?;
            if out.len() as u64 > bound {
                return Err(budget::BAG_MESSAGE.exceeded(out.len() as u64, WHAT).into());
            }
        }
    }
    budget::charge_bytes(out.len() as u64, &|| WHAT.to_string())?;
    Ok(())
}

#[cfg(feature = "bag-compression")]
#[cfg(test)]
mod tests {
    use super::*;

    /// A file of `bytes` in a directory of its own under the system's temporary directory.
    fn file(name: &str, bytes: &[u8]) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("odocal-compression-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(name);
        std::fs::write(&path, bytes).unwrap();
        path
    }

    fn all(path: &Path, whole: Whole) -> Result<Vec<u8>, std::io::Error> {
        let mut out = Vec::new();
        stream(path, whole).unwrap().read_to_end(&mut out)?;
        Ok(out)
    }

    #[test]
    fn files_and_messages_decompress_and_garbage_is_an_error() {
        let text = b"the same bytes, over and over ".repeat(100);
        let frame = zstd::bulk::compress(&text, 3).unwrap();
        assert_eq!(Whole::of(&frame), Some(Whole::Zstd));
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
        let two = file("two.db3.zstd", &[frame.clone(), streamed].concat());
        assert_eq!(head(&two, Whole::Zstd, 16).unwrap(), text[..16]);
        assert_eq!(
            all(&two, Whole::Zstd).unwrap(),
            [text.clone(), text].concat()
        );
        // Cut short, or a lying header: errors.
        for cut in [4, frame.len() / 2, frame.len() - 1] {
            assert!(zstd_message(&frame[..cut], &mut ctx, &mut out).is_err());
            let cut = file("cut.db3.zstd", &frame[..cut]);
            assert!(all(&cut, Whole::Zstd).is_err());
        }
        assert!(zstd_message(&[0x28, 0xB5, 0x2F, 0xFD, 0xFF], &mut ctx, &mut out).is_err());
    }

    #[test]
    fn a_message_past_its_budget_is_refused_whether_its_frame_says_so_or_not() {
        let big = vec![0u8; (budget::BAG_MESSAGE.get() + 1) as usize];
        let mut ctx = zstd::bulk::Decompressor::new().unwrap();
        let mut out = Vec::new();
        let recorded = zstd::bulk::compress(&big, 3).unwrap();
        let mut streamed = Vec::new();
        let mut enc = zstd::stream::write::Encoder::new(&mut streamed, 3).unwrap();
        std::io::Write::write_all(&mut enc, &big).unwrap();
        enc.finish().unwrap();
        for frame in [recorded, streamed] {
            let e = zstd_message(&frame, &mut ctx, &mut out)
                .unwrap_err()
                .to_string();
            assert!(e.contains("--budget bag-message="), "{e}");
        }
    }

    #[test]
    fn lz4_files_decompress_and_garbage_is_an_error() {
        let text = b"the same bytes, over and over ".repeat(100);
        let mut enc = lz4::EncoderBuilder::new().build(Vec::new()).unwrap();
        std::io::Write::write_all(&mut enc, &text).unwrap();
        let (frame, done) = enc.finish();
        done.unwrap();
        assert_eq!(Whole::of(&frame), Some(Whole::Lz4));
        let two = file("two.mcap.lz4", &[frame.clone(), frame.clone()].concat());
        assert_eq!(
            all(&two, Whole::Lz4).unwrap(),
            [text.clone(), text].concat()
        );
        for cut in [4, frame.len() / 2, frame.len() - 1] {
            let path = file("cut.mcap.lz4", &frame[..cut]);
            let result = match stream(&path, Whole::Lz4) {
                Ok(mut r) => r.read_to_end(&mut Vec::new()).map(|_| ()),
                Err(BagError::Lz4 { source, .. }) => Err(source),
                Err(e) => panic!("{e}"),
            };
            assert!(result.is_err(), "cut at {cut}");
        }
    }
}
