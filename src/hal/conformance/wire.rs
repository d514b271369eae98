//! The port as the conformance run sees it: frames out, answers and events back within a
//! deadline ([`Wire`]), and the device's requests adapted to real time and a real robot
//! ([`Device::adapt`]: speeds capped, long motions shortened).

use super::*;
use crate::io::transport::{self, Deadline, Read};

/// The port's frames, one request at a time.
pub(super) struct Wire<S> {
    pub(super) stream: S,
    pub(super) codec: FrameCodec,
    pub(super) buf: BytesMut,
    pub(super) pending: VecDeque<Frame>,
    pub(super) seq: u8,
}

/// A request's answer and the events that came before it.
pub(super) struct Exchange {
    pub(super) events: Vec<Frame>,
    pub(super) answer: Frame,
}

impl<S: AsyncRead + AsyncWrite + Unpin> Wire<S> {
    /// The next frame received before `until`.
    pub(super) async fn next(&mut self, until: Instant) -> std::io::Result<Option<Frame>> {
        loop {
            if let Some(f) = self.pending.pop_front() {
                return Ok(Some(f));
            }
            let mut chunk = [0u8; 512];
            match transport::read_some_by(&mut self.stream, &mut chunk, Deadline::at(until)).await?
            {
                Read::Late => return Ok(None),
                Read::Closed => return Err(std::io::ErrorKind::UnexpectedEof.into()),
                Read::Got(n) => {
                    let frames = self.codec.feed(&mut self.buf, &chunk[..n]);
                    self.pending.extend(frames);
                }
            }
        }
    }

    /// The events received during `wait`.
    pub(super) async fn collect(&mut self, wait: Duration) -> std::io::Result<Vec<Frame>> {
        let until = Instant::now() + wait;
        let mut events = Vec::new();
        while let Some(f) = self.next(until).await? {
            if f.kind == FrameKind::Event {
                events.push(f);
            }
        }
        Ok(events)
    }

    /// Sends `bytes` (a request) and waits for its answer, sending it again once (a safe
    /// retry: same sequence number) if none comes; `None` if none ever does.
    pub(super) async fn exchange(&mut self, bytes: &[u8]) -> std::io::Result<Option<Exchange>> {
        let (Some(&seq), Some(&msg)) = (bytes.get(5), bytes.get(6)) else {
            return Ok(None);
        };
        let mut events = Vec::new();
        for _ in 0..2 {
            // The wire does not know the baud: the deadline is the frame's at the slowest a
            // port may run (crate::hal::BAUD_RANGE), for a port that takes nothing is gone.
            let by = transport::write_deadline(bytes.len(), *crate::hal::BAUD_RANGE.start());
            transport::write_all_by(&mut self.stream, bytes, by).await?;
            let until = Instant::now() + ANSWER_TIMEOUT;
            while let Some(f) = self.next(until).await? {
                match f.kind {
                    FrameKind::Event => events.push(f),
                    FrameKind::Response | FrameKind::Nack if f.seq == seq && f.msg == msg => {
                        return Ok(Some(Exchange { events, answer: f }));
                    }
                    // A late answer to an earlier request.
                    _ => {}
                }
            }
        }
        Ok(None)
    }

    /// The bytes of `request` with the harness's next sequence number (kept clear of the
    /// vectors', which count from 1).
    pub(super) fn frame(&mut self, request: Request) -> Vec<u8> {
        self.seq = self.seq.wrapping_add(1).max(0x80);
        Packet::request(self.seq, request).to_frame().to_bytes()
    }

    /// One of the harness's own requests: the answer, or the NACK.
    pub(super) async fn call(
        &mut self,
        what: &'static str,
        request: Request,
    ) -> Result<Result<Response, Nack>, ConformanceError> {
        let bytes = self.frame(request);
        let ex = self
            .exchange(&bytes)
            .await?
            .ok_or(ConformanceError::Silent {
                what,
                after: 2 * ANSWER_TIMEOUT,
            })?;
        match Packet::from_frame(&ex.answer).map(|p| p.body) {
            Ok(Body::Response { response }) => Ok(Ok(response)),
            Ok(Body::Nack { nack, .. }) => Ok(Err(nack)),
            Ok(Body::Request { request }) => Err(ConformanceError::Setup {
                what,
                why: format!("answered with a request ({})", request.name()),
            }),
            Ok(Body::Event { .. }) => Err(ConformanceError::Setup {
                what,
                why: "answered with an event".into(),
            }),
            Err(e) => Err(ConformanceError::Setup {
                what,
                why: format!("undecodable answer: {e}"),
            }),
        }
    }

    /// [`Wire::call`] that must be answered, not refused.
    pub(super) async fn ok(
        &mut self,
        what: &'static str,
        request: Request,
    ) -> Result<Response, ConformanceError> {
        self.call(what, request)
            .await?
            .map_err(|nack| ConformanceError::Setup {
                what,
                why: format!("refused {} (detail {})", nack.code, nack.detail),
            })
    }

    pub(super) async fn status(
        &mut self,
    ) -> Result<crate::protocol::message::Status, ConformanceError> {
        match self.ok("GET_STATUS", Request::GetStatus).await? {
            Response::GetStatus(s) => Ok(s),
            other => Err(ConformanceError::Setup {
                what: "GET_STATUS",
                why: format!("answered {}", other.name()),
            }),
        }
    }

    /// STOP, then waits until the base reports idle.
    pub(super) async fn stop_and_settle(&mut self) -> Result<(), ConformanceError> {
        self.ok("STOP", Request::Stop).await?;
        let until = Instant::now() + Duration::from_secs(3);
        loop {
            let s = self.status().await?;
            if s.motion_state == MotionState::Idle && s.queue_depth == 0 {
                return Ok(());
            }
            if Instant::now() > until {
                return Err(ConformanceError::Setup {
                    what: "STOP",
                    why: format!(
                        "the base is still {} 3 s after STOP (fault flags {:#06x})",
                        s.motion_state, s.fault_flags
                    ),
                });
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }
}

/// What the harness knows about the device and how it may move it.
pub(super) struct Device {
    pub(super) info: DeviceInfo,
    pub(super) params: ParamsBlock,
    pub(super) speed_mm_s: u16,
    pub(super) rate_mrad_s: u16,
    pub(super) time_scale: f64,
}

impl Device {
    /// Device milliseconds as wall-clock time.
    pub(super) fn wall(&self, device_ms: f64) -> Duration {
        Duration::from_secs_f64((device_ms / self.time_scale).max(0.0) / 1e3)
    }

    pub(super) fn has(&self, bit: u32) -> bool {
        self.info.capabilities & bit != 0
    }

    /// Puts the device in a rule's starting state (see the module documentation); returns
    /// `completed_motions` there.
    pub(super) async fn fresh<S: AsyncRead + AsyncWrite + Unpin>(
        &self,
        w: &mut Wire<S>,
    ) -> Result<u32, ConformanceError> {
        w.stop_and_settle().await?;
        if self.has(capability::WATCHDOG) {
            let off = WatchdogTimeout { timeout_ms: 0 };
            w.ok("CONFIGURE_WATCHDOG", Request::ConfigureWatchdog(off))
                .await?;
        }
        if self.has(capability::TELEMETRY) {
            let off = crate::protocol::message::TelemetryPeriod { period_ms: 0 };
            w.ok("CONFIGURE_TELEMETRY", Request::ConfigureTelemetry(off))
                .await?;
        }
        w.ok("SET_PARAMS", Request::SetParams(self.params)).await?;
        let completed = w.status().await?.completed_motions;
        if self.has(capability::WATCHDOG) {
            let safety = WatchdogTimeout {
                timeout_ms: SAFETY_WATCHDOG_MS,
            };
            w.ok("CONFIGURE_WATCHDOG", Request::ConfigureWatchdog(safety))
                .await?;
        }
        w.ok("HELLO", hello()).await?;
        // Telemetry still in flight belongs to the previous rule.
        w.collect(Duration::from_millis(20)).await?;
        Ok(completed)
    }

    /// A vector's request as sent here: speeds capped, a motion that only needs to run cut
    /// to [`LONG_MS`] (`wait` false), or kept whole and stopped once accepted (`wait` true).
    pub(super) fn adapt(&self, frame: &Frame, wait: bool) -> Sent {
        let mut sent = Sent {
            bytes: frame.to_bytes(),
            stop_at_once: false,
            expected_ms: 0.0,
        };
        let Ok(Packet {
            seq,
            body: Body::Request { request },
        }) = Packet::from_frame(frame)
        else {
            return sent;
        };
        // A motion of `size` (µm or µrad, signed) at `rate` (mm/s or mrad/s): the rate capped,
        // the size cut to LONG_MS unless it is out of range or to be kept whole (`wait`).
        let mut motion = |size: i32, rate: u16, cap: u16, max: u32| -> (i32, u16) {
            let rate = if rate == 0 { 0 } else { rate.min(cap) };
            let abs = size.unsigned_abs();
            let ms = f64::from(abs) / f64::from(rate.max(1));
            sent.expected_ms = ms;
            sent.stop_at_once = wait && ms > LONG_MS as f64;
            if abs == 0 || abs > max || rate == 0 || ms <= LONG_MS as f64 || wait {
                return (size, rate);
            }
            sent.expected_ms = LONG_MS as f64;
            let cut = (u64::from(rate) * LONG_MS).min(u64::from(max)) as i32;
            (cut * size.signum(), rate)
        };
        let adapted = match request {
            Request::MoveStraight(m) => {
                let (distance_um, max_speed_mm_s) = motion(
                    m.distance_um,
                    m.max_speed_mm_s,
                    self.speed_mm_s,
                    crate::protocol::device::MAX_DISTANCE_UM,
                );
                Request::MoveStraight(MoveStraightRequest {
                    distance_um,
                    max_speed_mm_s,
                    mode: m.mode,
                })
            }
            Request::TurnInPlace(t) => {
                let (angle_urad, max_rate_mrad_s) = motion(
                    t.angle_urad,
                    t.max_rate_mrad_s,
                    self.rate_mrad_s,
                    crate::protocol::device::MAX_ANGLE_URAD,
                );
                Request::TurnInPlace(TurnInPlaceRequest {
                    angle_urad,
                    max_rate_mrad_s,
                    mode: t.mode,
                })
            }
            Request::WheelSpeed(s) => {
                let limit = self.speed_mm_s.min(i16::MAX as u16) as i16;
                sent.expected_ms = f64::from(s.duration_ms);
                Request::WheelSpeed(WheelSpeedRequest {
                    left_mm_s: s.left_mm_s.clamp(-limit, limit),
                    right_mm_s: s.right_mm_s.clamp(-limit, limit),
                    duration_ms: s.duration_ms,
                })
            }
            other => other,
        };
        if adapted != request {
            sent.bytes = Packet::request(seq, adapted).to_frame().to_bytes();
        }
        sent
    }
}

/// A request as sent, and what to do after its answer.
pub(super) struct Sent {
    pub(super) bytes: Vec<u8>,
    /// A long motion accepted only to check its acceptance: STOP it at once.
    pub(super) stop_at_once: bool,
    /// How long the motion takes at its speed (device ms).
    pub(super) expected_ms: f64,
}

pub(super) fn hello() -> Request {
    Request::Hello(HelloRequest {
        host_major: crate::protocol::frame::MAJOR,
        host_min_minor: 0,
    })
}
