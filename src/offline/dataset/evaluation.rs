//! Replay evaluation of parameter sets against a set's ground truth: the end-point errors of
//! each run dead-reckoned with the parameters, per method and pooled, and the estimate of each
//! recording held out from the fit.

use super::*;

impl OptiOdomSet {
    /// Replays every run with `params`: mean |final heading error| (rad) and mean final
    /// position error (m) of the odometry against the ground truth.
    pub fn evaluate(&self, params: &WheelParams) -> (f64, f64) {
        let n = self.runs.len().max(1) as f64;
        let (mut heading, mut position) = (0.0, 0.0);
        for run in &self.runs {
            let end = run.replay(params);
            heading += wrap_angle(end.odometry_turn_rad - end.truth_turn_rad).abs() / n;
            position +=
                (end.odometry.x_m - end.truth.x_m).hypot(end.odometry.y_m - end.truth.y_m) / n;
        }
        (heading, position)
    }

    /// Replays every run with `params` and measures the **systematic** error, as Borenstein's
    /// `E_max,sys` does for positions: per direction (told from the ground-truth turn) the mean
    /// signed final heading error and the mean final position error vector; returns the larger
    /// |mean heading error| (rad) and the larger |mean position error| (m) of the two directions.
    /// Run-to-run scatter, which no calibration removes, averages out.
    pub fn evaluate_systematic(&self, params: &WheelParams) -> (f64, f64) {
        let mut sums = [[0.0f64; 4]; 2];
        for run in &self.runs {
            let end = run.replay(params);
            let k = usize::from(end.truth_turn_rad > 0.0);
            sums[k][0] += wrap_angle(end.odometry_turn_rad - end.truth_turn_rad);
            sums[k][1] += end.odometry.x_m - end.truth.x_m;
            sums[k][2] += end.odometry.y_m - end.truth.y_m;
            sums[k][3] += 1.0;
        }
        let (mut heading, mut position) = (0.0f64, 0.0f64);
        for [h, x, y, n] in sums {
            if n > 0.0 {
                heading = heading.max((h / n).abs());
                position = position.max((x / n).hypot(y / n));
            }
        }
        (heading, position)
    }
}

/// One row of a replay evaluation.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EvaluationRow {
    /// Evaluated set id.
    pub dataset: String,
    /// Method name, or "uncalibrated" for the set's own configured parameters.
    pub method: String,
    /// Mean absolute final heading error of the odometry (deg).
    pub heading_error_deg: f64,
    /// Mean final position error of the odometry (m).
    pub position_error_m: f64,
    /// Systematic final heading error: the larger |mean| of the two directions (deg; see
    /// [`OptiOdomSet::evaluate_systematic`]).
    pub systematic_heading_error_deg: f64,
    /// Systematic final position error: the larger |mean end-point error| of the two
    /// directions (m).
    pub systematic_position_error_m: f64,
}

/// A replay: estimates from one or more square sets of one robot, pooled, and their evaluation
/// on other sets.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Replay {
    /// Sets calibrated on.
    pub datasets: Vec<String>,
    /// Every method that succeeded on every set, pooled ([`calibration::pool`]) and expressed
    /// against the first set's configured parameters.
    pub estimates: Vec<Estimate>,
    /// The pooled physical estimates behind `estimates`, with the per-recording values and the
    /// recording-to-recording spread.
    pub pooled: Vec<Pooled>,
    /// Which uncertainty the estimates' standard errors are.
    pub uncertainty: UncertaintyKind,
    /// The method to write back unless told otherwise ([`calibration::default_method`]).
    pub default_method: Option<Method>,
    /// Methods that failed on some set, with the set and the reason.
    pub failures: Vec<(Method, String)>,
    /// Uncalibrated and calibrated odometry errors on each evaluated set.
    pub evaluations: Vec<EvaluationRow>,
}

/// Calibrates from `calibrate_on` (one or more square sets of one robot) with every method,
/// pools each method over the sets in physical terms, and evaluates the results on
/// `evaluate_on`.
///
/// On each evaluated set the pooled robot is expressed against that set's own configured
/// parameters (so sets recorded with other configurations compare); "uncalibrated" is each
/// evaluated set's configured parameters.
pub fn replay(
    calibrate_on: &[OptiOdomSet],
    evaluate_on: &[OptiOdomSet],
    convention: SplitConvention,
) -> Result<Replay, DatasetError> {
    let first = calibrate_on
        .first()
        .ok_or_else(|| DatasetError::NotASet(PathBuf::from("(no calibration set given)")))?;
    let tests = calibrate_on
        .iter()
        .map(OptiOdomSet::square_test)
        .collect::<Result<Vec<_>, _>>()?;
    let mut failures = Vec::new();
    let mut per_set = Vec::new();
    for (set, test) in calibrate_on.iter().zip(&tests) {
        let mut ok = Vec::new();
        for (method, result) in calibration::estimate_all(test, convention)? {
            match result {
                Ok(e) => ok.push(e),
                Err(e) => failures.push((method, format!("{}: {e}", set.id))),
            }
        }
        per_set.push(ok);
    }
    let recordings: Vec<_> = calibrate_on
        .iter()
        .zip(&tests)
        .zip(&per_set)
        .map(|((set, test), estimates)| RecordingEstimates {
            name: set.id.clone(),
            configured: set.configured,
            estimates,
            runs_per_direction: test.cw.len().min(test.ccw.len()),
        })
        .collect();
    let pooled = pool_methods(&recordings, &first.configured, convention)?;
    for (method, sets) in &pooled.missing {
        failures.push((*method, format!("not estimated on {}", sets.join(", "))));
    }
    let PooledMethods {
        pooled,
        estimates,
        uncertainty,
        ..
    } = pooled;
    let mut evaluations = Vec::new();
    for set in evaluate_on {
        let mut row = |method: String, params: &WheelParams| {
            let (h, p) = set.evaluate(params);
            let (hs, ps) = set.evaluate_systematic(params);
            evaluations.push(EvaluationRow {
                dataset: set.id.clone(),
                method,
                heading_error_deg: h.to_degrees(),
                position_error_m: p,
                systematic_heading_error_deg: hs.to_degrees(),
                systematic_position_error_m: ps,
            });
        };
        row("uncalibrated".into(), &set.configured);
        for p in &pooled {
            let params = p
                .estimate_for(&set.configured, convention)?
                .correction
                .apply(&set.configured)?;
            row(p.method.name().into(), &params);
        }
    }
    let has = |f: fn(&SquareTest) -> bool| tests.iter().all(f);
    let default_method = calibration::default_method(
        has(SquareTest::has_leg_headings),
        has(SquareTest::has_positions),
        // Motion capture: the heading is the reference.
        calibration::HeadingKind::Reference,
    )
    .filter(|m| pooled.iter().any(|p| p.method == *m));
    Ok(Replay {
        datasets: calibrate_on.iter().map(|s| s.id.clone()).collect(),
        estimates,
        uncertainty,
        pooled,
        default_method,
        failures,
        evaluations,
    })
}

/// One recording held out: every method calibrated on the other recordings of its robot,
/// pooled, and evaluated on it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HeldOut {
    /// The held-out set.
    pub dataset: String,
    /// Calibration on the others, evaluated on the held-out set.
    pub replay: Replay,
    /// The held-out set's own estimates (every method that succeeded on it alone).
    pub own: Vec<Estimate>,
}

/// Leave-one-recording-out over square sets: each set is held out in turn and every method is
/// calibrated on the other sets **of the same robot**, pooled. Sets are taken to be of one
/// robot when they share the square side (one recording campaign each in the OptiOdom data); a
/// set with no other of its robot is skipped.
pub fn leave_one_recording_out(
    sets: &[OptiOdomSet],
    convention: SplitConvention,
) -> Result<Vec<HeldOut>, DatasetError> {
    let mut out = Vec::new();
    for (i, held) in sets.iter().enumerate() {
        let others: Vec<OptiOdomSet> = sets
            .iter()
            .enumerate()
            .filter(|(j, s)| *j != i && s.side_m == held.side_m)
            .map(|(_, s)| s.clone())
            .collect();
        if others.is_empty() {
            continue;
        }
        let replay = replay(&others, std::slice::from_ref(held), convention)?;
        let own = calibration::estimate_all(&held.square_test()?, convention)?
            .into_iter()
            .filter_map(|(_, r)| r.ok())
            .collect();
        out.push(HeldOut {
            dataset: held.id.clone(),
            replay,
            own,
        });
    }
    Ok(out)
}
