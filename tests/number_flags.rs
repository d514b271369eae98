//! Every numeric flag of `plan`, `estimate` and `simulate` given random finite and
//! non-finite values, one flag at a time over a valid noisy command: the command either
//! refuses the value with a clear error (no panic) or succeeds with every result a finite
//! number and every standard error above zero (the input is noisy: a zero σ would be a
//! false certainty).

mod common;

use proptest::prelude::*;
use serde_json::Value;

/// A command: its name, and each flag with the value of the valid noisy base command (`{}`
/// marks where a fuzzed value goes when the flag is the one fuzzed; the rest of the template
/// stays valid).
struct Command {
    name: &'static str,
    flags: &'static [(&'static str, &'static str, &'static str)],
}

const PLAN: Command = Command {
    name: "plan",
    flags: &[
        ("--heading-sigma-deg", "0.5", "{}"),
        ("--wheelbase-m", "0.39", "{}"),
        ("--side-max-m", "4", "{}"),
        ("--wheel-diameter-m", "0.15", "{}"),
        ("--counts-per-rev", "4096", "{}"),
        ("--heading-hz", "10", "{}"),
        ("--footprint-m", "0.5", "{}"),
        ("--run-scatter-deg", "0.1", "{}"),
        ("--target-end-m", "0.01", "{}"),
        ("--max-speed-m-s", "0.3", "{}"),
        ("--max-rate-rad-s", "1", "{}"),
        ("--settle-s", "1", "{}"),
        ("--target-eb-std", "0.001", "{}"),
        ("--target-ed-std", "0.0005", "{}"),
    ],
};

const ESTIMATE: Command = Command {
    name: "estimate",
    flags: &[
        ("--side-m", "4", "{}"),
        ("--wheelbase-m", "0.39", "{}"),
        ("--wheel-diameter-m", "0.15", "{}"),
        ("--cw-heading-deg", "-26.31,-26.92", "{},-26.92"),
        ("--ccw-heading-deg", "-11.62,-12.15", "-11.62,{}"),
        ("--heading-sigma-deg", "0.3", "{}"),
    ],
};

const SIMULATE: Command = Command {
    name: "simulate",
    flags: &[
        ("--runs", "2", "2"),
        ("--true-eb", "0.976", "{}"),
        ("--true-ed", "0.992", "{}"),
        ("--side-m", "2", "{}"),
        ("--lee-side-m", "2", "{}"),
        ("--wheelbase-m", "0.39", "{}"),
        ("--wheel-diameter-m", "0.15", "{}"),
        ("--counts-per-rev", "4096", "{}"),
        ("--heading-sigma-deg", "0.3", "{}"),
        ("--compass-bias-deg", "0", "{}"),
        ("--slip-sigma", "0.001", "{}"),
        ("--position-sigma-m", "0.002", "{}"),
        ("--motor-offset-deg", "0", "{}"),
        ("--heading-quantum-deg", "0", "{}"),
        ("--heading-latency-s", "0", "{}"),
        ("--heading-loss", "0", "{}"),
    ],
};

/// A number as a user could type it: non-finite, extreme, zero, negative, or ordinary.
fn number() -> impl Strategy<Value = String> {
    prop_oneof![
        Just("nan".to_string()),
        Just("inf".to_string()),
        Just("-inf".to_string()),
        Just("0".to_string()),
        Just("-0".to_string()),
        Just("1e308".to_string()),
        Just("-1e308".to_string()),
        Just("1e-308".to_string()),
        Just("-1".to_string()),
        (-1e6..1e6f64).prop_map(|v| v.to_string()),
        (-10.0..10.0f64).prop_map(|v| v.to_string()),
        (0.0..1e-6f64).prop_map(|v| v.to_string()),
    ]
}

/// The result fields that must be finite numbers, and those (standard errors) that must also
/// be above zero, wherever they are in the output.
const FINITE: [&str; 7] = [
    "e_b",
    "e_d",
    "wheelbase_m",
    "left_wheel_diameter_m",
    "right_wheel_diameter_m",
    "predicted_end_point_m",
    "robot_time_s",
];
const POSITIVE: [&str; 4] = [
    "e_b_std_err",
    "e_d_std_err",
    "predicted_std_e_b",
    "predicted_std_e_d",
];

/// Where in `v` a result is not a finite number or a standard error is not above zero.
fn bad_numbers(v: &Value, path: &str, out: &mut Vec<String>) {
    match v {
        Value::Object(m) => {
            for (k, x) in m {
                let here = format!("{path}.{k}");
                if FINITE.contains(&k.as_str()) || POSITIVE.contains(&k.as_str()) {
                    match x.as_f64() {
                        Some(n) if n.is_finite() => {
                            if POSITIVE.contains(&k.as_str()) && n <= 0.0 {
                                out.push(format!("{here} = {n}"));
                            }
                        }
                        _ => out.push(format!("{here} = {x}")),
                    }
                }
                bad_numbers(x, &here, out);
            }
        }
        Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                bad_numbers(x, &format!("{path}[{i}]"), out);
            }
        }
        _ => {}
    }
}

fn check(cmd: &Command, which: usize, value: &str) -> Result<(), TestCaseError> {
    let mut args: Vec<String> = vec![cmd.name.into(), "--json".into()];
    for (i, (flag, base, template)) in cmd.flags.iter().enumerate() {
        let v = if i == which {
            template.replace("{}", value)
        } else {
            base.to_string()
        };
        args.push(format!("{flag}={v}"));
    }
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    let (ok, out, err) = common::odocal(&refs);
    prop_assert!(!err.contains("panicked"), "{args:?}: {err}");
    if !ok {
        prop_assert!(err.starts_with("error"), "{args:?}: {err}");
        return Ok(());
    }
    let v: Value = serde_json::from_str(&out)
        .map_err(|e| TestCaseError::fail(format!("{args:?}: not JSON ({e}): {out}")))?;
    let mut bad = Vec::new();
    bad_numbers(&v, "", &mut bad);
    // Noise-free headings or positions are the inputs whose standard errors may be zero
    // (the methods that read them are exact then).
    let noise_free = ["--heading-sigma-deg", "--position-sigma-m"].contains(&cmd.flags[which].0)
        && value.parse::<f64>().is_ok_and(|s| s == 0.0);
    if noise_free {
        bad.retain(|b| !POSITIVE.iter().any(|k| b.contains(k)) || b.contains("null"));
    }
    prop_assert!(bad.is_empty(), "{args:?} succeeded with {bad:?}");
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn plan_flags_give_a_finite_plan_or_an_error(which in 0..PLAN.flags.len(), value in number()) {
        check(&PLAN, which, &value)?;
    }

    #[test]
    fn estimate_flags_give_finite_estimates_with_errors_or_an_error(
        which in 0..ESTIMATE.flags.len(),
        value in number(),
    ) {
        check(&ESTIMATE, which, &value)?;
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn simulate_flags_give_finite_results_or_an_error(
        which in 0..SIMULATE.flags.len(),
        value in number(),
    ) {
        check(&SIMULATE, which, &value)?;
    }
}
