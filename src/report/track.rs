//! What `odocal track` says at the end of a session: the online filter's last estimate with
//! how well the drive excited it, the heading gate, the streams' time offsets, and for a
//! session with a pose reference the geometry in metres, the reference's mounting and any
//! drift of the parameters in use; as text and as stdout's JSON.

use crate::calibration::online::{Excitation, OnlineEstimate};
use crate::calibration::pose_fit::Param;
use crate::calibration::tracker::Tracker;
use crate::kinematics::WheelParams;
use serde_json::json;
use std::fmt::Write as _;

/// A parameter in use further than this many standard deviations from the drive's estimate
/// is reported as drifted.
pub const DRIFT_SIGMAS: f64 = 3.0;

/// The end of a tracking session.
pub struct TrackSummary<'a> {
    /// The tracker, fed to the end.
    pub tracker: &'a Tracker,
    /// Its last estimate.
    pub last: &'a OnlineEstimate,
    /// The parameters in use during the session.
    pub configured: &'a WheelParams,
    /// Whether a pose reference was tracked against.
    pub with_poses: bool,
    /// How well the drive excited E_b and E_d.
    pub excitation: &'a Excitation,
    /// The parameters written back, if they were.
    pub written: Option<WheelParams>,
}

impl TrackSummary<'_> {
    /// As stdout's JSON: every checkpoint and the last estimate, the pose reference's
    /// mounting and drift, the heading filter's statistics, the time offsets, and what was
    /// written.
    pub fn json(&self) -> serde_json::Value {
        let t = self.tracker;
        let mut estimates: Vec<_> = t.checkpoints.clone();
        estimates.push(*self.last);
        let (mount, mount_std) = t.filter().mount();
        let (pose_nis, pose_fixes) = t.filter().nis_pose_mean();
        let (nis, updates) = t.filter().nis_mean();
        json!({
            "configured": self.configured,
            "estimates": estimates,
            "pose_reference": self.with_poses.then(|| json!({
                "fixes": pose_fixes,
                "nis_mean_per_dof": pose_nis,
                "sensor_x_m": mount[0], "sensor_x_m_std": mount_std[0],
                "sensor_y_m": mount[1], "sensor_y_m_std": mount_std[1],
                "sensor_yaw_rad": mount[2], "sensor_yaw_rad_std": mount_std[2],
                "started_after_s": t.started_from.as_ref().map(|f| f.span_s),
                "reference_delay_s": t.started_from.as_ref().map(|_| t.pose_delay_s()),
                "reference_delay_s_std": t.started_from.as_ref().and_then(|f| f.std(Param::TimeOffset)),
                "drift": self.last.drift(self.configured, DRIFT_SIGMAS),
            })),
            "heading_updates": updates,
            "heading_nis_mean": nis,
            "heading_gate": t.filter().gate_stats(),
            "excitation": self.excitation,
            "time_offsets": t.time_offsets,
            "written": self.written,
        })
    }

    /// As the terminal shows it, after the last estimate's line (and [`pose_session`]'s,
    /// which come before a write-back's question).
    pub fn text(&self) -> String {
        let t = self.tracker;
        let mut out = String::new();
        if !self.with_poses {
            let (nis, updates) = t.filter().nis_mean();
            let gate = t.filter().gate_stats();
            let _ = writeln!(
                out,
                "{updates} heading updates, mean NIS {nis:.2} (≈ 1 when the noise settings fit \
                 the robot); {} reading(s) rejected by the gate, {} heading re-anchor(s)",
                gate.rejected, gate.resets
            );
        }
        let x = self.excitation;
        let _ = writeln!(
            out,
            "E_b {} (σ {:.0} % of the prior's), E_d {} (σ {:.0} % of the prior's)",
            x.e_b,
            100.0 * x.e_b_ratio,
            x.e_d,
            100.0 * x.e_d_ratio
        );
        if let Some(advice) = x.advice() {
            let _ = writeln!(out, "warning: {advice}");
        }
        for o in &t.time_offsets {
            let what = if o.corrected {
                "corrected"
            } else if o.offset.significant() {
                "NOT corrected (live); fix the clocks or the sensor delay"
            } else {
                "below the warning threshold"
            };
            let prefix = if o.offset.significant() {
                "warning: "
            } else {
                ""
            };
            let _ = writeln!(
                out,
                "{prefix}{}: heading stream {} the encoders by {:.3} s (rate correlation {:.2}, \
                 {:.2} at 0 s): {what}",
                o.run,
                if o.offset.offset_s >= 0.0 {
                    "lags"
                } else {
                    "leads"
                },
                o.offset.offset_s.abs(),
                o.offset.correlation,
                o.offset.correlation_at_zero
            );
        }
        out
    }
}

/// What a session with a pose reference found: the geometry in metres (± 1σ, beside what is in
/// use), the reference frame's mounting on the robot, the pose fixes' statistics, and whether
/// the parameters in use have drifted.
pub fn pose_session(t: &Tracker, last: &OnlineEstimate, configured: &WheelParams) -> String {
    let mut out = String::new();
    if let Some(fit) = &t.started_from {
        let _ = writeln!(
            out,
            "the filter started from a batch fit of {:.1} s of driving (once the drive had \
             turned both ways and driven straight), then took every pose fix",
            fit.span_s
        );
        if let Some(std) = fit.std(Param::TimeOffset) {
            let _ = writeln!(
                out,
                "the reference's stamps are {:.3} s late (± {std:.3} s, 1σ, measured by the \
                 start fit{}), taken off every fix",
                t.pose_delay_s(),
                if (t.pose_delay_s() - fit.value(Param::TimeOffset)).abs() > 1e-9 {
                    " on top of --reference-delay-s"
                } else {
                    ""
                }
            );
        }
    }
    if last.correction_std.is_some() {
        for p in last.against(configured) {
            let _ = writeln!(
                out,
                "{:<24} {:.6} ± {:.6} (1σ; in use {:.6})",
                p.parameter, p.estimate, p.std, p.in_use
            );
        }
    }
    let (m, ms) = t.filter().mount();
    let _ = writeln!(
        out,
        "reference frame in base_link: x {:.4} ± {:.4} m, y {:.4} ± {:.4} m, yaw {:.2} ± \
         {:.2}°",
        m[0],
        ms[0],
        m[1],
        ms[1],
        m[2].to_degrees(),
        ms[2].to_degrees()
    );
    let (nis, fixes) = t.filter().nis_pose_mean();
    let gate = t.filter().gate_stats();
    let _ = writeln!(
        out,
        "{fixes} pose fixes, mean NIS per degree of freedom {nis:.2} (≈ 1 when the noise \
         fits); {} rejected by the gate, {} re-anchor(s)",
        gate.rejected, gate.resets
    );
    let drift = last.drift(configured, DRIFT_SIGMAS);
    if drift.is_empty() {
        let _ = writeln!(
            out,
            "no drift: every parameter in use is within {DRIFT_SIGMAS}σ of what the drive \
             says"
        );
    }
    for d in drift {
        let _ = writeln!(
            out,
            "drift: {} in use {:.6} is off by {:+.6} ({:+.1}σ): the drive says {:.6} ± \
             {:.6}; write it back with --write-back, or fit the recording with odocal fit",
            d.parameter,
            d.in_use,
            d.estimate - d.in_use,
            d.sigmas,
            d.estimate,
            d.std
        );
    }
    out
}
