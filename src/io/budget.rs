//! The budgets of what one run of odocal may read out of a bag: each bound a file, a chunk or
//! a message may decompress to, and the total bytes decompressed and messages read in one
//! run (over every file of every bag it reads). Each is checked where the bytes are produced,
//! before or while they are, so a file built to exhaust memory or time fails within seconds
//! with an error that names the budget and the flag that raises it ([`Exceeded`]).
//!
//! The budgets are process-wide: a command line sets them once before it reads anything
//! (`--budget NAME=SIZE`, [`set`]); a program that reads bag after bag as runs of their own
//! calls [`reset_run`] between them. The defaults are far above a recording of the topics
//! odocal reads (an hour of wheel joints, IMU and odometry is a few hundred MiB, a few million
//! messages) and low enough that the most they let through takes seconds, not minutes; the
//! bytes count every chunk decompressed, so a bag that also holds hours of camera images may
//! need `run-bytes` raised, and its error says so.

use std::sync::atomic::{AtomicU64, Ordering};

/// One budget: its name (as `--budget` takes it), what it covers, its value.
pub struct Budget {
    /// The name `--budget NAME=SIZE` takes.
    pub name: &'static str,
    /// What it bounds, for documentation and errors.
    pub what: &'static str,
    /// The unit its value counts: "bytes" or "messages".
    pub unit: &'static str,
    /// Its default.
    pub default: u64,
    value: AtomicU64,
}

impl Budget {
    const fn new(name: &'static str, what: &'static str, unit: &'static str, default: u64) -> Self {
        Self {
            name,
            what,
            unit,
            default,
            value: AtomicU64::new(default),
        }
    }

    /// Its value now (its default unless [`set`] raised or lowered it).
    pub fn get(&self) -> u64 {
        self.value.load(Ordering::Relaxed)
    }

    /// A value as this budget's unit reads: "4 GiB", "50000000 messages".
    pub fn show(&self, n: u64) -> String {
        if self.unit == "bytes" {
            super::bytes(n)
        } else {
            format!("{n} {}", self.unit)
        }
    }

    /// The error for `n` past this budget, `what` saying where.
    pub fn exceeded(&'static self, n: u64, what: impl Into<String>) -> Exceeded {
        Exceeded {
            budget: self,
            what: what.into(),
            seen: n,
            bound: self.get(),
        }
    }

    /// `Ok` when `n` is within this budget, else [`Budget::exceeded`].
    pub fn check(&'static self, n: u64, what: impl Into<String>) -> Result<(), Exceeded> {
        if n > self.get() {
            return Err(self.exceeded(n, what));
        }
        Ok(())
    }
}

/// `n` as `--budget` takes it: `512MiB` (never with a space, which a shell would split).
fn flag_size(unit: &str, n: u64) -> String {
    let shown = super::bytes(n);
    if unit != "bytes" || shown.ends_with(" bytes") {
        n.to_string()
    } else {
        shown.replace(' ', "")
    }
}

/// A budget exceeded: which, by what, and the flag that raises it.
#[derive(Clone)]
pub struct Exceeded {
    /// The budget.
    pub budget: &'static Budget,
    /// Where it was exceeded.
    pub what: String,
    /// How much was seen, in the budget's unit.
    pub seen: u64,
    /// The bound it had.
    pub bound: u64,
}

impl Exceeded {
    /// The flag that raises the budget (to twice its bound).
    pub fn raise(&self) -> String {
        format!(
            "--budget {}={}",
            self.budget.name,
            flag_size(self.budget.unit, self.bound.saturating_mul(2))
        )
    }
}

impl std::fmt::Display for Exceeded {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let seen = if self.budget.unit == "bytes" {
            format!("{} bytes", self.seen)
        } else {
            format!("{} {}", self.seen, self.budget.unit)
        };
        write!(
            f,
            "{} reaches {seen}, past the {} budget `{}` ({}); if this input is really that \
             large, raise it with `{}`",
            self.what,
            self.budget.show(self.bound),
            self.budget.name,
            self.budget.what,
            self.raise()
        )
    }
}

impl std::fmt::Debug for Exceeded {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Exceeded")
            .field("budget", &self.budget.name)
            .field("what", &self.what)
            .field("seen", &self.seen)
            .field("bound", &self.bound)
            .finish()
    }
}

impl std::error::Error for Exceeded {}

impl From<Exceeded> for std::io::Error {
    fn from(e: Exceeded) -> Self {
        // Its own kind, so a reader does not take it for a malformed input.
        std::io::Error::new(std::io::ErrorKind::QuotaExceeded, e)
    }
}

/// One bag file, and what a file compressed whole decompresses to.
pub static BAG_FILE: Budget = Budget::new(
    "bag-file",
    "one bag file (of a directory: each file), also once decompressed",
    "bytes",
    super::MAX_BAG_FILE,
);

/// What one chunk (MCAP, ROS 1) declares it decompresses to: checked before a byte of it is
/// decompressed (writers make chunks of about 1 MiB, a chunk of its own for a larger
/// message).
pub static BAG_CHUNK: Budget = Budget::new(
    "bag-chunk",
    "one MCAP or ROS 1 chunk, decompressed",
    "bytes",
    super::MAX_BAG_CHUNK,
);

/// One message rosbag2 compressed on its own, decompressed (joint states, IMU, odometry: a
/// few hundred bytes each).
pub static BAG_MESSAGE: Budget = Budget::new(
    "bag-message",
    "one compressed message on the topics odocal reads, decompressed",
    "bytes",
    super::MAX_BAG_MESSAGE,
);

/// Everything one run decompresses, over every file of every bag.
pub static RUN_BYTES: Budget = Budget::new(
    "run-bytes",
    "all bytes decompressed in one run, over every bag it reads",
    "bytes",
    8 << 30,
);

/// Every message one run reads, over every file of every bag (each topic's).
pub static RUN_MESSAGES: Budget = Budget::new(
    "run-messages",
    "all messages read in one run, over every bag it reads",
    "messages",
    50_000_000,
);

/// Every budget, in the order `--help` lists them.
pub static BUDGETS: [&Budget; 5] = [
    &BAG_FILE,
    &BAG_CHUNK,
    &BAG_MESSAGE,
    &RUN_BYTES,
    &RUN_MESSAGES,
];

static DECOMPRESSED: AtomicU64 = AtomicU64::new(0);
static MESSAGES: AtomicU64 = AtomicU64::new(0);

/// Starts a run's totals at zero.
pub fn reset_run() {
    DECOMPRESSED.store(0, Ordering::Relaxed);
    MESSAGES.store(0, Ordering::Relaxed);
}

/// Counts `n` more decompressed bytes against [`RUN_BYTES`] (`what` names the input).
pub fn charge_bytes(n: u64, what: &dyn Fn() -> String) -> Result<(), Exceeded> {
    let total = DECOMPRESSED
        .fetch_add(n, Ordering::Relaxed)
        .saturating_add(n);
    RUN_BYTES.check(total, format!("decompressing {}", what()))
}

/// Counts one more message read against [`RUN_MESSAGES`] (`what` names the input).
pub fn charge_message(what: &dyn Fn() -> String) -> Result<(), Exceeded> {
    let total = MESSAGES.fetch_add(1, Ordering::Relaxed).saturating_add(1);
    if total > RUN_MESSAGES.get() {
        return Err(RUN_MESSAGES.exceeded(total, format!("reading {}", what())));
    }
    Ok(())
}

/// Why a `--budget` setting was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SettingError {
    /// Not `NAME=SIZE`.
    #[error("`{0}` is not NAME=SIZE (for example `bag-chunk=512MiB`); the budgets: {names}", names = names())]
    Form(String),
    /// No budget of that name.
    #[error("there is no budget `{0}`; the budgets: {names}", names = names())]
    Name(String),
    /// A size that is not a positive whole number with an optional unit.
    #[error(
        "`{0}` is not a size: a positive whole number with an optional unit \
         (KiB, MiB, GiB, TiB; for messages a plain number)"
    )]
    Size(String),
}

fn names() -> String {
    BUDGETS
        .iter()
        .map(|b| b.name)
        .collect::<Vec<_>>()
        .join(", ")
}

/// A size as `--budget` takes it: `512MiB`, `4GiB`, `1000000` (bytes or messages), `2 KiB`.
pub fn parse_size(text: &str) -> Result<u64, SettingError> {
    let t = text.trim();
    let split = t.find(|c: char| !c.is_ascii_digit()).unwrap_or(t.len());
    let (digits, unit) = t.split_at(split);
    let unit: u32 = match unit.trim() {
        "" | "B" => 0,
        "KiB" => 10,
        "MiB" => 20,
        "GiB" => 30,
        "TiB" => 40,
        _ => return Err(SettingError::Size(text.into())),
    };
    digits
        .parse::<u64>()
        .ok()
        .filter(|&n| n > 0)
        .and_then(|n| n.checked_mul(1 << unit))
        .ok_or_else(|| SettingError::Size(text.into()))
}

/// Sets one budget from `NAME=SIZE` (a command line's `--budget`).
pub fn set(setting: &str) -> Result<(), SettingError> {
    let (name, size) = setting
        .split_once('=')
        .ok_or_else(|| SettingError::Form(setting.into()))?;
    let budget = BUDGETS
        .iter()
        .find(|b| b.name == name.trim())
        .ok_or_else(|| SettingError::Name(name.trim().into()))?;
    budget.value.store(parse_size(size)?, Ordering::Relaxed);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_with_binary_units_and_bad_ones_are_refused() {
        assert_eq!(parse_size("512MiB"), Ok(512 << 20));
        assert_eq!(parse_size("4 GiB"), Ok(4 << 30));
        assert_eq!(parse_size("1000"), Ok(1000));
        for bad in ["", "0", "-1", "1.5GiB", "4GB", "GiB", "99999999999TiB"] {
            assert!(parse_size(bad).is_err(), "{bad}");
        }
        assert!(matches!(set("bag-chunk"), Err(SettingError::Form(_))));
        assert!(matches!(set("bag-chunks=1MiB"), Err(SettingError::Name(_))));
        assert!(matches!(set("bag-chunk=lots"), Err(SettingError::Size(_))));
    }

    #[test]
    fn an_exceeded_budget_names_itself_and_the_flag_that_raises_it() {
        let e = BAG_CHUNK
            .exceeded(300 << 20, "a chunk at byte 4096")
            .to_string();
        assert!(e.contains("bag-chunk"), "{e}");
        assert!(e.contains("256 MiB"), "{e}");
        assert!(e.contains("--budget bag-chunk=512MiB"), "{e}");
        assert_eq!(flag_size("bytes", 3000), "3000");
        assert!(RUN_MESSAGES.check(10, "x").is_ok());
        let e = RUN_MESSAGES.exceeded(60_000_000, "reading x").to_string();
        assert!(e.contains("50000000 messages"), "{e}");
    }
}
