//! The one place odocal opens a serial port: every backend on a serial line (our protocol, a
//! RoboClaw, an NMEA compass) and every mock's pseudo-terminal peer goes through [`open`]; and
//! what a byte costs on such a line ([`transmission`]). Its errors are `std::io::Error`s in
//! odocal's words: the serial crate's error type stops here, so no backend's error names it.

#[cfg(feature = "serial")]
/// Opens the serial port `path` at `baud` (8N1, no flow control), exclusively where the
/// platform allows it. A path that is not a serial port (missing, a plain file, a device that
/// takes no serial settings such as `/dev/null`) is an error that says so and points to
/// `odocal ports`, instead of the system's words ("Not a typewriter").
pub fn open(path: &str, baud: u32) -> std::io::Result<tokio_serial::SerialStream> {
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
                std::io::Error::from(e)
            }
        })
}

#[cfg(feature = "serial")]
/// Drops what `port` received and nobody read yet (a compass's sentences from before the
/// call, which would be taken for readings after it).
pub fn clear_input(port: &tokio_serial::SerialStream) -> std::io::Result<()> {
    tokio_serial::SerialPort::clear(port, tokio_serial::ClearBuffer::Input).map_err(Into::into)
}

#[cfg(feature = "serial")]
/// One serial port of this machine, with its USB ids where known (`odocal ports`): what tells
/// the motor controller's adapter from the compass's.
#[derive(Debug, Clone, PartialEq)]
pub struct PortInfo {
    /// Its path.
    pub port: String,
    /// usb, pci, bluetooth or unknown.
    pub kind: &'static str,
    /// Vendor id (hex), of a USB port.
    pub vid: Option<String>,
    /// Product id (hex), of a USB port.
    pub pid: Option<String>,
    /// Manufacturer, of a USB port that says.
    pub manufacturer: Option<String>,
    /// Product, of a USB port that says.
    pub product: Option<String>,
    /// Serial number, of a USB port that says.
    pub serial_number: Option<String>,
}

#[cfg(feature = "serial")]
/// The serial ports of this machine.
pub fn list_ports() -> std::io::Result<Vec<PortInfo>> {
    use serialport::SerialPortType as T;
    Ok(serialport::available_ports()
        .map_err(std::io::Error::from)?
        .into_iter()
        .map(|p| {
            let mut info = PortInfo {
                port: p.port_name,
                kind: "unknown",
                vid: None,
                pid: None,
                manufacturer: None,
                product: None,
                serial_number: None,
            };
            match p.port_type {
                T::UsbPort(u) => {
                    info.kind = "usb";
                    info.vid = Some(format!("{:04x}", u.vid));
                    info.pid = Some(format!("{:04x}", u.pid));
                    (info.manufacturer, info.product) = (u.manufacturer, u.product);
                    info.serial_number = u.serial_number;
                }
                T::PciPort => info.kind = "pci",
                T::BluetoothPort => info.kind = "bluetooth",
                T::Unknown => {}
            }
            info
        })
        .collect())
}

#[cfg(feature = "serial")]
impl PortInfo {
    /// The port as JSON: `port` and `type`, and for USB the ids, maker, product and serial
    /// number (null when it does not say).
    pub fn json(&self) -> serde_json::Value {
        let mut v = serde_json::json!({ "port": self.port, "type": self.kind });
        if self.kind == "usb" {
            v["vid"] = self.vid.clone().into();
            v["pid"] = self.pid.clone().into();
            v["manufacturer"] = self.manufacturer.clone().into();
            v["product"] = self.product.clone().into();
            v["serial_number"] = self.serial_number.clone().into();
        }
        v
    }
}

#[cfg(feature = "serial")]
/// A port in a line: its path, and for USB the ids, maker, product and serial number.
impl std::fmt::Display for PortInfo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (Some(vid), Some(pid)) = (&self.vid, &self.pid) else {
            return write!(f, "{:<20} {}", self.port, self.kind);
        };
        let text = |o: &Option<String>| o.clone().unwrap_or_default();
        write!(
            f,
            "{:<20} usb {vid}:{pid}  {} {} {}",
            self.port,
            text(&self.manufacturer),
            text(&self.product),
            (self.serial_number.as_ref())
                .map(|s| format!("(serial {s})"))
                .unwrap_or_default()
        )
    }
}

#[cfg(feature = "serial")]
/// What `odocal ports` is for, said where a port is wrong.
const SEE_PORTS: &str = "`odocal ports` lists the serial ports of this machine";

#[cfg(feature = "serial")]
fn not_a_port(path: &str, what: &str) -> std::io::Error {
    std::io::Error::new(
        std::io::ErrorKind::InvalidInput,
        format!("{path} is {what}, not a serial port: {SEE_PORTS}"),
    )
}

#[cfg(feature = "serial")]
/// Why `path` cannot be a serial port, from what it is on disk (nothing is opened: opening a
/// port can reset the board behind it): missing, or not a character device. Where devices
/// are not files (Windows' `COM3`), only a missing path under `/dev` is refused.
pub fn check_path(path: &str) -> std::io::Result<()> {
    let p = std::path::Path::new(path);
    match std::fs::metadata(p) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            if cfg!(unix) || path.starts_with("/dev/") {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::NotFound,
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

#[cfg(feature = "serial")]
#[cfg(test)]
mod port_tests {
    use super::*;

    #[test]
    fn a_usb_port_shows_its_ids_and_says_null_where_it_does_not_tell() {
        let usb = PortInfo {
            port: "/dev/ttyUSB0".into(),
            kind: "usb",
            vid: Some("0403".into()),
            pid: Some("6001".into()),
            manufacturer: Some("FTDI".into()),
            product: None,
            serial_number: Some("A1".into()),
        };
        assert_eq!(
            usb.to_string(),
            "/dev/ttyUSB0         usb 0403:6001  FTDI  (serial A1)"
        );
        let v = usb.json();
        assert_eq!(v["vid"], "0403");
        assert!(v["product"].is_null() && v.get("product").is_some());
        let pci = PortInfo {
            port: "/dev/ttyS0".into(),
            kind: "pci",
            vid: None,
            pid: None,
            manufacturer: None,
            product: None,
            serial_number: None,
        };
        assert_eq!(pci.to_string(), "/dev/ttyS0           pci");
        assert_eq!(
            pci.json(),
            serde_json::json!({"port": "/dev/ttyS0", "type": "pci"})
        );
    }
}
