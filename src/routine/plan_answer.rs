//! `odocal plan`'s answer, before anything moves (it moves nothing): the plan of a routine's
//! settings on the floor given ([`super::planning`]), today's fixed plan beside it, the method
//! whose estimate would be written, and the words and flags to drive it.

use super::config::RoutineConfig;
use super::overrides::Shape;
use super::planning::{expected_method, plan_input, plan_of, Setting};
use crate::calibration::plan::{
    duration_text, floor_needed, largest_side, plan, Plan, Space, Target,
};
use crate::calibration::{HeadingKind, Method};
use crate::ranges::{check_range, compact};
use serde_json::json;
use std::fmt::Write as _;

/// What `odocal plan` is asked: the robot and floor as given, and the routine's shape (with the
/// `cli` feature, `odocal plan`'s flags, their doc comments the help).
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[cfg_attr(feature = "cli", command(group(clap::ArgGroup::new("space").required(true).multiple(true).args(["floor_m", "side_max_m", "side_m"]))))]
pub struct PlanRequest {
    /// The free floor, WIDTH,LENGTH (m, either way round): the clockwise and counter-clockwise
    /// squares lie either side of the first leg.
    #[cfg_attr(feature = "cli", arg(long = "floor-m", value_name = "W,L"))]
    pub floor_m: Option<String>,
    /// The longest square side to consider (m), instead of --floor-m.
    #[cfg_attr(feature = "cli", arg(long, conflicts_with = "floor_m"))]
    pub side_max_m: Option<f64>,
    /// Squares of exactly this side (m) instead of the largest that fits (with --floor-m: it
    /// must fit).
    #[cfg_attr(feature = "cli", arg(long, conflicts_with = "side_max_m"))]
    pub side_m: Option<f64>,
    /// The heading sensor's noise per reading at rest (deg): `odocal heading --heading-samples 50`
    /// prints it.
    #[cfg_attr(feature = "cli", arg(long))]
    pub heading_sigma_deg: f64,
    /// The wheelbase configured on the robot (m).
    #[cfg_attr(feature = "cli", arg(long))]
    pub wheelbase_m: f64,
    /// The wheel diameter configured on the robot (m): with --counts-per-rev, the end point
    /// counts the rounding of every motion to whole encoder counts (a controller that drives to
    /// wheel targets in counts: our protocol's devices, a RoboClaw).
    #[cfg_attr(feature = "cli", arg(long, requires = "counts_per_rev"))]
    pub wheel_diameter_m: Option<f64>,
    /// Encoder counts per wheel revolution (with --wheel-diameter-m).
    #[cfg_attr(feature = "cli", arg(long, requires = "wheel_diameter_m"))]
    pub counts_per_rev: Option<f64>,
    /// What the heading sensor is (decides the default method and the compass swing):
    /// magnetic, gyro, reference or unknown.
    #[cfg_attr(feature = "cli", arg(long, default_value = "unknown"))]
    pub heading_kind: HeadingKind,
    /// Heading readings per second [default: the telemetry rate, 50].
    #[cfg_attr(feature = "cli", arg(long))]
    pub heading_hz: Option<f64>,
    /// The robot's largest width (m), added to the floor the squares need.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = super::planning::DEFAULT_FOOTPRINT_M))]
    pub footprint_m: f64,
    /// Scatter of a run's heading error beyond the sensor's noise (deg), from an earlier
    /// calibration of this robot on this floor (slip, bumps); 0 when unknown.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.0))]
    pub run_scatter_deg: f64,
    /// Target RMS end-point error (m) of one square of the plan's side driven with the
    /// calibrated parameters (the rounding to whole encoder counts included when known).
    #[cfg_attr(feature = "cli", arg(long))]
    pub target_end_m: Option<f64>,
    /// What the calibration drives: the routine's defaults with these set.
    #[cfg_attr(feature = "cli", command(flatten))]
    pub shape: Shape,
}

impl PlanRequest {
    /// Wheel diameter (m) and counts per revolution, when both are given.
    fn wheel(&self) -> Option<(f64, f64)> {
        self.wheel_diameter_m.zip(self.counts_per_rev)
    }
}

/// What it gets back.
#[derive(Debug, Clone, PartialEq)]
pub struct PlanAnswer {
    /// The plan of the settings.
    pub plan: Plan,
    /// The plan without a precision target, on the same floor.
    pub fixed: Plan,
    /// The method whose estimate would be written.
    pub method: Method,
    /// The routine's settings planned (its defaults with the request's shape).
    pub cfg: RoutineConfig,
    /// The request.
    pub request: PlanRequest,
}

/// Refuses a side whose two squares do not fit the floor, with what they need.
fn side_fits(floor: Space, side_m: f64, footprint_m: f64) -> Result<(), String> {
    let largest = largest_side(floor, footprint_m);
    if side_m <= largest + 1e-9 {
        return Ok(());
    }
    let [along, across] = floor_needed(side_m, footprint_m);
    Err(format!(
        "--side-m {side_m}: two squares of {side_m} m need {along:.1} × {across:.1} m of floor \
         (with the robot's footprint and 10 % for drift); the floor given holds squares of at \
         most {:.1} m: give a shorter --side-m or leave it out for the largest that fits",
        (largest * 10.0).floor() / 10.0
    ))
}

/// Every number of the request within the range a robot and a sensor have, by flag.
fn check(r: &PlanRequest) -> Result<(), String> {
    check_range("--heading-sigma-deg", r.heading_sigma_deg, 0.0, 45.0)?;
    // Below a millionth of a degree no sensor reads, and its square would underflow.
    if r.heading_sigma_deg > 0.0 && r.heading_sigma_deg < 1e-6 {
        return Err(format!(
            "--heading-sigma-deg must be 0 (noise-free) or in [1e-6, 45] deg, got {}",
            compact(r.heading_sigma_deg)
        ));
    }
    check_range("--run-scatter-deg", r.run_scatter_deg, 0.0, 45.0)?;
    check_range("--wheelbase-m", r.wheelbase_m, 0.01, 10.0)?;
    check_range("--footprint-m", r.footprint_m, 0.0, 10.0)?;
    if let Some(hz) = r.heading_hz {
        check_range("--heading-hz", hz, 0.1, 1000.0)?;
    }
    if let Some(t) = r.target_end_m {
        check_range("--target-end-m", t, 1e-6, 10.0)?;
    }
    Ok(())
}

/// `--floor-m WIDTH,LENGTH` (m).
pub fn parse_floor(s: &str) -> Result<Space, String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    let [w, l] = parts.as_slice() else {
        return Err(format!(
            "--floor-m {s:?}: give WIDTH,LENGTH in metres, e.g. 5,9"
        ));
    };
    let num = |v: &str| {
        v.parse::<f64>()
            .map_err(|_| format!("--floor-m {s:?}: {v:?} is not a number of metres"))
    };
    Ok(Space::Floor {
        width_m: num(w)?,
        length_m: num(l)?,
    })
}

/// Plans `request`; an error names the flag to change.
pub fn answer(request: PlanRequest) -> Result<PlanAnswer, Box<dyn std::error::Error>> {
    check(&request)?;
    let floor = request.floor_m.as_deref().map(parse_floor).transpose()?;
    let space = match (floor, request.side_max_m, request.side_m) {
        (floor, _, Some(side)) => {
            if let Some(floor) = floor {
                side_fits(floor, side, request.footprint_m)?;
            }
            Space::Side(side)
        }
        (Some(floor), _, None) => floor,
        (None, Some(s), None) => Space::MaxSide(s),
        (None, None, None) => return Err("give --floor-m W,L, --side-max-m or --side-m".into()),
    };
    if let Some((d, n)) = request.wheel() {
        check_range("--wheel-diameter-m", d, 0.01, 2.0)?;
        check_range("--counts-per-rev", n, 1.0, 1e9)?;
    }
    let mut cfg = RoutineConfig::default();
    request.shape.apply(&mut cfg);
    cfg.validate()?;
    let setting = Setting {
        space: Some(space),
        footprint_m: request.footprint_m,
        wheelbase_m: request.wheelbase_m,
        heading_sigma_rad: request.heading_sigma_deg.to_radians(),
        heading_kind: request.heading_kind,
        readings_per_s: request.heading_hz,
        run_scatter_rad: request.run_scatter_deg.to_radians(),
        m_per_count: request
            .wheel()
            .map_or(0.0, |(d, n)| std::f64::consts::PI * d / n),
    };
    // An end-point target is the plan's alone: the routine stops on standard errors.
    let mut input = plan_input(&cfg, &setting);
    input.target = Target {
        end_point_m: request.target_end_m,
        ..input.target
    };
    let planned = plan(&input)?;
    // Today's fixed plan on the same floor, for comparison.
    let fixed_cfg = RoutineConfig {
        target_e_b_std: None,
        target_e_d_std: None,
        ..cfg.clone()
    };
    let fixed = plan_of(&fixed_cfg, &setting)?;
    let method = expected_method(&cfg, request.heading_kind);
    Ok(PlanAnswer {
        plan: planned,
        fixed,
        method,
        cfg,
        request,
    })
}

impl PlanAnswer {
    /// The answer as stdout's JSON.
    pub fn json(&self) -> serde_json::Value {
        let plan = &self.plan;
        json!({
            "side_m": plan.side_m,
            "runs_per_direction": plan.runs_per_direction,
            "rounds": plan.rounds,
            "squares": plan.squares,
            "robot_time_s": plan.robot_time_s,
            "distance_m": plan.distance_m,
            "predicted_std_e_b": plan.predicted_std_e_b,
            "predicted_std_e_d": plan.predicted_std_e_d,
            "predicted_end_point_m": plan.predicted_end_point_m,
            "plan": plan,
            "fixed_plan": self.fixed,
            "moves": false,
        })
    }

    /// Why the rounds stop: the targets, or a fixed number of squares.
    fn stopping(&self) -> String {
        let cfg = &self.cfg;
        if !self.plan.sequential {
            return "a fixed number of squares (--target-eb-std or --target-ed-std instead drives \
                    them in pairs until the estimate is that precise)"
                .to_string();
        }
        let mut targets = Vec::new();
        if let Some(t) = cfg.target_e_b_std {
            targets.push(format!("E_b's standard error at most {t:e}"));
        }
        if let Some(t) = cfg.target_e_d_std {
            targets.push(format!("E_d's standard error at most {t:e}"));
        }
        if let Some(t) = self.request.target_end_m {
            targets.push(format!("an end point of {:.1} mm RMS", 1000.0 * t));
        }
        format!(
            "the rounds stop once the target is reached ({})",
            targets.join(", ")
        )
    }

    /// The flags of `odocal calibrate` that drive this plan.
    fn flags(&self) -> String {
        let (plan, cfg) = (&self.plan, &self.cfg);
        let mut flags = format!("--side-m {}", plan.side_m);
        for (flag, v) in [
            ("--target-eb-std", cfg.target_e_b_std),
            ("--target-ed-std", cfg.target_e_d_std),
        ] {
            if let Some(v) = v {
                let _ = write!(flags, " {flag} {v}");
            }
        }
        if !plan.sequential {
            let _ = write!(flags, " --runs {}", plan.runs_per_direction);
        } else if self.request.target_end_m.is_some() && cfg.target().is_none() {
            // The routine stops on standard errors: the end-point target's, as the plan
            // predicts them.
            let _ = write!(
                flags,
                " --target-eb-std {:.2e} --target-ed-std {:.2e}",
                plan.predicted_std_e_b, plan.predicted_std_e_d
            );
        }
        flags
    }

    /// The answer as the terminal shows it.
    pub fn text(&self) -> String {
        let (plan, fixed) = (&self.plan, &self.fixed);
        let mut out = String::new();
        let _ = writeln!(
            out,
            "odocal plan (moves nothing): {} is the estimate written (heading {}, σ {}° per \
             reading); {}",
            self.method,
            self.request.heading_kind,
            self.request.heading_sigma_deg,
            self.stopping()
        );
        let _ = writeln!(out, "{plan}");
        if plan.end_point_from_rounding_m == 0.0 {
            let _ = writeln!(
                out,
                "(give --wheel-diameter-m and --counts-per-rev to count the rounding to whole \
                 encoder counts of a controller that drives to wheel targets: millimetres on \
                 4 m squares)"
            );
        }
        if plan.sequential {
            // The same side either way: only the number of squares differs.
            let _ = writeln!(
                out,
                "without a target, on the same {:.2} m squares ({} per direction, confirmed, \
                 verified): {} squares, {}, E_b ± {:.2e}, E_d ± {:.2e}",
                fixed.side_m,
                fixed.runs_per_direction,
                fixed.squares,
                duration_text(fixed.robot_time_s),
                fixed.predicted_std_e_b,
                fixed.predicted_std_e_d
            );
        }
        let _ = writeln!(out, "to drive it: odocal calibrate … {}", self.flags());
        if matches!(self.method, Method::Legs | Method::MatchedLegs) {
            let _ = writeln!(
                out,
                "(the leg methods' prediction counts every reading along a leg as independent: \
                 a sensor that filters averages less)"
            );
        }
        out
    }

    /// `Err` with what to change when the plan does not reach its target.
    pub fn check_reached(&self) -> Result<(), String> {
        if self.plan.target_reached {
            return Ok(());
        }
        Err(format!(
            "the target is not reached within {} runs per direction: more floor, more readings \
             at rest (--heading-samples), a quieter heading sensor or --max-runs",
            self.cfg.max_runs_per_direction
        ))
    }
}
