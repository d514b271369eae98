//! RoboClaw packet serial, from Basicmicro's public command reference: the command numbers
//! odocal and its mock controller use, the byte layouts odocal sends (big-endian) and the CRC.
//!
//! A write is `address, command, data…, CRC16` and is acknowledged with `0xFF`; a read is
//! `address, command` and is answered with `data…, CRC16`, the CRC covering the address, the
//! command and the data. The CRC is CRC-16/XMODEM (polynomial 0x1021, initial value 0).

use crc::{Crc, CRC_16_XMODEM};

/// The packet CRC.
pub const CRC16: Crc<u16> = Crc::<u16>::new(&CRC_16_XMODEM);

/// The acknowledgement of a write.
pub const ACK: u8 = 0xFF;

/// Valid controller addresses.
pub const ADDRESSES: std::ops::RangeInclusive<u8> = 0x80..=0x87;

/// Command numbers: those odocal sends, and the rest of what its mock controller answers.
pub mod cmd {
    /// Set serial timeout (tenths of a second, 0 = off).
    pub const SET_SERIAL_TIMEOUT: u8 = 14;
    /// Read the serial timeout (tenths of a second).
    pub const READ_SERIAL_TIMEOUT: u8 = 15;
    /// Read encoder M1: count u32, status u8.
    pub const READ_ENCODER_M1: u8 = 16;
    /// Read encoder M2.
    pub const READ_ENCODER_M2: u8 = 17;
    /// Read M1's encoder speed: counts/s i32, direction u8 (1 = backwards).
    pub const READ_SPEED_M1: u8 = 18;
    /// Read M2's encoder speed.
    pub const READ_SPEED_M2: u8 = 19;
    /// Reset both encoders to 0.
    pub const RESET_ENCODERS: u8 = 20;
    /// Read the firmware version string.
    pub const READ_VERSION: u8 = 21;
    /// Set encoder M1's counter (u32).
    pub const SET_ENCODER_M1: u8 = 22;
    /// Set encoder M2's counter.
    pub const SET_ENCODER_M2: u8 = 23;
    /// Read the main battery voltage (tenths of a volt).
    pub const READ_MAIN_BATTERY: u8 = 24;
    /// Read the logic battery voltage (tenths of a volt).
    pub const READ_LOGIC_BATTERY: u8 = 25;
    /// Set M1's velocity PID: D, P, I (×65536) and QPPS, u32 each.
    pub const SET_VELOCITY_PID_M1: u8 = 28;
    /// Set M2's velocity PID.
    pub const SET_VELOCITY_PID_M2: u8 = 29;
    /// Read M1's raw speed over the last 1/300 s: counts/s i32, direction u8.
    pub const READ_RAW_SPEED_M1: u8 = 30;
    /// Read M2's raw speed.
    pub const READ_RAW_SPEED_M2: u8 = 31;
    /// Drive M1 at a signed duty (±32767).
    pub const DUTY_M1: u8 = 32;
    /// Drive M2 at a signed duty.
    pub const DUTY_M2: u8 = 33;
    /// Drive both motors at signed duties.
    pub const DUTY_M1M2: u8 = 34;
    /// Drive M1 at a signed speed (counts/s).
    pub const SPEED_M1: u8 = 35;
    /// Drive M2 at a signed speed.
    pub const SPEED_M2: u8 = 36;
    /// Drive both motors at signed speeds (counts/s).
    pub const DRIVE_SPEEDS: u8 = 37;
    /// Drive M1 at a signed speed reached with an acceleration (counts/s²).
    pub const SPEED_ACCEL_M1: u8 = 38;
    /// Drive M2 at a signed speed with an acceleration.
    pub const SPEED_ACCEL_M2: u8 = 39;
    /// Drive both motors at signed speeds with one acceleration.
    pub const SPEED_ACCEL_M1M2: u8 = 40;
    /// Buffered drive of M1: signed speed and distance.
    pub const SPEED_DISTANCE_M1: u8 = 41;
    /// Buffered drive of M2: signed speed and distance.
    pub const SPEED_DISTANCE_M2: u8 = 42;
    /// Buffered drive of both motors: signed speed and distance each.
    pub const SPEED_DISTANCE_M1M2: u8 = 43;
    /// Buffered drive of M1: acceleration, signed speed and distance.
    pub const SPEED_ACCEL_DISTANCE_M1: u8 = 44;
    /// Buffered drive of M2: acceleration, signed speed and distance.
    pub const SPEED_ACCEL_DISTANCE_M2: u8 = 45;
    /// Buffered drive of both motors: signed speed, acceleration and distance.
    pub const DRIVE_SPEED_ACCEL_DISTANCE: u8 = 46;
    /// Read both motors' buffer lengths.
    pub const READ_BUFFERS: u8 = 47;
    /// Read both motors' PWM duties (i16 each, ±32767).
    pub const READ_PWMS: u8 = 48;
    /// Read both motors' currents (10 mA units).
    pub const READ_CURRENTS: u8 = 49;
    /// Drive both motors at signed speeds, each with its own acceleration (not buffered).
    pub const SPEED_INDIVIDUAL_ACCEL_M1M2: u8 = 50;
    /// Buffered drive of both motors, each with its own acceleration, speed and distance.
    pub const SPEED_INDIVIDUAL_ACCEL_DISTANCE_M1M2: u8 = 51;
    /// Read M1's velocity PID: P, I, D (×65536) and QPPS.
    pub const READ_VELOCITY_PID_M1: u8 = 55;
    /// Read M2's velocity PID.
    pub const READ_VELOCITY_PID_M2: u8 = 56;
    /// Read both encoders.
    pub const READ_ENCODERS: u8 = 78;
    /// Read both motors' raw speeds over the last 1/300 s (i32 each).
    pub const READ_RAW_SPEEDS: u8 = 79;
    /// Read the board temperature (tenths of a degree Celsius).
    pub const READ_TEMPERATURE: u8 = 82;
    /// Read the second temperature sensor (tenths of a degree Celsius).
    pub const READ_TEMPERATURE_2: u8 = 83;
    /// Read the status (error and warning bits).
    pub const READ_STATUS: u8 = 90;
    /// Read both encoder modes.
    pub const READ_ENCODER_MODES: u8 = 91;
    /// Set M1's encoder mode.
    pub const SET_ENCODER_MODE_M1: u8 = 92;
    /// Set M2's encoder mode.
    pub const SET_ENCODER_MODE_M2: u8 = 93;
    /// Write the settings to EEPROM; carries [`super::NVM_KEY`].
    pub const WRITE_SETTINGS: u8 = 94;
    /// Reload the settings from EEPROM.
    pub const RELOAD_SETTINGS: u8 = 95;
    /// Set the standard configuration word.
    pub const SET_CONFIG: u8 = 98;
    /// Read the standard configuration word.
    pub const READ_CONFIG: u8 = 99;
    /// Read both motors' average speeds over the last second (i32 each).
    pub const READ_AVERAGE_SPEEDS: u8 = 108;
}

/// The key current firmware requires after Write Settings (94), as Basicmicro's libraries send
/// it; the manual's older layout has no data.
pub const NVM_KEY: u32 = 0xE22E_AB7A;

/// Bits of an encoder's status byte.
pub mod encoder_status {
    /// The counter underflowed (wrapped below zero).
    pub const UNDERFLOW: u8 = 1 << 0;
    /// The motor turns backwards.
    pub const REVERSE: u8 = 1 << 1;
    /// The counter overflowed.
    pub const OVERFLOW: u8 = 1 << 2;
}

/// A buffer length meaning "empty, and the last command has finished".
pub const BUFFER_IDLE: u8 = 0x80;

/// The bytes of a write command: address, command, data, CRC.
pub fn write_frame(address: u8, command: u8, data: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(data.len() + 4);
    out.push(address);
    out.push(command);
    out.extend_from_slice(data);
    let crc = CRC16.checksum(&out);
    out.extend_from_slice(&crc.to_be_bytes());
    out
}

/// The bytes of a read request: address, command.
pub fn read_frame(address: u8, command: u8) -> [u8; 2] {
    [address, command]
}

/// Checks a read answer (`data` then CRC over address, command and data); returns the data.
pub fn check_answer(address: u8, command: u8, answer: &[u8]) -> Option<&[u8]> {
    let (data, crc) = answer.split_at(answer.len().checked_sub(2)?);
    let mut d = CRC16.digest();
    d.update(&[address, command]);
    d.update(data);
    (d.finalize().to_be_bytes() == crc).then_some(data)
}

/// The data of command 46 for both motors, executing at once (not queued behind a running
/// command): acceleration (counts/s²), then per motor signed speed (counts/s) and distance
/// (counts).
pub fn drive_distance_data(
    accel: u32,
    speed1: i32,
    dist1: u32,
    speed2: i32,
    dist2: u32,
) -> Vec<u8> {
    let mut d = Vec::with_capacity(21);
    d.extend_from_slice(&accel.to_be_bytes());
    d.extend_from_slice(&speed1.to_be_bytes());
    d.extend_from_slice(&dist1.to_be_bytes());
    d.extend_from_slice(&speed2.to_be_bytes());
    d.extend_from_slice(&dist2.to_be_bytes());
    d.push(1);
    d
}

/// Reads a big-endian u32 at `at`.
pub fn be_u32(b: &[u8], at: usize) -> Option<u32> {
    b.get(at..at + 4)
        .map(|s| u32::from_be_bytes([s[0], s[1], s[2], s[3]]))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hex(s: &str) -> Vec<u8> {
        s.split_whitespace()
            .map(|h| u8::from_str_radix(h, 16).unwrap())
            .collect()
    }

    /// Byte strings written from the reference's layouts, CRCs from an independent CRC-16/XMODEM
    /// (Python's `binascii.crc_hqx(bytes, 0)`).
    #[test]
    fn every_command_we_send_has_the_reference_bytes() {
        assert_eq!(CRC16.checksum(b"123456789"), 0x31C3);
        assert_eq!(
            write_frame(0x80, cmd::SET_SERIAL_TIMEOUT, &[5]),
            hex("80 0E 05 48 F0")
        );
        assert_eq!(
            write_frame(0x80, cmd::DRIVE_SPEEDS, &[0; 8]),
            hex("80 25 00 00 00 00 00 00 00 00 34 04")
        );
        for (c, crc) in [
            (cmd::READ_VERSION, "59 0C"),
            (cmd::READ_BUFFERS, "CE 15"),
            (cmd::READ_ENCODERS, "B2 92"),
            (cmd::READ_MAIN_BATTERY, "88 A1"),
            (cmd::READ_STATUS, "E0 27"),
            (cmd::READ_ENCODER_M1, "09 A9"),
            (cmd::READ_ENCODER_M2, "19 88"),
        ] {
            // A read request carries no CRC; the CRC over address and command starts the answer's.
            assert_eq!(read_frame(0x80, c), [0x80, c]);
            assert_eq!(
                CRC16.checksum(&[0x80, c]).to_be_bytes().to_vec(),
                hex(crc),
                "{c}"
            );
        }
        // An answer: battery 12.3 V = 123 tenths; the CRC covers 80 18 00 7B.
        let mut answer = vec![0x00, 0x7B];
        answer.extend_from_slice(&CRC16.checksum(&[0x80, 0x18, 0x00, 0x7B]).to_be_bytes());
        assert_eq!(
            check_answer(0x80, cmd::READ_MAIN_BATTERY, &answer),
            Some(&[0x00, 0x7B][..])
        );
        answer[1] ^= 1;
        assert_eq!(check_answer(0x80, cmd::READ_MAIN_BATTERY, &answer), None);
        let d = drive_distance_data(1000, 2000, 3000, -2000, 3000);
        assert_eq!(
            write_frame(0x80, cmd::DRIVE_SPEED_ACCEL_DISTANCE, &d),
            hex("80 2E 00 00 03 E8 00 00 07 D0 00 00 0B B8 FF FF F8 30 00 00 0B B8 01 56 D0")
        );
    }
}
