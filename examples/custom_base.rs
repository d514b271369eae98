//! A robot odocal has no backend for: its [`Drive`], [`HeadingSource`] and [`ParamStore`] over
//! a small line protocol on any byte stream (a serial port, a TCP socket, a pipe), handed to
//! the routine as a [`Base`].
//!
//! The protocol: ASCII lines ending in `\n`; the host sends one line and the robot answers one
//! (or `ERR reason`). Numbers are SI (m, m/s, rad, rad/s, s), headings counter-clockwise
//! positive.
//!
//! | host              | robot                | meaning                                       |
//! |-------------------|----------------------|-----------------------------------------------|
//! | `MOVE d v`        | `OK`                 | start driving d m straight at most v m/s      |
//! | `TURN a w`        | `OK`                 | start turning a rad in place at most w rad/s  |
//! | `STOP`            | `OK`                 | stop now                                      |
//! | `WDG ms`          | `OK`                 | stop by itself when no line comes for ms      |
//! | `ENC?`            | `ENC t l r busy`     | clock, wheel travel since boot (m), 1: moving |
//! | `HDG?`            | `HDG t h`            | the compass's newest reading and its time     |
//! | `GET`, `SAVED?`   | `PAR dl dr b cpr`    | wheel diameters, wheelbase (m), counts/rev    |
//! | `SET dl dr b cpr` | `PAR dl dr b cpr`    | use these parameters (as stored)              |
//! | `SAVE`            | `OK`                 | keep them across restarts                     |
//!
//! `SAVED?` answers `NONE` when nothing was ever saved; `HDG` gives `NaN` for a lost reading.
//!
//! `main` runs the whole routine against a simulated robot speaking the protocol at the other
//! end of an in-memory pipe, in virtual time (tokio's paused clock: seconds of driving take
//! microseconds): `cargo run --example custom_base`. On a robot, open its port instead
//! (`tokio_serial::SerialStream`, `tokio::net::TcpStream`) and use a normal runtime.

use async_trait::async_trait;
use odocal::base::{
    Achieved, Base, BaseError, ComponentInfo, Drive, HeadingKind, HeadingSample, HeadingSource,
    ParamStore, Preflight, SampleStream, TravelSample, Validity,
};
use odocal::kinematics::{SplitConvention, WheelParams};
use odocal::routine::config::{RoutineConfig, WritePolicy};
use odocal::routine::Report;
use odocal::routine::{run, Unattended};
use odocal::sim::{Motion, MotionPlan, NoiseModel, Simulator};
use std::io::{Error as IoError, ErrorKind};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::io::{AsyncBufReadExt, AsyncRead, AsyncWrite, AsyncWriteExt, BufReader};
use tokio::sync::{mpsc, oneshot};
use tokio::time::{sleep, timeout, Instant};
use tokio_util::sync::CancellationToken;

// ---- The host side: what you write for your robot. ----

/// A line out and where its answer goes.
type Request = (String, oneshot::Sender<std::io::Result<String>>);

/// The robot at the other end of a byte stream: drive, compass and parameter store at once.
/// Cheap to clone; all clones share one link, which answers one request at a time.
#[derive(Clone)]
pub struct LineRobot {
    requests: mpsc::Sender<Request>,
    name: String,
    /// The time of the newest heading reading returned (a reading is never returned twice).
    last_heading_s: Arc<Mutex<f64>>,
}

impl LineRobot {
    /// Talks the protocol over `stream` (a task owns it until every clone is dropped).
    pub fn new<S: AsyncRead + AsyncWrite + Send + 'static>(stream: S, name: &str) -> Self {
        let (requests, mut queue) = mpsc::channel::<Request>(64);
        tokio::spawn(async move {
            let (rx, mut tx) = tokio::io::split(stream);
            let mut lines = BufReader::new(rx).lines();
            while let Some((line, answer)) = queue.recv().await {
                let reply = async {
                    tx.write_all(format!("{line}\n").as_bytes()).await?;
                    lines.next_line().await?.ok_or_else(|| {
                        IoError::new(ErrorKind::UnexpectedEof, "the robot closed the link")
                    })
                };
                let reply = timeout(Duration::from_secs(1), reply)
                    .await
                    .unwrap_or_else(|_| Err(IoError::new(ErrorKind::TimedOut, "no answer in 1 s")));
                let _ = answer.send(reply);
            }
        });
        LineRobot {
            requests,
            name: name.into(),
            last_heading_s: Arc::new(Mutex::new(f64::NEG_INFINITY)),
        }
    }

    /// Sends `line`; the robot's answer in words (an `ERR` is a refusal).
    pub async fn exchange(&self, line: &str) -> Result<Vec<String>, BaseError> {
        let link = |e: IoError| BaseError::backend(self.name.clone(), e);
        let closed = || link(IoError::new(ErrorKind::BrokenPipe, "the link task ended"));
        let (answer, reply) = oneshot::channel();
        self.requests
            .send((line.into(), answer))
            .await
            .map_err(|_| closed())?;
        let reply = reply.await.map_err(|_| closed())?.map_err(link)?;
        let words: Vec<String> = reply.split_whitespace().map(str::to_string).collect();
        match words.split_first() {
            Some((err, reason)) if err == "ERR" => Err(BaseError::Refused {
                component: self.name.clone(),
                what: line.into(),
                reason: reason.join(" "),
            }),
            _ => Ok(words),
        }
    }

    /// The `N` numbers of an answer tagged `tag`.
    fn parse<const N: usize>(
        &self,
        words: &[String],
        line: &str,
        tag: &str,
    ) -> Result<[f64; N], BaseError> {
        let numbers = match words.split_first() {
            Some((t, rest)) if t == tag => rest.iter().map(|w| w.parse().ok()).collect(),
            _ => None,
        };
        numbers
            .and_then(|n: Vec<f64>| n.try_into().ok())
            .ok_or_else(|| {
                let why = format!("{words:?} answering {line:?}: expected {tag} and {N} numbers");
                BaseError::backend(self.name.clone(), IoError::new(ErrorKind::InvalidData, why))
            })
    }

    /// Sends `line`; the `N` numbers of its answer tagged `tag`.
    async fn numbers<const N: usize>(&self, line: &str, tag: &str) -> Result<[f64; N], BaseError> {
        let words = self.exchange(line).await?;
        self.parse(&words, line, tag)
    }

    /// Sends `line`, expecting `OK`.
    pub async fn ok(&self, line: &str) -> Result<(), BaseError> {
        self.numbers::<0>(line, "OK").await.map(drop)
    }

    /// `(time, left, right, moving)` from `ENC?`.
    pub async fn encoders(&self) -> Result<(f64, f64, f64, bool), BaseError> {
        let [t, l, r, busy] = self.numbers("ENC?", "ENC").await?;
        Ok((t, l, r, busy != 0.0))
    }

    /// Starts a motion and returns once the robot reports it done (or the time it should
    /// take, twice over, has passed).
    async fn motion(&self, line: String, expected_s: f64) -> Result<Option<Achieved>, BaseError> {
        self.ok(&line).await?;
        let limit = Duration::from_secs_f64(2.0 * expected_s + 2.0);
        let deadline = Instant::now() + limit;
        while self.encoders().await?.3 {
            if Instant::now() > deadline {
                self.emergency_stop();
                return Err(BaseError::MotionTimeout { after: limit });
            }
            sleep(Duration::from_millis(20)).await;
        }
        // The robot counts wheel targets: it executed the motion to its encoders' resolution.
        Ok(None)
    }

    /// `PAR …` as parameters.
    fn params([dl, dr, b, cpr]: [f64; 4]) -> WheelParams {
        WheelParams {
            left_wheel_diameter_m: dl,
            right_wheel_diameter_m: dr,
            wheelbase_m: b,
            counts_per_wheel_rev: cpr,
        }
    }

    /// `HDG?` as a sample (a lost reading is `NaN`, returned as invalid).
    async fn heading(&self) -> Result<HeadingSample, BaseError> {
        let [time_s, heading_rad] = self.numbers("HDG?", "HDG").await?;
        let validity = if heading_rad.is_finite() {
            Validity::Valid
        } else {
            Validity::Invalid("the compass lost this reading".into())
        };
        Ok(HeadingSample {
            time_s,
            heading_rad,
            validity,
        })
    }

    fn info(&self, what: &str) -> ComponentInfo {
        ComponentInfo {
            kind: "line-protocol".into(),
            id: format!("{}-{what}", self.name),
            details: serde_json::Value::Null,
        }
    }
}

#[async_trait]
impl Drive for LineRobot {
    fn info(&self) -> ComponentInfo {
        LineRobot::info(self, "drive")
    }
    async fn preflight(&self) -> Result<Preflight, BaseError> {
        self.encoders().await?;
        Ok(Preflight::default())
    }
    async fn arm_watchdog(&self, timeout: Duration) -> Result<Option<Duration>, BaseError> {
        self.ok(&format!("WDG {}", timeout.as_millis())).await?;
        Ok(Some(timeout))
    }
    async fn move_straight(&self, d: f64, v: f64) -> Result<Option<Achieved>, BaseError> {
        let v = BaseError::check_limit("drive", "speed limit", v)?;
        self.motion(format!("MOVE {d} {v}"), d.abs() / v).await
    }
    async fn turn_in_place(&self, a: f64, w: f64) -> Result<Option<Achieved>, BaseError> {
        let w = BaseError::check_limit("drive", "turn-rate limit", w)?;
        self.motion(format!("TURN {a} {w}"), a.abs() / w).await
    }
    async fn stop(&self) -> Result<(), BaseError> {
        self.ok("STOP").await
    }
    fn emergency_stop(&self) {
        // Queued without waiting (this may run in a destructor); the answer is not awaited.
        let (answer, _) = oneshot::channel();
        let _ = self.requests.try_send(("STOP".into(), answer));
    }
    async fn travel(
        &self,
        period: Duration,
    ) -> Result<Option<SampleStream<TravelSample>>, BaseError> {
        let (tx, rx) = mpsc::channel(odocal::base::STREAM_CAPACITY);
        let robot = self.clone();
        let (_, mut l0, mut r0, _) = self.encoders().await?;
        tokio::spawn(async move {
            while let Ok((time_s, l, r, _)) = robot.encoders().await {
                let sample = TravelSample {
                    time_s,
                    left_m: l - l0,
                    right_m: r - r0,
                };
                (l0, r0) = (l, r);
                if tx.send(sample).await.is_err() {
                    break; // the reader is gone
                }
                sleep(period).await;
            }
        });
        Ok(Some(rx))
    }
    fn clock(&self) -> Option<String> {
        Some(self.name.clone())
    }
}

#[async_trait]
impl HeadingSource for LineRobot {
    fn info(&self) -> ComponentInfo {
        LineRobot::info(self, "compass")
    }
    /// The robot answers with its newest reading, which may be older than this call or
    /// already returned: wait for one stamped later than both.
    async fn read(&self) -> Result<HeadingSample, BaseError> {
        let at_call = self.heading().await?.time_s;
        loop {
            let s = self.heading().await?;
            {
                let mut last = self
                    .last_heading_s
                    .lock()
                    .unwrap_or_else(|p| p.into_inner());
                if s.time_s > at_call && s.time_s > *last {
                    *last = s.time_s;
                    return Ok(s);
                }
            }
            sleep(Duration::from_millis(5)).await;
        }
    }
    async fn stream(
        &self,
        period: Duration,
    ) -> Result<Option<SampleStream<HeadingSample>>, BaseError> {
        let (tx, rx) = mpsc::channel(odocal::base::STREAM_CAPACITY);
        let robot = self.clone();
        tokio::spawn(async move {
            let mut last = f64::NEG_INFINITY;
            while let Ok(s) = robot.heading().await {
                if s.time_s > last {
                    last = s.time_s;
                    if tx.send(s).await.is_err() {
                        break;
                    }
                }
                sleep(period).await;
            }
        });
        Ok(Some(rx))
    }
    fn kind(&self) -> HeadingKind {
        HeadingKind::Magnetic
    }
    fn clock(&self) -> Option<String> {
        Some(self.name.clone())
    }
}

#[async_trait]
impl ParamStore for LineRobot {
    fn info(&self) -> ComponentInfo {
        LineRobot::info(self, "params")
    }
    async fn read(&self) -> Result<WheelParams, BaseError> {
        Ok(Self::params(self.numbers("GET", "PAR").await?))
    }
    async fn write(&self, p: &WheelParams) -> Result<WheelParams, BaseError> {
        let line = format!(
            "SET {} {} {} {}",
            p.left_wheel_diameter_m,
            p.right_wheel_diameter_m,
            p.wheelbase_m,
            p.counts_per_wheel_rev
        );
        Ok(Self::params(self.numbers(&line, "PAR").await?))
    }
    async fn commit(&self) -> Result<(), BaseError> {
        self.ok("SAVE").await
    }
    async fn read_committed(&self) -> Result<Option<WheelParams>, BaseError> {
        let words = self.exchange("SAVED?").await?;
        if words.first().is_some_and(|w| w == "NONE") {
            return Ok(None);
        }
        Ok(Some(Self::params(self.parse(&words, "SAVED?", "PAR")?)))
    }
    fn resolution(&self) -> WheelParams {
        // Numbers travel in Rust's shortest round-trip form: nothing is lost.
        WheelParams::nominal(1e-12, 1e-12, 1e-9)
    }
}

// ---- The other end: a simulated robot speaking the protocol (yours is firmware). ----

/// A motion under way: its plan, when it started, how long it takes, how much is done.
struct Moving {
    plan: MotionPlan,
    start_s: f64,
    duration_s: f64,
    done: f64,
}

/// The simulated robot's state.
struct Robot {
    sim: Arc<Mutex<Simulator>>,
    boot: Instant,
    moving: Option<Moving>,
    watchdog_s: Option<f64>,
    last_line_s: f64,
    wheels_m: (f64, f64),
    saved: Option<WheelParams>,
    /// The compass reads at 50 Hz: the newest reading's index and value.
    reading: (i64, f64),
}

/// The compass's rate (Hz).
const COMPASS_HZ: f64 = 50.0;

impl Robot {
    /// Moves the simulated robot on to `now_s`: the motion under way, stopped by the watchdog
    /// when the host fell silent.
    fn catch_up(&mut self, now_s: f64) {
        let mut sim = self.sim.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(m) = &mut self.moving {
            let silent = self
                .watchdog_s
                .map_or(f64::INFINITY, |w| self.last_line_s + w);
            let until = now_s.min(silent);
            let to = ((until - m.start_s) / m.duration_s).clamp(0.0, 1.0);
            sim.advance_plan(&m.plan, m.done, to);
            let cfg = *sim.configured();
            let f = to - m.done;
            self.wheels_m.0 += f * m.plan.left_counts * cfg.left_m_per_count();
            self.wheels_m.1 += f * m.plan.right_counts * cfg.right_m_per_count();
            m.done = to;
            if to >= 1.0 || until < now_s {
                self.moving = None;
            }
        }
        let k = (now_s * COMPASS_HZ).floor() as i64;
        if k != self.reading.0 {
            sim.set_time(k as f64 / COMPASS_HZ);
            self.reading = (k, sim.heading_reading().unwrap_or(f64::NAN));
        }
    }

    /// The answer to one line.
    fn answer(&mut self, line: &str) -> String {
        let now = self.boot.elapsed().as_secs_f64();
        self.catch_up(now);
        self.last_line_s = now;
        let mut words = line.split_whitespace();
        let cmd = words.next().unwrap_or("");
        let args: Vec<f64> = words.filter_map(|w| w.parse().ok()).collect();
        let par = |p: &WheelParams| {
            format!(
                "PAR {} {} {} {}",
                p.left_wheel_diameter_m,
                p.right_wheel_diameter_m,
                p.wheelbase_m,
                p.counts_per_wheel_rev
            )
        };
        let mut sim = self.sim.lock().unwrap_or_else(|p| p.into_inner());
        match (cmd, args.as_slice()) {
            ("MOVE" | "TURN", _) if self.moving.is_some() => "ERR busy".into(),
            ("MOVE" | "TURN", &[size, max]) if size.is_finite() && max > 0.0 => {
                let motion = if cmd == "MOVE" {
                    Motion::Straight { distance_m: size }
                } else {
                    Motion::TurnInPlace { angle_rad: size }
                };
                match sim.plan(&motion) {
                    Ok(plan) => {
                        let duration_s = (size.abs() / max).max(1e-3);
                        self.moving = Some(Moving {
                            plan,
                            start_s: now,
                            duration_s,
                            done: 0.0,
                        });
                        "OK".into()
                    }
                    Err(e) => format!("ERR {e}"),
                }
            }
            ("STOP", []) => {
                self.moving = None;
                "OK".into()
            }
            ("WDG", &[ms]) if ms > 0.0 => {
                self.watchdog_s = Some(ms / 1000.0);
                "OK".into()
            }
            ("ENC?", []) => {
                let busy = u8::from(self.moving.is_some());
                format!("ENC {now} {} {} {busy}", self.wheels_m.0, self.wheels_m.1)
            }
            ("HDG?", []) => format!(
                "HDG {} {}",
                self.reading.0 as f64 / COMPASS_HZ,
                self.reading.1
            ),
            ("GET", []) => par(sim.configured()),
            ("SAVED?", []) => self.saved.as_ref().map_or("NONE".into(), par),
            ("SET", &[dl, dr, b, cpr]) => {
                let p = LineRobot::params([dl, dr, b, cpr]);
                match sim.set_configured(p) {
                    Ok(()) => par(&p),
                    Err(e) => format!("ERR {e}"),
                }
            }
            ("SAVE", []) => {
                self.saved = Some(*sim.configured());
                "OK".into()
            }
            _ => format!("ERR unknown request {line:?}"),
        }
    }
}

/// Serves `sim` over `stream` until the host hangs up.
pub async fn serve<S: AsyncRead + AsyncWrite + Send + 'static>(
    stream: S,
    sim: Arc<Mutex<Simulator>>,
) -> std::io::Result<()> {
    let saved = Some(*sim.lock().unwrap_or_else(|p| p.into_inner()).configured());
    let mut robot = Robot {
        sim,
        boot: Instant::now(),
        moving: None,
        watchdog_s: None,
        last_line_s: 0.0,
        wheels_m: (0.0, 0.0),
        saved,
        reading: (-1, f64::NAN),
    };
    let (rx, mut tx) = tokio::io::split(stream);
    let mut lines = BufReader::new(rx).lines();
    while let Some(line) = lines.next_line().await? {
        let answer = robot.answer(&line);
        tx.write_all(format!("{answer}\n").as_bytes()).await?;
    }
    Ok(())
}

/// A simulated robot (truly `E_b` 0.976, `E_d` 0.992, compass σ 0.3°) served on one end of an
/// in-memory pipe, and the routine run on the other through [`LineRobot`]; returns the report
/// and the simulator (to compare with its truth).
pub async fn calibrate_simulated_robot(
    seed: u64,
) -> Result<(Report, Arc<Mutex<Simulator>>), Box<dyn std::error::Error>> {
    let nominal = WheelParams::nominal(0.15, 0.39, 4096.0);
    let truth = WheelParams::from_ratios(&nominal, 0.976, 0.992, &SplitConvention::LeftNominal)?;
    let noise = NoiseModel {
        compass_sigma_rad: 0.3f64.to_radians(),
        ..NoiseModel::default()
    };
    let sim = Arc::new(Mutex::new(Simulator::new(truth, nominal, noise, seed)?));
    let (host_end, robot_end) = tokio::io::duplex(4096);
    tokio::spawn(serve(robot_end, sim.clone()));

    // The part that is about odocal: a base of the robot's three roles, the routine on it.
    let robot = LineRobot::new(host_end, "line-robot");
    let base = Base::new(
        Arc::new(robot.clone()),
        Arc::new(robot.clone()),
        Arc::new(robot),
    );
    let dir =
        std::env::temp_dir().join(format!("odocal-custom-base-{}-{seed}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let cfg = RoutineConfig {
        side_m: 1.0,
        runs_per_direction: 3,
        verification_runs: 2,
        max_speed_m_s: 0.5,
        max_rate_rad_s: 1.0,
        telemetry_ms: 50,
        write_back: WritePolicy::Yes,
        confirm_motion: false,
        backup_dir: Some(dir.clone()),
        ..RoutineConfig::default()
    };
    let report = run(
        &base,
        &cfg,
        None,
        &mut Unattended,
        &CancellationToken::new(),
    )
    .await?;
    std::fs::remove_dir_all(&dir)?;
    Ok((report, sim))
}

#[tokio::main(flavor = "current_thread", start_paused = true)]
async fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (report, sim) = calibrate_simulated_robot(1).await?;
    print!("{}", odocal::report::summary_table(&report));
    let sim = sim.lock().unwrap_or_else(|p| p.into_inner());
    let (done, truth) = (sim.configured(), sim.truth());
    println!(
        "the robot now uses wheelbase {:.4} m (truly {:.4} m), right wheel {:.5} m (truly {:.5} m)",
        done.wheelbase_m,
        truth.wheelbase_m,
        done.right_wheel_diameter_m,
        truth.right_wheel_diameter_m
    );
    Ok(())
}
