//! Hostile bags, each built here from a small generator, read as `odocal bag` reads them (the
//! container, the messages, the validation, the analysis when it gets that far), each in a
//! process of its own: its wall time and its peak resident memory (`VmHWM`), against issue
//! 29's bounds of 10 s and 1 GB each.
//!
//! - an alias bomb: a rosbag2 `metadata.yaml` of twelve levels of nine aliases each;
//! - chunk bombs: an MCAP chunk declaring 40 GiB decompressed, and one declaring 1 KiB that
//!   holds 300 MiB;
//! - split bombs: an `.mcap.zstd` of 150 KB that decompresses to 3.9 GiB of records odocal
//!   skips (within the 4 GiB a file may have), alone and three times in one rosbag2 directory,
//!   and three of noise that compresses 16:1 (which decompresses at a copy's speed);
//! - a many-frame bomb: a sqlite3 bag whose 20 000 joint-state messages are each a zstd frame
//!   of 1 MiB (within the bound of one message, 20 GiB in all);
//! - bags whose time runs backwards (MCAP, sqlite3; `tests/ros_bag.rs` has every container),
//!   and bags with one joint-state sample of 1e308 rad or one spike of 3 rad in a leg.
//!
//! `cargo run --release --example hostile_benchmark` (each row: a clear error or a result, in
//! under 10 s and 1 GB).

use odocal::kinematics::WheelParams;
use odocal::ros::bag::writer::{write_simulated_bag, BagWriter, SimulatedBag};
use odocal::ros::bag::{analyse, infer_geometry, read_bag, BagOptions, GeometrySource, RosTopics};
use odocal::ros::yaml::RAD_PER_REV;
use odocal::sim::{NoiseModel, Simulator};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

type Error = Box<dyn std::error::Error>;

fn main() -> Result<(), Error> {
    let args: Vec<String> = std::env::args().collect();
    if let [_, flag, path] = args.as_slice() {
        if flag == "--one" {
            return one(Path::new(path));
        }
    }
    let dir = std::env::temp_dir().join(format!("odocal-hostile-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let result = run(&dir);
    std::fs::remove_dir_all(&dir)?;
    result
}

/// Reads and analyses one bag as `odocal bag --side-m 1` does; prints the outcome's first line
/// and the peak memory.
fn one(path: &Path) -> Result<(), Error> {
    let opts = BagOptions {
        side_m: Some(1.0),
        ..BagOptions::default()
    };
    let outcome = read_bag(path, &opts)
        .map_err(|e| e.to_string())
        .and_then(|data| {
            let g = infer_geometry(&data).map_err(|e| e.to_string())?;
            let report = analyse(
                path,
                &data,
                g.params(),
                GeometrySource::Inferred(g),
                (0.075, 0.39),
                &opts,
            )
            .map_err(|e| e.to_string())?;
            Ok(format!(
                "a result: {} runs, {} notes",
                report.runs.len(),
                report.notes.len()
            ))
        });
    let status = std::fs::read_to_string("/proc/self/status")?;
    let kib: u64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().strip_suffix("kB"))
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or(0);
    let said = match outcome {
        Ok(r) => r,
        Err(e) => format!("refused: {e}"),
    };
    println!("{kib}\t{}", said.chars().take(110).collect::<String>());
    Ok(())
}

fn run(dir: &Path) -> Result<(), Error> {
    let exe = std::env::current_exe()?;
    println!(
        "{:<44} {:>7} {:>9}  {:<5} outcome",
        "hostile input", "wall s", "peak MiB", "ok"
    );
    let inputs: Vec<(&str, PathBuf)> = vec![
        ("alias bomb (metadata.yaml)", alias_bomb(dir)?),
        (
            "chunk declaring 40 GiB",
            mcap_chunk(dir, "declares", 40 << 30)?,
        ),
        (
            "chunk declaring 1 KiB, holding 300 MiB",
            mcap_chunk(dir, "lies", 1 << 10)?,
        ),
        ("split bomb: .mcap.zstd of 3.9 GiB", split_bomb(dir)?),
        ("three split bombs in one directory", three_splits(dir)?),
        (
            "three splits of 3.9 GiB of 16:1 noise",
            three_noisy_splits(dir)?,
        ),
        ("many-frame bomb: 20 000 frames of 1 MiB", many_frames(dir)?),
        ("time backwards, MCAP", reversed_mcap(dir)?),
        ("time backwards, sqlite3", reversed_db3(dir)?),
        ("one joint sample of 1e308 rad", wild(dir, 1e308)?),
        ("one spike of 3 rad in a leg", wild(dir, 3.0)?),
    ];
    let mut worst = (0.0f64, 0u64);
    for (name, path) in inputs {
        let t = Instant::now();
        let out = Command::new(&exe)
            .args(["--one", path.to_str().ok_or("a path that is not text")?])
            .output()?;
        let wall = t.elapsed().as_secs_f64();
        let text = String::from_utf8_lossy(&out.stdout);
        let (kib, said) = text
            .trim()
            .split_once('\t')
            .map(|(k, s)| (k.parse::<u64>().unwrap_or(0), s.to_string()))
            .unwrap_or((0, String::from_utf8_lossy(&out.stderr).into_owned()));
        let ok = wall < 10.0 && kib < 1 << 20 && out.status.success();
        worst = (worst.0.max(wall), worst.1.max(kib));
        println!(
            "{name:<44} {wall:>7.2} {:>9.1}  {:<5} {said}",
            kib as f64 / 1024.0,
            if ok { "yes" } else { "NO" }
        );
    }
    println!(
        "worst: {:.2} s, {:.1} MiB (bounds: 10 s, 1 GB)",
        worst.0,
        worst.1 as f64 / 1024.0
    );
    Ok(())
}

/// A simulated square test (one run each way, 1 m side) as an MCAP bag, read back.
fn simulated(dir: &Path) -> Result<odocal::ros::bag::BagData, Error> {
    let path = dir.join("simulated.mcap");
    if !path.exists() {
        let configured = WheelParams::nominal(0.15, 0.39, RAD_PER_REV);
        let truth = WheelParams::from_ratios(
            &configured,
            0.976,
            0.992,
            &odocal::kinematics::SplitConvention::LeftNominal,
        )?;
        let mut sim = Simulator::new(truth, configured, NoiseModel::default(), 7)?;
        let cfg = SimulatedBag {
            side_m: 1.0,
            runs: 1,
            ..SimulatedBag::default()
        };
        write_simulated_bag(&path, &mut sim, &cfg, &RosTopics::default())?;
    }
    Ok(read_bag(&path, &BagOptions::default())?)
}

/// `data`'s joints and IMU written again as MCAP to `path`, in reverse order when `reverse`,
/// the joint sample `edit` names changed by it.
fn rewritten(
    data: &odocal::ros::bag::BagData,
    path: &Path,
    reverse: bool,
    edit: Option<(usize, f64)>,
) -> Result<PathBuf, Error> {
    let mut w = BagWriter::create(path, &RosTopics::default())?;
    // Each joint sample with the odometry and IMU samples of its step (the IMU runs at a
    // multiple of the joints' rate).
    let per = (data.imu.len() / data.joints.len().max(1)).max(1);
    let mut steps: Vec<usize> = (0..data.joints.len()).collect();
    if reverse {
        steps.reverse();
    }
    for i in steps {
        let j = &data.joints[i];
        let bump = match edit {
            Some((at, by)) if at == i => by,
            _ => 0.0,
        };
        w.joints(1.0 + j.t, j.left_rad + bump, j.right_rad)?;
        if let Some(o) = data.odom.get(i) {
            w.odom(1.0 + o.t, o.x_m, o.y_m, o.yaw_rad)?;
        }
        let mut imu: Vec<_> = data.imu.iter().skip(i * per).take(per).collect();
        if reverse {
            imu.reverse();
        }
        for y in imu {
            w.imu(1.0 + y.t, y.yaw_rad.unwrap_or(0.0))?;
        }
    }
    w.finish()?;
    Ok(path.to_path_buf())
}

fn alias_bomb(dir: &Path) -> Result<PathBuf, Error> {
    let d = dir.join("alias");
    std::fs::create_dir_all(&d)?;
    let mut yaml = String::from("a0: &a0 [lol]\n");
    for level in 1..12 {
        let refs = vec![format!("*a{}", level - 1); 9].join(", ");
        yaml.push_str(&format!("a{level}: &a{level} [{refs}]\n"));
    }
    yaml.push_str("rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: mcap\n");
    yaml.push_str("  relative_file_paths: *a11\n");
    std::fs::write(d.join("metadata.yaml"), yaml)?;
    Ok(d)
}

/// An MCAP record: opcode, u64 length, body.
fn record(op: u8, body: &[u8]) -> Vec<u8> {
    [
        vec![op],
        (body.len() as u64).to_le_bytes().to_vec(),
        body.to_vec(),
    ]
    .concat()
}

/// An MCAP string or byte array: u32 length, bytes.
fn string(s: &[u8]) -> Vec<u8> {
    [(s.len() as u32).to_le_bytes().to_vec(), s.to_vec()].concat()
}

/// The MCAP magic and a header record.
fn mcap_start() -> Vec<u8> {
    [
        mcap::MAGIC.to_vec(),
        record(0x01, &[string(b"ros2"), string(b"hostile")].concat()),
    ]
    .concat()
}

/// A data end, an empty footer and the closing magic.
fn mcap_end() -> Vec<u8> {
    [
        record(0x0F, &0u32.to_le_bytes()),
        record(0x02, &[0u8; 20]),
        mcap::MAGIC.to_vec(),
    ]
    .concat()
}

/// One zstd chunk holding 300 MiB of zeros, declaring `declared` bytes decompressed.
fn mcap_chunk(dir: &Path, name: &str, declared: u64) -> Result<PathBuf, Error> {
    let frame = zstd::bulk::compress(&vec![0u8; 300 << 20], 1)?;
    let body = [
        0u64.to_le_bytes().to_vec(),
        0u64.to_le_bytes().to_vec(),
        declared.to_le_bytes().to_vec(),
        0u32.to_le_bytes().to_vec(),
        string(b"zstd"),
        (frame.len() as u64).to_le_bytes().to_vec(),
        frame,
    ]
    .concat();
    let path = dir.join(format!("{name}.mcap"));
    std::fs::write(
        &path,
        [mcap_start(), record(0x06, &body), mcap_end()].concat(),
    )?;
    Ok(path)
}

/// An MCAP start, then 3.9 GiB of 1 MiB records of an opcode MCAP leaves to users (which
/// readers skip), all zeros, compressed whole with zstd.
fn split_bomb(dir: &Path) -> Result<PathBuf, Error> {
    split_of(&dir.join("b_0.mcap.zstd"), &vec![0u8; (1 << 20) - 9], 3)
}

/// [`split_bomb`] with records of noise that repeats every 64 KiB (it compresses 16:1 and
/// decompresses at the speed of a copy, not of a memset).
fn noisy_split(dir: &Path) -> Result<PathBuf, Error> {
    std::fs::create_dir_all(dir.join("noisy"))?;
    let mut noise = 0x2545_F491_4F6C_DD1Du64;
    let mut block = vec![0u8; 1 << 16];
    for chunk in block.chunks_mut(8) {
        noise ^= noise << 13;
        noise ^= noise >> 7;
        noise ^= noise << 17;
        chunk.copy_from_slice(&noise.to_le_bytes());
    }
    let body: Vec<u8> = block.iter().copied().cycle().take((1 << 20) - 9).collect();
    split_of(&dir.join("noisy").join("b_0.mcap.zstd"), &body, 1)
}

/// An `.mcap.zstd` at `path`: 3900 records of `body` (opcode 0x80) between an MCAP start and
/// end, compressed whole at zstd `level`.
fn split_of(path: &Path, body: &[u8], level: i32) -> Result<PathBuf, Error> {
    let mut enc = zstd::stream::write::Encoder::new(std::fs::File::create(path)?, level)?;
    enc.write_all(&mcap_start())?;
    let skipped = record(0x80, body);
    for _ in 0..3900 {
        enc.write_all(&skipped)?;
    }
    enc.write_all(&mcap_end())?;
    enc.finish()?;
    Ok(path.to_path_buf())
}

fn three_splits(dir: &Path) -> Result<PathBuf, Error> {
    splits_of(dir, "splits", &dir.join("b_0.mcap.zstd"))
}

fn three_noisy_splits(dir: &Path) -> Result<PathBuf, Error> {
    splits_of(dir, "noisy-splits", &noisy_split(dir)?)
}

/// A rosbag2 directory of three copies of the split `one`.
fn splits_of(dir: &Path, name: &str, one: &Path) -> Result<PathBuf, Error> {
    let d = dir.join(name);
    std::fs::create_dir_all(&d)?;
    for i in 0..3 {
        std::fs::copy(one, d.join(format!("b_{i}.mcap.zstd")))?;
    }
    std::fs::write(
        d.join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: mcap\n  \
         relative_file_paths: [b_0.mcap, b_1.mcap, b_2.mcap]\n  compression_format: zstd\n  \
         compression_mode: FILE\n  topics_with_message_count: []\n",
    )?;
    Ok(d)
}

/// A new sqlite3 file at `path` with rosbag2's two tables.
fn rosbag2_db3(path: &Path) -> Result<rusqlite::Connection, Error> {
    let db = rusqlite::Connection::open(path)?;
    db.execute_batch(
        "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
             serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);
         CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,
             timestamp INTEGER NOT NULL, data BLOB NOT NULL);",
    )?;
    Ok(db)
}

fn many_frames(dir: &Path) -> Result<PathBuf, Error> {
    let path = dir.join("frames.db3");
    let mut db = rosbag2_db3(&path)?;
    db.execute_batch(
        "CREATE INDEX timestamp_idx ON messages (timestamp ASC);
         INSERT INTO topics VALUES (1, '/joint_states', 'sensor_msgs/msg/JointState', 'cdr', '');",
    )?;
    // A CDR JointState of zeros (no joints) padded to 1 MiB, compressed.
    let mut cdr = vec![0u8; 1 << 20];
    cdr[..4].copy_from_slice(&[0, 1, 0, 0]);
    let frame = zstd::bulk::compress(&cdr, 1)?;
    let tx = db.transaction()?;
    for i in 0..20_000i64 {
        tx.execute(
            "INSERT INTO messages VALUES (?1, 1, ?2, ?3)",
            rusqlite::params![i, 1_000_000_000 + i * 10_000_000, frame],
        )?;
    }
    tx.commit()?;
    Ok(path)
}

/// The simulated bag written last message first, as MCAP.
fn reversed_mcap(dir: &Path) -> Result<PathBuf, Error> {
    let data = simulated(dir)?;
    rewritten(&data, &dir.join("reversed.mcap"), true, None)
}

/// The simulated bag as sqlite3, every message stamped in the reverse of its order.
fn reversed_db3(dir: &Path) -> Result<PathBuf, Error> {
    let data = simulated(dir)?;
    let forward = rewritten(&data, &dir.join("forward.mcap"), false, None)?;
    let bytes = std::fs::read(&forward)?;
    let path = dir.join("reversed.db3");
    let mut db = rosbag2_db3(&path)?;
    let tx = db.transaction()?;
    let mut topics = std::collections::BTreeSet::new();
    let end = 200_000_000_000i64;
    for m in mcap::MessageStream::new(&bytes)? {
        let m = m?;
        if topics.insert(m.channel.id) {
            let ty = m.channel.schema.as_ref().map(|s| s.name.clone());
            tx.execute(
                "INSERT INTO topics VALUES (?1, ?2, ?3, 'cdr', '')",
                rusqlite::params![m.channel.id, m.channel.topic, ty.unwrap_or_default()],
            )?;
        }
        // Stored in order of arrival, stamped backwards: the reader's ORDER BY time turns
        // the recording round.
        tx.execute(
            "INSERT INTO messages(topic_id, timestamp, data) VALUES (?1, ?2, ?3)",
            rusqlite::params![m.channel.id, end - m.log_time as i64, &m.data[..]],
        )?;
    }
    tx.commit()?;
    Ok(path)
}

/// The simulated bag with one left-wheel angle a third of the way through moved by `by`
/// (1e308: a wild sample; a few radians: a spike in a leg).
fn wild(dir: &Path, by: f64) -> Result<PathBuf, Error> {
    let data = simulated(dir)?;
    let at = data.joints.len() / 3;
    rewritten(
        &data,
        &dir.join(format!("wild-{by:e}.mcap")),
        false,
        Some((at, by)),
    )
}
