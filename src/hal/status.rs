//! What `odocal status` shows of a controller of our protocol: who it is (HELLO) and how it is
//! (GET_STATUS), as text and as JSON.

use crate::protocol::message::{DeviceInfo, Status};
use serde_json::json;

/// A device and its status, read together.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceStatus {
    /// HELLO's answer.
    pub device: DeviceInfo,
    /// GET_STATUS's answer.
    pub status: Status,
}

impl DeviceStatus {
    /// The report as JSON: `{"device": …, "status": …}`.
    pub fn json(&self) -> serde_json::Value {
        json!({ "device": self.device, "status": self.status })
    }
}

impl std::fmt::Display for DeviceStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (info, s) = (&self.device, &self.status);
        writeln!(
            f,
            "{} (protocol {}.{}, serial {:#x})",
            info.firmware_id, info.major, info.minor, info.serial_number
        )?;
        writeln!(f, "motion state       {}", s.motion_state)?;
        writeln!(f, "queue depth        {}", s.queue_depth)?;
        writeln!(f, "completed motions  {}", s.completed_motions)?;
        writeln!(f, "fault flags        {:#06x}", s.fault_flags)?;
        writeln!(f, "watchdog           {}", s.watchdog_state)?;
        writeln!(
            f,
            "uptime             {:.1} s",
            f64::from(s.uptime_ms) / 1e3
        )
    }
}
