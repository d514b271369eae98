//! Transactions with a RoboClaw over any byte stream: one at a time, reads retried (they are
//! safe to repeat), writes acknowledged and never blindly resent.
//!
//! Timing is a link budget, not an attempt count. Each attempt waits for its answer the
//! transmission time at the baud rate plus the adapter's latency as measured at connection
//! ([`RoboClaw::measure_latency`]: a USB serial adapter adds 1–16 ms) with room for a host
//! that is late by a scheduling slice. An attempt that gets no answer is retried until the
//! budget is spent: the controller's serial timeout once it is set (a silence the controller
//! itself tolerates, keeping its buffered motion, before it stops its motors), or
//! [`DEFAULT_BUDGET`] before. A host stalled for less than that costs nothing; only a link
//! silent past it aborts, and then the controller has stopped by itself.

use super::packet::{self, cmd, ADDRESSES};
use super::wire::{Job, Timing, Wire, DEVICE_TIME};
use crate::io::transport::Transport;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::{mpsc, oneshot};

/// Errors talking to a RoboClaw.
#[derive(Debug, Clone, thiserror::Error)]
pub enum RoboClawError {
    /// Reading or writing the port failed.
    #[error("RoboClaw I/O error: {0}")]
    Io(#[source] Arc<std::io::Error>),
    /// The port could not be opened.
    #[error("cannot open {path}: {source}")]
    Open {
        /// The port.
        path: String,
        /// Why.
        #[source]
        source: Arc<std::io::Error>,
    },
    /// No (complete) answer in time.
    #[error("no answer to command {command} within {} after {attempts} attempt(s)", crate::io::seconds(.after))]
    Timeout {
        /// The command.
        command: u8,
        /// The deadline per attempt.
        after: Duration,
        /// Attempts made.
        attempts: u32,
    },
    /// Answers failed their CRC on every attempt.
    #[error("answers to command {command} failed their CRC {attempts} time(s): wrong baud or a noisy line?")]
    Crc {
        /// The command.
        command: u8,
        /// Attempts made.
        attempts: u32,
    },
    /// A write was answered with something other than the acknowledgement.
    #[error("command {command} was answered with 0x{got:02X}, not the acknowledgement 0xFF")]
    Nak {
        /// The command.
        command: u8,
        /// The byte received.
        got: u8,
    },
    /// A value cannot be sent.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// Whatever answers on the port is not a RoboClaw.
    #[error(
        "{port}: not a RoboClaw at address 0x{address:02X} (wrong baud or address?): {reason}"
    )]
    NotARoboClaw {
        /// The port.
        port: String,
        /// The address tried.
        address: u8,
        /// What happened.
        reason: String,
    },
}

impl From<std::io::Error> for RoboClawError {
    fn from(e: std::io::Error) -> Self {
        RoboClawError::Io(Arc::new(e))
    }
}

/// How to reach the controller.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RoboClawConfig {
    /// Packet serial address (0x80–0x87).
    pub address: u8,
    /// Baud rate, for transmission times.
    pub baud: u32,
    /// The adapter's latency before it is measured (added to every answer's wait).
    pub latency: Duration,
    /// How long a read that is safe to repeat keeps retrying before the serial timeout is set.
    pub budget: Duration,
}

/// The retry budget of a repeatable read before the controller's serial timeout is set.
pub const DEFAULT_BUDGET: Duration = Duration::from_secs(1);

impl RoboClawConfig {
    /// An address a RoboClaw answers (0x80–0x87) and a baud rate it runs at; why not.
    pub fn check(&self) -> Result<(), String> {
        if !ADDRESSES.contains(&self.address) {
            return Err(format!(
                "address 0x{:02X} is outside 0x80–0x87",
                self.address
            ));
        }
        if !(1200..=460_800).contains(&self.baud) {
            return Err(format!("baud {} is not a RoboClaw rate", self.baud));
        }
        Ok(())
    }
}

impl Default for RoboClawConfig {
    fn default() -> Self {
        RoboClawConfig {
            address: 0x80,
            baud: 38_400,
            // A USB serial adapter's worst (16 ms) until measured.
            latency: Duration::from_millis(16),
            budget: DEFAULT_BUDGET,
        }
    }
}

/// The Tokio runtime a client's port task runs in; an error outside one.
fn runtime() -> Result<tokio::runtime::Handle, RoboClawError> {
    tokio::runtime::Handle::try_current().map_err(|_| {
        RoboClawError::Io(Arc::new(std::io::Error::other(
            "a RoboClaw client needs a Tokio runtime to run its port's task in",
        )))
    })
}

/// A connection to one controller; cheap to clone, all clones share the port.
///
/// The port belongs to one task that runs one transaction at a time ([`crate::io::transport`]'s
/// concurrency model): a caller that gives up on its answer (a timeout around it, Ctrl-C) never
/// cuts a transaction in half; a transaction whose caller has gone before it starts is
/// skipped, and one under way ends after its current attempt.
#[derive(Clone)]
pub struct RoboClaw {
    jobs: mpsc::UnboundedSender<Job>,
    cfg: RoboClawConfig,
    label: Arc<str>,
    timing: Arc<Timing>,
}

impl RoboClaw {
    /// Takes a byte stream (serial port, PTY, in-memory [`crate::io::transport::pair`]) and
    /// spawns the task that owns it (so it needs a Tokio runtime); `label` names it in errors.
    pub fn new<S: Transport>(
        stream: S,
        cfg: RoboClawConfig,
        label: &str,
    ) -> Result<Self, RoboClawError> {
        cfg.check().map_err(RoboClawError::InvalidArgument)?;
        let ms = |d: Duration| u64::try_from(d.as_millis()).unwrap_or(u64::MAX);
        let us = |d: Duration| u64::try_from(d.as_micros()).unwrap_or(u64::MAX);
        let timing = Arc::new(Timing {
            latency_us: AtomicU64::new(us(cfg.latency)),
            budget_ms: AtomicU64::new(ms(cfg.budget)),
            owed: AtomicU32::new(0),
        });
        let (jobs, queue) = mpsc::unbounded_channel();
        let wire = Wire {
            port: Box::new(stream),
            cfg,
            timing: timing.clone(),
        };
        runtime()?.spawn(wire.serve(queue));
        Ok(RoboClaw {
            jobs,
            cfg,
            label: Arc::from(label),
            timing,
        })
    }

    /// Opens a serial port by path.
    pub fn open(path: &str, cfg: RoboClawConfig) -> Result<Self, RoboClawError> {
        // Registering the port needs the runtime too: refuse before opening it.
        runtime()?;
        let port = crate::io::serial::open(path, cfg.baud).map_err(|e| RoboClawError::Open {
            path: path.into(),
            source: Arc::new(e),
        })?;
        Self::new(port, cfg, path)
    }

    /// The port's name.
    pub fn label(&self) -> &str {
        &self.label
    }

    /// The settings.
    pub fn config(&self) -> RoboClawConfig {
        self.cfg
    }

    /// The adapter's latency in use (measured, or the configured guess).
    pub fn latency(&self) -> Duration {
        self.timing.latency()
    }

    /// How long a repeatable read keeps retrying.
    pub fn budget(&self) -> Duration {
        self.timing.budget()
    }

    /// Hands a transaction to the port's task and awaits its answer.
    async fn ask<T>(
        &self,
        job: impl FnOnce(oneshot::Sender<Result<T, RoboClawError>>) -> Job,
    ) -> Result<T, RoboClawError> {
        let (reply, answer) = oneshot::channel();
        self.jobs.send(job(reply)).map_err(|_| self.gone())?;
        answer.await.map_err(|_| self.gone())?
    }

    /// The port's task has ended: its runtime shut down.
    fn gone(&self) -> RoboClawError {
        RoboClawError::Io(Arc::new(std::io::Error::new(
            std::io::ErrorKind::BrokenPipe,
            format!(
                "the task that owns {} has ended (its runtime shut down)",
                self.label
            ),
        )))
    }

    /// Measures the adapter's latency: the slowest of a few short reads' round trips beyond
    /// their transmission time, which every later wait then allows for. Call it once the
    /// controller answers (after [`RoboClaw::version`]).
    pub async fn measure_latency(&self) -> Result<Duration, RoboClawError> {
        let mut worst = Duration::ZERO;
        for _ in 0..5 {
            let started = tokio::time::Instant::now();
            self.read(cmd::READ_MAIN_BATTERY, 2).await?;
            let wire = crate::io::serial::transmission(6, self.cfg.baud);
            worst = worst.max(started.elapsed().saturating_sub(wire + DEVICE_TIME));
        }
        // Half the round trip is one way; allow the slowest seen, at least a millisecond.
        let latency = (worst / 2).max(Duration::from_millis(1));
        let us = u64::try_from(latency.as_micros()).unwrap_or(u64::MAX);
        self.timing.latency_us.store(us, Ordering::Relaxed);
        Ok(latency)
    }

    /// A read of `len` data bytes (plus CRC), until the budget is spent. A request that gets
    /// no answer in time is sent again, and whichever answer then arrives first is taken: an
    /// answer to a repeatable read is as good late as on time, so a slow controller or a host
    /// that stalls costs a repeat, never the read. Answers are read exactly to their length,
    /// so one never eats into the next.
    pub async fn read(&self, command: u8, len: usize) -> Result<Vec<u8>, RoboClawError> {
        self.ask(|reply| Job::Read {
            command,
            len,
            reply,
        })
        .await
    }

    /// A write, acknowledged once; the caller decides whether repeating it is safe.
    pub async fn write(&self, command: u8, data: &[u8]) -> Result<(), RoboClawError> {
        let data = data.to_vec();
        self.ask(|reply| Job::Write {
            command,
            data,
            reply,
        })
        .await
    }

    /// A write that is safe to repeat (stop, settings), retried within the budget.
    pub async fn write_idempotent(&self, command: u8, data: &[u8]) -> Result<(), RoboClawError> {
        let started = tokio::time::Instant::now();
        let budget = self.budget();
        loop {
            match self.write(command, data).await {
                Ok(()) => return Ok(()),
                Err(e @ (RoboClawError::Io(_) | RoboClawError::Nak { .. })) => return Err(e),
                Err(e) if started.elapsed() >= budget => return Err(e),
                Err(_) => {}
            }
        }
    }

    /// The firmware version string (the handshake: a RoboClaw answers it, others do not).
    /// Asked at least three times and for the link's budget (unless the caller gives up), so
    /// that a host stalled while it connects does not take a RoboClaw for another device.
    pub async fn version(&self) -> Result<String, RoboClawError> {
        self.ask(|reply| Job::Version { reply }).await
    }

    /// Both encoder counters (M1, M2), wrapping 32-bit.
    pub async fn encoders(&self) -> Result<(u32, u32), RoboClawError> {
        let d = self.read(cmd::READ_ENCODERS, 8).await?;
        Ok((
            packet::be_u32(&d, 0).unwrap_or(0),
            packet::be_u32(&d, 4).unwrap_or(0),
        ))
    }

    /// One encoder (1 or 2) with its status byte ([`packet::encoder_status`]).
    pub async fn encoder(&self, motor: u8) -> Result<(u32, u8), RoboClawError> {
        let c = if motor == 2 {
            cmd::READ_ENCODER_M2
        } else {
            cmd::READ_ENCODER_M1
        };
        let d = self.read(c, 5).await?;
        Ok((packet::be_u32(&d, 0).unwrap_or(0), d[4]))
    }

    /// Main battery voltage (V).
    pub async fn battery_v(&self) -> Result<f64, RoboClawError> {
        let d = self.read(cmd::READ_MAIN_BATTERY, 2).await?;
        Ok(f64::from(u16::from_be_bytes([d[0], d[1]])) / 10.0)
    }

    /// Status bits (errors and warnings; 0 when all is well).
    pub async fn status(&self) -> Result<u32, RoboClawError> {
        let d = self.read(cmd::READ_STATUS, 4).await?;
        Ok(packet::be_u32(&d, 0).unwrap_or(0))
    }

    /// Battery, status bits and both encoders beside `firmware` (the [`Self::version`] read
    /// first, the answer that tells a RoboClaw is there): [`StatusReport`], what `odocal
    /// status` shows of a RoboClaw.
    pub async fn status_report(&self, firmware: String) -> Result<StatusReport, RoboClawError> {
        Ok(StatusReport {
            firmware,
            battery_v: self.battery_v().await?,
            status: self.status().await?,
            encoders: [self.encoder(1).await?, self.encoder(2).await?],
        })
    }

    /// Both motors' buffer lengths ([`packet::BUFFER_IDLE`] when finished).
    pub async fn buffers(&self) -> Result<(u8, u8), RoboClawError> {
        let d = self.read(cmd::READ_BUFFERS, 2).await?;
        Ok((d[0], d[1]))
    }

    /// Stops both motors (speed 0); safe to repeat.
    pub async fn stop(&self) -> Result<(), RoboClawError> {
        self.write_idempotent(cmd::DRIVE_SPEEDS, &[0; 8]).await
    }

    /// The serial timeout: the controller stops its motors when no valid packet arrives for
    /// this long (rounded to tenths of a second, at most 25.5 s; zero turns it off).
    pub async fn set_serial_timeout(&self, t: Duration) -> Result<Duration, RoboClawError> {
        let tenths = (t.as_secs_f64() * 10.0).round().clamp(0.0, 255.0) as u8;
        self.write_idempotent(cmd::SET_SERIAL_TIMEOUT, &[tenths])
            .await?;
        let set = Duration::from_millis(u64::from(tenths) * 100);
        // The controller now tolerates this much silence and then stops by itself: reads may
        // keep trying as long (never less than the default).
        let budget = set.max(DEFAULT_BUDGET);
        self.timing.budget_ms.store(
            u64::try_from(budget.as_millis()).unwrap_or(u64::MAX),
            Ordering::Relaxed,
        );
        Ok(set)
    }
}

/// What `odocal status` shows of a RoboClaw.
#[derive(Debug, Clone, PartialEq)]
pub struct StatusReport {
    /// The firmware's version string.
    pub firmware: String,
    /// Main battery (V).
    pub battery_v: f64,
    /// Status bits.
    pub status: u32,
    /// Encoder M1 and M2: the count and its status bits.
    pub encoders: [(u32, u8); 2],
}

impl StatusReport {
    /// The report as JSON.
    pub fn json(&self) -> serde_json::Value {
        let [(m1, s1), (m2, s2)] = self.encoders;
        serde_json::json!({
            "firmware": self.firmware, "battery_v": self.battery_v, "status": self.status,
            "encoders": [{"count": m1, "status": s1}, {"count": m2, "status": s2}],
        })
    }
}

impl std::fmt::Display for StatusReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let [(m1, s1), (m2, s2)] = self.encoders;
        writeln!(f, "{}", self.firmware.escape_debug())?;
        writeln!(f, "main battery       {:.1} V", self.battery_v)?;
        writeln!(f, "status bits        0x{:08X}", self.status)?;
        writeln!(f, "encoder M1         {m1} (status 0x{s1:02X})")?;
        writeln!(f, "encoder M2         {m2} (status 0x{s2:02X})")
    }
}
