//! `odocal calibrate` on `odocal mock-device` (20 times real speed) interrupted by a signal in
//! each phase — SIGINT (Ctrl-C), and SIGTERM and SIGHUP (what a service manager, `timeout`, a
//! closed SSH session send), handled alike: the command fails, its last two lines say that the
//! robot stopped and what its parameters are, the device is idle and holds what the lines say,
//! and nothing is left outside the report directory (nothing at all when nothing was driven).

mod common;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// What a run interrupted at `marker` must end with.
struct Case {
    name: &'static str,
    signal: &'static str,
    /// The stderr line (its start, trimmed) after which the signal is sent.
    marker: &'static str,
    /// What the last line says of the parameters.
    parameters: &'static str,
    /// Whether the run leaves files (it measured a square).
    leaves_files: bool,
}

const CASES: [Case; 6] = [
    Case {
        name: "int-preflight",
        signal: "INT",
        marker: "· pre-flight checks",
        parameters: "parameters: untouched",
        leaves_files: false,
    },
    Case {
        name: "int-round1",
        signal: "INT",
        marker: "round 1: square 1 of",
        parameters: "parameters: untouched",
        leaves_files: true,
    },
    Case {
        name: "int-round2",
        signal: "INT",
        marker: "round 2: square 1 of",
        parameters: "parameters: restored to what they were before the run",
        leaves_files: true,
    },
    Case {
        name: "int-verification",
        signal: "INT",
        marker: "verification: square 1 of",
        parameters: "parameters: restored to what they were before the run",
        leaves_files: true,
    },
    Case {
        name: "term-round2",
        signal: "TERM",
        marker: "round 2: square 1 of",
        parameters: "parameters: restored to what they were before the run",
        leaves_files: true,
    },
    Case {
        name: "hup-verification",
        signal: "HUP",
        marker: "verification: square 1 of",
        parameters: "parameters: restored to what they were before the run",
        leaves_files: true,
    },
];

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
    let mut child = Command::new(env!("CARGO_BIN_EXE_odocal"))
        .args(&args)
        .current_dir(&dir)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = Vec::new();
    let mut sent = false;
    for line in BufReader::new(child.stderr.take().unwrap()).lines() {
        let line = line.unwrap();
        if !sent && line.trim_start().starts_with(case.marker) {
            let ok = Command::new("kill")
                .args([&format!("-{}", case.signal), &child.id().to_string()])
                .status()
                .unwrap()
                .success();
            assert!(ok, "{}: kill", case.name);
            sent = true;
        }
        lines.push(line);
    }
    let status = child.wait().unwrap();
    let text = lines.join("\n");
    assert!(
        sent,
        "{}: never reached `{}`:\n{text}",
        case.name, case.marker
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
        parameters.starts_with(case.parameters),
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
    let restored = case.parameters.contains("restored");
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
    if case.leaves_files {
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
    std::thread::scope(|s| {
        for pair in CASES.chunks(3) {
            s.spawn(move || pair.iter().for_each(interrupted));
        }
    });
}
