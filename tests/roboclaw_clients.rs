//! `mock-roboclaw` against a RoboClaw client odocal did not write: Basicmicro's own Python
//! library (pinned in `.ci/requirements.txt`) runs `tests/clients/roboclaw_conformance.py` —
//! every command odocal uses and every read the mock answers, with the user manual's layouts:
//! buffered distance commands queued and replacing, the buffer length, speed commands, the
//! serial timeout, bad CRCs and unknown commands unanswered, the EEPROM key.

mod common;

use std::process::Command;
use std::time::{Duration, Instant};

/// Robot seconds per wall-clock second: quick legs, still slow enough to watch the buffers.
const TIME_SCALE: &str = "4";

#[test]
fn basicmicro_passes_its_conformance_checks_against_the_mock() {
    let Some(python) = common::client_python() else {
        return;
    };
    let (_, profile) = common::scratch_with("basicmicro", "robot.toml", common::ROBOCLAW_PROFILE);
    let (mut mock, lines) = common::spawn_server_lines(
        "mock-roboclaw",
        &[
            "--profile",
            profile.to_str().unwrap(),
            "--time-scale",
            TIME_SCALE,
        ],
        2,
    );
    let claw = lines[0].clone();
    assert!(claw.starts_with("roboclaw:/"), "{claw}");
    let script = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/clients/roboclaw_conformance.py"
    );
    let started = Instant::now();
    let out = Command::new(&python)
        .args([script, &claw, TIME_SCALE])
        .output()
        .expect("python runs");
    let took = started.elapsed();
    let _ = mock.kill();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains(" passed, 0 failed"), "{stdout}");
    assert!(took < Duration::from_secs(20), "{took:?}\n{stdout}");
}
