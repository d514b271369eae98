//! The package as a new user meets it: the declared minimum Rust version covers every locked
//! dependency, and the README's worked examples print what the README shows.

mod common;

use serde_json::Value;
use std::process::Command;

fn version(v: &str) -> (u64, u64, u64) {
    let mut parts = v.split('.').map(|p| p.parse::<u64>().unwrap_or(0));
    (
        parts.next().unwrap_or(0),
        parts.next().unwrap_or(0),
        parts.next().unwrap_or(0),
    )
}

/// `rust-version` once said 1.80 while the locked dependencies needed 1.85: someone on 1.80
/// would have been told the package builds and then seen it fail.
#[test]
fn the_declared_rust_version_covers_every_locked_dependency() {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    // Offline, so only this platform's dependencies (the others' sources were never fetched).
    let rustc = Command::new(std::env::var("RUSTC").unwrap_or_else(|_| "rustc".into()))
        .arg("-vV")
        .output()
        .expect("rustc runs");
    let host = String::from_utf8_lossy(&rustc.stdout)
        .lines()
        .find_map(|l| l.strip_prefix("host: ").map(str::to_string))
        .expect("rustc names its host");
    let out = Command::new(cargo)
        .args(["metadata", "--format-version", "1", "--locked", "--offline"])
        .args(["--filter-platform", &host])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("cargo runs");
    assert!(
        out.status.success(),
        "cargo metadata: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let meta: Value = serde_json::from_slice(&out.stdout).unwrap();
    let packages = meta["packages"].as_array().unwrap();
    let ours = packages
        .iter()
        .find(|p| p["name"] == "odocal")
        .and_then(|p| p["rust_version"].as_str())
        .expect("odocal declares a rust-version");
    let needs_more: Vec<String> = packages
        .iter()
        .filter_map(|p| {
            let theirs = p["rust_version"].as_str()?;
            (version(theirs) > version(ours))
                .then(|| format!("{} {} needs {theirs}", p["name"], p["version"]))
        })
        .collect();
    assert!(
        needs_more.is_empty(),
        "rust-version {ours} is too low: {needs_more:?}"
    );
    // The protocol crate, which firmware links alone, declares its own and it must hold too.
    let protocol = packages
        .iter()
        .find(|p| p["name"] == "odocal-protocol")
        .and_then(|p| p["rust_version"].as_str())
        .expect("odocal-protocol declares a rust-version");
    assert!(version(protocol) <= version(ours));
}

/// The `sh` block that holds `command` and the `text` block after it.
fn worked_example<'a>(readme: &'a str, command: &str) -> &'a str {
    let at = readme
        .find(&format!("```sh\n{command}\n```"))
        .unwrap_or_else(|| panic!("README shows `{command}`"));
    let rest = &readme[at..];
    let start = rest.find("```text\n").expect("followed by its output") + "```text\n".len();
    let len = rest[start..].find("```").expect("closed");
    &rest[start..start + len]
}

/// The simulate table once showed numbers from other flags than the command above it.
#[test]
fn the_readme_simulate_table_is_what_its_command_prints() {
    let readme =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/README.md")).unwrap();
    let command = "odocal simulate --runs 5 --compass-sigma-deg 0.37";
    let shown = worked_example(&readme, command);
    let args: Vec<&str> = command.split_whitespace().skip(1).collect();
    let (ok, stdout, stderr) = common::odocal(&args);
    assert!(ok, "{stderr}");
    let lines = |s: &str| -> Vec<String> { s.lines().map(|l| l.trim_end().to_string()).collect() };
    assert_eq!(
        lines(&stdout),
        lines(shown),
        "README's simulate table is stale"
    );
}

/// README paragraphs outside code blocks.
fn paragraphs(readme: &str) -> Vec<String> {
    let (mut out, mut cur, mut code) = (Vec::new(), Vec::<&str>::new(), false);
    for line in readme.lines() {
        let fence = line.starts_with("```");
        if fence {
            code = !code;
        }
        if fence || code || line.trim().is_empty() {
            if !cur.is_empty() {
                out.push(cur.join("\n"));
                cur.clear();
            }
        } else {
            cur.push(line);
        }
    }
    out.extend((!cur.is_empty()).then(|| cur.join("\n")));
    out
}

/// The README's speed figures were once about 3.5× off on the machine they were claimed for,
/// with nothing to re-measure them by. Speed is not asserted in tests (it lives in benchmarks);
/// what is asserted is that every figure names the command that reproduces it and the machine
/// it came from, so a reader can check it.
#[test]
fn every_speed_figure_in_the_readme_names_its_command_and_machine() {
    let readme =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/README.md")).unwrap();
    // A rate, a latency, or a median time in seconds ("median 0.65–0.67 s").
    let is_figure = |p: &str| {
        ["MiB/s", "frames/s", "per second", "µs"]
            .iter()
            .any(|u| p.contains(u))
            || p.split("median").skip(1).any(|after| {
                let mut words = after.split_whitespace();
                words.next().is_some_and(|n| {
                    n.split('–')
                        .next()
                        .is_some_and(|n| n.parse::<f64>().is_ok())
                }) && words.next().is_some_and(|u| u.starts_with('s'))
            })
    };
    let figures: Vec<String> = paragraphs(&readme)
        .into_iter()
        .map(|p| p.split_whitespace().collect::<Vec<_>>().join(" "))
        .filter(|p| is_figure(p))
        .collect();
    assert!(
        figures.len() >= 5,
        "the README's figures were found: {figures:#?}"
    );
    for p in figures {
        let command = p.contains("cargo run --release --example") || p.contains("cargo bench");
        assert!(
            command && p.contains("machine"),
            "a figure without its command or machine: {p}"
        );
    }
}

/// The README quotes every size bound odocal applies to files (`io::SIZE_BOUNDS`), as it is.
#[test]
fn the_readme_quotes_every_file_size_bound() {
    let readme = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/README.md"))
        .unwrap()
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ");
    for (what, bytes) in odocal::io::SIZE_BOUNDS {
        let shown = if bytes % (1 << 30) == 0 {
            format!("{} GiB", bytes >> 30)
        } else {
            format!("{} MiB", bytes >> 20)
        };
        assert!(
            readme.contains(&shown),
            "the README does not give the bound of {what}: {shown}"
        );
    }
    assert!(readme.contains("io::SIZE_BOUNDS"));
}
