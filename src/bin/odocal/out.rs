//! How the binary prints results (a leaf: it uses no other file of the binary): pretty JSON on
//! stdout, and parameters as a table or JSON.

use odocal::kinematics::WheelParams;

type CliResult = Result<(), Box<dyn std::error::Error>>;

/// Prints `value` as pretty JSON on stdout.
pub fn print_json(value: &serde_json::Value) -> Result<(), Box<dyn std::error::Error>> {
    println!("{}", serde_json::to_string_pretty(value)?);
    Ok(())
}

/// Prints parameters as a table, or as JSON with `extra`'s fields.
pub fn print_params(p: &WheelParams, json_out: bool, extra: serde_json::Value) -> CliResult {
    if json_out {
        let mut v = serde_json::to_value(p)?;
        if let (Some(obj), Some(extra)) = (v.as_object_mut(), extra.as_object()) {
            obj.extend(extra.clone());
        }
        return print_json(&v);
    }
    println!("left_wheel_diameter_m  {:.9}", p.left_wheel_diameter_m);
    println!("right_wheel_diameter_m {:.9}", p.right_wheel_diameter_m);
    println!("wheelbase_m            {:.9}", p.wheelbase_m);
    println!("counts_per_wheel_rev   {:.6}", p.counts_per_wheel_rev);
    Ok(())
}
