//! Bag throughput, every container side by side: `odocal bag`'s reading (container, CDR or
//! ROS 1 decoding of JointState, Imu and Odometry) and analysis of one simulated bag of about
//! a million messages, on one core, stored as:
//!
//! - MCAP with zstd chunks (odocal's writer; rosbag2's default compression), and with lz4
//!   chunks (`compression: "Lz4"` in rosbag2's storage config);
//! - a sqlite3 `.db3` (rosbag2's schema, with its timestamp index);
//! - a rosbag2 directory of two split `.db3` files and `metadata.yaml`;
//! - a ROS 1 `.bag`, chunks plain, LZ4 and bz2;
//! - compressed: a `.db3.zstd` (rosbag2's FILE mode), and a rosbag2 directory whose messages
//!   are each a zstd frame (MESSAGE mode).
//!
//! The other containers are written here from the MCAP's messages (ROS 1 messages serialised by
//! hand: the header's sequence number, then the ROS 2 fields without alignment).
//!
//! Each row says whether its reading rate is at least half of MCAP's (zstd chunks). Under the
//! bz2 row, the rate of the bzip2 library alone decompressing the same chunks, and of the
//! `bzip2` tool (C libbz2) on them when it is installed: the ceiling bz2 chunks put on any
//! reader.
//!
//! `cargo run --release --example bag_benchmark` (target: MCAP ≥ 1 million messages per second,
//! no container below half of it)

use odocal::kinematics::{SplitConvention, WheelParams};
use odocal::ros::bag::writer::{write_simulated_bag, SimulatedBag};
use odocal::ros::bag::{
    analyse, infer_geometry, open_container, read_bag, BagOptions, GeometrySource, RosTopics,
};
use odocal::ros::msg::{cdr, Header, Imu, JointState, Odometry};
use odocal::ros::yaml::RAD_PER_REV;
use odocal::sim::{NoiseModel, Simulator};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

type Error = Box<dyn std::error::Error>;

/// One message of the simulated bag: topic, type, log time (ns), CDR bytes.
struct Message {
    topic: String,
    type_name: String,
    t_ns: u64,
    cdr: Vec<u8>,
}

fn main() -> Result<(), Error> {
    let dir = std::env::temp_dir().join(format!("odocal-bag-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let result = run(&dir);
    std::fs::remove_dir_all(&dir)?;
    result
}

fn run(dir: &Path) -> Result<(), Error> {
    let mcap = dir.join("bench.mcap");
    let configured = WheelParams::nominal(0.15, 0.39, RAD_PER_REV);
    let truth = WheelParams::from_ratios(&configured, 0.976, 0.992, &SplitConvention::LeftNominal)?;
    let noise = NoiseModel {
        compass_sigma_rad: 0.2f64.to_radians(),
        ..NoiseModel::default()
    };
    let mut sim = Simulator::new(truth, configured, noise, 1)?;
    let cfg = SimulatedBag {
        side_m: 4.0,
        runs: 20,
        imu_hz: 200.0,
        joint_hz: 100.0,
        ..SimulatedBag::default()
    };
    let written = write_simulated_bag(&mcap, &mut sim, &cfg, &RosTopics::default())?;
    let mut messages = Vec::new();
    open_container(&mcap)?.messages(&mut |m| {
        messages.push(Message {
            topic: m.channel.topic.clone(),
            type_name: m.channel.type_name.clone(),
            t_ns: m.log_time_ns,
            cdr: m.data.to_vec(),
        });
        Ok(())
    })?;
    println!(
        "one simulated bag of {written} messages (JointState + Imu + Odometry) read by `odocal \
         bag` (container and messages into joints, IMU and odometry), then analysed; median of \
         3 on one core, million messages per second:\n"
    );
    println!(
        "{:<40}{:>8}{:>8}{:>9}{:>10}{:>10}{:>14}{:>12}",
        "container", "MiB", "read s", "read", "+ anal. s", "with it", "exact E_b", "≥ ½ MCAP"
    );
    let mcap_rate = measure("MCAP (zstd chunks)", &mcap, None)?;
    let measure = |name: &str, path: &Path| measure(name, path, Some(mcap_rate));
    let kept = std::env::var_os("ODOCAL_BENCH_KEEP").map(PathBuf::from);
    // With ODOCAL_BENCH_KEEP=DIR, each bag is kept there for another reader (rosbags,
    // `examples/rosbags_read.py`), a single rosbag2 file in a directory of its own with its
    // metadata.yaml, as `ros2 bag record` leaves it; otherwise removed once measured.
    let done = |path: &Path, slug: &str, storage: Option<(&str, &str)>| -> Result<(), Error> {
        let Some(keep) = &kept else {
            if path.is_dir() {
                std::fs::remove_dir_all(path)?;
            } else {
                std::fs::remove_file(path)?;
            }
            return Ok(());
        };
        let to = keep.join(slug);
        match storage {
            Some((storage, mode)) => {
                std::fs::create_dir_all(&to)?;
                let name = path.file_name().ok_or("no file name")?.to_string_lossy();
                std::fs::rename(path, to.join(&*name))?;
                // rosbag2 lists a file it compressed whole by its compressed name.
                metadata(&to, storage, &[&name], mode, &messages)?;
            }
            None => std::fs::rename(path, &to)?,
        }
        Ok(())
    };
    let lz4_mcap = dir.join("bench_lz4.mcap");
    write_mcap(&lz4_mcap, &messages, mcap::Compression::Lz4)?;
    measure("MCAP (lz4 chunks)", &lz4_mcap)?;
    done(&lz4_mcap, "mcap-lz4", Some(("mcap", "")))?;
    if kept.is_some() {
        std::fs::copy(&mcap, dir.join("bench_zstd.mcap"))?;
        done(
            &dir.join("bench_zstd.mcap"),
            "mcap-zstd",
            Some(("mcap", "")),
        )?;
    }
    let db3 = dir.join("bench.db3");
    write_db3(&db3, messages.iter(), None)?;
    measure("sqlite3 .db3", &db3)?;
    let zstd_file = dir.join("bench.db3.zstd");
    std::fs::write(
        &zstd_file,
        zstd::stream::encode_all(std::fs::File::open(&db3)?, 3)?,
    )?;
    done(&db3, "db3", Some(("sqlite3", "")))?;
    measure("sqlite3 .db3.zstd (rosbag2 FILE mode)", &zstd_file)?;
    done(&zstd_file, "db3-zstd-file", Some(("sqlite3", "file")))?;
    let split = dir.join("split");
    write_rosbag2(&split, &messages, "")?;
    measure("rosbag2 directory, 2 split .db3 files", &split)?;
    done(&split, "db3-split", None)?;
    let per_message = dir.join("per_message");
    write_rosbag2(&per_message, &messages, "message")?;
    measure("rosbag2 directory, zstd per message", &per_message)?;
    done(&per_message, "db3-zstd-message", None)?;
    for compression in ["none", "lz4", "bz2"] {
        let bag = dir.join(format!("bench_{compression}.bag"));
        let chunks = write_ros1(&bag, &messages, compression)?;
        measure(&format!("ROS 1 .bag, {compression} chunks"), &bag)?;
        done(&bag, &format!("ros1-{compression}.bag"), None)?;
        if compression == "bz2" {
            bz2_ceiling(dir, &chunks, messages.len())?;
        }
    }
    Ok(())
}

/// What bz2 chunks allow any reader: the bzip2 library (the one `odocal bag` uses) alone
/// decompressing `chunks` (compressed, uncompressed size), median of 3, and the `bzip2` tool
/// (C libbz2) on the same streams when it is installed; both as MiB/s of output and as the
/// million messages per second that caps.
fn bz2_ceiling(dir: &Path, chunks: &[(Vec<u8>, usize)], messages: usize) -> Result<(), Error> {
    use std::io::Read;
    let raw: usize = chunks.iter().map(|(_, n)| n).sum();
    let rates = |s: f64| {
        format!(
            "{:.0} MiB/s, {:.2} M msg/s",
            raw as f64 / (1 << 20) as f64 / s,
            messages as f64 / s / 1e6
        )
    };
    let mut times = Vec::new();
    let mut out = Vec::new();
    for _ in 0..3 {
        let t = Instant::now();
        for (data, size) in chunks {
            out.clear();
            out.reserve(*size);
            bzip2::read::BzDecoder::new(data.as_slice()).read_to_end(&mut out)?;
            assert_eq!(out.len(), *size);
        }
        times.push(t.elapsed().as_secs_f64());
    }
    times.sort_by(f64::total_cmp);
    println!(
        "{:<40}the bzip2 library (libbz2-rs-sys) alone decompressing its chunks: {}",
        "",
        rates(times[1])
    );
    // The same streams back to back are one multi-stream .bz2 file to the tool.
    let file = dir.join("chunks.bz2");
    std::fs::write(
        &file,
        chunks
            .iter()
            .flat_map(|(d, _)| d.iter().copied())
            .collect::<Vec<u8>>(),
    )?;
    let t = Instant::now();
    let tool = std::process::Command::new("bzip2")
        .arg("-dc")
        .arg(&file)
        .stdout(std::process::Stdio::null())
        .status();
    let took = t.elapsed().as_secs_f64();
    std::fs::remove_file(&file)?;
    match tool {
        Ok(s) if s.success() => println!(
            "{:<40}`bzip2 -dc` (C libbz2) on the same chunks: {}",
            "",
            rates(took)
        ),
        _ => println!("{:<40}(no `bzip2` tool to compare with)", ""),
    }
    Ok(())
}

/// An MCAP of the messages with chunks compressed as given.
fn write_mcap(
    path: &Path,
    messages: &[Message],
    compression: mcap::Compression,
) -> Result<(), Error> {
    let mut writer = mcap::WriteOptions::new()
        .profile("ros2")
        .compression(Some(compression))
        .create(std::io::BufWriter::new(std::fs::File::create(path)?))?;
    let mut channels: Vec<(&str, u16)> = Vec::new();
    for (sequence, m) in messages.iter().enumerate() {
        let channel_id = match channels.iter().find(|(t, _)| *t == m.topic) {
            Some((_, id)) => *id,
            None => {
                let definition = odocal::ros::msg::types::definition(&m.type_name);
                let schema = writer.add_schema(&m.type_name, "ros2msg", definition.as_bytes())?;
                let id = writer.add_channel(schema, &m.topic, "cdr", &Default::default())?;
                channels.push((&m.topic, id));
                id
            }
        };
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: sequence as u32,
            log_time: m.t_ns,
            publish_time: m.t_ns,
        };
        writer.write_to_known_channel(&header, &m.cdr)?;
    }
    writer.finish()?;
    Ok(())
}

/// Reads and analyses `path` three times; prints the median rates of reading alone and of
/// reading and analysing, and whether reading is at least half of `mcap` (M messages/s), when
/// given. Returns the reading rate.
fn measure(name: &str, path: &Path, mcap: Option<f64>) -> Result<f64, Error> {
    let bytes = size(path)?;
    let opts = BagOptions {
        side_m: Some(4.0),
        ..BagOptions::default()
    };
    let (mut reads, mut totals) = (Vec::new(), Vec::new());
    let mut messages = 0;
    let mut e_b = f64::NAN;
    for _ in 0..3 {
        // Each read is a run of its own, as each `odocal bag` is.
        odocal::io::budget::reset_run();
        let t = Instant::now();
        let data = read_bag(path, &opts)?;
        reads.push(t.elapsed().as_secs_f64());
        let g = infer_geometry(&data)?;
        let report = analyse(
            path,
            &data,
            g.params(),
            GeometrySource::Inferred(g),
            (0.075, 0.39),
            &opts,
        )?;
        totals.push(t.elapsed().as_secs_f64());
        messages = data.messages;
        assert_eq!(report.runs.len(), 40, "{name}");
        e_b = report
            .estimates
            .iter()
            .find(|e| e.estimate.method == odocal::calibration::Method::Exact)
            .map_or(f64::NAN, |e| e.estimate.e_b);
    }
    reads.sort_by(f64::total_cmp);
    totals.sort_by(f64::total_cmp);
    let (read, total) = (reads[1], totals[1]);
    let rate = messages as f64 / read / 1e6;
    let half = match mcap {
        None => "-".to_string(),
        Some(m) if rate >= 0.5 * m => "yes".to_string(),
        Some(m) => format!("no ({:.0} %)", 100.0 * rate / m),
    };
    println!(
        "{name:<40}{:>8.1}{read:>8.2}{rate:>9.2}{total:>10.2}{:>10.2}{e_b:>14.9}{half:>12}",
        bytes as f64 / (1 << 20) as f64,
        messages as f64 / total / 1e6
    );
    Ok(rate)
}

/// Bytes of a file, or of every file of a directory.
fn size(path: &Path) -> std::io::Result<u64> {
    if path.is_dir() {
        let mut total = 0;
        for e in std::fs::read_dir(path)? {
            total += size(&e?.path())?;
        }
        Ok(total)
    } else {
        Ok(std::fs::metadata(path)?.len())
    }
}

/// A rosbag2 sqlite3 database (schema as Humble writes it), each payload zstd-compressed on
/// its own when `level` is given.
fn write_db3<'a>(
    path: &Path,
    messages: impl Iterator<Item = &'a Message>,
    level: Option<i32>,
) -> Result<(), Error> {
    let mut db = rusqlite::Connection::open(path)?;
    db.execute_batch(
        "PRAGMA journal_mode = MEMORY; PRAGMA synchronous = OFF;
         CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
             serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);
         CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,
             timestamp INTEGER NOT NULL, data BLOB NOT NULL);
         CREATE INDEX timestamp_idx ON messages (timestamp ASC);",
    )?;
    let tx = db.transaction()?;
    {
        // Topic ids as SQLite's integers.
        let mut topics: Vec<String> = Vec::new();
        let mut add_topic = tx.prepare(
            "INSERT INTO topics(id, name, type, serialization_format, offered_qos_profiles) \
             VALUES (?1, ?2, ?3, 'cdr', '')",
        )?;
        let mut add =
            tx.prepare("INSERT INTO messages(topic_id, timestamp, data) VALUES (?1, ?2, ?3)")?;
        for m in messages {
            let id = match topics.iter().position(|t| *t == m.topic) {
                Some(i) => i as i64 + 1,
                None => {
                    topics.push(m.topic.clone());
                    let id = topics.len() as i64;
                    add_topic.execute(rusqlite::params![id, m.topic, m.type_name])?;
                    id
                }
            };
            let data = match level {
                Some(level) => zstd::bulk::compress(&m.cdr, level)?,
                None => m.cdr.clone(),
            };
            add.execute(rusqlite::params![id, m.t_ns as i64, data])?;
        }
    }
    tx.commit()?;
    Ok(())
}

/// A rosbag2 directory of two split sqlite3 files, compressed by message when `mode` says so.
fn write_rosbag2(dir: &Path, messages: &[Message], mode: &str) -> Result<(), Error> {
    std::fs::create_dir_all(dir)?;
    let name = dir
        .file_name()
        .map_or("bag".into(), |n| n.to_string_lossy().into_owned());
    let half = messages.len() / 2;
    let files: Vec<PathBuf> = (0..2)
        .map(|i| dir.join(format!("{name}_{i}.db3")))
        .collect();
    let level = (mode == "message").then_some(1);
    write_db3(&files[0], messages[..half].iter(), level)?;
    write_db3(&files[1], messages[half..].iter(), level)?;
    let listed: Vec<String> = files
        .iter()
        .filter_map(|f| f.file_name())
        .map(|f| f.to_string_lossy().into_owned())
        .collect();
    let listed: Vec<&str> = listed.iter().map(String::as_str).collect();
    metadata(dir, "sqlite3", &listed, mode, messages)
}

/// rosbag2's `metadata.yaml` in `dir` for `files` of `storage` (`sqlite3`, `mcap`), zstd
/// compressed by `mode` (`file`, `message`, or "" for none), holding `messages`.
fn metadata(
    dir: &Path,
    storage: &str,
    files: &[&str],
    mode: &str,
    messages: &[Message],
) -> Result<(), Error> {
    let mut topics = String::new();
    for (topic, type_name) in [
        ("/joint_states", "sensor_msgs/msg/JointState"),
        ("/imu", "sensor_msgs/msg/Imu"),
        ("/odom", "nav_msgs/msg/Odometry"),
    ] {
        let count = messages.iter().filter(|m| m.topic == topic).count();
        topics.push_str(&format!(
            "    - topic_metadata:\n        name: {topic}\n        type: {type_name}\n        \
             serialization_format: cdr\n        offered_qos_profiles: ''\n      \
             message_count: {count}\n"
        ));
    }
    let format = if mode.is_empty() { "" } else { "zstd" };
    let first = messages.first().map_or(0, |m| m.t_ns);
    let last = messages.last().map_or(0, |m| m.t_ns);
    let paths: String = files.iter().map(|f| format!("    - {f}\n")).collect();
    let mut meta = std::fs::File::create(dir.join("metadata.yaml"))?;
    write!(
        meta,
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: {storage}\n  \
         relative_file_paths:\n{paths}  \
         duration:\n    nanoseconds: {}\n  starting_time:\n    nanoseconds_since_epoch: {first}\n  \
         compression_format: '{format}'\n  compression_mode: '{}'\n  message_count: {}\n  \
         topics_with_message_count:\n{topics}",
        last - first,
        mode.to_uppercase(),
        messages.len()
    )?;
    Ok(())
}

/// Appends a ROS 1 record: its header fields, then its data.
fn record(out: &mut Vec<u8>, fields: &[(&str, &[u8])], data: &[u8]) {
    let len: usize = fields.iter().map(|(n, v)| 4 + n.len() + 1 + v.len()).sum();
    out.extend((len as u32).to_le_bytes());
    for (name, value) in fields {
        out.extend(((name.len() + 1 + value.len()) as u32).to_le_bytes());
        out.extend(name.as_bytes());
        out.push(b'=');
        out.extend(*value);
    }
    out.extend((data.len() as u32).to_le_bytes());
    out.extend(data);
}

/// A ROS 1 header block (a connection record's data).
fn header_block(fields: &[(&str, &[u8])]) -> Vec<u8> {
    let mut out = Vec::new();
    record(&mut out, fields, &[]);
    // `record` framed it as a record; a header block is only the fields.
    out[4..out.len() - 4].to_vec()
}

/// A ROS 1 bag of the messages as rosbag writes one (format 2.0): its header padded to 4 KiB
/// with the index position and the connection and chunk counts, chunks of about 768 KiB
/// (rosbag's default) compressed as asked, each followed by its index data records, then the
/// connections and a chunk info record per chunk. Returns each chunk's data as stored, with
/// its uncompressed size.
fn write_ros1(
    path: &Path,
    messages: &[Message],
    compression: &str,
) -> Result<Vec<(Vec<u8>, usize)>, Error> {
    /// A message's place in its chunk: connection, time (sec, nsec), offset.
    type Entry = (u32, [u8; 8], u32);
    /// A chunk's position, first and last time, and messages per connection.
    type ChunkInfo = (u64, [u8; 8], [u8; 8], Vec<(u32, u32)>);
    let mut out = b"#ROSBAG V2.0\n".to_vec();
    let header_at = out.len();
    let mut conns: Vec<(String, Vec<u8>)> = Vec::new();
    let mut seqs: Vec<u32> = Vec::new();
    let mut chunk = Vec::new();
    let mut entries: Vec<Entry> = Vec::new();
    let mut in_chunk: Vec<bool> = Vec::new();
    let mut stored: Vec<(Vec<u8>, usize)> = Vec::new();
    let mut infos: Vec<ChunkInfo> = Vec::new();
    // The bag header, written again at the end with the real values (same length).
    let bag_header = |index_pos: u64, conn_count: u32, chunk_count: u32| {
        let mut h = Vec::new();
        let fields: [(&str, &[u8]); 4] = [
            ("op", &[0x03]),
            ("index_pos", &index_pos.to_le_bytes()),
            ("conn_count", &conn_count.to_le_bytes()),
            ("chunk_count", &chunk_count.to_le_bytes()),
        ];
        let header_len: usize = fields.iter().map(|(n, v)| 4 + n.len() + 1 + v.len()).sum();
        record(&mut h, &fields, &vec![b' '; 4096 - 8 - header_len]);
        h
    };
    out.extend(bag_header(0, 0, 0));
    let mut flush =
        |out: &mut Vec<u8>, chunk: &mut Vec<u8>, entries: &mut Vec<Entry>| -> Result<(), Error> {
            let data = match compression {
                "lz4" => {
                    let mut e = lz4::EncoderBuilder::new().build(Vec::new())?;
                    e.write_all(chunk)?;
                    let (data, result) = e.finish();
                    result?;
                    data
                }
                "bz2" => {
                    let mut e =
                        bzip2::write::BzEncoder::new(Vec::new(), bzip2::Compression::best());
                    e.write_all(chunk)?;
                    e.finish()?
                }
                _ => chunk.clone(),
            };
            let chunk_pos = out.len() as u64;
            record(
                out,
                &[
                    ("op", &[0x05]),
                    ("compression", compression.as_bytes()),
                    ("size", &(chunk.len() as u32).to_le_bytes()),
                ],
                &data,
            );
            let mut counts: Vec<(u32, u32)> = Vec::new();
            let mut ids: Vec<u32> = entries.iter().map(|e| e.0).collect();
            ids.sort_unstable();
            ids.dedup();
            for id in ids {
                let mine: Vec<&Entry> = entries.iter().filter(|e| e.0 == id).collect();
                let mut index = Vec::new();
                for (_, time, offset) in &mine {
                    index.extend(time);
                    index.extend(offset.to_le_bytes());
                }
                record(
                    out,
                    &[
                        ("op", &[0x04]),
                        ("ver", &1u32.to_le_bytes()),
                        ("conn", &id.to_le_bytes()),
                        ("count", &(mine.len() as u32).to_le_bytes()),
                    ],
                    &index,
                );
                counts.push((id, mine.len() as u32));
            }
            let key = |t: &[u8; 8]| {
                (
                    u32::from_le_bytes([t[0], t[1], t[2], t[3]]),
                    u32::from_le_bytes([t[4], t[5], t[6], t[7]]),
                )
            };
            let start = entries
                .iter()
                .map(|e| e.1)
                .min_by_key(key)
                .unwrap_or([0; 8]);
            let end = entries
                .iter()
                .map(|e| e.1)
                .max_by_key(key)
                .unwrap_or([0; 8]);
            infos.push((chunk_pos, start, end, counts));
            stored.push((data, chunk.len()));
            chunk.clear();
            entries.clear();
            Ok(())
        };
    for m in messages {
        let id = match conns.iter().position(|(t, _)| *t == m.topic) {
            Some(i) => i,
            None => {
                let ros1_type = m.type_name.replacen("/msg/", "/", 1);
                conns.push((
                    m.topic.clone(),
                    header_block(&[
                        ("topic", m.topic.as_bytes()),
                        ("type", ros1_type.as_bytes()),
                        ("md5sum", b"*"),
                        ("message_definition", b""),
                    ]),
                ));
                seqs.push(0);
                in_chunk.push(false);
                conns.len() - 1
            }
        };
        let conn = (id as u32).to_le_bytes();
        if !in_chunk[id] {
            let (topic, data) = &conns[id];
            record(
                &mut chunk,
                &[
                    ("op", &[0x07]),
                    ("conn", &conn),
                    ("topic", topic.as_bytes()),
                ],
                data,
            );
            in_chunk[id] = true;
        }
        let mut time = [0u8; 8];
        time[..4].copy_from_slice(&((m.t_ns / 1_000_000_000) as u32).to_le_bytes());
        time[4..].copy_from_slice(&((m.t_ns % 1_000_000_000) as u32).to_le_bytes());
        let data = ros1_of(&m.type_name, &m.cdr, seqs[id])?;
        seqs[id] += 1;
        entries.push((id as u32, time, chunk.len() as u32));
        record(
            &mut chunk,
            &[("op", &[0x02]), ("conn", &conn), ("time", &time)],
            &data,
        );
        if chunk.len() > 768 << 10 {
            flush(&mut out, &mut chunk, &mut entries)?;
            in_chunk.iter_mut().for_each(|c| *c = false);
        }
    }
    if !chunk.is_empty() {
        flush(&mut out, &mut chunk, &mut entries)?;
    }
    let index_pos = out.len() as u64;
    for (id, (topic, data)) in conns.iter().enumerate() {
        let conn = (id as u32).to_le_bytes();
        record(
            &mut out,
            &[
                ("op", &[0x07]),
                ("conn", &conn),
                ("topic", topic.as_bytes()),
            ],
            data,
        );
    }
    for (chunk_pos, start, end, counts) in &infos {
        let data: Vec<u8> = counts
            .iter()
            .flat_map(|(id, n)| [id.to_le_bytes(), n.to_le_bytes()].concat())
            .collect();
        record(
            &mut out,
            &[
                ("op", &[0x06]),
                ("ver", &1u32.to_le_bytes()),
                ("chunk_pos", &chunk_pos.to_le_bytes()),
                ("start_time", start),
                ("end_time", end),
                ("count", &(counts.len() as u32).to_le_bytes()),
            ],
            &data,
        );
    }
    let header = bag_header(index_pos, conns.len() as u32, infos.len() as u32);
    out[header_at..header_at + header.len()].copy_from_slice(&header);
    std::fs::write(path, out)?;
    Ok(stored)
}

/// ROS 1 serialisation of a message odocal wrote in CDR.
fn ros1_of(type_name: &str, cdr: &[u8], seq: u32) -> Result<Vec<u8>, Error> {
    fn header(out: &mut Vec<u8>, h: &Header, seq: u32) {
        out.extend(seq.to_le_bytes());
        out.extend((h.stamp.sec as u32).to_le_bytes());
        out.extend(h.stamp.nanosec.to_le_bytes());
        string(out, &h.frame_id);
    }
    fn string(out: &mut Vec<u8>, s: &str) {
        out.extend((s.len() as u32).to_le_bytes());
        out.extend(s.as_bytes());
    }
    fn f64s(out: &mut Vec<u8>, values: &[f64]) {
        for v in values {
            out.extend(v.to_le_bytes());
        }
    }
    fn array(out: &mut Vec<u8>, values: &[f64]) {
        out.extend((values.len() as u32).to_le_bytes());
        f64s(out, values);
    }
    let mut out = Vec::new();
    match type_name {
        "sensor_msgs/msg/JointState" => {
            let js: JointState = cdr::decode(cdr)?;
            header(&mut out, &js.header, seq);
            out.extend((js.name.len() as u32).to_le_bytes());
            js.name.iter().for_each(|n| string(&mut out, n));
            array(&mut out, &js.position);
            array(&mut out, &js.velocity);
            array(&mut out, &js.effort);
        }
        "sensor_msgs/msg/Imu" => {
            let imu: Imu = cdr::decode(cdr)?;
            header(&mut out, &imu.header, seq);
            let q = imu.orientation;
            f64s(&mut out, &[q.x, q.y, q.z, q.w]);
            f64s(&mut out, &imu.orientation_covariance);
            let v = imu.angular_velocity;
            f64s(&mut out, &[v.x, v.y, v.z]);
            f64s(&mut out, &imu.angular_velocity_covariance);
            let a = imu.linear_acceleration;
            f64s(&mut out, &[a.x, a.y, a.z]);
            f64s(&mut out, &imu.linear_acceleration_covariance);
        }
        "nav_msgs/msg/Odometry" => {
            let o: Odometry = cdr::decode(cdr)?;
            header(&mut out, &o.header, seq);
            string(&mut out, &o.child_frame_id);
            let (p, q) = (o.pose.pose.position, o.pose.pose.orientation);
            f64s(&mut out, &[p.x, p.y, p.z, q.x, q.y, q.z, q.w]);
            f64s(&mut out, &o.pose.covariance.0);
            let (l, a) = (o.twist.twist.linear, o.twist.twist.angular);
            f64s(&mut out, &[l.x, l.y, l.z, a.x, a.y, a.z]);
            f64s(&mut out, &o.twist.covariance.0);
        }
        other => return Err(format!("no ROS 1 form of {other} here").into()),
    }
    Ok(out)
}
