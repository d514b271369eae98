//! Hostile bags, each built here by a small generator, given to the `odocal` binary: a clear
//! error or a correct result, within a bound on the process's peak memory (its resident set
//! as the kernel reports it on exit). How long each takes is the benchmark's to measure, not
//! this test's.

mod common;

use common::scratch;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Most memory (KiB) one `odocal bag` may take on a hostile input.
const MAX_RSS_KIB: i64 = 1 << 20;

/// Runs `odocal bag <path>`: success, its error output, its peak resident memory (KiB), which
/// the binary reports itself (`ODOCAL_PEAK_MEMORY`: `wait4`'s figure for a child also counts
/// what this test process held when it started it).
fn bag(path: &Path) -> (bool, String, i64) {
    let out = Command::new(env!("CARGO_BIN_EXE_odocal"))
        .args(["bag", path.to_str().unwrap(), "--side-m", "1"])
        .env("ODOCAL_PEAK_MEMORY", "1")
        .stdout(std::process::Stdio::null())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!err.contains("panicked"), "{err}");
    let rss = err
        .lines()
        .find_map(|l| l.strip_prefix("peak resident memory: "))
        .and_then(|kib| kib.strip_suffix(" kB"))
        .and_then(|kib| kib.trim().parse().ok())
        .unwrap_or_else(|| panic!("no peak memory reported: {err}"));
    (out.status.success(), err, rss)
}

/// An MCAP string: u32 length, bytes.
fn string(s: &str) -> Vec<u8> {
    [&(s.len() as u32).to_le_bytes()[..], s.as_bytes()].concat()
}

/// An MCAP record: opcode, u64 length, body.
fn record(op: u8, body: &[u8]) -> Vec<u8> {
    [&[op][..], &(body.len() as u64).to_le_bytes(), body].concat()
}

/// An MCAP file of one zstd chunk holding `compressed`, declaring `declared` bytes.
fn mcap_with_chunk(compressed: &[u8], declared: u64) -> Vec<u8> {
    let header = record(0x01, &[string("ros2"), string("hostile")].concat());
    let chunk = record(
        0x06,
        &[
            &0u64.to_le_bytes()[..],
            &0u64.to_le_bytes(),
            &declared.to_le_bytes(),
            &0u32.to_le_bytes(),
            &string("zstd"),
            &(compressed.len() as u64).to_le_bytes(),
            compressed,
        ]
        .concat(),
    );
    let data_end = record(0x0F, &0u32.to_le_bytes());
    let footer = record(0x02, &[0u8; 20]);
    [
        mcap::MAGIC,
        &header,
        &chunk,
        &data_end,
        &footer,
        mcap::MAGIC,
    ]
    .concat()
}

/// `n` zero bytes as one zstd frame (its size recorded, or streamed without it).
fn zeros_frame(n: u64, recorded: bool) -> Vec<u8> {
    let mut out = Vec::new();
    let mut enc = zstd::stream::write::Encoder::new(&mut out, 1).unwrap();
    if recorded {
        enc.set_pledged_src_size(Some(n)).unwrap();
    }
    let block = vec![0u8; 1 << 20];
    for _ in 0..n / block.len() as u64 {
        std::io::Write::write_all(&mut enc, &block).unwrap();
    }
    enc.finish().unwrap();
    out
}

/// A simulated square test (one run each way, 1 m) written as an MCAP bag at `path`.
fn simulated_bag(path: &Path) {
    let (ok, out, err) = common::odocal(&[
        "simulate",
        "--write-bag",
        path.to_str().unwrap(),
        "--runs",
        "1",
        "--side-m",
        "1",
    ]);
    assert!(ok, "{out}{err}");
}

fn dir(name: &str) -> PathBuf {
    let d = scratch(name);
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn a_chunk_that_declares_or_holds_gigabytes_is_refused_in_bounded_memory() {
    let d = dir("hostile-chunk");
    // 300 MiB of zeros in a few KiB: declared as such, and declared as 1 KiB.
    let frame = zeros_frame(300 << 20, true);
    for (name, declared, says) in [
        (
            "declares.mcap",
            300u64 << 20,
            "past the 256 MiB budget `bag-chunk`",
        ),
        ("lies.mcap", 1 << 10, "(it declares 1024 bytes)"),
    ] {
        let path = d.join(name);
        std::fs::write(&path, mcap_with_chunk(&frame, declared)).unwrap();
        let (ok, err, rss) = bag(&path);
        assert!(!ok && err.contains(says), "{name}: {err}");
        assert!(rss < MAX_RSS_KIB, "{name}: {rss} KiB");
    }
}

#[test]
fn a_thousand_message_frames_of_256_mib_each_are_refused_at_the_first() {
    let d = dir("hostile-frames");
    let path = d.join("frames.db3");
    let db = rusqlite::Connection::open(&path).unwrap();
    db.execute_batch(
        "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
             serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);
         CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,
             timestamp INTEGER NOT NULL, data BLOB NOT NULL);
         INSERT INTO topics VALUES (1, '/joint_states', 'sensor_msgs/msg/JointState', 'cdr', '');
         INSERT INTO topics VALUES (2, '/imu', 'sensor_msgs/msg/Imu', 'cdr', '');",
    )
    .unwrap();
    for (recorded, first_id) in [(true, 0), (false, 1000)] {
        let frame = zeros_frame(256 << 20, recorded);
        for i in 0..500i64 {
            db.execute(
                "INSERT INTO messages VALUES (?1, 1, ?2, ?3)",
                rusqlite::params![first_id + i, 1_000_000_000 + i * 10_000_000, frame],
            )
            .unwrap();
        }
    }
    drop(db);
    let (ok, err, rss) = bag(&path);
    assert!(
        !ok && err.contains("past the 1 MiB budget `bag-message`")
            && err.contains("--budget bag-message=2MiB"),
        "{err}"
    );
    assert!(err.contains("message 0"), "{err}");
    assert!(rss < MAX_RSS_KIB, "{rss} KiB");
}

#[test]
fn a_metadata_yaml_of_nested_aliases_is_read_without_expanding_them() {
    let d = dir("hostile-alias");
    let bag_dir = d.join("bag");
    std::fs::create_dir_all(&bag_dir).unwrap();
    let mcap = bag_dir.join("b_0.mcap");
    simulated_bag(&mcap);
    // Twelve levels of nine aliases: 2.8e11 nodes once expanded.
    let mut bomb = String::from("a0: &a0 [x, x, x, x, x, x, x, x, x]\n");
    for i in 1..=12 {
        let p = format!("*a{}", i - 1);
        bomb.push_str(&format!("a{i}: &a{i} [{}]\n", [p.as_str(); 9].join(", ")));
    }
    let meta = |files: &str| {
        format!(
            "{bomb}rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: mcap\n  \
             relative_file_paths: {files}\n  compression_format: ''\n  compression_mode: ''\n  \
             extra: *a12\n"
        )
    };
    std::fs::write(bag_dir.join("metadata.yaml"), meta("[b_0.mcap]")).unwrap();
    let (ok, err, rss) = bag(&bag_dir);
    assert!(ok, "{err}");
    assert!(rss < MAX_RSS_KIB, "{rss} KiB");
    std::fs::write(bag_dir.join("metadata.yaml"), meta("*a12")).unwrap();
    let (ok, err, rss) = bag(&bag_dir);
    assert!(!ok && err.contains("a file path that is not text"), "{err}");
    assert!(rss < MAX_RSS_KIB, "{rss} KiB");
}

/// `blob` filled with noise that does not compress (xorshift64 from `state`).
fn fill_noise(blob: &mut [u8], state: &mut u64) {
    for chunk in blob.chunks_mut(8) {
        *state ^= *state << 13;
        *state ^= *state >> 7;
        *state ^= *state << 17;
        chunk.copy_from_slice(&state.to_le_bytes()[..chunk.len()]);
    }
}

/// `from` compressed whole into `to` with zstd, as rosbag2's FILE mode does.
fn zstd_whole(from: &Path, to: &Path) {
    zstd::stream::copy_encode(
        std::fs::File::open(from).unwrap(),
        std::fs::File::create(to).unwrap(),
        1,
    )
    .unwrap();
}

/// The simulated bag at `from` rewritten with `blobs` messages of 1 MiB of noise on a camera
/// topic among its own (what a robot's full recording holds beside the topics odocal reads).
fn padded(from: &Path, to: &Path, blobs: usize) {
    let bytes = std::fs::read(from).unwrap();
    let out = std::io::BufWriter::new(std::fs::File::create(to).unwrap());
    let mut w = mcap::WriteOptions::new()
        .profile("ros2")
        .create(out)
        .unwrap();
    let mut ids = std::collections::BTreeMap::new();
    let image_schema = w
        .add_schema("sensor_msgs/msg/Image", "ros2msg", b"")
        .unwrap();
    let camera = w
        .add_channel(
            image_schema,
            "/camera/image_raw",
            "cdr",
            &Default::default(),
        )
        .unwrap();
    let mut noise = 0x2545_F491_4F6C_DD1Du64;
    let mut blob = vec![0u8; 1 << 20];
    let messages: Vec<_> = mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| m.unwrap())
        .collect();
    let every = messages.len() / blobs.max(1);
    for (i, m) in messages.iter().enumerate() {
        let ch = *ids.entry(m.channel.id).or_insert_with(|| {
            let s = m.channel.schema.as_ref().unwrap();
            let schema = w.add_schema(&s.name, &s.encoding, &s.data).unwrap();
            w.add_channel(schema, &m.channel.topic, "cdr", &Default::default())
                .unwrap()
        });
        let header = mcap::records::MessageHeader {
            channel_id: ch,
            sequence: m.sequence,
            log_time: m.log_time,
            publish_time: m.publish_time,
        };
        w.write_to_known_channel(&header, &m.data).unwrap();
        if i % every == 0 {
            fill_noise(&mut blob, &mut noise);
            let header = mcap::records::MessageHeader {
                channel_id: camera,
                sequence: i as u32,
                log_time: m.log_time,
                publish_time: m.log_time,
            };
            w.write_to_known_channel(&header, &blob).unwrap();
        }
    }
    w.finish().unwrap();
}

#[test]
fn a_large_bag_is_read_in_memory_near_its_largest_chunk_not_its_size() {
    let d = dir("hostile-large");
    let sim = d.join("sim.mcap");
    simulated_bag(&sim);
    // 300 MiB of camera frames that do not compress, plain and compressed whole.
    let big = d.join("big.mcap");
    padded(&sim, &big, 300);
    assert!(std::fs::metadata(&big).unwrap().len() > 300 << 20);
    let zst = d.join("big.mcap.zstd");
    zstd_whole(&big, &zst);
    for path in [&big, &zst] {
        let (ok, err, rss) = bag(path);
        assert!(ok, "{}: {err}", path.display());
        assert!(rss < 100 << 10, "{}: {rss} KiB", path.display());
    }
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn an_mcap_compressed_whole_that_unpacks_to_a_gigabyte_of_zeros_is_refused_at_once() {
    let d = dir("hostile-split");
    // The MCAP magic, then 1 GiB of zeros, compressed whole as rosbag2's FILE mode does.
    let path = d.join("b_0.mcap.zstd");
    let mut out = Vec::new();
    {
        let mut enc = zstd::stream::write::Encoder::new(&mut out, 1).unwrap();
        std::io::Write::write_all(&mut enc, mcap::MAGIC).unwrap();
        let block = vec![0u8; 1 << 20];
        for _ in 0..1024 {
            std::io::Write::write_all(&mut enc, &block).unwrap();
        }
        enc.finish().unwrap();
    }
    std::fs::write(&path, &out).unwrap();
    let (ok, err, rss) = bag(&path);
    assert!(!ok && err.contains("not a readable MCAP bag"), "{err}");
    assert!(rss < 100 << 10, "{rss} KiB");
    std::fs::remove_dir_all(&d).unwrap();
}

/// A ROS 1 record: its `name=value` header fields, then its data.
fn ros1_record(fields: &[(&str, &[u8])], data: &[u8]) -> Vec<u8> {
    let mut header = Vec::new();
    for (name, value) in fields {
        header.extend(((name.len() + 1 + value.len()) as u32).to_le_bytes());
        header.extend(name.as_bytes());
        header.push(b'=');
        header.extend(*value);
    }
    [
        &(header.len() as u32).to_le_bytes()[..],
        &header,
        &(data.len() as u32).to_le_bytes(),
        data,
    ]
    .concat()
}

#[test]
fn a_large_ros1_bag_is_read_in_memory_near_its_largest_record_not_its_size() {
    let d = dir("hostile-ros1");
    let path = d.join("camera.bag");
    let mut f = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
    use std::io::Write;
    f.write_all(b"#ROSBAG V2.0\n").unwrap();
    f.write_all(&ros1_record(&[("op", &[3]), ("index_pos", &[0; 8])], &[]))
        .unwrap();
    let conn_info = ros1_record(
        &[("topic", b"/camera"), ("type", b"sensor_msgs/Image")],
        &[],
    );
    // A connection record's data is a header block: drop the framing lengths around it.
    let info = &conn_info[4..conn_info.len() - 4];
    f.write_all(&ros1_record(
        &[
            ("op", &[7]),
            ("conn", &0u32.to_le_bytes()),
            ("topic", b"/camera"),
        ],
        info,
    ))
    .unwrap();
    let frame = vec![0x5Au8; 1 << 20];
    for i in 0..300u32 {
        let time = [i.to_le_bytes(), 0u32.to_le_bytes()].concat();
        f.write_all(&ros1_record(
            &[("op", &[2]), ("conn", &0u32.to_le_bytes()), ("time", &time)],
            &frame,
        ))
        .unwrap();
    }
    f.flush().unwrap();
    drop(f);
    assert!(std::fs::metadata(&path).unwrap().len() > 300 << 20);
    let (ok, err, rss) = bag(&path);
    assert!(!ok && err.contains("no wheel joint topic"), "{err}");
    assert!(rss < 100 << 10, "{rss} KiB");
    std::fs::remove_dir_all(&d).unwrap();
}

/// The simulated MCAP bag at `from` rewritten as a rosbag2 sqlite3 file with `blobs` messages
/// of 1 MiB of noise on a camera topic among its own.
fn padded_db3(from: &Path, to: &Path, blobs: usize) {
    let bytes = std::fs::read(from).unwrap();
    let mut db = rusqlite::Connection::open(to).unwrap();
    db.execute_batch(
        "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
             serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);
         CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,
             timestamp INTEGER NOT NULL, data BLOB NOT NULL);
         INSERT INTO topics VALUES (1000, '/camera/image_raw', 'sensor_msgs/msg/Image', 'cdr', '');",
    )
    .unwrap();
    let tx = db.transaction().unwrap();
    let messages: Vec<_> = mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| m.unwrap())
        .collect();
    let every = messages.len() / blobs.max(1);
    let mut topics = std::collections::BTreeSet::new();
    let mut noise = 0x2545_F491_4F6C_DD1Du64;
    let mut blob = vec![0u8; 1 << 20];
    for (i, m) in messages.iter().enumerate() {
        if topics.insert(m.channel.id) {
            tx.execute(
                "INSERT INTO topics VALUES (?1, ?2, ?3, 'cdr', '')",
                rusqlite::params![
                    m.channel.id,
                    m.channel.topic,
                    m.channel.schema.as_ref().unwrap().name
                ],
            )
            .unwrap();
        }
        tx.execute(
            "INSERT INTO messages(topic_id, timestamp, data) VALUES (?1, ?2, ?3)",
            rusqlite::params![m.channel.id, m.log_time as i64, &m.data[..]],
        )
        .unwrap();
        if i % every == 0 {
            fill_noise(&mut blob, &mut noise);
            tx.execute(
                "INSERT INTO messages(topic_id, timestamp, data) VALUES (1000, ?1, ?2)",
                rusqlite::params![m.log_time as i64, &blob],
            )
            .unwrap();
        }
    }
    tx.commit().unwrap();
}

/// `from` compressed whole into `to` with LZ4 frames, as the `lz4` tool does.
fn lz4_whole(from: &Path, to: &Path) {
    let mut enc = lz4::EncoderBuilder::new()
        .build(std::fs::File::create(to).unwrap())
        .unwrap();
    std::io::copy(&mut std::fs::File::open(from).unwrap(), &mut enc).unwrap();
    let (_, done) = enc.finish();
    done.unwrap();
}

#[test]
fn a_large_sqlite_or_lz4_bag_compressed_whole_is_read_near_its_largest_message() {
    let d = dir("hostile-whole");
    let sim = d.join("sim.mcap");
    simulated_bag(&sim);
    let db3 = d.join("big.db3");
    padded_db3(&sim, &db3, 200);
    assert!(std::fs::metadata(&db3).unwrap().len() > 200 << 20);
    let zst = d.join("big.db3.zstd");
    zstd_whole(&db3, &zst);
    let db3_lz4 = d.join("big.db3.lz4");
    lz4_whole(&db3, &db3_lz4);
    let mcap = d.join("big.mcap");
    padded(&sim, &mcap, 200);
    let mcap_lz4 = d.join("big.mcap.lz4");
    lz4_whole(&mcap, &mcap_lz4);
    let temporaries = || {
        std::fs::read_dir(std::env::temp_dir())
            .unwrap()
            .filter(|e| {
                let name = e.as_ref().unwrap().file_name();
                let name = name.to_string_lossy();
                name.starts_with("odocal-") && name.ends_with(".db3")
            })
            .count()
    };
    let (mut plain, mut whole) = (None, None);
    for path in [&db3, &zst, &db3_lz4, &mcap_lz4] {
        let before = temporaries();
        let (ok, err, rss) = bag(path);
        assert!(ok, "{}: {err}", path.display());
        assert!(rss < 100 << 10, "{}: {rss} KiB", path.display());
        // The decompressed copy a database is read from is gone with the run.
        assert!(temporaries() <= before, "{}", path.display());
        let json = || common::odocal(&["bag", path.to_str().unwrap(), "--side-m", "1", "--json"]).1;
        if path == &db3 {
            plain = Some(json());
        } else if path == &zst {
            whole = Some(json());
        }
    }
    // What a compressed copy gives is what the file itself gives.
    let strip = |s: Option<String>| {
        let mut v: serde_json::Value = serde_json::from_str(&s.unwrap()).unwrap();
        v.as_object_mut().unwrap().remove("file");
        v
    };
    assert_eq!(strip(plain), strip(whole));
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn a_run_past_its_total_budget_is_refused_naming_the_flag_that_raises_it() {
    let d = dir("hostile-run-budget");
    let sim = d.join("sim.mcap");
    simulated_bag(&sim);
    let zst = d.join("sim.mcap.zstd");
    zstd_whole(&sim, &zst);
    let path = zst.to_str().unwrap();
    let (ok, out, err) = common::odocal(&["bag", path, "--side-m", "1"]);
    assert!(ok, "{out}{err}");
    // Messages over every bag of the run, and bytes decompressed: each budget named with the
    // flag that raises it, and raising it is enough.
    for (budget, low, raise) in [
        ("run-messages", "1000", "--budget run-messages=2000"),
        ("run-bytes", "64KiB", "--budget run-bytes=128KiB"),
    ] {
        let setting = format!("{budget}={low}");
        let (ok, _, err) = common::odocal(&["bag", path, "--side-m", "1", "--budget", &setting]);
        assert!(!ok, "{budget}");
        assert!(
            err.contains(&format!("budget `{budget}`")) && err.contains(raise),
            "{err}"
        );
        let (ok, out, err) = common::odocal(&[
            "--budget",
            &format!("{budget}=1GiB"),
            "bag",
            path,
            "--side-m",
            "1",
        ]);
        assert!(ok, "{out}{err}");
    }
    // A plain MCAP's zstd chunks count too, and a budget spent is not a broken bag.
    let (ok, _, err) = common::odocal(&[
        "bag",
        sim.to_str().unwrap(),
        "--side-m",
        "1",
        "--budget",
        "run-bytes=64KiB",
    ]);
    assert!(!ok, "{err}");
    assert!(
        err.contains("(its chunks) reaches") && err.contains("budget `run-bytes`"),
        "{err}"
    );
    assert!(!err.contains("not a readable"), "{err}");
    // The help states each budget's default as the library has it.
    let (_, help, _) = common::odocal(&["bag", "--help"]);
    let help = help.split_whitespace().collect::<Vec<_>>().join(" ");
    for b in odocal::io::budget::BUDGETS {
        let default = match b.unit {
            "bytes" => odocal::io::bytes(b.default).replace(' ', ""),
            _ => b.default.to_string(),
        };
        assert!(
            help.contains(&format!("{} (default {default}", b.name))
                || help.contains(&format!("{} ({default}", b.name)),
            "{}: {help}",
            b.name
        );
    }
    // A setting that is not one is refused before anything is read, naming the budgets.
    let (ok, _, err) = common::odocal(&["bag", path, "--budget", "bag-chunks=1MiB"]);
    assert!(
        !ok && err.contains("there is no budget `bag-chunks`"),
        "{err}"
    );
    assert!(err.contains("run-messages"), "{err}");
    let (ok, _, err) = common::odocal(&["bag", path, "--budget", "bag-chunk=4GB"]);
    assert!(!ok && err.contains("is not a size"), "{err}");
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn a_file_compressed_whole_past_its_budget_and_a_temporary_directory_that_takes_no_copy_are_named()
{
    let d = dir("hostile-whole-errors");
    let sim = d.join("sim.mcap");
    simulated_bag(&sim);
    let zst = d.join("sim.mcap.zstd");
    zstd_whole(&sim, &zst);
    // A budget the compressed file is within, what it decompresses to is not: refused while
    // it decompresses, naming the budget.
    let packed = std::fs::metadata(&zst).unwrap().len();
    let unpacked = std::fs::metadata(&sim).unwrap().len();
    let bound = packed + 1024;
    assert!(unpacked > bound, "{packed} {unpacked}");
    let setting = format!("bag-file={bound}");
    let (ok, _, err) = common::odocal(&[
        "bag",
        zst.to_str().unwrap(),
        "--side-m",
        "1",
        "--budget",
        &setting,
    ]);
    assert!(!ok, "{err}");
    assert!(
        err.contains("budget `bag-file`") && err.contains("--budget bag-file="),
        "{err}"
    );
    // A `.db3.zstd` with nowhere to decompress to: the directory and the way out are named.
    let db3 = d.join("sim.db3");
    padded_db3(&sim, &db3, 1);
    let db3_zst = d.join("sim.db3.zstd");
    zstd_whole(&db3, &db3_zst);
    let out = Command::new(env!("CARGO_BIN_EXE_odocal"))
        .args(["bag", db3_zst.to_str().unwrap(), "--side-m", "1"])
        .env("TMPDIR", d.join("no-such-directory"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("no-such-directory") && err.contains("set TMPDIR to a writable directory"),
        "{err}"
    );
    std::fs::remove_dir_all(&d).unwrap();
}
