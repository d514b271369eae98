//! The rules that keep each concept in one room, checked over the library's source: the
//! odometry turn is written once (`kinematics`), clocks are aligned once
//! (`calibration::recording`), squares are found once (`calibration::segment`), serial ports are
//! opened in one place (`io::serial`); the calibration layer does no I/O, the routine sees only
//! the seam, and no backend knows another. (The protocol crate's `no_std` core is built by CI
//! on its own.)

use std::path::{Path, PathBuf};

/// Every `.rs` file under `src/` with its text, comments dropped (what a rule is about is code,
/// not prose about it).
fn sources() -> Vec<(PathBuf, String)> {
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
    walk(&root.join("src"), &mut files);
    files.sort();
    files
        .into_iter()
        .map(|p| {
            let code: Vec<&str> = Vec::new();
            let text = std::fs::read_to_string(&p).unwrap();
            let mut kept = code;
            for line in text.lines() {
                let trimmed = line.trim_start();
                if trimmed.starts_with("//") {
                    continue;
                }
                kept.push(line.split(" // ").next().unwrap_or(line));
            }
            let rel = p.strip_prefix(root).unwrap().to_path_buf();
            (rel, kept.join("\n"))
        })
        .collect()
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
            &["src/calibration/online.rs", "src/calibration/recording.rs"][..],
        ),
        ("tokio_serial::new(", &["src/io/serial.rs"][..]),
        ("open_native_async", &["src/io/serial.rs"][..]),
    ] {
        let outside: Vec<String> = files_with(&sources, needle)
            .into_iter()
            .filter(|f| !allowed.contains(&f.as_str()))
            .collect();
        assert!(
            outside.is_empty(),
            "`{needle}` belongs in {allowed:?}, found in {outside:?}"
        );
    }
}

#[test]
fn layers_only_use_the_layers_below_them() {
    let sources = sources();
    let rules: [(&str, &[&str]); 7] = [
        // Pure: no I/O, no async, nothing of the seam or above.
        (
            "src/calibration",
            &[
                "tokio",
                "std::fs",
                "crate::base",
                "crate::hal",
                "crate::ros",
                "crate::io",
            ],
        ),
        // The procedure sees the seam only.
        (
            "src/routine",
            &[
                "crate::hal",
                "crate::ros",
                "crate::roboclaw",
                "crate::nmea",
                "crate::mock",
                "crate::spec",
            ],
        ),
        // No backend knows another.
        (
            "src/hal",
            &[
                "crate::ros",
                "crate::roboclaw",
                "crate::nmea",
                "crate::mock",
            ],
        ),
        (
            "src/ros",
            &[
                "crate::hal",
                "crate::roboclaw",
                "crate::nmea",
                "crate::mock",
            ],
        ),
        (
            "src/roboclaw",
            &["crate::hal", "crate::ros", "crate::nmea", "crate::mock"],
        ),
        (
            "src/nmea",
            &["crate::hal", "crate::ros", "crate::roboclaw", "crate::mock"],
        ),
        // The seam knows no backend.
        (
            "src/base",
            &[
                "crate::hal",
                "crate::ros",
                "crate::roboclaw",
                "crate::nmea",
                "crate::mock",
                "crate::spec",
            ],
        ),
    ];
    let mut broken = Vec::new();
    for (dir, forbidden) in rules {
        for (path, code) in sources.iter().filter(|(p, _)| under(p, dir)) {
            for f in forbidden {
                if code.contains(f) {
                    broken.push(format!("{} uses {f}", path.display()));
                }
            }
        }
    }
    assert!(broken.is_empty(), "{}", broken.join("\n"));
}
