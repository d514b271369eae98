//! The task that owns a RoboClaw's port: one transaction at a time, each within its deadlines
//! ([`crate::io::transport`]). Reads are retried (they are safe to repeat) until the link's
//! budget is spent; a write is sent once and its acknowledgement awaited; an answer that comes
//! too late is owed, and the next transaction waits it out before it speaks.

use super::client::{RoboClawConfig, RoboClawError};
use super::packet::{self, cmd, ACK};
use crate::io::transport::{self, BoxTransport, Deadline, Read};
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::{mpsc, oneshot};

/// Slack on every answer's wait for a host that is late by a scheduling slice.
const HOST_SLACK: Duration = Duration::from_millis(20);
/// Answers failing their CRC this many times end a read: a wrong baud rate or a noisy line.
const CRC_ATTEMPTS: u32 = 3;
/// The controller's own answer time (≥ 1 ms at 38400 baud and below, manual).
pub(super) const DEVICE_TIME: Duration = Duration::from_millis(2);
/// The longest a port is drained before a transaction.
const DRAIN_AT_MOST: Duration = Duration::from_millis(500);

/// What the link has learnt about itself: the adapter's latency and the budget.
#[derive(Debug)]
pub(super) struct Timing {
    pub(super) latency_us: AtomicU64,
    pub(super) budget_ms: AtomicU64,
    /// Requests whose answers were not read (they may still arrive).
    pub(super) owed: AtomicU32,
}

impl Timing {
    /// The adapter's latency in use (measured, or the configured guess).
    pub(super) fn latency(&self) -> Duration {
        Duration::from_micros(self.latency_us.load(Ordering::Relaxed))
    }

    /// How long a repeatable read keeps retrying.
    pub(super) fn budget(&self) -> Duration {
        Duration::from_millis(self.budget_ms.load(Ordering::Relaxed))
    }
}

/// One transaction for the task that owns the port, with where its answer goes.
pub(super) enum Job {
    Read {
        command: u8,
        len: usize,
        reply: oneshot::Sender<Result<Vec<u8>, RoboClawError>>,
    },
    Write {
        command: u8,
        data: Vec<u8>,
        reply: oneshot::Sender<Result<(), RoboClawError>>,
    },
    Version {
        reply: oneshot::Sender<Result<String, RoboClawError>>,
    },
}

/// The port and what the task knows of the link.
pub(super) struct Wire {
    pub(super) port: BoxTransport,
    pub(super) cfg: RoboClawConfig,
    pub(super) timing: Arc<Timing>,
}

impl Wire {
    /// Runs the transactions asked for, in order, until every handle is dropped. One whose
    /// caller has already gone is skipped; one whose caller goes while it runs ends after the
    /// attempt under way (never in the middle of one), so that what the caller does next — a
    /// stop, above all — does not wait out a read's whole budget on a controller that has
    /// stopped answering.
    pub(super) async fn serve(mut self, mut jobs: mpsc::UnboundedReceiver<Job>) {
        while let Some(job) = jobs.recv().await {
            match job {
                Job::Read {
                    command,
                    len,
                    reply,
                } => {
                    if !reply.is_closed() {
                        let answer = self.read(command, len, &|| reply.is_closed()).await;
                        let _ = reply.send(answer);
                    }
                }
                Job::Write {
                    command,
                    data,
                    reply,
                } => {
                    if !reply.is_closed() {
                        let _ = reply.send(self.write(command, &data).await);
                    }
                }
                Job::Version { reply } => {
                    if !reply.is_closed() {
                        let answer = self.version(&|| reply.is_closed()).await;
                        let _ = reply.send(answer);
                    }
                }
            }
        }
    }

    /// How long one attempt waits for an answer of `bytes` bytes in all (request and answer):
    /// their transmission, the controller's answer time, twice the adapter's latency (there
    /// and back) and a host's scheduling slice.
    fn deadline(&self, bytes: usize) -> Duration {
        crate::io::serial::transmission(bytes, self.cfg.baud)
            + DEVICE_TIME
            + 2 * self.timing.latency()
            + HOST_SLACK
    }

    /// Sends a frame, by the time its transmission takes and a write's slack.
    async fn send(&mut self, frame: &[u8]) -> Result<(), RoboClawError> {
        let by = transport::write_deadline(frame.len(), self.cfg.baud);
        Ok(transport::write_all_by(&mut self.port, frame, by).await?)
    }

    /// Discards bytes that arrive within `quiet` of each other — whatever a late answer left
    /// in the port, or the rest of a broken one — for at most [`DRAIN_AT_MOST`] (a port that
    /// streams without pause is not waited out).
    async fn drain(&mut self, quiet: Duration) {
        transport::drain(&mut self.port, quiet, DRAIN_AT_MOST).await;
    }

    /// Before a transaction: the port cleared of answers still owed to earlier requests (they
    /// may arrive late: waited for as long as an answer may take), else of stray bytes.
    async fn settle(&mut self) {
        let owed = self.timing.owed.swap(0, Ordering::Relaxed);
        let quiet = if owed > 0 {
            self.deadline(8)
        } else {
            Duration::from_millis(1)
        };
        self.drain(quiet).await;
    }

    /// [`super::client::RoboClaw::read`]'s transaction; it asks no more once `gone()`.
    async fn read(
        &mut self,
        command: u8,
        len: usize,
        gone: &(dyn Fn() -> bool + Sync),
    ) -> Result<Vec<u8>, RoboClawError> {
        let after = self.deadline(len + 4);
        let budget = self.timing.budget();
        let started = tokio::time::Instant::now();
        let want = len + 2;
        self.settle().await;
        let (mut sent, mut crc_failures) = (0u32, 0u32);
        let mut buf: Vec<u8> = Vec::with_capacity(want);
        let mut resend = true;
        let mut chunk = [0u8; 64];
        loop {
            if resend {
                self.send(&packet::read_frame(self.cfg.address, command))
                    .await?;
                sent += 1;
            }
            let room = (want - buf.len()).min(chunk.len());
            let by = Deadline::after(after);
            match transport::read_some_by(&mut self.port, &mut chunk[..room], by).await? {
                Read::Closed => {
                    return Err(std::io::Error::from(std::io::ErrorKind::UnexpectedEof).into())
                }
                Read::Got(n) => {
                    buf.extend_from_slice(&chunk[..n]);
                    resend = false;
                    if buf.len() < want {
                        continue;
                    }
                    if let Some(data) = packet::check_answer(self.cfg.address, command, &buf) {
                        let data = data.to_vec();
                        self.timing.owed.store(sent - 1, Ordering::Relaxed);
                        return Ok(data);
                    }
                    // A broken answer (noise, or the tail of another): start clean.
                    crc_failures += 1;
                    if crc_failures >= CRC_ATTEMPTS {
                        break;
                    }
                    self.drain(after).await;
                    buf.clear();
                    resend = true;
                    sent = 0;
                }
                Read::Late => {
                    if started.elapsed() + after > budget || gone() {
                        break;
                    }
                    // Silence: ask again. A half answer that went silent is broken.
                    if !buf.is_empty() {
                        self.drain(after).await;
                        buf.clear();
                        sent = 0;
                    }
                    resend = true;
                }
            }
        }
        self.timing.owed.store(sent, Ordering::Relaxed);
        if crc_failures >= CRC_ATTEMPTS {
            Err(RoboClawError::Crc {
                command,
                attempts: crc_failures,
            })
        } else {
            Err(RoboClawError::Timeout {
                command,
                after: started.elapsed(),
                attempts: sent.max(1),
            })
        }
    }

    /// [`super::client::RoboClaw::write`]'s transaction.
    async fn write(&mut self, command: u8, data: &[u8]) -> Result<(), RoboClawError> {
        let frame = packet::write_frame(self.cfg.address, command, data);
        let after = self.deadline(frame.len() + 1);
        self.settle().await;
        self.send(&frame).await?;
        let mut ack = [0u8; 1];
        match transport::read_exact_by(&mut self.port, &mut ack, Deadline::after(after)).await? {
            Read::Late => {
                // The acknowledgement may still come: the next transaction waits for it.
                self.timing.owed.fetch_add(1, Ordering::Relaxed);
                Err(RoboClawError::Timeout {
                    command,
                    after,
                    attempts: 1,
                })
            }
            Read::Closed => Err(std::io::Error::from(std::io::ErrorKind::UnexpectedEof).into()),
            Read::Got(_) if ack[0] == ACK => Ok(()),
            Read::Got(_) => Err(RoboClawError::Nak {
                command,
                got: ack[0],
            }),
        }
    }

    /// [`super::client::RoboClaw::version`]'s transaction; it asks no more once `gone()`.
    async fn version(&mut self, gone: &(dyn Fn() -> bool + Sync)) -> Result<String, RoboClawError> {
        let after = self.deadline(52);
        let started = tokio::time::Instant::now();
        let budget = self.timing.budget();
        let mut attempts = 0;
        while (attempts < 3 || started.elapsed() < budget) && !(attempts > 0 && gone()) {
            attempts += 1;
            let quiet = if attempts == 1 {
                Duration::from_millis(1)
            } else {
                after
            };
            self.drain(quiet).await;
            self.send(&packet::read_frame(self.cfg.address, cmd::READ_VERSION))
                .await?;
            if let Some(got) = self.version_answer(Deadline::after(after)).await {
                if let Some(text) = packet::check_answer(self.cfg.address, cmd::READ_VERSION, &got)
                {
                    return Ok(String::from_utf8_lossy(text)
                        .trim_end_matches(['\0', '\n'])
                        .to_string());
                }
            }
        }
        // The last request's answer may still come: the next transaction waits for it.
        self.timing.owed.store(1, Ordering::Relaxed);
        Err(RoboClawError::Timeout {
            command: cmd::READ_VERSION,
            after,
            attempts,
        })
    }

    /// The version's answer: up to 48 characters ending "\n\0", then the CRC; `None` if it
    /// is not whole by `by` (or the port fails: the next attempt meets it).
    async fn version_answer(&mut self, by: Deadline) -> Option<Vec<u8>> {
        let mut got = Vec::new();
        let mut b = [0u8; 1];
        loop {
            match transport::read_exact_by(&mut self.port, &mut b, by).await {
                Ok(Read::Got(_)) => got.push(b[0]),
                _ => return None,
            }
            if got.ends_with(b"\n\0") || got.len() >= 48 {
                break;
            }
        }
        let mut crc = [0u8; 2];
        match transport::read_exact_by(&mut self.port, &mut crc, by).await {
            Ok(Read::Got(_)) => {
                got.extend_from_slice(&crc);
                Some(got)
            }
            _ => None,
        }
    }
}
