//! The mock controller's command set as Basicmicro's manual documents it: a packet's fields
//! read in order, each command's kind and data length (so a packet written in pieces is
//! reassembled), the reads' answer layouts, the writes' effects and their acknowledgement.

use super::*;

impl MockRobot {
    /// Answers one complete packet (`frame` from the address to the CRC); empty for no answer.
    pub(super) fn packet(&mut self, kind: Kind, frame: &[u8]) -> Vec<u8> {
        let (Some(&address), Some(&command)) = (frame.first(), frame.get(1)) else {
            return Vec::new();
        };
        let rest = frame.get(2..).unwrap_or_default();
        match kind {
            Kind::Read => {
                self.last_packet = Instant::now();
                let Some(data) = self.read(command) else {
                    return Vec::new();
                };
                let lose = self.cfg.lose_answer_rate;
                if lose > 0.0 && self.rng.random_bool(lose.min(1.0)) {
                    self.counters.lost_answers += 1;
                    return Vec::new();
                }
                let mut d = CRC16.digest();
                // The answer's CRC covers the address as sent: any of 0x80–0x87 over USB.
                d.update(&[address, command]);
                d.update(&data);
                let mut out = data;
                out.extend_from_slice(&d.finalize().to_be_bytes());
                out
            }
            Kind::Write(len) => {
                let (Some(data), Some(crc)) = (rest.get(..len), rest.get(len..len + 2)) else {
                    return Vec::new();
                };
                if CRC16.checksum(&frame[..len + 2]).to_be_bytes() != crc {
                    self.counters.bad_crcs += 1;
                    return Vec::new();
                }
                self.last_packet = Instant::now();
                if self.write(command, data).is_none() {
                    self.counters.refused += 1;
                    return Vec::new();
                }
                self.ack()
            }
        }
    }

    /// The data a read command answers.
    pub(super) fn read(&mut self, command: u8) -> Option<Vec<u8>> {
        use cmd::*;
        let i = usize::from(matches!(
            command,
            READ_ENCODER_M2
                | READ_SPEED_M2
                | READ_RAW_SPEED_M2
                | READ_VELOCITY_PID_M2
                | READ_TEMPERATURE_2
        ));
        let speed = |m: &Motor| m.speed.round() as i32;
        let pair32 = |a: i32, b: i32| [a.to_be_bytes(), b.to_be_bytes()].concat();
        Some(match command {
            READ_SERIAL_TIMEOUT => vec![self.serial_timeout],
            READ_ENCODER_M1 | READ_ENCODER_M2 => {
                let m = &mut self.motors[i];
                let mut status = 0;
                for (set, bit) in [
                    (m.underflow, encoder_status::UNDERFLOW),
                    (m.speed < 0.0, encoder_status::REVERSE),
                    (m.overflow, encoder_status::OVERFLOW),
                ] {
                    if set {
                        status |= bit;
                    }
                }
                // The wrap flags clear once read.
                m.underflow = false;
                m.overflow = false;
                let mut d = m.register().to_be_bytes().to_vec();
                d.push(status);
                d
            }
            READ_SPEED_M1 | READ_SPEED_M2 | READ_RAW_SPEED_M1 | READ_RAW_SPEED_M2 => {
                // Signed, with the direction repeated in the status byte (1 = backwards).
                let m = &self.motors[i];
                let mut d = speed(m).to_be_bytes().to_vec();
                d.push(u8::from(m.speed < 0.0));
                d
            }
            READ_VERSION => {
                let mut v = self.cfg.version.clone().into_bytes();
                v.truncate(47);
                v.push(0);
                v
            }
            READ_MAIN_BATTERY | READ_LOGIC_BATTERY => ((self.cfg.battery_v * 10.0).round() as u16)
                .to_be_bytes()
                .to_vec(),
            READ_BUFFERS => self.motors.iter().map(Motor::buffer_length).collect(),
            READ_PWMS => (0..2)
                .flat_map(|i| {
                    let duty = self.motors[i].duty(self.qpps(i));
                    ((duty * 32767.0).round() as i16).to_be_bytes()
                })
                .collect(),
            READ_CURRENTS => (0..2)
                .flat_map(|i| {
                    let amps = self.motors[i].duty(self.qpps(i)).abs() * FULL_DUTY_CURRENT_A;
                    ((amps * 100.0).round() as u16).to_be_bytes()
                })
                .collect(),
            READ_VELOCITY_PID_M1 | READ_VELOCITY_PID_M2 => {
                let p = self.settings.pid[i];
                [p.p, p.i, p.d, p.qpps]
                    .iter()
                    .flat_map(|v| v.to_be_bytes())
                    .collect()
            }
            READ_ENCODERS => [self.motors[0].register(), self.motors[1].register()]
                .iter()
                .flat_map(|v| v.to_be_bytes())
                .collect(),
            READ_RAW_SPEEDS | READ_AVERAGE_SPEEDS => {
                pair32(speed(&self.motors[0]), speed(&self.motors[1]))
            }
            READ_TEMPERATURE | READ_TEMPERATURE_2 => ((BOARD_TEMPERATURE_C * 10.0).round() as u16)
                .to_be_bytes()
                .to_vec(),
            READ_STATUS => 0u32.to_be_bytes().to_vec(),
            READ_ENCODER_MODES => self.settings.encoder_modes.to_vec(),
            READ_CONFIG => self.settings.config.to_be_bytes().to_vec(),
            _ => return None,
        })
    }

    /// Executes a write; `None` refuses it (no acknowledgement).
    pub(super) fn write(&mut self, command: u8, data: &[u8]) -> Option<()> {
        use cmd::*;
        let mut f = Fields::new(data);
        let m2 = usize::from(matches!(
            command,
            SET_ENCODER_M2
                | SET_VELOCITY_PID_M2
                | DUTY_M2
                | SPEED_M2
                | SPEED_ACCEL_M2
                | SPEED_DISTANCE_M2
                | SPEED_ACCEL_DISTANCE_M2
                | SET_ENCODER_MODE_M2
        ));
        let speed = |target: i32, accel: f64| Running::Speed {
            target: f64::from(target),
            accel: accel.max(1.0),
        };
        let duty = |d: i16| Running::Duty {
            duty: (f64::from(d) / 32767.0).clamp(-1.0, 1.0),
        };
        match command {
            SET_SERIAL_TIMEOUT => self.serial_timeout = f.u8()?,
            RESET_ENCODERS => {
                for m in &mut self.motors {
                    m.counter = 0.0;
                    m.underflow = false;
                    m.overflow = false;
                }
            }
            SET_ENCODER_M1 | SET_ENCODER_M2 => self.motors[m2].counter = f64::from(f.u32()?),
            SET_VELOCITY_PID_M1 | SET_VELOCITY_PID_M2 => {
                // Sent D, P, I; read back P, I, D.
                let (d, p, i, qpps) = (f.u32()?, f.u32()?, f.u32()?, f.u32()?);
                self.settings.pid[m2] = VelocityPid { p, i, d, qpps };
            }
            DUTY_M1 | DUTY_M2 => self.run(&[(m2, duty(f.i16()?))]),
            DUTY_M1M2 => {
                let (a, b) = (f.i16()?, f.i16()?);
                self.run(&[(0, duty(a)), (1, duty(b))]);
            }
            SPEED_M1 | SPEED_M2 => self.run(&[(m2, speed(f.i32()?, INSTANT_ACCEL))]),
            DRIVE_SPEEDS => {
                let (a, b) = (f.i32()?, f.i32()?);
                self.run(&[(0, speed(a, INSTANT_ACCEL)), (1, speed(b, INSTANT_ACCEL))]);
            }
            SPEED_ACCEL_M1 | SPEED_ACCEL_M2 => {
                let accel = f64::from(f.u32()?);
                self.run(&[(m2, speed(f.i32()?, accel))]);
            }
            SPEED_ACCEL_M1M2 => {
                let accel = f64::from(f.u32()?);
                let (a, b) = (f.i32()?, f.i32()?);
                self.run(&[(0, speed(a, accel)), (1, speed(b, accel))]);
            }
            SPEED_INDIVIDUAL_ACCEL_M1M2 => {
                let (a1, s1) = (f.u32()?, f.i32()?);
                let (a2, s2) = (f.u32()?, f.i32()?);
                self.run(&[(0, speed(s1, f64::from(a1))), (1, speed(s2, f64::from(a2)))]);
            }
            SPEED_DISTANCE_M1 | SPEED_DISTANCE_M2 => {
                let leg = f.leg(None)?;
                self.buffer(&[(m2, leg)], f.replace()?)?;
            }
            SPEED_ACCEL_DISTANCE_M1 | SPEED_ACCEL_DISTANCE_M2 => {
                let accel = f.u32()?;
                let leg = f.leg(Some(accel))?;
                self.buffer(&[(m2, leg)], f.replace()?)?;
            }
            SPEED_DISTANCE_M1M2 => {
                let (a, b) = (f.leg(None)?, f.leg(None)?);
                self.buffer(&[(0, a), (1, b)], f.replace()?)?;
            }
            DRIVE_SPEED_ACCEL_DISTANCE => {
                let accel = f.u32()?;
                let (a, b) = (f.leg(Some(accel))?, f.leg(Some(accel))?);
                self.buffer(&[(0, a), (1, b)], f.replace()?)?;
            }
            SPEED_INDIVIDUAL_ACCEL_DISTANCE_M1M2 => {
                let a1 = f.u32()?;
                let a = f.leg(Some(a1))?;
                let a2 = f.u32()?;
                let b = f.leg(Some(a2))?;
                self.buffer(&[(0, a), (1, b)], f.replace()?)?;
            }
            SET_ENCODER_MODE_M1 | SET_ENCODER_MODE_M2 => {
                self.settings.encoder_modes[m2] = f.u8()?;
            }
            WRITE_SETTINGS => {
                if f.u32()? != NVM_KEY {
                    return None;
                }
                self.eeprom = self.settings;
            }
            RELOAD_SETTINGS => self.settings = self.eeprom,
            SET_CONFIG => self.settings.config = f.u16()?,
            _ => return None,
        }
        Some(())
    }

    /// Speed or duty commands for these motors.
    pub(super) fn run(&mut self, commands: &[(usize, Running)]) {
        for &(i, running) in commands {
            if let Some(m) = self.motors.get_mut(i) {
                m.command(running);
            }
        }
        self.counters.speed_commands += 1;
        let stands = |m: &Motor| match m.running {
            Running::Idle => true,
            Running::Speed { target, .. } => target == 0.0,
            Running::Duty { duty } => duty == 0.0,
            Running::Leg { .. } => false,
        };
        if self.motors.iter().all(stands) {
            self.counters.stops += 1;
        }
    }

    /// Buffered commands for these motors, all taken or (a buffer full) none.
    pub(super) fn buffer(&mut self, legs: &[(usize, Leg)], replace: bool) -> Option<()> {
        if !legs
            .iter()
            .all(|&(i, _)| self.motors.get(i).is_some_and(|m| m.takes(replace)))
        {
            return None;
        }
        for &(i, leg) in legs {
            if let Some(m) = self.motors.get_mut(i) {
                m.buffer(leg, replace);
            }
        }
        self.counters.drive_commands += 1;
        Some(())
    }

    pub(super) fn ack(&mut self) -> Vec<u8> {
        if self.cfg.lose_ack_rate > 0.0 && self.rng.random_bool(self.cfg.lose_ack_rate.min(1.0)) {
            self.counters.lost_acks += 1;
            Vec::new()
        } else {
            vec![ACK]
        }
    }
}

/// Big-endian fields of a write's data, in order.
pub(super) struct Fields<'a> {
    pub(super) data: &'a [u8],
    pub(super) at: usize,
}

impl<'a> Fields<'a> {
    pub(super) fn new(data: &'a [u8]) -> Self {
        Fields { data, at: 0 }
    }

    pub(super) fn take<const N: usize>(&mut self) -> Option<[u8; N]> {
        let bytes = self.data.get(self.at..self.at + N)?.try_into().ok()?;
        self.at += N;
        Some(bytes)
    }

    pub(super) fn u8(&mut self) -> Option<u8> {
        self.take::<1>().map(|b| b[0])
    }

    pub(super) fn u16(&mut self) -> Option<u16> {
        self.take().map(u16::from_be_bytes)
    }

    pub(super) fn i16(&mut self) -> Option<i16> {
        self.take().map(i16::from_be_bytes)
    }

    pub(super) fn u32(&mut self) -> Option<u32> {
        self.take().map(u32::from_be_bytes)
    }

    pub(super) fn i32(&mut self) -> Option<i32> {
        self.take().map(i32::from_be_bytes)
    }

    /// A buffered command's per-motor part: optional acceleration, signed speed, distance.
    pub(super) fn leg(&mut self, accel: Option<u32>) -> Option<Leg> {
        let accel = accel.map_or(INSTANT_ACCEL, f64::from);
        Some(Leg::new(self.i32()?, self.u32()?, accel))
    }

    /// The buffer flag: 0 queues, anything else replaces.
    pub(super) fn replace(&mut self) -> Option<bool> {
        self.u8().map(|b| b != 0)
    }
}

/// How a command travels on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Kind {
    /// `address, command`; answered with data and a CRC.
    Read,
    /// `address, command`, this many data bytes, a CRC; acknowledged with `0xFF`.
    Write(usize),
}

/// The commands this controller knows; `None` for the rest.
pub(super) fn kind(command: u8) -> Option<Kind> {
    use cmd::*;
    Some(match command {
        READ_SERIAL_TIMEOUT | READ_ENCODER_M1 | READ_ENCODER_M2 | READ_SPEED_M1 | READ_SPEED_M2
        | READ_VERSION | READ_MAIN_BATTERY | READ_LOGIC_BATTERY | READ_RAW_SPEED_M1
        | READ_RAW_SPEED_M2 | READ_BUFFERS | READ_PWMS | READ_CURRENTS | READ_VELOCITY_PID_M1
        | READ_VELOCITY_PID_M2 | READ_ENCODERS | READ_RAW_SPEEDS | READ_TEMPERATURE
        | READ_TEMPERATURE_2 | READ_STATUS | READ_ENCODER_MODES | READ_CONFIG
        | READ_AVERAGE_SPEEDS => Kind::Read,
        RESET_ENCODERS | RELOAD_SETTINGS => Kind::Write(0),
        SET_SERIAL_TIMEOUT | SET_ENCODER_MODE_M1 | SET_ENCODER_MODE_M2 => Kind::Write(1),
        DUTY_M1 | DUTY_M2 | SET_CONFIG => Kind::Write(2),
        SET_ENCODER_M1 | SET_ENCODER_M2 | DUTY_M1M2 | SPEED_M1 | SPEED_M2 | WRITE_SETTINGS => {
            Kind::Write(4)
        }
        DRIVE_SPEEDS | SPEED_ACCEL_M1 | SPEED_ACCEL_M2 => Kind::Write(8),
        SPEED_DISTANCE_M1 | SPEED_DISTANCE_M2 => Kind::Write(9),
        SPEED_ACCEL_M1M2 => Kind::Write(12),
        SPEED_ACCEL_DISTANCE_M1 | SPEED_ACCEL_DISTANCE_M2 => Kind::Write(13),
        SET_VELOCITY_PID_M1 | SET_VELOCITY_PID_M2 | SPEED_INDIVIDUAL_ACCEL_M1M2 => Kind::Write(16),
        SPEED_DISTANCE_M1M2 => Kind::Write(17),
        DRIVE_SPEED_ACCEL_DISTANCE => Kind::Write(21),
        SPEED_INDIVIDUAL_ACCEL_DISTANCE_M1M2 => Kind::Write(25),
        _ => return None,
    })
}

/// What the bytes at the start of the input are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Parsed {
    /// The start of a packet: more bytes are needed.
    Incomplete,
    /// This many bytes start no packet (not an address).
    Junk(usize),
    /// A whole packet of `len` bytes; `ours` is false for another controller's on a shared bus.
    Packet { len: usize, kind: Kind, ours: bool },
    /// A command the controller does not know: nothing tells where it ends.
    Unknown,
}

/// Splits the next packet off `buf`; `ours` says which addresses this controller answers.
pub(super) fn parse(buf: &[u8], ours: impl Fn(u8) -> bool) -> Parsed {
    let Some(&address) = buf.first() else {
        return Parsed::Incomplete;
    };
    if !ADDRESSES.contains(&address) {
        let junk = buf.iter().position(|b| ADDRESSES.contains(b));
        return Parsed::Junk(junk.unwrap_or(buf.len()));
    }
    let Some(&command) = buf.get(1) else {
        return Parsed::Incomplete;
    };
    let Some(kind) = kind(command) else {
        return Parsed::Unknown;
    };
    let len = match kind {
        Kind::Read => 2,
        Kind::Write(n) => n + 4,
    };
    if buf.len() < len {
        return Parsed::Incomplete;
    }
    Parsed::Packet {
        len,
        kind,
        ours: ours(address),
    }
}

/// An acceleration that reaches any speed within one physics step: the manual's "accelerate as
/// fast as possible" of the speed commands without an acceleration.
const INSTANT_ACCEL: f64 = 1e9;

/// Motor current at full duty (A), for the current read (49).
const FULL_DUTY_CURRENT_A: f64 = 2.0;

/// Board temperature (°C), for the temperature reads (82, 83).
const BOARD_TEMPERATURE_C: f64 = 25.0;
