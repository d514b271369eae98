//! RoboClaw (Basicmicro) motor controllers over packet serial, as a [`crate::base::Drive`].
//! [`packet`] has the bytes; [`client`] the transactions; [`drive`] the open-loop motions.

pub mod client;
pub mod drive;
pub mod packet;
pub mod profile;

use crate::base::{Base, HeadingSource};
use profile::ProfileStore;
use std::sync::Arc;

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
