//! `odocal calibrate` on `odocal mock-device` (20 times real speed), and on `odocal
//! mock-roboclaw` with its robot profile, interrupted in each phase (pre-flight, round 1,
//! round 2, verification) by each signal — SIGINT (Ctrl-C) on the device, and SIGTERM and
//! SIGHUP (what a service manager, `timeout`, a closed SSH session send) on both — handled
//! alike: the command fails, its last two lines say that the
//! robot stopped and what its parameters are, the device is idle and holds what the lines say,
//! and nothing is left outside the report directory (nothing at all when nothing was driven).

mod common;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// A phase of `calibrate` a signal may land in, and what a run interrupted there must end with.
struct Phase {
    name: &'static str,
    /// The stderr line (its start, trimmed) after which the signal is sent.
    marker: &'static str,
    /// What the last line says of the parameters.
    parameters: &'static str,
    /// Whether the run leaves files (it measured a square).
    leaves_files: bool,
}

const UNTOUCHED: &str = "parameters: untouched";
const RESTORED: &str = "parameters: restored to what they were before the run";

const PHASES: [Phase; 4] = [
    Phase {
        name: "preflight",
        marker: "· pre-flight checks",
        parameters: UNTOUCHED,
        leaves_files: false,
    },
    Phase {
        name: "round1",
        marker: "round 1: square 1 of",
        parameters: UNTOUCHED,
        leaves_files: true,
    },
    Phase {
        name: "round2",
        marker: "round 2: square 1 of",
        parameters: RESTORED,
        leaves_files: true,
    },
    Phase {
        name: "verification",
        marker: "verification: square 1 of",
        parameters: RESTORED,
        leaves_files: true,
    },
];

/// One interrupted run: a signal in a phase.
struct Case {
    name: String,
    signal: &'static str,
    phase: &'static Phase,
}

/// Every signal in every phase.
fn cases(signals: &[&'static str], prefix: &str) -> Vec<Case> {
    signals
        .iter()
        .flat_map(|&signal| {
            PHASES.iter().map(move |phase| Case {
                name: format!("{prefix}{}-{}", signal.to_lowercase(), phase.name),
                signal,
                phase,
            })
        })
        .collect()
}

/// Runs `odocal args…` in `dir` and sends `signal` once a stderr line starts with `marker`:
/// whether it was sent, the exit status, the lines.
fn signalled(
    args: &[&str],
    dir: &Path,
    signal: &str,
    marker: &str,
) -> (bool, std::process::ExitStatus, Vec<String>) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_odocal"))
        .args(args)
        .current_dir(dir)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = Vec::new();
    let mut sent = false;
    for line in BufReader::new(child.stderr.take().unwrap()).lines() {
        let line = line.unwrap();
        if !sent && line.trim_start().starts_with(marker) {
            let ok = Command::new("kill")
                .args([&format!("-{signal}"), &child.id().to_string()])
                .status()
                .unwrap()
                .success();
            assert!(ok, "kill -{signal}");
            sent = true;
        }
        lines.push(line);
    }
    (sent, child.wait().unwrap(), lines)
}

/// Every file under `dir`, recursively.
fn tree(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            out.extend(tree(&p));
        } else {
            out.push(p);
        }
    }
    out.sort();
    out
}

fn interrupted(case: &Case) {
    let (mut mock, port) = common::spawn_mock(&["--time-scale", "20", "--seed", "3"]);
    let dir = common::scratch(&format!("signal-{}", case.name));
    std::fs::create_dir_all(&dir).unwrap();
    let mut args = vec!["calibrate", "--port", &port];
    args.extend(common::QUICK_FLAGS);
    args.extend(["--report-dir", "report"]);
    let phase = case.phase;
    let (sent, status, lines) = signalled(&args, &dir, case.signal, phase.marker);
    let text = lines.join("\n");
    assert!(
        sent,
        "{}: never reached `{}`:\n{text}",
        case.name, phase.marker
    );
    assert!(!status.success(), "{}: exit {status}:\n{text}", case.name);
    let last: Vec<&str> = lines
        .iter()
        .map(|l| l.trim())
        .filter(|l| !l.is_empty())
        .collect();
    let [.., robot, parameters] = last.as_slice() else {
        panic!("{}: no output", case.name)
    };
    assert_eq!(*robot, "robot: stopped", "{}:\n{text}", case.name);
    assert!(
        parameters.starts_with(phase.parameters),
        "{}:\n{text}",
        case.name
    );
    // The device is idle and holds the original parameters in use, and stored too once a
    // write had been committed (the mock starts with no stored copy).
    let status = common::odocal_json(&["status", "--port", &port, "--json"]);
    assert_eq!(
        status["status"]["motion_state"], "idle",
        "{}: {status}",
        case.name
    );
    let restored = phase.parameters == RESTORED;
    for source in ["active", "stored"]
        .iter()
        .take(if restored { 2 } else { 1 })
    {
        let p = common::odocal_json(&[
            "params", "get", "--port", &port, "--source", *source, "--json",
        ]);
        assert_eq!(p["wheelbase_m"].as_f64(), Some(0.39), "{}: {p}", case.name);
    }
    drop(mock.stdin.take());
    let _ = mock.wait();
    // Nothing outside the report directory; in it, the backup and the partial report only
    // when a square was measured, else nothing at all.
    let left = tree(&dir);
    let report = dir.join("report");
    assert!(
        left.iter().all(|f| f.starts_with(&report)),
        "{}: {left:?}",
        case.name
    );
    if phase.leaves_files {
        let names: Vec<String> = left
            .iter()
            .map(|f| f.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names.len(), 2, "{}: {names:?}", case.name);
        assert!(
            names.iter().any(|n| n.starts_with("odocal-backup-"))
                && names.iter().any(|n| n.starts_with("partial-report-")),
            "{}: {names:?}",
            case.name
        );
    } else {
        assert!(left.is_empty(), "{}: {left:?}", case.name);
        assert!(!report.exists(), "{}: an empty report directory", case.name);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_signal_in_any_phase_stops_the_robot_restores_and_says_so_last() {
    // The runs mostly wait on the simulated robot's time: several at once.
    let all = cases(&["INT", "TERM", "HUP"], "");
    std::thread::scope(|s| {
        for pair in all.chunks(2) {
            s.spawn(move || pair.iter().for_each(interrupted));
        }
    });
}

/// The last two non-empty lines of `lines`.
fn last_two(lines: &[String]) -> (String, String) {
    let last: Vec<&str> = lines
        .iter()
        .map(|l| l.trim())
        .filter(|l| !l.is_empty())
        .collect();
    match last.as_slice() {
        [.., a, b] => (a.to_string(), b.to_string()),
        _ => panic!("no output"),
    }
}

/// `calibrate` on `mock-roboclaw` interrupted as `case` says: the robot's wheels are still,
/// the last two lines say so and what the profile holds, and that is true of the file.
fn roboclaw_interrupted(case: &Case) {
    let (name, signal, phase) = (&case.name, case.signal, case.phase);
    let (dir, profile) = common::scratch_with(name, "robot.toml", common::ROBOCLAW_PROFILE);
    let profile_s = profile.to_str().unwrap().to_string();
    let (mut mock, ports) = common::spawn_server_lines(
        "mock-roboclaw",
        &["--profile", &profile_s, "--time-scale", "20"],
        2,
    );
    let mut args = vec![
        "calibrate",
        "--base",
        &ports[0],
        "--heading",
        &ports[1],
        "--profile",
        &profile_s,
    ];
    args.extend(common::QUICK_FLAGS);
    args.extend(["--report-dir", "report"]);
    let (sent, status, lines) = signalled(&args, &dir, signal, phase.marker);
    let text = lines.join("\n");
    assert!(sent, "{name}: never reached `{}`:\n{text}", phase.marker);
    assert!(!status.success(), "{name}: exit {status}:\n{text}");
    // The wheels are still: the encoders count the same twice, 0.3 s apart (6 s of the
    // simulated robot's time). (Their status bits are latched events, not motion.)
    let encoders = || {
        let s = common::odocal_json(&["status", "--port", &ports[0], "--json"]);
        [
            s["encoders"][0]["count"].clone(),
            s["encoders"][1]["count"].clone(),
        ]
    };
    let first = encoders();
    assert!(first.iter().all(|c| c.is_u64()), "{name}: {first:?}");
    std::thread::sleep(std::time::Duration::from_millis(300));
    assert_eq!(encoders(), first, "{name}: the wheels still turn");
    drop(mock.stdin.take());
    let _ = mock.wait();
    let (robot, parameters) = last_two(&lines);
    assert_eq!(robot, "robot: stopped", "{name}:\n{text}");
    assert!(parameters.starts_with(phase.parameters), "{name}:\n{text}");
    // The statement is true of the file: the profile is byte for byte as it was.
    assert_eq!(
        std::fs::read_to_string(&profile).unwrap(),
        common::ROBOCLAW_PROFILE,
        "{name}"
    );
    let report = dir.join("report");
    if phase.leaves_files {
        let names: Vec<String> = tree(&report)
            .iter()
            .map(|f| f.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert!(
            names.iter().any(|n| n.contains("odocal-backup-"))
                && names.iter().any(|n| n.contains("partial-report-")),
            "{name}: {names:?}"
        );
    } else {
        assert!(
            !report.exists(),
            "{name}: a report directory with nothing measured"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn on_a_roboclaw_sigterm_and_sighup_in_any_phase_stop_the_robot_and_leave_the_profile_as_it_was() {
    let all = cases(&["TERM", "HUP"], "roboclaw-");
    std::thread::scope(|s| {
        for pair in all.chunks(2) {
            s.spawn(move || pair.iter().for_each(roboclaw_interrupted));
        }
    });
}

/// A device that stops answering once the first signal came (its process stopped): odocal's
/// stop and restore wait on it, and a second signal leaves at once, exit status 130, after
/// telling the robot to stop (which the device obeys once it runs again) and saying what may be
/// left to do.
#[test]
fn a_second_signal_while_the_device_does_not_answer_stops_the_robot_and_leaves_at_once() {
    let (mut mock, port) = common::spawn_mock(&["--time-scale", "20", "--seed", "3"]);
    let dir = common::scratch("signal-second");
    std::fs::create_dir_all(&dir).unwrap();
    let mut args = vec!["calibrate", "--port", port.as_str()];
    args.extend(common::QUICK_FLAGS);
    args.extend(["--report-dir", "report"]);
    let mut child = Command::new(env!("CARGO_BIN_EXE_odocal"))
        .args(&args)
        .current_dir(&dir)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let kill = |signal: &str, pid: u32| {
        let ok = Command::new("kill")
            .args([&format!("-{signal}"), &pid.to_string()])
            .status()
            .unwrap()
            .success();
        assert!(ok, "kill -{signal} {pid}");
    };
    let mut lines = Vec::new();
    let mut reader = BufReader::new(child.stderr.take().unwrap()).lines();
    for line in reader.by_ref() {
        let line = line.unwrap();
        let at = line.trim_start().starts_with("round 2: square 1 of");
        lines.push(line);
        if at {
            break;
        }
    }
    kill("STOP", mock.id());
    kill("TERM", child.id());
    std::thread::sleep(std::time::Duration::from_millis(300));
    let sent = std::time::Instant::now();
    kill("TERM", child.id());
    let status = child.wait().unwrap();
    let waited = sent.elapsed();
    lines.extend(reader.map(|l| l.unwrap()));
    let text = lines.join("\n");
    kill("CONT", mock.id());
    assert_eq!(status.code(), Some(130), "{text}");
    assert!(
        waited < std::time::Duration::from_secs(10),
        "{waited:?} after the second signal:\n{text}"
    );
    assert!(
        text.contains("SIGTERM again: the robot was told to stop, leaving now")
            && text.contains("odocal restore BACKUP"),
        "{text}"
    );
    // The device, running again, is idle.
    let status = common::odocal_json(&["status", "--port", &port, "--json"]);
    assert_eq!(status["status"]["motion_state"], "idle", "{status}");
    drop(mock.stdin.take());
    let _ = mock.wait();
    std::fs::remove_dir_all(&dir).unwrap();
}
