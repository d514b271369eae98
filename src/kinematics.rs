//! Differential-drive kinematics: wheel parameters, the exact pose update, angle wrapping, the
//! calibration ratios `E_d`/`E_b`, and how a ratio estimate becomes new controller parameters.
//!
//! # Sign conventions (defined here, once, for the whole crate)
//! - The robot frame has `x` forward and `y` to the left. Headings are counter-clockwise
//!   positive (seen from above), in radians, wrapped to `(-π, π]` by [`wrap_angle`].
//! - A positive wheel arc drives that wheel forward. Right wheel faster than left turns the robot
//!   counter-clockwise (positive heading change).
//! - `E_d = D_R / D_L` (right over left actual diameter) and `E_b = b_actual / b_configured`,
//!   both *relative to the parameters the controller used while the test ran* (the paper's
//!   nominal parameters on a first calibration). This is what makes repeated calibrations
//!   compound: each round multiplies the configured parameters by a [`Correction`].

use serde::{Deserialize, Serialize};
use std::f64::consts::PI;
use std::str::FromStr;

/// Errors of the kinematics layer: parameters no robot can have.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum KinematicsError {
    /// A length or count that must be finite and strictly positive was not.
    #[error("{name} must be finite and > 0, got {value}")]
    NotPositive {
        /// Which parameter.
        name: &'static str,
        /// The offending value.
        value: f64,
    },
    /// A straight-line distance check cannot fix the wheel scale (e.g. zero distance measured).
    #[error("straight-line scale check is unusable: {0}")]
    BadScaleCheck(String),
    /// A parameter outside the physical range of any robot odocal calibrates.
    #[error("{name} {value} is outside [{lo}, {hi}]")]
    Unphysical {
        /// Which parameter.
        name: &'static str,
        /// The offending value.
        value: f64,
        /// Smallest allowed.
        lo: f64,
        /// Largest allowed.
        hi: f64,
    },
}

/// Wheel diameters odocal accepts from files and streams (m): 1 mm to 5 m.
pub const PHYSICAL_DIAMETER_M: (f64, f64) = (1e-3, 5.0);
/// Wheelbases odocal accepts from files and streams (m): 1 cm to 10 m.
pub const PHYSICAL_WHEELBASE_M: (f64, f64) = (1e-2, 10.0);
/// Encoder counts per wheel revolution odocal accepts: 1 to 10⁹.
pub const PHYSICAL_COUNTS_PER_REV: (f64, f64) = (1.0, 1e9);

/// Wraps an angle to `(-π, π]`.
pub fn wrap_angle(angle_rad: f64) -> f64 {
    if !angle_rad.is_finite() || (angle_rad > -PI && angle_rad <= PI) {
        // Already in range (most angles a fit compares): returned as they are, exactly.
        return angle_rad;
    }
    // The nearest whole number of turns taken off (a division and a rounding: `rem_euclid`'s
    // exact remainder cost a tenth of a pose fit), then the ends of the half-open interval;
    // beyond a million turns the product's rounding error exceeds a turn: the exact remainder.
    let mut a = if angle_rad.abs() < 1e6 {
        angle_rad - (angle_rad / (2.0 * PI)).round() * (2.0 * PI)
    } else {
        (angle_rad + PI).rem_euclid(2.0 * PI) - PI
    };
    if a <= -PI {
        a += 2.0 * PI;
    } else if a > PI {
        a -= 2.0 * PI;
    }
    a
}

/// The circular mean of `angles` (rad), wrapped to (−π, π]: the direction of the sum of
/// their unit vectors, so readings either side of ±π average near ±π. `None` for no angles.
pub fn circular_mean(angles: impl IntoIterator<Item = f64>) -> Option<f64> {
    let (s, c, n) = angles.into_iter().fold((0.0, 0.0, 0usize), |(s, c, n), a| {
        (s + a.sin(), c + a.cos(), n + 1)
    });
    (n > 0).then(|| wrap_angle(s.atan2(c)))
}

/// `sin(x)/x`, accurate near zero (used by the exact arc update and the scale check).
pub fn sinc(x: f64) -> f64 {
    if x.abs() < 1e-4 {
        let x2 = x * x;
        1.0 - x2 / 6.0 + x2 * x2 / 120.0
    } else {
        x.sin() / x
    }
}

/// What the odometry makes of one interval of wheel travel: how far the robot's centre went
/// forward and how far it turned.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Displacement {
    /// Forward travel of the centre between the wheels (m): the mean of the wheel arcs.
    pub distance_m: f64,
    /// Turn (rad, counter-clockwise positive, not wrapped).
    pub turn_rad: f64,
}

impl Displacement {
    /// The displacement of wheel arcs `left_m`, `right_m` (m, forward positive) on a
    /// `wheelbase_m` base: the one place the crate writes the turn `(s_R − s_L)/b`.
    pub fn of_wheels(left_m: f64, right_m: f64, wheelbase_m: f64) -> Self {
        Displacement {
            distance_m: 0.5 * (left_m + right_m),
            turn_rad: (right_m - left_m) / wheelbase_m,
        }
    }

    /// The wheel arcs (left, right; m) that make this displacement on a `wheelbase_m` base:
    /// the inverse of [`Displacement::of_wheels`].
    pub fn wheels(&self, wheelbase_m: f64) -> (f64, f64) {
        let half = 0.5 * self.turn_rad * wheelbase_m;
        (self.distance_m - half, self.distance_m + half)
    }

    /// The sum of two displacements.
    pub fn plus(&self, other: &Displacement) -> Self {
        Displacement {
            distance_m: self.distance_m + other.distance_m,
            turn_rad: self.turn_rad + other.turn_rad,
        }
    }
}

fn check_positive(name: &'static str, value: f64) -> Result<(), KinematicsError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(KinematicsError::NotPositive { name, value })
    }
}

/// Kinematic parameters of a differential-drive base (true or as configured on a controller).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WheelParams {
    /// Left wheel diameter (m).
    pub left_wheel_diameter_m: f64,
    /// Right wheel diameter (m).
    pub right_wheel_diameter_m: f64,
    /// Distance between the wheels' contact points (m).
    pub wheelbase_m: f64,
    /// Encoder counts per wheel revolution (after any gearbox); fractional values are allowed.
    pub counts_per_wheel_rev: f64,
}

impl std::fmt::Display for WheelParams {
    /// `left wheel 0.150000 m, right wheel 0.148800 m, wheelbase 0.380659 m, 4096 counts/rev`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "left wheel {:.6} m, right wheel {:.6} m, wheelbase {:.6} m, {} counts/rev",
            self.left_wheel_diameter_m,
            self.right_wheel_diameter_m,
            self.wheelbase_m,
            self.counts_per_wheel_rev
        )
    }
}

impl WheelParams {
    /// Equal wheels of `wheel_diameter_m` on a `wheelbase_m` base.
    pub fn nominal(wheel_diameter_m: f64, wheelbase_m: f64, counts_per_wheel_rev: f64) -> Self {
        Self {
            left_wheel_diameter_m: wheel_diameter_m,
            right_wheel_diameter_m: wheel_diameter_m,
            wheelbase_m,
            counts_per_wheel_rev,
        }
    }

    /// The parameters of a robot whose ratios to `nominal` are `e_b`, `e_d`, split by `split`
    /// (how the paper defines a mis-calibrated robot for simulation).
    pub fn from_ratios(
        nominal: &WheelParams,
        e_b: f64,
        e_d: f64,
        split: &SplitConvention,
    ) -> Result<Self, KinematicsError> {
        split.split(e_b, e_d, nominal.wheelbase_m)?.apply(nominal)
    }

    /// Checks every field is finite and strictly positive.
    pub fn validate(&self) -> Result<(), KinematicsError> {
        check_positive("left_wheel_diameter_m", self.left_wheel_diameter_m)?;
        check_positive("right_wheel_diameter_m", self.right_wheel_diameter_m)?;
        check_positive("wheelbase_m", self.wheelbase_m)?;
        check_positive("counts_per_wheel_rev", self.counts_per_wheel_rev)
    }

    /// Checks the parameters lie in the physical ranges ([`PHYSICAL_DIAMETER_M`],
    /// [`PHYSICAL_WHEELBASE_M`], [`PHYSICAL_COUNTS_PER_REV`]) that input from files and
    /// streams must meet before anything is computed from it (a 1e300 diameter would make
    /// every later bound meaningless).
    pub fn check_physical(&self) -> Result<(), KinematicsError> {
        for (name, value, (lo, hi)) in [
            (
                "left_wheel_diameter_m",
                self.left_wheel_diameter_m,
                PHYSICAL_DIAMETER_M,
            ),
            (
                "right_wheel_diameter_m",
                self.right_wheel_diameter_m,
                PHYSICAL_DIAMETER_M,
            ),
            ("wheelbase_m", self.wheelbase_m, PHYSICAL_WHEELBASE_M),
            (
                "counts_per_wheel_rev",
                self.counts_per_wheel_rev,
                PHYSICAL_COUNTS_PER_REV,
            ),
        ] {
            if !(value.is_finite() && (lo..=hi).contains(&value)) {
                return Err(KinematicsError::Unphysical {
                    name,
                    value,
                    lo,
                    hi,
                });
            }
        }
        Ok(())
    }

    /// `E_d = D_R / D_L` of these parameters.
    pub fn e_d(&self) -> f64 {
        self.right_wheel_diameter_m / self.left_wheel_diameter_m
    }

    /// `E_b` of these parameters relative to a reference wheelbase.
    pub fn e_b_relative_to(&self, reference_wheelbase_m: f64) -> f64 {
        self.wheelbase_m / reference_wheelbase_m
    }

    /// Left wheel travel per encoder count (m).
    pub fn left_m_per_count(&self) -> f64 {
        PI * self.left_wheel_diameter_m / self.counts_per_wheel_rev
    }

    /// Right wheel travel per encoder count (m).
    pub fn right_m_per_count(&self) -> f64 {
        PI * self.right_wheel_diameter_m / self.counts_per_wheel_rev
    }

    /// Wheel travel (left, right; m) of encoder count increments under these parameters.
    pub fn travel_m(&self, left_counts: f64, right_counts: f64) -> (f64, f64) {
        (
            left_counts * self.left_m_per_count(),
            right_counts * self.right_m_per_count(),
        )
    }

    /// The odometry's displacement for encoder count increments under these parameters.
    pub fn displacement(&self, left_counts: f64, right_counts: f64) -> Displacement {
        let (l, r) = self.travel_m(left_counts, right_counts);
        Displacement::of_wheels(l, r, self.wheelbase_m)
    }

    /// Pose change for encoder count increments interpreted with these parameters.
    pub fn odometry_step(&self, pose: &Pose, left_counts: f64, right_counts: f64) -> Pose {
        let (l, r) = self.travel_m(left_counts, right_counts);
        pose.advance(l, r, self.wheelbase_m)
    }
}

/// Which way a square is driven: clockwise turns right at each corner.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Direction {
    /// Clockwise: four right (negative) 90° turns; the square lies to the right of the first leg.
    Cw,
    /// Counter-clockwise: four left (positive) 90° turns; the square lies to the left.
    Ccw,
}

impl std::fmt::Display for Direction {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Direction::Cw => "clockwise",
            Direction::Ccw => "counter-clockwise",
        })
    }
}

impl Direction {
    /// `+1` for counter-clockwise, `-1` for clockwise (the sign of each corner turn).
    pub fn turn_sign(self) -> f64 {
        match self {
            Direction::Cw => -1.0,
            Direction::Ccw => 1.0,
        }
    }

    /// The direction of a square whose whole turn was `turn_rad` (rad, unwrapped): within
    /// `tolerance_rad` of −2π clockwise, of +2π counter-clockwise; otherwise not a square.
    pub fn of_square_turn(turn_rad: f64, tolerance_rad: f64) -> Option<Direction> {
        let full = 2.0 * std::f64::consts::PI;
        if (turn_rad + full).abs() < tolerance_rad {
            Some(Direction::Cw)
        } else if (turn_rad - full).abs() < tolerance_rad {
            Some(Direction::Ccw)
        } else {
            None
        }
    }
}

/// A planar pose: position (m) and counter-clockwise heading (rad, wrapped to `(-π, π]`).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Pose {
    /// x position (m).
    pub x_m: f64,
    /// y position (m).
    pub y_m: f64,
    /// Heading (rad), counter-clockwise positive, wrapped to `(-π, π]`.
    pub heading_rad: f64,
}

impl Pose {
    /// A pose at `(x_m, y_m)` facing `heading_rad` (wrapped).
    pub fn new(x_m: f64, y_m: f64, heading_rad: f64) -> Self {
        Self {
            x_m,
            y_m,
            heading_rad: wrap_angle(heading_rad),
        }
    }

    /// Exact pose after the wheels travel `left_arc_m`, `right_arc_m` at constant ratio.
    ///
    /// Constant wheel-speed ratio means a circular arc (a straight line or an in-place turn are
    /// its limits). The chord of an arc of length `s` turning `Δθ` is `s·sinc(Δθ/2)` in the
    /// direction `θ + Δθ/2`; written this way one formula is exact and well-conditioned for every
    /// `Δθ`, including the straight-line limit.
    pub fn advance(&self, left_arc_m: f64, right_arc_m: f64, wheelbase_m: f64) -> Pose {
        let Displacement {
            distance_m: ds,
            turn_rad: dtheta,
        } = Displacement::of_wheels(left_arc_m, right_arc_m, wheelbase_m);
        let chord = ds * sinc(0.5 * dtheta);
        let mid = self.heading_rad + 0.5 * dtheta;
        Pose {
            x_m: self.x_m + chord * mid.cos(),
            y_m: self.y_m + chord * mid.sin(),
            heading_rad: wrap_angle(self.heading_rad + dtheta),
        }
    }

    /// This pose expressed in the frame of `origin` (position rotated into it, heading relative).
    pub fn relative_to(&self, origin: &Pose) -> Pose {
        let (s, c) = origin.heading_rad.sin_cos();
        let dx = self.x_m - origin.x_m;
        let dy = self.y_m - origin.y_m;
        Pose {
            x_m: c * dx + s * dy,
            y_m: -s * dx + c * dy,
            heading_rad: wrap_angle(self.heading_rad - origin.heading_rad),
        }
    }

    /// Distance from the origin (m).
    pub fn distance_m(&self) -> f64 {
        self.x_m.hypot(self.y_m)
    }
}

/// Multiplicative corrections to the parameters a controller had configured during a test.
///
/// New parameters are the configured ones times these factors, so successive calibrations
/// compound. `E_d = right/left` and `E_b = wheelbase_scale`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Correction {
    /// Factor on the configured left wheel diameter.
    pub left_diameter_scale: f64,
    /// Factor on the configured right wheel diameter.
    pub right_diameter_scale: f64,
    /// Factor on the configured wheelbase (`E_b`).
    pub wheelbase_scale: f64,
}

impl Correction {
    /// `E_d` this correction encodes (right factor over left factor).
    pub fn e_d(&self) -> f64 {
        self.right_diameter_scale / self.left_diameter_scale
    }

    /// `E_b` this correction encodes.
    pub fn e_b(&self) -> f64 {
        self.wheelbase_scale
    }

    /// Applies the correction to the parameters currently on the controller.
    pub fn apply(&self, configured: &WheelParams) -> Result<WheelParams, KinematicsError> {
        let out = WheelParams {
            left_wheel_diameter_m: configured.left_wheel_diameter_m * self.left_diameter_scale,
            right_wheel_diameter_m: configured.right_wheel_diameter_m * self.right_diameter_scale,
            wheelbase_m: configured.wheelbase_m * self.wheelbase_scale,
            counts_per_wheel_rev: configured.counts_per_wheel_rev,
        };
        out.validate()?;
        Ok(out)
    }
}

/// Fastest a wheel of a robot this tool calibrates can travel (m/s). Recorded counts beyond it
/// between two samples are corrupt data, not a wheel (telemetry logs, recorded sets).
pub const MAX_WHEEL_SPEED_M_S: f64 = 20.0;

/// A magnetic compass's deviation curve `[A₁, B₁, A₂, B₂]` (rad): a compass on a robot reads
/// `ψ + d(ψ)` for a true heading `ψ`, with `d(ψ) = A₁·sin ψ + B₁·cos ψ + A₂·sin 2ψ + B₂·cos 2ψ`
/// (hard and soft iron: motors, battery, steel; marine practice's B, C, D, E — its constant A
/// is a bias that no heading change sees).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Deviation(pub [f64; 4]);

impl Deviation {
    /// `d(ψ)` (rad) at heading `psi` (rad).
    pub fn at(&self, psi: f64) -> f64 {
        let [a1, b1, a2, b2] = self.0;
        a1 * psi.sin() + b1 * psi.cos() + a2 * (2.0 * psi).sin() + b2 * (2.0 * psi).cos()
    }

    /// The true heading of a compass reading `r` (rad): `r − d(ψ)`, solved by fixed-point
    /// iteration (a deviation of a few degrees converges in three steps).
    pub fn remove(&self, r: f64) -> f64 {
        let mut psi = r;
        for _ in 0..4 {
            psi = r - self.at(psi);
        }
        wrap_angle(psi)
    }

    /// The largest |d(ψ)| over a turn (rad).
    pub fn amplitude(&self) -> f64 {
        (0..360)
            .map(|k| self.at(f64::from(k).to_radians()).abs())
            .fold(0.0, f64::max)
    }

    /// Whether every coefficient is zero.
    pub fn is_zero(&self) -> bool {
        self.0.iter().all(|c| *c == 0.0)
    }
}

impl FromStr for Deviation {
    type Err = String;

    /// `A1,B1,A2,B2` in degrees.
    fn from_str(s: &str) -> Result<Self, String> {
        let v: Vec<f64> = s
            .split(',')
            .map(|x| x.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|_| format!("{s:?}: expected A1,B1,A2,B2 in degrees"))?;
        let arr: [f64; 4] = v
            .try_into()
            .map_err(|_| format!("{s:?}: expected four coefficients A1,B1,A2,B2"))?;
        if arr.iter().any(|c| !(c.is_finite() && c.abs() <= 45.0)) {
            return Err(format!("{s:?}: each coefficient must be within ±45°"));
        }
        Ok(Deviation(arr.map(f64::to_radians)))
    }
}

/// How a wheel-*ratio* estimate is split into two absolute wheel diameters.
///
/// Heading errors only observe `D_R/(D·E_b)` and `D_L/(D·E_b)`; the absolute wheel scale is
/// invisible to them. A convention supplies the missing constraint. Estimation and write-back
/// must use the same one: mixed, a 4 m square is left several centimetres open.
///
/// This one type serves the library, routine files, the command line and JSON. Its text form
/// ([`FromStr`], [`Display`](std::fmt::Display)) is `left-nominal`,
/// `mean-preserving` or `measured-scale:COMMANDED_M,MEASURED_M`; in TOML and JSON the first two
/// are strings and the third a table, `{ measured-scale = { commanded_m = 2.0, measured_m =
/// 1.98 } }`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SplitConvention {
    /// The mean of the two diameter factors stays 1 (Borenstein's UMBmark split:
    /// `D_L = 2D/(E_d+1)`, `D_R = 2D/(1/E_d+1)` for equal configured wheels).
    MeanPreserving,
    /// The left wheel keeps its configured diameter; the right becomes `E_d` times it
    /// (the split implied by the paper's coupled term, eq. 9).
    LeftNominal,
    /// The absolute scale comes from a straight-line run: commanded `commanded_m`, measured
    /// (tape measure, start to end) `measured_m`. Diameters and wheelbase are scaled together,
    /// which leaves every heading prediction unchanged and makes the straight distance match.
    MeasuredScale {
        /// Straight distance commanded with the configured parameters (m).
        commanded_m: f64,
        /// Straight-line distance actually travelled, measured start to end (m).
        measured_m: f64,
    },
}

impl SplitConvention {
    /// Short name used on the command line and in reports.
    pub fn name(&self) -> &'static str {
        match self {
            SplitConvention::MeanPreserving => "mean-preserving",
            SplitConvention::LeftNominal => "left-nominal",
            SplitConvention::MeasuredScale { .. } => "measured-scale",
        }
    }

    /// Checks a measured scale is physical: both distances positive and within 20 % of each
    /// other (a larger difference is a measuring mistake, not a wheel).
    pub fn validate(&self) -> Result<(), KinematicsError> {
        if let SplitConvention::MeasuredScale {
            commanded_m,
            measured_m,
        } = *self
        {
            check_positive("commanded straight distance", commanded_m)?;
            check_positive("measured straight distance", measured_m)?;
            if (measured_m / commanded_m - 1.0).abs() > 0.2 {
                return Err(KinematicsError::BadScaleCheck(format!(
                    "measured {measured_m} m for {commanded_m} m commanded differs by more \
                     than 20 %: check the measurement"
                )));
            }
        }
        Ok(())
    }

    /// Splits ratio estimates into per-parameter factors on the configured parameters.
    ///
    /// `configured_wheelbase_m` is the wheelbase the controller used during the test; only the
    /// measured-scale convention needs it (for the slight curvature of the straight run).
    pub fn split(
        &self,
        e_b: f64,
        e_d: f64,
        configured_wheelbase_m: f64,
    ) -> Result<Correction, KinematicsError> {
        check_positive("E_b", e_b)?;
        check_positive("E_d", e_d)?;
        match *self {
            SplitConvention::LeftNominal => Ok(Correction {
                left_diameter_scale: 1.0,
                right_diameter_scale: e_d,
                wheelbase_scale: e_b,
            }),
            SplitConvention::MeanPreserving => Ok(Correction {
                left_diameter_scale: 2.0 / (e_d + 1.0),
                right_diameter_scale: 2.0 * e_d / (e_d + 1.0),
                wheelbase_scale: e_b,
            }),
            SplitConvention::MeasuredScale {
                commanded_m,
                measured_m,
            } => {
                let base = SplitConvention::LeftNominal.split(e_b, e_d, configured_wheelbase_m)?;
                base.rescaled_to_distance(commanded_m, measured_m, configured_wheelbase_m)
            }
        }
    }
}

impl std::fmt::Display for SplitConvention {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SplitConvention::MeasuredScale {
                commanded_m,
                measured_m,
            } => write!(f, "measured-scale:{commanded_m},{measured_m}"),
            other => f.write_str(other.name()),
        }
    }
}

impl std::str::FromStr for SplitConvention {
    type Err = KinematicsError;

    fn from_str(s: &str) -> Result<Self, KinematicsError> {
        let bad = || {
            KinematicsError::BadScaleCheck(format!(
                "unknown convention {s:?}: use left-nominal, mean-preserving or \
                 measured-scale:COMMANDED_M,MEASURED_M"
            ))
        };
        let c = match s.trim() {
            "left-nominal" => SplitConvention::LeftNominal,
            "mean-preserving" => SplitConvention::MeanPreserving,
            other => {
                let (commanded, measured) = other
                    .strip_prefix("measured-scale:")
                    .and_then(|rest| rest.split_once(','))
                    .ok_or_else(bad)?;
                SplitConvention::MeasuredScale {
                    commanded_m: commanded.trim().parse().map_err(|_| bad())?,
                    measured_m: measured.trim().parse().map_err(|_| bad())?,
                }
            }
        };
        c.validate()?;
        Ok(c)
    }
}

impl Correction {
    /// Scales all three factors by one number so that a straight run of `commanded_m` with the
    /// configured parameters ends `measured_m` from its start.
    ///
    /// A uniform scale leaves `D/b` and so every heading unchanged; the straight run's turn
    /// `Δθ = L·(r_R − r_L)/(b·ρ)` is scale-invariant, so one division is exact.
    pub fn rescaled_to_distance(
        &self,
        commanded_m: f64,
        measured_m: f64,
        configured_wheelbase_m: f64,
    ) -> Result<Correction, KinematicsError> {
        check_positive("commanded straight distance", commanded_m)?;
        check_positive("measured straight distance", measured_m)?;
        check_positive("configured wheelbase", configured_wheelbase_m)?;
        let mean = 0.5 * (self.left_diameter_scale + self.right_diameter_scale);
        let dtheta = commanded_m * (self.right_diameter_scale - self.left_diameter_scale)
            / (configured_wheelbase_m * self.wheelbase_scale);
        let predicted = commanded_m * mean * sinc(0.5 * dtheta);
        if !(predicted.is_finite() && predicted > 0.0) {
            return Err(KinematicsError::BadScaleCheck(format!(
                "predicted straight distance {predicted} m is not positive"
            )));
        }
        let s = measured_m / predicted;
        Ok(Correction {
            left_diameter_scale: self.left_diameter_scale * s,
            right_diameter_scale: self.right_diameter_scale * s,
            wheelbase_scale: self.wheelbase_scale * s,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_convention_type_reads_and_writes_every_form() {
        for c in [
            SplitConvention::LeftNominal,
            SplitConvention::MeanPreserving,
            SplitConvention::MeasuredScale {
                commanded_m: 2.0,
                measured_m: 1.98,
            },
        ] {
            assert_eq!(c.to_string().parse::<SplitConvention>().unwrap(), c);
            let json = serde_json::to_string(&c).unwrap();
            assert_eq!(serde_json::from_str::<SplitConvention>(&json).unwrap(), c);
        }
        assert_eq!(
            serde_json::to_string(&SplitConvention::LeftNominal).unwrap(),
            "\"left-nominal\""
        );
        assert!("measured-scale:2,1".parse::<SplitConvention>().is_err());
        assert!("right-nominal".parse::<SplitConvention>().is_err());
    }
    use approx::assert_relative_eq;

    #[test]
    fn wrap_is_half_open_at_minus_pi() {
        assert_relative_eq!(wrap_angle(PI), PI);
        assert_relative_eq!(wrap_angle(-PI), PI);
        assert_relative_eq!(wrap_angle(3.0 * PI), PI);
        assert_relative_eq!(wrap_angle(0.1 - 2.0 * PI), 0.1, epsilon = 1e-12);
        assert_relative_eq!(
            wrap_angle((-179.9f64).to_radians() - 0.2f64.to_radians()),
            179.9f64.to_radians(),
            epsilon = 1e-12
        );
        // Every finite angle lands in (−π, π], however many turns it holds (the rounded
        // number of turns is exact only below a million of them).
        for a in [
            1e5 + 0.3,
            -7e5,
            1.5e6,
            4.97e17,
            -1e18,
            1e300,
            -f64::MAX,
            f64::MAX,
        ] {
            let w = wrap_angle(a);
            assert!(w > -PI && w <= PI, "{a} wrapped to {w}");
        }
        // Below a million turns the fast path agrees with the exact remainder.
        let a = 12345.678;
        assert_relative_eq!(
            wrap_angle(a),
            (a + PI).rem_euclid(2.0 * PI) - PI,
            epsilon = 1e-9
        );
    }

    #[test]
    fn straight_and_in_place_limits() {
        let p = Pose::new(1.0, 2.0, PI / 2.0).advance(0.5, 0.5, 0.4);
        assert_relative_eq!(p.x_m, 1.0, epsilon = 1e-15);
        assert_relative_eq!(p.y_m, 2.5, epsilon = 1e-15);
        let q = Pose::default().advance(-0.1 * PI, 0.1 * PI, 0.4);
        assert_relative_eq!(q.heading_rad, PI / 2.0, epsilon = 1e-15);
        assert_relative_eq!(q.distance_m(), 0.0, epsilon = 1e-15);
    }

    #[test]
    fn arc_matches_circle_geometry() {
        // Quarter circle of radius 1 m to the left: ends at (1, 1) facing +y.
        let b = 0.5;
        let theta = PI / 2.0;
        let p = Pose::default().advance(theta * (1.0 - b / 2.0), theta * (1.0 + b / 2.0), b);
        assert_relative_eq!(p.x_m, 1.0, epsilon = 1e-14);
        assert_relative_eq!(p.y_m, 1.0, epsilon = 1e-14);
        assert_relative_eq!(p.heading_rad, PI / 2.0, epsilon = 1e-14);
    }

    #[test]
    fn arc_is_continuous_through_the_straight_limit() {
        let b = 0.39;
        let a = Pose::default().advance(1.0, 1.0 + 1e-9, b);
        let c = Pose::default().advance(1.0, 1.0 + 2e-9, b);
        assert!((a.y_m - c.y_m).abs() < 1e-8 && a.y_m > 0.0);
    }

    #[test]
    fn splits_encode_the_ratio_and_compound() {
        for conv in [
            SplitConvention::LeftNominal,
            SplitConvention::MeanPreserving,
        ] {
            let c = conv.split(0.976, 0.992, 0.39).unwrap();
            assert_relative_eq!(c.e_d(), 0.992, epsilon = 1e-15);
            assert_relative_eq!(c.e_b(), 0.976, epsilon = 1e-15);
        }
        let m = SplitConvention::MeanPreserving
            .split(1.0, 0.99, 0.39)
            .unwrap();
        assert_relative_eq!(
            0.5 * (m.left_diameter_scale + m.right_diameter_scale),
            1.0,
            epsilon = 1e-15
        );
        let nominal = WheelParams::nominal(0.15, 0.39, 4096.0);
        let once = m.apply(&nominal).unwrap();
        let twice = m.apply(&once).unwrap();
        assert_relative_eq!(twice.e_d(), 0.99 * 0.99, epsilon = 1e-14);
    }

    #[test]
    fn measured_scale_reproduces_the_measured_distance() {
        let nominal = WheelParams::nominal(0.15, 0.39, 4096.0);
        let conv = SplitConvention::MeasuredScale {
            commanded_m: 4.0,
            measured_m: 3.97,
        };
        let corr = conv.split(0.98, 0.99, nominal.wheelbase_m).unwrap();
        let truth = corr.apply(&nominal).unwrap();
        // Controller drives 4 m by wheel rotation computed with the nominal parameters.
        let rot_l = 4.0 / (0.5 * nominal.left_wheel_diameter_m);
        let rot_r = 4.0 / (0.5 * nominal.right_wheel_diameter_m);
        let end = Pose::default().advance(
            rot_l * 0.5 * truth.left_wheel_diameter_m,
            rot_r * 0.5 * truth.right_wheel_diameter_m,
            truth.wheelbase_m,
        );
        assert_relative_eq!(end.distance_m(), 3.97, epsilon = 1e-12);
        assert_relative_eq!(corr.e_d(), 0.99, epsilon = 1e-14);
    }

    #[test]
    fn bad_parameters_are_refused() {
        let bad = WheelParams::nominal(f64::NAN, 0.39, 100.0);
        assert!(matches!(
            bad.validate(),
            Err(KinematicsError::NotPositive { name, .. }) if name == "left_wheel_diameter_m"
        ));
        assert!(SplitConvention::LeftNominal.split(-1.0, 1.0, 0.39).is_err());
        assert!(SplitConvention::MeasuredScale {
            commanded_m: 1.0,
            measured_m: 0.0
        }
        .split(1.0, 1.0, 0.39)
        .is_err());
    }
}
