//! Every command in README.md's shell blocks, run as a reader would run it, on the mocks: the
//! hardware in a command (`/dev/ttyUSB0`, `roboclaw:/dev/ttyACM0`, `rosbridge://ROBOT:9090`, a
//! bag) is replaced by the mock or recording that stands for it, a prompt is answered "y", a
//! command that runs until Ctrl-C gets one after a few seconds. Each must exit 0 (or, stopped by
//! Ctrl-C, say so) and print no Rust `Debug` text. A command is run, or skipped for a reason
//! this file names (another test runs it, or it is not odocal's); a new README command that is
//! neither fails the test until it is placed.

mod common;

use std::io::Write;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Commands run elsewhere or that are not odocal's, by how they start, and why.
const SKIPPED: &[(&str, &str)] = &[
    (
        "cargo ",
        "cargo itself: the test suite is this command's own run",
    ),
    ("git clone", "fetches the repository this test runs in"),
    ("ros2 bag record", "ROS's own tool, on the robot"),
    (
        "odocal demo",
        "a sample: run and compared with the README by readme_and_manifest.rs",
    ),
    (
        "odocal plan",
        "a sample: run and compared with the README by readme_and_manifest.rs",
    ),
    (
        "odocal estimate",
        "a sample: run and compared with the README by readme_and_manifest.rs",
    ),
    (
        "odocal conformance",
        "conformance.rs runs it against mock-device as the README shows it \
         (the_mock_device_as_the_readme_shows_it_passes_conformance)",
    ),
    (
        "odocal mock-device --time-scale 5",
        "conformance.rs starts it as the README shows it",
    ),
    (
        "odocal calibrate --base 'rosbridge://ROBOT:9090'",
        "a real robot's defaults (5 squares each way of 2 m, a swing): its try-it form below \
         runs on mock-rosbridge",
    ),
    (
        "odocal calibrate --base 'roboclaw:/dev/ttyACM0'",
        "a real robot's defaults: its try-it form below runs on mock-roboclaw",
    ),
];

/// Rust `Debug` forms that must not reach a user.
fn debug_text(out: &str) -> Option<String> {
    for pat in [
        "Some(", "None)", "Ok(", "Err(", "Os {", "Custom {", "kind: ", "Error {",
    ] {
        if out.contains(pat) {
            return Some(pat.to_string());
        }
    }
    // A Duration's Debug form: digits glued to a unit ("1.5s", "250ms").
    let b = out.as_bytes();
    for (i, w) in b.windows(3).enumerate() {
        let unit_end = |j: usize| b.get(j).is_none_or(|c| !c.is_ascii_alphanumeric());
        if w[0].is_ascii_digit()
            && ((w[1] == b's' && unit_end(i + 2)) || (&w[1..] == b"ms" && unit_end(i + 3)))
            && (i == 0 || !b[i - 1].is_ascii_alphabetic())
        {
            let near: String =
                String::from_utf8_lossy(&b[i.saturating_sub(20)..(i + 10).min(b.len())])
                    .into_owned();
            return Some(near);
        }
    }
    None
}

/// Shell words ([`common::shell_words`]); a word starting with `#` ends the command.
fn words(command: &str) -> Vec<String> {
    let mut out = common::shell_words(command);
    let end = out
        .iter()
        .position(|w| w.starts_with('#'))
        .unwrap_or(out.len());
    out.truncate(end);
    out
}

/// The README's shell blocks, each as its commands (continued lines joined, comments cut).
fn blocks(readme: &str) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    let mut block: Option<Vec<String>> = None;
    let mut pending = String::new();
    for line in readme.lines() {
        let t = line.trim_start();
        match (&mut block, t) {
            (None, "```sh") => block = Some(Vec::new()),
            (Some(_), "```") => out.extend(block.take()),
            (Some(b), _) => {
                pending.push_str(t);
                if let Some(head) = pending.strip_suffix('\\') {
                    pending = format!("{head} ");
                    continue;
                }
                let cmd = std::mem::take(&mut pending);
                if !cmd.trim().is_empty() {
                    b.push(cmd);
                }
            }
            _ => {}
        }
    }
    out
}

/// A server a block started; killed when the block ends.
struct Server(Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn server(args: &[String], lines: usize, cwd: &Path) -> (Server, Vec<String>) {
    let (child, printed) = common::spawn_odocal_server(args, lines, Some(cwd));
    (Server(child), printed)
}

/// What one run printed.
struct Ran {
    ok: bool,
    interrupted: bool,
    out: String,
    err: String,
}

/// Runs odocal with `args` in `cwd`, answering every prompt "y"; with `interrupt_after`, sends
/// SIGINT then (a command that runs until Ctrl-C).
fn run(args: &[String], cwd: &Path, interrupt_after: Option<Duration>) -> Ran {
    let mut child = Command::new(env!("CARGO_BIN_EXE_odocal"))
        .args(args)
        .current_dir(cwd)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("odocal runs");
    if let Some(mut stdin) = child.stdin.take() {
        let _ = stdin.write_all("y\n".repeat(20).as_bytes());
    }
    let mut interrupted = false;
    if let Some(after) = interrupt_after {
        std::thread::sleep(after);
        let sent = Command::new("kill")
            .args(["-INT", &child.id().to_string()])
            .status()
            .is_ok_and(|s| s.success());
        assert!(sent, "kill -INT {}", child.id());
        interrupted = true;
    }
    let out = child.wait_with_output().expect("odocal ends");
    Ran {
        ok: out.status.success(),
        interrupted,
        out: String::from_utf8_lossy(&out.stdout).into_owned(),
        err: String::from_utf8_lossy(&out.stderr).into_owned(),
    }
}

/// Replaces each word's hardware with what stands for it.
fn substitute(words: &[String], map: &[(String, String)]) -> Vec<String> {
    words
        .iter()
        .map(|w| {
            let mut w = w.clone();
            for (from, to) in map {
                w = w.replace(from.as_str(), to);
            }
            w
        })
        .collect()
}

#[test]
fn every_command_in_the_readme_runs_on_the_mocks() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let readme = std::fs::read_to_string(root.join("README.md")).unwrap();
    let work = common::scratch("readme-commands");
    std::fs::create_dir_all(work.join("config")).unwrap();
    // What the README's placeholders name: a controller YAML and a profile of one robot.
    std::fs::copy(
        root.join("examples/diff_drive.yaml"),
        work.join("config/diff_drive.yaml"),
    )
    .unwrap();
    std::fs::copy(
        root.join("examples/diff_drive.yaml"),
        work.join("diff_drive.yaml"),
    )
    .unwrap();
    std::fs::copy(root.join("examples/robot.toml"), work.join("robot.toml")).unwrap();
    let started = Instant::now();
    // Blocks are independent (each its own files and servers): they run side by side, as a
    // reader's terminals would, and their reports are joined in the README's order.
    let reports: Vec<Report> = std::thread::scope(|scope| {
        let handles: Vec<_> = blocks(&readme)
            .into_iter()
            .map(|block| scope.spawn(|| run_block(block, root, &work)))
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("a block's thread ends"))
            .collect()
    });
    let (mut ran, mut skipped, mut failures) = (Vec::new(), Vec::new(), Vec::new());
    for r in reports {
        ran.extend(r.ran);
        skipped.extend(r.skipped);
        failures.extend(r.failures);
    }
    eprintln!(
        "ran {} command(s) in {:.0} s; skipped {}:\n  {}",
        ran.len(),
        started.elapsed().as_secs_f64(),
        skipped.len(),
        skipped.join("\n  ")
    );
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
    // The commands this test exists for were found and run.
    for must in [
        "odocal calibrate --base rosbridge://127.0.0.1:9090",
        "odocal calibrate --base roboclaw:/dev/pts/N",
        "odocal export --from bag.json",
        "odocal track --log drive.jsonl",
        "odocal params get --port /dev/ttyUSB0",
    ] {
        assert!(
            ran.iter().any(|l| l.starts_with(must)),
            "`{must}…` not run: {ran:#?}"
        );
    }
    // What they wrote: the try-it runs' new geometry, the bag's multipliers.
    let yaml = std::fs::read_to_string(work.join("my_diff_drive.yaml")).unwrap();
    let example = std::fs::read_to_string(root.join("examples/diff_drive.yaml")).unwrap();
    assert_ne!(yaml, example, "the ROS try-it run wrote its multipliers");
    let toml = std::fs::read_to_string(work.join("my_robot.toml")).unwrap();
    let profile = std::fs::read_to_string(root.join("examples/robot.toml")).unwrap();
    assert_ne!(toml, profile, "the RoboClaw try-it run wrote its geometry");
    let exported = std::fs::read_to_string(work.join("config/diff_drive.yaml")).unwrap();
    assert_ne!(exported, example, "export wrote the bag's multipliers");
}

/// What one block's commands did.
#[derive(Default)]
struct Report {
    ran: Vec<String>,
    skipped: Vec<String>,
    failures: Vec<String>,
}

/// Runs one README block's commands in order in `work`, with the servers it starts or needs.
fn run_block(block: Vec<String>, root: &Path, work: &Path) -> Report {
    let Report {
        mut ran,
        mut skipped,
        mut failures,
    } = Report::default();
    // Servers this block started, and what their addresses replace.
    let mut servers: Vec<Server> = Vec::new();
    let mut map: Vec<(String, String)> = Vec::new();
    for command in block {
        let w = words(&command);
        let line = w.join(" ");
        if let Some((_, why)) = SKIPPED
            .iter()
            .find(|(p, _)| command.starts_with(p) || line.starts_with(p.replace('\'', "").as_str()))
        {
            skipped.push(format!("{line}: {why}"));
            continue;
        }
        match w.first().map(String::as_str) {
            Some("cp") => {
                std::fs::copy(root.join(&w[1]), work.join(&w[2])).unwrap();
                ran.push(line);
                continue;
            }
            Some("odocal") => {}
            _ => {
                failures.push(format!("`{line}`: not placed (run it or say why not)"));
                continue;
            }
        }
        let mut args: Vec<String> = w[1..].to_vec();
        // A redirect: the output goes to that file in the work directory (or nowhere).
        let mut redirect = None;
        if let Some(i) = args.iter().position(|a| a == ">") {
            redirect = args.get(i + 1).cloned();
            args.truncate(i);
        }
        // Paths in the user's home go to the work directory.
        for a in args.iter_mut() {
            if a.starts_with("~/") {
                *a = work.join("home").join(&a[2..]).display().to_string();
            }
        }
        match args[0].as_str() {
            "mock-device" | "mock-rosbridge" | "mock-roboclaw" => {
                // A loopback port of the system's choosing: 9090 may be taken.
                if let Some(i) = args.iter().position(|a| a == "--tcp-port") {
                    args[i + 1] = "0".into();
                }
                let lines = if args[0] == "mock-roboclaw" { 2 } else { 1 };
                let (s, printed) = server(&args, lines, work);
                servers.push(s);
                match args[0].as_str() {
                    "mock-rosbridge" => {
                        map.push(("rosbridge://127.0.0.1:9090".into(), printed[0].clone()))
                    }
                    "mock-roboclaw" => {
                        map.push(("roboclaw:/dev/pts/N".into(), printed[0].clone()));
                        map.push(("nmea:/dev/pts/M".into(), printed[1].clone()));
                    }
                    _ => map.push(("/dev/pts/N".into(), printed[0].clone())),
                }
                ran.push(line);
                continue;
            }
            _ => {}
        }
        let joined = args.join(" ");
        // Hardware the command names that no server of the block stands for yet.
        if joined.contains("roboclaw:/dev/ttyACM0") || joined.contains("nmea:/dev/ttyUSB0") {
            if !map.iter().any(|(f, _)| f == "/dev/ttyACM0") {
                let (s, printed) = server(
                    &[
                        "mock-roboclaw".into(),
                        "--profile".into(),
                        "robot.toml".into(),
                        "--time-scale".into(),
                        "20".into(),
                    ],
                    2,
                    work,
                );
                servers.push(s);
                let path = |p: &str, scheme: &str| p.trim_start_matches(scheme).to_string();
                map.push(("/dev/ttyACM0".into(), path(&printed[0], "roboclaw:")));
                map.push(("nmea:/dev/ttyUSB0".into(), printed[1].clone()));
            }
        } else if joined.contains("/dev/ttyUSB0") && !map.iter().any(|(f, _)| f == "/dev/ttyUSB0") {
            // Recording and tracking read a clock that runs; the rest suits virtual time.
            let live = matches!(args[0].as_str(), "record" | "track");
            let mut a = vec!["mock-device".to_string()];
            if live {
                a.extend(["--time-scale".into(), "5".into()]);
            }
            let (s, printed) = server(&a, 1, work);
            servers.push(s);
            map.push(("/dev/ttyUSB0".into(), printed[0].clone()));
        }
        if joined.contains("rosbridge://ROBOT:9090")
            && !map.iter().any(|(f, _)| f == "rosbridge://ROBOT:9090")
        {
            let yaml = args
                .iter()
                .position(|a| a == "--ros-yaml")
                .map(|i| args[i + 1].clone())
                .expect("a rosbridge command names its YAML");
            let (s, printed) = server(
                &[
                    "mock-rosbridge".into(),
                    "--ros-yaml".into(),
                    yaml,
                    "--tcp-port".into(),
                    "0".into(),
                    "--time-scale".into(),
                    "20".into(),
                ],
                1,
                work,
            );
            servers.push(s);
            map.push(("rosbridge://ROBOT:9090".into(), printed[0].clone()));
        }
        if let Some(bag) = args.iter().find(|a| a.starts_with("rosbag2_")).cloned() {
            // A rosbag2 directory as `ros2 bag record` leaves it (one MCAP file here; the
            // robot of examples/diff_drive.yaml).
            if !work.join(&bag).exists() {
                std::fs::create_dir_all(work.join(&bag)).unwrap();
                let made = run(
                    &[
                        "simulate".into(),
                        "--write-bag".into(),
                        format!("{bag}/{bag}_0.mcap"),
                        "--runs".into(),
                        "2".into(),
                        "--side-m".into(),
                        "2".into(),
                    ],
                    work,
                    None,
                );
                assert!(made.ok, "{}", made.err);
            }
        }
        let args = substitute(&args, &map);
        // Commands that run until Ctrl-C.
        let until_ctrl_c = match args[0].as_str() {
            "record" | "track" => {
                args.iter().any(|a| a == "--port" || a == "--base")
                    && !args.iter().any(|a| a == "--duration-s" || a == "--drive")
            }
            _ => false,
        };
        let r = run(&args, work, until_ctrl_c.then(|| Duration::from_secs(4)));
        if let Some(file) = &redirect {
            if !file.starts_with('~') {
                std::fs::write(work.join(file), &r.out).unwrap();
            }
        }
        let all = format!("{}\n{}", r.out, r.err);
        if r.interrupted {
            // Stopped, it says so, and ends as it should: with what it has, or (the mock
            // robot stood still: nobody drove it) with the error that says to drive.
            let still = all.contains("too little data") && all.contains("drive at least");
            if !all.contains("stopped by Ctrl-C") || !(r.ok || still) {
                failures.push(format!(
                    "`{line}` (Ctrl-C after 4 s) did not end as a stop should:\n{all}"
                ));
            }
        } else if !r.ok {
            failures.push(format!("`{line}` failed:\n{all}"));
        }
        // JSON output is data (its quoting is not Debug text); the rest is read by people.
        let human = if args.iter().any(|a| a == "--json") {
            r.err.clone()
        } else {
            all.clone()
        };
        if let Some(d) = debug_text(&human) {
            failures.push(format!("`{line}` printed Rust Debug text ({d}):\n{all}"));
        }
        ran.push(line);
    }
    drop(servers);
    Report {
        ran,
        skipped,
        failures,
    }
}
