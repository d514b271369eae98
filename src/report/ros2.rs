//! Exporting a calibration for other software: ros2_control's `diff_drive_controller`.

use crate::kinematics::WheelParams;
use std::fmt::Write as _;

/// YAML parameters for ros2_control's `diff_drive_controller`.
///
/// The URDF keeps the nominal geometry (`wheel_separation`, `wheel_radius` from `nominal`, the
/// mean of its two wheels); the calibration goes into the controller's multipliers, which is
/// how the controller expects corrections: `wheel_separation_multiplier = b_cal / b_nom` and
/// `left/right_wheel_radius_multiplier = D_cal / D_nom` per wheel.
pub fn ros2_diff_drive_yaml(
    controller_name: &str,
    nominal: &WheelParams,
    calibrated: &WheelParams,
) -> String {
    let radius = 0.25 * (nominal.left_wheel_diameter_m + nominal.right_wheel_diameter_m);
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# Written by odocal {}: odometry calibration for diff_drive_controller.",
        env!("CARGO_PKG_VERSION")
    );
    let _ = writeln!(
        s,
        "# Calibrated: left D {:.9} m, right D {:.9} m, wheelbase {:.9} m.",
        calibrated.left_wheel_diameter_m, calibrated.right_wheel_diameter_m, calibrated.wheelbase_m
    );
    let _ = writeln!(s, "{controller_name}:\n  ros__parameters:");
    let _ = writeln!(s, "    wheel_separation: {:.9}", nominal.wheelbase_m);
    let _ = writeln!(s, "    wheel_radius: {radius:.9}");
    let _ = writeln!(
        s,
        "    wheel_separation_multiplier: {:.9}",
        calibrated.wheelbase_m / nominal.wheelbase_m
    );
    let _ = writeln!(
        s,
        "    left_wheel_radius_multiplier: {:.9}",
        calibrated.left_wheel_diameter_m / (2.0 * radius)
    );
    let _ = writeln!(
        s,
        "    right_wheel_radius_multiplier: {:.9}",
        calibrated.right_wheel_diameter_m / (2.0 * radius)
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn multipliers_reproduce_the_calibrated_geometry() {
        let nominal = WheelParams::nominal(0.15, 0.39, 4096.0);
        let cal = WheelParams {
            right_wheel_diameter_m: 0.1488,
            wheelbase_m: 0.38064,
            ..nominal
        };
        let y = ros2_diff_drive_yaml("diff_drive_controller", &nominal, &cal);
        let get = |k: &str| -> f64 {
            y.lines()
                .find_map(|l| l.trim().strip_prefix(k)?.strip_prefix(':'))
                .unwrap()
                .trim()
                .parse()
                .unwrap()
        };
        assert!(
            (get("wheel_separation") * get("wheel_separation_multiplier") - 0.38064).abs() < 1e-9
        );
        assert!(
            (2.0 * get("wheel_radius") * get("right_wheel_radius_multiplier") - 0.1488).abs()
                < 1e-9
        );
        assert!((get("left_wheel_radius_multiplier") - 1.0).abs() < 1e-12);
        assert!(y.starts_with("# Written by odocal"));
    }
}
