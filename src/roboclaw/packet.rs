//! RoboClaw packet serial, from Basicmicro's public command reference: the commands odocal
//! uses, their byte layouts (big-endian) and the CRC.
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

/// Command numbers.
pub mod cmd {
    /// Set serial timeout (tenths of a second, 0 = off).
    pub const SET_SERIAL_TIMEOUT: u8 = 14;
    /// Read encoder M1: count u32, status u8.
    pub const READ_ENCODER_M1: u8 = 16;
    /// Read encoder M2.
    pub const READ_ENCODER_M2: u8 = 17;
    /// Reset both encoders to 0.
    pub const RESET_ENCODERS: u8 = 20;
    /// Read the firmware version string.
    pub const READ_VERSION: u8 = 21;
    /// Read the main battery voltage (tenths of a volt).
    pub const READ_MAIN_BATTERY: u8 = 24;
    /// Drive both motors at signed speeds (counts/s).
    pub const DRIVE_SPEEDS: u8 = 37;
    /// Buffered drive of both motors: signed speed, acceleration and distance.
    pub const DRIVE_SPEED_ACCEL_DISTANCE: u8 = 46;
    /// Read both motors' buffer lengths.
    pub const READ_BUFFERS: u8 = 47;
    /// Read both encoders.
    pub const READ_ENCODERS: u8 = 78;
    /// Read the status (error and warning bits).
    pub const READ_STATUS: u8 = 90;
}

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
