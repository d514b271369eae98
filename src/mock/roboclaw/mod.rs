//! A mock RoboClaw and a mock NMEA compass backed by **one** simulated robot: the controller's
//! packet serial, as Basicmicro's user manual documents it, drives the true robot's wheels; the
//! compass reports its true heading with noise as `$--HDT` sentences. Each serves any byte
//! stream: an in-memory duplex or a real pseudo-terminal.
//!
//! The controller knows every command's data length, so a packet written in pieces (Basicmicro's
//! own library writes each field separately) is reassembled, and a partial packet is dropped
//! after 10 ms of silence between bytes. A write is acknowledged with `0xFF` only when its CRC
//! is right; an unknown command gets no answer. Buffered distance commands (41–46, 51) queue
//! per motor with buffer flag 0 and replace the running one and the queue with 1; speed (35–40,
//! 50) and duty (32–34) commands run until another command or the serial timeout stops both
//! motors. Over USB a RoboClaw answers any address 0x80–0x87 (each USB connection is already
//! unique, says the manual), and so does this mock unless it is given one address, as a
//! controller on a shared TTL serial bus has.
//!
//! Faults: lost acknowledgements (the command executed, the `0xFF` never sent), lost bytes of
//! answers, a brown-out (encoders reset, motors stopped, settings reloaded from the EEPROM),
//! occasional bad compass checksums.

use super::nmea::{HeadingFn, MockCompassConfig};
use super::pty::{spawn_on_pty, PtyServer};
use crate::kinematics::{Pose, WheelParams};
use crate::roboclaw::packet::{cmd, encoder_status, ACK, ADDRESSES, BUFFER_IDLE, CRC16, NVM_KEY};
use crate::sim::sensor::HeadingModel;
use crate::sim::{NoiseModel, Simulator};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::time::Instant;

mod motor;
use motor::*;
mod commands;
use commands::*;

/// Commands one motor's buffer holds behind the running one (the manual's 64); more are
/// refused without an acknowledgement.
pub const BUFFER_DEPTH: usize = 64;

/// Silence between bytes after which a partial packet is discarded (the manual's packet
/// timeout).
pub const PACKET_TIMEOUT: Duration = Duration::from_millis(10);

/// How the simulated robot is built and wired.
#[derive(Debug, Clone)]
pub struct MockRoboClawConfig {
    /// Packet serial address: `None` answers every address 0x80–0x87 as a RoboClaw on USB
    /// does; `Some` answers only that one, as on a TTL serial bus shared by several units.
    pub address: Option<u8>,
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
    /// Main battery (V); the logic supply is taken from it (the LB-MB jumper fitted).
    pub battery_v: f64,
    /// Probability that a write's acknowledgement is lost (the write executes).
    pub lose_ack_rate: f64,
    /// Probability that a read's answer is lost on the line.
    pub lose_answer_rate: f64,
    /// Every answer leaves this late (wall clock): a slow USB adapter or a busy controller.
    pub answer_delay: std::time::Duration,
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
            address: None,
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
            answer_delay: std::time::Duration::ZERO,
            compass_hz: 10.0,
            compass_talker: "HC".into(),
            bad_checksum_rate: 0.0,
        }
    }
}

/// What Write Settings (94) keeps over a power cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Settings {
    pid: [VelocityPid; 2],
    encoder_modes: [u8; 2],
    config: u16,
}

impl Settings {
    fn factory(address: Option<u8>) -> Self {
        // Packet serial (0x0003) at 38400 baud (0x0060), the address in bits 8–10.
        let address_bits = u16::from(address.unwrap_or(0x80).saturating_sub(0x80) & 7) << 8;
        Settings {
            pid: [VelocityPid::default(); 2],
            encoder_modes: [0; 2],
            config: 0x0063 | address_bits,
        }
    }
}

/// What a test can read back.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RoboClawCounters {
    /// Buffered distance commands accepted (41–46, 51).
    pub drive_commands: u64,
    /// Speed and duty commands executed (32–40, 50).
    pub speed_commands: u64,
    /// Speed or duty commands that left both motors commanded to stand.
    pub stops: u64,
    /// Serial timeouts that stopped the motors.
    pub serial_timeouts: u64,
    /// Acknowledgements deliberately lost.
    pub lost_acks: u64,
    /// Packets refused for a bad CRC.
    pub bad_crcs: u64,
    /// Read answers deliberately lost.
    pub lost_answers: u64,
    /// Packets with a command the controller does not know (no answer).
    pub unknown_commands: u64,
    /// Partial packets dropped after the packet timeout.
    pub partial_packets: u64,
    /// Valid writes refused without an acknowledgement (a full buffer, a wrong key).
    pub refused: u64,
}

/// The shared robot.
pub struct MockRobot {
    cfg: MockRoboClawConfig,
    sim: Simulator,
    motors: [Motor; 2],
    /// Serial timeout (tenths of a second, 0 = off).
    serial_timeout: u8,
    last_packet: Instant,
    settings: Settings,
    eeprom: Settings,
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
    fn new(cfg: MockRoboClawConfig) -> Result<Self, crate::sim::SimError> {
        let sim = Simulator::new(cfg.truth, cfg.truth, cfg.noise, cfg.seed)?
            .with_heading_model(cfg.heading_model)?;
        let settings = Settings::factory(cfg.address);
        Ok(MockRobot {
            rng: ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x5EED),
            sim,
            motors: Default::default(),
            serial_timeout: 0,
            last_packet: Instant::now(),
            settings,
            eeprom: settings,
            time_s: 0.0,
            counters: RoboClawCounters::default(),
            cfg,
        })
    }

    /// The true pose.
    pub fn pose(&self) -> Pose {
        self.sim.pose()
    }

    /// The true parameters.
    pub fn truth(&self) -> WheelParams {
        *self.sim.truth()
    }

    /// Whether a motor turns or is commanded to.
    pub fn moving(&self) -> bool {
        self.motors.iter().any(Motor::moving)
    }

    /// A brown-out: the controller resets (encoders zero, motors stopped, timeout off, the
    /// settings those last written to the EEPROM).
    pub fn brown_out(&mut self) {
        self.motors = Default::default();
        self.serial_timeout = 0;
        self.settings = self.eeprom;
    }

    fn stop(&mut self) {
        for m in &mut self.motors {
            m.stop();
        }
    }

    fn qpps(&self, i: usize) -> f64 {
        f64::from(self.settings.pid[i].qpps)
    }

    /// Advances robot time by `dt` seconds.
    fn advance(&mut self, dt: f64) {
        let timeout = Duration::from_millis(100 * u64::from(self.serial_timeout));
        if self.serial_timeout > 0 && self.last_packet.elapsed() > timeout && self.moving() {
            self.stop();
            self.counters.serial_timeouts += 1;
        }
        let qpps = [self.qpps(0), self.qpps(1)];
        let mut wheel = [0.0; 2];
        for (i, m) in self.motors.iter_mut().enumerate() {
            wheel[i] = m.step(dt, qpps[i]);
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
}

/// Builds the shared robot and starts its physics (robot time at `time_scale`).
pub fn spawn_robot(cfg: MockRoboClawConfig) -> Result<SharedRobot, crate::sim::SimError> {
    let robot_state = Arc::new(Mutex::new(MockRobot::new(cfg)?));
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
    let only = robot(&robot_state).cfg.address;
    let ours = |a: u8| only.is_none_or(|o| o == a);
    let mut buf: Vec<u8> = Vec::new();
    // After an unknown command, everything until the line goes quiet: its length is unknown.
    let mut ignoring = false;
    let mut chunk = [0u8; 256];
    loop {
        let n = match tokio::time::timeout(PACKET_TIMEOUT, rd.read(&mut chunk)).await {
            Err(_) => {
                if !buf.is_empty() {
                    robot(&robot_state).counters.partial_packets += 1;
                }
                buf.clear();
                ignoring = false;
                continue;
            }
            Ok(Ok(0)) => return Ok(()),
            Ok(Ok(n)) => n,
            Ok(Err(e)) => return Err(e),
        };
        if ignoring {
            continue;
        }
        buf.extend_from_slice(&chunk[..n]);
        loop {
            match parse(&buf, ours) {
                Parsed::Incomplete => break,
                Parsed::Junk(n) => {
                    buf.drain(..n);
                }
                Parsed::Unknown => {
                    robot(&robot_state).counters.unknown_commands += 1;
                    buf.clear();
                    ignoring = true;
                    break;
                }
                Parsed::Packet { len, kind, ours } => {
                    let frame: Vec<u8> = buf.drain(..len).collect();
                    if !ours {
                        continue;
                    }
                    let (answer, delay) = {
                        let mut r = robot(&robot_state);
                        (r.packet(kind, &frame), r.cfg.answer_delay)
                    };
                    if !answer.is_empty() {
                        if !delay.is_zero() {
                            tokio::time::sleep(delay).await;
                        }
                        wr.write_all(&answer).await?;
                        wr.flush().await?;
                    }
                }
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

/// One motor's velocity PID as the controller stores it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct VelocityPid {
    p: u32,
    i: u32,
    d: u32,
    qpps: u32,
}

impl Default for VelocityPid {
    /// The manual's defaults.
    fn default() -> Self {
        VelocityPid {
            p: 0x0001_0000,
            i: 0x0000_8000,
            d: 0x0000_4000,
            qpps: 44_000,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::roboclaw::packet::{check_answer, write_frame};

    fn test_robot() -> MockRobot {
        MockRobot::new(MockRoboClawConfig::new(WheelParams::nominal(
            0.15, 0.39, 4096.0,
        )))
        .expect("a valid robot")
    }

    /// A whole frame through the parser and the executor, as the server takes it.
    fn send(r: &mut MockRobot, frame: &[u8]) -> Vec<u8> {
        match parse(frame, |_| true) {
            Parsed::Packet { len, kind, .. } if len == frame.len() => r.packet(kind, frame),
            other => panic!("{frame:02X?} parsed as {other:?}"),
        }
    }

    fn write(r: &mut MockRobot, command: u8, data: &[u8]) -> Vec<u8> {
        send(r, &write_frame(0x80, command, data))
    }

    /// A read's data, its CRC checked.
    fn read(r: &mut MockRobot, command: u8) -> Vec<u8> {
        let answer = send(r, &[0x80, command]);
        check_answer(0x80, command, &answer)
            .unwrap_or_else(|| panic!("command {command}: bad answer {answer:02X?}"))
            .to_vec()
    }

    fn leg46(accel: u32, s1: i32, d1: u32, s2: i32, d2: u32, flag: u8) -> Vec<u8> {
        let mut d = accel.to_be_bytes().to_vec();
        for v in [
            s1.to_be_bytes(),
            d1.to_be_bytes(),
            s2.to_be_bytes(),
            d2.to_be_bytes(),
        ] {
            d.extend_from_slice(&v);
        }
        d.push(flag);
        d
    }

    fn encoders(r: &mut MockRobot) -> (i32, i32) {
        let d = read(r, cmd::READ_ENCODERS);
        let v = |at: usize| i32::from_be_bytes([d[at], d[at + 1], d[at + 2], d[at + 3]]);
        (v(0), v(4))
    }

    fn buffers(r: &mut MockRobot) -> (u8, u8) {
        let d = read(r, cmd::READ_BUFFERS);
        (d[0], d[1])
    }

    fn run(r: &mut MockRobot, seconds: f64) {
        for _ in 0..(seconds * 1000.0).round() as usize {
            r.advance(1e-3);
        }
    }

    fn run_until_still(r: &mut MockRobot) {
        for _ in 0..60_000 {
            if !r.moving() {
                return;
            }
            r.advance(1e-3);
        }
        panic!("still moving after a minute");
    }

    #[test]
    fn a_queued_leg_runs_after_the_running_one_and_the_buffer_length_says_so() {
        let mut r = test_robot();
        assert_eq!(buffers(&mut r), (BUFFER_IDLE, BUFFER_IDLE));
        let forward = leg46(3000, 3000, 3000, -3000, 3000, 0);
        let back = leg46(3000, -3000, 3000, 3000, 3000, 0);
        assert_eq!(
            write(&mut r, cmd::DRIVE_SPEED_ACCEL_DISTANCE, &forward),
            [ACK]
        );
        // Idle: it starts at once, nothing waits.
        assert_eq!(buffers(&mut r), (0, 0));
        assert_eq!(write(&mut r, cmd::DRIVE_SPEED_ACCEL_DISTANCE, &back), [ACK]);
        assert_eq!(buffers(&mut r), (1, 1));
        run(&mut r, 1.0);
        let (m1, m2) = encoders(&mut r);
        assert!(m1 > 1000 && m2 < -1000, "the first leg runs: {m1}, {m2}");
        let mut steps = 0;
        while buffers(&mut r) == (1, 1) {
            r.advance(1e-3);
            steps += 1;
            assert!(steps < 5000, "the first leg never ends");
        }
        assert_eq!(buffers(&mut r), (0, 0), "the second runs, none waits");
        assert_eq!(encoders(&mut r), (3000, -3000), "where the first leg ended");
        run_until_still(&mut r);
        assert_eq!(encoders(&mut r), (0, 0), "back where it began");
        assert_eq!(buffers(&mut r), (BUFFER_IDLE, BUFFER_IDLE));
        assert_eq!(r.counters.drive_commands, 2);
    }

    #[test]
    fn a_replacing_leg_stops_the_running_one_and_deletes_the_queue() {
        let mut r = test_robot();
        let forward = leg46(3000, 3000, 3000, 3000, 3000, 0);
        for _ in 0..3 {
            assert_eq!(
                write(&mut r, cmd::DRIVE_SPEED_ACCEL_DISTANCE, &forward),
                [ACK]
            );
        }
        assert_eq!(buffers(&mut r), (2, 2));
        run(&mut r, 1.0);
        let (at, _) = encoders(&mut r);
        let replace = leg46(1_000_000, -1000, 500, -1000, 500, 1);
        assert_eq!(
            write(&mut r, cmd::DRIVE_SPEED_ACCEL_DISTANCE, &replace),
            [ACK]
        );
        assert_eq!(buffers(&mut r), (0, 0));
        run_until_still(&mut r);
        let (m1, m2) = encoders(&mut r);
        assert_eq!(
            (m1, m2),
            (at - 500, at - 500),
            "only the replacing leg ran after it"
        );
    }

    #[test]
    fn a_full_buffer_refuses_the_command_without_an_acknowledgement() {
        let mut r = test_robot();
        let leg = leg46(1000, 1000, 100_000, 1000, 100_000, 0);
        // One runs, 64 wait.
        for _ in 0..=BUFFER_DEPTH {
            assert_eq!(write(&mut r, cmd::DRIVE_SPEED_ACCEL_DISTANCE, &leg), [ACK]);
        }
        assert_eq!(buffers(&mut r), (64, 64));
        assert!(write(&mut r, cmd::DRIVE_SPEED_ACCEL_DISTANCE, &leg).is_empty());
        assert_eq!(r.counters.refused, 1);
        // A single-motor leg queues on its own channel only.
        let mut one = 1000i32.to_be_bytes().to_vec();
        one.extend_from_slice(&10u32.to_be_bytes());
        one.push(1);
        assert_eq!(write(&mut r, cmd::SPEED_DISTANCE_M2, &one), [ACK]);
        assert_eq!(buffers(&mut r), (64, 0));
    }

    #[test]
    fn speed_commands_drive_until_replaced_and_the_serial_timeout_stops_them() {
        let mut r = test_robot();
        let mut speeds = 1000i32.to_be_bytes().to_vec();
        speeds.extend_from_slice(&(-500i32).to_be_bytes());
        assert_eq!(write(&mut r, cmd::DRIVE_SPEEDS, &speeds), [ACK]);
        // Not a buffered command: the buffers stay idle while it runs.
        assert_eq!(buffers(&mut r), (BUFFER_IDLE, BUFFER_IDLE));
        run(&mut r, 2.0);
        let (m1, m2) = encoders(&mut r);
        // Within the count the first step's speed jump leaves.
        assert!(
            (m1 - 2000).abs() <= 1 && (m2 + 1000).abs() <= 1,
            "{m1}, {m2}"
        );
        // Speeds are signed, the direction repeated in the status byte.
        let d = read(&mut r, cmd::READ_SPEED_M2);
        assert_eq!(
            (i32::from_be_bytes([d[0], d[1], d[2], d[3]]), d[4]),
            (-500, 1)
        );
        let d = read(&mut r, cmd::READ_RAW_SPEEDS);
        assert_eq!(i32::from_be_bytes([d[0], d[1], d[2], d[3]]), 1000);
        let d = read(&mut r, cmd::READ_PWMS);
        let pwm1 = i16::from_be_bytes([d[0], d[1]]);
        assert_eq!(pwm1, (1000.0f64 / 44_000.0 * 32767.0).round() as i16);
        // M2 counted down through zero: the underflow bit, cleared once read.
        let d = read(&mut r, cmd::READ_ENCODER_M2);
        assert_eq!(
            d[4],
            encoder_status::UNDERFLOW | encoder_status::REVERSE,
            "{d:02X?}"
        );
        assert_eq!(
            read(&mut r, cmd::READ_ENCODER_M2)[4],
            encoder_status::REVERSE
        );
        // Another speed command replaces it.
        let back = (-2000i32).to_be_bytes();
        assert_eq!(write(&mut r, cmd::SPEED_M1, &back), [ACK]);
        run(&mut r, 1.0);
        let (m1, m2) = encoders(&mut r);
        assert!(m1.abs() <= 1 && (m2 + 1500).abs() <= 1, "{m1}, {m2}");
        // 100 ms of silence with the timeout at 0.1 s stops both motors.
        assert_eq!(write(&mut r, cmd::SET_SERIAL_TIMEOUT, &[1]), [ACK]);
        assert_eq!(read(&mut r, cmd::READ_SERIAL_TIMEOUT), [1]);
        std::thread::sleep(Duration::from_millis(150));
        run(&mut r, 0.01);
        assert!(!r.moving());
        assert_eq!(r.counters.serial_timeouts, 1);
        // A duty command drives open loop at its share of QPPS.
        let duties = [16384i16.to_be_bytes(), 0i16.to_be_bytes()].concat();
        assert_eq!(write(&mut r, cmd::DUTY_M1M2, &duties), [ACK]);
        let before = encoders(&mut r).0;
        run(&mut r, 0.05);
        let moved = encoders(&mut r).0 - before;
        assert!((moved - 1100).abs() <= 1, "{moved}");
    }

    #[test]
    fn every_read_answers_its_documented_layout() {
        let mut r = test_robot();
        for (command, len) in [
            (cmd::READ_SERIAL_TIMEOUT, 1),
            (cmd::READ_ENCODER_M1, 5),
            (cmd::READ_ENCODER_M2, 5),
            (cmd::READ_SPEED_M1, 5),
            (cmd::READ_SPEED_M2, 5),
            (cmd::READ_MAIN_BATTERY, 2),
            (cmd::READ_LOGIC_BATTERY, 2),
            (cmd::READ_RAW_SPEED_M1, 5),
            (cmd::READ_RAW_SPEED_M2, 5),
            (cmd::READ_BUFFERS, 2),
            (cmd::READ_PWMS, 4),
            (cmd::READ_CURRENTS, 4),
            (cmd::READ_VELOCITY_PID_M1, 16),
            (cmd::READ_VELOCITY_PID_M2, 16),
            (cmd::READ_ENCODERS, 8),
            (cmd::READ_RAW_SPEEDS, 8),
            (cmd::READ_TEMPERATURE, 2),
            (cmd::READ_TEMPERATURE_2, 2),
            (cmd::READ_STATUS, 4),
            (cmd::READ_ENCODER_MODES, 2),
            (cmd::READ_CONFIG, 2),
            (cmd::READ_AVERAGE_SPEEDS, 8),
        ] {
            assert_eq!(read(&mut r, command).len(), len, "command {command}");
        }
        assert_eq!(
            read(&mut r, cmd::READ_VERSION),
            b"USB Roboclaw 2x7a v4.2.8\n\0"
        );
        assert_eq!(read(&mut r, cmd::READ_MAIN_BATTERY), 123u16.to_be_bytes());
        assert_eq!(read(&mut r, cmd::READ_TEMPERATURE), 250u16.to_be_bytes());
        assert_eq!(read(&mut r, cmd::READ_CONFIG), 0x0063u16.to_be_bytes());
        let pid: Vec<u8> = [0x1_0000u32, 0x8000, 0x4000, 44_000]
            .iter()
            .flat_map(|v| v.to_be_bytes())
            .collect();
        assert_eq!(read(&mut r, cmd::READ_VELOCITY_PID_M1), pid);
    }

    #[test]
    fn settings_are_kept_over_a_brown_out_only_when_written_with_the_key() {
        let mut r = test_robot();
        // Sent D, P, I, QPPS.
        let pid: Vec<u8> = [1u32, 2, 3, 5000]
            .iter()
            .flat_map(|v| v.to_be_bytes())
            .collect();
        assert_eq!(write(&mut r, cmd::SET_VELOCITY_PID_M2, &pid), [ACK]);
        let back: Vec<u8> = [2u32, 3, 1, 5000]
            .iter()
            .flat_map(|v| v.to_be_bytes())
            .collect();
        assert_eq!(read(&mut r, cmd::READ_VELOCITY_PID_M2), back);
        assert!(write(&mut r, cmd::WRITE_SETTINGS, &[0, 0, 0, 0]).is_empty());
        assert_eq!(r.counters.refused, 1);
        r.brown_out();
        assert_ne!(read(&mut r, cmd::READ_VELOCITY_PID_M2), back, "not written");
        assert_eq!(write(&mut r, cmd::SET_VELOCITY_PID_M2, &pid), [ACK]);
        assert_eq!(write(&mut r, cmd::SET_ENCODER_MODE_M1, &[0x40]), [ACK]);
        assert_eq!(write(&mut r, cmd::SET_CONFIG, &[0x20, 0x63]), [ACK]);
        assert_eq!(
            write(&mut r, cmd::WRITE_SETTINGS, &NVM_KEY.to_be_bytes()),
            [ACK]
        );
        assert_eq!(write(&mut r, cmd::SET_ENCODER_MODE_M1, &[0]), [ACK]);
        r.brown_out();
        assert_eq!(read(&mut r, cmd::READ_VELOCITY_PID_M2), back);
        assert_eq!(read(&mut r, cmd::READ_ENCODER_MODES), [0x40, 0]);
        assert_eq!(read(&mut r, cmd::READ_CONFIG), [0x20, 0x63]);
    }

    #[test]
    fn usb_answers_every_address_under_its_own_crc_and_a_bus_unit_only_its_own() {
        let mut r = test_robot();
        for address in ADDRESSES {
            let answer = send(&mut r, &[address, cmd::READ_MAIN_BATTERY]);
            assert_eq!(
                check_answer(address, cmd::READ_MAIN_BATTERY, &answer),
                Some(&123u16.to_be_bytes()[..]),
                "0x{address:02X}"
            );
            let frame = write_frame(address, cmd::RESET_ENCODERS, &[]);
            assert_eq!(send(&mut r, &frame), [ACK]);
        }
        let only = |a: u8| a == 0x82;
        let other = write_frame(0x81, cmd::SET_SERIAL_TIMEOUT, &[5]);
        assert_eq!(
            parse(&other, only),
            Parsed::Packet {
                len: 5,
                kind: Kind::Write(1),
                ours: false
            }
        );
        assert_eq!(parse(&other[..4], only), Parsed::Incomplete);
        assert_eq!(parse(&[0x00, 0x7F, 0x81], only), Parsed::Junk(2));
        assert_eq!(parse(&[0x82, 200, 1, 2], only), Parsed::Unknown);
    }

    async fn silent_for(host: &mut tokio::io::DuplexStream, wait: Duration) -> bool {
        let mut b = [0u8; 16];
        tokio::time::timeout(wait, host.read(&mut b)).await.is_err()
    }

    #[tokio::test]
    async fn a_packet_in_pieces_is_reassembled_and_a_partial_one_dropped_after_10_ms() {
        let robot_state = spawn_robot(MockRoboClawConfig::new(WheelParams::nominal(
            0.15, 0.39, 4096.0,
        )))
        .expect("a valid robot");
        let (mut host, dev) = tokio::io::duplex(1024);
        tokio::spawn(serve_roboclaw(dev, robot_state.clone()));
        // Field by field, as Basicmicro's library writes: address and command, each field, CRC.
        let frame = write_frame(
            0x80,
            cmd::DRIVE_SPEED_ACCEL_DISTANCE,
            &leg46(1000, 100, 10, 100, 10, 1),
        );
        for piece in [
            &frame[..2],
            &frame[2..6],
            &frame[6..10],
            &frame[10..22],
            &frame[22..],
        ] {
            host.write_all(piece).await.unwrap();
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
        let mut ack = [0u8; 1];
        let within = Duration::from_secs(1);
        tokio::time::timeout(within, host.read_exact(&mut ack))
            .await
            .expect("an acknowledgement")
            .unwrap();
        assert_eq!(ack, [ACK]);
        // Half a packet, then 30 ms of silence: it is dropped, and the next packet stands
        // alone.
        let timeout = write_frame(0x80, cmd::SET_SERIAL_TIMEOUT, &[7]);
        host.write_all(&timeout[..3]).await.unwrap();
        tokio::time::sleep(Duration::from_millis(30)).await;
        host.write_all(&[0x80, cmd::READ_SERIAL_TIMEOUT])
            .await
            .unwrap();
        let mut answer = [0u8; 3];
        tokio::time::timeout(within, host.read_exact(&mut answer))
            .await
            .expect("an answer")
            .unwrap();
        assert_eq!(
            check_answer(0x80, cmd::READ_SERIAL_TIMEOUT, &answer),
            Some(&[0][..])
        );
        // An unknown command and a bad CRC get no answer; the line works again after silence.
        host.write_all(&[0x80, 200, 0x80, cmd::READ_STATUS])
            .await
            .unwrap();
        assert!(silent_for(&mut host, Duration::from_millis(50)).await);
        let mut bad = timeout.clone();
        bad[4] ^= 1;
        host.write_all(&bad).await.unwrap();
        assert!(silent_for(&mut host, Duration::from_millis(50)).await);
        host.write_all(&timeout).await.unwrap();
        tokio::time::timeout(within, host.read_exact(&mut ack))
            .await
            .expect("an acknowledgement")
            .unwrap();
        assert_eq!(ack, [ACK]);
        let r = robot(&robot_state);
        assert_eq!(
            (
                r.counters.partial_packets,
                r.counters.unknown_commands,
                r.counters.bad_crcs
            ),
            (1, 1, 1)
        );
        assert_eq!(r.serial_timeout, 7);
    }

    #[tokio::test]
    async fn a_unit_on_a_shared_bus_skips_the_packets_of_the_others() {
        let mut cfg = MockRoboClawConfig::new(WheelParams::nominal(0.15, 0.39, 4096.0));
        cfg.address = Some(0x82);
        let robot_state = spawn_robot(cfg).expect("a valid robot");
        let (mut host, dev) = tokio::io::duplex(1024);
        tokio::spawn(serve_roboclaw(dev, robot_state.clone()));
        // Another unit's write, then its read, then ours, back to back.
        let mut bytes = write_frame(0x80, cmd::SET_SERIAL_TIMEOUT, &[9]);
        bytes.extend_from_slice(&[0x81, cmd::READ_CONFIG, 0x82, cmd::READ_CONFIG]);
        host.write_all(&bytes).await.unwrap();
        let mut answer = [0u8; 4];
        tokio::time::timeout(Duration::from_secs(1), host.read_exact(&mut answer))
            .await
            .expect("an answer")
            .unwrap();
        assert_eq!(
            check_answer(0x82, cmd::READ_CONFIG, &answer),
            Some(&0x0263u16.to_be_bytes()[..]),
            "packet serial at 38400 baud, address 0x82 in the configuration word"
        );
        assert!(silent_for(&mut host, Duration::from_millis(50)).await);
        assert_eq!(robot(&robot_state).serial_timeout, 0, "not ours");
    }
}
