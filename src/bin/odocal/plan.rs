//! `odocal plan`: what a calibration will cost and reach before anything moves (it moves
//! nothing): the side that fits the floor, the runs per direction, rounds, robot time and
//! distance, and the predicted standard errors ([`odocal::calibration::plan`]).

use crate::out::print_json;
use crate::routine::ShapeFlags;
use odocal::calibration::plan::{Space, Target};
use odocal::calibration::{HeadingKind, Method};
use odocal::ranges::check_range as in_range;
use odocal::routine::config::RoutineConfig;
use odocal::routine::planning::{expected_method, plan_of, Setting, DEFAULT_FOOTPRINT_M};
use serde_json::json;

type CliResult = Result<(), Box<dyn std::error::Error>>;

/// Arguments of `odocal plan`.
#[derive(Debug, clap::Args)]
#[command(group(clap::ArgGroup::new("space").required(true).multiple(true).args(["floor_m", "side_max_m", "side_m"])))]
pub struct Args {
    /// The free floor, WIDTH,LENGTH (m, either way round): the clockwise and counter-clockwise
    /// squares lie either side of the first leg.
    #[arg(long, value_name = "W,L")]
    floor_m: Option<String>,
    /// The longest square side to consider (m), instead of --floor-m.
    #[arg(long, conflicts_with = "floor_m")]
    side_max_m: Option<f64>,
    /// Squares of exactly this side (m) instead of the largest that fits (with --floor-m: it
    /// must fit).
    #[arg(long, conflicts_with = "side_max_m")]
    side_m: Option<f64>,
    /// The heading sensor's noise per reading at rest (deg): `odocal heading --heading-samples 50`
    /// prints it.
    #[arg(long)]
    heading_sigma_deg: f64,
    /// The wheelbase configured on the robot (m).
    #[arg(long)]
    wheelbase_m: f64,
    /// The wheel diameter configured on the robot (m): with --counts-per-rev, the end point
    /// counts the rounding of every motion to whole encoder counts (a controller that drives to
    /// wheel targets in counts: our protocol's devices, a RoboClaw).
    #[arg(long, requires = "counts_per_rev")]
    wheel_diameter_m: Option<f64>,
    /// Encoder counts per wheel revolution (with --wheel-diameter-m).
    #[arg(long, requires = "wheel_diameter_m")]
    counts_per_rev: Option<f64>,
    /// What the heading sensor is (decides the default method and the compass swing):
    /// magnetic, gyro, reference or unknown.
    #[arg(long, default_value = "unknown")]
    heading_kind: HeadingKind,
    /// Heading readings per second [default: the telemetry rate, 50].
    #[arg(long)]
    heading_hz: Option<f64>,
    /// The robot's largest width (m), added to the floor the squares need.
    #[arg(long, default_value_t = DEFAULT_FOOTPRINT_M)]
    footprint_m: f64,
    /// Scatter of a run's heading error beyond the sensor's noise (deg), from an earlier
    /// calibration of this robot on this floor (slip, bumps); 0 when unknown.
    #[arg(long, default_value_t = 0.0)]
    run_scatter_deg: f64,
    /// Target RMS end-point error (m) of one square of the plan's side driven with the
    /// calibrated parameters (the rounding to whole encoder counts included when known).
    #[arg(long)]
    target_end_m: Option<f64>,
    #[command(flatten)]
    shape: ShapeFlags,
    /// Print the plan as one JSON object.
    #[arg(long)]
    json: bool,
}

fn parse_floor(s: &str) -> Result<Space, String> {
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

/// Refuses a side whose two squares do not fit the floor, with what they need.
fn side_fits(floor: Space, side_m: f64, footprint_m: f64) -> Result<(), String> {
    let largest = odocal::calibration::plan::largest_side(floor, footprint_m);
    if side_m <= largest + 1e-9 {
        return Ok(());
    }
    let [along, across] = odocal::calibration::plan::floor_needed(side_m, footprint_m);
    Err(format!(
        "--side-m {side_m}: two squares of {side_m} m need {along:.1} × {across:.1} m of floor \
         (with the robot's footprint and 10 % for drift); the floor given holds squares of at most {:.1} m: give \
         a shorter --side-m or leave it out for the largest that fits",
        (largest * 10.0).floor() / 10.0
    ))
}

/// Runs `odocal plan`.
pub fn run(args: Args) -> CliResult {
    in_range("--heading-sigma-deg", args.heading_sigma_deg, 0.0, 45.0)?;
    // Below a millionth of a degree no sensor reads, and its square would underflow.
    if args.heading_sigma_deg > 0.0 && args.heading_sigma_deg < 1e-6 {
        return Err(format!(
            "--heading-sigma-deg must be 0 (noise-free) or in [1e-6, 45] deg, got {}",
            odocal::ranges::compact(args.heading_sigma_deg)
        )
        .into());
    }
    in_range("--run-scatter-deg", args.run_scatter_deg, 0.0, 45.0)?;
    in_range("--wheelbase-m", args.wheelbase_m, 0.01, 10.0)?;
    in_range("--footprint-m", args.footprint_m, 0.0, 10.0)?;
    if let Some(hz) = args.heading_hz {
        in_range("--heading-hz", hz, 0.1, 1000.0)?;
    }
    if let Some(t) = args.target_end_m {
        in_range("--target-end-m", t, 1e-6, 10.0)?;
    }
    let floor = args.floor_m.as_deref().map(parse_floor).transpose()?;
    let space = match (floor, args.side_max_m, args.side_m) {
        (floor, _, Some(side)) => {
            if let Some(floor) = floor {
                side_fits(floor, side, args.footprint_m)?;
            }
            Space::Side(side)
        }
        (Some(floor), _, None) => floor,
        (None, Some(s), None) => Space::MaxSide(s),
        (None, None, None) => return Err("give --floor-m W,L, --side-max-m or --side-m".into()),
    };
    let m_per_count = match (args.wheel_diameter_m, args.counts_per_rev) {
        (Some(d), Some(n)) => {
            in_range("--wheel-diameter-m", d, 0.01, 2.0)?;
            in_range("--counts-per-rev", n, 1.0, 1e9)?;
            std::f64::consts::PI * d / n
        }
        _ => 0.0,
    };
    let mut cfg = RoutineConfig::default();
    args.shape.apply(&mut cfg);
    cfg.validate()?;
    let setting = Setting {
        space: Some(space),
        footprint_m: args.footprint_m,
        wheelbase_m: args.wheelbase_m,
        heading_sigma_rad: args.heading_sigma_deg.to_radians(),
        heading_kind: args.heading_kind,
        readings_per_s: args.heading_hz,
        run_scatter_rad: args.run_scatter_deg.to_radians(),
        m_per_count,
    };
    // An end-point target is the plan's alone: the routine stops on standard errors.
    let with_end = |cfg: &RoutineConfig| -> Result<_, Box<dyn std::error::Error>> {
        let mut input = odocal::routine::planning::plan_input(cfg, &setting);
        input.target = Target {
            end_point_m: args.target_end_m,
            ..input.target
        };
        Ok(odocal::calibration::plan::plan(&input)?)
    };
    let plan = with_end(&cfg)?;
    // Today's fixed plan on the same floor, for comparison.
    let fixed_cfg = RoutineConfig {
        target_e_b_std: None,
        target_e_d_std: None,
        ..cfg.clone()
    };
    let fixed = plan_of(&fixed_cfg, &setting)?;
    let method = expected_method(&cfg, args.heading_kind);
    if args.json {
        print_json(&json!({
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
            "fixed_plan": fixed,
            "moves": false,
        }))?;
    } else {
        println!(
            "odocal plan (moves nothing): {method} is the estimate written (heading {}, σ {}° \
             per reading); {}",
            args.heading_kind,
            args.heading_sigma_deg,
            if plan.sequential {
                let mut targets = Vec::new();
                if let Some(t) = cfg.target_e_b_std {
                    targets.push(format!("E_b's standard error at most {t:e}"));
                }
                if let Some(t) = cfg.target_e_d_std {
                    targets.push(format!("E_d's standard error at most {t:e}"));
                }
                if let Some(t) = args.target_end_m {
                    targets.push(format!("an end point of {:.1} mm RMS", 1000.0 * t));
                }
                format!(
                    "the rounds stop once the target is reached ({})",
                    targets.join(", ")
                )
            } else {
                "a fixed number of squares (--target-eb-std or --target-ed-std instead drives \
                 them in pairs until the estimate is that precise)"
                    .to_string()
            }
        );
        println!("{plan}");
        if plan.end_point_from_rounding_m == 0.0 {
            println!(
                "(give --wheel-diameter-m and --counts-per-rev to count the rounding to whole \
                 encoder counts of a controller that drives to wheel targets: millimetres on \
                 4 m squares)"
            );
        }
        if plan.sequential {
            // The same side either way: only the number of squares differs.
            println!(
                "without a target, on the same {:.2} m squares ({} per direction, confirmed, \
                 verified): {} squares, {}, E_b ± {:.2e}, E_d ± {:.2e}",
                fixed.side_m,
                fixed.runs_per_direction,
                fixed.squares,
                odocal::calibration::plan::duration_text(fixed.robot_time_s),
                fixed.predicted_std_e_b,
                fixed.predicted_std_e_d
            );
        }
        let mut flags = format!("--side-m {}", plan.side_m);
        for (flag, v) in [
            ("--target-eb-std", cfg.target_e_b_std),
            ("--target-ed-std", cfg.target_e_d_std),
        ] {
            if let Some(v) = v {
                flags.push_str(&format!(" {flag} {v}"));
            }
        }
        if !plan.sequential {
            flags.push_str(&format!(" --runs {}", plan.runs_per_direction));
        } else if args.target_end_m.is_some() && cfg.target().is_none() {
            // The routine stops on standard errors: the end-point target's, as the plan
            // predicts them.
            flags.push_str(&format!(
                " --target-eb-std {:.2e} --target-ed-std {:.2e}",
                plan.predicted_std_e_b, plan.predicted_std_e_d
            ));
        }
        println!("to drive it: odocal calibrate … {flags}");
        if matches!(method, Method::Legs | Method::MatchedLegs) {
            println!(
                "(the leg methods' prediction counts every reading along a leg as independent: \
                 a sensor that filters averages less)"
            );
        }
    }
    if !plan.target_reached {
        return Err(format!(
            "the target is not reached within {} runs per direction: more floor, more readings \
             at rest (--heading-samples), a quieter heading sensor or --max-runs",
            cfg.max_runs_per_direction
        )
        .into());
    }
    Ok(())
}
