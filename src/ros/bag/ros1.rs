//! The ROS 1 bag container (format 2.0, what Noetic's `rosbag record` writes). A record is a
//! `u32`-length header of `u32`-length `name=value` fields (`op` says which record it is)
//! followed by a `u32`-length data block. After the 13-byte magic come the bag header, then
//! chunks (their data a run of connection and message records, stored plain, bz2 or as an LZ4
//! frame) each followed by its index records, and at the bag header's `index_pos` every
//! connection again and the chunk infos. Messages are read chunk by chunk from the start, so
//! a bag whose index was never written (a recording cut off, then reindexed or not) reads the
//! same; the connections at `index_pos` give the channels up front.
//!
//! A bag file is read as a stream, one record at a time (a plain file where it lies, its index
//! sought; one compressed whole as it decompresses, without its index), so memory stays near
//! its largest chunk: a record's data and a chunk's declared size are bounded by
//! [`crate::io::budget::BAG_CHUNK`], checked before either is read; what chunks decompress to
//! counts against the run's [`crate::io::budget::RUN_BYTES`].

use super::{BagError, Channel, Container, RawMessage};
use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};

/// The first bytes of every ROS 1 bag of format 2.0.
pub const MAGIC: &[u8] = b"#ROSBAG V2.0\n";

const OP_MESSAGE_DATA: u8 = 0x02;
const OP_BAG_HEADER: u8 = 0x03;
const OP_INDEX_DATA: u8 = 0x04;
const OP_CHUNK: u8 = 0x05;
const OP_CHUNK_INFO: u8 = 0x06;
const OP_CONNECTION: u8 = 0x07;

/// The fields of a record header odocal uses.
#[derive(Debug, Default, Clone, Copy)]
struct Fields<'a> {
    op: Option<u8>,
    conn: Option<u32>,
    time_ns: Option<u64>,
    index_pos: Option<u64>,
    compression: Option<&'a [u8]>,
    size: Option<u32>,
    topic: Option<&'a [u8]>,
    type_name: Option<&'a [u8]>,
}

/// One record: where it starts (in its buffer), its header's fields and its data.
#[derive(Debug, Clone, Copy)]
struct Record<'a> {
    at: usize,
    fields: Fields<'a>,
    data: &'a [u8],
}

fn le_u32(b: &[u8]) -> Option<u32> {
    Some(u32::from_le_bytes(b.try_into().ok()?))
}

fn le_u64(b: &[u8]) -> Option<u64> {
    Some(u64::from_le_bytes(b.try_into().ok()?))
}

/// The `name=value` fields of a header block (a record header, or a connection's data).
fn fields(mut h: &[u8]) -> Result<Fields<'_>, String> {
    let mut f = Fields::default();
    while !h.is_empty() {
        let len = h
            .get(..4)
            .and_then(le_u32)
            .ok_or("a header field cut short")? as usize;
        let end = len
            .checked_add(4)
            .filter(|&e| e <= h.len())
            .ok_or("a header field longer than its header")?;
        let field = &h[4..end];
        h = &h[end..];
        let eq = field
            .iter()
            .position(|&b| b == b'=')
            .ok_or("a header field without `=`")?;
        let (name, value) = (&field[..eq], &field[eq + 1..]);
        let bad = |what: &str| format!("header field `{what}` of {} bytes", value.len());
        match name {
            b"op" => f.op = Some(*value.first().ok_or_else(|| bad("op"))?),
            b"conn" => f.conn = Some(le_u32(value).ok_or_else(|| bad("conn"))?),
            b"time" => {
                let sec = value.get(..4).and_then(le_u32).ok_or_else(|| bad("time"))?;
                let nsec = value.get(4..).and_then(le_u32).ok_or_else(|| bad("time"))?;
                f.time_ns = Some(u64::from(sec) * 1_000_000_000 + u64::from(nsec));
            }
            b"index_pos" => f.index_pos = Some(le_u64(value).ok_or_else(|| bad("index_pos"))?),
            b"compression" => f.compression = Some(value),
            b"size" => f.size = Some(le_u32(value).ok_or_else(|| bad("size"))?),
            b"topic" => f.topic = Some(value),
            b"type" => f.type_name = Some(value),
            _ => {}
        }
    }
    Ok(f)
}

/// The record at `at` of `buf`, and where the next one starts.
fn record(buf: &[u8], at: usize) -> Result<(Record<'_>, usize), String> {
    let cut = || format!("a record cut short at byte {at} (a recording cut off?)");
    let block = |from: usize| -> Result<(&[u8], usize), String> {
        let len = buf.get(from..from + 4).and_then(le_u32).ok_or_else(cut)? as usize;
        let start = from + 4;
        let end = start.checked_add(len).ok_or_else(cut)?;
        Ok((buf.get(start..end).ok_or_else(cut)?, end))
    };
    let (header, next) = block(at)?;
    let (data, next) = block(next)?;
    let fields = fields(header).map_err(|e| format!("record at byte {at}: {e}"))?;
    Ok((Record { at, fields, data }, next))
}

/// Every record of `buf` from `at` on, in order.
fn records(buf: &[u8], mut at: usize) -> impl Iterator<Item = Result<Record<'_>, String>> {
    let mut failed = false;
    std::iter::from_fn(move || {
        if failed || at >= buf.len() {
            return None;
        }
        match record(buf, at) {
            Ok((r, next)) => {
                at = next;
                Some(Ok(r))
            }
            Err(e) => {
                failed = true;
                Some(Err(e))
            }
        }
    })
}

/// Where a ROS 1 bag's bytes come from.
enum Source {
    /// Bytes in memory.
    Bytes(Vec<u8>),
    /// A plain file, read where it lies.
    File,
    /// A file compressed whole (zstd, lz4), decompressed as it is read.
    Whole(super::compression::Whole),
}

/// A ROS 1 bag, in memory or read as a stream each time its messages are asked for.
pub struct Ros1Bag {
    source: Source,
    path: PathBuf,
    /// The connections of the index section by id, when the bag has one.
    indexed: Option<BTreeMap<u32, Channel>>,
}

/// Most bytes of a record header (a few named fields).
const MAX_RECORD_HEADER: u64 = 1 << 20;

/// Most bytes of the index section read to learn the connections up front.
const MAX_INDEX: u64 = 64 << 20;

/// Reads the next record of `input` into `buf` (its header, then its data, each length
/// checked before it is read): the header's length and the record's length in the file;
/// `None` at the end of the input, between records.
fn read_record(input: &mut dyn Read, buf: &mut Vec<u8>) -> std::io::Result<Option<(usize, usize)>> {
    use std::io::{Error, ErrorKind};
    let mut len = [0u8; 4];
    let mut got = 0;
    while got < 4 {
        match input.read(&mut len[got..])? {
            0 => break,
            n => got += n,
        }
    }
    if got == 0 {
        return Ok(None);
    }
    let cut = || Error::new(ErrorKind::UnexpectedEof, "cut short");
    if got < 4 {
        return Err(cut());
    }
    let header_len = u64::from(u32::from_le_bytes(len));
    if header_len > MAX_RECORD_HEADER {
        return Err(Error::new(
            ErrorKind::InvalidData,
            format!("a record header of {header_len} bytes"),
        ));
    }
    buf.clear();
    input.take(header_len).read_to_end(buf)?;
    if buf.len() as u64 != header_len {
        return Err(cut());
    }
    input.read_exact(&mut len).map_err(|_| cut())?;
    let data_len = u64::from(u32::from_le_bytes(len));
    crate::io::budget::BAG_CHUNK.check(data_len, "a record's data")?;
    input.take(data_len).read_to_end(buf)?;
    if buf.len() as u64 != header_len + data_len {
        return Err(cut());
    }
    // Both lengths are within u32 and the bounds above: they fit a usize.
    Ok(Some((
        header_len as usize,
        (8 + header_len + data_len) as usize,
    )))
}

/// The connections of an index section (`buf`, from the bag header's `index_pos` on); `None`
/// when it cannot be read (the messages are read without it).
fn index_of(buf: &[u8]) -> Option<BTreeMap<u32, Channel>> {
    let mut channels = BTreeMap::new();
    for r in records(buf, 0) {
        let r = r.ok()?;
        if r.fields.op == Some(OP_CONNECTION) {
            let (id, ch) = connection(&r).ok()?;
            channels.insert(id, ch);
        }
    }
    Some(channels)
}

impl Ros1Bag {
    /// Checks the bag header of `bytes` (from `path`) and reads the connections its index
    /// lists.
    pub fn new(bytes: Vec<u8>, path: &Path) -> Result<Self, BagError> {
        let mut bag = Ros1Bag {
            source: Source::Bytes(Vec::new()),
            path: path.to_path_buf(),
            indexed: None,
        };
        let (index_pos, _) = bag.header(&mut bytes.as_slice())?;
        // An index that cannot be read is no error: the messages are read without it.
        bag.indexed = index_pos
            .and_then(|p| usize::try_from(p).ok())
            .filter(|&p| p > MAGIC.len() && p < bytes.len())
            .and_then(|p| index_of(&bytes[p..]));
        bag.source = Source::Bytes(bytes);
        Ok(bag)
    }

    /// The plain bag file at `path`, read where it lies: its header checked and the
    /// connections its index lists read (sought at `index_pos`, within 64 MiB).
    pub fn open(path: &Path) -> Result<Self, BagError> {
        use std::io::{Seek, SeekFrom};
        let mut bag = Ros1Bag {
            source: Source::File,
            path: path.to_path_buf(),
            indexed: None,
        };
        let mut file = crate::io::open_bounded(path, crate::io::budget::BAG_FILE.get())
            .map_err(|e| bag.io(e))?
            .into_inner();
        let len = file.metadata().map_err(|e| bag.io(e))?.len();
        let (index_pos, _) = bag.header(&mut file)?;
        bag.indexed = match index_pos {
            Some(p) if p > MAGIC.len() as u64 && p < len && len - p <= MAX_INDEX => {
                let mut tail = Vec::new();
                file.seek(SeekFrom::Start(p)).map_err(|e| bag.io(e))?;
                file.read_to_end(&mut tail).map_err(|e| bag.io(e))?;
                index_of(&tail)
            }
            _ => None,
        };
        Ok(bag)
    }

    /// The bag file at `path` compressed whole with zstd: its header checked; no index (it
    /// cannot be sought), the connections learnt as it is read.
    pub fn open_whole(path: &Path, whole: super::compression::Whole) -> Result<Self, BagError> {
        let bag = Ros1Bag {
            source: Source::Whole(whole),
            path: path.to_path_buf(),
            indexed: None,
        };
        bag.header(&mut bag.stream()?)?;
        Ok(bag)
    }

    /// Reads the magic and the bag header of `input`: the header's `index_pos`, and where
    /// the record after it starts.
    fn header(&self, input: &mut dyn Read) -> Result<(Option<u64>, usize), BagError> {
        let mut magic = [0u8; 13];
        input
            .read_exact(&mut magic)
            .map_err(|_| self.malformed("shorter than its magic".into()))?;
        let mut buf = Vec::new();
        let (h, len) = read_record(input, &mut buf)
            .map_err(|e| self.malformed(format!("the bag header: {e}")))?
            .ok_or_else(|| self.malformed("no bag header".into()))?;
        let f = fields(&buf[..h]).map_err(|e| self.malformed(format!("the bag header: {e}")))?;
        if f.op != Some(OP_BAG_HEADER) {
            return Err(self.malformed("the first record is not the bag header".into()));
        }
        Ok((f.index_pos, MAGIC.len() + len))
    }

    /// The bag's bytes from the start, as a stream.
    fn stream(&self) -> Result<Box<dyn Read + '_>, BagError> {
        Ok(match &self.source {
            Source::Bytes(b) => Box::new(b.as_slice()),
            Source::File => Box::new(
                crate::io::open_bounded(&self.path, crate::io::budget::BAG_FILE.get())
                    .map_err(|e| self.io(e))?,
            ),
            Source::Whole(whole) => super::compression::stream(&self.path, *whole)?,
        })
    }

    fn io(&self, source: std::io::Error) -> BagError {
        BagError::Io {
            path: self.path.clone(),
            source,
        }
    }

    fn malformed(&self, reason: String) -> BagError {
        BagError::Container {
            path: self.path.clone(),
            format: "ROS 1",
            reason,
        }
    }
}

/// [`Ros1Bag::new`] as a [`super::FileFormat`] opens it.
pub fn open(bytes: Vec<u8>, path: &Path) -> Result<Box<dyn Container>, BagError> {
    Ok(Box::new(Ros1Bag::new(bytes, path)?))
}

/// [`Ros1Bag::open`] as a [`super::FileFormat`] opens a plain file where it lies.
pub fn open_in_place(path: &Path) -> Result<Box<dyn Container>, BagError> {
    Ok(Box::new(Ros1Bag::open(path)?))
}

/// [`Ros1Bag::open_whole`] as a [`super::FileFormat`] opens a file compressed whole.
pub fn open_whole(
    path: &Path,
    whole: super::compression::Whole,
) -> Result<Box<dyn Container>, BagError> {
    Ok(Box::new(Ros1Bag::open_whole(path, whole)?))
}

/// A connection record's id and channel.
fn connection(r: &Record<'_>) -> Result<(u32, Channel), String> {
    let at = r.at;
    let id = r
        .fields
        .conn
        .ok_or_else(|| format!("connection record at byte {at} without `conn`"))?;
    let info = fields(r.data).map_err(|e| format!("connection record at byte {at}: {e}"))?;
    let text = |v: Option<&[u8]>| v.map(|b| String::from_utf8_lossy(b).into_owned());
    let topic = text(r.fields.topic.or(info.topic))
        .ok_or_else(|| format!("connection record at byte {at} without `topic`"))?;
    let type_name = text(info.type_name)
        .ok_or_else(|| format!("connection record at byte {at} without `type`"))?;
    Ok((
        id,
        Channel {
            topic,
            type_name,
            encoding: "ros1".into(),
        },
    ))
}

impl Ros1Bag {
    /// Hands the messages of a chunk's records (`buf`, decompressed; the chunk at byte
    /// `chunk` of the file) to `each`, learning connections on the way.
    fn chunk_records(
        &self,
        buf: &[u8],
        chunk: usize,
        conns: &mut BTreeMap<u32, Channel>,
        each: &mut dyn FnMut(RawMessage<'_>) -> Result<(), BagError>,
    ) -> Result<(), BagError> {
        for r in records(buf, 0) {
            let r = r.map_err(|e| self.malformed(format!("in the chunk at byte {chunk}: {e}")))?;
            // A chunk holds no chunk: no scratch is needed below.
            self.one(&r, Some(chunk), conns, &mut Vec::new(), each)?;
        }
        Ok(())
    }

    /// One record (at `r.at` of the file, or of the chunk at `in_chunk`): a message handed to
    /// `each`, a connection learnt, a chunk's records in turn.
    fn one(
        &self,
        r: &Record<'_>,
        in_chunk: Option<usize>,
        conns: &mut BTreeMap<u32, Channel>,
        scratch: &mut Vec<u8>,
        each: &mut dyn FnMut(RawMessage<'_>) -> Result<(), BagError>,
    ) -> Result<(), BagError> {
        let place = |at: usize| match in_chunk {
            Some(chunk) => format!("in the chunk at byte {chunk}, byte {at}"),
            None => format!("at byte {at}"),
        };
        match r.fields.op {
            Some(OP_MESSAGE_DATA) => {
                let (Some(id), Some(log_time_ns)) = (r.fields.conn, r.fields.time_ns) else {
                    return Err(self.malformed(format!(
                        "message record {} without `conn` or `time`",
                        place(r.at)
                    )));
                };
                let Some(channel) = conns.get(&id) else {
                    return Err(self.malformed(format!(
                        "message record {} of connection {id}, before any record of it",
                        place(r.at)
                    )));
                };
                each(RawMessage {
                    channel,
                    log_time_ns,
                    data: r.data,
                })?;
            }
            Some(OP_CONNECTION) => {
                let (id, ch) = connection(r).map_err(|e| self.malformed(e))?;
                conns.insert(id, ch);
            }
            Some(OP_CHUNK) if in_chunk.is_none() => {
                let mut chunk = std::mem::take(scratch);
                let data = self.chunk(r, &mut chunk)?;
                let result = self.chunk_records(data, r.at, conns, each);
                *scratch = chunk;
                result?;
            }
            Some(OP_BAG_HEADER | OP_INDEX_DATA | OP_CHUNK_INFO) => {}
            Some(OP_CHUNK) => {
                return Err(self.malformed(format!("a chunk {} inside a chunk", place(r.at))))
            }
            Some(op) => {
                return Err(self.malformed(format!(
                    "a record of op 0x{op:02X} {} (format 2.0 has 0x02 to 0x07)",
                    place(r.at)
                )))
            }
            None => return Err(self.malformed(format!("a record without `op` {}", place(r.at)))),
        }
        Ok(())
    }

    /// A chunk's records, decompressed into `out` unless stored plain.
    fn chunk<'a>(&self, r: &Record<'a>, out: &'a mut Vec<u8>) -> Result<&'a [u8], BagError> {
        let at = r.at;
        let compression = r.fields.compression.unwrap_or(b"none");
        let size = r.fields.size.ok_or_else(|| {
            self.malformed(format!(
                "chunk at byte {at} without its uncompressed `size`"
            ))
        })?;
        crate::io::budget::BAG_CHUNK
            .check(u64::from(size), format!("the chunk at byte {at}"))
            .map_err(|e| {
                self.malformed(format!(
                    "{e} (or rewrite the bag with smaller chunks: `rosbag compress` with a \
                     smaller --chunk-threshold)"
                ))
            })?;
        let result = match compression {
            b"none" => return Ok(r.data),
            c @ (b"bz2" | b"lz4") => inflate(c, r.data, size, out, &self.path)?,
            other => {
                return Err(self.malformed(format!(
                    "chunk at byte {at} compressed with `{}` (ROS 1 has none, bz2 and lz4)",
                    String::from_utf8_lossy(other)
                )))
            }
        };
        let compression = String::from_utf8_lossy(compression).into_owned();
        let chunk_err = |source| BagError::Ros1Chunk {
            path: self.path.clone(),
            at,
            compression: compression.clone(),
            source,
        };
        result.map_err(chunk_err)?;
        if out.len() != size as usize {
            return Err(chunk_err(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!(
                    "it holds {}{} bytes where its header says {size}",
                    out.len(),
                    if out.len() > size as usize {
                        " or more"
                    } else {
                        ""
                    }
                ),
            )));
        }
        // Not the bag's fault: the run's budget (the error names it and its flag).
        crate::io::budget::charge_bytes(u64::from(size), &|| {
            format!("{} (its chunks)", self.path.display())
        })?;
        Ok(out)
    }
}

impl Container for Ros1Bag {
    fn format(&self) -> &'static str {
        "ROS 1"
    }

    fn channels(&self) -> Option<Vec<Channel>> {
        self.indexed.as_ref().map(|c| c.values().cloned().collect())
    }

    fn messages(
        &self,
        each: &mut dyn FnMut(RawMessage<'_>) -> Result<(), BagError>,
    ) -> Result<(), BagError> {
        // A chunk repeats the connection record before its first message of it; the index's
        // copy covers a writer that left that out.
        let mut conns = self.indexed.clone().unwrap_or_default();
        let mut scratch = Vec::new();
        // Record by record from the stream (bytes in memory too), each where it is in the file
        // for messages.
        let mut input = self.stream()?;
        let (_, mut at) = self.header(&mut input)?;
        let mut buf = Vec::new();
        loop {
            let next = read_record(&mut input, &mut buf).map_err(|e| match e.kind() {
                std::io::ErrorKind::UnexpectedEof => self.malformed(format!(
                    "a record cut short at byte {at} (a recording cut off?)"
                )),
                std::io::ErrorKind::InvalidData => self.malformed(format!("at byte {at}: {e}")),
                std::io::ErrorKind::QuotaExceeded => self.io(e),
                _ => match self.source {
                    Source::Whole(whole) => whole.error(&self.path, e),
                    _ => self.io(e),
                },
            })?;
            let Some((header_len, len)) = next else {
                return Ok(());
            };
            let fields = fields(&buf[..header_len])
                .map_err(|e| self.malformed(format!("record at byte {at}: {e}")))?;
            let r = Record {
                at,
                fields,
                data: &buf[header_len..],
            };
            self.one(&r, None, &mut conns, &mut scratch, each)?;
            at += len;
        }
    }
}

/// A `bz2` or `lz4` chunk's `data` decompressed into `out` (cleared first; at most one byte past
/// its `size`): how that went.
#[cfg(feature = "bag-compression")]
fn inflate(
    compression: &[u8],
    data: &[u8],
    size: u32,
    out: &mut Vec<u8>,
    _path: &Path,
) -> Result<std::io::Result<usize>, BagError> {
    let take = |reader: &mut dyn Read, out: &mut Vec<u8>| {
        out.clear();
        reader.take(u64::from(size) + 1).read_to_end(out)
    };
    Ok(if compression == b"bz2" {
        take(&mut bzip2::read::BzDecoder::new(data), out)
    } else {
        lz4::Decoder::new(data).and_then(|mut d| take(&mut d, out))
    })
}

/// A compressed chunk, in a build without `bag-compression`: refused by name.
#[cfg(not(feature = "bag-compression"))]
fn inflate(
    compression: &[u8],
    _data: &[u8],
    _size: u32,
    _out: &mut Vec<u8>,
    path: &Path,
) -> Result<std::io::Result<usize>, BagError> {
    let what = format!(
        "{}, a ROS 1 bag with {} chunks,",
        path.display(),
        String::from_utf8_lossy(compression)
    );
    Err(crate::features::NotBuilt::new(what, &["bag-compression"]).into())
}

#[cfg(all(test, feature = "bag-compression"))]
mod tests {
    use super::*;

    fn header(fields: &[(&str, &[u8])]) -> Vec<u8> {
        let mut h = Vec::new();
        for (name, value) in fields {
            h.extend(((name.len() + 1 + value.len()) as u32).to_le_bytes());
            h.extend(name.as_bytes());
            h.push(b'=');
            h.extend(*value);
        }
        h
    }

    fn record(fields: &[(&str, &[u8])], data: &[u8]) -> Vec<u8> {
        let h = header(fields);
        let mut r = Vec::new();
        r.extend((h.len() as u32).to_le_bytes());
        r.extend(h);
        r.extend((data.len() as u32).to_le_bytes());
        r.extend(data);
        r
    }

    fn time(sec: u32, nsec: u32) -> Vec<u8> {
        [sec.to_le_bytes(), nsec.to_le_bytes()].concat()
    }

    /// A bag with one chunk (compressed as asked) holding a connection and two messages, and
    /// the index section's connection.
    fn bag(compression: &str) -> Vec<u8> {
        bag_with(compression, true)
    }

    /// The connection record of `/imu` (`sensor_msgs/Imu`, connection 3).
    fn imu_connection() -> Vec<u8> {
        record(
            &[
                ("op", &[OP_CONNECTION]),
                ("conn", &3u32.to_le_bytes()),
                ("topic", b"/imu"),
            ],
            &header(&[
                ("topic", b"/imu"),
                ("type", b"sensor_msgs/Imu"),
                ("md5sum", b"x"),
            ]),
        )
    }

    /// [`bag`], its chunk without the connection record when `conn_in_chunk` is false.
    fn bag_with(compression: &str, conn_in_chunk: bool) -> Vec<u8> {
        let conn = imu_connection();
        let inner = [
            if conn_in_chunk {
                conn.clone()
            } else {
                Vec::new()
            },
            record(
                &[
                    ("op", &[OP_MESSAGE_DATA]),
                    ("conn", &3u32.to_le_bytes()),
                    ("time", &time(5, 7)),
                ],
                b"first",
            ),
            record(
                &[
                    ("op", &[OP_MESSAGE_DATA]),
                    ("conn", &3u32.to_le_bytes()),
                    ("time", &time(6, 0)),
                ],
                b"second",
            ),
        ]
        .concat();
        let data = match compression {
            "none" => inner.clone(),
            "bz2" => {
                let mut e =
                    bzip2::read::BzEncoder::new(inner.as_slice(), bzip2::Compression::best());
                let mut out = Vec::new();
                e.read_to_end(&mut out).unwrap();
                out
            }
            "lz4" => {
                let mut e = lz4::EncoderBuilder::new().build(Vec::new()).unwrap();
                std::io::Write::write_all(&mut e, &inner).unwrap();
                e.finish().0
            }
            _ => unreachable!(),
        };
        let chunk = record(
            &[
                ("op", &[OP_CHUNK]),
                ("compression", compression.as_bytes()),
                ("size", &(inner.len() as u32).to_le_bytes()),
            ],
            &data,
        );
        let head_len =
            MAGIC.len() + record(&[("op", &[OP_BAG_HEADER]), ("index_pos", &[0; 8])], &[]).len();
        let index_pos = (head_len + chunk.len()) as u64;
        [
            MAGIC.to_vec(),
            record(
                &[
                    ("op", &[OP_BAG_HEADER]),
                    ("index_pos", &index_pos.to_le_bytes()),
                ],
                &[],
            ),
            chunk,
            conn,
        ]
        .concat()
    }

    fn read(bytes: Vec<u8>) -> Result<Vec<(String, u64, Vec<u8>)>, BagError> {
        let bag = Ros1Bag::new(bytes, Path::new("t.bag"))?;
        let mut out = Vec::new();
        bag.messages(&mut |m| {
            out.push((m.channel.type_name.clone(), m.log_time_ns, m.data.to_vec()));
            Ok(())
        })?;
        Ok(out)
    }

    #[test]
    fn plain_bz2_and_lz4_chunks_read_alike() {
        for compression in ["none", "bz2", "lz4"] {
            let bytes = bag(compression);
            let bag = Ros1Bag::new(bytes.clone(), Path::new("t.bag")).unwrap();
            let ch = bag.channels().unwrap();
            assert_eq!(
                (ch[0].topic.as_str(), ch[0].encoding.as_str()),
                ("/imu", "ros1")
            );
            let got = read(bytes).unwrap();
            assert_eq!(got.len(), 2, "{compression}");
            assert_eq!(
                got[0],
                ("sensor_msgs/Imu".into(), 5_000_000_007, b"first".to_vec())
            );
            assert_eq!(got[1].2, b"second");
        }
    }

    #[test]
    fn a_connection_left_out_of_a_chunk_comes_from_the_index() {
        assert_eq!(read(bag_with("lz4", false)).unwrap().len(), 2);
        // Without the index either, the message is named.
        let mut no_index = bag_with("none", false);
        let at = no_index
            .windows(10)
            .position(|w| w == b"index_pos=")
            .unwrap()
            + 10;
        no_index[at..at + 8].copy_from_slice(&[0; 8]);
        let conn_len = imu_connection().len();
        no_index.truncate(no_index.len() - conn_len);
        assert!(matches!(
            read(no_index),
            Err(BagError::Container { reason, .. }) if reason.contains("connection 3, before any record of it")
        ));
    }

    #[test]
    fn a_record_or_chunk_past_its_bound_is_refused_before_it_is_read() {
        let head = [
            MAGIC.to_vec(),
            record(&[("op", &[OP_BAG_HEADER]), ("index_pos", &[0; 8])], &[]),
        ]
        .concat();
        // A record that says its data is 300 MiB: refused at its length, nothing allocated.
        let mut long = header(&[("op", &[OP_MESSAGE_DATA])]);
        long = [(long.len() as u32).to_le_bytes().to_vec(), long].concat();
        long.extend((300u32 << 20).to_le_bytes());
        let err = read([head.clone(), long].concat()).unwrap_err().to_string();
        assert!(
            err.contains(
                "a record's data reaches 314572800 bytes, past the 256 MiB budget `bag-chunk`"
            ),
            "{err}"
        );
        assert!(err.contains("--budget bag-chunk=512MiB"), "{err}");
        // A record header of 2 MiB.
        let mut wide = (2u32 << 20).to_le_bytes().to_vec();
        wide.extend([0u8; 16]);
        let err = read([head.clone(), wide].concat()).unwrap_err().to_string();
        assert!(err.contains("a record header of 2097152 bytes"), "{err}");
        // A chunk declaring 300 MiB uncompressed, holding a few bytes.
        let chunk = record(
            &[
                ("op", &[OP_CHUNK]),
                ("compression", b"lz4"),
                ("size", &(300u32 << 20).to_le_bytes()),
            ],
            b"tiny",
        );
        let err = read([head, chunk].concat()).unwrap_err().to_string();
        assert!(
            err.contains("reaches 314572800 bytes, past the 256 MiB budget `bag-chunk`"),
            "{err}"
        );
        assert!(err.contains("--budget bag-chunk=512MiB"), "{err}");
    }

    #[test]
    fn cut_or_corrupt_bags_are_errors_not_panics() {
        for compression in ["none", "bz2", "lz4"] {
            let bytes = bag(compression);
            // Cut anywhere but between two records: an error. (Cut between records, what is
            // there is whole and reads, as a recording cut off between two chunks does.)
            let mut between = vec![MAGIC.len()];
            let mut at = MAGIC.len();
            while at < bytes.len() {
                at = super::record(&bytes, at).unwrap().1;
                between.push(at);
            }
            for cut in 0..bytes.len() {
                let got = read(bytes[..cut].to_vec());
                if cut == MAGIC.len() || !between.contains(&cut) {
                    assert!(got.is_err(), "{compression} cut at {cut} read {got:?}");
                }
            }
            // Flipped bytes: whatever happens, no panic.
            for at in (MAGIC.len()..bytes.len()).step_by(3) {
                let mut bad = bytes.clone();
                bad[at] ^= 0x5A;
                let _ = read(bad);
            }
        }
        // A chunk whose header lies about its size.
        let mut bytes = bag("lz4");
        let at = bytes.windows(5).position(|w| w == b"size=").unwrap() + 5;
        bytes[at] = bytes[at].wrapping_add(1);
        assert!(matches!(read(bytes), Err(BagError::Ros1Chunk { .. })));
    }
}
