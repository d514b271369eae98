//! `odocal params` on a controller of our protocol: the fields a user sets laid over what the
//! controller uses ([`ParamsPatch`]), and every change — set, save, the factory copy put back —
//! written through the one write service ([`crate::base::write`]): checked, backed up, written,
//! read back, undone on failure. Which copy each touches and what it asks is decided here.

use super::{Client, HalError};
use crate::base::write::{
    write_once, Bounds, Commit, Question, WriteError, WritePolicy, WriteRequest, WriteUi, Written,
};
use crate::kinematics::WheelParams;
use crate::protocol::message::ParamSource;
use std::path::Path;
use std::sync::Arc;

/// Why a parameter command failed.
#[derive(Debug, thiserror::Error)]
pub enum ParamsError {
    /// The controller's parameters could not be read.
    #[error(transparent)]
    Read(#[from] HalError),
    /// The write was refused, declined or failed (what the controller holds then is said).
    #[error(transparent)]
    Write(#[from] WriteError),
}

/// The parameters a user sets; those not given keep the controller's value (with the `cli`
/// feature, `odocal params set`'s flags).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
pub struct ParamsPatch {
    /// Left wheel diameter (m).
    #[cfg_attr(feature = "cli", arg(long))]
    pub left_wheel_diameter_m: Option<f64>,
    /// Right wheel diameter (m).
    #[cfg_attr(feature = "cli", arg(long))]
    pub right_wheel_diameter_m: Option<f64>,
    /// Wheelbase (m).
    #[cfg_attr(feature = "cli", arg(long))]
    pub wheelbase_m: Option<f64>,
    /// Encoder counts per wheel revolution.
    #[cfg_attr(feature = "cli", arg(long))]
    pub counts_per_rev: Option<f64>,
}

impl ParamsPatch {
    /// `current` with the fields given replaced.
    pub fn applied_to(&self, current: &WheelParams) -> WheelParams {
        WheelParams {
            left_wheel_diameter_m: (self.left_wheel_diameter_m)
                .unwrap_or(current.left_wheel_diameter_m),
            right_wheel_diameter_m: (self.right_wheel_diameter_m)
                .unwrap_or(current.right_wheel_diameter_m),
            wheelbase_m: self.wheelbase_m.unwrap_or(current.wheelbase_m),
            counts_per_wheel_rev: self.counts_per_rev.unwrap_or(current.counts_per_wheel_rev),
        }
    }
}

/// Writes `new` through the write service, backing up into `dir`; asks `ask` first when
/// given (else the command itself was the question).
async fn write_to(
    client: &Arc<Client>,
    new: WheelParams,
    commit: Commit,
    dir: &Path,
    ask: Option<Question>,
    ui: &mut dyn WriteUi,
) -> Result<Written, WriteError> {
    let request = WriteRequest {
        new,
        bounds: Bounds::Physical,
        policy: match ask {
            Some(_) => WritePolicy::Ask,
            None => WritePolicy::Yes,
        },
        commit,
        backup_dir: dir,
        question: ask.unwrap_or(Question::Plain(String::new())),
    };
    write_once(client.clone(), None, request, ui).await
}

/// `params set`: the fields given, the others as they are, to the copy in use (RAM).
pub async fn set(
    client: &Arc<Client>,
    patch: &ParamsPatch,
    dir: &Path,
    ui: &mut dyn WriteUi,
) -> Result<Written, ParamsError> {
    let current = client.get_params(ParamSource::Active).await?;
    let wanted = patch.applied_to(&current);
    Ok(write_to(client, wanted, Commit::InUse, dir, None, ui).await?)
}

/// `params save`: what is in use, committed (the stored copy is backed up first and read back).
pub async fn save(
    client: &Arc<Client>,
    dir: &Path,
    ui: &mut dyn WriteUi,
) -> Result<Written, ParamsError> {
    let active = client.get_params(ParamSource::Active).await?;
    Ok(write_to(client, active, Commit::Both, dir, None, ui).await?)
}

/// `params restore` without a backup file: the factory parameters, written as any others
/// (asked unless `yes`, backed up, read back, undone on failure); stored too with `stored`.
pub async fn restore_factory(
    client: &Arc<Client>,
    (stored, yes): (bool, bool),
    dir: &Path,
    ui: &mut dyn WriteUi,
) -> Result<Written, ParamsError> {
    let factory = client.get_params(ParamSource::Factory).await?;
    let commit = if stored { Commit::Both } else { Commit::InUse };
    let question = Question::OldToNew(format!(
        "restore the factory parameters{}?",
        if stored { " and commit them" } else { "" }
    ));
    let ask = (!yes).then_some(question);
    Ok(write_to(client, factory, commit, dir, ask, ui).await?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_patch_replaces_what_it_gives_only() {
        let current = WheelParams::nominal(0.15, 0.39, 4096.0);
        assert_eq!(ParamsPatch::default().applied_to(&current), current);
        let p = ParamsPatch {
            right_wheel_diameter_m: Some(0.151),
            wheelbase_m: Some(0.4),
            ..ParamsPatch::default()
        };
        let new = p.applied_to(&current);
        assert_eq!(new.left_wheel_diameter_m, 0.15);
        assert_eq!((new.right_wheel_diameter_m, new.wheelbase_m), (0.151, 0.4));
        assert_eq!(new.counts_per_wheel_rev, 4096.0);
    }
}
