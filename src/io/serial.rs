//! The one place odocal opens a serial port: every backend on a serial line (our protocol, a
//! RoboClaw, an NMEA compass) and every mock's pseudo-terminal peer goes through [`open`].

/// Opens the serial port `path` at `baud` (8N1, no flow control), exclusively where the
/// platform allows it.
pub fn open(path: &str, baud: u32) -> Result<tokio_serial::SerialStream, tokio_serial::Error> {
    use tokio_serial::SerialPortBuilderExt;
    tokio_serial::new(path, baud).open_native_async()
}
