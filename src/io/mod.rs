//! Input and output every layer above shares: bounded reads, atomic writes, files created new,
//! backups ([`files`]), the size bounds of every kind of file odocal reads ([`SIZE_BOUNDS`]),
//! opening serial ports ([`serial`]), the byte stream under every protocol client and its
//! deadlines ([`transport`]) and the signals that end a session ([`signals`]).

pub mod budget;
pub mod files;
pub mod serial;
pub mod signals;
pub mod transport;

pub use files::*;

/// Most bytes odocal reads of a configuration, routine, profile, controller YAML, backup or
/// result file.
pub const MAX_TEXT_FILE: u64 = 16 << 20;

/// Most bytes odocal reads of one recorded run or telemetry log (hours of 200 Hz samples).
pub const MAX_DATA_FILE: u64 = 1 << 30;

/// Most bytes of one bag file, and of what a file compressed whole decompresses to, by
/// default ([`budget::BAG_FILE`], which `--budget bag-file=SIZE` raises). Every file is read
/// where it lies or, compressed whole, decompressed as it is read; a `.db3.zstd` into a
/// temporary file, as SQLite reads only files.
pub const MAX_BAG_FILE: u64 = 4 << 30;

/// Most bytes one MCAP or ROS 1 chunk may declare it decompresses to, by default
/// ([`budget::BAG_CHUNK`]).
pub const MAX_BAG_CHUNK: u64 = 256 << 20;

/// Most bytes one message rosbag2 compressed on its own may decompress to, by default
/// ([`budget::BAG_MESSAGE`]).
pub const MAX_BAG_MESSAGE: u64 = 1 << 20;

/// Every size bound, for documentation: what it covers and the bound (bytes; for the bag
/// budgets their defaults, see [`budget`] for the run totals). The README's table is checked
/// against it.
pub const SIZE_BOUNDS: [(&str, u64); 5] = [
    (
        "text: routine files, robot profiles, controller YAML, backups, results to export",
        MAX_TEXT_FILE,
    ),
    (
        "data: telemetry and recording logs, recorded runs",
        MAX_DATA_FILE,
    ),
    (
        "bag: one bag file (of a directory: each file), also once decompressed",
        MAX_BAG_FILE,
    ),
    ("bag: one MCAP or ROS 1 chunk, decompressed", MAX_BAG_CHUNK),
    (
        "bag: one compressed message on the topics odocal reads, decompressed",
        MAX_BAG_MESSAGE,
    ),
];

/// A size bound as a person reads it: "4 GiB", "256 MiB", "64 KiB", else bytes.
pub fn bytes(n: u64) -> String {
    if n >= 1 << 30 && n.is_multiple_of(1 << 30) {
        format!("{} GiB", n >> 30)
    } else if n >= 1 << 20 && n.is_multiple_of(1 << 20) {
        format!("{} MiB", n >> 20)
    } else if n >= 1 << 10 && n.is_multiple_of(1 << 10) {
        format!("{} KiB", n >> 10)
    } else {
        format!("{n} bytes")
    }
}

/// A duration as a person reads it in a message: "250 ms", "1.5 s" (never Rust's `Debug`
/// form).
pub fn seconds(d: &std::time::Duration) -> String {
    let s = d.as_secs_f64();
    if s < 0.001 {
        format!("{} µs", d.as_micros())
    } else if s < 1.0 {
        format!("{} ms", d.as_millis())
    } else {
        format!("{s:.1} s")
    }
}

/// This process's peak resident memory as Linux counts it for this program alone (`VmHWM` of
/// `/proc/self/status`: unlike a parent's `wait4`, which also counts what the parent held when
/// it started the child), e.g. `"41236 kB"`; `None` where there is no such line. For the memory
/// figures of the benchmarks and the hostile-input tests.
pub fn peak_resident_memory() -> Option<String> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let kib = status.lines().find_map(|l| l.strip_prefix("VmHWM:"))?;
    Some(kib.trim().to_string())
}

#[cfg(test)]
mod tests {
    use super::seconds;
    use std::time::Duration;

    #[test]
    fn durations_read_in_the_unit_a_person_uses() {
        assert_eq!(seconds(&Duration::from_micros(250)), "250 µs");
        assert_eq!(seconds(&Duration::from_millis(250)), "250 ms");
        assert_eq!(seconds(&Duration::from_millis(1500)), "1.5 s");
        assert_eq!(seconds(&Duration::from_secs(30)), "30.0 s");
    }
}
