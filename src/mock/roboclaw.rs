//! A mock RoboClaw and a mock NMEA compass backed by **one** simulated robot: the controller's
//! packet serial (CRC, acknowledgements, the buffered distance command, buffer status, the
//! serial timeout) drives the true robot's wheels; the compass reports its true heading with
//! noise as `$--HDT` sentences. Each serves any byte stream: an in-memory duplex or a real
//! pseudo-terminal.
//!
//! Faults: lost acknowledgements (the command executed, the `0xFF` never sent), lost bytes of
//! answers, a brown-out (encoders reset, motors stopped), occasional bad compass checksums.

use super::nmea::{HeadingFn, MockCompassConfig};
use super::pty::{spawn_on_pty, PtyServer};
use crate::kinematics::{Pose, WheelParams};
use crate::roboclaw::packet::{be_u32, cmd, ACK, BUFFER_IDLE, CRC16};
use crate::sim::sensor::HeadingModel;
use crate::sim::{NoiseModel, Simulator};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::time::Instant;

/// How the simulated robot is built and wired.
#[derive(Debug, Clone)]
pub struct MockRoboClawConfig {
    /// Packet serial address.
    pub address: u8,
    /// The robot's true parameters (counts per wheel revolution = encoder counts × gearing).
    pub truth: WheelParams,
    /// Which channel drives the left wheel.
    pub left_on_m1: bool,
    /// +1 when the left encoder counts up driving forward.
    pub left_encoder_sign: i8,
    /// The same for the right encoder.
    pub right_encoder_sign: i8,
    /// Compass noise and bias.
    pub noise: NoiseModel,
    /// How the compass errs (deviation, the motors' field, latency, loss…).
    pub heading_model: HeadingModel,
    /// Seed of every draw.
    pub seed: u64,
    /// Robot seconds per wall-clock second.
    pub time_scale: f64,
    /// Firmware version string.
    pub version: String,
    /// Main battery (V).
    pub battery_v: f64,
    /// Probability that a write's acknowledgement is lost (the write executes).
    pub lose_ack_rate: f64,
    /// Probability that a read's answer is lost on the line.
    pub lose_answer_rate: f64,
    /// Compass sentences per second of robot time.
    pub compass_hz: f64,
    /// Compass talker id.
    pub compass_talker: String,
    /// Probability of a compass sentence with a wrong checksum.
    pub bad_checksum_rate: f64,
}

impl MockRoboClawConfig {
    /// A robot whose true geometry is `truth`, wired straight (left on M1, encoders forward).
    pub fn new(truth: WheelParams) -> Self {
        MockRoboClawConfig {
            address: 0x80,
            truth,
            left_on_m1: true,
            left_encoder_sign: 1,
            right_encoder_sign: 1,
            noise: NoiseModel::default(),
            heading_model: HeadingModel::default(),
            seed: 1,
            time_scale: 1.0,
            version: "USB Roboclaw 2x7a v4.2.8\n".into(),
            battery_v: 12.3,
            lose_ack_rate: 0.0,
            lose_answer_rate: 0.0,
            compass_hz: 10.0,
            compass_talker: "HC".into(),
            bad_checksum_rate: 0.0,
        }
    }
}

/// One motor channel's motion.
#[derive(Debug, Clone, Copy, Default)]
struct Motor {
    /// Encoder counter (its own sign convention).
    counter: f64,
    /// Speed (counts/s, signed).
    speed: f64,
    /// Commanded speed magnitude (counts/s).
    target_speed: f64,
    /// Direction of the command (±1).
    direction: f64,
    /// Counts still to go.
    remaining: f64,
    /// Acceleration (counts/s²).
    accel: f64,
    /// Whether a command runs.
    busy: bool,
}

/// What a test can read back.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RoboClawCounters {
    /// Distance commands executed.
    pub drive_commands: u64,
    /// Stop commands executed.
    pub stops: u64,
    /// Serial timeouts that stopped the motors.
    pub serial_timeouts: u64,
    /// Acknowledgements deliberately lost.
    pub lost_acks: u64,
    /// Packets refused for a bad CRC.
    pub bad_crcs: u64,
    /// Read answers deliberately lost.
    pub lost_answers: u64,
}

/// The shared robot.
pub struct MockRobot {
    cfg: MockRoboClawConfig,
    sim: Simulator,
    motors: [Motor; 2],
    serial_timeout: Option<Duration>,
    last_packet: Instant,
    rng: ChaCha8Rng,
    /// Robot time (s).
    pub time_s: f64,
    /// Counters.
    pub counters: RoboClawCounters,
}

/// A robot shared by the controller's and the compass's servers.
pub type SharedRobot = Arc<Mutex<MockRobot>>;

/// Locks the shared robot (poisoning ignored: observers still read it).
pub fn robot(r: &SharedRobot) -> MutexGuard<'_, MockRobot> {
    r.lock().unwrap_or_else(|p| p.into_inner())
}

impl MockRobot {
    /// The true pose.
    pub fn pose(&self) -> Pose {
        self.sim.pose()
    }

    /// The true parameters.
    pub fn truth(&self) -> WheelParams {
        *self.sim.truth()
    }

    /// Whether a motor turns.
    pub fn moving(&self) -> bool {
        self.motors.iter().any(|m| m.speed != 0.0 || m.busy)
    }

    /// A brown-out: the controller resets (encoders zero, motors stopped, timeout off).
    pub fn brown_out(&mut self) {
        self.motors = [Motor::default(); 2];
        self.serial_timeout = None;
    }

    fn stop(&mut self) {
        for m in &mut self.motors {
            m.speed = 0.0;
            m.remaining = 0.0;
            m.busy = false;
        }
    }

    /// Advances robot time by `dt` seconds.
    fn advance(&mut self, dt: f64) {
        if let Some(t) = self.serial_timeout {
            if self.last_packet.elapsed() > t && self.moving() {
                self.stop();
                self.counters.serial_timeouts += 1;
            }
        }
        let mut wheel = [0.0; 2];
        for (i, m) in self.motors.iter_mut().enumerate() {
            if !m.busy {
                continue;
            }
            // Trapezoid: accelerate to the target speed, brake to stop on the distance.
            let v = m.speed.abs();
            let brake = (2.0 * m.accel * m.remaining).sqrt();
            let v1 = (v + m.accel * dt).min(m.target_speed).min(brake).max(0.0);
            let step = (0.5 * (v + v1) * dt).min(m.remaining);
            m.remaining -= step;
            m.counter += m.direction * step;
            m.speed = m.direction * v1;
            wheel[i] = m.direction * step;
            if m.remaining <= 1e-9 {
                m.remaining = 0.0;
                m.speed = 0.0;
                m.busy = false;
            }
        }
        // Channels to wheels, encoder counts to forward rotation.
        let (l, r) = if self.cfg.left_on_m1 {
            (wheel[0], wheel[1])
        } else {
            (wheel[1], wheel[0])
        };
        let l = l * f64::from(self.cfg.left_encoder_sign);
        let r = r * f64::from(self.cfg.right_encoder_sign);
        self.time_s += dt;
        let now = self.time_s;
        self.sim.set_time(now);
        if l != 0.0 || r != 0.0 {
            self.sim.step_counts(l, r);
        }
    }

    fn counter(&self, i: usize) -> u32 {
        (self.motors[i].counter.round() as i64) as u32
    }

    /// Executes one complete packet; returns the answer bytes.
    fn execute(&mut self, command: u8, data: &[u8]) -> Vec<u8> {
        let a = self.cfg.address;
        let answer = |data: &[u8]| {
            let mut d = CRC16.digest();
            d.update(&[a, command]);
            d.update(data);
            let mut out = data.to_vec();
            out.extend_from_slice(&d.finalize().to_be_bytes());
            out
        };
        self.last_packet = Instant::now();
        match command {
            cmd::READ_VERSION => {
                let mut v = self.cfg.version.clone().into_bytes();
                v.push(0);
                answer(&v)
            }
            cmd::READ_MAIN_BATTERY => {
                answer(&((self.cfg.battery_v * 10.0).round() as u16).to_be_bytes())
            }
            cmd::READ_STATUS => answer(&0u32.to_be_bytes()),
            cmd::READ_ENCODERS => {
                let mut d = self.counter(0).to_be_bytes().to_vec();
                d.extend_from_slice(&self.counter(1).to_be_bytes());
                answer(&d)
            }
            cmd::READ_ENCODER_M1 | cmd::READ_ENCODER_M2 => {
                let i = usize::from(command == cmd::READ_ENCODER_M2);
                let mut d = self.counter(i).to_be_bytes().to_vec();
                d.push(if self.motors[i].speed < 0.0 { 0x02 } else { 0 });
                answer(&d)
            }
            cmd::READ_BUFFERS => {
                let b = |m: &Motor| if m.busy { 0 } else { BUFFER_IDLE };
                answer(&[b(&self.motors[0]), b(&self.motors[1])])
            }
            cmd::SET_SERIAL_TIMEOUT => {
                let t = data.first().copied().unwrap_or(0);
                self.serial_timeout = (t > 0).then(|| Duration::from_millis(u64::from(t) * 100));
                self.ack()
            }
            cmd::RESET_ENCODERS => {
                for m in &mut self.motors {
                    m.counter = 0.0;
                }
                self.ack()
            }
            cmd::DRIVE_SPEEDS => {
                // Only a full stop is simulated (what odocal sends).
                self.stop();
                self.counters.stops += 1;
                self.ack()
            }
            cmd::DRIVE_SPEED_ACCEL_DISTANCE => {
                let accel = f64::from(be_u32(data, 0).unwrap_or(0));
                for (i, at) in [(0usize, 4usize), (1, 12)] {
                    let speed = be_u32(data, at).unwrap_or(0) as i32;
                    let dist = f64::from(be_u32(data, at + 4).unwrap_or(0));
                    self.motors[i] = Motor {
                        counter: self.motors[i].counter,
                        speed: self.motors[i].speed,
                        target_speed: f64::from(speed.unsigned_abs()),
                        direction: if speed < 0 { -1.0 } else { 1.0 },
                        remaining: dist,
                        accel: accel.max(1.0),
                        busy: dist > 0.0 && speed != 0,
                    };
                }
                self.counters.drive_commands += 1;
                self.ack()
            }
            _ => Vec::new(),
        }
    }

    fn ack(&mut self) -> Vec<u8> {
        if self.cfg.lose_ack_rate > 0.0 && self.rng.random_bool(self.cfg.lose_ack_rate.min(1.0)) {
            self.counters.lost_acks += 1;
            Vec::new()
        } else {
            vec![ACK]
        }
    }
}

/// Data bytes a write command carries (before its CRC); `None` for reads.
fn write_len(command: u8) -> Option<usize> {
    match command {
        cmd::SET_SERIAL_TIMEOUT => Some(1),
        cmd::RESET_ENCODERS => Some(0),
        cmd::DRIVE_SPEEDS => Some(8),
        cmd::DRIVE_SPEED_ACCEL_DISTANCE => Some(21),
        _ => None,
    }
}

/// Builds the shared robot and starts its physics (robot time at `time_scale`).
pub fn spawn_robot(cfg: MockRoboClawConfig) -> Result<SharedRobot, crate::sim::SimError> {
    let sim = Simulator::new(cfg.truth, cfg.truth, cfg.noise, cfg.seed)?
        .with_heading_model(cfg.heading_model)?;
    let robot_state = Arc::new(Mutex::new(MockRobot {
        rng: ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x5EED),
        sim,
        motors: [Motor::default(); 2],
        serial_timeout: None,
        last_packet: Instant::now(),
        time_s: 0.0,
        counters: RoboClawCounters::default(),
        cfg,
    }));
    let weak = Arc::downgrade(&robot_state);
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(Duration::from_millis(1));
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        let start = Instant::now();
        loop {
            tick.tick().await;
            let Some(r) = weak.upgrade() else { return };
            let mut r = robot(&r);
            // At most 20 ms of robot time per tick: a host that falls behind slows the robot's
            // clock rather than locking the device away from its serial port for a long batch.
            let target =
                (start.elapsed().as_secs_f64() * r.cfg.time_scale.max(1e-3)).min(r.time_s + 0.02);
            while r.time_s + 1e-3 <= target {
                r.advance(1e-3);
            }
        }
    });
    Ok(robot_state)
}

/// Serves the controller's packet serial on `stream` until it closes.
pub async fn serve_roboclaw<S>(stream: S, robot_state: SharedRobot) -> std::io::Result<()>
where
    S: AsyncRead + AsyncWrite + Unpin,
{
    let (mut rd, mut wr) = tokio::io::split(stream);
    let address = robot(&robot_state).cfg.address;
    let mut buf: Vec<u8> = Vec::new();
    let mut chunk = [0u8; 256];
    loop {
        // A partial packet is dropped after 10 ms of silence, as the controller does.
        let n = match tokio::time::timeout(Duration::from_millis(10), rd.read(&mut chunk)).await {
            Err(_) => {
                buf.clear();
                continue;
            }
            Ok(Ok(0)) => return Ok(()),
            Ok(Ok(n)) => n,
            Ok(Err(e)) => return Err(e),
        };
        buf.extend_from_slice(&chunk[..n]);
        loop {
            // Resynchronise on this controller's address.
            match buf.iter().position(|&b| b == address) {
                Some(0) => {}
                Some(p) => {
                    buf.drain(..p);
                }
                None => {
                    buf.clear();
                    break;
                }
            }
            if buf.len() < 2 {
                break;
            }
            let command = buf[1];
            let answer = match write_len(command) {
                None => {
                    buf.drain(..2);
                    let mut r = robot(&robot_state);
                    let answer = r.execute(command, &[]);
                    let lose = r.cfg.lose_answer_rate;
                    if lose > 0.0 && r.rng.random_bool(lose.min(1.0)) {
                        r.counters.lost_answers += 1;
                        Vec::new()
                    } else {
                        answer
                    }
                }
                Some(len) => {
                    if buf.len() < len + 4 {
                        break;
                    }
                    let frame: Vec<u8> = buf.drain(..len + 4).collect();
                    let crc = u16::from_be_bytes([frame[len + 2], frame[len + 3]]);
                    if CRC16.checksum(&frame[..len + 2]) != crc {
                        robot(&robot_state).counters.bad_crcs += 1;
                        Vec::new()
                    } else {
                        robot(&robot_state).execute(command, &frame[2..len + 2])
                    }
                }
            };
            if !answer.is_empty() {
                wr.write_all(&answer).await?;
                wr.flush().await?;
            }
        }
    }
}

/// Both devices on new pseudo-terminals; keep the handle alive while they are used.
pub struct MockRoboClawPtys {
    /// The controller's terminal.
    pub roboclaw_path: String,
    /// The compass's terminal.
    pub compass_path: String,
    /// The shared robot.
    pub robot: SharedRobot,
    _servers: (PtyServer<()>, PtyServer<()>),
}

/// The robot's compass: its simulator's reading (noise and bias of the robot's model).
pub fn compass_of(robot_state: &SharedRobot) -> (MockCompassConfig, HeadingFn) {
    let r = robot(robot_state);
    let cfg = MockCompassConfig {
        hz: r.cfg.compass_hz,
        talker: r.cfg.compass_talker.clone(),
        bad_checksum_rate: r.cfg.bad_checksum_rate,
        // The robot's simulator adds the compass's noise.
        sigma_rad: 0.0,
        time_scale: r.cfg.time_scale,
        seed: r.cfg.seed,
        ..MockCompassConfig::default()
    };
    let shared = robot_state.clone();
    (cfg, Arc::new(move || robot(&shared).sim.heading_reading()))
}

/// Serves a mock RoboClaw and a mock compass of one robot on two pseudo-terminals.
pub fn spawn_ptys(cfg: MockRoboClawConfig) -> std::io::Result<MockRoboClawPtys> {
    let robot_state =
        spawn_robot(cfg).map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e))?;
    let r = robot_state.clone();
    let claw = spawn_on_pty(Box::new(move |master| {
        Box::pin(serve_roboclaw(master, r.clone()))
    }))?;
    let (compass_cfg, heading) = compass_of(&robot_state);
    let compass = super::nmea::spawn_pty(compass_cfg, heading)?;
    Ok(MockRoboClawPtys {
        roboclaw_path: claw.path.clone(),
        compass_path: compass.path.clone(),
        robot: robot_state,
        _servers: (claw, compass),
    })
}
