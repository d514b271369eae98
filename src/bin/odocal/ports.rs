//! `odocal ports`: the serial ports this machine has, with USB ids where known, so a user can
//! tell the motor controller's adapter from the compass's.

use crate::out::print_json;
use serde_json::json;

/// Arguments of `odocal ports`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
}

/// Runs `odocal ports`.
pub fn run(args: Args) -> Result<(), Box<dyn std::error::Error>> {
    let ports = serialport::available_ports()?;
    let rows: Vec<serde_json::Value> = ports
        .iter()
        .map(|p| match &p.port_type {
            serialport::SerialPortType::UsbPort(u) => json!({
                "port": p.port_name,
                "type": "usb",
                "vid": format!("{:04x}", u.vid),
                "pid": format!("{:04x}", u.pid),
                "manufacturer": u.manufacturer,
                "product": u.product,
                "serial_number": u.serial_number,
            }),
            serialport::SerialPortType::PciPort => json!({"port": p.port_name, "type": "pci"}),
            serialport::SerialPortType::BluetoothPort => {
                json!({"port": p.port_name, "type": "bluetooth"})
            }
            serialport::SerialPortType::Unknown => json!({"port": p.port_name, "type": "unknown"}),
        })
        .collect();
    if args.json {
        return print_json(&json!({ "ports": rows }));
    }
    if rows.is_empty() {
        println!("no serial ports found (is the adapter plugged in, and may this user read it?)");
        return Ok(());
    }
    for r in &rows {
        let text = |k: &str| r[k].as_str().unwrap_or("").to_string();
        if r["type"] == "usb" {
            println!(
                "{:<20} usb {}:{}  {} {} {}",
                text("port"),
                text("vid"),
                text("pid"),
                text("manufacturer"),
                text("product"),
                r["serial_number"]
                    .as_str()
                    .map(|s| format!("(serial {s})"))
                    .unwrap_or_default()
            );
        } else {
            println!("{:<20} {}", text("port"), text("type"));
        }
    }
    Ok(())
}
