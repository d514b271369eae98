//! The rosbag2 directory, what `ros2 bag record` makes: `metadata.yaml` and one or more split
//! storage files, each read in turn through [`super::open_file`] (so each is any format odocal
//! reads, zstd-compressed or not, within the bound of one file).
//!
//! From `metadata.yaml` (`rosbag2_bagfile_information`, versions 1 to 9) odocal takes the
//! files in `relative_file_paths` order, the topics, and checks `storage_identifier`
//! (`sqlite3`, `mcap`) and the compression (`zstd` by `FILE` or by `MESSAGE`; rosbags writes
//! the mode in lower case). The file names are trusted as listed; before version 4 they carry
//! the bag's directory, and in `FILE` mode rosbag2 renames only `relative_file_paths` to the
//! `.zstd` names, so a listed file that is not there is looked for by its bare name and with or
//! without `.zstd`. A directory without `metadata.yaml` (lost, or a recording cut off) has its
//! `.db3` and `.mcap` files read in name order, and the notes say so.

use super::{open_file, BagError, Channel, Container, RawMessage};
use crate::ros::yaml::tree::{Kind, Tree};
use std::collections::BTreeMap;
use std::path::{Component, Path, PathBuf};

/// The extensions of the storage files of a directory without `metadata.yaml`.
const STORAGE_FILES: [&str; 4] = [".db3", ".mcap", ".db3.zstd", ".mcap.zstd"];

/// A rosbag2 directory: the first file open (its channels and metadata), the others opened
/// one at a time as the messages are read.
pub struct Rosbag2Dir {
    files: Vec<PathBuf>,
    first: Box<dyn Container>,
    channels: Option<Vec<Channel>>,
    notes: std::cell::RefCell<Vec<String>>,
}

/// What odocal takes from `metadata.yaml`.
#[derive(Debug, Clone, PartialEq)]
struct Metadata {
    files: Vec<String>,
    compression_file: bool,
    topics: Vec<Channel>,
}

impl Rosbag2Dir {
    /// Opens the bag directory `dir` and its first file.
    pub fn open(dir: &Path) -> Result<Self, BagError> {
        let meta_path = dir.join("metadata.yaml");
        let mut notes = Vec::new();
        let (files, topics) = if meta_path.is_file() {
            let text = crate::io::read_bounded(&meta_path, crate::io::MAX_TEXT_FILE).map_err(
                |source| BagError::Io {
                    path: meta_path.clone(),
                    source,
                },
            )?;
            // A tree that follows aliases where they stand: expanding them (what a loader
            // does) turns a kilobyte of nested aliases into gigabytes.
            let body = text.strip_prefix('\u{feff}').unwrap_or(&text);
            let tree = Tree::parse(body).map_err(|source| BagError::MetadataYaml {
                path: meta_path.clone(),
                source,
            })?;
            let meta = parse(&tree).map_err(|reason| BagError::Metadata {
                path: meta_path.clone(),
                reason,
            })?;
            let files = meta
                .files
                .iter()
                .map(|name| {
                    resolve(dir, name, meta.compression_file).ok_or_else(|| BagError::Metadata {
                        path: meta_path.clone(),
                        reason: format!(
                            "it lists `{name}`, which is not in the directory (with or \
                             without .zstd)"
                        ),
                    })
                })
                .collect::<Result<Vec<_>, _>>()?;
            (files, meta.topics)
        } else {
            let files = storage_files(dir)?;
            notes.push(format!(
                "{} has no metadata.yaml: read its {} in name order ({})",
                dir.display(),
                if files.len() == 1 {
                    "one bag file".to_string()
                } else {
                    format!("{} bag files", files.len())
                },
                files
                    .iter()
                    .filter_map(|f| f.file_name().map(|n| n.to_string_lossy().into_owned()))
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
            (files, Vec::new())
        };
        let Some(first) = files.first() else {
            return Err(BagError::Metadata {
                path: meta_path,
                reason: "its `relative_file_paths` lists no file".into(),
            });
        };
        let first = open_file(first)?;
        let channels = if topics.is_empty() {
            first.channels()
        } else {
            Some(topics)
        };
        Ok(Rosbag2Dir {
            files,
            first,
            channels,
            notes: std::cell::RefCell::new(notes),
        })
    }
}

/// The storage files of a directory without metadata, in name order (numbers by value, so
/// `bag_10` follows `bag_9`).
fn storage_files(dir: &Path) -> Result<Vec<PathBuf>, BagError> {
    let io = |source| BagError::Io {
        path: dir.to_path_buf(),
        source,
    };
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(io)? {
        let path = entry.map_err(io)?.path();
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().to_lowercase())
            .unwrap_or_default();
        if STORAGE_FILES.iter().any(|e| name.ends_with(e)) && path.is_file() {
            files.push(path);
        }
    }
    if files.is_empty() {
        return Err(BagError::NotABagDirectory {
            path: dir.to_path_buf(),
        });
    }
    files.sort_by_cached_key(|p| natural_key(&p.file_name().unwrap_or_default().to_string_lossy()));
    Ok(files)
}

/// A sort key comparing runs of digits by their value.
fn natural_key(name: &str) -> Vec<(String, u128)> {
    let mut key = Vec::new();
    let mut text = String::new();
    let mut digits = String::new();
    for c in name.chars() {
        if c.is_ascii_digit() {
            digits.push(c);
        } else {
            if !digits.is_empty() {
                key.push((
                    std::mem::take(&mut text),
                    digits.parse().unwrap_or(u128::MAX),
                ));
                digits.clear();
            }
            text.push(c);
        }
    }
    key.push((text, digits.parse().unwrap_or(0)));
    key
}

/// Where a file `metadata.yaml` lists is: as listed (when that stays inside the directory),
/// else by its bare name; each with and without `.zstd`.
fn resolve(dir: &Path, listed: &str, compressed: bool) -> Option<PathBuf> {
    let listed_path = Path::new(listed);
    let inside = listed_path
        .components()
        .all(|c| matches!(c, Component::Normal(_) | Component::CurDir));
    let mut names: Vec<PathBuf> = Vec::new();
    if inside {
        names.push(listed_path.to_path_buf());
    }
    if let Some(bare) = listed_path.file_name() {
        names.push(PathBuf::from(bare));
    }
    let mut candidates = Vec::new();
    for name in names {
        let text = name.to_string_lossy();
        let other = match text.strip_suffix(".zstd") {
            Some(plain) => PathBuf::from(plain),
            None => PathBuf::from(format!("{text}.zstd")),
        };
        // In FILE mode the compressed name is the likelier one.
        if compressed && !text.ends_with(".zstd") {
            candidates.extend([other, name]);
        } else {
            candidates.extend([name, other]);
        }
    }
    candidates
        .into_iter()
        .map(|c| dir.join(c))
        .find(|p| p.is_file())
}

/// What odocal takes from `metadata.yaml`'s documents, or what is wrong with them.
fn parse(tree: &Tree) -> Result<Metadata, String> {
    let info = tree
        .docs
        .first()
        .and_then(|&d| tree.get(d, "rosbag2_bagfile_information"))
        .map(|i| tree.resolve(i))
        .filter(|&i| matches!(tree.nodes[i].kind, Kind::Map { .. }))
        .ok_or("no `rosbag2_bagfile_information` section")?;
    let text_of = |key: &str| {
        tree.get(info, key)
            .and_then(|v| tree.text(v))
            .map(|s| s.trim().to_string())
    };
    let storage = text_of("storage_identifier").unwrap_or_default();
    if !matches!(storage.as_str(), "sqlite3" | "mcap") {
        return Err(format!(
            "storage `{storage}`: odocal reads rosbag2's sqlite3 and mcap storage"
        ));
    }
    let mode = text_of("compression_mode")
        .unwrap_or_default()
        .to_ascii_lowercase();
    let format = text_of("compression_format").unwrap_or_default();
    let compressed = match mode.as_str() {
        "" | "none" => None,
        "file" => Some(true),
        "message" => Some(false),
        other => {
            return Err(format!(
                "compression mode `{other}`: odocal reads FILE and MESSAGE compression"
            ))
        }
    };
    if compressed.is_some() && !format.eq_ignore_ascii_case("zstd") {
        return Err(format!(
            "compression format `{format}`: rosbag2 compresses files and messages with zstd \
             only (rosbag2_compression_zstd is the one compression plugin it ships), which is \
             what odocal reads; a bag of another format was written by a plugin odocal does not \
             know: `ros2 bag convert` with that plugin installed writes it uncompressed. (MCAP \
             storage's own lz4 chunks, `compression: Lz4` in a storage config, are read.)"
        ));
    }
    let paths = tree
        .get(info, "relative_file_paths")
        .map(|p| tree.resolve(p))
        .filter(|&p| matches!(tree.nodes[p].kind, Kind::Seq { .. }))
        .ok_or("no `relative_file_paths` list")?;
    let files: Vec<String> = tree
        .items(paths)
        .iter()
        .map(|&f| {
            tree.text(f)
                .map(String::from)
                .ok_or("a file path that is not text")
        })
        .collect::<Result<_, _>>()?;
    let topics = tree
        .get(info, "topics_with_message_count")
        .map(|ts| {
            tree.items(ts)
                .iter()
                .filter_map(|&t| {
                    let m = tree.get(t, "topic_metadata")?;
                    let field = |k: &str| tree.get(m, k).and_then(|v| tree.text(v));
                    Some(Channel {
                        topic: field("name")?.to_string(),
                        type_name: field("type")?.to_string(),
                        encoding: field("serialization_format").unwrap_or("cdr").to_string(),
                    })
                })
                .collect()
        })
        .unwrap_or_default();
    Ok(Metadata {
        files,
        compression_file: compressed == Some(true),
        topics,
    })
}

impl Container for Rosbag2Dir {
    fn format(&self) -> &'static str {
        "rosbag2"
    }

    fn channels(&self) -> Option<Vec<Channel>> {
        self.channels.clone()
    }

    fn metadata(&self, name: &str) -> Option<BTreeMap<String, String>> {
        self.first.metadata(name)
    }

    fn messages(
        &self,
        each: &mut dyn FnMut(RawMessage<'_>) -> Result<(), BagError>,
    ) -> Result<(), BagError> {
        let mut notes = self.first.notes();
        self.first.messages(each)?;
        for file in self.files.iter().skip(1) {
            let next = open_file(file)?;
            next.messages(each)?;
            notes.extend(next.notes());
        }
        self.notes.borrow_mut().extend(notes);
        Ok(())
    }

    fn notes(&self) -> Vec<String> {
        self.notes.borrow().clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const META: &str = "rosbag2_bagfile_information:
  version: 5
  storage_identifier: sqlite3
  duration:
    nanoseconds: 1
  relative_file_paths:
    - old_bag/old_bag_0.db3
    - old_bag_1.db3
  compression_format: ZSTD
  compression_mode: FILE
  topics_with_message_count:
    - topic_metadata:
        name: /imu
        type: sensor_msgs/msg/Imu
        serialization_format: cdr
        offered_qos_profiles: \"- history: 3\\n\"
      message_count: 3
";

    fn parse(text: &str) -> Result<Metadata, String> {
        super::parse(&Tree::parse(text).unwrap())
    }

    #[test]
    fn metadata_gives_files_compression_and_topics() {
        let m = parse(META).unwrap();
        assert_eq!(m.files, ["old_bag/old_bag_0.db3", "old_bag_1.db3"]);
        assert!(m.compression_file);
        assert_eq!(m.topics[0].topic, "/imu");
        assert_eq!(m.topics[0].encoding, "cdr");
        // rosbags writes the mode in lower case; no compression is empty.
        let lower = META.replace("FILE", "message");
        assert!(!parse(&lower).unwrap().compression_file);
        let none = META.replace("compression_format: ZSTD", "compression_format: ''");
        let none = none.replace("compression_mode: FILE", "compression_mode: ''");
        assert!(!parse(&none).unwrap().compression_file);
        for (from, to, says) in [
            ("sqlite3", "rosbag_v2", "storage `rosbag_v2`"),
            (
                "ZSTD",
                "lz4",
                "compression format `lz4`: rosbag2 compresses files and messages with zstd only",
            ),
            ("FILE", "BLOCK", "compression mode `block`"),
            ("relative_file_paths", "paths", "relative_file_paths"),
            (
                "rosbag2_bagfile_information",
                "x",
                "rosbag2_bagfile_information",
            ),
        ] {
            let err = parse(&META.replace(from, to)).unwrap_err();
            assert!(err.contains(says), "{from} → {to}: {err}");
        }
        assert!(parse("[]")
            .unwrap_err()
            .contains("rosbag2_bagfile_information"));
    }

    /// Twelve levels of nine aliases each: 9^12 (2.8e11) nodes when expanded.
    fn alias_bomb(key: &str) -> String {
        let mut s = String::from("a0: &a0 [x, x, x, x, x, x, x, x, x]\n");
        for i in 1..=12 {
            let p = format!("*a{}", i - 1);
            s.push_str(&format!("a{i}: &a{i} [{}]\n", [p.as_str(); 9].join(", ")));
        }
        s + &format!("{key}: *a12\n")
    }

    #[test]
    fn aliases_are_followed_not_expanded() {
        // Beside the section (rosbag2 would ignore it): the bag reads.
        let beside = format!("{}{META}", alias_bomb("bomb"));
        assert_eq!(parse(&beside).unwrap().files.len(), 2);
        // As the file list or the topics: refused or empty, never expanded.
        let info = META.replace(
            "  relative_file_paths:\n    - old_bag/old_bag_0.db3\n    - old_bag_1.db3\n",
            "  relative_file_paths: *a12\n",
        );
        let files = format!("{}{info}", alias_bomb("bomb"));
        assert!(parse(&files).unwrap_err().contains("not text"));
        let topics = format!("{}{}", alias_bomb("bomb"), META).replace(
            "  topics_with_message_count:\n",
            "  topics_with_message_count: *a12\n  unused:\n",
        );
        assert!(parse(&topics).unwrap().topics.is_empty());
        // Nesting past the bound is an error naming it (the scanner's own limit, 255 flow
        // levels, comes later), not a stack overflow.
        let deep = format!("{}{}", "[".repeat(100), "]".repeat(100));
        let err = Tree::parse(&deep).unwrap_err().to_string();
        assert!(err.contains("nested deeper than 64 levels"), "{err}");
        let deeper = format!("{}{}", "[".repeat(100_000), "]".repeat(100_000));
        let err = Tree::parse(&deeper).unwrap_err().to_string();
        assert!(err.contains("recursion limit"), "{err}");
    }

    #[test]
    fn listed_files_are_found_inside_the_directory_only() {
        let dir = std::env::temp_dir().join(format!("odocal-rosbag2-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        for f in [
            "old_bag_0.db3",
            "b_1.mcap.zstd",
            "b_10.mcap",
            "b_9.mcap",
            "notes.txt",
        ] {
            std::fs::write(dir.join(f), b"x").unwrap();
        }
        // Before version 4 the names carry the bag's directory.
        assert_eq!(
            resolve(&dir, "old_bag/old_bag_0.db3", false),
            Some(dir.join("old_bag_0.db3"))
        );
        // FILE mode: `files[].path` may keep the plain name of a `.zstd` file.
        assert_eq!(
            resolve(&dir, "b_1.mcap", true),
            Some(dir.join("b_1.mcap.zstd"))
        );
        assert_eq!(
            resolve(&dir, "../old_bag_0.db3", false),
            Some(dir.join("old_bag_0.db3"))
        );
        assert_eq!(resolve(&dir, "missing.db3", false), None);
        let names: Vec<String> = storage_files(&dir)
            .unwrap()
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert_eq!(
            names,
            ["b_1.mcap.zstd", "b_9.mcap", "b_10.mcap", "old_bag_0.db3"]
        );
        std::fs::remove_dir_all(&dir).unwrap();
        std::fs::create_dir_all(&dir).unwrap();
        assert!(matches!(
            Rosbag2Dir::open(&dir),
            Err(BagError::NotABagDirectory { .. })
        ));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
