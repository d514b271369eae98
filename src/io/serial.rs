//! The one place odocal opens a serial port: every backend on a serial line (our protocol, a
//! RoboClaw, an NMEA compass) and every mock's pseudo-terminal peer goes through [`open`]; and
//! what a byte costs on such a line ([`transmission`]).

/// Opens the serial port `path` at `baud` (8N1, no flow control), exclusively where the
/// platform allows it. A path that is not a serial port (missing, a plain file, a device that
/// takes no serial settings such as `/dev/null`) is an error that says so and points to
/// `odocal ports`, instead of the system's words ("Not a typewriter").
pub fn open(path: &str, baud: u32) -> Result<tokio_serial::SerialStream, tokio_serial::Error> {
    use tokio_serial::SerialPortBuilderExt;
    check_path(path)?;
    tokio_serial::new(path, baud)
        .open_native_async()
        .map_err(|e| {
            // ENOTTY. serialport passes errno on only as text: nix's fixed English description
            // ("Not a typewriter"), not the locale's strerror, so the words are stable; the
            // C library's ("Inappropriate ioctl for device") is matched as well.
            if e.description.contains("typewriter") || e.description.contains("ioctl") {
                not_a_port(path, "a device that takes no serial settings")
            } else {
                e
            }
        })
}

/// What `odocal ports` is for, said where a port is wrong.
const SEE_PORTS: &str = "`odocal ports` lists the serial ports of this machine";

fn not_a_port(path: &str, what: &str) -> tokio_serial::Error {
    tokio_serial::Error::new(
        tokio_serial::ErrorKind::NoDevice,
        format!("{path} is {what}, not a serial port: {SEE_PORTS}"),
    )
}

/// Why `path` cannot be a serial port, from what it is on disk (nothing is opened: opening a
/// port can reset the board behind it): missing, or not a character device. Where devices
/// are not files (Windows' `COM3`), only a missing path under `/dev` is refused.
pub fn check_path(path: &str) -> Result<(), tokio_serial::Error> {
    let p = std::path::Path::new(path);
    match std::fs::metadata(p) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            if cfg!(unix) || path.starts_with("/dev/") {
                return Err(tokio_serial::Error::new(
                    tokio_serial::ErrorKind::NoDevice,
                    format!("{path} does not exist (is the adapter plugged in?): {SEE_PORTS}"),
                ));
            }
            Ok(())
        }
        Err(_) => Ok(()),
        Ok(m) if m.is_dir() => Err(not_a_port(path, "a directory")),
        Ok(m) if m.is_file() => Err(not_a_port(path, "a regular file")),
        Ok(_) => Ok(()),
    }
}

/// How long `bytes` take on an 8N1 line at `baud` (10 bits a byte: start, eight, stop).
pub fn transmission(bytes: usize, baud: u32) -> std::time::Duration {
    std::time::Duration::from_secs_f64(10.0 * bytes as f64 / f64::from(baud.max(1)))
}
