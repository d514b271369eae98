//! The routine's steps on the base: the pre-flight checks, a round of squares and the method
//! chosen for it, the swing, realigning between squares and driving the squares themselves.

use super::*;

impl Calibration<'_> {
    /// **Moves the robot**: the compass swing ([`RoutineConfig::swing`]); a deviation it
    /// measures is removed from every reading after. A base that cannot swing, or a fit that
    /// fails its checks (refused, never applied), is a warning and the run goes on: the
    /// default method pairs legs by azimuth and does not need it.
    pub(super) async fn swing(&mut self, params: &WheelParams) -> Result<(), RoutineError> {
        let kind = self.base.heading.kind();
        if !planning::swings(self.cfg, kind) {
            return Ok(());
        }
        self.progress.stage = Stage::Swing;
        let cmd = SwingCommand {
            turns_per_direction: planning::SWING_TURNS_PER_DIRECTION,
            rate_rad_s: planning::swing_rate_rad_s(self.cfg),
            wheelbase_m: params.wheelbase_m,
            stream_period: Duration::from_millis(self.cfg.telemetry_ms.max(1)),
            noise_std_rad: Some(self.noise.std_rad()).filter(|s| *s > 0.0),
        };
        self.stage(format!(
            "compass swing: two full turns in place each way at {:.2} rad/s (the heading is {kind})",
            cmd.rate_rad_s
        ));
        match cancellable(self.cancel, swing::run_swing(&self.base, &cmd)).await? {
            Ok(fit) => {
                let [a1, b1, a2, b2] = fit.deviation.0.map(f64::to_degrees);
                self.stage(format!(
                    "compass deviation up to {:.2}° (A1 {a1:+.2}°, B1 {b1:+.2}°, A2 {a2:+.2}°, \
                     B2 {b2:+.2}°; residual {:.2}°): removed from every reading from here on \
                     (kept in the report; `odocal swing --save` keeps a curve in a robot profile)",
                    fit.amplitude_rad.to_degrees(),
                    fit.residual_rms_rad.to_degrees()
                ));
                if let Some(advice) = fit.advice() {
                    self.warn(advice);
                }
                self.base.heading = Arc::new(Adjusted::new(
                    self.base.heading.clone(),
                    None,
                    fit.deviation,
                ));
                self.swing = Some(fit);
            }
            Err(swing::NoSwing::Refused(why)) => self.warn(format!(
                "compass swing refused: {why}; going on without a deviation correction"
            )),
            Err(why) => self.warn(format!("no compass swing: {why}")),
        }
        Ok(())
    }

    /// Drive faults, the heading sensor at rest (its validity and noise), the watchdog.
    pub(super) async fn preflight(&mut self) -> Result<(), RoutineError> {
        self.progress.stage = Stage::PreFlight;
        self.stage("pre-flight checks".into());
        let check = cancellable(self.cancel, self.base.drive.preflight()).await?;
        if !check.faults.is_empty() {
            return Err(RoutineError::Preflight(check.faults.join("; ")));
        }
        let readings = match cancellable(
            self.cancel,
            heading::readings_within(
                self.base.heading.as_ref(),
                PREFLIGHT_READINGS.0,
                PREFLIGHT_READINGS.1,
                PREFLIGHT_BUDGET,
            ),
        )
        .await
        {
            Err(RoutineError::Base(BaseError::HeadingInvalid { reason })) => {
                return Err(RoutineError::Preflight(format!(
                    "the heading sensor reports invalid: {reason}"
                )))
            }
            other => other?,
        };
        self.noise = heading::NoisePool::of(&readings);
        self.preflight_noise = self.noise;
        self.stage(format!(
            "heading noise at rest: {:.3}° (σ of {} readings; refined by every rest that follows)",
            self.noise.std_rad().to_degrees(),
            readings.len()
        ));
        let armed = cancellable(
            self.cancel,
            self.base
                .drive
                .arm_watchdog(Duration::from_millis(self.cfg.watchdog_ms)),
        )
        .await?;
        let mut warnings = check.warnings;
        if let Some(w) = gyro_warning(self.base.heading.kind(), self.cfg.gyro_scale_error) {
            warnings.push(w);
        }
        if armed.is_none() {
            warnings.push(
                "the drive has no watchdog: if this host vanishes mid-motion, only the drive's \
                 own limits stop the robot"
                    .into(),
            );
        }
        for w in warnings {
            self.warn(w);
        }
        Ok(())
    }

    /// Adds a square's readings at rest to the noise estimate, unless their spread shows the
    /// robot was still moving (judged against the pre-flight's σ), which is counted instead.
    pub(super) fn pool_rest_noise(&mut self, rec: &SquareRecord) {
        if rec.rest_noise.consistent_with(&self.preflight_noise) {
            self.noise = self.noise.plus(rec.rest_noise);
        } else {
            self.moving_rests += 1;
        }
    }

    /// A calibration round: its squares, every method's estimate, the chosen one and whether
    /// it is within tolerance.
    pub(super) async fn round(
        &mut self,
        round: usize,
        current: &WheelParams,
    ) -> Result<RoundReport, RoutineError> {
        self.stage(format!("round {round}: calibration squares"));
        let phase = Phase::Calibration { round };
        let (runs, stopped) = match self.cfg.target() {
            Some(target) => {
                let (runs, why) = self.drive_until(phase, &target, current).await?;
                (runs, Some(why))
            }
            None => (
                self.drive_runs(phase, self.cfg.runs_per_direction, current)
                    .await?,
                None,
            ),
        };
        for r in &runs {
            self.warnings.extend(r.warnings.iter().cloned());
        }
        let test = square_test(self.cfg, current, &runs, self.noise.std_rad());
        let mut estimates = Vec::new();
        let mut failures = Vec::new();
        for (method, result) in estimate_all(&test, self.cfg.split_convention())? {
            match result {
                Ok(e) => estimates.push(e),
                Err(e) => failures.push((method, e.to_string())),
            }
        }
        let (method, chosen_because) = self.choose(&test);
        let chosen = estimates
            .iter()
            .find(|e| e.method == method)
            .cloned()
            .ok_or_else(|| {
                let why = failures.iter().find(|(m, _)| *m == method).map_or(
                    "it needs data this run did not record".to_string(),
                    |(_, e)| e.clone(),
                );
                RoutineError::Implausible(format!("method {method} gave no estimate: {why}"))
            })?;
        let crb = cramer_rao_std(
            self.cfg,
            &chosen,
            self.noise.std_rad(),
            current.wheelbase_m,
            test.cw.len().min(test.ccw.len()),
        );
        let stopped_because = stopped.map(|why| {
            let text = why.describe(test.cw.len().min(test.ccw.len()));
            match why {
                Stop::Ceiling => self.warn(format!("round {round}: {text}")),
                _ => self.stage(format!("round {round}: {text}")),
            }
            text
        });
        let converged_because = convergence(self.cfg, &chosen, crb, current.wheelbase_m);
        Ok(RoundReport {
            round,
            params_before: *current,
            runs,
            estimates,
            failures,
            chosen,
            chosen_because,
            cramer_rao_std: crb,
            converged: converged_because.is_some(),
            converged_because,
            stopped_because,
            params_after: None,
            written: false,
        })
    }

    /// The method to write and why: the configured one, or the data's default
    /// ([`default_method`]), saying when some runs lacked the heading along the legs.
    pub(super) fn choose(&mut self, test: &SquareTest) -> (Method, String) {
        let m = self.method_for(test);
        if self.cfg.method.is_some() {
            return (
                m,
                "named in the settings (--method or the routine file)".into(),
            );
        }
        let (without, of) = test.runs_without_leg_headings();
        if !matches!(m, Method::Legs | Method::MatchedLegs) {
            self.warn(
                "the heading along the legs was not recorded in any run of one direction: \
                 estimating from the headings at rest (exact), which counts any start transient"
                    .into(),
            );
        } else if without > 0 {
            self.warn(format!(
                "the heading along the legs was not recorded in {without} of {of} runs \
                 (incomplete streams): the leg method uses the other {}",
                of - without
            ));
        }
        (m, default_method_reason(m).into())
    }

    /// The method to write for `test`, without a word (see [`Calibration::choose`]).
    pub(super) fn method_for(&self, test: &SquareTest) -> Method {
        self.cfg.method.unwrap_or_else(|| {
            default_method(
                test.has_leg_headings(),
                test.has_positions(),
                self.base.heading.kind(),
            )
            .unwrap_or(Method::Exact)
        })
    }

    /// **Moves the robot**: turns in place back to the heading the first square started at
    /// (by the heading sensor: a deviation is the same at one azimuth, so the same reading is
    /// the same true heading), so that every square's legs point the same four ways. The first
    /// call notes the heading instead.
    pub(super) async fn realign(&mut self) -> Result<(), RoutineError> {
        if !self.cfg.realign {
            return Ok(());
        }
        let n = self.cfg.heading_samples;
        let now = cancellable(
            self.cancel,
            heading::mean_heading(self.base.heading.as_ref(), n),
        )
        .await?;
        let Some(target) = self.start_heading_rad else {
            self.start_heading_rad = Some(now);
            return Ok(());
        };
        // Twice at most: the second turn takes out what the drive's own error left.
        let mut off = wrap_angle(target - now);
        let mut turned = None;
        let mut turns = 0;
        for _ in 0..2 {
            if off.abs() < REALIGN_WITHIN_RAD {
                break;
            }
            let guard = MotionGuard::new(&self.base.drive);
            cancellable(
                self.cancel,
                self.base.drive.turn_in_place(off, self.cfg.max_rate_rad_s),
            )
            .await?;
            guard.disarm();
            turned = Some(turned.unwrap_or(0.0) + off);
            turns += 1;
            if self.cfg.settle_s > 0.0 {
                tokio::time::sleep(Duration::from_secs_f64(self.cfg.settle_s)).await;
            }
            let now = cancellable(
                self.cancel,
                heading::mean_heading(self.base.heading.as_ref(), n),
            )
            .await?;
            off = wrap_angle(target - now);
        }
        if let Some(turn_rad) = turned {
            self.ui.event(&RoutineEvent::Realigned {
                turn_rad,
                left_rad: off,
                turns,
            });
        }
        Ok(())
    }

    /// **Moves the robot**: `per_direction` squares clockwise, then as many counter-clockwise,
    /// each measured, kept in the progress and checked for plausibility.
    pub(super) async fn drive_runs(
        &mut self,
        phase: Phase,
        per_direction: usize,
        params: &WheelParams,
    ) -> Result<Vec<RunReport>, RoutineError> {
        self.progress.stage = Stage::of(phase);
        let of = per_direction * 2;
        self.ui.event(&RoutineEvent::Plan {
            motions: of as u64 * 8,
            robot_time_s: of as f64 * square_motion_time_s(self.cfg),
        });
        let mut out = Vec::with_capacity(of);
        for direction in [Direction::Cw, Direction::Ccw] {
            for _ in 0..per_direction {
                let run = self
                    .drive_square(phase, direction, out.len() + 1, of, params)
                    .await?;
                out.push(run);
            }
        }
        Ok(out)
    }

    /// **Moves the robot**: one square (after turning back to the first square's heading),
    /// measured, kept in the progress and checked for plausibility; `index` of `of` in its
    /// phase.
    pub(super) async fn drive_square(
        &mut self,
        phase: Phase,
        direction: Direction,
        index: usize,
        of: usize,
        params: &WheelParams,
    ) -> Result<RunReport, RoutineError> {
        let cfg = self.cfg;
        let cmd = SquareCommand {
            side_m: cfg.side_m,
            direction,
            max_speed_m_s: cfg.max_speed_m_s,
            max_rate_rad_s: cfg.max_rate_rad_s,
            heading_samples: cfg.heading_samples,
            settle: Duration::from_secs_f64(cfg.settle_s),
            stream_period: Duration::from_millis(cfg.telemetry_ms.max(1)),
        };
        self.realign().await?;
        let start = self.truth.map(|t| t.pose());
        let rec = {
            let ui = &mut *self.ui;
            let on_motion = move |motion| {
                ui.event(&RoutineEvent::Motion {
                    phase,
                    run: index,
                    of,
                    direction,
                    motion,
                    duration_s: motion_time_s(cfg, motion),
                })
            };
            cancellable(self.cancel, run_square(&self.base, &cmd, on_motion)).await?
        };
        self.pool_rest_noise(&rec);
        let mut run = RunReport::new(phase, &rec, params, start, self.truth);
        if let Some(s) = cfg.gyro_scale_error {
            run.remove_gyro_scale(s, cfg.side_m);
        }
        // Measured is kept, even a square the next check refuses.
        self.progress.runs.push(run.clone());
        check_plausible(&rec, &run, params, self.ui)?;
        self.ui.event(&RoutineEvent::RunDone {
            phase,
            run: index,
            of,
            direction,
            heading_error_deg: run.heading_error_deg,
        });
        Ok(run)
    }
}
