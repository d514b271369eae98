//! A firmware's main loop over the device kit (`odocal_protocol::device`), runnable on a PC:
//! the board is emulated (motors that do exactly what they are told, encoders, a heading
//! integrated from the wheels, the wall clock) and the UART is a pseudo-terminal whose path
//! is printed first. On a microcontroller the same loop reads the UART's received bytes and
//! the `Board` methods talk to the motor driver, the encoder counters, the IMU and a timer.
//!
//! ```sh
//! cargo run --example kit_device            # prints e.g. /dev/pts/4, serves until Ctrl-C
//! cargo run -- conformance --port /dev/pts/4 --yes   # every rule of SPEC.md §7 it can check
//! ```

use odocal::protocol::device::ideal::encoder_reading;
use odocal::protocol::device::{
    Board, ByteSink, Device, DeviceConfig, DriveCommand, HeadingReading, IdealWheels, RamStorage,
};
use odocal::protocol::message::{FirmwareId, ParamsBlock};
use serialport::SerialPort;
use std::f64::consts::PI;
use std::io::{Read, Write};
use std::time::{Duration, Instant};

/// The robot: 0.15 m wheels (the right one 0.5 % larger: a robot that needs calibrating),
/// a 0.39 m wheelbase, 4096 counts per wheel revolution.
const WHEEL_M: [f64; 2] = [0.15, 0.15 * 1.005];
const WHEELBASE_M: f64 = 0.39;
const COUNTS_PER_REV: f64 = 4096.0;

/// The hardware as the kit sees it. Here the motors are emulated: whenever the firmware looks
/// (the clock, the encoders), the wheels have turned as commanded since it last looked.
struct EmulatedBoard {
    start: Instant,
    last_us: u64,
    wheels: IdealWheels,
    position: [f64; 2],
    heading_rad: f64,
}

impl EmulatedBoard {
    /// Turns the emulated wheels up to now (on hardware, physics does this).
    fn catch_up(&mut self) -> u64 {
        let now = self.start.elapsed().as_micros() as u64;
        let dt = (now - self.last_us) as f64 * 1e-6;
        let after = self.wheels.step(dt, self.position);
        let arc = |i: usize| (after[i] - self.position[i]) * PI * WHEEL_M[i] / COUNTS_PER_REV;
        self.heading_rad += (arc(1) - arc(0)) / WHEELBASE_M;
        self.position = after;
        self.last_us = now;
        now
    }
}

impl Board for EmulatedBoard {
    fn now_us(&mut self) -> u64 {
        // A free-running microsecond timer.
        self.catch_up()
    }

    fn drive(&mut self, command: &DriveCommand) {
        // Give each wheel's speed controller its speed (counts/s) and the encoder reading to
        // stop on.
        self.catch_up();
        self.wheels.command(command, self.position);
    }

    fn stop(&mut self) {
        // Brake both motors.
        self.catch_up();
        self.wheels.stop();
    }

    fn encoders(&mut self) -> (i32, i32) {
        // Read the quadrature counters.
        self.catch_up();
        (
            encoder_reading(self.position[0]),
            encoder_reading(self.position[1]),
        )
    }

    fn reset_encoders(&mut self) {
        self.catch_up();
        self.wheels.stop();
        self.position = [0.0; 2];
    }

    fn heading(&mut self) -> HeadingReading {
        // Read the IMU: counter-clockwise positive, wrapped to (−π, π], in µrad.
        self.catch_up();
        let wrapped = (self.heading_rad + PI).rem_euclid(2.0 * PI) - PI;
        HeadingReading {
            heading_urad: (wrapped * 1e6).round() as i32,
            valid: true,
            sensor_status: 1,
        }
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let nominal = ParamsBlock {
        left_wheel_diameter_nm: 150_000_000,
        right_wheel_diameter_nm: 150_000_000,
        wheelbase_nm: 390_000_000,
        counts_per_wheel_rev_micro: 4_096_000_000,
    };
    let config = DeviceConfig {
        firmware_id: FirmwareId::new("kit-example")?,
        firmware_version: 0x00_01_00,
        serial_number: 1,
        max_speed_mm_s: 500,
        max_rate_mrad_s: 3000,
        factory: nominal,
    };
    let board = EmulatedBoard {
        start: Instant::now(),
        last_us: 0,
        wheels: IdealWheels::default(),
        position: [0.0; 2],
        heading_rad: 0.0,
    };
    // A board with flash implements `ParamStorage` over two slots; this one keeps it in RAM.
    let mut device = Device::new(board, RamStorage::default(), config)?;

    // The "UART": a pseudo-terminal whose other side a host opens by path.
    let (mut uart, host_side) = serialport::TTYPort::pair()?;
    uart.set_timeout(Duration::from_millis(1))?;
    let mut tx = uart.try_clone_native()?;
    println!("{}", host_side.name().unwrap_or_default());
    let mut sink = ByteSink(|bytes: &[u8]| tx.write_all(bytes).is_ok());

    let mut rx = [0u8; 256];
    loop {
        match uart.read(&mut rx) {
            Ok(n) => device.receive(&rx[..n], &mut sink),
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            // No host has the terminal open: wait for one.
            Err(_) => std::thread::sleep(Duration::from_millis(5)),
        }
        device.poll(&mut sink);
    }
}
