//! Where a rule's steps run: a device over a port in real time ([`Live`]) or the device kit in
//! process with its clock held ([`Clocked`]), and the rule runner over either.

use super::*;

/// A device the rules' steps run against: over a port in real time ([`Live`]), or in
/// process with its clock held ([`Clocked`]).
#[async_trait::async_trait]
pub(super) trait Target {
    /// Sends a vector's request; with `until_idle`, device time then runs until the base is
    /// idle. The answer and the events that came before it; `Err` is why there is none.
    async fn send(&mut self, frame: &Frame, until_idle: bool) -> Result<Exchange, String>;
    /// `ms` of device time pass with the host silent; the events sent meanwhile (with
    /// `late`, also those that arrive a little after: their timestamps say when they were
    /// taken).
    async fn advance(&mut self, ms: u64, late: bool) -> Result<Vec<Frame>, String>;
}

/// A device on a port, in real time, its requests adapted ([`Device::adapt`]).
pub(super) struct Live<'a, S> {
    pub(super) w: &'a mut Wire<S>,
    pub(super) dev: &'a Device,
}

#[async_trait::async_trait]
impl<S: AsyncRead + AsyncWrite + Unpin + Send> Target for Live<'_, S> {
    async fn send(&mut self, frame: &Frame, until_idle: bool) -> Result<Exchange, String> {
        let what = message_name(frame.msg);
        let sent = self.dev.adapt(frame, until_idle);
        let io = |e: std::io::Error| format!("the link failed: {e}");
        let ex = self
            .w
            .exchange(&sent.bytes)
            .await
            .map_err(io)?
            .ok_or_else(|| format!("no answer to {what}"))?;
        let accepted_motion = ex.answer.kind == FrameKind::Response
            && matches!(
                ex.answer.msg,
                id::MOVE_STRAIGHT | id::TURN_IN_PLACE | id::WHEEL_SPEED
            );
        if !(until_idle && accepted_motion) {
            return Ok(ex);
        }
        if sent.stop_at_once {
            self.w.stop_and_settle().await.map_err(|e| e.to_string())?;
            return Ok(ex);
        }
        // "Until idle", the host present: the status polled until the base is idle.
        let limit = self.dev.wall(sent.expected_ms * 1.5 + 2000.0) + Duration::from_secs(1);
        let until = Instant::now() + limit;
        loop {
            tokio::time::sleep(STATUS_POLL).await;
            let s = self.w.status().await.map_err(|e| e.to_string())?;
            if s.motion_state == MotionState::Idle && s.queue_depth == 0 {
                return Ok(ex);
            }
            if Instant::now() > until {
                return Err(format!(
                    "{what} accepted but the base is still {} after {:.1} s",
                    s.motion_state,
                    limit.as_secs_f64()
                ));
            }
        }
    }

    async fn advance(&mut self, ms: u64, late: bool) -> Result<Vec<Frame>, String> {
        // A busy host or link delivers telemetry late, not less of it.
        let grace = if late { LATE_EVENTS } else { Duration::ZERO };
        let wait = self.dev.wall(ms as f64) + grace;
        self.w
            .collect(wait)
            .await
            .map_err(|e| format!("the link failed: {e}"))
    }
}

/// A device built on the kit, in process, its clock held by the harness (the clock hook of
/// SPEC.md §7): its board's clock moves only when a step says.
pub struct Clocked<B, S>(pub KitDevice<B, S>);

#[async_trait::async_trait]
impl<B, S> Target for Clocked<B, S>
where
    B: SimulatedBoard + Send,
    S: ParamStorage + Send,
{
    async fn send(&mut self, frame: &Frame, until_idle: bool) -> Result<Exchange, String> {
        let d = &mut self.0;
        let mut out = VecSink::default();
        d.handle_frame(frame, &mut out);
        let at = out
            .frames
            .iter()
            .position(|f| f.kind != FrameKind::Event)
            .ok_or_else(|| format!("no answer to {}", message_name(frame.msg)))?;
        let answer = out.frames.remove(at);
        if until_idle {
            // The host waits for the base: it counts as present, the watchdog cannot trip.
            d.hold_watchdog(true);
            while d.is_moving() {
                let now = d.board_mut().now_us();
                let Some(left) = d.remaining_us(now) else {
                    return Err("an open-ended WHEEL_SPEED never becomes idle".into());
                };
                d.advance_to(now + left.max(1), &mut VecSink::default());
            }
            d.hold_watchdog(false);
        }
        Ok(Exchange {
            events: out.frames,
            answer,
        })
    }

    async fn advance(&mut self, ms: u64, _late: bool) -> Result<Vec<Frame>, String> {
        let d = &mut self.0;
        let mut out = VecSink::default();
        let now = d.board_mut().now_us();
        d.advance_to(now + ms * 1000, &mut out);
        Ok(out.frames)
    }
}

/// Runs one rule's steps; `Err` is why it failed.
pub(super) async fn run_steps(
    target: &mut (dyn Target + Send),
    steps: &[Value],
    c: &mut Counters,
) -> Result<(), String> {
    for (i, step) in steps.iter().enumerate() {
        let at = |why: String| format!("step {}: {why}", i + 1);
        if let Some(ms) = step["advance_ms"].as_u64() {
            let min = step["telemetry_min"].as_u64();
            let events = target.advance(ms, min.is_some()).await.map_err(at)?;
            check_motion_done(&events, step, c).map_err(at)?;
            if let Some(min) = min {
                let n = telemetry_within(&events, ms * 1000) as u64;
                if n < min {
                    return Err(at(format!(
                        "{n} TELEMETRY samples in {ms} ms, expected {min}"
                    )));
                }
            }
            continue;
        }
        // `[request, answer]` runs until idle; `send` does not; `repeat` sends a cycle.
        let (requests, want, until_idle) = match (step.as_array(), step["repeat"].as_u64()) {
            (Some(_), _) => (vec![request_of(step).clone()], answer_of(step), true),
            (None, Some(n)) => {
                let cycle = step["send_cycle"].as_array().cloned().unwrap_or_default();
                let all = cycle.iter().cycle().take(n as usize).cloned().collect();
                (all, &step["answer"], true)
            }
            (None, None) => (vec![step["send"].clone()], &step["answer"], false),
        };
        for hex in &requests {
            let hex = hex
                .as_str()
                .ok_or_else(|| at(format!("unknown step {step}")))?;
            let frame = vector_frame(hex).map_err(&at)?;
            let ex = target.send(&frame, until_idle).await.map_err(&at)?;
            let what = message_name(frame.msg);
            check_answer(&ex.answer, want, c).map_err(|e| at(format!("{what} {e}")))?;
            check_motion_done(&ex.events, step, c).map_err(&at)?;
        }
    }
    Ok(())
}

/// A rule's section, its text, and its steps.
pub(super) fn rule_parts(rule: &Value) -> (RuleResult, &[Value]) {
    let name = rule["name"].as_str().unwrap_or("");
    let (section, text) = name.split_once(' ').unwrap_or((name, ""));
    let result = RuleResult {
        section: section.to_string(),
        rule: text.to_string(),
        outcome: Outcome::Skip,
        reason: None,
    };
    (result, rule["steps"].as_array().map_or(&[], Vec::as_slice))
}

/// Runs one vector rule in real time.
pub(super) async fn run_rule<S: AsyncRead + AsyncWrite + Unpin + Send>(
    w: &mut Wire<S>,
    dev: &Device,
    rule: &Value,
    saved_copy: bool,
) -> Result<RuleResult, ConformanceError> {
    let (mut result, steps) = rule_parts(rule);
    if let Some(n) = steps.iter().find_map(|s| s["repeat"].as_u64()) {
        result.reason = Some(format!(
            "needs the clock hook: {n} motions in a row (run the vectors against the device \
             with its clock held, SPEC.md §7)"
        ));
        return Ok(result);
    }
    if let Some(why) = missing_capability(steps, dev.info.capabilities) {
        result.reason = Some(why);
        return Ok(result);
    }
    if saved_copy && needs_nothing_saved(steps) {
        result.reason = Some(
            "the device holds a saved parameter copy; the rule needs one that never saved".into(),
        );
        return Ok(result);
    }
    let completed = dev.fresh(w).await?;
    let mut counters = Counters {
        id_offset: None,
        completed,
    };
    let outcome = run_steps(&mut Live { w, dev }, steps, &mut counters).await;
    result.set(outcome);
    w.stop_and_settle().await?;
    Ok(result)
}

impl RuleResult {
    pub(super) fn set(&mut self, outcome: Result<(), String>) {
        match outcome {
            Ok(()) => self.outcome = Outcome::Pass,
            Err(why) => {
                self.outcome = Outcome::Fail;
                self.reason = Some(why);
            }
        }
    }
}

/// Runs every rule of the vectors, each against a freshly powered-up device from `power_up`
/// with its clock held (SPEC.md §7's harness): nothing is adapted or skipped, ids and counts
/// are checked as written.
pub async fn run_clocked<B, S>(
    mut power_up: impl FnMut() -> KitDevice<B, S>,
) -> Result<Vec<RuleResult>, ConformanceError>
where
    B: SimulatedBoard + Send,
    S: ParamStorage + Send,
{
    let mut results = Vec::new();
    for rule in device_rules()?.iter() {
        let (mut result, steps) = rule_parts(rule);
        let mut counters = Counters {
            id_offset: Some(0),
            completed: 0,
        };
        let mut target = Clocked(power_up());
        result.set(run_steps(&mut target, steps, &mut counters).await);
        results.push(result);
    }
    Ok(results)
}

/// The vectors' device rules.
pub(super) fn device_rules() -> Result<Vec<Value>, ConformanceError> {
    let mut vectors: Value =
        serde_json::from_str(VECTORS).map_err(|e| ConformanceError::Vectors(e.to_string()))?;
    match vectors["device_rules"].take() {
        Value::Array(rules) => Ok(rules),
        _ => Err(ConformanceError::Vectors("no device_rules".into())),
    }
}
