//! The checks no vector can express in device time, run after the rules: a retried motion is
//! answered again and runs once, a retry answered from the cache feeds the watchdog, the device's
//! clock runs at the host's rate, and the stored parameter copy is what it was at the start.

use super::*;

/// §3: a retried motion is answered from the cache and runs once.
pub(super) async fn retried_motion_runs_once<S: AsyncRead + AsyncWrite + Unpin + Send>(
    w: &mut Wire<S>,
    dev: &Device,
) -> Result<Result<(), String>, ConformanceError> {
    let completed = dev.fresh(w).await?;
    // Half a second of driving at the capped speed.
    let request = Request::MoveStraight(MoveStraightRequest {
        distance_um: i32::from(dev.speed_mm_s) * 500,
        max_speed_mm_s: dev.speed_mm_s,
        mode: MotionMode::Queue,
    });
    let bytes = w.frame(request);
    let first = w.exchange(&bytes).await?;
    let again = w.exchange(&bytes).await?;
    let (Some(first), Some(again)) = (first, again) else {
        return Ok(Err("no answer to MOVE_STRAIGHT or to its retry".into()));
    };
    if first.answer.to_bytes() != again.answer.to_bytes() {
        return Ok(Err(format!(
            "the retry was answered {}, the request {} (frames in hex)",
            hex(&again.answer.to_bytes()),
            hex(&first.answer.to_bytes())
        )));
    }
    let mut events = first.events;
    events.extend(again.events);
    events.extend(w.collect(dev.wall(500.0 * 3.0 + 1000.0)).await?);
    let status = w.status().await?;
    let done = motion_done_of(&events);
    if status.completed_motions != completed.wrapping_add(1) || done.len() != 1 {
        return Ok(Err(format!(
            "completed_motions went from {completed} to {} and {} MOTION_DONE came: \
             the retry ran again",
            status.completed_motions,
            done.len()
        )));
    }
    Ok(Ok(()))
}

/// §7.2: a retry answered from the cache feeds the watchdog.
pub(super) async fn retries_feed_the_watchdog<S: AsyncRead + AsyncWrite + Unpin + Send>(
    w: &mut Wire<S>,
    dev: &Device,
) -> Result<Result<(), String>, ConformanceError> {
    const TIMEOUT_MS: u16 = 500;
    const RETRYING: Duration = Duration::from_millis(1500);
    dev.fresh(w).await?;
    let timeout = WatchdogTimeout {
        timeout_ms: TIMEOUT_MS,
    };
    w.ok("CONFIGURE_WATCHDOG", Request::ConfigureWatchdog(timeout))
        .await?;
    // A motion that outlasts the retrying twice over.
    let run_ms = 2.0 * RETRYING.as_secs_f64() * 1e3 * dev.time_scale;
    let request = Request::MoveStraight(MoveStraightRequest {
        distance_um: (f64::from(dev.speed_mm_s) * run_ms) as i32,
        max_speed_mm_s: dev.speed_mm_s,
        mode: MotionMode::Replace,
    });
    w.ok("MOVE_STRAIGHT", request).await?;
    let status = w.frame(Request::GetStatus);
    let until = Instant::now() + RETRYING;
    while Instant::now() < until {
        if w.exchange(&status).await?.is_none() {
            return Ok(Err("no answer to a retried GET_STATUS".into()));
        }
        tokio::time::sleep(Duration::from_millis(u64::from(TIMEOUT_MS) / 10)).await;
    }
    let s = w.status().await?;
    let outcome = if s.watchdog_state == WatchdogState::Tripped {
        Err(format!(
            "the watchdog ({TIMEOUT_MS} ms) tripped while the same GET_STATUS was retried every \
             {} ms",
            TIMEOUT_MS / 10
        ))
    } else if s.motion_state != MotionState::Moving {
        Err(format!(
            "the {run_ms:.0} ms motion ended early: {}",
            s.motion_state
        ))
    } else {
        Ok(())
    };
    w.stop_and_settle().await?;
    Ok(outcome)
}

/// How long [`clock_rate`] watches the device's clock (wall time).
pub(super) const CLOCK_WATCH: Duration = Duration::from_millis(400);

/// The device's clock rate: device milliseconds (STATUS `uptime_ms`) per wall-clock millisecond
/// over [`CLOCK_WATCH`]; 1 for hardware, the speed-up of a simulator, 0 for one in virtual time.
/// Returns the rate and the last uptime.
pub(super) async fn clock_rate<S: AsyncRead + AsyncWrite + Unpin>(
    w: &mut Wire<S>,
) -> Result<(f64, u32), ConformanceError> {
    let t0 = Instant::now();
    let first = w.status().await?.uptime_ms;
    tokio::time::sleep(CLOCK_WATCH).await;
    let last = w.status().await?.uptime_ms;
    let wall_ms = t0.elapsed().as_secs_f64() * 1e3;
    Ok((f64::from(last.wrapping_sub(first)) / wall_ms, last))
}

/// The scale the rules time themselves by: `given` when it agrees with the device's clock rate
/// within 25 %, the measured rate (rounded, in [1, 100]) when none is given; a clock that
/// stands still is [`ConformanceError::ClockStill`].
pub(super) async fn time_scale<S: AsyncRead + AsyncWrite + Unpin>(
    w: &mut Wire<S>,
    given: Option<f64>,
) -> Result<f64, ConformanceError> {
    let (rate, uptime_ms) = clock_rate(w).await?;
    if rate < 0.05 {
        return Err(ConformanceError::ClockStill {
            uptime_ms,
            waited_ms: CLOCK_WATCH.as_millis() as u64,
        });
    }
    let measured = rate.round().clamp(1.0, 100.0);
    match given {
        None => Ok(measured),
        Some(k) if (0.8..=1.25).contains(&(rate / k)) => Ok(k),
        Some(k) => Err(ConformanceError::InvalidArgument(format!(
            "--time-scale {k} was given, but the device's clock runs {rate:.2} times the wall \
             clock: give --time-scale {measured}, or leave it out (it is measured)"
        ))),
    }
}

pub(super) async fn stored<S: AsyncRead + AsyncWrite + Unpin>(
    w: &mut Wire<S>,
) -> Result<Result<Response, Nack>, ConformanceError> {
    let stored = GetParamsRequest {
        source: ParamSource::Stored,
    };
    w.call("GET_PARAMS", Request::GetParams(stored)).await
}
