//! The rules that keep each concept in one room, checked over the library's source: the
//! odometry turn is written once (`kinematics`), clocks are aligned once
//! (`calibration::recording`), squares are found once (`calibration::segment`), serial ports are
//! opened in one place (`io::serial`); the calibration layer does no I/O, the routine sees only
//! the seam, and no backend knows another. (The protocol crate's `no_std` core is built by CI
//! on its own.)

use std::path::{Path, PathBuf};

/// Every `.rs` file under `src/` with its text, comments and `#[cfg(test)]` modules dropped
/// (what a rule is about is the library's code, not prose about it nor its tests).
fn sources() -> Vec<(PathBuf, String)> {
    sources_under("src")
        .into_iter()
        .map(|(p, code, _)| (p, code))
        .collect()
}

/// Every `.rs` file under `dir` (relative to the crate) with its code as [`sources`] keeps it
/// and the number of its lines outside `#[cfg(test)]` modules (comments counted).
fn sources_under(dir: &str) -> Vec<(PathBuf, String, usize)> {
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(&p, out);
            } else if p.extension().is_some_and(|x| x == "rs") {
                out.push(p);
            }
        }
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    walk(&root.join(dir), &mut files);
    files.sort();
    // Files a `#[cfg(test)] mod NAME;` declares: test code, like a test module's block.
    let mut test_files: Vec<PathBuf> = Vec::new();
    let mut out = Vec::new();
    for p in files {
        let text = std::fs::read_to_string(&p).unwrap();
        let mut kept: Vec<&str> = Vec::new();
        let mut outside = 0;
        // Inside an item under `#[cfg(test)]` (a test module, a test-only function): its brace
        // depth. Test code may use what the library itself must not (the simulator, a
        // transaction to set a scene up).
        let mut in_test: Option<i64> = None;
        // Lines since a `#[cfg(test)]` (it and the attributes after it), while they run.
        let mut cfg_test: Option<usize> = None;
        let mut in_string = false;
        for line in text.lines() {
            let trimmed = line.trim_start();
            outside += usize::from(in_test.is_none());
            // Dropped lines stay as empty ones: line numbers are the file's.
            if trimmed.starts_with("//") {
                kept.push("");
                continue;
            }
            let code = line.split(" // ").next().unwrap_or(line);
            if let Some(depth) = in_test.as_mut() {
                *depth += braces(code, &mut in_string);
                if *depth <= 0 {
                    in_test = None;
                }
                kept.push("");
                continue;
            }
            if let Some(attributes) = cfg_test {
                let item = trimmed.trim_end();
                if item.ends_with('{') || item.ends_with(';') {
                    // The item and the attribute lines above it are test code.
                    outside -= attributes + 1;
                    cfg_test = None;
                    kept.push("");
                    if item.ends_with('{') {
                        let depth = braces(code, &mut in_string);
                        in_test = (depth > 0).then_some(depth);
                    } else if let Some(name) = item
                        .strip_prefix("pub mod ")
                        .or_else(|| item.strip_prefix("mod "))
                        .and_then(|m| m.strip_suffix(';'))
                    {
                        let parent = p.parent().unwrap_or(Path::new("."));
                        let stem = p.file_stem().and_then(|s| s.to_str());
                        let here = if matches!(stem, Some("mod" | "lib" | "main")) {
                            parent.to_path_buf()
                        } else {
                            parent.join(stem.unwrap_or_default())
                        };
                        test_files.push(here.join(format!("{name}.rs")));
                        test_files.push(here.join(name).join("mod.rs"));
                    }
                    continue;
                }
            }
            // (`#[cfg(all(test, feature = "x"))]`: test code of a build with feature x.)
            cfg_test = if trimmed == "#[cfg(test)]" || trimmed.starts_with("#[cfg(all(test, ") {
                Some(1)
            } else {
                cfg_test
                    .filter(|_| trimmed.starts_with("#["))
                    .map(|n| n + 1)
            };
            kept.push(code);
        }
        assert!(
            in_test.is_none(),
            "{}: a #[cfg(test)] item whose end the brace count missed (a brace in a raw \
             string or char literal?): the rules would skip the code after it",
            p.display()
        );
        out.push((p, kept.join("\n"), outside));
    }
    out.into_iter()
        .filter(|(p, _, _)| !test_files.contains(p))
        .map(|(p, code, outside)| {
            let rel = p.strip_prefix(root).unwrap().to_path_buf();
            (rel, code, outside)
        })
        .collect()
}

/// `{` minus `}` in `line` outside string and char literals; `in_string` carries a string
/// literal from one line to the next.
fn braces(line: &str, in_string: &mut bool) -> i64 {
    let chars: Vec<char> = line.chars().collect();
    let mut depth = 0;
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        if *in_string {
            match c {
                '\\' => i += 1,
                '"' => *in_string = false,
                _ => {}
            }
        } else {
            match c {
                '"' => *in_string = true,
                // A char literal (`'{'`, `'\''`), not a lifetime.
                '\'' if chars.get(i + 2) == Some(&'\'') => i += 2,
                '\'' if chars.get(i + 1) == Some(&'\\') => {
                    i += 2;
                    while i < chars.len() && chars[i] != '\'' {
                        i += 1;
                    }
                }
                '{' => depth += 1,
                '}' => depth -= 1,
                _ => {}
            }
        }
        i += 1;
    }
    depth
}

fn under(path: &Path, dir: &str) -> bool {
    path.starts_with(dir)
}

/// The files (relative) whose code contains `needle`.
fn files_with(sources: &[(PathBuf, String)], needle: &str) -> Vec<String> {
    sources
        .iter()
        .filter(|(_, code)| code.contains(needle))
        .map(|(p, _)| p.display().to_string())
        .collect()
}

/// Whether `tight` (a line without white space) holds `(…r…-…l…)`: a parenthesised difference
/// whose first term names a right wheel and whose second a left one.
fn right_minus_left(tight: &str) -> bool {
    // A name of the right wheel: `s_r`, `r…`, `right…`, or a scaled one (`ur*…`, `u_r*…`).
    let scaled = |t: &str, side: char| {
        t.split('*')
            .next()
            .is_some_and(|f| f.len() <= 3 && f.ends_with(side) && f != "0")
    };
    let names_right =
        |t: &str| t.contains("_r") || t.starts_with('r') || t.contains("right") || scaled(t, 'r');
    let names_left =
        |t: &str| t.contains("_l") || t.starts_with('l') || t.contains("left") || scaled(t, 'l');
    tight.match_indices('(').any(|(i, _)| {
        let inner = &tight[i + 1..];
        let Some(end) = inner.find(')') else {
            return false;
        };
        let inner = &inner[..end];
        match inner.split_once('-') {
            Some((a, b)) if !a.is_empty() && !a.contains(['(', ',']) => {
                names_right(a) && names_left(b)
            }
            _ => false,
        }
    })
}

#[test]
fn the_odometry_turn_is_written_once() {
    let sources = sources();
    let mut found = Vec::new();
    for (path, code) in &sources {
        for (i, line) in code.lines().enumerate() {
            let tight: String = line.chars().filter(|c| !c.is_whitespace()).collect();
            // A right wheel's arc minus a left one's, however the arcs are named or scaled
            // (`(ur*s_r-ul*s_l)` in a filter as much as `(s_r-s_l)`).
            let difference = [
                "(right",
                "(sr-sl)",
                "(tr-tl)",
                "(dr-dl)",
                "(wr-wl)",
                "(s_r-s_l)",
            ]
            .iter()
            .any(|p| tight.contains(p) && tight.contains('-'))
                || right_minus_left(&tight);
            let over_wheelbase =
                tight.contains(")/") && (tight.contains("wheelbase") || tight.contains(")/b"));
            if difference && over_wheelbase && !path.ends_with("src/kinematics.rs") {
                found.push(format!("{}:{}: {}", path.display(), i + 1, line.trim()));
            }
        }
    }
    assert!(
        found.is_empty(),
        "the turn (s_R − s_L)/b outside kinematics::Displacement:\n{}",
        found.join("\n")
    );
}

#[test]
fn clocks_are_aligned_and_squares_found_in_one_place_each() {
    let sources = sources();
    for (needle, allowed) in [
        (
            "estimate_time_offset(",
            &[
                "src/calibration/time_offset.rs",
                "src/calibration/recording.rs",
            ][..],
        ),
        (
            "unwrapped_heading_at(",
            &[
                "src/calibration/time_offset.rs",
                "src/calibration/recording.rs",
            ][..],
        ),
        // Legs and turns are split in one place (legs::pieces), for the leg method and for
        // square finding alike.
        ("Phase::Straight", &["src/calibration/legs.rs"][..]),
        (
            "LegSample {",
            &["src/calibration/legs.rs", "src/calibration/recording.rs"][..],
        ),
        (
            "predict_travel(",
            &[
                "src/calibration/online/mod.rs",
                "src/calibration/recording.rs",
            ][..],
        ),
        ("tokio_serial::new(", &["src/io/serial.rs"][..]),
        ("open_native_async", &["src/io/serial.rs"][..]),
        // The serial crate's errors stop at the one place that opens a port: a backend's
        // error holds a std::io::Error in odocal's words.
        ("tokio_serial::Error", &["src/io/serial.rs"][..]),
        ("serialport::Error", &["src/io/serial.rs"][..]),
        (
            "tokio_serial::SerialPort::",
            &["src/io/serial.rs", "src/mock/pty.rs"][..],
        ),
    ] {
        only_in(&sources, needle, allowed, "");
    }
}

/// Protocol clients read and write their byte stream through `io::transport`'s helpers, each
/// with a deadline (a read that is late, a stream that ended and an error told apart): outside
/// `io/transport.rs` no code imports the extension traits that read or write a stream (by
/// name, or through `tokio::io::*` or a `tokio::io::{…, *}` group). The mocks (the far end of a link) are exempt.
#[test]
fn protocol_clients_use_the_transport_and_its_deadlines() {
    let sources = sources();
    for needle in [
        "AsyncReadExt",
        "AsyncWriteExt",
        "AsyncBufReadExt",
        "tokio::io::*",
    ] {
        let outside: Vec<String> = files_with(&sources, needle)
            .into_iter()
            .filter(|f| f != "src/io/transport.rs" && !f.starts_with("src/mock/"))
            .collect();
        assert!(
            outside.is_empty(),
            "`{needle}` belongs in src/io/transport.rs (and the mocks), found in {outside:?}: \
             read and write through io::transport's read_some_by, read_exact_by, write_all_by"
        );
    }
    // A group with a glob (`use tokio::io::{self, *};`) brings them in unnamed too.
    let globbed: Vec<String> = sources
        .iter()
        .filter(|(p, _)| {
            let f = p.display().to_string();
            f != "src/io/transport.rs" && !f.starts_with("src/mock/")
        })
        .flat_map(|(p, code)| {
            code.lines()
                .filter(|l| l.contains("tokio::io::{") && l.contains('*'))
                .map(move |l| format!("{}: {}", p.display(), l.trim()))
        })
        .collect();
    assert!(
        globbed.is_empty(),
        "a glob of tokio::io outside src/io/transport.rs: {globbed:?}"
    );
}

/// A drive, a heading source and a store are each one module plus one line in
/// `src/spec/registry.rs`: only the registry lists the backends, an option that was given is a
/// key (never a substring of the text), and no code outside a backend recognises its text form.
#[test]
fn backends_are_listed_in_the_registry_only() {
    let sources = sources();
    let hint = ": a backend is its module plus one line in src/spec/registry.rs";
    for (needle, allowed) in [
        (
            "&crate::hal::base::DRIVE_BACKEND",
            &["src/spec/registry.rs"][..],
        ),
        (
            "&crate::ros::live::DRIVE_BACKEND",
            &["src/spec/registry.rs"][..],
        ),
        (
            "&crate::roboclaw::DRIVE_BACKEND",
            &["src/spec/registry.rs"][..],
        ),
        (
            "&crate::nmea::HEADING_BACKEND",
            &["src/spec/registry.rs"][..],
        ),
        ("::STORE_BACKEND,", &["src/spec/registry.rs"][..]),
        ("contains(\"baud=\")", &[][..]),
        (
            "starts_with(\"rosbridge://\")",
            &["src/ros/live/mod.rs"][..],
        ),
        ("strip_prefix(\"profile:\")", &[][..]),
        // One rule for a fresh reading of a streaming sensor (base/latest.rs).
        (
            "Option<(Instant, HeadingSample)>",
            &["src/base/latest.rs"][..],
        ),
    ] {
        only_in(&sources, needle, allowed, hint);
    }
}

/// Fails when `needle` is in the code of a file outside `allowed`; `hint` says what to do.
fn only_in(sources: &[(PathBuf, String)], needle: &str, allowed: &[&str], hint: &str) {
    let outside: Vec<String> = files_with(sources, needle)
        .into_iter()
        .filter(|f| !allowed.contains(&f.as_str()))
        .collect();
    assert!(
        outside.is_empty(),
        "`{needle}` belongs in {allowed:?}, found in {outside:?}{hint}"
    );
}

/// Parameters reach a store through the write service alone (`base/write.rs`, over the
/// transaction's mechanism in `base/transaction.rs`): the policy, the bounds, the backup, the
/// read-back and the undo cannot be skipped by a command that writes on its own.
#[test]
fn parameters_are_written_through_the_write_service_only() {
    let sources = sources();
    let service = &["src/base/transaction.rs", "src/base/write.rs"][..];
    for (needle, allowed) in [
        ("Transaction", service),
        ("backup_store(", service),
        (".rollback()", service),
        (".write_in_use(", service),
        (".apply_text(", service),
        ("what_the_store_holds", service),
        ("Rollback", service),
        // A store's own commit, inside its implementation of the seam.
        (
            ".commit()",
            &["src/base/transaction.rs", "src/ros/live/store.rs"][..],
        ),
        ("set_multipliers(", &["src/ros/live/store.rs"][..]),
        // The controller's requests, inside its client and its adapter to the seam.
        (".set_params(", &["src/hal/base.rs"][..]),
        (".save_params(", &["src/hal/base.rs"][..]),
        (".restore_defaults(", &[][..]),
        (".load_params(", &[][..]),
        (
            "Request::SetParams",
            &["src/hal/mod.rs", "src/hal/conformance/wire.rs"][..],
        ),
        ("Request::SaveParams", &["src/hal/mod.rs"][..]),
        ("Request::RestoreDefaults", &["src/hal/mod.rs"][..]),
        ("Request::LoadParams", &["src/hal/mod.rs"][..]),
        (
            "replace_atomically(",
            &[
                "src/io/files.rs",
                "src/io/mod.rs",
                "src/base/file_store.rs",
                "src/base/transaction.rs",
                "src/offline/pose_csv.rs",
            ][..],
        ),
    ] {
        let hint = ": a parameter write goes through odocal::base::write";
        only_in(&sources, needle, allowed, hint);
    }
}

#[test]
fn layers_only_use_the_layers_below_them() {
    let sources = sources();
    // Each room, and the rooms it may not name (test modules are dropped: a test may use the
    // simulator or a mock). Reading down the list is reading up the layers: `all_but(own,
    // extra, allowed)` is every backend and every room above the seam except the room itself
    // and `allowed`, plus `extra`.
    let rules: Vec<(&str, Vec<String>)> = vec![
        // The samples every layer passes along: below everything but the kinematics.
        (
            "src/samples.rs",
            all_but(
                "",
                &["crate::calibration", "crate::base", "crate::sim", "tokio"],
                &[],
            ),
        ),
        // Pure: no I/O, no async, nothing of the seam, a backend, the simulator or above.
        (
            "src/calibration",
            all_but(
                "",
                &["tokio", "std::fs", "crate::base", "crate::io", "crate::sim"],
                &[],
            ),
        ),
        // The simulator is maths over the samples: no seam, no backend, no room above.
        ("src/sim", all_but("", &["crate::base", "tokio"], &[])),
        // The seam knows no backend and no estimator.
        ("src/base", all_but("", &["crate::calibration"], &[])),
        // A client speaks its protocol; only its adapter (hal/base.rs) knows the seam.
        ("src/hal/mod.rs", vec!["crate::base".into()]),
        ("src/hal/link.rs", vec!["crate::base".into()]),
        // No backend knows another, nor a room above.
        ("src/hal", all_but("crate::hal", &[], &[])),
        ("src/ros", all_but("crate::ros", &[], &[])),
        ("src/roboclaw", all_but("crate::roboclaw", &[], &[])),
        ("src/nmea", all_but("crate::nmea", &[], &[])),
        // Recordings and data sets: files in, a Recording out; no backend, no procedure.
        (
            "src/offline",
            all_but("crate::offline", &["crate::protocol"], &[]),
        ),
        // The procedure sees the seam only (and writes its logs).
        (
            "src/routine",
            all_but("crate::routine", &[], &["crate::offline"]),
        ),
        // Reports render what a run returned; they open and write no store.
        (
            "src/report",
            all_but(
                "crate::report",
                &["crate::base::transaction", "crate::base::write", "tokio"],
                &["crate::offline", "crate::routine"],
            ),
        ),
        // The composition root knows every backend, but no peer and no renderer.
        (
            "src/spec",
            strings(&[
                "crate::mock",
                "crate::report",
                "crate::offline",
                "crate::demo",
            ]),
        ),
        // Peers speak bytes: never a host client, nor a room above.
        (
            "src/mock",
            strings(&[
                "crate::hal",
                "crate::routine",
                "crate::report",
                "crate::spec",
                "crate::offline",
                "crate::demo",
            ]),
        ),
    ];
    let mut broken = Vec::new();
    for (dir, forbidden) in &rules {
        for (path, code) in sources.iter().filter(|(p, _)| under(p, dir)) {
            for f in forbidden {
                if code.contains(f.as_str()) {
                    broken.push(format!("{} uses {f}", path.display()));
                }
            }
        }
    }
    assert!(broken.is_empty(), "{}", broken.join("\n"));
}

fn strings(list: &[&str]) -> Vec<String> {
    list.iter().map(|s| s.to_string()).collect()
}

/// Every backend and every room above the seam, but `own` and `allowed`; and `extra`.
fn all_but(own: &str, extra: &[&str], allowed: &[&str]) -> Vec<String> {
    const ROOMS: [&str; 10] = [
        "crate::hal",
        "crate::ros",
        "crate::roboclaw",
        "crate::nmea",
        "crate::mock",
        "crate::offline",
        "crate::routine",
        "crate::report",
        "crate::spec",
        "crate::demo",
    ];
    let mut all: Vec<String> = ROOMS
        .iter()
        .filter(|r| **r != own && !allowed.contains(r))
        .map(|r| r.to_string())
        .collect();
    all.extend(strings(extra));
    all
}

/// Each function in `sources` under `dir` longer than `limit` lines, as `file:line name
/// (lines)`: from its `fn` line to its closing brace (braces counted outside strings and
/// chars; a declaration without a body is skipped).
fn long_functions(sources: &[(PathBuf, String)], dir: &str, limit: usize) -> Vec<String> {
    let mut long = Vec::new();
    for (path, code) in sources.iter().filter(|(p, _)| under(p, dir)) {
        let lines: Vec<&str> = code.lines().collect();
        for (i, line) in lines.iter().enumerate() {
            let Some(name) = fn_name(line) else {
                continue;
            };
            let (mut depth, mut opened, mut in_string) = (0i64, false, false);
            for (j, l) in lines.iter().enumerate().skip(i) {
                depth += braces(l, &mut in_string);
                opened |= l.contains('{');
                if !opened && l.trim_end().ends_with(';') {
                    break;
                }
                if opened && depth <= 0 {
                    if j - i + 1 > limit {
                        long.push(format!(
                            "{}:{} {name} ({} lines)",
                            path.display(),
                            i + 1,
                            j - i + 1
                        ));
                    }
                    break;
                }
            }
        }
    }
    long
}

/// The name of the function a line declares, if it does (`fn NAME` as a word).
fn fn_name(line: &str) -> Option<&str> {
    let at = line.find("fn ")?;
    let before = line[..at].trim_end();
    let declares = before.is_empty()
        || before.ends_with("pub")
        || before.ends_with(')')
        || before.ends_with("async")
        || before.ends_with("const")
        || before.ends_with("unsafe");
    let rest = &line[at + 3..];
    let end = rest.find(|c: char| !(c.is_alphanumeric() || c == '_'))?;
    (declares && end > 0).then(|| &rest[..end])
}

/// The files of the binary and the `crate::FILE` uses between them; a circle between them
/// means two files that cannot be read (or moved) apart.
#[test]
fn the_command_line_files_use_each_other_without_circles() {
    let sources = sources();
    let files: Vec<(String, &String)> = sources
        .iter()
        .filter(|(p, _)| under(p, "src/bin/odocal"))
        .filter_map(|(p, code)| Some((p.file_stem()?.to_str()?.to_string(), code)))
        .collect();
    let names: Vec<&str> = files.iter().map(|(n, _)| n.as_str()).collect();
    let uses = |code: &str| -> Vec<usize> {
        (0..names.len())
            .filter(|&k| code.contains(&format!("crate::{}", names[k])))
            .collect()
    };
    let graph: Vec<Vec<usize>> = files.iter().map(|(_, code)| uses(code)).collect();
    // Depth-first search for a back edge; the circle is the path from the file it returns to.
    fn visit(
        k: usize,
        graph: &[Vec<usize>],
        state: &mut [u8],
        path: &mut Vec<usize>,
    ) -> Option<Vec<usize>> {
        state[k] = 1;
        path.push(k);
        for &n in graph[k].iter().filter(|&&n| n != k) {
            if state[n] == 1 {
                let start = path.iter().position(|&p| p == n).unwrap_or(0);
                return Some([&path[start..], &[n]].concat());
            }
            if state[n] == 0 {
                if let Some(circle) = visit(n, graph, state, path) {
                    return Some(circle);
                }
            }
        }
        path.pop();
        state[k] = 2;
        None
    }
    let mut state = vec![0u8; names.len()];
    for k in 0..names.len() {
        if state[k] != 0 {
            continue;
        }
        if let Some(circle) = visit(k, &graph, &mut state, &mut Vec::new()) {
            let circle: Vec<&str> = circle.iter().map(|&i| names[i]).collect();
            panic!(
                "a circle between the binary's files: {}",
                circle.join(" → ")
            );
        }
    }
}

/// No function of the binary is over 60 lines: a long one decides something the library
/// should (and test).
#[test]
fn the_command_line_functions_are_short() {
    let long = long_functions(&sources(), "src/bin", 60);
    assert!(
        long.is_empty(),
        "functions over 60 lines in src/bin:\n{}",
        long.join("\n")
    );
}

/// The binary parses and prints: what it decides lives in the library, with tests.
#[test]
fn the_command_line_is_thin() {
    let sources = sources();
    // Every line of every file, comments and tests included (`wc -l`).
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let lines: usize = sources
        .iter()
        .filter(|(p, _)| under(p, "src/bin"))
        .map(|(p, _)| std::fs::read_to_string(root.join(p)).map_or(0, |t| t.lines().count()))
        .sum();
    let long = long_functions(&sources, "src/bin", 60);
    assert!(
        lines <= 2500 && long.is_empty(),
        "src/bin: {lines} lines (at most 2 500); functions over 60 lines:\n{}",
        long.join("\n")
    );
}

/// No file of the library or the protocol crate is over 800 lines outside its test module
/// (the message table excepted: one row per message), and no function over 100 lines: a
/// longer one holds more than one concept. An exception is named here with its reason, and an
/// exception no longer needed fails the test too (the lists only shrink).
#[test]
fn files_and_functions_stay_small() {
    const LONG_FILES: &[(&str, &str)] = &[(
        "protocol/src/message.rs",
        "the message table: one row per message of the protocol",
    )];
    // `file function`.
    const LONG_FUNCTIONS: &[(&str, &str)] = &[];
    let mut files = Vec::new();
    let mut functions = Vec::new();
    for dir in ["src", "protocol/src"] {
        let sources = sources_under(dir);
        for (p, _, outside) in &sources {
            if *outside > 800 {
                files.push((p.display().to_string(), *outside));
            }
        }
        let code: Vec<(PathBuf, String)> =
            sources.into_iter().map(|(p, code, _)| (p, code)).collect();
        functions.extend(long_functions(&code, dir, 100));
    }
    let new_files: Vec<String> = files
        .iter()
        .filter(|(f, _)| !LONG_FILES.iter().any(|(e, _)| e == f))
        .map(|(f, n)| format!("{f} ({n} lines outside its tests)"))
        .collect();
    // `long_functions` says `file:line name (n lines)`.
    let named = |f: &str, e: &str| {
        let (file, name) = e.split_once(' ').unwrap_or((e, ""));
        f.starts_with(&format!("{file}:")) && f.contains(&format!(" {name} ("))
    };
    let new_functions: Vec<&String> = functions
        .iter()
        .filter(|f| !LONG_FUNCTIONS.iter().any(|(e, _)| named(f, e)))
        .collect();
    let stale: Vec<&str> = LONG_FILES
        .iter()
        .filter(|(e, _)| !files.iter().any(|(f, _)| f == e))
        .chain(
            LONG_FUNCTIONS
                .iter()
                .filter(|(e, _)| !functions.iter().any(|f| named(f, e))),
        )
        .map(|(e, _)| *e)
        .collect();
    assert!(
        new_files.is_empty() && new_functions.is_empty() && stale.is_empty(),
        "files over 800 lines:\n{}\nfunctions over 100 lines:\n{}\nexceptions no longer \
         needed (take them off the lists):\n{}",
        new_files.join("\n"),
        new_functions
            .iter()
            .map(|f| f.as_str())
            .collect::<Vec<_>>()
            .join("\n"),
        stale.join("\n")
    );
}
