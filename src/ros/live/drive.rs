//! The drive: a leg or a turn published as ramped, speed-limited `Twist`s in the running
//! geometry, ended when the robot's own odometry says it is done, and zero published whenever a
//! motion ends, fails or is abandoned (also on drop).

use super::*;

impl RosDrive {
    /// One motion closed on the odometry; a turn that ends more than [`TURN_TRIM_RAD`] off its
    /// target is trimmed by up to two slow turns in place (a tenth of the rate): the braking
    /// runs on messages that arrive late by the link's latency, and a square whose corners
    /// are not square points its legs elsewhere than the other direction's (which the methods
    /// that pair legs by azimuth rely on).
    pub(super) async fn motion(
        &self,
        kind: Kind,
        target: f64,
        max: f64,
    ) -> Result<Option<Achieved>, BaseError> {
        let mut done = self.motion_once(kind, target, max, true).await?;
        if kind == Kind::Turn {
            for _ in 0..2 {
                let rest = target - done.turn_rad;
                if rest.abs() <= TURN_TRIM_RAD {
                    break;
                }
                // A trim creeps, and a wheel may stick at a creep: no stillness diagnosis.
                let trim = self.motion_once(kind, rest, 0.1 * max, false).await?;
                done.turn_rad += trim.turn_rad;
                done.distance_m += trim.distance_m;
            }
        }
        Ok(Some(done))
    }

    /// Drives until the odometry's `kind` quantity has changed by `target`, ramping at the
    /// configured acceleration and limited to `max` (m/s or rad/s); with `diagnose`, a robot
    /// that stays still is stopped and the error says why ([`NotMoving`]).
    async fn motion_once(
        &self,
        kind: Kind,
        target: f64,
        max: f64,
        diagnose: bool,
    ) -> Result<Achieved, BaseError> {
        check_motion(target, max)?;
        let accel = self.accel_of(kind);
        let mut odo = self.odo.clone();
        let mut closed = self.commander.client.closed_watch();
        let start = *odo.borrow();
        let pick = |o: &Odo| match kind {
            Kind::Straight => o.distance_m,
            Kind::Turn => o.turn_rad,
        };
        let (sign, goal) = (target.signum(), target.abs());
        // Tolerance: a millimetre, or a twentieth of a degree.
        let tol = match kind {
            Kind::Straight => 0.001,
            Kind::Turn => 0.001,
        };
        let expected = goal / max + max / accel;
        let deadline = Instant::now() + Duration::from_secs_f64(3.0 * expected + 5.0);
        let mut ramp = Ramp {
            kind,
            sign,
            max,
            accel,
            last_cmd: 0.0,
        };
        let mut last_t = Instant::now();
        let mut last_progress_t = Instant::now();
        let mut last_samples = start.samples;
        let first_command = Instant::now();
        let witnessed = self.witness.now();
        let mut moved = false;
        loop {
            let now_odo = *odo.borrow();
            let progress = sign * (pick(&now_odo) - pick(&start));
            moved |= (now_odo.distance_m - start.distance_m).abs() > STILL_M
                || (now_odo.turn_rad - start.turn_rad).abs() > STILL_RAD;
            let remaining = goal - progress;
            if remaining <= tol {
                break;
            }
            if now_odo.samples != last_samples {
                last_samples = now_odo.samples;
                last_progress_t = Instant::now();
            }
            let now = Instant::now();
            self.check_progress(now, deadline, expected, last_progress_t)?;
            // Wheel data arrives (the check above) and shows no motion: nothing obeys.
            if diagnose && !moved && first_command.elapsed() > STILL_LIMIT {
                let _ = self.commander.send(0.0, 0.0);
                return Err(drive_err(self.diagnose_still(&witnessed).await));
            }
            let dt = (now - last_t).as_secs_f64().clamp(0.0, 0.1);
            last_t = now;
            let (v, w) = ramp.next(remaining, dt);
            self.commander.send(v, w).map_err(drive_err)?;
            tokio::select! {
                _ = odo.changed() => {}
                _ = tokio::time::sleep(Duration::from_millis(50)) => {}
                _ = closed.changed() => {
                    return Err(self.link_closed());
                }
            }
        }
        self.commander.send(0.0, 0.0).map_err(drive_err)?;
        settle(&mut odo).await?;
        let end = *self.odo.borrow();
        Ok(Achieved {
            distance_m: end.distance_m - start.distance_m,
            turn_rad: end.turn_rad - start.turn_rad,
        })
    }

    /// The configured acceleration for a motion of `kind` (m/s² or rad/s²), at least 1e-3.
    fn accel_of(&self, kind: Kind) -> f64 {
        match kind {
            Kind::Straight => self.cfg.max_accel_m_s2,
            Kind::Turn => self.cfg.max_alpha_rad_s2,
        }
        .max(1e-3)
    }

    /// Stops the robot with an error when the motion has run past its `deadline` (3 × the
    /// `expected` s + 5 s) or the wheel data has not advanced since `last_progress_t` for 1 s.
    fn check_progress(
        &self,
        now: Instant,
        deadline: Instant,
        expected: f64,
        last_progress_t: Instant,
    ) -> Result<(), BaseError> {
        if now > deadline {
            let _ = self.commander.send(0.0, 0.0);
            return Err(BaseError::MotionTimeout {
                after: Duration::from_secs_f64(3.0 * expected + 5.0),
            });
        }
        if now - last_progress_t > Duration::from_secs(1) {
            let _ = self.commander.send(0.0, 0.0);
            return Err(self.wheel_data_lost());
        }
        Ok(())
    }

    /// The error for a motion stopped because the wheel data stopped for 1 s, naming its topic.
    fn wheel_data_lost(&self) -> BaseError {
        drive_err(RosbridgeError::Timeout(format!(
            "no wheel data for 1 s during a motion (topic {}): stopped",
            self.cfg.wheel_topic()
        )))
    }

    /// The error for a motion ended by the rosbridge connection closing, with its reason.
    fn link_closed(&self) -> BaseError {
        let reason = self.commander.client.closed().unwrap_or_default();
        drive_err(RosbridgeError::Closed(format!(
            "{reason} during a motion; the controller's cmd_vel_timeout ({} s) stops the wheels",
            self.cmd_vel_timeout_s
        )))
    }
}

/// Refuses a motion whose target or top speed is not finite, or whose top speed is not
/// positive.
fn check_motion(target: f64, max: f64) -> Result<(), BaseError> {
    if !(target.is_finite() && max.is_finite() && max > 0.0) {
        return Err(BaseError::InvalidArgument {
            component: "drive (rosbridge)".into(),
            reason: format!("motion {target} at up to {max} is not a motion"),
        });
    }
    Ok(())
}

/// A motion's speed command from step to step: the kind, direction, top speed and
/// acceleration, and the last speed commanded.
struct Ramp {
    kind: Kind,
    sign: f64,
    max: f64,
    accel: f64,
    last_cmd: f64,
}

impl Ramp {
    /// The twist (v, w) to publish with `remaining` of the goal left, `dt` s after the last.
    fn next(&mut self, remaining: f64, dt: f64) -> (f64, f64) {
        // Ramp up at `accel`, brake so as to stop at the goal, never below a creep speed.
        let cmd = self
            .max
            .min((2.0 * self.accel * remaining).sqrt())
            .min(self.last_cmd + self.accel * dt.max(0.02))
            .max(0.05 * self.max);
        self.last_cmd = cmd;
        match self.kind {
            Kind::Straight => (self.sign * cmd, 0.0),
            Kind::Turn => (0.0, self.sign * cmd),
        }
    }
}

/// Waits until the wheels have been still for 0.2 s of robot time (at most 3 s); an error
/// when the wheel data ends meanwhile.
async fn settle(odo: &mut watch::Receiver<Odo>) -> Result<(), BaseError> {
    let settled = tokio::time::timeout(
        Duration::from_secs(3),
        odo.wait_for(|o| o.still_since_s.is_some_and(|s| o.stamp_s - s >= 0.2)),
    )
    .await
    .map(|r| r.map(|o| *o));
    if let Ok(Err(_)) = settled {
        return Err(drive_err(RosbridgeError::Closed("wheel data ended".into())));
    }
    Ok(())
}

/// The velocity publisher, shared by motions, stops and guards.
///
/// A motion is meant in the *configured* geometry (the store's, which a calibration changes),
/// but the running controller turns twists into wheel speeds with the geometry it was started
/// with (or last set live). The commander translates: the wheel speeds the configured geometry
/// asks for, expressed as the twist the running controller needs to produce them.
#[derive(Clone)]
pub(super) struct Commander {
    pub(super) client: RosbridgeClient,
    pub(super) topic: String,
    pub(super) stamped: bool,
    pub(super) configured: Geometry,
    pub(super) running: Arc<RwLock<WheelParams>>,
}

/// The effective parameters of the section now.
pub(super) fn effective(g: &Geometry) -> WheelParams {
    g.read().unwrap_or_else(|p| p.into_inner()).effective()
}

/// The twist that makes a controller running with `running` turn its wheels as (`v`, `w`) in
/// `configured` asks.
pub(super) fn translate(
    v: f64,
    w: f64,
    configured: &WheelParams,
    running: &WheelParams,
) -> (f64, f64) {
    let asked = Displacement {
        distance_m: v,
        turn_rad: w,
    };
    let (l, r) = asked.wheels(configured.wheelbase_m);
    // Wheel angle rates, then what the running geometry makes of them.
    let (sl, sr) = running.travel_m(
        l / configured.left_m_per_count(),
        r / configured.right_m_per_count(),
    );
    let made = Displacement::of_wheels(sl, sr, running.wheelbase_m);
    (made.distance_m, made.turn_rad)
}

impl Commander {
    pub(super) fn send(&self, v: f64, w: f64) -> Result<(), RosbridgeError> {
        let (v, w) = if v == 0.0 && w == 0.0 {
            (0.0, 0.0)
        } else {
            let c = effective(&self.configured);
            let r = *self.running.read().unwrap_or_else(|p| p.into_inner());
            translate(v, w, &c, &r)
        };
        let twist = Twist::planar(v, w);
        let msg = if self.stamped {
            serde_json::to_value(TwistStamped {
                twist,
                ..TwistStamped::default()
            })
        } else {
            serde_json::to_value(twist)
        };
        self.client.publish(&self.topic, msg.unwrap_or(Value::Null))
    }
}

/// Which odometry quantity a motion watches.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(super) enum Kind {
    Straight,
    Turn,
}

/// A turn that ends further than this from its target (rad; 0.2°) by the odometry is trimmed.
pub const TURN_TRIM_RAD: f64 = 0.2 * std::f64::consts::PI / 180.0;

#[async_trait]
impl Drive for RosDrive {
    fn info(&self) -> ComponentInfo {
        ComponentInfo {
            kind: "rosbridge".into(),
            id: self.cfg.url.clone(),
            details: json!({
                "cmd_vel": self.cfg.cmd_vel,
                "twist_stamped": self.cfg.twist_stamped,
                "wheel_source": self.cfg.wheel_source,
                "topics": self.cfg.topics,
            }),
        }
    }

    fn diagnostics(&self) -> Value {
        // Every message a topic's checks dropped (not a number, not physical, stamped back, a
        // spike), by topic and reason: none is used silently.
        json!({ "dropped": self.rejects.summary() })
    }

    async fn preflight(&self) -> Result<Preflight, BaseError> {
        let mut out = Preflight::default();
        if let Some(reason) = self.commander.client.closed() {
            out.faults
                .push(format!("the rosbridge connection closed: {reason}"));
        }
        if self.odo.borrow().samples == 0 {
            out.faults.push("no wheel data yet".into());
        }
        Ok(out)
    }

    async fn arm_watchdog(&self, _timeout: Duration) -> Result<Option<Duration>, BaseError> {
        // The dead-man is the controller's cmd_vel_timeout: it is configured on the robot, and
        // the drive publishes at least every 50 ms during a motion to stay inside it.
        Ok(Some(Duration::from_secs_f64(
            self.cmd_vel_timeout_s.clamp(0.01, 60.0),
        )))
    }

    async fn move_straight(
        &self,
        distance_m: f64,
        max_speed_m_s: f64,
    ) -> Result<Option<Achieved>, BaseError> {
        self.motion(Kind::Straight, distance_m, max_speed_m_s).await
    }

    async fn turn_in_place(
        &self,
        angle_rad: f64,
        max_rate_rad_s: f64,
    ) -> Result<Option<Achieved>, BaseError> {
        self.motion(Kind::Turn, angle_rad, max_rate_rad_s).await
    }

    async fn stop(&self) -> Result<(), BaseError> {
        self.commander.send(0.0, 0.0).map_err(drive_err)
    }

    fn emergency_stop(&self) {
        let _ = self.commander.send(0.0, 0.0);
    }

    async fn travel(
        &self,
        _period: Duration,
    ) -> Result<Option<SampleStream<TravelSample>>, BaseError> {
        Ok(Some(self.travel.subscribe()))
    }

    fn clock(&self) -> Option<String> {
        Some(robot_clock(&self.cfg.url))
    }
}

impl Drop for RosDrive {
    fn drop(&mut self) {
        // Leaving: whatever happened, the last word on the velocity topic is zero.
        let _ = self.commander.send(0.0, 0.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn twists_are_translated_into_the_running_geometry() {
        let running = WheelParams::nominal(0.15, 0.39, std::f64::consts::TAU);
        let mut configured = running;
        configured.right_wheel_diameter_m *= 0.99;
        configured.wheelbase_m *= 0.97;
        // Same geometry: unchanged.
        let (v, w) = translate(0.3, 0.2, &running, &running);
        assert!((v - 0.3).abs() < 1e-12 && (w - 0.2).abs() < 1e-12);
        // Straight in the configured geometry: the right wheel turns faster by 1/0.99, which the
        // running controller sees as a slight left turn.
        let (v, w) = translate(0.3, 0.0, &configured, &running);
        let wl = (v - 0.5 * w * running.wheelbase_m) / running.left_m_per_count();
        let wr = (v + 0.5 * w * running.wheelbase_m) / running.right_m_per_count();
        assert!(
            (wr * configured.right_m_per_count() - wl * configured.left_m_per_count()).abs()
                < 1e-12
        );
        assert!(w > 0.0);
    }
}
