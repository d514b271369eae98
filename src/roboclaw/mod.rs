//! RoboClaw (Basicmicro) motor controllers over packet serial, as a [`crate::base::Drive`].
//! [`packet`] has the bytes; [`client`] the transactions (run by the task in `wire.rs` that owns
//! the port); [`drive`] the open-loop motions.

pub mod client;
pub mod drive;
pub mod packet;
pub mod profile;
mod wire;

use crate::base::drive_backend::{
    DriveBackend, DriveOpen, DriveStatus, HeadingPart, OpenDrive, StorePart,
};
use crate::base::port_spec::PortSpec;
use crate::base::{Base, HeadingSource};
use profile::ProfileStore;
use std::sync::Arc;

/// Baud rate of a RoboClaw unless configured.
pub const DEFAULT_BAUD: u32 = 38_400;
/// Packet serial address of a RoboClaw unless configured.
pub const DEFAULT_ADDRESS: u8 = 0x80;

/// A RoboClaw on a serial port: `roboclaw:PORT[?address=128&baud=38400]`. A drive only: its
/// geometry and wiring are in a robot profile (`profile:PATH`), and it has no heading sensor.
pub const DRIVE_BACKEND: DriveBackend = DriveBackend {
    name: "roboclaw",
    what: "a RoboClaw",
    form: "roboclaw:PORT[?address=128&baud=38400]",
    options: &["address", "baud"],
    recognise: |text| PortSpec::parse(text, "roboclaw", &["address", "baud"]),
    bare_port: false,
    heading: HeadingPart::Needed,
    store: StorePart::Profile,
    settings: None,
    check: |spec| config_of(spec).map(drop),
    ready: |_| Ok(()),
    place: |spec| spec.port.clone(),
    open: |how: DriveOpen| -> OpenDrive {
        Box::pin(async move {
            let heading = how.heading.ok_or("a RoboClaw needs a heading source")?;
            let profile = how.profile.ok_or("a RoboClaw needs a robot profile")?;
            let claw = client::RoboClaw::open(&how.target.spec.port, config_of(&how.target.spec)?)?;
            Ok(base(claw, heading, ProfileStore::open(&profile)?).await?)
        })
    },
    status: Some(|target| {
        Box::pin(async move {
            let spec = &target.spec;
            let claw = client::RoboClaw::open(&spec.port, config_of(spec)?)?;
            let firmware = claw.version().await.map_err(|e| {
                format!(
                    "{}: no answer to the version request ({e}): not a RoboClaw, or the wrong \
                     baud or address",
                    spec.text("roboclaw")
                )
            })?;
            let report = claw.status_report(firmware).await?;
            Ok(DriveStatus {
                text: report.to_string(),
                json: report.json(),
            })
        })
    }),
};

/// The connection a RoboClaw spec's options give (address, baud; defaults unless given).
/// Checked before any port is opened.
pub fn config_of(spec: &PortSpec) -> Result<client::RoboClawConfig, String> {
    let cfg = client::RoboClawConfig {
        address: spec.option("address", DEFAULT_ADDRESS)?,
        baud: spec.option("baud", DEFAULT_BAUD)?,
        ..client::RoboClawConfig::default()
    };
    cfg.check()?;
    Ok(cfg)
}

/// A robot made of a RoboClaw drive, any heading source (an NMEA compass, an IMU) and its
/// profile file as the store: the drive counts with the profile's geometry, which a written
/// calibration updates at once.
pub async fn base(
    claw: client::RoboClaw,
    heading: Arc<dyn HeadingSource>,
    profile: ProfileStore,
) -> Result<Base, client::RoboClawError> {
    let drive = drive::RoboClawDrive::connect(claw, profile.shared()).await?;
    Ok(Base::new(Arc::new(drive), heading, Arc::new(profile)))
}
