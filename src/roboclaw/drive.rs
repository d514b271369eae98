//! A RoboClaw as the seam's [`Drive`]: each leg or turn is one buffered "speed, acceleration
//! and distance" command for both motors, its encoder counts computed from the robot profile's
//! *configured* geometry (the open loop of the paper); motion ends when both buffers report
//! idle. The profile says which channel is the left wheel and which way each encoder counts.

use super::client::{RoboClaw, RoboClawError};
use super::packet::{cmd, drive_distance_data, BUFFER_IDLE};
use crate::base::{
    Achieved, BaseError, ComponentInfo, Drive, Fanout, Preflight, SampleStream, TravelSample,
};
use crate::roboclaw::profile::{Channel, Profile};
use async_trait::async_trait;
use std::sync::{Arc, RwLock};
use std::time::Duration;
use tokio::time::Instant;

/// How often a running motion is polled (this also feeds the controller's serial timeout).
pub const POLL: Duration = Duration::from_millis(20);

/// The drive.
pub struct RoboClawDrive {
    claw: RoboClaw,
    version: String,
    profile: Arc<RwLock<Profile>>,
    travel: Fanout<TravelSample>,
}

fn err(what: &'static str) -> impl Fn(RoboClawError) -> BaseError {
    move |e| match e {
        RoboClawError::InvalidArgument(reason) => BaseError::InvalidArgument {
            component: "drive (RoboClaw)".into(),
            reason,
        },
        RoboClawError::Nak { command, got } => BaseError::Refused {
            component: "drive (RoboClaw)".into(),
            what: what.into(),
            reason: format!("command {command} answered 0x{got:02X}"),
        },
        other => BaseError::backend(format!("drive (RoboClaw, {what})"), other),
    }
}

/// Encoder counts (left, right) as wheel rotations forward, from M1/M2 counters.
fn wheels(p: &Profile, m1: u32, m2: u32) -> (u32, u32, i8, i8) {
    let w = &p.wiring;
    match w.left_channel {
        Channel::M1 => (m1, m2, w.left_encoder_sign, w.right_encoder_sign),
        Channel::M2 => (m2, m1, w.left_encoder_sign, w.right_encoder_sign),
    }
}

impl RoboClawDrive {
    /// Greets the controller (reads its firmware version) and wraps it; fails with a diagnosis
    /// when nothing or something else answers.
    pub async fn connect(
        claw: RoboClaw,
        profile: Arc<RwLock<Profile>>,
    ) -> Result<Self, RoboClawError> {
        let version = claw
            .version()
            .await
            .map_err(|e| RoboClawError::NotARoboClaw {
                port: claw.label().into(),
                address: claw.config().address,
                reason: e.to_string(),
            })?;
        claw.measure_latency().await?;
        Ok(RoboClawDrive {
            claw,
            version,
            profile,
            travel: Fanout::default(),
        })
    }

    /// The firmware version it reported.
    pub fn version(&self) -> &str {
        &self.version
    }

    fn profile(&self) -> Profile {
        *self.profile.read().unwrap_or_else(|p| p.into_inner())
    }

    /// Wheel travel (m, forward) between two encoder readings.
    fn travel_between(&self, p: &Profile, a: (u32, u32), b: (u32, u32)) -> (f64, f64) {
        let (la, ra, ls, rs) = wheels(p, a.0, a.1);
        let (lb, rb, _, _) = wheels(p, b.0, b.1);
        let g = p.params();
        (
            f64::from(lb.wrapping_sub(la) as i32) * f64::from(ls) * g.left_m_per_count(),
            f64::from(rb.wrapping_sub(ra) as i32) * f64::from(rs) * g.right_m_per_count(),
        )
    }

    fn forward(&self, left_m: f64, right_m: f64) {
        let sample = TravelSample {
            time_s: crate::base::host_time_s(),
            left_m,
            right_m,
        };
        self.travel.send(&sample);
    }

    /// Drives the wheels by `left_m`, `right_m` at most `speed_m_s` (the faster wheel), both
    /// finishing together.
    async fn wheels_by(
        &self,
        left_m: f64,
        right_m: f64,
        speed_m_s: f64,
    ) -> Result<Option<Achieved>, BaseError> {
        let p = self.profile();
        let g = p.params();
        let (data, speed, longest) = motion_command(&p, left_m, right_m, speed_m_s)?;
        let before = self.claw.encoders().await.map_err(err("an encoder read"))?;
        // The stream is silent at rest: a zero sample marks where this motion's travel starts
        // (a sample covers the time since the one before it).
        self.forward(0.0, 0.0);
        self.send_motion(&data, before).await?;
        // Trapezoid time plus slack: 3× + 2 s.
        let expected = longest / speed + speed / p.limits.max_accel_m_s2;
        let limit = Duration::from_secs_f64(3.0 * expected + 2.0);
        let last = self.follow_until_idle(&p, before, limit).await?;
        let after = self.claw.encoders().await.map_err(err("an encoder read"))?;
        let (sl, sr) = self.travel_between(&p, before, after);
        self.check_direction((sl, sr), (left_m, right_m)).await?;
        let (tl, tr) = self.travel_between(&p, last, after);
        if tl != 0.0 || tr != 0.0 {
            self.forward(tl, tr);
        }
        Ok(Some(Achieved::of_wheels(sl, sr, g.wheelbase_m)))
    }

    /// Sends the motion command; resends it only if the ack is lost and it never arrived.
    async fn send_motion(&self, data: &[u8], before: (u32, u32)) -> Result<(), BaseError> {
        match self.claw.write(cmd::DRIVE_SPEED_ACCEL_DISTANCE, data).await {
            Ok(()) => {}
            Err(RoboClawError::Timeout { .. }) => {
                // The acknowledgement is lost: did the command arrive? Moving encoders or a busy
                // buffer say yes. Never resend a motion that may be running.
                tokio::time::sleep(POLL).await;
                let (b1, b2) = self.claw.buffers().await.map_err(err("a buffer read"))?;
                let now = self.claw.encoders().await.map_err(err("an encoder read"))?;
                let arrived = b1 != BUFFER_IDLE || b2 != BUFFER_IDLE || now != before;
                if !arrived {
                    self.claw
                        .write(cmd::DRIVE_SPEED_ACCEL_DISTANCE, data)
                        .await
                        .map_err(err("a motion"))?;
                }
            }
            Err(e) => return Err(err("a motion")(e)),
        }
        Ok(())
    }

    /// Forwards the motion's travel until both buffers are idle; returns the last encoders.
    /// Past the time limit it stops the controller and fails with a motion timeout.
    async fn follow_until_idle(
        &self,
        p: &Profile,
        before: (u32, u32),
        limit: Duration,
    ) -> Result<(u32, u32), BaseError> {
        let started = Instant::now();
        let mut last = before;
        loop {
            tokio::time::sleep(POLL).await;
            let now = self.claw.encoders().await.map_err(err("an encoder read"))?;
            let (sl, sr) = self.travel_between(p, last, now);
            if sl != 0.0 || sr != 0.0 {
                self.forward(sl, sr);
            }
            last = now;
            let (b1, b2) = self.claw.buffers().await.map_err(err("a buffer read"))?;
            if b1 == BUFFER_IDLE && b2 == BUFFER_IDLE {
                break;
            }
            if started.elapsed() > limit {
                let _ = self.claw.stop().await;
                return Err(BaseError::MotionTimeout { after: limit });
            }
        }
        Ok(last)
    }

    /// Stops the base and refuses the motion when a wheel went the other way than commanded.
    async fn check_direction(
        &self,
        (sl, sr): (f64, f64),
        (left_m, right_m): (f64, f64),
    ) -> Result<(), BaseError> {
        // A wheel that went the other way than commanded means the profile's wiring is wrong
        // (channel swapped, or an encoder counting the other way): stop before it goes on.
        for (name, got, want) in [("left", sl, left_m), ("right", sr, right_m)] {
            if want.abs() > 0.01 && got * want < 0.0 && got.abs() > 0.1 * want.abs() {
                let _ = self.claw.stop().await;
                return Err(BaseError::Refused {
                    component: "drive (RoboClaw)".into(),
                    what: "a motion".into(),
                    reason: format!(
                        "the {name} wheel moved {got:+.3} m for {want:+.3} m commanded: check \
                         the profile's [wiring] (left_channel, {name}_encoder_sign)"
                    ),
                });
            }
        }
        Ok(())
    }
}

/// The motion's command bytes, its capped speed and the longer wheel's travel (m).
fn motion_command(
    p: &Profile,
    left_m: f64,
    right_m: f64,
    speed_m_s: f64,
) -> Result<(Vec<u8>, f64, f64), BaseError> {
    let g = p.params();
    let invalid = |reason: String| BaseError::InvalidArgument {
        component: "drive (RoboClaw)".into(),
        reason,
    };
    if !(left_m.is_finite() && right_m.is_finite() && speed_m_s.is_finite() && speed_m_s > 0.0) {
        return Err(invalid(format!(
            "wheels {left_m}, {right_m} m at {speed_m_s} m/s is not a motion"
        )));
    }
    let speed = speed_m_s.min(p.limits.max_speed_m_s);
    let longest = left_m.abs().max(right_m.abs()).max(1e-9);
    let counts = |m: f64, per: f64| (m / per).round();
    let (cl, cr) = (
        counts(left_m, g.left_m_per_count()),
        counts(right_m, g.right_m_per_count()),
    );
    if cl.abs() > f64::from(i32::MAX) || cr.abs() > f64::from(i32::MAX) {
        return Err(invalid(
            "the motion is longer than the encoders can count".into(),
        ));
    }
    // Speeds proportional to each wheel's share so both finish together.
    let ql = speed * left_m.abs() / longest / g.left_m_per_count();
    let qr = speed * right_m.abs() / longest / g.right_m_per_count();
    let accel = (p.limits.max_accel_m_s2 / g.left_m_per_count().min(g.right_m_per_count())).round();
    // Encoder counts per channel, signed as that encoder counts forward travel.
    let (w1, w2) = match p.wiring.left_channel {
        Channel::M1 => (
            (cl, ql, p.wiring.left_encoder_sign),
            (cr, qr, p.wiring.right_encoder_sign),
        ),
        Channel::M2 => (
            (cr, qr, p.wiring.right_encoder_sign),
            (cl, ql, p.wiring.left_encoder_sign),
        ),
    };
    let speed_of =
        |(c, q, s): (f64, f64, i8)| (q.round().max(1.0) * c.signum() * f64::from(s)) as i32;
    let data = drive_distance_data(
        accel.clamp(1.0, f64::from(u32::MAX)) as u32,
        speed_of(w1),
        w1.0.abs() as u32,
        speed_of(w2),
        w2.0.abs() as u32,
    );
    Ok((data, speed, longest))
}

#[async_trait]
impl Drive for RoboClawDrive {
    fn rounds_to_counts(&self) -> bool {
        // Buffered speed-and-distance commands take whole counts (see `counts` above).
        true
    }

    fn info(&self) -> ComponentInfo {
        let c = self.claw.config();
        ComponentInfo {
            kind: "roboclaw".into(),
            id: format!("{}@0x{:02X}", self.claw.label(), c.address),
            details: serde_json::json!({
                "port": self.claw.label(),
                "address": c.address,
                "baud": c.baud,
                "adapter_latency_ms": self.claw.latency().as_secs_f64() * 1e3,
                "read_budget_ms": self.claw.budget().as_secs_f64() * 1e3,
                "firmware": self.version,
            }),
        }
    }

    async fn preflight(&self) -> Result<Preflight, BaseError> {
        let mut out = Preflight::default();
        let p = self.profile();
        let v = self
            .claw
            .battery_v()
            .await
            .map_err(err("the battery voltage"))?;
        if let Some(min) = p.limits.min_battery_v {
            if v < min {
                out.faults.push(format!(
                    "main battery {v:.1} V is below the profile's {min:.1} V"
                ));
            }
        }
        let status = self.claw.status().await.map_err(err("the status"))?;
        if status != 0 {
            out.warnings
                .push(format!("the RoboClaw reports status bits 0x{status:08X}"));
        }
        // Both encoders must answer. Their wrap bits are no fault: an encoder that counts down
        // driving forward wraps below zero on its first leg (the controller sets the underflow
        // bit until it is read), and the drive counts differences modulo 2³².
        for m in [1u8, 2] {
            self.claw.encoder(m).await.map_err(err("an encoder"))?;
        }
        Ok(out)
    }

    async fn arm_watchdog(&self, timeout: Duration) -> Result<Option<Duration>, BaseError> {
        // The RoboClaw's serial timeout, at least a few polls long.
        let t = timeout.max(POLL * 5);
        self.claw
            .set_serial_timeout(t)
            .await
            .map(Some)
            .map_err(err("the serial timeout"))
    }

    async fn move_straight(
        &self,
        distance_m: f64,
        max_speed_m_s: f64,
    ) -> Result<Option<Achieved>, BaseError> {
        self.wheels_by(distance_m, distance_m, max_speed_m_s).await
    }

    async fn turn_in_place(
        &self,
        angle_rad: f64,
        max_rate_rad_s: f64,
    ) -> Result<Option<Achieved>, BaseError> {
        let b = self.profile().params().wheelbase_m;
        let turn = |rad: f64| Achieved {
            distance_m: 0.0,
            turn_rad: rad,
        };
        let (left, right) = turn(angle_rad).wheels(b);
        // The turn-rate limit as the wheels' speed.
        let (_, speed) = turn(max_rate_rad_s).wheels(b);
        self.wheels_by(left, right, speed).await
    }

    async fn stop(&self) -> Result<(), BaseError> {
        self.claw.stop().await.map_err(err("STOP"))
    }

    fn emergency_stop(&self) {
        let claw = self.claw.clone();
        // Not awaitable from Drop: stop in the background (the serial timeout backs it up).
        if let Ok(rt) = tokio::runtime::Handle::try_current() {
            rt.spawn(async move {
                let _ = claw.stop().await;
            });
        }
    }

    async fn travel(
        &self,
        _period: Duration,
    ) -> Result<Option<SampleStream<TravelSample>>, BaseError> {
        Ok(Some(self.travel.subscribe()))
    }

    fn clock(&self) -> Option<String> {
        // Stamped on arrival of each encoder read.
        Some(crate::base::HOST_CLOCK.into())
    }
}
