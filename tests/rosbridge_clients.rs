//! `mock-rosbridge` against a rosbridge client odocal did not write: roslibpy (pinned in
//! `.ci/requirements.txt`) runs `tests/clients/rosbridge_conformance.py` — subscriptions per
//! id with throttle, two subscribers, publish, the controller's parameter services, rosapi,
//! status messages and calls without an id.

mod common;

use std::process::Command;

#[test]
fn roslibpy_passes_its_conformance_checks_against_the_mock() {
    let Some(python) = common::client_python() else {
        return;
    };
    let (_, yaml) = common::scratch_with("roslibpy", "diff_drive.yaml", common::DIFF_DRIVE_YAML);
    let (mut server, lines) = common::spawn_server_lines(
        "mock-rosbridge",
        &["--ros-yaml", yaml.to_str().unwrap(), "--port", "0"],
        1,
    );
    let port = lines[0].rsplit(':').next().unwrap().to_string();
    let script = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/clients/rosbridge_conformance.py"
    );
    let out = Command::new(&python)
        .args([script, "127.0.0.1", &port, "/diff_drive_controller"])
        .output()
        .expect("python runs");
    let _ = server.kill();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains(" passed, 0 failed"), "{stdout}");
}
