//! What a bag says about the robot: the configured geometry (from the YAML, or inferred from
//! the controller's `/odom` against the joints), the square runs
//! ([`crate::calibration::segment`] on the bag's [`Recording`]), every square method's
//! estimate with the multipliers it implies, and the online filter over the whole bag.

use super::{BagData, BagError, BagOptions, JointSample};
use crate::calibration::online::{
    Excitation, GateStats, OnlineConfig, OnlineEstimate, ScaleSource,
};
use crate::calibration::pool::{pool_methods, PooledMethods, RecordingEstimates};
use crate::calibration::recording::{Clocks, HeadingSample, Recording, TravelSample, Validity};
use crate::calibration::segment::{find_squares, RunSegment, SegmentOptions};
use crate::calibration::time_offset::TimeOffset;
use crate::calibration::tracker::Tracker;
use crate::calibration::{
    default_method, estimate_all, Estimate, HeadingKind, Method, RunMeasurement, SquareTest,
};
use crate::kinematics::{wrap_angle, Direction, SplitConvention, WheelParams};
use crate::ros::yaml::{Multipliers, RAD_PER_REV};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Configured geometry inferred from the controller's `/odom` against the wheel joints.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct InferredGeometry {
    /// Wheel radius (m), one for both wheels (what `diff_drive_controller` configures).
    pub wheel_radius_m: f64,
    /// Wheel separation (m).
    pub wheel_separation_m: f64,
    /// Odometry intervals used.
    pub intervals: usize,
}

impl InferredGeometry {
    /// As parameters (wheel angles in radians as counts).
    pub fn params(&self) -> WheelParams {
        WheelParams {
            left_wheel_diameter_m: 2.0 * self.wheel_radius_m,
            right_wheel_diameter_m: 2.0 * self.wheel_radius_m,
            wheelbase_m: self.wheel_separation_m,
            counts_per_wheel_rev: RAD_PER_REV,
        }
    }
}

/// Joint angles interpolated at `t` (the samples must cover it).
fn joints_at(j: &[JointSample], t: f64) -> Option<(f64, f64)> {
    let i = j.partition_point(|s| s.t < t);
    let b = j.get(i)?;
    if i == 0 {
        return (b.t == t).then_some((b.left_rad, b.right_rad));
    }
    let a = &j[i - 1];
    let f = if b.t > a.t {
        (t - a.t) / (b.t - a.t)
    } else {
        0.0
    };
    Some((
        a.left_rad + f * (b.left_rad - a.left_rad),
        a.right_rad + f * (b.right_rad - a.right_rad),
    ))
}

/// Infers the wheel radius and separation the controller's odometry uses: between consecutive
/// `/odom` messages, the distance it reports against the mean wheel angle change (radius), and
/// the turn it reports against the wheel angle difference (separation). Least squares.
pub fn infer_geometry(data: &BagData) -> Result<InferredGeometry, BagError> {
    if data.odom.len() < 10 {
        return Err(BagError::Inference(format!(
            "{} odometry messages (need the controller's odometry topic)",
            data.odom.len()
        )));
    }
    let (mut sxy, mut sxx, mut n) = (0.0, 0.0, 0usize);
    let mut turns = Vec::new();
    for w in data.odom.windows(2) {
        let (Some(a), Some(b)) = (
            joints_at(&data.joints, w[0].t),
            joints_at(&data.joints, w[1].t),
        ) else {
            continue;
        };
        let (dl, dr) = (b.0 - a.0, b.1 - a.1);
        let dyaw = wrap_angle(w[1].yaw_rad - w[0].yaw_rad);
        // Forward distance along the mean heading (sign from the wheels).
        let mean_yaw = w[0].yaw_rad + 0.5 * dyaw;
        let ds = (w[1].x_m - w[0].x_m) * mean_yaw.cos() + (w[1].y_m - w[0].y_m) * mean_yaw.sin();
        let phi = 0.5 * (dl + dr);
        sxy += ds * phi;
        sxx += phi * phi;
        turns.push((dr - dl, dyaw));
        n += 1;
    }
    if sxx < 1e-6 {
        return Err(BagError::Inference(
            "the wheels barely turned while /odom was recorded".into(),
        ));
    }
    let r = sxy / sxx;
    // dyaw = r (dr − dl) / b  ⇒  b = r Σ(dφ)² / Σ(dφ·dyaw).
    let (num, den) = turns.iter().fold((0.0, 0.0), |(a, b), (dphi, dyaw)| {
        (a + dphi * dphi, b + dphi * dyaw)
    });
    if den.abs() < 1e-9 || !(r.is_finite() && r > 0.0) {
        return Err(BagError::Inference(
            "the robot did not turn while /odom was recorded".into(),
        ));
    }
    let b = r * num / den;
    if !(b.is_finite() && b > 0.0) {
        return Err(BagError::Inference(format!("separation came out as {b} m")));
    }
    // Inside the bounds every parameter file must meet, or /odom and the joints disagree
    // (another robot's odometry, a unit other than radians, stamps out of order).
    let (dlo, dhi) = crate::kinematics::PHYSICAL_DIAMETER_M;
    let (blo, bhi) = crate::kinematics::PHYSICAL_WHEELBASE_M;
    if !(dlo..=dhi).contains(&(2.0 * r)) || !(blo..=bhi).contains(&b) {
        return Err(BagError::Inference(format!(
            "/odom against the joints gives a wheel diameter of {:.2} mm and a separation of \
             {:.4} m, outside what a robot has ({dlo}–{dhi} m, {blo}–{bhi} m): the odometry \
             and the joints do not describe the same motion",
            2e3 * r,
            b
        )));
    }
    Ok(InferredGeometry {
        wheel_radius_m: r,
        wheel_separation_m: b,
        intervals: n,
    })
}

/// A square run found in (or assigned to) the bag ([`crate::calibration::segment`]).
pub type BagRun = RunSegment;

impl BagData {
    /// The bag as a [`Recording`]: wheel joint increments as wheel travel under `configured`
    /// (angles in radians as counts), the IMU's yaw as the heading stream (invalid where the
    /// message carries no orientation), both on the bag's header stamps.
    pub fn recording(&self, configured: &WheelParams) -> Recording {
        let travel = std::iter::once(self.joints.first().map(|j| (j.t, 0.0, 0.0)))
            .flatten()
            .chain(self.joints.windows(2).map(|w| {
                let (l, r) = configured.travel_m(
                    w[1].left_rad - w[0].left_rad,
                    w[1].right_rad - w[0].right_rad,
                );
                (w[1].t, l, r)
            }))
            .map(|(time_s, left_m, right_m)| TravelSample {
                time_s,
                left_m,
                right_m,
            })
            .collect();
        let headings = self
            .imu
            .iter()
            .map(|y| HeadingSample {
                time_s: y.t,
                heading_rad: y.yaw_rad.unwrap_or(f64::NAN),
                validity: match y.yaw_rad {
                    Some(_) => Validity::Valid,
                    None => Validity::Invalid("the IMU message carries no orientation".into()),
                },
            })
            .collect();
        Recording {
            travel,
            headings,
            clocks: Clocks::Shared,
            poses: Vec::new(),
        }
    }
}

/// Finds the square runs (or uses `opts.ranges`) and measures each
/// ([`crate::calibration::segment`] on the bag's [`Recording`]).
pub fn find_runs(
    data: &BagData,
    configured: &WheelParams,
    opts: &BagOptions,
) -> Result<(Vec<BagRun>, Vec<String>), BagError> {
    let b = configured.wheelbase_m;
    let track = data.recording(configured).track(b);
    let seg = SegmentOptions {
        min_rest_s: opts.min_rest_s,
        ranges: opts.ranges.clone(),
        keep_irregular: opts.side_m.is_some() || data.side_m.is_some(),
    };
    find_squares(&track, b, &seg).map_err(|e| BagError::Range(e.0))
}

/// Where the configured geometry came from.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "snake_case", tag = "source")]
pub enum GeometrySource {
    /// The controller's YAML.
    Yaml {
        /// The file.
        file: PathBuf,
        /// The controller.
        controller: String,
    },
    /// Inferred from `/odom` against the joints.
    Inferred(InferredGeometry),
}

/// One method's result with the multipliers it would write.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BagEstimate {
    /// The estimate.
    #[serde(flatten)]
    pub estimate: Estimate,
    /// The multipliers it implies on the configured nominal values.
    pub multipliers: Multipliers,
}

/// Everything `odocal bag` reports.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BagReport {
    /// The bag.
    pub file: PathBuf,
    /// Messages read on the needed topics.
    pub messages: u64,
    /// Every topic in the bag.
    pub topics: Vec<(String, String)>,
    /// Configured (effective) parameters.
    pub configured: WheelParams,
    /// Where they came from.
    pub geometry: GeometrySource,
    /// Square side used (m) and where it came from.
    pub side_m: f64,
    /// `flag`, `metadata` or `legs`.
    pub side_source: &'static str,
    /// Runs found.
    pub runs: Vec<BagRun>,
    /// Stretches of motion that were not used, and why.
    pub skipped: Vec<String>,
    /// Choices made while reading the bag.
    pub notes: Vec<String>,
    /// Every square method's estimate.
    pub estimates: Vec<BagEstimate>,
    /// Methods without an estimate, and why.
    pub failures: Vec<(Method, String)>,
    /// The online filter over the whole bag.
    pub online: Option<OnlineEstimate>,
    /// Mean heading NIS of the online filter.
    pub online_nis: Option<f64>,
    /// What the online filter's heading gate rejected.
    pub online_gate: Option<GateStats>,
    /// Which parameters the bag's driving observed.
    pub online_excitation: Option<Excitation>,
    /// Clock offset between the joint states and the IMU, when it could be estimated
    /// (corrected before the online filter when significant).
    pub time_offset: Option<TimeOffset>,
}

/// The ros2_control multipliers that make `nominal` (wheel radius, separation; m) into `p`.
pub fn multipliers(p: &WheelParams, nominal: (f64, f64)) -> Multipliers {
    Multipliers {
        wheel_separation_multiplier: p.wheelbase_m / nominal.1,
        left_wheel_radius_multiplier: p.left_wheel_diameter_m / (2.0 * nominal.0),
        right_wheel_radius_multiplier: p.right_wheel_diameter_m / (2.0 * nominal.0),
    }
}

/// Analyses a bag: runs, every square method, the online filter. `nominal` gives the nominal
/// wheel radius and separation the multipliers are relative to.
pub fn analyse(
    path: &Path,
    data: &BagData,
    configured: WheelParams,
    geometry: GeometrySource,
    nominal: (f64, f64),
    opts: &BagOptions,
) -> Result<BagReport, BagError> {
    let (runs, skipped) = find_runs(data, &configured, opts)?;
    let legs: Vec<f64> = runs.iter().filter_map(|r| r.mean_leg_m).collect();
    let (side_m, side_source) = match (opts.side_m, data.side_m) {
        (Some(s), _) => (s, "flag"),
        (None, Some(s)) => (s, "metadata"),
        (None, None) if !legs.is_empty() => (legs.iter().sum::<f64>() / legs.len() as f64, "legs"),
        _ => (f64::NAN, "none"),
    };
    let test = SquareTest::from_runs(
        side_m,
        configured.wheelbase_m,
        runs.iter().map(|r| {
            let m = RunMeasurement {
                heading_error_rad: r.heading_error_rad,
                final_xy_m: None,
                odometry: Some(r.odometry),
                legs: r.legs,
                noise_variance_rad2: None,
            };
            (r.direction, m)
        }),
    );
    let (mut estimates, mut failures) = (Vec::new(), Vec::new());
    match estimate_all(&test, opts.convention) {
        Ok(all) => {
            for (method, result) in all {
                match result.and_then(|e| {
                    let p = e.correction.apply(&configured)?;
                    Ok((e, p))
                }) {
                    Ok((estimate, p)) => estimates.push(BagEstimate {
                        multipliers: multipliers(&p, nominal),
                        estimate,
                    }),
                    Err(e) => failures.push((method, e.to_string())),
                }
            }
        }
        Err(e) => failures.push((Method::Exact, e.to_string())),
    }
    let online = online_over(data, &configured, opts.convention);
    Ok(BagReport {
        file: path.to_path_buf(),
        messages: data.messages,
        topics: data.topics.clone(),
        configured,
        geometry,
        side_m,
        side_source,
        runs,
        skipped,
        notes: data.notes.clone(),
        estimates,
        failures,
        online: online.estimate,
        online_nis: online.nis,
        online_gate: online.gate,
        online_excitation: online.excitation,
        time_offset: online.time_offset,
    })
}

/// What the online filter made of a bag.
struct OnlineOver {
    estimate: Option<OnlineEstimate>,
    nis: Option<f64>,
    gate: Option<GateStats>,
    excitation: Option<Excitation>,
    time_offset: Option<TimeOffset>,
}

/// The online filter over the whole bag ([`Tracker::feed_recording`]: a significant clock
/// offset between the joint states and the IMU is removed first).
fn online_over(
    data: &BagData,
    configured: &WheelParams,
    convention: SplitConvention,
) -> OnlineOver {
    let mut out = OnlineOver {
        estimate: None,
        nis: None,
        gate: None,
        excitation: None,
        time_offset: None,
    };
    let cfg = OnlineConfig::new(*configured);
    let scale = ScaleSource::Convention(convention);
    let Ok(mut t) = Tracker::new(cfg, scale, f64::INFINITY) else {
        return out;
    };
    t.feed_recording("bag", &data.recording(configured));
    out.time_offset = t.time_offsets.first().map(|o| o.offset);
    let f = t.filter();
    let (nis, n) = f.nis_mean();
    out.estimate = f.estimate(scale).ok().filter(|_| f.distance_m() > 1.0);
    out.nis = (n > 0).then_some(nis);
    out.gate = Some(f.gate_stats());
    out.excitation = f.excitation(scale).ok();
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ros::bag::writer::{write_simulated_bag, SimulatedBag};
    use crate::ros::bag::{read_bag, RosTopics};
    use crate::sim::{NoiseModel, Simulator};

    fn robot(noise: NoiseModel) -> (Simulator, WheelParams) {
        let configured = WheelParams::nominal(0.15, 0.39, RAD_PER_REV);
        let truth =
            WheelParams::from_ratios(&configured, 0.976, 0.992, &SplitConvention::LeftNominal)
                .unwrap();
        (
            Simulator::new(truth, configured, noise, 4).unwrap(),
            configured,
        )
    }

    #[test]
    fn wrapped_joint_angles_are_unwrapped_and_topics_are_found_by_type() {
        use crate::ros::bag::writer::BagWriter;
        let dir = std::env::temp_dir().join(format!("odocal-bag-wrap-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("wrapped.mcap");
        let topics = RosTopics {
            imu: "/imu/data".into(),
            ..RosTopics::default()
        };
        let mut w = BagWriter::create(&path, &topics).unwrap();
        // Wheels turning forward 0.3 rad per sample, published wrapped to (−π, π].
        for k in 0..100 {
            let a = 0.3 * f64::from(k);
            let wrapped = crate::kinematics::wrap_angle(a);
            w.joints(0.02 * f64::from(k), wrapped, wrapped).unwrap();
            w.imu(0.02 * f64::from(k), 0.0).unwrap();
        }
        w.finish().unwrap();
        let data = read_bag(&path, &BagOptions::default()).unwrap();
        assert_eq!(
            data.notes,
            vec!["IMU from /imu/data: the bag has no /imu".to_string()]
        );
        let last = data.joints.last().unwrap();
        assert!((last.left_rad - 0.3 * 99.0).abs() < 1e-9, "{last:?}");
        assert!(data
            .joints
            .windows(2)
            .all(|w| w[1].left_rad > w[0].left_rad));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_simulated_bag_gives_back_the_simulated_robot() {
        let dir = std::env::temp_dir().join(format!("odocal-bag-unit-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("sim.mcap");
        let (mut sim, configured) = robot(NoiseModel::default());
        let cfg = SimulatedBag {
            runs: 2,
            ..SimulatedBag::default()
        };
        write_simulated_bag(&path, &mut sim, &cfg, &RosTopics::default()).unwrap();
        let opts = BagOptions::default();
        let data = read_bag(&path, &opts).unwrap();
        assert_eq!(data.side_m, Some(2.0));
        // The geometry inferred from /odom is the configured one.
        let g = infer_geometry(&data).unwrap();
        assert!((g.wheel_radius_m - 0.075).abs() < 1e-9, "{g:?}");
        assert!((g.wheel_separation_m - 0.39).abs() < 1e-9, "{g:?}");
        // Odometry in millimetres against joints in radians: no robot has that geometry.
        let mut mm = data.clone();
        for o in &mut mm.odom {
            (o.x_m, o.y_m) = (o.x_m * 1e-3, o.y_m * 1e-3);
        }
        let err = infer_geometry(&mm).unwrap_err().to_string();
        assert!(
            err.contains("wheel diameter of 0.15 mm") && err.contains("do not describe the same"),
            "{err}"
        );
        let report = analyse(
            &path,
            &data,
            configured,
            GeometrySource::Inferred(g),
            (0.075, 0.39),
            &opts,
        )
        .unwrap();
        assert_eq!(report.runs.len(), 4, "{:?}", report.skipped);
        for r in &report.runs {
            assert!((r.mean_leg_m.unwrap() - 2.0).abs() < 1e-9, "{r:?}");
        }
        let exact = report
            .estimates
            .iter()
            .find(|e| e.estimate.method == Method::Exact)
            .unwrap();
        assert!((exact.estimate.e_b - 0.976).abs() < 1e-6, "{exact:?}");
        assert!((exact.estimate.e_d - 0.992).abs() < 1e-6, "{exact:?}");
        assert!((exact.multipliers.wheel_separation_multiplier - 0.976).abs() < 1e-6);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

/// Several bags of one robot, every method's estimates pooled ([`pool_methods`]) onto the
/// first bag's configured parameters.
#[derive(Debug, Clone, Serialize)]
pub struct PooledBags {
    /// The pooled estimates, and the methods some bag could not estimate.
    pub methods: PooledMethods,
    /// Each pooled estimate with its multipliers.
    pub estimates: Vec<BagEstimate>,
    /// What `calibrate` would write, when every bag supports it.
    pub default_method: Option<Method>,
}

/// What the IMU's yaw of `bags` is, and where that comes from: what the user `given`, else
/// what every bag's `odocal` metadata says ([`BagData::heading_kind`], bags odocal wrote), else
/// unknown (with why: nothing said, or the bags disagree).
pub fn heading_kind(
    given: Option<HeadingKind>,
    bags: &[Option<HeadingKind>],
) -> (HeadingKind, &'static str) {
    match (given, bags.first().copied().flatten()) {
        (Some(k), _) => (k, "--heading-kind"),
        (None, Some(k)) if bags.iter().all(|x| *x == Some(k)) => (k, "the bag's metadata"),
        (None, _) if bags.iter().any(Option::is_some) => (
            HeadingKind::Unknown,
            "the bags' metadata disagree: give --heading-kind",
        ),
        _ => (HeadingKind::Unknown, "not stated: give --heading-kind"),
    }
}

/// Pools the estimates of `reports` (bags of one robot whose heading sensor is `kind`);
/// multipliers are relative to `nominal` (wheel radius, separation).
pub fn pool(
    reports: &[BagReport],
    nominal: (f64, f64),
    convention: SplitConvention,
    kind: HeadingKind,
) -> Result<PooledBags, BagError> {
    let per: Vec<Vec<Estimate>> = reports
        .iter()
        .map(|r| r.estimates.iter().map(|e| e.estimate.clone()).collect())
        .collect();
    let recordings: Vec<RecordingEstimates<'_>> = reports
        .iter()
        .zip(&per)
        .map(|(r, estimates)| {
            let count = |d| r.runs.iter().filter(|run| run.direction == d).count();
            RecordingEstimates {
                name: r.file.display().to_string(),
                configured: r.configured,
                estimates,
                runs_per_direction: count(Direction::Cw).min(count(Direction::Ccw)),
            }
        })
        .collect();
    let target = reports
        .first()
        .map(|r| r.configured)
        .ok_or(BagError::NoBags)?;
    let methods = pool_methods(&recordings, &target, convention)?;
    let estimates = methods
        .estimates
        .iter()
        .map(|e| {
            Ok(BagEstimate {
                multipliers: multipliers(&e.correction.apply(&target)?, nominal),
                estimate: e.clone(),
            })
        })
        .collect::<Result<Vec<_>, BagError>>()?;
    let all_legs = reports
        .iter()
        .all(|r| r.runs.iter().all(|run| run.leg_heading_error_rad.is_some()));
    let default_method = default_method(all_legs, false, kind)
        .filter(|m| methods.estimates.iter().any(|e| e.method == *m));
    Ok(PooledBags {
        methods,
        estimates,
        default_method,
    })
}
