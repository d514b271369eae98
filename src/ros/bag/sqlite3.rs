//! The sqlite3 container (`.db3`, the ROS 2 default storage up to Humble): rosbag2's schema
//! versions 1 to 4 all keep `topics(id, name, type, serialization_format, …)` and
//! `messages(id, topic_id, timestamp, data)`, and that is all odocal reads.
//!
//! A plain file is opened where it lies, read-only and `immutable` (SQLite reads the pages it
//! needs, takes no lock and creates nothing beside the file: no journal, no WAL index); a
//! `.db3.zstd` or `.db3.lz4` is decompressed as a stream into a temporary file (as rosbag2's
//! own reader does: SQLite reads only files), opened there and, on Unix, unlinked at once
//! (SQLite keeps it open; elsewhere it is removed when the bag is dropped); bytes already in memory are opened there. Either way a file shorter than its header
//! says is refused first: SQLite would read the missing pages as zeros.

use super::compression::{self, Whole};
use super::{BagError, Channel, Container, RawMessage};
use rusqlite::types::ValueRef;
use rusqlite::{Connection, OpenFlags};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The first bytes of every SQLite 3 database.
pub const MAGIC: &[u8] = b"SQLite format 3\0";

/// The length of SQLite's file header.
const HEADER: usize = 100;

/// A rosbag2 sqlite3 file, read-only.
pub struct Sqlite3Bag {
    db: Connection,
    path: PathBuf,
    /// Channels by topic id, in id order.
    topics: BTreeMap<i64, Channel>,
    notes: Vec<String>,
    /// The decompressed copy the database is read from, if any: after `db`, so dropped after
    /// it is closed.
    _copy: Option<Temporary>,
}

/// A temporary file, removed when dropped.
struct Temporary(PathBuf);

impl Drop for Temporary {
    fn drop(&mut self) {
        // Nothing to tell anyone if it is gone already.
        let _ = std::fs::remove_file(&self.0);
    }
}

impl Sqlite3Bag {
    /// Opens the database in `bytes` (from `path`) and reads its topics.
    pub fn new(mut bytes: Vec<u8>, path: &Path) -> Result<Self, BagError> {
        let sql = |source| BagError::Sqlite {
            path: path.to_path_buf(),
            source,
        };
        check_length(&bytes, bytes.len() as u64, path)?;
        // Bytes 18 and 19 are the write and read versions: 2 for a database in WAL mode, which
        // SQLite will not open from memory. The file alone is the database as of its last
        // checkpoint, which legacy mode (1) reads as it is.
        for b in bytes.iter_mut().skip(18).take(2) {
            if *b == 2 {
                *b = 1;
            }
        }
        let mut db = Connection::open_in_memory_with_flags(
            OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )
        .map_err(sql)?;
        db.deserialize_read_exact(rusqlite::MAIN_DB, bytes.as_slice(), bytes.len(), true)
            .map_err(sql)?;
        drop(bytes);
        Self::with(db, path)
    }

    /// Opens the plain database file `path` where it lies (its size and kind already checked
    /// by the caller), read-only and immutable, and reads its topics.
    pub fn in_place(path: &Path) -> Result<Self, BagError> {
        Self::at(path, path)
    }

    /// The database file `path` compressed whole, decompressed as a stream into a temporary
    /// file (in the system's temporary directory, `TMPDIR`) and opened there.
    pub fn decompressed(path: &Path, whole: Whole) -> Result<Self, BagError> {
        use std::io::{Read, Write};
        let mut input = compression::stream(path, whole)?;
        let dir = std::env::temp_dir();
        // The first free name; any error but a name taken is the directory's, and final.
        let mut made = None;
        for n in 0..1000u32 {
            let p = dir.join(format!("odocal-{}-{n}.db3", std::process::id()));
            match std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(&p)
            {
                Ok(f) => {
                    made = Some((Temporary(p), f));
                    break;
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
                Err(e) => {
                    return Err(BagError::Io {
                        path: dir.clone(),
                        source: std::io::Error::new(
                            e.kind(),
                            format!(
                                "{e}: no temporary file can be made there to decompress the \
                                 bag into; set TMPDIR to a writable directory"
                            ),
                        ),
                    })
                }
            }
        }
        let (copy, mut file) = made.ok_or_else(|| BagError::Io {
            path: dir.clone(),
            source: std::io::Error::other(
                "a thousand temporary files of this process are there already; remove them",
            ),
        })?;
        let written = |source: std::io::Error| BagError::Io {
            path: copy.0.clone(),
            source: std::io::Error::new(
                source.kind(),
                format!(
                    "the decompressed copy of {}: {source} (set TMPDIR to a disk with room \
                     for it)",
                    path.display()
                ),
            ),
        };
        let mut buf = vec![0u8; 1 << 20];
        loop {
            let n = input.read(&mut buf).map_err(|e| whole.error(path, e))?;
            if n == 0 {
                break;
            }
            file.write_all(&buf[..n]).map_err(written)?;
        }
        file.flush().map_err(written)?;
        drop(file);
        let mut bag = Self::at(&copy.0, path)?;
        // SQLite holds the file open from here on: on Unix its name can go now, so that a
        // process killed while it reads leaves no copy behind (elsewhere it goes on drop).
        #[cfg(unix)]
        let _ = std::fs::remove_file(&copy.0);
        bag._copy = Some(copy);
        Ok(bag)
    }

    /// Opens the database file `file`, named `path` in errors.
    fn at(file: &Path, path: &Path) -> Result<Self, BagError> {
        let io = |source| BagError::Io {
            path: path.to_path_buf(),
            source,
        };
        let mut head = Vec::with_capacity(HEADER);
        let file_path = file;
        let file =
            crate::io::open_bounded(file_path, crate::io::budget::BAG_FILE.get()).map_err(io)?;
        let len = file.get_ref().metadata().map_err(io)?.len();
        std::io::Read::read_to_end(&mut std::io::Read::take(file, HEADER as u64), &mut head)
            .map_err(io)?;
        check_length(&head, len, path)?;
        let db = Connection::open_with_flags(
            uri(file_path),
            OpenFlags::SQLITE_OPEN_READ_ONLY
                | OpenFlags::SQLITE_OPEN_NO_MUTEX
                | OpenFlags::SQLITE_OPEN_URI,
        )
        .map_err(|source| BagError::Sqlite {
            path: path.to_path_buf(),
            source,
        })?;
        Self::with(db, path)
    }

    /// The bag of an open database: its topics read, and a note when a write-ahead log lies
    /// beside the file.
    fn with(db: Connection, path: &Path) -> Result<Self, BagError> {
        let sql = |source| BagError::Sqlite {
            path: path.to_path_buf(),
            source,
        };
        let tables: i64 = db
            .query_row(
                "SELECT count(*) FROM sqlite_master WHERE type = 'table' \
                 AND name IN ('topics', 'messages')",
                [],
                |r| r.get(0),
            )
            .map_err(sql)?;
        if tables != 2 {
            return Err(BagError::Container {
                path: path.to_path_buf(),
                format: "sqlite3",
                reason: "an SQLite database without rosbag2's `topics` and `messages` tables"
                    .into(),
            });
        }
        let mut topics = BTreeMap::new();
        {
            let mut stmt = db
                .prepare("SELECT id, name, type, serialization_format FROM topics ORDER BY id")
                .map_err(sql)?;
            let mut rows = stmt.query([]).map_err(sql)?;
            while let Some(row) = rows.next().map_err(sql)? {
                topics.insert(
                    row.get::<_, i64>(0).map_err(sql)?,
                    Channel {
                        topic: row.get(1).map_err(sql)?,
                        type_name: row.get(2).map_err(sql)?,
                        encoding: row.get(3).map_err(sql)?,
                    },
                );
            }
        }
        let mut notes = Vec::new();
        let mut wal = path.as_os_str().to_owned();
        wal.push("-wal");
        if std::fs::metadata(&wal).is_ok_and(|m| m.len() > 0) {
            notes.push(format!(
                "{} has a write-ahead log beside it: what was recorded into it after the last \
                 checkpoint is not read (opening the file once with sqlite3 folds it in)",
                path.display()
            ));
        }
        Ok(Sqlite3Bag {
            db,
            path: path.to_path_buf(),
            topics,
            notes,
            _copy: None,
        })
    }

    fn malformed(&self, reason: String) -> BagError {
        BagError::Container {
            path: self.path.clone(),
            format: "sqlite3",
            reason,
        }
    }
}

/// `path` as an SQLite URI that opens it immutable: percent-encoded but for the characters
/// a URI path keeps (SQLite decodes `%XX` in the path before opening), an absolute path after
/// an empty authority (`file:///…`).
fn uri(path: &Path) -> String {
    let mut uri = String::from(if path.has_root() { "file://" } else { "file:" });
    for &b in path.as_os_str().as_encoded_bytes() {
        if b.is_ascii_alphanumeric() || b"/._-~".contains(&b) {
            uri.push(char::from(b));
        } else {
            uri.push_str(&format!("%{b:02X}"));
        }
    }
    uri.push_str("?immutable=1");
    uri
}

/// Refuses a database whose file (of `len` bytes, starting `head`) is shorter than its header
/// says. SQLite itself reads the pages past the end of a cut file as zeros, so a recording cut
/// in the middle of a page would read as messages of zeros.
fn check_length(head: &[u8], len: u64, path: &Path) -> Result<(), BagError> {
    let be32 = |at: usize| {
        head.get(at..at + 4)
            .and_then(|b| b.try_into().ok())
            .map(u32::from_be_bytes)
    };
    let reason = match (
        head.get(16..18).map(|b| u16::from_be_bytes([b[0], b[1]])),
        be32(24),
        be32(28),
        be32(92),
    ) {
        (Some(page_size), Some(changes), Some(pages), Some(valid_for)) => {
            // A page size of 1 means 65536; the page count is valid only where the header says
            // it was written by the same change as the rest (SQLite 3.7.0 and later).
            let page_size = if page_size == 1 {
                65536
            } else {
                u64::from(page_size)
            };
            let expected = page_size * u64::from(pages);
            (changes == valid_for && pages > 0 && expected > len).then(|| {
                format!(
                    "cut short: its header says {pages} pages of {page_size} bytes ({expected} \
                     bytes), the file has {len}"
                )
            })
        }
        _ => Some(format!(
            "{len} bytes, shorter than SQLite's {HEADER}-byte header"
        )),
    };
    match reason {
        Some(reason) => Err(BagError::Container {
            path: path.to_path_buf(),
            format: "sqlite3",
            reason,
        }),
        None => Ok(()),
    }
}

/// [`Sqlite3Bag::new`] as a [`super::FileFormat`] opens it.
pub fn open(bytes: Vec<u8>, path: &Path) -> Result<Box<dyn Container>, BagError> {
    Ok(Box::new(Sqlite3Bag::new(bytes, path)?))
}

/// [`Sqlite3Bag::in_place`] as a [`super::FileFormat`] opens a plain file.
pub fn open_in_place(path: &Path) -> Result<Box<dyn Container>, BagError> {
    Ok(Box::new(Sqlite3Bag::in_place(path)?))
}

/// [`Sqlite3Bag::decompressed`] as a [`super::FileFormat`] opens a file compressed whole.
pub fn open_whole(path: &Path, whole: Whole) -> Result<Box<dyn Container>, BagError> {
    Ok(Box::new(Sqlite3Bag::decompressed(path, whole)?))
}

impl Container for Sqlite3Bag {
    fn format(&self) -> &'static str {
        "sqlite3"
    }

    fn channels(&self) -> Option<Vec<Channel>> {
        Some(self.topics.values().cloned().collect())
    }

    fn messages(
        &self,
        each: &mut dyn FnMut(RawMessage<'_>) -> Result<(), BagError>,
    ) -> Result<(), BagError> {
        let sql = |source| BagError::Sqlite {
            path: self.path.clone(),
            source,
        };
        // rosbag2's reader orders by time; the id keeps equal stamps in recording order.
        // rosbag2 indexes the timestamps, and SQLite then walks that index, holding one message
        // at a time. Without the index it would sort: then only the keys are sorted and each
        // message's data fetched by its id in that order, since sorting the data too would hold
        // the whole bag in memory (this SQLite sorts in memory).
        const IN_ORDER: &str =
            "SELECT id, topic_id, timestamp, data FROM messages ORDER BY timestamp, id";
        const KEYS_IN_ORDER: &str =
            "SELECT id, topic_id, timestamp, NULL FROM messages ORDER BY timestamp, id";
        let plan: Vec<String> = self
            .db
            .prepare(&format!("EXPLAIN QUERY PLAN {IN_ORDER}"))
            .and_then(|mut s| {
                s.query_map([], |r| r.get::<_, String>(3))?
                    .collect::<Result<_, _>>()
            })
            .map_err(sql)?;
        let sorts = plan.iter().any(|step| step.contains("TEMP B-TREE"));
        let mut stmt = self
            .db
            .prepare(if sorts { KEYS_IN_ORDER } else { IN_ORDER })
            .map_err(sql)?;
        let mut fetch = self
            .db
            .prepare("SELECT data FROM messages WHERE id = ?1")
            .map_err(sql)?;
        let mut rows = stmt.query([]).map_err(sql)?;
        while let Some(row) = rows.next().map_err(sql)? {
            let id: i64 = row.get(0).map_err(sql)?;
            let topic_id: i64 = row.get(1).map_err(sql)?;
            let stamp: i64 = row.get(2).map_err(sql)?;
            let Some(channel) = self.topics.get(&topic_id) else {
                return Err(self.malformed(format!(
                    "a message of topic id {topic_id}, which the topics table does not have"
                )));
            };
            let log_time_ns = u64::try_from(stamp).map_err(|_| {
                self.malformed(format!("a message stamped {stamp} ns, before 1970"))
            })?;
            let mut fetched;
            let data = if sorts {
                fetched = fetch.query([id]).map_err(sql)?;
                let Some(data) = fetched.next().map_err(sql)? else {
                    return Err(self.malformed(format!("message {id} went missing while read")));
                };
                data.get_ref(0).map_err(sql)?
            } else {
                row.get_ref(3).map_err(sql)?
            };
            let data = match data {
                ValueRef::Blob(b) => b,
                other => {
                    return Err(self.malformed(format!(
                        "message data of type {} where a blob belongs",
                        other.data_type()
                    )))
                }
            };
            each(RawMessage {
                channel,
                log_time_ns,
                data,
            })?;
        }
        Ok(())
    }

    fn notes(&self) -> Vec<String> {
        self.notes.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A rosbag2 schema-1 database (Foxy's: no QoS column) written here, as SQLite writes it.
    fn database(rows: &[(i64, i64, &[u8])]) -> Vec<u8> {
        database_with(rows, "")
    }

    /// [`database`] with `extra` SQL run after the tables are made (an index).
    fn database_with(rows: &[(i64, i64, &[u8])], extra: &str) -> Vec<u8> {
        let mut db = Connection::open_in_memory().unwrap();
        db.execute_batch(
            "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
                 serialization_format TEXT NOT NULL);
             CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,
                 timestamp INTEGER NOT NULL, data BLOB NOT NULL);
             INSERT INTO topics VALUES (1, '/imu', 'sensor_msgs/msg/Imu', 'cdr');",
        )
        .unwrap();
        db.execute_batch(extra).unwrap();
        for (topic, t, data) in rows {
            db.execute(
                "INSERT INTO messages(topic_id, timestamp, data) VALUES (?1, ?2, ?3)",
                rusqlite::params![topic, t, data],
            )
            .unwrap();
        }
        db.serialize(rusqlite::MAIN_DB).unwrap().to_vec()
    }

    fn read(bag: &Sqlite3Bag) -> Result<Vec<(u64, Vec<u8>)>, BagError> {
        let mut out = Vec::new();
        bag.messages(&mut |m| {
            out.push((m.log_time_ns, m.data.to_vec()));
            Ok(())
        })?;
        Ok(out)
    }

    #[test]
    fn messages_come_in_time_order_with_their_topics() {
        let bytes = database(&[(1, 30, b"c"), (1, 10, b"a"), (1, 30, b"d"), (1, 20, b"b")]);
        assert!(bytes.starts_with(MAGIC));
        let bag = Sqlite3Bag::new(bytes, Path::new("x.db3")).unwrap();
        assert_eq!(bag.channels().unwrap()[0].type_name, "sensor_msgs/msg/Imu");
        let got = read(&bag).unwrap();
        let order: Vec<&[u8]> = got.iter().map(|(_, d)| d.as_slice()).collect();
        assert_eq!(order, [b"a", b"b", b"c", b"d"]);
        assert_eq!(got[0].0, 10);
        // With rosbag2's timestamp index (walked, not sorted), the same order.
        let rows: &[(i64, i64, &[u8])] =
            &[(1, 30, b"c"), (1, 10, b"a"), (1, 30, b"d"), (1, 20, b"b")];
        let indexed = database_with(
            rows,
            "CREATE INDEX timestamp_idx ON messages (timestamp ASC);",
        );
        let bag = Sqlite3Bag::new(indexed, Path::new("x.db3")).unwrap();
        let got = read(&bag).unwrap();
        let order: Vec<&[u8]> = got.iter().map(|(_, d)| d.as_slice()).collect();
        assert_eq!(order, [b"a", b"b", b"c", b"d"]);
    }

    #[test]
    fn a_file_is_read_in_place_whatever_its_name_and_nothing_is_made_beside_it() {
        let dir = std::env::temp_dir().join(format!("odocal-sqlite3-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let bytes = database(&[(1, 5, b"x")]);
        for name in ["plain.db3", "odd ?#%&=name.db3"] {
            let path = dir.join(name);
            std::fs::write(&path, &bytes).unwrap();
            let bag = Sqlite3Bag::in_place(&path).unwrap();
            assert_eq!(read(&bag).unwrap(), [(5, b"x".to_vec())], "{name}");
            // Relative, too.
            let here = std::env::current_dir().unwrap();
            if let Ok(rel) = path.strip_prefix(&here) {
                assert_eq!(read(&Sqlite3Bag::in_place(rel).unwrap()).unwrap().len(), 1);
            }
        }
        let cut = dir.join("cut.db3");
        std::fs::write(&cut, &bytes[..bytes.len() - 1]).unwrap();
        assert!(matches!(
            Sqlite3Bag::in_place(&cut),
            Err(BagError::Container { reason, .. }) if reason.contains("cut short")
        ));
        let mut left: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        left.sort();
        assert_eq!(left, ["cut.db3", "odd ?#%&=name.db3", "plain.db3"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn bad_databases_are_typed_errors() {
        // A message of a topic the bag does not list.
        let bag = Sqlite3Bag::new(database(&[(7, 1, b"x")]), Path::new("x.db3")).unwrap();
        assert!(matches!(
            read(&bag),
            Err(BagError::Container { reason, .. }) if reason.contains("topic id 7")
        ));
        // Cut anywhere: an error (SQLite's, or ours), never a panic.
        let bytes = database(&[(1, 1, &[0u8; 3000]), (1, 2, &[1u8; 3000])]);
        for cut in (0..bytes.len()).step_by(97) {
            let result = Sqlite3Bag::new(bytes[..cut].to_vec(), Path::new("x.db3"))
                .and_then(|bag| read(&bag));
            assert!(result.is_err(), "cut at {cut} read");
        }
        // Any byte flipped: whatever SQLite makes of it, no panic.
        for at in (0..bytes.len()).step_by(13) {
            let mut bad = bytes.clone();
            bad[at] ^= 0x5A;
            let _ = Sqlite3Bag::new(bad, Path::new("x.db3")).and_then(|bag| read(&bag));
        }
        // An SQLite database of something else.
        let mut other = Connection::open_in_memory().unwrap();
        other.execute_batch("CREATE TABLE t(x)").unwrap();
        let bytes = other.serialize(rusqlite::MAIN_DB).unwrap().to_vec();
        assert!(matches!(
            Sqlite3Bag::new(bytes, Path::new("x.db3")),
            Err(BagError::Container { reason, .. }) if reason.contains("`topics`")
        ));
    }
}
