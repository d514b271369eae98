//! The MCAP container (the ROS 2 default storage from Iron on): channels and metadata from the
//! summary section when the file has one, messages from one pass over the data. Chunks
//! compressed with zstd or lz4 (rosbag2's default is zstd) are the `mcap` crate's to undo,
//! each within [`crate::io::MAX_BAG_CHUNK`]: what a chunk declares is checked before any is
//! decompressed (the crate stops a chunk at what it declares).

use super::{BagError, Channel, Container, RawMessage};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The first bytes of every MCAP file.
pub const MAGIC: &[u8] = ::mcap::MAGIC;

/// An MCAP file in memory.
pub struct McapBag {
    bytes: Vec<u8>,
    path: PathBuf,
    summary: Option<::mcap::Summary>,
}

impl McapBag {
    /// Reads the summary of `bytes` (from `path`), if it has one.
    pub fn new(bytes: Vec<u8>, path: &Path) -> Result<Self, BagError> {
        check_chunks(&bytes, path)?;
        let summary = ::mcap::Summary::read(&bytes).map_err(|e| error(path, e))?;
        Ok(McapBag {
            bytes,
            path: path.to_path_buf(),
            summary,
        })
    }
}

/// [`McapBag::new`] as a [`super::FileFormat`] opens it.
pub fn open(bytes: Vec<u8>, path: &Path) -> Result<Box<dyn Container>, BagError> {
    Ok(Box::new(McapBag::new(bytes, path)?))
}

/// The little-endian u64 at `at`, if the bytes reach that far.
fn le_u64(bytes: &[u8], at: usize) -> Option<u64> {
    let b: [u8; 8] = bytes.get(at..at.checked_add(8)?)?.try_into().ok()?;
    Some(u64::from_le_bytes(b))
}

/// Refuses a file with a chunk that declares more than [`crate::io::MAX_BAG_CHUNK`]
/// decompressed, walking the records (opcode, u64 length) up to the footer. A record whose
/// length runs past the file ends the walk: the reader names that.
fn check_chunks(bytes: &[u8], path: &Path) -> Result<(), BagError> {
    const CHUNK: u8 = 0x06;
    const FOOTER: u8 = 0x02;
    let mut at = MAGIC.len();
    while let (Some(&op), Some(len)) = (bytes.get(at), le_u64(bytes, at + 1)) {
        let body = at + 9;
        if op == CHUNK {
            // message_start_time, message_end_time, then uncompressed_size.
            if let Some(declared) = le_u64(bytes, body + 16) {
                if declared > crate::io::MAX_BAG_CHUNK {
                    return Err(BagError::Container {
                        path: path.to_path_buf(),
                        format: "MCAP",
                        reason: format!(
                            "the chunk at byte {at} declares {declared} bytes decompressed, \
                             past the {} a chunk may have (io::SIZE_BOUNDS); rewrite it with \
                             smaller chunks (`mcap convert`, `ros2 bag convert`)",
                            crate::io::bytes(crate::io::MAX_BAG_CHUNK)
                        ),
                    });
                }
            }
        }
        if op == FOOTER {
            break;
        }
        match usize::try_from(len).ok().and_then(|l| body.checked_add(l)) {
            Some(next) if next <= bytes.len() => at = next,
            _ => break,
        }
    }
    Ok(())
}

fn error(path: &Path, source: ::mcap::McapError) -> BagError {
    BagError::Mcap {
        path: path.to_path_buf(),
        source,
    }
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
        let summary = self.summary.as_ref()?;
        summary
            .metadata_indexes
            .iter()
            .rev()
            .filter(|i| i.name == name)
            .find_map(|i| ::mcap::read::metadata(&self.bytes, i).ok())
            .map(|m| m.metadata)
    }

    fn messages(
        &self,
        each: &mut dyn FnMut(RawMessage<'_>) -> Result<(), BagError>,
    ) -> Result<(), BagError> {
        // Channels converted once each, by the reader's channel id.
        let mut known: BTreeMap<u16, Channel> = BTreeMap::new();
        for m in ::mcap::MessageStream::new(&self.bytes).map_err(|e| error(&self.path, e))? {
            let m = m.map_err(|e| error(&self.path, e))?;
            let ch = known
                .entry(m.channel.id)
                .or_insert_with(|| channel(&m.channel));
            each(RawMessage {
                channel: ch,
                log_time_ns: m.log_time,
                data: &m.data,
            })?;
        }
        Ok(())
    }
}
