//! [`MotionGuard`]: stops the base when a motion is abandoned.

use super::Drive;
use std::sync::Arc;

/// Calls [`Drive::emergency_stop`] when dropped unless [`MotionGuard::disarm`] was called: an
/// error, a panic or a cancelled future (Ctrl-C) while the robot moves stops the base.
pub struct MotionGuard {
    drive: Arc<dyn Drive>,
    armed: bool,
}

impl MotionGuard {
    /// Arms a guard on `drive`.
    pub fn new(drive: &Arc<dyn Drive>) -> Self {
        MotionGuard {
            drive: drive.clone(),
            armed: true,
        }
    }

    /// The motion finished normally: do not stop on drop.
    pub fn disarm(mut self) {
        self.armed = false;
    }
}

impl Drop for MotionGuard {
    fn drop(&mut self) {
        if self.armed {
            self.drive.emergency_stop();
        }
    }
}
