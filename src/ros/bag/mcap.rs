//! The MCAP container (the ROS 2 default storage from Iron on), read as a stream: channels
//! and metadata from the summary section when the file has one and can be sought (a plain
//! file; not a file compressed whole), messages from one pass over the data, so that memory
//! stays near the largest chunk, not the file.
//!
//! Bounds where the bytes are produced: a record or a compressed chunk past
//! [`crate::io::budget::BAG_CHUNK`] is refused before it is read; a chunk declaring more than
//! that decompressed is refused before a byte of it is decompressed, and one holding more than
//! it declares is an error at its declared size; what chunks decompress to counts against the
//! run's [`crate::io::budget::RUN_BYTES`]; a file compressed whole stops at
//! [`crate::io::budget::BAG_FILE`]. Chunks may be plain, zstd (rosbag2's default) or lz4. A
//! record of opcode 0, which MCAP reserves and no writer writes (what zeros read as), ends the
//! read.

use super::{BagError, Channel, Container, RawMessage};
use ::mcap::records::{self, op, Record};
use ::mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use ::mcap::sans_io::summary_reader::{SummaryReadEvent, SummaryReader, SummaryReaderOptions};
use std::cell::RefCell;
use std::collections::{BTreeMap, HashMap};
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

/// The first bytes of every MCAP file.
pub const MAGIC: &[u8] = ::mcap::MAGIC;

/// Where an MCAP bag's bytes come from.
enum Source {
    /// A file as it lies.
    File,
    /// A file compressed whole (zstd, lz4), decompressed as it is read.
    Whole(super::compression::Whole),
    /// Bytes in memory.
    Bytes(Vec<u8>),
}

/// An MCAP bag, read as a stream each time its messages are asked for.
pub struct McapBag {
    path: PathBuf,
    source: Source,
    summary: Option<::mcap::Summary>,
    /// Metadata records met while reading the messages (a bag without a summary has them only
    /// there).
    seen_metadata: RefCell<Vec<records::Metadata>>,
}

fn error(path: &Path, source: ::mcap::McapError) -> BagError {
    BagError::Mcap {
        path: path.to_path_buf(),
        source,
    }
}

fn malformed(path: &Path, reason: String) -> BagError {
    BagError::Container {
        path: path.to_path_buf(),
        format: "MCAP",
        reason,
    }
}

fn io_error(path: &Path, source: std::io::Error) -> BagError {
    BagError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Most bytes of any one record or compressed chunk, as the reader's `usize` limit.
fn record_limit() -> usize {
    usize::try_from(crate::io::budget::BAG_CHUNK.get()).unwrap_or(usize::MAX)
}

/// The summary of a seekable MCAP of `len` bytes, if it has one.
fn summary_of(
    r: &mut (impl Read + Seek),
    len: u64,
    path: &Path,
) -> Result<Option<::mcap::Summary>, BagError> {
    let mut reader = SummaryReader::new_with_options(
        SummaryReaderOptions::default()
            .with_file_size(len)
            .with_record_length_limit(record_limit()),
    );
    while let Some(event) = reader.next_event() {
        match event.map_err(|e| error(path, e))? {
            SummaryReadEvent::ReadRequest(n) => {
                let got = r.read(reader.insert(n)).map_err(|e| io_error(path, e))?;
                reader.notify_read(got);
            }
            SummaryReadEvent::SeekRequest(to) => {
                let at = r.seek(to).map_err(|e| io_error(path, e))?;
                reader.notify_seeked(at);
            }
        }
    }
    Ok(reader.finish())
}

impl McapBag {
    /// An MCAP file in memory (`path` names it in errors).
    pub fn new(bytes: Vec<u8>, path: &Path) -> Result<Self, BagError> {
        let summary = summary_of(
            &mut std::io::Cursor::new(bytes.as_slice()),
            bytes.len() as u64,
            path,
        )?;
        Ok(McapBag {
            path: path.to_path_buf(),
            source: Source::Bytes(bytes),
            summary,
            seen_metadata: RefCell::new(Vec::new()),
        })
    }

    /// The plain MCAP file at `path`, its summary read where it lies.
    pub fn open(path: &Path) -> Result<Self, BagError> {
        let mut file = crate::io::open_bounded(path, crate::io::budget::BAG_FILE.get())
            .map_err(|e| io_error(path, e))?
            .into_inner();
        let len = file.metadata().map_err(|e| io_error(path, e))?.len();
        let summary = summary_of(&mut file, len, path)?;
        Ok(McapBag {
            path: path.to_path_buf(),
            source: Source::File,
            summary,
            seen_metadata: RefCell::new(Vec::new()),
        })
    }

    /// The MCAP file at `path` compressed whole with zstd: no summary (it cannot be sought),
    /// its channels learnt as it is read.
    pub fn open_whole(path: &Path, whole: super::compression::Whole) -> Result<Self, BagError> {
        Ok(McapBag {
            path: path.to_path_buf(),
            source: Source::Whole(whole),
            summary: None,
            seen_metadata: RefCell::new(Vec::new()),
        })
    }

    /// The bag's bytes from the start, as a stream.
    fn stream(&self) -> Result<Box<dyn Read + '_>, BagError> {
        Ok(match &self.source {
            Source::Bytes(b) => Box::new(b.as_slice()),
            Source::File => Box::new(
                crate::io::open_bounded(&self.path, crate::io::budget::BAG_FILE.get())
                    .map_err(|e| io_error(&self.path, e))?,
            ),
            Source::Whole(whole) => super::compression::stream(&self.path, *whole)?,
        })
    }

    /// The metadata record `name` the summary indexes, read where it lies.
    fn indexed_metadata(&self, name: &str) -> Option<BTreeMap<String, String>> {
        let summary = self.summary.as_ref()?;
        let index = summary
            .metadata_indexes
            .iter()
            .rev()
            .find(|i| i.name == name)?;
        let len = usize::try_from(index.length).ok()?;
        if index.length > crate::io::MAX_TEXT_FILE {
            return None;
        }
        let mut buf = vec![0; len];
        match &self.source {
            Source::Bytes(b) => {
                let start = usize::try_from(index.offset).ok()?;
                buf.copy_from_slice(b.get(start..start.checked_add(len)?)?);
            }
            Source::File => {
                let mut f = std::fs::File::open(&self.path).ok()?;
                f.seek(SeekFrom::Start(index.offset)).ok()?;
                f.read_exact(&mut buf).ok()?;
            }
            Source::Whole(_) => return None,
        }
        match ::mcap::parse_record(*buf.first()?, buf.get(9..)?) {
            Ok(Record::Metadata(m)) => Some(m.metadata),
            _ => None,
        }
    }
}

/// [`McapBag::new`] as a [`super::FileFormat`] opens it.
pub fn open(bytes: Vec<u8>, path: &Path) -> Result<Box<dyn Container>, BagError> {
    Ok(Box::new(McapBag::new(bytes, path)?))
}

/// [`McapBag::open`] as a [`super::FileFormat`] opens a plain file where it lies.
pub fn open_in_place(path: &Path) -> Result<Box<dyn Container>, BagError> {
    Ok(Box::new(McapBag::open(path)?))
}

/// [`McapBag::open_whole`] as a [`super::FileFormat`] opens a file compressed whole.
pub fn open_whole(
    path: &Path,
    whole: super::compression::Whole,
) -> Result<Box<dyn Container>, BagError> {
    Ok(Box::new(McapBag::open_whole(path, whole)?))
}

fn channel(c: &::mcap::Channel<'_>) -> Channel {
    Channel {
        topic: c.topic.clone(),
        type_name: c
            .schema
            .as_ref()
            .map(|s| s.name.clone())
            .unwrap_or_default(),
        encoding: c.message_encoding.clone(),
    }
}

/// What one pass over the records has learnt: schema names and channels by id, and a
/// decompression context and buffer reused from chunk to chunk.
#[derive(Default)]
struct Pass {
    schemas: HashMap<u16, String>,
    channels: HashMap<u16, Channel>,
    #[cfg(feature = "bag-compression")]
    zstd: Option<zstd::bulk::Decompressor<'static>>,
    chunk: Vec<u8>,
    metadata: Vec<records::Metadata>,
}

impl Pass {
    /// One record (`data` without its opcode and length); a chunk's records in turn.
    fn record(
        &mut self,
        opcode: u8,
        data: &[u8],
        path: &Path,
        each: &mut dyn FnMut(RawMessage<'_>) -> Result<(), BagError>,
    ) -> Result<(), BagError> {
        match opcode {
            0 => Err(malformed(
                path,
                "a record of opcode 0, which MCAP reserves: the file is not MCAP past its start \
                 (zeros?)"
                    .into(),
            )),
            op::MESSAGE => {
                let Ok(Record::Message { header, data }) = ::mcap::parse_record(opcode, data)
                else {
                    return Err(malformed(path, "a message record cut short".into()));
                };
                let ch = self.channels.get(&header.channel_id).ok_or_else(|| {
                    malformed(
                        path,
                        format!(
                            "a message on channel {} before that channel's record",
                            header.channel_id
                        ),
                    )
                })?;
                each(RawMessage {
                    channel: ch,
                    log_time_ns: header.log_time,
                    data: &data[..],
                })
            }
            op::SCHEMA | op::CHANNEL | op::METADATA | op::CHUNK => {
                match ::mcap::parse_record(opcode, data).map_err(|e| error(path, e))? {
                    Record::Schema { header, .. } => {
                        self.schemas.insert(header.id, header.name);
                    }
                    Record::Channel(c) => {
                        let type_name = self.schemas.get(&c.schema_id).cloned().unwrap_or_default();
                        self.channels.insert(
                            c.id,
                            Channel {
                                topic: c.topic,
                                type_name,
                                encoding: c.message_encoding,
                            },
                        );
                    }
                    Record::Metadata(m) => self.metadata.push(m),
                    Record::Chunk { header, data } => self.chunk(&header, &data, path, each)?,
                    _ => {}
                }
                Ok(())
            }
            _ => Ok(()),
        }
    }

    /// A chunk's records, decompressed within its declared size.
    fn chunk(
        &mut self,
        header: &records::ChunkHeader,
        data: &[u8],
        path: &Path,
        each: &mut dyn FnMut(RawMessage<'_>) -> Result<(), BagError>,
    ) -> Result<(), BagError> {
        let declared = header.uncompressed_size;
        crate::io::budget::BAG_CHUNK
            .check(declared, "a chunk's declared size")
            .map_err(|e| {
                malformed(
                    path,
                    format!(
                        "{e} (or rewrite the bag with smaller chunks: `mcap convert`, \
                         `ros2 bag convert`)"
                    ),
                )
            })?;
        let mut buf = std::mem::take(&mut self.chunk);
        buf.clear();
        let kind = match header.compression.as_str() {
            "" => "plain",
            c => c,
        };
        let bad = |what: String| malformed(path, format!("a {kind} chunk: {what}"));
        let records: &[u8] = match header.compression.as_str() {
            "" => data,
            c => {
                self.inflate(c, data, declared, &mut buf, path, &bad)?;
                &buf
            }
        };
        if records.len() as u64 != declared {
            let got = records.len();
            self.chunk = buf;
            return Err(bad(format!(
                "it holds {got} bytes or more and declares {declared}"
            )));
        }
        if !header.compression.is_empty() {
            let charged = crate::io::budget::charge_bytes(declared, &|| {
                format!("{} (its chunks)", path.display())
            });
            if let Err(e) = charged {
                self.chunk = buf;
                return Err(BagError::Budget(e));
            }
        }
        let mut at = 0usize;
        let mut result = Ok(());
        while at < records.len() {
            let (Some(&opcode), Some(len)) = (records.get(at), le_u64(records, at + 1)) else {
                result = Err(bad("a record cut short".into()));
                break;
            };
            let body = usize::try_from(len)
                .ok()
                .and_then(|l| (at + 9).checked_add(l))
                .and_then(|end| records.get(at + 9..end));
            let Some(body) = body else {
                result = Err(bad("a record runs past the chunk".into()));
                break;
            };
            if opcode == op::CHUNK {
                result = Err(bad("a chunk inside a chunk".into()));
                break;
            }
            if let Err(e) = self.record(opcode, body, path, each) {
                result = Err(e);
                break;
            }
            at += 9 + body.len();
        }
        self.chunk = buf;
        result
    }

    /// A chunk's `data`, compressed with `compression`, decompressed into `buf` (within its
    /// `declared` size: more is an error, not an allocation); `bad` words what went wrong.
    // Without bag-compression every compressed chunk is refused before it is read: the data,
    // the buffer (which only a decompressor grows) and the rest go unused.
    #[cfg_attr(
        not(feature = "bag-compression"),
        allow(unused_variables, clippy::ptr_arg)
    )]
    fn inflate(
        &mut self,
        compression: &str,
        data: &[u8],
        declared: u64,
        buf: &mut Vec<u8>,
        path: &Path,
        bad: &dyn Fn(String) -> BagError,
    ) -> Result<(), BagError> {
        match compression {
            #[cfg(not(feature = "bag-compression"))]
            c @ ("zstd" | "lz4") => {
                let what = format!("{}, an MCAP with {c} chunks,", path.display());
                Err(crate::features::NotBuilt::new(what, &["bag-compression"]).into())
            }
            #[cfg(feature = "bag-compression")]
            "zstd" => {
                buf.reserve(usize::try_from(declared).unwrap_or(usize::MAX));
                let ctx = match self.zstd.take() {
                    Some(c) => c,
                    None => zstd::bulk::Decompressor::new().map_err(|e| bad(e.to_string()))?,
                };
                let ctx = self.zstd.insert(ctx);
                // Into at most the declared room: more is an error, not an allocation.
                ctx.decompress_to_buffer(data, buf)
                    .map_err(|e| bad(format!("{e} (it declares {declared} bytes)")))?;
                Ok(())
            }
            #[cfg(feature = "bag-compression")]
            "lz4" => {
                lz4::Decoder::new(data)
                    .and_then(|d| d.take(declared + 1).read_to_end(buf))
                    .map_err(|e| bad(e.to_string()))?;
                Ok(())
            }
            other => Err(malformed(
                path,
                format!("a chunk compressed with `{other}`: odocal reads zstd and lz4 chunks"),
            )),
        }
    }
}

/// The little-endian u64 at `at`, if the bytes reach that far.
fn le_u64(bytes: &[u8], at: usize) -> Option<u64> {
    let b: [u8; 8] = bytes.get(at..at.checked_add(8)?)?.try_into().ok()?;
    Some(u64::from_le_bytes(b))
}

impl Container for McapBag {
    fn format(&self) -> &'static str {
        "MCAP"
    }

    fn channels(&self) -> Option<Vec<Channel>> {
        self.summary
            .as_ref()
            .map(|s| s.channels.values().map(|c| channel(c)).collect())
    }

    fn metadata(&self, name: &str) -> Option<BTreeMap<String, String>> {
        self.indexed_metadata(name).or_else(|| {
            self.seen_metadata
                .borrow()
                .iter()
                .rev()
                .find(|m| m.name == name)
                .map(|m| m.metadata.clone())
        })
    }

    fn messages(
        &self,
        each: &mut dyn FnMut(RawMessage<'_>) -> Result<(), BagError>,
    ) -> Result<(), BagError> {
        let mut input = self.stream()?;
        let mut reader = LinearReader::new_with_options(
            LinearReaderOptions::default()
                .with_emit_chunks(true)
                .with_record_length_limit(record_limit()),
        );
        let mut pass = Pass::default();
        while let Some(event) = reader.next_event() {
            match event.map_err(|e| error(&self.path, e))? {
                LinearReadEvent::ReadRequest(n) => {
                    let got = input
                        .read(reader.insert(n))
                        .map_err(|source| match self.source {
                            Source::Whole(whole) => whole.error(&self.path, source),
                            _ => io_error(&self.path, source),
                        })?;
                    reader.notify_read(got);
                }
                LinearReadEvent::Record { opcode, data } => {
                    pass.record(opcode, data, &self.path, each)?;
                }
            }
        }
        *self.seen_metadata.borrow_mut() = pass.metadata;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn string(s: &str) -> Vec<u8> {
        [&(s.len() as u32).to_le_bytes()[..], s.as_bytes()].concat()
    }

    fn record(op: u8, body: &[u8]) -> Vec<u8> {
        [&[op][..], &(body.len() as u64).to_le_bytes(), body].concat()
    }

    /// An MCAP file of `records` between its header and its data end, without a summary.
    fn file(records: &[Vec<u8>]) -> Vec<u8> {
        [
            MAGIC.to_vec(),
            record(op::HEADER, &[string("ros2"), string("t")].concat()),
            records.concat(),
            record(op::DATA_END, &0u32.to_le_bytes()),
            record(op::FOOTER, &[0u8; 20]),
            MAGIC.to_vec(),
        ]
        .concat()
    }

    /// A message on `channel`: sequence, log and publish times, then its data.
    fn message(channel: u16) -> Vec<u8> {
        let body = [
            &channel.to_le_bytes()[..],
            &1u32.to_le_bytes(),
            &5u64.to_le_bytes(),
            &5u64.to_le_bytes(),
            b"data",
        ]
        .concat();
        record(op::MESSAGE, &body)
    }

    /// A chunk of `records` stored plain (or naming `compression` with them plain).
    fn chunk(compression: &str, records: &[u8]) -> Vec<u8> {
        let body = [
            &0u64.to_le_bytes()[..],
            &0u64.to_le_bytes(),
            &(records.len() as u64).to_le_bytes(),
            &0u32.to_le_bytes(),
            &string(compression),
            &(records.len() as u64).to_le_bytes(),
            records,
        ]
        .concat();
        record(op::CHUNK, &body)
    }

    fn channel() -> Vec<u8> {
        let body = [
            &3u16.to_le_bytes()[..],
            &0u16.to_le_bytes(),
            &string("/imu"),
            &string("cdr"),
            &0u32.to_le_bytes(),
        ]
        .concat();
        record(op::CHANNEL, &body)
    }

    fn read(bytes: Vec<u8>) -> Result<usize, BagError> {
        let bag = McapBag::new(bytes, Path::new("t.mcap"))?;
        let mut n = 0;
        bag.messages(&mut |m| {
            assert_eq!(m.channel.topic, "/imu");
            n += 1;
            Ok(())
        })?;
        Ok(n)
    }

    #[test]
    fn messages_read_plain_and_in_chunks_and_bad_records_are_named() {
        assert_eq!(read(file(&[channel(), message(3)])).unwrap(), 1);
        let inner = [channel(), message(3), message(3)].concat();
        assert_eq!(read(file(&[chunk("", &inner)])).unwrap(), 2);
        for (records, says) in [
            (
                vec![message(3)],
                "a message on channel 3 before that channel's record",
            ),
            (vec![record(0, &[])], "a record of opcode 0"),
            (vec![chunk("brotli", &inner)], "compressed with `brotli`"),
            (
                vec![chunk("", &chunk("", &inner))],
                "a chunk inside a chunk",
            ),
            (
                vec![chunk("", &message(3)[..10])],
                "a plain chunk: a record runs past the chunk",
            ),
            (
                vec![chunk("", &message(3)[..5])],
                "a plain chunk: a record cut short",
            ),
        ] {
            let err = read(file(&records)).unwrap_err().to_string();
            assert!(err.contains(says), "{says}: {err}");
            assert!(err.contains("not a readable MCAP bag"), "{err}");
        }
    }
}
