//! A simulated robot behind the seam, in process: no protocol, no pseudo-terminal, virtual
//! time. The same [`Simulator`] as the mock device, driven directly, so the routine can be
//! tested end to end in microseconds and its failure paths provoked on purpose.

use crate::base::{
    Achieved, BaseError, ComponentInfo, Drive, Fanout, GroundTruth, HeadingSample, HeadingSource,
    ParamStore, Preflight, SampleStream, TravelSample, Validity,
};
use crate::kinematics::{Pose, WheelParams};
use crate::sim::{Motion, SimError, Simulator};
use async_trait::async_trait;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

/// Failures a test can ask the simulated base for.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SimFaults {
    /// Every motion after this many completed ones fails (the drive "vanishes").
    pub fail_after_motions: Option<u64>,
    /// Every commit fails with an I/O error (it is unknown whether it happened).
    pub commit_fails: bool,
    /// The heading source reports invalid readings.
    pub heading_invalid: bool,
}

/// What a test can read back from the simulated base.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SimCounters {
    /// Motions completed.
    pub motions: u64,
    /// Stops asked for (`stop` and `emergency_stop`).
    pub stops: u64,
    /// Parameter writes.
    pub writes: u64,
    /// Commits.
    pub commits: u64,
}

struct State {
    sim: Simulator,
    time_s: f64,
    committed: Option<WheelParams>,
    faults: SimFaults,
    counters: SimCounters,
    travel: Fanout<TravelSample>,
    headings: Fanout<HeadingSample>,
    period_s: f64,
}

/// A simulated base: drive, heading source and parameter store at once. Cheap to clone; all
/// clones share one robot.
#[derive(Clone)]
pub struct SimBase {
    state: Arc<Mutex<State>>,
}

#[derive(Debug, thiserror::Error)]
#[error("simulated fault: {0}")]
struct SimFault(&'static str);

impl SimBase {
    /// A base around `sim` whose parameters were committed as configured.
    pub fn new(sim: Simulator) -> Self {
        let committed = Some(*sim.configured());
        SimBase {
            state: Arc::new(Mutex::new(State {
                sim,
                time_s: 0.0,
                committed,
                faults: SimFaults::default(),
                counters: SimCounters::default(),
                travel: Fanout::default(),
                headings: Fanout::default(),
                period_s: 0.02,
            })),
        }
    }

    fn state(&self) -> MutexGuard<'_, State> {
        // A panic elsewhere leaves the simulation usable for observers.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Sets the failures to simulate from now on.
    pub fn set_faults(&self, faults: SimFaults) {
        self.state().faults = faults;
    }

    /// What happened so far.
    pub fn counters(&self) -> SimCounters {
        self.state().counters
    }

    /// Robot time so far (s): every motion's duration at its speed limit (the simulation's
    /// clock; pauses at rest take none).
    pub fn time_s(&self) -> f64 {
        self.state().time_s
    }

    /// The parameters the simulated controller uses now.
    pub fn configured(&self) -> WheelParams {
        *self.state().sim.configured()
    }

    /// The committed copy.
    pub fn committed(&self) -> Option<WheelParams> {
        self.state().committed
    }

    /// Runs `f` on the simulator (to place the robot, read its truth).
    pub fn with_sim<T>(&self, f: impl FnOnce(&mut Simulator) -> T) -> T {
        f(&mut self.state().sim)
    }

    async fn execute(&self, motion: Motion, duration_s: f64) -> Result<(), BaseError> {
        let steps = {
            let st = self.state();
            if let Some(n) = st.faults.fail_after_motions {
                if st.counters.motions >= n {
                    return Err(BaseError::backend("drive", SimFault("the drive vanished")));
                }
            }
            (duration_s / st.period_s).ceil().clamp(1.0, 1e6) as u32
        };
        let plan = self
            .state()
            .sim
            .plan(&motion)
            .map_err(|e| BaseError::InvalidArgument {
                component: "drive".into(),
                reason: e.to_string(),
            })?;
        for k in 0..steps {
            {
                let mut st = self.state();
                let (from, to) = (
                    f64::from(k) / f64::from(steps),
                    f64::from(k + 1) / f64::from(steps),
                );
                st.time_s += duration_s / f64::from(steps);
                let now = st.time_s;
                st.sim.set_time(now);
                st.sim.advance_plan(&plan, from, to);
                let cfg = *st.sim.configured();
                let f = to - from;
                let travel = TravelSample {
                    time_s: st.time_s,
                    left_m: f * plan.left_counts * cfg.left_m_per_count(),
                    right_m: f * plan.right_counts * cfg.right_m_per_count(),
                };
                let heading = reading(&mut st);
                st.travel.send(&travel);
                st.headings.send(&heading);
            }
            // Let a cancellation (Ctrl-C in a test) land mid-motion, as it would on hardware.
            tokio::task::yield_now().await;
        }
        self.state().counters.motions += 1;
        Ok(())
    }
}

/// A heading reading now: invalid when the faults say so or the sensor lost it.
fn reading(st: &mut State) -> HeadingSample {
    let now = st.time_s;
    st.sim.set_time(now);
    let validity = heading_validity(&st.faults);
    match st.sim.heading_reading() {
        Some(h) => HeadingSample {
            time_s: now,
            heading_rad: h,
            validity,
        },
        None => HeadingSample {
            time_s: now,
            heading_rad: f64::NAN,
            validity: Validity::Invalid("the sensor lost this reading".into()),
        },
    }
}

fn heading_validity(faults: &SimFaults) -> Validity {
    if faults.heading_invalid {
        Validity::Invalid("simulated sensor fault".into())
    } else {
        Validity::Valid
    }
}

fn info(what: &str) -> ComponentInfo {
    ComponentInfo {
        kind: "simulated".into(),
        id: format!("in-process-{what}"),
        details: serde_json::Value::Null,
    }
}

#[async_trait]
impl Drive for SimBase {
    fn info(&self) -> ComponentInfo {
        info("drive")
    }

    fn rounds_to_counts(&self) -> bool {
        self.state().sim.noise().quantise_encoders
    }

    async fn preflight(&self) -> Result<Preflight, BaseError> {
        Ok(Preflight::default())
    }

    async fn arm_watchdog(&self, timeout: Duration) -> Result<Option<Duration>, BaseError> {
        // Nothing can vanish in process; say the timer was set so the routine does not warn.
        Ok(Some(timeout))
    }

    async fn move_straight(
        &self,
        distance_m: f64,
        max_speed_m_s: f64,
    ) -> Result<Option<Achieved>, BaseError> {
        BaseError::check_limit("drive", "speed limit", max_speed_m_s)?;
        let duration = distance_m.abs() / max_speed_m_s;
        self.execute(Motion::Straight { distance_m }, duration)
            .await?;
        Ok(None)
    }

    async fn turn_in_place(
        &self,
        angle_rad: f64,
        max_rate_rad_s: f64,
    ) -> Result<Option<Achieved>, BaseError> {
        BaseError::check_limit("drive", "turn-rate limit", max_rate_rad_s)?;
        let duration = angle_rad.abs() / max_rate_rad_s;
        self.execute(Motion::TurnInPlace { angle_rad }, duration)
            .await?;
        Ok(None)
    }

    async fn stop(&self) -> Result<(), BaseError> {
        self.state().counters.stops += 1;
        Ok(())
    }

    fn emergency_stop(&self) {
        self.state().counters.stops += 1;
    }

    async fn travel(
        &self,
        period: Duration,
    ) -> Result<Option<SampleStream<TravelSample>>, BaseError> {
        let mut st = self.state();
        st.period_s = period.as_secs_f64().max(1e-3);
        Ok(Some(st.travel.subscribe()))
    }

    fn clock(&self) -> Option<String> {
        Some(SIM_CLOCK.into())
    }
}

#[async_trait]
impl HeadingSource for SimBase {
    fn info(&self) -> ComponentInfo {
        info("heading")
    }

    async fn read(&self) -> Result<HeadingSample, BaseError> {
        Ok(reading(&mut self.state()))
    }

    async fn stream(
        &self,
        period: Duration,
    ) -> Result<Option<SampleStream<HeadingSample>>, BaseError> {
        let mut st = self.state();
        st.period_s = period.as_secs_f64().max(1e-3);
        Ok(Some(st.headings.subscribe()))
    }

    fn kind(&self) -> crate::base::HeadingKind {
        super::heading_kind(self.state().sim.heading_model())
    }

    fn clock(&self) -> Option<String> {
        Some(SIM_CLOCK.into())
    }
}

/// The simulation's clock, on which both streams are stamped.
const SIM_CLOCK: &str = "simulation";

#[async_trait]
impl ParamStore for SimBase {
    fn info(&self) -> ComponentInfo {
        info("store")
    }

    async fn read(&self) -> Result<WheelParams, BaseError> {
        Ok(*self.state().sim.configured())
    }

    async fn write(&self, params: &WheelParams) -> Result<WheelParams, BaseError> {
        let mut st = self.state();
        st.sim
            .set_configured(*params)
            .map_err(|e: SimError| BaseError::Refused {
                component: "store".into(),
                what: "the parameters".into(),
                reason: e.to_string(),
            })?;
        st.counters.writes += 1;
        Ok(*params)
    }

    async fn commit(&self) -> Result<(), BaseError> {
        let mut st = self.state();
        if st.faults.commit_fails {
            return Err(BaseError::backend("store", SimFault("the commit was lost")));
        }
        st.committed = Some(*st.sim.configured());
        st.counters.commits += 1;
        Ok(())
    }

    async fn read_committed(&self) -> Result<Option<WheelParams>, BaseError> {
        Ok(self.state().committed)
    }

    fn resolution(&self) -> WheelParams {
        WheelParams {
            left_wheel_diameter_m: 0.0,
            right_wheel_diameter_m: 0.0,
            wheelbase_m: 0.0,
            counts_per_wheel_rev: 0.0,
        }
    }
}

impl GroundTruth for SimBase {
    fn pose(&self) -> Pose {
        self.state().sim.pose()
    }

    fn true_params(&self) -> WheelParams {
        *self.state().sim.truth()
    }
}
