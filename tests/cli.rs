//! The `odocal` binary end to end: JSON shapes other tools rely on, and clear failures.

mod common;

use common::{odocal, odocal_json, scratch, spawn_mock};
use serde_json::Value;
use std::path::PathBuf;
use std::process::{Command, Stdio};

fn json(args: &[&str]) -> Value {
    odocal_json(args)
}

/// `odocal estimate` on the README's 4 m square, followed by `extra`.
fn estimate_args<'a>(extra: &[&'a str]) -> Vec<&'a str> {
    let mut v = vec!["estimate", "--side-m", "4", "--wheelbase-m", "0.39"];
    v.extend_from_slice(extra);
    v
}

fn method<'a>(v: &'a Value, name: &str) -> &'a Value {
    v["estimates"]
        .as_array()
        .expect("estimates array")
        .iter()
        .find(|e| e["method"] == name)
        .unwrap_or_else(|| panic!("no {name} estimate"))
}

#[test]
fn simulate_json_reproduces_the_paper() {
    let v = json(&[
        "simulate",
        "--heading-sigma-deg",
        "0",
        "--true-eb",
        "0.976",
        "--true-ed",
        "0.992",
        "--json",
    ]);
    let umb = method(&v, "umbmark");
    assert!((umb["e_b_error_pp"].as_f64().unwrap() - 0.7253).abs() < 5e-5);
    assert!((umb["e_max_sys_m"].as_f64().unwrap() - 0.1639).abs() < 5e-5);
    let exact = method(&v, "exact");
    assert!((exact["e_b"].as_f64().unwrap() - 0.976).abs() < 1e-12);
    assert!((exact["e_d"].as_f64().unwrap() - 0.992).abs() < 1e-12);
    assert!(exact["e_max_sys_m"].as_f64().unwrap() < 1e-9);
    assert_eq!(v["estimates"].as_array().unwrap().len(), 5);
}

#[test]
fn estimate_json_and_corrected_parameters() {
    let v = json(&estimate_args(&[
        "--cw-heading-deg",
        "-26.31,-26.92,-26.55",
        "--ccw-heading-deg",
        "-11.62,-12.15,-11.84",
        "--wheel-diameter-m",
        "0.15",
        "--json",
    ]));
    // Without positions only the heading methods run.
    assert_eq!(v["estimates"].as_array().unwrap().len(), 3);
    let exact = method(&v, "exact");
    let e_b = exact["e_b"].as_f64().unwrap();
    assert!((e_b - 0.976).abs() < 0.001, "{e_b}");
    assert!(exact["e_b_std_err"].as_f64().unwrap() > 0.0);
    let b = exact["wheelbase_m"].as_f64().unwrap();
    assert!((b - 0.39 * e_b).abs() < 1e-12);
    assert_eq!(exact["left_wheel_diameter_m"].as_f64().unwrap(), 0.15);
}

#[test]
fn estimate_with_positions_runs_every_method() {
    let v = json(&estimate_args(&[
        "--cw-heading-deg=-26.64",
        "--ccw-heading-deg=-11.89",
        "--cw-xy-m=1.0354,0.6618",
        "--ccw-xy-m=-0.3698,0.4712",
        "--convention",
        "mean-preserving",
        "--json",
    ]));
    assert_eq!(v["estimates"].as_array().unwrap().len(), 5);
    assert_eq!(v["convention"], "mean-preserving");
}

#[test]
fn bad_input_fails_with_a_clear_message() {
    // Beyond ±180° a heading error cannot be wrapped: a unit mistake, named with its run.
    // (90°–180° is estimated with a warning: see heading_errors_up_to_180_degrees_….)
    let (ok, _, err) = odocal(&estimate_args(&[
        "--cw-heading-deg=-196",
        "--ccw-heading-deg=-11.6",
    ]));
    assert!(!ok);
    assert!(
        err.contains("clockwise run 1") && err.contains("180°"),
        "{err}"
    );
    let (ok, _, err) = odocal(&estimate_args(&[
        "--cw-heading-deg=-26",
        "--ccw-heading-deg=-11.6",
        "--cw-xy-m=1,2;3,4",
    ]));
    assert!(!ok);
    assert!(err.contains("1 headings but 2 positions"), "{err}");
    let (ok, _, err) = odocal(&["replay", "--dataset", "/nonexistent/set"]);
    assert!(!ok);
    assert!(err.contains("cannot read /nonexistent/set"), "{err}");
}

#[test]
fn plan_states_side_runs_robot_time_and_predicted_errors_and_moves_nothing() {
    let base = [
        "plan",
        "--floor-m",
        "5,9.5",
        "--heading-sigma-deg",
        "0.37",
        "--wheelbase-m",
        "0.39",
        "--heading-kind",
        "magnetic",
        "--method",
        "exact",
        "--heading-samples",
        "1",
    ];
    let with = |extra: &[&'static str]| -> Vec<&'static str> {
        base.iter().chain(extra).copied().collect()
    };
    let v = json(&with(&["--target-eb-std", "3e-4", "--json"]));
    let f = |k: &str| v[k].as_f64().unwrap_or_else(|| panic!("no {k}: {v}"));
    // E_b ± σ_c/(2π√n) at rest (one reading at each end): about 12 runs per direction.
    let runs = f("runs_per_direction");
    let std_e_b = f("predicted_std_e_b");
    assert!((12.0..=16.0).contains(&runs), "{v}");
    assert!(std_e_b <= 3e-4 && std_e_b > 2.5e-4, "{v}");
    assert!(f("predicted_std_e_d") > 0.0 && f("side_m") >= 1.0 && f("side_m") <= 4.0);
    // Squares, their robot time and the compass swing (two turns each way at 0.5 rad/s).
    let plan = &v["plan"];
    let squares = plan["squares"].as_f64().unwrap();
    let square_s = plan["square_time_s"].as_f64().unwrap();
    let swing_s = 4.0 * std::f64::consts::TAU / 0.5;
    assert!(
        (f("robot_time_s") - swing_s - squares * square_s).abs() < 1e-6,
        "{v}"
    );
    assert_eq!(v["moves"], false);
    // Text: what it costs, where, and the flags that drive it.
    let (ok, out, err) = odocal(&with(&["--target-eb-std", "3e-4"]));
    assert!(ok, "{err}");
    assert!(
        out.contains("moves nothing") && out.contains("of robot time") && out.contains("floor:"),
        "{out}"
    );
    assert!(out.contains("--target-eb-std 0.0003"), "{out}");
    // A target out of reach, or no room: said, and a failure.
    let (ok, _, err) = odocal(&with(&["--target-eb-std", "1e-6"]));
    assert!(!ok && err.contains("not reached within 20 runs"), "{err}");
    let mut small = with(&[]);
    small[2] = "1,2";
    let (ok, _, err) = odocal(&small);
    assert!(!ok && err.contains("no room"), "{err}");
}

#[test]
fn replay_json_has_evaluations() {
    let root = odocal::offline::dataset::default_optiodom_root();
    let set = root.join("square/231220200040");
    if !set.is_dir() {
        assert!(
            std::env::var_os("CI").is_none(),
            "OptiOdom data missing in CI"
        );
        eprintln!("NOTICE: skipping, no OptiOdom data at {}", root.display());
        return;
    }
    let other = root.join("square/231220200029");
    let v = json(&[
        "replay",
        "--dataset",
        set.to_str().unwrap(),
        "--evaluate",
        other.to_str().unwrap(),
        "--json",
    ]);
    let evals = v["evaluations"].as_array().unwrap();
    let get = |m: &str| {
        evals
            .iter()
            .find(|r| r["method"] == m && r["dataset"] == "231220200029")
            .unwrap()["heading_error_deg"]
            .as_f64()
            .unwrap()
    };
    assert!(get("exact") < get("uncalibrated"));
    assert!(evals.iter().all(|r| r["position_error_m"].is_number()));
}

#[test]
fn mock_device_serves_a_pty_that_params_get_can_open() {
    let (mut mock, line) = spawn_mock(&["--wheelbase-m", "0.41", "--seed", "3"]);
    let path = line;
    assert!(
        path.starts_with("/dev/"),
        "first line is the terminal path: {path:?}"
    );
    let v = json(&["params", "get", "--port", &path, "--json"]);
    assert_eq!(v["wheelbase_m"], 0.41);
    assert_eq!(v["source"], "active");
    let v = json(&["status", "--port", &path, "--json"]);
    assert_eq!(v["status"]["motion_state"], "idle");
    // The same port as `--port` takes it elsewhere: `odocal:PORT?baud=N` opens PORT.
    let spec = format!("odocal:{path}?baud=115200");
    let v = json(&["status", "--port", &spec, "--json"]);
    assert_eq!(v["status"]["motion_state"], "idle");
    let v = json(&["params", "get", "--port", &spec, "--json"]);
    assert_eq!(v["wheelbase_m"], 0.41);
    // Closing stdin stops the device.
    drop(mock.stdin.take());
    let status = mock.wait().unwrap();
    assert!(status.success());
    let (ok, _, err) = odocal(&["params", "get", "--port", "/dev/does-not-exist"]);
    assert!(
        !ok && err.contains("cannot open /dev/does-not-exist"),
        "{err}"
    );
}

#[test]
fn demo_json_reports_a_tenfold_improvement_and_writes_files() {
    let dir = scratch("demo");
    let (ok, out, err) = odocal(&["demo", "--json", "--report-dir", dir.to_str().unwrap()]);
    assert!(ok, "{err}");
    // Stdout carries the result, not the paths (they are in report.json): tens of kB, not MB.
    assert!(
        out.len() < 100_000,
        "demo --json printed {} bytes",
        out.len()
    );
    let v: Value = serde_json::from_str(&out).unwrap();
    assert!(v["rounds"][0]["runs"][0].get("odometry_path").is_none());
    let on_disk: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap();
    assert!(on_disk["rounds"][0]["runs"][0]["odometry_path"].is_array());
    let before = v["e_max_sys_before_m"].as_f64().unwrap();
    let after = v["e_max_sys_after_m"].as_f64().unwrap();
    assert!(after * 10.0 < before, "{before} → {after}");
    assert!(v["estimates"]
        .as_array()
        .unwrap()
        .iter()
        .any(|e| e["method"] == "exact"));
    // Every file but the plots always; each plot when its data is there (report.md links
    // those drawn).
    let md = std::fs::read_to_string(dir.join("report.md")).unwrap();
    let plots: Vec<&str> = odocal::report::REPORT_FILES
        .into_iter()
        .filter(|f| !f.ends_with(".svg") || md.contains(&format!("({f})")))
        .collect();
    for f in &plots {
        assert!(dir.join(f).is_file(), "{f} not written");
    }
    let plots = plots.iter().filter(|f| f.ends_with(".svg")).count();
    for f in [
        "paths.svg",
        "heading_errors.svg",
        "end_points.svg",
        "estimates.svg",
        "heading_along_legs.svg",
    ] {
        assert!(dir.join(f).is_file(), "{f}: the demo has its data");
    }
    // report.html stands alone: plots inline, nothing fetched, tags balanced (checked by
    // structure here, and in a headless browser when one is installed: see below).
    let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
    assert!(html.starts_with("<!DOCTYPE html>"), "{}", &html[..50]);
    assert_eq!(
        html.matches("<figure><svg").count(),
        plots,
        "every plot inline"
    );
    assert!(!html.contains("<img") && !html.contains(" src=") && !html.contains("<?xml"));
    for tag in ["table", "figure", "ul", "pre", "h2", "svg", "html", "body"] {
        assert_eq!(
            html.matches(&format!("<{tag}")).count(),
            html.matches(&format!("</{tag}>")).count(),
            "<{tag}> balanced"
        );
    }
    assert!(html.contains("<th>method</th>") && html.contains("(chosen)"));
    // Every run of round 1 and of the verification is a trace on the paths plot as the
    // odometry believed it, with the simulation's true path, and again with the written
    // parameters when it ran with others.
    let runs = on_disk["rounds"][0]["runs"]
        .as_array()
        .unwrap()
        .iter()
        .chain(on_disk["verification"].as_array().unwrap());
    let traces: usize = runs
        .map(|r| {
            1 + usize::from(r["true_path"].is_array())
                + usize::from(r["params"] != on_disk["final_params"])
        })
        .sum();
    assert!(traces >= 16, "{traces}");
    opens_in_a_browser_with_its_plots_and_fetches_nothing(&dir.join("report.html"), plots, traces);
    // The report exports for ros2_control.
    let yaml = dir.join("diff_drive.yaml");
    let (ok, _, err) = odocal(&[
        "export",
        "--report",
        dir.join("report.json").to_str().unwrap(),
        "--ros2",
        yaml.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let text = std::fs::read_to_string(&yaml).unwrap();
    assert!(text.contains("wheel_separation_multiplier: 0.97"), "{text}");
    let (ok, _, err) = odocal(&[
        "export",
        "--report",
        "/nonexistent.json",
        "--ros2",
        "x.yaml",
    ]);
    assert!(
        !ok && err.contains("cannot read /nonexistent.json"),
        "{err}"
    );
}

#[test]
fn routine_files_run_and_malformed_ones_name_the_line() {
    let dir = scratch("run");
    std::fs::create_dir_all(&dir).unwrap();
    let good = dir.join("routine.toml");
    std::fs::write(
        &good,
        format!(
            "port = \"mock\"\nside_m = 2.0\nruns_per_direction = 3\nwrite_back = \"dry-run\"\n\
             settle_s = 0.0\nbackup_dir = \"{0}\"\nreport_dir = \"{0}\"\n",
            dir.display()
        ),
    )
    .unwrap();
    let v = json(&["run", good.to_str().unwrap(), "--json"]);
    assert_eq!(v["written"], false, "dry run");
    assert_eq!(v["final_params"], v["original_params"]);
    assert!(dir.join("report.md").is_file());
    let bad = dir.join("bad.toml");
    std::fs::write(
        &bad,
        "port = \"mock\"\nside_m = 2.0\n\nmax_speed_m_s = 3.0\n",
    )
    .unwrap();
    let (ok, _, err) = odocal(&["run", bad.to_str().unwrap()]);
    assert!(!ok);
    assert!(
        err.contains("line 4") && err.contains("max_speed_m_s"),
        "{err}"
    );
    std::fs::write(&bad, "port = \"mock\"\nsid_m = 2.0\n").unwrap();
    let (ok, _, err) = odocal(&["run", bad.to_str().unwrap()]);
    assert!(!ok && err.contains("line 2"), "{err}");
    // The shipped example files parse.
    for f in ["examples/routine-mock.toml", "examples/routine-robot.toml"] {
        let text = std::fs::read_to_string(f).unwrap();
        odocal::spec::RoutineFile::from_toml(&text).unwrap_or_else(|e| panic!("{f}: {e}"));
    }
}

#[test]
fn calibrate_drives_a_device_on_a_port_end_to_end() {
    let (mut mock, port) = spawn_mock(&["--seed", "5"]);
    let dir = scratch("calibrate");
    let common = [
        "calibrate",
        "--port",
        &port,
        "--side-m",
        "2",
        "--runs",
        "3",
        "--settle-s",
        "0",
        "--json",
    ];
    // A dry run first: estimates, writes nothing.
    let mut args = common.to_vec();
    args.extend(["--dry-run", "--yes", "--report-dir", dir.to_str().unwrap()]);
    let v = json(&args);
    assert_eq!(v["written"], false);
    assert_eq!(
        json(&["params", "get", "--port", &port, "--json"])["wheelbase_m"],
        0.39
    );
    // Then for real.
    let mut args = common.to_vec();
    args.extend(["--yes", "--report-dir", dir.to_str().unwrap()]);
    let v = json(&args);
    assert_eq!(v["written"], true);
    assert!(v["converged"].as_bool().unwrap());
    let b = json(&[
        "params", "get", "--port", &port, "--source", "stored", "--json",
    ])["wheelbase_m"]
        .as_f64()
        .unwrap();
    assert!((b - 0.39 * 0.976).abs() < 0.002, "stored wheelbase {b}");
    assert!(dir.join("report.md").is_file());
    drop(mock.stdin.take());
    assert!(mock.wait().unwrap().success());
}

#[test]
fn ports_lists_serial_ports_as_json() {
    let v = odocal_json(&["ports", "--json"]);
    let ports = v["ports"]
        .as_array()
        .expect("a ports array, possibly empty");
    for p in ports {
        assert!(p["port"].as_str().is_some_and(|s| !s.is_empty()), "{p}");
        assert!(p["type"].is_string(), "{p}");
    }
}

#[test]
fn a_closed_pipe_ends_the_program_quietly_and_negative_values_reach_validation() {
    use std::io::Read;
    // `odocal track … | head -c 10` over ~200 kB of output (more than a pipe holds): the
    // reader goes away after a few bytes.
    let Some(root) = common::optiodom("free") else {
        return;
    };
    let set = root.join("free/020120212354");
    let mut child = Command::new(env!("CARGO_BIN_EXE_odocal"))
        .args([
            "track",
            "--dataset",
            set.to_str().unwrap(),
            "--every-m",
            "0.005",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut first = [0u8; 10];
    child.stdout.take().unwrap().read_exact(&mut first).unwrap();
    // stdout is dropped here: the pipe is closed.
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "{err}");
    // A negative number is a value to check, not an unknown flag.
    let (ok, _, err) = common::odocal(&[
        "estimate",
        "--side-m",
        "-4",
        "--wheelbase-m",
        "0.39",
        "--cw-heading-deg",
        "-1",
        "--ccw-heading-deg",
        "1",
    ]);
    assert!(!ok);
    assert!(
        err.contains("side_m must be finite and > 0, got -4"),
        "{err}"
    );
}

#[test]
fn record_says_why_nothing_was_recorded_and_records_from_a_real_time_mock() {
    let dir = scratch("record");
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("log.jsonl");
    // The mock in virtual time: nothing moves, nothing streams.
    let (mut mock, path) = spawn_mock(&[]);
    let (ok, _, err) = odocal(&[
        "record",
        "--port",
        &path,
        "--out",
        out.to_str().unwrap(),
        "--duration-s",
        "0.5",
    ]);
    drop(mock.stdin.take());
    let _ = mock.wait();
    assert!(!ok);
    assert!(
        err.contains("no telemetry arrived") && err.contains("--time-scale 1"),
        "{err}"
    );
    // In real time it streams at rest, and the log reads back.
    let out2 = dir.join("log2.jsonl");
    let (mut mock, path) = spawn_mock(&["--time-scale", "1"]);
    let (ok, stdout, err) = odocal(&[
        "record",
        "--port",
        &path,
        "--out",
        out2.to_str().unwrap(),
        "--duration-s",
        "0.5",
    ]);
    drop(mock.stdin.take());
    let _ = mock.wait();
    assert!(ok, "{err}");
    let (_, samples) = odocal::offline::log::read_log(&out2).unwrap();
    assert!(
        samples.travel.len() > 5 && samples.headings.len() > 5,
        "{stdout}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `status` on a pseudo-terminal that sends random bytes (another device, a wrong baud rate) and
/// on one that sends nothing: each is diagnosed, within 3 s, in words.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_port_with_garbage_or_silence_is_diagnosed_within_three_seconds() {
    use tokio::io::AsyncWriteExt;
    use tokio_serial::SerialPort;
    for garbage in [true, false] {
        let (mut master, slave) = tokio_serial::SerialStream::pair().unwrap();
        let path = slave.name().unwrap();
        let writer = tokio::spawn(async move {
            let mut x: u32 = 12345;
            loop {
                if garbage {
                    let mut chunk = [0u8; 64];
                    for b in &mut chunk {
                        // A small LCG: any bytes that are not frames.
                        x = x.wrapping_mul(1_103_515_245).wrapping_add(12_345);
                        *b = (x >> 16) as u8;
                    }
                    if master.write_all(&chunk).await.is_err() {
                        tokio::time::sleep(std::time::Duration::from_millis(5)).await;
                    }
                }
                tokio::time::sleep(std::time::Duration::from_millis(10)).await;
            }
        });
        let started = std::time::Instant::now();
        let (ok, _, err) =
            tokio::task::spawn_blocking(move || common::odocal(&["status", "--port", &path]))
                .await
                .unwrap();
        let took = started.elapsed();
        writer.abort();
        drop(slave);
        assert!(!ok);
        if garbage {
            assert!(err.contains("none forms an odocal frame"), "{err}");
            assert!(err.contains("baud"), "{err}");
        } else {
            assert!(err.contains("nothing arrived"), "{err}");
        }
        assert!(
            took < std::time::Duration::from_secs(3),
            "took {took:?}: {err}"
        );
    }
}

#[test]
fn backups_never_overwrite_and_restore_from_a_backup_shows_the_change_first() {
    let dir = scratch("restore-from");
    std::fs::create_dir_all(&dir).unwrap();
    let (mut mock, path) = spawn_mock(&[]);
    let d = dir.to_str().unwrap();
    let get = |path: &str| {
        odocal_json(&["params", "get", "--port", path, "--json"])["wheelbase_m"]
            .as_f64()
            .unwrap()
    };
    let original = get(&path);
    // Two changes in quick succession: two backups, the first still holding the original.
    for wheelbase in ["0.41", "0.42"] {
        let (ok, _, err) = odocal(&[
            "params",
            "set",
            "--port",
            &path,
            "--wheelbase-m",
            wheelbase,
            "--backup-dir",
            d,
        ]);
        assert!(ok, "{err}");
    }
    let mut backups: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    backups.sort();
    assert_eq!(backups.len(), 2, "{backups:?}");
    let first = backups
        .iter()
        .find(|b| {
            odocal::base::transaction::read_backup(b)
                .unwrap()
                .active
                .wheelbase_m
                == original
        })
        .expect("a backup of the original parameters")
        .clone();
    // Declined (stdin is empty): nothing written, the change was shown.
    let (ok, _, err) = odocal(&[
        "params",
        "restore",
        "--port",
        &path,
        "--from",
        first.to_str().unwrap(),
        "--backup-dir",
        d,
    ]);
    assert!(!ok && err.contains("declined"), "{err}");
    assert!(err.contains("wheelbase"), "the diff is shown first: {err}");
    assert_eq!(get(&path), 0.42);
    // With --yes: restored, after a third backup of what was there.
    let (ok, _, err) = odocal(&[
        "params",
        "restore",
        "--port",
        &path,
        "--from",
        first.to_str().unwrap(),
        "--backup-dir",
        d,
        "--yes",
    ]);
    assert!(ok, "{err}");
    assert_eq!(get(&path), original);
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 3);
    // A file that is not a backup is refused with its name, and nothing changes.
    let junk = dir.join("junk.json");
    std::fs::write(&junk, "{\"active\": 3}").unwrap();
    let (ok, _, err) = odocal(&[
        "params",
        "restore",
        "--port",
        &path,
        "--from",
        junk.to_str().unwrap(),
        "--yes",
    ]);
    assert!(!ok && err.contains("junk.json"), "{err}");
    // A backup of another device is refused unless asked for.
    let mut other = odocal::base::transaction::read_backup(&first).unwrap();
    other.store.id = "someone-else-1234".into();
    let foreign = dir.join("foreign.json");
    std::fs::write(&foreign, serde_json::to_string(&other).unwrap()).unwrap();
    let (ok, _, err) = odocal(&[
        "params",
        "restore",
        "--port",
        &path,
        "--from",
        foreign.to_str().unwrap(),
        "--yes",
    ]);
    assert!(!ok && err.contains("--any-device"), "{err}");
    drop(mock.stdin.take());
    let _ = mock.wait();
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn heading_errors_up_to_180_degrees_are_estimated_with_a_warning() {
    let args = |cw: &str, ccw: &str| {
        odocal(&[
            "estimate",
            "--side-m",
            "4",
            "--wheelbase-m",
            "0.39",
            &format!("--cw-heading-deg={cw}"),
            &format!("--ccw-heading-deg={ccw}"),
            "--method",
            "exact",
        ])
    };
    // A skid-steer-like robot: 100° short on every square.
    let (ok, out, err) = args("-100,-101", "95,96");
    assert!(ok, "{err}");
    assert!(out.contains("exact"), "{out}");
    assert!(err.contains("90° or more"), "{err}");
    // Beyond 180° an error cannot be a wrapped heading: refused, naming the units.
    let (ok, _, err) = args("-200", "95");
    assert!(!ok && err.contains("degrees vs radians"), "{err}");
}

#[test]
fn a_skid_steer_sized_change_needs_allow_large_change_and_then_calibrates() {
    let dir = scratch("large-change");
    let d = dir.to_str().unwrap();
    // A simulated robot whose effective wheelbase is 1.5 × the configured one.
    let (ok, _, err) = odocal(&["demo", "--true-eb", "1.5", "--report-dir", d]);
    assert!(!ok);
    assert!(
        err.contains("+50.0 %") && err.contains("--allow-large-change"),
        "{err}"
    );
    let (ok, out, err) = odocal(&[
        "demo",
        "--true-eb",
        "1.5",
        "--allow-large-change",
        "--report-dir",
        d,
        "--json",
    ]);
    assert!(ok, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    let report = if v.get("report").is_some() {
        &v["report"]
    } else {
        &v
    };
    assert_eq!(report["converged"], true);
    let b = report["final_params"]["wheelbase_m"].as_f64().unwrap();
    assert!((b / (0.39 * 1.5) - 1.0).abs() < 1e-3, "wheelbase {b}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn routine_files_refuse_large_changes_unless_allowed() {
    use odocal::routine::config::RoutineConfig;
    let mut cfg = RoutineConfig {
        max_change: 0.9,
        ..RoutineConfig::default()
    };
    let err = cfg.validate().unwrap_err().to_string();
    assert!(err.contains("allow_large_change"), "{err}");
    cfg.allow_large_change = true;
    assert!(cfg.validate().is_ok());
    cfg.max_change = 1.5;
    assert!(cfg.validate().is_err());
}

#[test]
fn numeric_flags_outside_their_physical_range_are_refused_before_anything_runs() {
    for (args, want) in [
        (
            vec![
                "simulate",
                "--heading-sigma-deg",
                "0",
                "--runs",
                "1000000000",
            ],
            "--runs must be in [1, 1000]",
        ),
        (
            vec!["simulate", "--heading-sigma-deg", "0", "--side-m", "1e308"],
            "--side-m must be in",
        ),
        (
            vec![
                "estimate",
                "--side-m",
                "1e308",
                "--wheelbase-m",
                "0.39",
                "--cw-heading-deg",
                "1",
                "--ccw-heading-deg",
                "1",
            ],
            "--side-m must be in [0.05, 100] m",
        ),
        (
            vec!["mock-device", "--faults", "latency-ms=-5"],
            "latency-ms must be in [0, 10000]",
        ),
        (
            vec!["mock-device", "--faults", "latency-ms=NaN"],
            "latency-ms must be in [0, 10000]",
        ),
        (
            vec!["status", "--port", "/dev/null", "--baud", "0"],
            "baud rate 0 is outside",
        ),
        (
            vec!["status", "--port", "roboclaw:/dev/null", "--baud", "0"],
            "baud 0 is not a RoboClaw rate",
        ),
        (
            vec!["params", "get", "--port", "mock"],
            "this command talks to an odocal-protocol controller",
        ),
    ] {
        let started = std::time::Instant::now();
        let (ok, _, err) = odocal(&args);
        assert!(!ok, "{args:?} must fail");
        assert!(err.contains(want), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
        assert!(
            started.elapsed() < std::time::Duration::from_secs(5),
            "{args:?}"
        );
    }
}

#[test]
fn parameters_outside_the_spec_are_refused_by_the_host_before_anything_is_sent() {
    let dir = scratch("host-range");
    std::fs::create_dir_all(&dir).unwrap();
    let (mut mock, path) = spawn_mock(&[]);
    let d = dir.to_str().unwrap();
    // 2.5 m fits the wire's u32 but not SPEC.md §4.1; 5 m does not even fit the wire (it was
    // a debug dump); a 0.5 right/left diameter ratio breaks the ratio rule.
    for (flag, value, says) in [
        (
            "--wheelbase-m",
            "2.5",
            "wheelbase 2.5 m is outside 0.02..=2 m",
        ),
        ("--wheelbase-m", "5", "wheelbase 5 m is outside 0.02..=2 m"),
        (
            "--right-wheel-diameter-m",
            "0.075",
            "ratio 0.5000 is outside 0.8..=1.25",
        ),
    ] {
        let (ok, _, err) = odocal(&[
            "params",
            "set",
            "--port",
            &path,
            flag,
            value,
            "--backup-dir",
            d,
        ]);
        assert!(!ok, "{flag} {value}");
        assert!(err.contains(says) && err.contains("not sent"), "{err}");
        assert!(!err.contains("UnitError"), "{err}");
    }
    let backups = std::fs::read_dir(&dir).map_or(0, |r| r.count());
    assert_eq!(backups, 0, "no backup for a change that was never sent");
    assert_eq!(
        odocal_json(&["params", "get", "--port", &path, "--json"])["wheelbase_m"],
        0.39
    );
    drop(mock.stdin.take());
    let _ = mock.wait();
    let _ = std::fs::remove_dir_all(&dir);
}

/// Runs the binary, which must finish within `secs` (it is killed and the test fails if not).
fn odocal_within(args: &[&str], secs: u64) -> (bool, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_odocal"))
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = std::time::Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let mut err = String::new();
            std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut err).unwrap();
            return (status.success(), err);
        }
        if start.elapsed() > std::time::Duration::from_secs(secs) {
            let _ = child.kill();
            panic!("odocal {args:?} still running after {secs} s");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

/// Files linked to endless devices (or a FIFO nobody writes) were read until the kernel killed
/// odocal: every file it reads is now judged first, refused with the reason, at once.
#[test]
fn endless_and_special_files_are_refused_not_read_forever() {
    let dir = scratch("endless");
    std::fs::create_dir_all(&dir).unwrap();
    let zero = |name: &str| {
        let p = dir.join(name);
        std::os::unix::fs::symlink("/dev/zero", &p).unwrap();
        p.to_str().unwrap().to_string()
    };
    let fifo = dir.join("fifo.toml");
    assert!(Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap()
        .success());
    let fifo = fifo.to_str().unwrap().to_string();
    let routine = zero("routine.toml");
    let log = zero("telemetry.log");
    let bag = zero("run.mcap");
    let backup = zero("backup.json");
    for args in [
        vec!["run", routine.as_str()],
        vec!["run", fifo.as_str()],
        vec!["track", "--log", log.as_str()],
        vec!["bag", bag.as_str()],
        vec!["export", "--from", backup.as_str(), "--ros2", "out.yaml"],
    ] {
        let (ok, err) = odocal_within(&args, 10);
        assert!(!ok, "{args:?}");
        assert!(err.contains("not a regular file"), "{args:?}: {err}");
    }
    // A recorded set whose run file is a link to /dev/zero.
    if let Some(root) = common::optiodom("square") {
        let real = root.join("square/230620202042");
        let set = dir.join("230620202042");
        std::fs::create_dir_all(&set).unwrap();
        for entry in std::fs::read_dir(&real).unwrap() {
            let p = entry.unwrap().path();
            let name = p.file_name().unwrap().to_owned();
            if name.to_string_lossy().ends_with("run-01.csv") {
                std::os::unix::fs::symlink("/dev/zero", set.join(&name)).unwrap();
            } else {
                std::fs::copy(&p, set.join(&name)).unwrap();
            }
        }
        let (ok, err) = odocal_within(&["replay", "--dataset", set.to_str().unwrap()], 10);
        assert!(!ok);
        assert!(err.contains("not a regular file"), "{err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The headless Chromium `.ci/run` installs, if it is there.
fn chromium() -> Option<PathBuf> {
    ["/usr/bin/chromium", "/usr/bin/chromium-browser"]
        .iter()
        .map(PathBuf::from)
        .find(|p| p.is_file())
}

/// Opens `page` in headless Chromium (with no network: nothing may be fetched) and reads back
/// what the page itself saw once loaded: how many plots, how many drawn at a real size, how
/// many run traces the first (the paths) shows on screen, how many resources were fetched.
/// Skipped, with a notice, where no browser is installed.
fn opens_in_a_browser_with_its_plots_and_fetches_nothing(
    page: &std::path::Path,
    plots: usize,
    traces: usize,
) {
    let Some(browser) = chromium() else {
        eprintln!("NOTICE: no headless Chromium; report.html checked by structure only");
        return;
    };
    let html = std::fs::read_to_string(page).unwrap();
    let probe = page.with_file_name("browser-probe.html");
    std::fs::write(
        &probe,
        html.replace(
            "</body>",
            "<script>window.addEventListener('load', () => { \
             const svgs = [...document.querySelectorAll('svg')]; \
             const drawn = svgs.filter(s => { const r = s.getBoundingClientRect(); \
               return r.width > 200 && r.height > 150; }).length; \
             const traces = [...svgs[0].querySelectorAll('polyline')].filter(p => \
               p.points.length > 2 && p.getBoundingClientRect().width > 10).length; \
             document.body.setAttribute('data-probe', \
               `svgs=${svgs.length} drawn=${drawn} traces=${traces} \
                fetched=${performance.getEntriesByType('resource').length}`); \
             });</script></body>",
        ),
    )
    .unwrap();
    let profile = probe.with_file_name("browser-profile");
    let out = Command::new(browser)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--virtual-time-budget=5000",
            "--dump-dom",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg(format!("file://{}", probe.display()))
        .output()
        .expect("chromium runs");
    let dom = String::from_utf8_lossy(&out.stdout);
    let seen = dom
        .split("data-probe=\"")
        .nth(1)
        .and_then(|rest| rest.split('"').next())
        .unwrap_or_else(|| {
            panic!(
                "the page reported nothing: {}",
                String::from_utf8_lossy(&out.stderr)
            )
        });
    assert_eq!(
        seen,
        format!("svgs={plots} drawn={plots} traces={traces} fetched=0"),
        "report.html in Chromium"
    );
    let _ = std::fs::remove_file(&probe);
    let _ = std::fs::remove_dir_all(&profile);
}

/// An option's help as one line (clap wraps it over several), with its name and whether it
/// takes a value.
struct OptionHelp {
    name: String,
    takes_value: bool,
    text: String,
}

/// The options in a `--help` page: each starts a line with `-` and runs on until the next.
fn options_in(help: &str) -> Vec<OptionHelp> {
    let mut texts: Vec<String> = Vec::new();
    for line in help.lines() {
        if line.trim_start().starts_with('-') {
            texts.push(String::new());
        }
        if let Some(t) = texts.last_mut() {
            t.push_str(line.trim());
            t.push(' ');
        }
    }
    texts
        .into_iter()
        .filter_map(|text| {
            let mut words = text.split_whitespace();
            let name = words.find(|w| w.starts_with("--"))?.trim_end_matches(',');
            let takes_value = words.next().is_some_and(|w| w.starts_with('<'));
            Some(OptionHelp {
                name: name.to_string(),
                takes_value,
                text: text.clone(),
            })
        })
        .collect()
}

/// The subcommands a `--help` page lists (not `help`).
fn subcommands_in(help: &str) -> Vec<String> {
    help.lines()
        .skip_while(|l| !l.starts_with("Commands:"))
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| l.split_whitespace().next())
        .filter(|c| *c != "help")
        .map(str::to_string)
        .collect()
}

/// `calibrate --help` states every default: each option that takes a value shows
/// `[default: …]` unless it is one that has none (a port, a file, a target, a measurement).
#[test]
fn calibrate_help_states_every_default() {
    let (ok, help, err) = odocal(&["calibrate", "--help"]);
    assert!(ok, "{err}");
    let no_default = [
        "--port",
        "--base",
        "--heading",
        "--profile",
        "--compass-deviation-deg",
        "--ros-yaml",
        "--config",
        "--target-eb-std",
        "--target-ed-std",
        "--gyro-scale-error",
        "--straight-commanded-m",
        "--straight-measured-m",
        // One flag for five budgets: each one's default is in its text.
        "--budget",
    ];
    let options: Vec<OptionHelp> = options_in(&help)
        .into_iter()
        .filter(|o| o.takes_value)
        .collect();
    for o in &options {
        let shown = o.text.contains("[default: ");
        if no_default.contains(&o.name.as_str()) {
            // The list stays true: an option given a default leaves it.
            assert!(!shown, "{} has a default now: {}", o.name, o.text);
        } else {
            assert!(shown, "{} shows no default: {}", o.name, o.text);
        }
    }
    // Every exempt option is still there, and the page was read: side, runs, speeds, method…
    for name in no_default {
        assert!(options.iter().any(|o| o.name == name), "no {name}: {help}");
    }
    assert!(options.len() > no_default.len() + 20, "{help}");
}

/// In every subcommand's help, an option that takes a value and has a default states it the one
/// way, `[default: …]`, where a reader (and the man page) looks for it, never in prose.
#[test]
fn every_default_in_help_is_stated_the_same_way() {
    let mut pages = vec![Vec::<String>::new()];
    let mut seen = 0;
    while let Some(path) = pages.pop() {
        let args: Vec<&str> = path.iter().map(String::as_str).chain(["--help"]).collect();
        let (ok, help, err) = odocal(&args);
        assert!(ok, "{args:?}: {err}");
        seen += 1;
        for o in options_in(&help).iter().filter(|o| o.takes_value) {
            // "(default: …)", "Default: …", "by default …", but not "the factory defaults".
            let prose = o.text.replace("[default: ", "").to_lowercase();
            assert!(
                !prose.contains("default:") && !prose.contains("by default"),
                "odocal {} {}: {}",
                path.join(" "),
                o.name,
                o.text
            );
        }
        for sub in subcommands_in(&help) {
            pages.push(path.iter().cloned().chain([sub]).collect());
        }
    }
    // odocal, its subcommands, and those of params.
    assert!(seen > 25, "only {seen} help pages");
}

#[test]
fn completions_and_man_pages_are_generated() {
    let (ok, bash, err) = odocal(&["completions", "bash"]);
    assert!(ok, "{err}");
    // The script completes the subcommands and their flags.
    assert!(bash.contains("complete -F"), "{bash}");
    for word in ["calibrate", "mock-roboclaw", "completions", "--side-m"] {
        assert!(bash.contains(word), "no {word} in the bash script");
    }
    for shell in ["zsh", "fish", "powershell", "elvish"] {
        let (ok, script, err) = odocal(&["completions", shell]);
        assert!(ok && script.contains("calibrate"), "{shell}: {err}");
    }
    let (ok, _, err) = odocal(&["completions", "tcsh"]);
    assert!(!ok && err.contains("possible values"), "{err}");

    // roff: a title line, then the sections, the subcommands among them.
    let (ok, page, err) = odocal(&["man"]);
    assert!(ok, "{err}");
    assert!(
        page.lines().any(|l| l.starts_with(".TH odocal 1")),
        "{page}"
    );
    for section in [".SH NAME", ".SH SYNOPSIS", ".SH SUBCOMMANDS"] {
        assert!(page.contains(section), "no {section}: {page}");
    }
    assert!(page.contains("odocal\\-calibrate(1)"), "{page}");

    // --out: one page per subcommand (and per nested one), each its own roff document.
    let dir = scratch("man");
    let (ok, out, err) = odocal(&["man", "--out", dir.to_str().unwrap()]);
    assert!(ok, "{err}");
    assert!(out.contains(dir.to_str().unwrap()), "{out}");
    let (_, help, _) = odocal(&["--help"]);
    let mut expected: Vec<String> = subcommands_in(&help)
        .iter()
        .map(|c| format!("odocal-{c}.1"))
        .collect();
    expected.push("odocal.1".into());
    expected.push("odocal-params-restore.1".into());
    for name in &expected {
        let text =
            std::fs::read_to_string(dir.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        let title = format!(".TH {} 1", name.trim_end_matches(".1"));
        assert!(
            text.lines().any(|l| l.starts_with(&title)),
            "{name}: {text}"
        );
    }
    let calibrate = std::fs::read_to_string(dir.join("odocal-calibrate.1")).unwrap();
    assert!(
        calibrate.contains("\\-\\-side\\-m") && calibrate.contains("[default: 4]"),
        "{calibrate}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A `--port` that is not a serial port (missing, a plain file, a directory, `/dev/null`) is
/// named as such, pointing to `odocal ports`, before anything says that the robot will move.
#[test]
fn a_path_that_is_not_a_serial_port_is_named_before_anything_says_it_moves() {
    let dir = scratch("not-a-port");
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("plain-file");
    std::fs::write(&file, "").unwrap();
    let missing = dir.join("ttyUSB9");
    let cases = [
        (file.to_str().unwrap().to_string(), "a regular file"),
        (dir.to_str().unwrap().to_string(), "a directory"),
        (missing.to_str().unwrap().to_string(), "does not exist"),
        ("/dev/null".to_string(), "takes no serial settings"),
    ];
    for (port, says) in &cases {
        for command in [
            &["calibrate", "--port", port, "--yes"][..],
            &["status", "--port", port],
        ] {
            let (ok, _, err) = odocal(command);
            assert!(!ok, "{command:?}");
            assert!(
                err.contains(says) && err.contains("odocal ports"),
                "{command:?}: {err}"
            );
            assert!(!err.contains("MOVES THE ROBOT"), "{command:?}: {err}");
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Numbers no square test or robot can produce are refused with the flag, its range and the
/// value in a form a person reads (issue 29, item 3 in part): a final position beyond the
/// square's perimeter, a 1e300 m wheel, 1e300 heading readings per second.
#[test]
fn numbers_beyond_any_robot_are_refused_with_their_range() {
    let square = [
        "estimate",
        "--side-m",
        "4",
        "--wheelbase-m",
        "0.39",
        "--cw-heading-deg=-26.31,-26.92",
        "--ccw-heading-deg=-11.62,-12.15",
    ];
    let mut far = square.to_vec();
    far.extend(["--cw-xy-m", "1e300,1e300;1,1", "--ccw-xy-m", "1,1;1,1"]);
    let (ok, out, err) = odocal(&far);
    assert!(!ok && out.is_empty(), "{out}");
    assert!(
        err.contains("clockwise run 1") && err.contains("1.414e300 m") && err.contains("16 m"),
        "{err}"
    );
    let mut wheel = square.to_vec();
    wheel.extend(["--wheel-diameter-m", "1e300"]);
    let (ok, _, err) = odocal(&wheel);
    assert!(
        !ok && err.contains("--wheel-diameter-m must be in [0.001, 5], got 1e300"),
        "{err}"
    );
    let (ok, _, err) = odocal(&[
        "plan",
        "--side-m",
        "2",
        "--heading-sigma-deg",
        "0.37",
        "--wheelbase-m",
        "0.39",
        "--heading-hz",
        "1e300",
    ]);
    assert!(
        !ok && err.contains("--heading-hz must be in [0.1, 1000], got 1e300"),
        "{err}"
    );
}

/// `record` stopped by Ctrl-C before any telemetry came (a mock in virtual time streams
/// nothing while idle) says so and how to start one that streams, with no time it never had.
#[test]
fn record_stopped_before_any_telemetry_says_what_to_do() {
    let (mut mock, port) = spawn_mock(&[]);
    let dir = scratch("record-empty");
    std::fs::create_dir_all(&dir).unwrap();
    let log = dir.join("drive.jsonl");
    let child = Command::new(env!("CARGO_BIN_EXE_odocal"))
        .args(["record", "--port", &port, "--out", log.to_str().unwrap()])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_secs(2));
    let sent = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .is_ok_and(|s| s.success());
    let out = child.wait_with_output().unwrap();
    let _ = mock.kill();
    let _ = mock.wait();
    assert!(sent);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("stopped by Ctrl-C")
            && err.contains("no telemetry arrived before it was stopped")
            && err.contains("--time-scale 1")
            && !err.contains("NaN"),
        "{err}"
    );
    // The log keeps its header: what was recorded is not lost.
    assert!(std::fs::read_to_string(&log).unwrap().lines().count() >= 1);
}

/// Every command and flag the features table says a build may leave out is one of the full
/// build (a renamed one cannot leave the table naming what no longer exists): each command
/// answers `--help`, each flag is in the help of a command that has it.
#[test]
fn the_words_a_feature_leaves_out_are_commands_and_flags_of_the_full_build() {
    let helps: Vec<String> = ["fit", "simulate", "replay"]
        .iter()
        .map(|c| common::odocal(&[c, "--help"]).1)
        .collect();
    for (word, features) in odocal::features::COMMAND_LINE {
        assert!(!features.is_empty(), "{word}");
        if word.starts_with("--") {
            let flag = format!("{word} ");
            assert!(helps.iter().any(|h| h.contains(&flag)), "{word}");
        } else {
            let (ok, help, err) = common::odocal(&[word, "--help"]);
            assert!(ok && help.contains("Usage: odocal"), "{word}: {err}");
        }
        assert!(odocal::features::left_out(word).is_none(), "{word}");
    }
}
