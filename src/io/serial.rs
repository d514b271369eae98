//! The one place odocal opens a serial port: every backend on a serial line (our protocol, a
//! RoboClaw, an NMEA compass) and every mock's pseudo-terminal peer goes through [`open`]; and
//! what a byte costs on such a line ([`transmission`]).

/// Opens the serial port `path` at `baud` (8N1, no flow control), exclusively where the
/// platform allows it.
pub fn open(path: &str, baud: u32) -> Result<tokio_serial::SerialStream, tokio_serial::Error> {
    use tokio_serial::SerialPortBuilderExt;
    tokio_serial::new(path, baud).open_native_async()
}

/// How long `bytes` take on an 8N1 line at `baud` (10 bits a byte: start, eight, stop).
pub fn transmission(bytes: usize, baud: u32) -> std::time::Duration {
    std::time::Duration::from_secs_f64(10.0 * bytes as f64 / f64::from(baud.max(1)))
}
