//! Whether a drive's wheels and reference are in the units and signs the model takes, and
//! whether a fit's result can be a robot of the nominal geometry.
//!
//! A fit believes its inputs: poses in millimetres give a wheelbase a thousand times too long
//! with a tiny ±, wheel angles in revolutions give wheels 2π times too big. Before the fit, the
//! reference's distance over straight stretches is compared with the wheels' (at the nominal
//! geometry), and its turns with theirs ([`DriveSurvey::yaw_slope`]); a ratio far from one is
//! matched against the factors users meet — millimetres, centimetres, feet, inches for the
//! positions; revolutions, degrees and encoder counts for the wheel angles; a radius given for
//! a diameter; a nominal geometry in millimetres — and refused with the one that fits by name.
//! Then the signs: wheels that turn against the reference are swapped wheels when the wheels
//! drive forward with the reference, and both encoders counting backwards when the wheels say
//! the robot drove backward where the reference says forward (swapping them would put each
//! diameter on the other wheel).
//!
//! Wheel angles that jump in one sample at fifty times their fastest ordinary rate (and by a
//! revolution or more) are a counter that wraps or resets ([`check_wheel_jumps`]).
//!
//! After the fit ([`check_fit`]), a diameter or wheelbase beyond ±[`PLAUSIBLE_FRACTION`] of the
//! nominal, or a residual of metres, is refused with the likely cause.

use super::observability::DriveSurvey;
use super::pool::upper_median;
use super::pose_fit::{Param, PoseFit};
use super::pose_reference::{Geometry, Odometry, PoseRecording, WheelAngles};
use super::CalibrationError;
use serde::Serialize;
use std::f64::consts::{PI, TAU};

/// Largest relative departure from the nominal geometry a robot is taken to have (30 %).
pub const PLAUSIBLE_FRACTION: f64 = 0.3;
/// Largest residual standard deviation of a position a real reference has against odometry
/// (m): a localization that is metres off is not measuring this robot.
pub const PLAUSIBLE_RESIDUAL_M: f64 = 0.5;
/// Shortest span over which distances are compared (s): long enough that a reference's noise
/// is small against the distance driven.
const SPAN_S: f64 = 1.0;
/// Largest turn per distance (rad per unit of the odometry's distance) of a straight span.
const STRAIGHT: f64 = 0.2;
/// Share of the distance one way above which a drive counts as driven that way.
const MOSTLY: f64 = 0.7;

/// The scale and direction of a drive's reference against its wheels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ScaleSurvey {
    /// The reference's distance over the wheels' (nominal geometry) on straight spans; `None`
    /// with fewer than five straight spans.
    pub distance_ratio: Option<f64>,
    /// Share of the wheels' distance driven forward (along the odometry's heading).
    pub wheels_forward_share: Option<f64>,
    /// Share of the reference's distance along its own yaw (forward); `None` without yaw.
    pub reference_forward_share: Option<f64>,
}

/// Surveys `recording`'s scale and direction at the `nominal` geometry.
pub fn survey_scale(recording: &PoseRecording, nominal: Geometry) -> ScaleSurvey {
    let odo = Odometry::integrate(&recording.wheels, nominal);
    let mut hint = 0;
    let at: Vec<_> = recording
        .poses
        .iter()
        .map(|p| odo.at(p.time_s, &mut hint))
        .collect();
    // (reference's chord, odometry's chord) of each straight span.
    let mut straight = Vec::new();
    let (mut wheels_fwd, mut wheels_all) = (0.0, 0.0);
    let (mut ref_fwd, mut ref_all) = (0.0, 0.0);
    let mut start: Option<usize> = None;
    for (j, o) in at.iter().enumerate() {
        let Some(b) = o else {
            start = None;
            continue;
        };
        let Some(i) = start else {
            start = Some(j);
            continue;
        };
        let (p0, p1) = (&recording.poses[i], &recording.poses[j]);
        if p1.time_s - p0.time_s < SPAN_S {
            continue;
        }
        start = Some(j);
        let Some(a) = at[i] else { continue };
        let (dx, dy) = (b.x - a.x, b.y - a.y);
        let chord = dx.hypot(dy);
        let along = dx * a.theta.cos() + dy * a.theta.sin();
        wheels_fwd += along.max(0.0);
        wheels_all += along.abs();
        let (rx, ry) = (p1.x_m - p0.x_m, p1.y_m - p0.y_m);
        if let Some(yaw) = p0.yaw_rad {
            let along = rx * yaw.cos() + ry * yaw.sin();
            ref_fwd += along.max(0.0);
            ref_all += along.abs();
        }
        if chord > 0.0 && (b.theta - a.theta).abs() < STRAIGHT * chord {
            straight.push((rx.hypot(ry), chord));
        }
    }
    ScaleSurvey {
        distance_ratio: median_ratio(&straight),
        wheels_forward_share: (wheels_all > 0.0).then(|| wheels_fwd / wheels_all),
        reference_forward_share: (ref_all > 0.0).then(|| ref_fwd / ref_all),
    }
}

/// The median ratio of the reference's chord to the odometry's over the spans that moved at
/// least half the typical distance (creeping spans are the reference's noise, and an outlier
/// spoils a sum but not a median); `None` with fewer than five.
fn median_ratio(spans: &[(f64, f64)]) -> Option<f64> {
    let typical = upper_median(spans.iter().map(|s| s.1).collect())?;
    let ratios: Vec<f64> = spans
        .iter()
        .filter(|s| s.1 >= 0.5 * typical)
        .map(|s| s.0 / s.1)
        .collect();
    if ratios.len() < 5 {
        return None;
    }
    upper_median(ratios)
}

/// One way a drive's numbers are off by a factor: the factor on the reference's distance over
/// the wheels', the one on its turns over theirs, and what it is.
struct Cause {
    distance: f64,
    turn: f64,
    what: &'static str,
}

/// The factors users meet, each with what to do.
fn causes() -> [Cause; 9] {
    [
        Cause {
            distance: 1000.0,
            turn: 1.0,
            what: "the reference's positions are in millimetres: divide x and y by 1000",
        },
        Cause {
            distance: 100.0,
            turn: 1.0,
            what: "the reference's positions are in centimetres: divide x and y by 100",
        },
        Cause {
            distance: 1.0 / 0.3048,
            turn: 1.0,
            what: "the reference's positions are in feet: multiply x and y by 0.3048",
        },
        Cause {
            distance: 1.0 / 0.0254,
            turn: 1.0,
            what: "the reference's positions are in inches: multiply x and y by 0.0254",
        },
        Cause {
            distance: 0.001,
            turn: 1.0,
            what: "the nominal geometry is in millimetres (or the positions in kilometres): \
                   give the wheel diameters and wheelbase in metres",
        },
        Cause {
            distance: TAU,
            turn: TAU,
            what: "the wheel angles are in revolutions: multiply them by 2π",
        },
        Cause {
            distance: PI / 180.0,
            turn: PI / 180.0,
            what: "the wheel angles are in degrees: multiply them by π/180",
        },
        Cause {
            distance: 2.0,
            turn: 2.0,
            what: "the nominal wheel diameter is half the true one: a radius given for the \
                   diameter; give the diameter",
        },
        Cause {
            distance: 0.5,
            turn: 0.5,
            what: "the nominal wheel diameter is twice the true one: a diameter given for the \
                   radius; check the nominal wheel size",
        },
    ]
}

/// Whether `a` is within the plausible fraction of `b` (in ratio).
fn near(a: f64, b: f64) -> bool {
    a > 0.0 && b > 0.0 && (a / b).ln().abs() < (1.0 + PLAUSIBLE_FRACTION).ln()
}

/// The likely cause of a reference that moves `distance` times and turns `turn` times what the
/// wheels say.
fn cause_of(distance: f64, turn: Option<f64>) -> String {
    let turn_fits = |c: &Cause| turn.is_none_or(|t| near(t, c.turn));
    if let Some(c) = causes()
        .iter()
        .find(|c| near(distance, c.distance) && turn_fits(c))
    {
        return c.what.to_string();
    }
    let both = turn.is_some_and(|t| near(t, distance));
    if both && distance < 0.05 {
        // Counts per revolution: 2π over the radians a count was taken for. From the turns
        // where there are some: wheels that turn thousands of times too far wind the
        // odometry's arcs round, and its straight stretches are few.
        return format!(
            "the wheel angles look like encoder counts, about {:.0} per revolution: convert \
             them to radians (angle = counts · 2π / counts per revolution)",
            TAU / turn.unwrap_or(distance)
        );
    }
    if both {
        return "the wheel angles (or the nominal wheel diameter) are off by that factor: a \
                gear ratio, or counts rather than radians"
            .to_string();
    }
    "the reference's positions are in another unit than metres, or the nominal geometry is \
     wrong: check both"
        .to_string()
}

/// Refuses a drive whose reference and wheels are in different units or signs, by name.
pub fn check_units_and_signs(
    scale: &ScaleSurvey,
    drive: &DriveSurvey,
) -> Result<(), CalibrationError> {
    let turn = drive.yaw_slope.or(drive.path_slope);
    if let Some(k) = scale.distance_ratio {
        if !near(k.abs(), 1.0) {
            return Err(CalibrationError::PoseInput(format!(
                "on straight stretches the reference moves {k:.4}× the distance the wheels \
                 give at the nominal geometry{}: {}; then fit again",
                turn.map_or(String::new(), |t| format!(" and turns {t:.4}× their turns")),
                cause_of(k, turn.map(f64::abs))
            )));
        }
    }
    let reversed = |s: Option<f64>| s.is_some_and(|s| s < -0.5);
    let backward = scale.wheels_forward_share.is_some_and(|s| s < 1.0 - MOSTLY);
    let reference_forward = scale.reference_forward_share.is_none_or(|s| s > MOSTLY);
    if reversed(drive.path_slope)
        && (drive.yaw_slope.is_none() || reversed(drive.yaw_slope))
        && backward
        && reference_forward
    {
        return Err(CalibrationError::PoseInput(format!(
            "the wheels say the robot drove backward for {:.0} % of its distance and turned \
             against the reference (slope {:.2}){}: both encoders count backwards; negate both \
             wheel angles (or both joints' signs) and fit again (swapping the wheels would put \
             each wheel's diameter on the other)",
            100.0 * (1.0 - scale.wheels_forward_share.unwrap_or(0.0)),
            drive.path_slope.unwrap_or(f64::NAN),
            scale
                .reference_forward_share
                .map_or(String::new(), |s| format!(
                    ", while the reference drove forward for {:.0} %",
                    100.0 * s
                ))
        )));
    }
    Ok(())
}

/// How many times its fastest ordinary rate (the 99th percentile) a wheel angle must jump at in
/// one sample to be a counter's wrap or reset rather than driving.
const WRAP_FACTOR: f64 = 50.0;

/// Refuses wheel angles that jump in one sample by far more than the wheel ever turns (and by a
/// revolution or more): a counter that wraps (16 or 32 bits) or resets, which the odometry would
/// take for the robot teleporting.
pub fn check_wheel_jumps(recording: &PoseRecording) -> Result<(), CalibrationError> {
    let wheels = &recording.wheels;
    let Some(first) = wheels.first() else {
        return Ok(());
    };
    for (name, right) in [("left", false), ("right", true)] {
        let angle = |w: &WheelAngles| if right { w.right_rad } else { w.left_rad };
        // Rates, not steps: a step across a hole in the stream is driving, not a wrap.
        let steps: Vec<(f64, f64)> = wheels
            .windows(2)
            .map(|w| (angle(&w[1]) - angle(&w[0]), w[1].time_s - w[0].time_s))
            .collect();
        let mut rates: Vec<f64> = steps
            .iter()
            .filter(|(_, dt)| *dt > 0.0)
            .map(|(d, dt)| (d / dt).abs())
            .collect();
        if rates.len() < 100 {
            continue;
        }
        rates.sort_by(f64::total_cmp);
        let ordinary = rates[rates.len() * 99 / 100];
        let wrap = |(d, dt): &(f64, f64)| d.abs() > TAU && d.abs() > WRAP_FACTOR * ordinary * dt;
        if let Some((i, (step, _))) = steps.iter().enumerate().find(|(_, s)| wrap(s)) {
            return Err(CalibrationError::PoseInput(format!(
                "the {name} wheel's angle jumps by {step:+.1} rad between {:.2} s and {:.2} s \
                 (from its first sample), while 99 % of the time it turns slower than \
                 {ordinary:.2} rad/s: a counter that wraps (or resets); unwrap the angles (add \
                 the counter's range at each wrap) and fit again",
                wheels[i].time_s - first.time_s,
                wheels[i + 1].time_s - first.time_s
            )));
        }
    }
    Ok(())
}

/// A warning when the wheels drove one way and the reference the other while both turn alike:
/// both encoders negated *and* the wheels swapped, or a reference frame that faces backward.
pub fn direction_warning(scale: &ScaleSurvey) -> Option<String> {
    let (w, r) = (scale.wheels_forward_share?, scale.reference_forward_share?);
    let opposite = (w < 1.0 - MOSTLY && r > MOSTLY) || (w > MOSTLY && r < 1.0 - MOSTLY);
    opposite.then(|| {
        format!(
            "the wheels say the robot drove forward for {:.0} % of its distance, the reference \
             for {:.0} % (the fit turns the reference frame by about 180° to match): unless the \
             reference frame faces backward on the robot, both wheel angles are negated and \
             the wheels swapped — negate both and swap them back, then fit again (as they are, \
             each diameter belongs to the other wheel)",
            100.0 * w,
            100.0 * r
        )
    })
}

/// Refuses a fit whose geometry is beyond what a robot of the nominal geometry can be, or
/// whose residual is metres, with the likely cause.
pub fn check_fit(fit: &PoseFit, nominal: Geometry) -> Result<(), CalibrationError> {
    let ratios = [
        (
            "left wheel diameter",
            fit.value(Param::LeftDiameter) / nominal.left_diameter_m,
        ),
        (
            "right wheel diameter",
            fit.value(Param::RightDiameter) / nominal.right_diameter_m,
        ),
        (
            "wheelbase",
            fit.value(Param::Wheelbase) / nominal.wheelbase_m,
        ),
    ];
    if let Some((name, k)) = ratios.iter().find(|(_, k)| !near(*k, 1.0)) {
        let mean_d = 0.5 * (ratios[0].1 + ratios[1].1);
        return Err(CalibrationError::PoseInput(format!(
            "the fit puts the {name} at {k:.4}× the nominal (diameters {mean_d:.4}×, wheelbase \
             {:.4}×), beyond the ±{:.0} % a robot of the nominal geometry can be: {}; then fit \
             again",
            ratios[2].1,
            100.0 * PLAUSIBLE_FRACTION,
            cause_of(mean_d, Some(mean_d / ratios[2].1))
        )));
    }
    if fit.residual_std_position_m > PLAUSIBLE_RESIDUAL_M {
        return Err(CalibrationError::PoseInput(format!(
            "the reference departs from the fitted odometry by {:.2} m (one standard \
             deviation): it is not in metres, or not this robot's pose; check its unit and \
             topic, then fit again",
            fit.residual_std_position_m
        )));
    }
    Ok(())
}
