//! The MCAP container (the ROS 2 default storage from Iron on): channels and metadata from the
//! summary section when the file has one, messages from one pass over the data. Chunks
//! compressed with zstd or lz4 (rosbag2's default is zstd) are the `mcap` crate's to undo.

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
