//! Errors at the seam: what any drive, heading source or parameter store can report, and what
//! the write transaction adds. Backends keep their own error as the `source`.

use crate::kinematics::WheelParams;
use std::path::PathBuf;
use std::time::Duration;

/// A backend's own error, boxed so the seam does not depend on any backend.
pub type BackendError = Box<dyn std::error::Error + Send + Sync + 'static>;

/// Errors of drives, heading sources, parameter stores and the write transaction.
#[derive(Debug, thiserror::Error)]
pub enum BaseError {
    /// The device or file behind a component failed (link lost, I/O, protocol).
    #[error("{component}: {source}")]
    Backend {
        /// Which component (`drive`, `heading`, `store`, or the backend's name).
        component: String,
        /// The backend's error.
        #[source]
        source: BackendError,
    },
    /// The device understood the request and refused it.
    #[error("{component} refused {what}: {reason}")]
    Refused {
        /// Which component.
        component: String,
        /// The request.
        what: String,
        /// The device's reason.
        reason: String,
    },
    /// The heading sensor says its reading cannot be used.
    #[error("the heading is invalid: {reason}")]
    HeadingInvalid {
        /// Why (sensor status, stale, bad checksum).
        reason: String,
    },
    /// The device's watchdog stopped the base.
    #[error("the device watchdog stopped the base")]
    WatchdogTripped,
    /// A motion did not finish in the time it should take.
    #[error("the motion did not finish within {}", crate::io::seconds(.after))]
    MotionTimeout {
        /// How long was waited.
        after: Duration,
    },
    /// A value cannot be sent to this component (outside its range or representation).
    #[error("invalid argument for {component}: {reason}")]
    InvalidArgument {
        /// Which component.
        component: String,
        /// What is wrong.
        reason: String,
    },
    /// The store cannot hold the parameters as asked (a file it cannot rewrite keeping the
    /// rest of it): nothing was changed.
    #[error("{component} cannot take the parameters: {source}; nothing was changed")]
    Unwritable {
        /// Which component.
        component: String,
        /// Why.
        #[source]
        source: BackendError,
    },
    /// The component does not offer this.
    #[error("{component} cannot {what}")]
    Unsupported {
        /// Which component.
        component: String,
        /// What was asked.
        what: String,
    },
    /// The parameter backup could not be written: nothing was changed.
    #[error(
        "cannot write the parameter backup {path}: {source}; nothing was changed (free space \
         on that disk or make the directory writable, then run again)"
    )]
    Backup {
        /// The backup file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// What was written did not read back.
    #[error("read-back mismatch ({copy}): wrote {written}, the store reports {}", read.as_ref().map_or_else(|| "nothing".to_string(), ToString::to_string))]
    ReadBack {
        /// `in use` or `committed`.
        copy: &'static str,
        /// What was written.
        written: WheelParams,
        /// What came back.
        read: Option<WheelParams>,
    },
}

impl BaseError {
    /// Wraps a backend's error.
    pub fn backend(
        component: impl Into<String>,
        source: impl std::error::Error + Send + Sync + 'static,
    ) -> Self {
        BaseError::Backend {
            component: component.into(),
            source: Box::new(source),
        }
    }

    /// `value` when it is a usable speed or turn-rate limit (positive and finite); else the
    /// [`BaseError::InvalidArgument`] of `component` naming `what`.
    pub fn check_limit(component: &str, what: &str, value: f64) -> Result<f64, BaseError> {
        if value.is_finite() && value > 0.0 {
            Ok(value)
        } else {
            Err(BaseError::InvalidArgument {
                component: component.into(),
                reason: format!("{what} must be positive and finite, got {value}"),
            })
        }
    }
}
