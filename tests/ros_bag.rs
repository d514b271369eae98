//! `odocal bag` end to end: simulated bags give back the simulated robot, in every container
//! odocal reads as an independent library writes it; a bag converted from a recorded OptiOdom
//! set calibrates as `replay` does on the set; and bad input is named.

mod common;

use common::{odocal, odocal_json, scratch, TRUE_E_B, TRUE_E_D};
use serde_json::Value;
use std::path::{Path, PathBuf};

fn method<'a>(v: &'a Value, name: &str) -> &'a Value {
    v["estimates"]
        .as_array()
        .expect("estimates array")
        .iter()
        .find(|e| e["method"] == name)
        .unwrap_or_else(|| panic!("no {name} estimate in {v}"))
}

/// `odocal simulate --write-bag bag --json` with `extra` flags: a bag of a simulated square
/// test (the simulated robot of `common::TRUE_E_B`, `common::TRUE_E_D`).
fn simulated_bag(bag: &Path, extra: &[&str]) {
    let mut args = vec!["simulate", "--write-bag", bag.to_str().unwrap(), "--json"];
    args.extend(extra);
    odocal_json(&args);
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

#[test]
fn a_simulated_bag_gives_back_the_simulated_parameters() {
    let dir = scratch("bag-sim");
    std::fs::create_dir_all(&dir).unwrap();
    let bag = dir.join("square.mcap");
    let bag_s = bag.to_str().unwrap();
    simulated_bag(
        &bag,
        &["--heading-sigma-deg", "0", "--runs", "2", "--side-m", "2"],
    );
    let v = odocal_json(&["bag", bag_s, "--json"]);
    assert_eq!(v["runs"].as_array().unwrap().len(), 4, "{v}");
    assert_eq!(v["geometry"]["source"], "inferred");
    let exact = method(&v, "exact");
    assert!((f(&exact["e_b"]) - 0.976).abs() < 1e-6, "{exact}");
    assert!((f(&exact["e_d"]) - 0.992).abs() < 1e-6, "{exact}");
    // The multipliers it would write, relative to the nominal wheel radius and separation.
    let m = &exact["multipliers"];
    assert!(
        (f(&m["wheel_separation_multiplier"]) - 0.976).abs() < 1e-6,
        "{m}"
    );
    assert!(
        (f(&m["left_wheel_radius_multiplier"]) - 1.0).abs() < 1e-9,
        "{m}"
    );
    assert!(
        (f(&m["right_wheel_radius_multiplier"]) - 0.992).abs() < 1e-6,
        "{m}"
    );
    for name in ["heading-only", "jung-chung"] {
        let e = method(&v, name);
        assert!(e["e_b"].is_number() && e["e_d"].is_number() && e["multipliers"].is_object());
    }
    // Given the YAML, the geometry comes from it and the multipliers compose with its own.
    let yaml = dir.join("diff_drive.yaml");
    std::fs::write(
        &yaml,
        "diff_drive_controller:\n  ros__parameters:\n    wheel_separation: 0.39\n    \
         wheel_radius: 0.075\n",
    )
    .unwrap();
    let v = odocal_json(&["bag", bag_s, "--ros-yaml", yaml.to_str().unwrap(), "--json"]);
    assert_eq!(v["geometry"]["source"], "yaml");
    assert!((f(&method(&v, "exact")["e_b"]) - 0.976).abs() < 1e-6);
    // A bag is never overwritten.
    let (ok, _, err) = odocal(&["simulate", "--heading-sigma-deg", "0", "--bag", bag_s]);
    assert!(!ok && err.contains("exists"), "{err}");
}

#[test]
fn a_bag_converted_from_a_recorded_set_calibrates_as_replay_does() {
    let Some(root) = common::optiodom("square") else {
        return;
    };
    let set = root.join("square/231220200040");
    let set_s = set.to_str().unwrap();
    let dir = scratch("bag-optiodom");
    std::fs::create_dir_all(&dir).unwrap();
    let bag = dir.join("set.mcap");
    let (ok, _, err) = odocal(&[
        "replay",
        "--dataset",
        set_s,
        "--write-bag",
        bag.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let from_bag = odocal_json(&[
        "bag",
        bag.to_str().unwrap(),
        "--min-rest-s",
        "1.5",
        "--json",
    ]);
    let replayed = odocal_json(&["replay", "--dataset", set_s, "--json"]);
    assert_eq!(from_bag["runs"].as_array().unwrap().len(), 6, "{from_bag}");
    // The bag reads each run's heading as the mean over the rest before and after it, replay
    // as the first and last motion-capture sample: they differ by the capture's jitter at
    // rest, which must stay far inside the run-to-run standard error.
    for name in ["heading-only", "jung-chung", "exact"] {
        let (a, b) = (method(&from_bag, name), method(&replayed, name));
        for (k, se) in [("e_b", "e_b_std_err"), ("e_d", "e_d_std_err")] {
            let diff = (f(&a[k]) - f(&b[k])).abs();
            assert!(
                diff < 0.1 * f(&b[se]),
                "{name} {k}: bag {} vs replay {} (standard error {})",
                a[k],
                b[k],
                b[se]
            );
        }
    }
}

#[test]
fn bags_of_one_robot_pool_as_replay_pools_their_sets() {
    let Some(root) = common::optiodom("square") else {
        return;
    };
    let dir = scratch("bag-pool");
    std::fs::create_dir_all(&dir).unwrap();
    // Two sets of the June robot recorded with different configured wheelbases and diameters.
    let ids = ["230620202042", "230620202258"];
    let mut bags = Vec::new();
    let mut sets = Vec::new();
    for id in ids {
        let set = root.join("square").join(id);
        let bag = dir.join(format!("{id}.mcap"));
        let (ok, _, err) = odocal(&[
            "replay",
            "--dataset",
            set.to_str().unwrap(),
            "--write-bag",
            bag.to_str().unwrap(),
        ]);
        assert!(ok, "{err}");
        bags.push(bag.to_str().unwrap().to_string());
        sets.push(set.to_str().unwrap().to_string());
    }
    let mut args = vec!["bag"];
    args.extend(bags.iter().map(String::as_str));
    // The bags' IMU is the motion capture's heading: said so, the bag chooses as replay does
    // (a bag's IMU of unknown kind gets the method deviation cannot bias, `matched-legs`).
    args.extend([
        "--min-rest-s",
        "1.5",
        "--heading-kind",
        "reference",
        "--json",
    ]);
    let pooled = odocal_json(&args);
    assert_eq!(pooled["bags"].as_array().unwrap().len(), 2, "{pooled}");
    assert_eq!(pooled["default_method"], "legs");
    assert_eq!(
        pooled["uncertainty"], "run-to-run-and-recording-to-recording",
        "{pooled}"
    );
    let replayed = odocal_json(&[
        "replay",
        "--dataset",
        &sets[0],
        "--dataset",
        &sets[1],
        "--json",
    ]);
    assert_eq!(replayed["default_method"], "legs");
    // Both against the first set's configuration, the default method (which reads the same
    // samples along the legs in both) gives the same pooled robot to a tenth of its stated
    // uncertainty. (The at-rest methods differ more: the bag reads the heading at rest as a
    // mean, replay as one sample; the single-set test above bounds that.)
    for name in ["legs"] {
        let (a, b) = (method(&pooled, name), method(&replayed, name));
        for (k, se) in [("e_b", "e_b_std_err"), ("e_d", "e_d_std_err")] {
            let diff = (f(&a[k]) - f(&b[k])).abs();
            assert!(
                diff < 0.1 * f(&b[se]),
                "{name} {k}: bags {} vs replay {} (standard error {})",
                a[k],
                b[k],
                b[se]
            );
        }
    }
    // Pooling is in physical terms: the two sets' own exact E_b differ by their configured
    // wheelbases (0.200 vs 0.205 m) and diameters, the pooled one sits between their physical
    // values, not between the factors.
    let single: Vec<f64> = sets
        .iter()
        .map(|s| f(&method(&odocal_json(&["replay", "--dataset", s, "--json"]), "exact")["e_b"]))
        .collect();
    assert!((single[0] - single[1]).abs() > 0.005, "{single:?}");
    let pooled_eb = f(&method(&replayed, "exact")["e_b"]);
    let physical_second = single[1] * 0.205 / 0.085 * 0.084 / 0.2;
    let (lo, hi) = (
        single[0].min(physical_second) - 1e-3,
        single[0].max(physical_second) + 1e-3,
    );
    assert!(
        (lo..=hi).contains(&pooled_eb),
        "{pooled_eb} not within {lo}..{hi}"
    );
}

#[test]
fn bad_bags_and_files_are_named() {
    let dir = scratch("bag-bad");
    std::fs::create_dir_all(&dir).unwrap();
    let bag = dir.join("s.mcap");
    let bag_s = bag.to_str().unwrap();
    simulated_bag(
        &bag,
        &["--heading-sigma-deg", "0", "--runs", "1", "--side-m", "1"],
    );
    // A topic that is not there, but one of its type is: that one is used, and said so.
    let v = odocal_json(&["bag", bag_s, "--imu-topic", "/imu/data", "--json"]);
    assert_eq!(
        v["notes"][0], "IMU from /imu: the bag has no /imu/data",
        "{v}"
    );
    // No IMU at all: the error lists the topics there are.
    let no_imu = dir.join("no_imu.mcap");
    {
        use odocal::ros::bag::writer::BagWriter;
        let mut w = BagWriter::create(&no_imu, &odocal::ros::bag::RosTopics::default()).unwrap();
        for k in 0..10 {
            let t = f64::from(k) * 0.1;
            w.joints(t, t, t).unwrap();
            w.odom(t, 0.0, 0.0, 0.0).unwrap();
        }
        w.finish().unwrap();
    }
    let (ok, _, err) = odocal(&["bag", no_imu.to_str().unwrap()]);
    assert!(!ok, "must fail");
    assert!(
        err.contains("no IMU topic `/imu`")
            && err.contains("/joint_states (sensor_msgs/msg/JointState)")
            && err.contains("/odom (nav_msgs/msg/Odometry)"),
        "{err}"
    );
    // A topic of another type: the type is named.
    let (ok, _, err) = odocal(&["bag", bag_s, "--imu-topic", "/odom"]);
    assert!(!ok && err.contains("nav_msgs/msg/Odometry"), "{err}");
    // A YAML without the controller: the sections it has are listed.
    let yaml = dir.join("c.yaml");
    std::fs::write(
        &yaml,
        "controller_manager:\n  ros__parameters:\n    update_rate: 50\n",
    )
    .unwrap();
    let (ok, _, err) = odocal(&["bag", bag_s, "--ros-yaml", yaml.to_str().unwrap()]);
    assert!(
        !ok && err.contains("controller_manager") && err.contains("diff_drive_controller"),
        "{err}"
    );
    // Not a bag at all.
    let junk = dir.join("junk.mcap");
    std::fs::write(&junk, b"this is not an mcap file").unwrap();
    let (ok, _, err) = odocal(&["bag", junk.to_str().unwrap()]);
    assert!(!ok && err.contains("not a readable MCAP"), "{err}");
    // Joints that cannot be told apart.
    let (ok, _, err) = odocal(&["bag", bag_s, "--left-joint", "wheel_fl"]);
    assert!(!ok && err.contains("left_wheel_joint"), "{err}");
}

#[test]
fn export_takes_any_result_and_merges_into_the_controller_yaml() {
    let dir = scratch("export-any");
    std::fs::create_dir_all(&dir).unwrap();
    let bag = dir.join("s.mcap");
    simulated_bag(
        &bag,
        &["--heading-sigma-deg", "0", "--runs", "2", "--side-m", "2"],
    );
    let (ok, bag_json, err) = odocal(&["bag", bag.to_str().unwrap(), "--json"]);
    assert!(ok, "{err}");
    let result = dir.join("bag.json");
    std::fs::write(&result, bag_json).unwrap();
    // An existing controller file: only the multipliers change; a backup sits beside it.
    let yaml = dir.join("controllers.yaml");
    let original = "controller_manager:\n  ros__parameters:\n    update_rate: 50\n\n\
diff_drive_controller:\n  ros__parameters:\n    wheel_separation: 0.39  # URDF\n    \
wheel_radius: 0.075\n    publish_rate: 50.0\n";
    std::fs::write(&yaml, original).unwrap();
    // Without --force an existing file is left alone, and the message says how to merge.
    let (ok, _, err) = odocal(&[
        "export",
        "--from",
        result.to_str().unwrap(),
        "--ros2",
        yaml.to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("--force"), "{err}");
    assert_eq!(std::fs::read_to_string(&yaml).unwrap(), original);
    let (ok, out, err) = odocal(&[
        "export",
        "--from",
        result.to_str().unwrap(),
        "--ros2",
        yaml.to_str().unwrap(),
        "--force",
    ]);
    assert!(ok, "{err}");
    // The bag's default method is the leg-aware one (a simulated bag has the IMU along the
    // legs).
    assert!(out.contains("merged") && out.contains("legs"), "{out}");
    let text = std::fs::read_to_string(&yaml).unwrap();
    assert!(
        text.contains("wheel_separation: 0.39  # URDF") && text.contains("update_rate: 50"),
        "{text}"
    );
    let cfg =
        odocal::ros::yaml::DiffDriveConfig::parse(&text, "diff_drive_controller", &yaml).unwrap();
    assert!((cfg.separation_multiplier - 0.976).abs() < 1e-5, "{text}");
    assert!((cfg.right_radius_multiplier - 0.992).abs() < 1e-5, "{text}");
    let backups: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .filter(|p| {
            p.file_name()
                .unwrap()
                .to_string_lossy()
                .starts_with("controllers.yaml.odocal-backup-")
        })
        .collect();
    assert_eq!(backups.len(), 1, "one backup for one write: {backups:?}");
    // The backup export wrote is one `odocal restore` takes: a dry run writes nothing, the
    // real run puts the file back byte for byte.
    let backup = backups[0].to_str().unwrap();
    assert!(out.contains(&format!("odocal restore {backup}")), "{out}");
    let (ok, _, err) = odocal(&["restore", backup, "--dry-run"]);
    assert!(ok && err.contains("dry run"), "{err}");
    assert_eq!(std::fs::read_to_string(&yaml).unwrap(), text);
    let (ok, _, err) = odocal(&["restore", backup, "--yes"]);
    assert!(ok, "{err}");
    assert_eq!(std::fs::read_to_string(&yaml).unwrap(), original);
    // `estimate --json` exports too; into a new file, which is then never replaced silently.
    let est = dir.join("est.json");
    let (ok, est_json, err) = odocal(&[
        "estimate",
        "--side-m",
        "4",
        "--wheelbase-m",
        "0.39",
        "--wheel-diameter-m",
        "0.15",
        "--cw-heading-deg=-26.31,-26.92",
        "--ccw-heading-deg=-11.62,-12.15",
        "--json",
    ]);
    assert!(ok, "{err}");
    std::fs::write(&est, est_json).unwrap();
    let fresh = dir.join("fresh.yaml");
    let (ok, out, err) = odocal(&[
        "export",
        "--from",
        est.to_str().unwrap(),
        "--ros2",
        fresh.to_str().unwrap(),
        "--method",
        "jung-chung",
    ]);
    assert!(ok && out.contains("wrote"), "{out}{err}");
    assert!(std::fs::read_to_string(&fresh)
        .unwrap()
        .contains("wheel_separation_multiplier: 0.976"));
    // A method the result does not have is named with the ones it has.
    let (ok, _, err) = odocal(&[
        "export",
        "--from",
        est.to_str().unwrap(),
        "--ros2",
        fresh.to_str().unwrap(),
        "--method",
        "umbmark",
    ]);
    assert!(
        !ok && err.contains("umbmark") && err.contains("exact"),
        "{err}"
    );
}

#[test]
fn an_absurd_result_is_not_exported() {
    let dir = scratch("export-absurd");
    std::fs::create_dir_all(&dir).unwrap();
    // A result whose estimate would make the wheelbase 10^300 times larger.
    let result = dir.join("absurd.json");
    std::fs::write(
        &result,
        r#"{"configured": {"left_wheel_diameter_m": 0.15, "right_wheel_diameter_m": 0.15,
            "wheelbase_m": 0.39, "counts_per_wheel_rev": 4096.0},
           "estimates": [{"method": "exact", "e_b": 1e300, "e_d": 1.0,
            "correction": {"left_diameter_scale": 1.0, "right_diameter_scale": 1.0,
                           "wheelbase_scale": 1e300}}]}"#,
    )
    .unwrap();
    let yaml = dir.join("out.yaml");
    let (ok, _, err) = odocal(&[
        "export",
        "--from",
        result.to_str().unwrap(),
        "--ros2",
        yaml.to_str().unwrap(),
    ]);
    assert!(!ok, "exported an absurd multiplier");
    assert!(
        err.contains("wheelbase") && (err.contains("not exported") || err.contains("finite")),
        "{err}"
    );
    assert!(!yaml.exists(), "nothing written");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// An IMU 0.3 s late (its readings show the heading 0.3 s ago, stamped now): the offset is
/// found and every method that models the squares exactly gives the simulated robot within
/// three of its standard errors, on three seeds; without noise, within 10 ppm, so nothing of
/// the last turn's tail is lost at a run's end. The paper's small-error approximations
/// (`heading-only`, `jung-chung`) carry their own model error at this size of error (the
/// same without latency), so they are held to what they give on the same robot with an IMU on
/// time: within three standard errors of it (10 ppm without noise).
#[test]
fn a_late_imu_is_found_and_every_method_stays_within_its_errors() {
    let dir = scratch("bag-late");
    std::fs::create_dir_all(&dir).unwrap();
    let analysed = |name: &str, seed: u64, sigma: &str, latency: &str| -> Value {
        let bag = dir.join(format!("{name}-{seed}.mcap"));
        let bag_s = bag.to_str().unwrap();
        let _ = std::fs::remove_file(&bag);
        odocal_json(&[
            "simulate",
            "--bag",
            bag_s,
            "--runs",
            "5",
            "--side-m",
            "2",
            "--heading-latency-s",
            latency,
            "--compass-sigma-deg",
            sigma,
            "--seed",
            &seed.to_string(),
            "--json",
        ]);
        odocal_json(&["bag", bag_s, "--json"])
    };
    for (seed, sigma) in [(1, "0.1"), (2, "0.1"), (3, "0.1"), (4, "0")] {
        let v = analysed("late", seed, sigma, "0.3");
        let on_time = analysed("on-time", seed, sigma, "0");
        for name in ["heading-only", "jung-chung"] {
            let (late, ref_) = (method(&v, name), method(&on_time, name));
            for key in ["e_b", "e_d"] {
                let moved = f(&late[key]) - f(&ref_[key]);
                let bound = if sigma == "0" {
                    1e-5
                } else {
                    3.0 * f(&late[format!("{key}_std_err")])
                };
                assert!(
                    moved.abs() < bound,
                    "seed {seed}: the late IMU moved {name} {key} by {moved:+.2e} (bound {bound:.1e})"
                );
            }
        }
        let offset = f(&v["time_offset"]["offset_s"]);
        assert!((offset - 0.3).abs() < 0.03, "seed {seed}: offset {offset}");
        let mut checked = 0;
        for name in ["exact", "legs", "matched-legs"] {
            let e = method(&v, name);
            for (key, truth) in [("e_b", 0.976), ("e_d", 0.992)] {
                let err = f(&e[key]) - truth;
                if sigma == "0" {
                    assert!(
                        err.abs() < 1e-5,
                        "seed {seed}: {name} {key} off by {err:+.2e}"
                    );
                } else {
                    let se = f(&e[format!("{key}_std_err")]);
                    assert!(
                        err.abs() < 3.0 * se,
                        "seed {seed}: {name} {key} off by {err:+.2e}, standard error {se:.1e}"
                    );
                }
                checked += 1;
            }
        }
        let online = &v["online"];
        for (key, truth) in [("e_b", 0.976), ("e_d", 0.992)] {
            let (err, se) = (f(&online[key]) - truth, f(&online[format!("{key}_std")]));
            assert!(
                err.abs() < 3.0 * se,
                "seed {seed}: online {key} {err:+.2e} ± {se:.1e}"
            );
        }
        assert_eq!(checked, 6);
    }
}

/// The fixture bags: one simulated square test (odocal's, noise-free, 2 Hz) written in every
/// container by the Python libraries `rosbags` and, for MCAP with lz4 chunks, `mcap`
/// (`tests/fixtures/bags/make_bags.py`).
const FIXTURES: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/bags");

/// Fixture `name` (a file or a directory) copied into `dir`, the files the repository keeps
/// packed (`<file>.zst`) unpacked to the file rosbags wrote.
fn fixture(name: &str, dir: &Path) -> PathBuf {
    fn copy(from: &Path, to: &Path) {
        if from.is_dir() {
            std::fs::create_dir_all(to).unwrap();
            for e in std::fs::read_dir(from).unwrap() {
                let e = e.unwrap();
                copy(&e.path(), &to.join(e.file_name()));
            }
        } else {
            std::fs::copy(from, to).unwrap();
        }
    }
    fn unpack(path: &Path) {
        if path.is_dir() {
            for e in std::fs::read_dir(path).unwrap() {
                unpack(&e.unwrap().path());
            }
        } else if let Some(plain) = path.to_str().and_then(|p| p.strip_suffix(".zst")) {
            let bytes = zstd::stream::decode_all(std::fs::File::open(path).unwrap()).unwrap();
            std::fs::write(plain, bytes).unwrap();
            std::fs::remove_file(path).unwrap();
        }
    }
    let root = Path::new(FIXTURES);
    let from = if root.join(name).exists() {
        root.join(name)
    } else {
        root.join(format!("{name}.zst"))
    };
    let to = dir.join(from.file_name().unwrap());
    copy(&from, &to);
    unpack(&to);
    dir.join(name)
}

/// `odocal bag` on `path` with the square side given (only odocal's own MCAP writer records
/// it), which must succeed.
fn bag_json(path: &Path) -> Value {
    odocal_json(&["bag", path.to_str().unwrap(), "--side-m", "1", "--json"])
}

#[test]
fn every_container_written_by_python_libraries_gives_the_same_simulated_robot() {
    let dir = scratch("bag-containers");
    std::fs::create_dir_all(&dir).unwrap();
    let mut cases: Vec<(String, PathBuf)> = [
        "sqlite3_split",
        "mcap_split",
        "square.db3",
        "square.mcap",
        "sqlite3_file_zstd",
        "mcap_message_zstd",
        "square.bag",
        "square_lz4.bag",
        "square_bz2.bag",
        // MCAP storage with `compression: Lz4` chunks (Foxglove's writer), and MCAP storage
        // compressed by rosbag2 as a whole file (`.mcap.zstd`).
        "square_lz4.mcap",
        "mcap_file_zstd",
        // A bag compressed whole by the `lz4` tool.
        "square.mcap.lz4",
    ]
    .iter()
    .map(|name| (name.to_string(), fixture(name, &dir)))
    .collect();
    // Any file zstd-compressed: the repository's packed ROS 1 bag, read as it is.
    cases.push((
        "square.bag.zst".into(),
        Path::new(FIXTURES).join("square.bag.zst"),
    ));
    let mut first: Option<(String, f64, f64)> = None;
    for (name, path) in &cases {
        let v = bag_json(path);
        assert_eq!(v["messages"], 303, "{name}: {v}");
        assert_eq!(v["runs"].as_array().unwrap().len(), 2, "{name}: {v}");
        assert_eq!(v["geometry"]["source"], "inferred", "{name}");
        let exact = method(&v, "exact");
        let (e_b, e_d) = (f(&exact["e_b"]), f(&exact["e_d"]));
        assert!((e_b - TRUE_E_B).abs() < 1e-5, "{name}: E_b {e_b}");
        assert!((e_d - TRUE_E_D).abs() < 1e-5, "{name}: E_d {e_d}");
        match &first {
            None => first = Some((name.clone(), e_b, e_d)),
            Some((other, b, d)) => assert!(
                (e_b - b).abs() < 1e-9 && (e_d - d).abs() < 1e-9,
                "{name} gives E_b {e_b}, E_d {e_d}; {other} gives {b}, {d}"
            ),
        }
    }
    // A directory without metadata.yaml: its bag files in name order, and the notes say so.
    let bare = dir.join("no_metadata");
    std::fs::create_dir_all(&bare).unwrap();
    for i in [1, 0] {
        let name = format!("sqlite3_split_{i}.db3");
        std::fs::copy(dir.join("sqlite3_split").join(&name), bare.join(&name)).unwrap();
    }
    let v = bag_json(&bare);
    assert!(
        v["notes"].as_array().unwrap().iter().any(|n| n
            .as_str()
            .unwrap()
            .contains("no metadata.yaml: read its 2 bag files in name order (sqlite3_split_0.db3, sqlite3_split_1.db3)")),
        "{}",
        v["notes"]
    );
    let (b, d) = first.map(|(_, b, d)| (b, d)).unwrap();
    assert!((f(&method(&v, "exact")["e_b"]) - b).abs() < 1e-9);
    assert!((f(&method(&v, "exact")["e_d"]) - d).abs() < 1e-9);
}

#[test]
fn what_is_not_a_bag_is_named_and_broken_bags_are_errors() {
    let dir = scratch("bag-broken");
    std::fs::create_dir_all(&dir).unwrap();
    let fails = |path: &Path| {
        let (ok, _, err) = odocal(&["bag", path.to_str().unwrap()]);
        assert!(!ok, "{} read", path.display());
        assert!(!err.contains("panicked"), "{err}");
        err
    };
    // A file of no format odocal reads: its first bytes, what they look like, what odocal reads.
    let text = dir.join("notes.txt");
    std::fs::write(&text, "joint states, then the IMU\n").unwrap();
    let err = fails(&text);
    for says in [
        "not a bag odocal reads",
        "\"joint states, th\"",
        "(text)",
        "MCAP",
        "sqlite3 (.db3)",
        "rosbag2 directories",
        "ROS 1 .bag",
        "zstd",
    ] {
        assert!(err.contains(says), "no {says:?} in {err}");
    }
    let gz = dir.join("square.mcap.gz");
    std::fs::write(&gz, [0x1F, 0x8B, 8, 0, 0, 0]).unwrap();
    assert!(fails(&gz).contains("gzip"));
    // A name that promises a format gets its complaint.
    let fake = dir.join("fake.db3");
    std::fs::write(&fake, "not sqlite").unwrap();
    assert!(fails(&fake).contains("not a readable sqlite3 bag"));
    // A directory is read only as a rosbag2 directory.
    let empty = dir.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    assert!(fails(&empty).contains("not a rosbag2 bag"));
    // Cut short: a typed error, not a panic, and no journal left beside the file.
    let db3 = fixture("square.db3", &dir);
    let bytes = std::fs::read(&db3).unwrap();
    let cut = dir.join("cut.db3");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let err = fails(&cut);
    assert!(
        err.contains("not a readable sqlite3 bag") && err.contains("cut short"),
        "{err}"
    );
    let left: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("cut.db3") && n != "cut.db3")
        .collect();
    assert!(left.is_empty(), "{left:?}");
    // Files with lz4 chunks (a ROS 1 bag, an MCAP), cut in half, and with their first LZ4
    // frame saying a version LZ4 does not have.
    let broken = |name: &str| {
        let bytes = std::fs::read(fixture(name, &dir)).unwrap();
        let cut = dir.join(format!("cut_{name}"));
        std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
        let mut flipped = bytes.clone();
        let lz4 = flipped
            .windows(4)
            .position(|w| w == [0x04, 0x22, 0x4D, 0x18])
            .unwrap();
        flipped[lz4 + 4] ^= 0xC0;
        let flipped_path = dir.join(format!("flipped_{name}"));
        std::fs::write(&flipped_path, &flipped).unwrap();
        (fails(&cut), fails(&flipped_path))
    };
    let (cut, flipped) = broken("square_lz4.bag");
    assert!(cut.contains("not a readable ROS 1 bag"), "{cut}");
    assert!(flipped.contains("lz4 chunk at byte"), "{flipped}");
    let (cut, flipped) = broken("square_lz4.mcap");
    assert!(cut.contains("not a readable MCAP bag"), "{cut}");
    assert!(flipped.contains("not a readable MCAP bag"), "{flipped}");
    // A whole-file LZ4 frame cut short.
    let lz4_file = fixture("square.mcap.lz4", &dir);
    let bytes = std::fs::read(&lz4_file).unwrap();
    std::fs::write(&lz4_file, &bytes[..bytes.len() - 100]).unwrap();
    let err = fails(&lz4_file);
    assert!(err.contains("square.mcap.lz4: lz4"), "{err}");
    // A zstd file cut short.
    let zstd = fixture("sqlite3_file_zstd", &dir).join("sqlite3_file_zstd.db3.zstd");
    let bytes = std::fs::read(&zstd).unwrap();
    std::fs::write(&zstd, &bytes[..bytes.len() - 100]).unwrap();
    assert!(fails(&dir.join("sqlite3_file_zstd")).contains("zstd"));
    // metadata.yaml listing a file the directory does not have.
    let split = fixture("sqlite3_split", &dir);
    std::fs::remove_file(split.join("sqlite3_split_1.db3")).unwrap();
    let err = fails(&split);
    assert!(
        err.contains("metadata.yaml") && err.contains("`sqlite3_split_1.db3`"),
        "{err}"
    );
}

/// One rule names the default method wherever the same data is calibrated: a simulated
/// compass robot's bag gets what `calibrate` (here the demo's, on the same simulated compass)
/// chooses, and a bag converted from a motion-capture set gets what `replay` chooses on the
/// set, without being told what its IMU is (odocal writes that into the bags it makes).
#[test]
fn bag_replay_and_calibrate_name_the_same_default_method_for_the_same_data() {
    let dir = scratch("bag-default-method");
    std::fs::create_dir_all(&dir).unwrap();
    let bag = dir.join("compass.mcap");
    let bag_s = bag.to_str().unwrap();
    simulated_bag(&bag, &["--runs", "2", "--side-m", "2"]);
    let from_bag = odocal_json(&["bag", bag_s, "--json"]);
    let report_dir = dir.join("demo-report");
    let demo = odocal_json(&[
        "demo",
        "--json",
        "--report-dir",
        report_dir.to_str().unwrap(),
    ]);
    let chosen = &demo["rounds"][0]["chosen"]["method"];
    assert_eq!(
        chosen, "matched-legs",
        "{}",
        demo["rounds"][0]["chosen_because"]
    );
    assert_eq!(&from_bag["default_method"], chosen, "{from_bag}");
    let (ok, out, err) = odocal(&["bag", bag_s]);
    assert!(ok, "{err}");
    assert!(
        out.contains("IMU yaw: magnetic (the bag's metadata)")
            && out.contains("default method (what calibrate writes): matched-legs, the default"),
        "{out}"
    );

    let Some(root) = common::optiodom("square") else {
        return;
    };
    let set = root.join("square/231220200045");
    let set_s = set.to_str().unwrap();
    let converted = dir.join("set.mcap");
    let (ok, _, err) = odocal(&[
        "replay",
        "--dataset",
        set_s,
        "--write-bag",
        converted.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let replayed = odocal_json(&["replay", "--dataset", set_s, "--json"]);
    let from_bag = odocal_json(&[
        "bag",
        converted.to_str().unwrap(),
        "--min-rest-s",
        "1.5",
        "--json",
    ]);
    assert_eq!(replayed["default_method"], "legs");
    assert_eq!(from_bag["default_method"], replayed["default_method"]);
    // Told otherwise, the user's word counts.
    let told = odocal_json(&[
        "bag",
        converted.to_str().unwrap(),
        "--min-rest-s",
        "1.5",
        "--heading-kind",
        "magnetic",
        "--json",
    ]);
    assert_eq!(told["default_method"], "matched-legs");
}

/// Bags odocal wrote whose metadata name different heading sensors (a compass and a gyro) are
/// pooled as of unknown kind, and the output says why and what settles it.
#[test]
fn bags_whose_metadata_disagree_on_the_imu_are_named_and_taken_as_unknown() {
    let dir = scratch("bag-kinds-disagree");
    std::fs::create_dir_all(&dir).unwrap();
    let (compass, gyro) = (dir.join("compass.mcap"), dir.join("gyro.mcap"));
    simulated_bag(&compass, &["--runs", "2", "--side-m", "2"]);
    simulated_bag(
        &gyro,
        &["--runs", "2", "--side-m", "2", "--heading-sensor", "gyro"],
    );
    let (c, g) = (compass.to_str().unwrap(), gyro.to_str().unwrap());
    let (ok, out, err) = odocal(&["bag", c, g]);
    assert!(ok, "{err}");
    assert!(
        out.contains("IMU yaw: unknown (the bags' metadata disagree: give --heading-kind)"),
        "{out}"
    );
    // Unknown may deviate: the method a deviation cannot bias, as for any unnamed IMU.
    assert_eq!(
        odocal_json(&["bag", c, g, "--json"])["default_method"],
        "matched-legs"
    );
    // Each alone says what it is.
    let (_, out, _) = odocal(&["bag", g]);
    assert!(out.contains("IMU yaw: gyro (the bag's metadata)"), "{out}");
}

/// `odocal bag` on `path`, which must fail (without a panic): its error output.
fn bag_fails(path: &Path) -> String {
    let (ok, _, err) = odocal(&["bag", path.to_str().unwrap(), "--side-m", "1"]);
    assert!(!ok, "{} read", path.display());
    assert!(!err.contains("panicked"), "{err}");
    err
}

/// A copy of a simulated bag written back through odocal's MCAP writer, its messages in time
/// order, after `edit` has had the joint samples (t, left, right).
fn rewritten(
    data: &odocal::ros::bag::BagData,
    path: &Path,
    edit: impl FnOnce(&mut Vec<(f64, f64, f64)>),
) -> PathBuf {
    use odocal::ros::bag::writer::BagWriter;
    let mut joints: Vec<(f64, f64, f64)> = data
        .joints
        .iter()
        .map(|j| (j.t, j.left_rad, j.right_rad))
        .collect();
    edit(&mut joints);
    let mut w = BagWriter::create(path, &Default::default()).unwrap();
    // Merged by time as a recorder writes them; the first message at 1 s.
    let (mut i, mut k, mut o) = (0, 0, 0);
    loop {
        let tj = joints.get(i).map_or(f64::INFINITY, |j| j.0);
        let ti = data.imu.get(k).map_or(f64::INFINITY, |y| y.t);
        let to = data.odom.get(o).map_or(f64::INFINITY, |p| p.t);
        let t = tj.min(ti).min(to);
        if !t.is_finite() {
            break;
        }
        if t == tj {
            let (t, l, r) = joints[i];
            w.joints(1.0 + t, l, r).unwrap();
            i += 1;
        } else if t == ti {
            w.imu(1.0 + t, data.imu[k].yaw_rad.unwrap()).unwrap();
            k += 1;
        } else {
            let p = data.odom[o];
            w.odom(1.0 + t, p.x_m, p.y_m, p.yaw_rad).unwrap();
            o += 1;
        }
    }
    w.finish().unwrap();
    path.to_path_buf()
}

#[test]
fn one_wild_sample_does_not_move_a_result_and_reversed_time_is_refused_in_mcap() {
    let dir = scratch("bag-wild");
    std::fs::create_dir_all(&dir).unwrap();
    let sim = dir.join("sim.mcap");
    simulated_bag(
        &sim,
        &["--heading-sigma-deg", "0", "--runs", "1", "--side-m", "1"],
    );
    let data = odocal::ros::bag::read_bag(&sim, &Default::default()).unwrap();
    let exact = |v: &Value| (f(&method(v, "exact")["e_b"]), f(&method(v, "exact")["e_d"]));
    let clean = bag_json(&rewritten(&data, &dir.join("clean.mcap"), |_| {}));
    let (b, d) = exact(&clean);
    assert!(
        (b - TRUE_E_B).abs() < 1e-4 && (d - TRUE_E_D).abs() < 1e-4,
        "{b} {d}"
    );
    // In the middle of a leg: one joint sample of 1e308 rad, one of a wheel jumping 2.8 rad
    // (which a 50 Hz wheel cannot turn) and back.
    let mid = data.joints.len() / 3;
    for (name, bad) in [("huge", 1e308), ("spike", 2.8)] {
        let path = rewritten(&data, &dir.join(format!("{name}.mcap")), |j| {
            j[mid].1 += bad
        });
        let v = bag_json(&path);
        let (b2, d2) = exact(&v);
        assert!(
            (b2 - b).abs() < 1e-6 && (d2 - d).abs() < 1e-6,
            "{name}: {b2} {d2} vs {b} {d}"
        );
        let notes = v["notes"].to_string();
        assert!(
            notes.contains("/joint_states: 1 of") && notes.contains(&format!("message {mid}")),
            "{name}: {notes}"
        );
    }
    // Written last to first: every sample stamped before the one read before it.
    let back = dir.join("back.mcap");
    {
        use odocal::ros::bag::writer::BagWriter;
        let mut w = BagWriter::create(&back, &Default::default()).unwrap();
        for (j, y) in data.joints.iter().rev().zip(data.imu.iter().rev()) {
            w.joints(1.0 + j.t, j.left_rad, j.right_rad).unwrap();
            w.imu(1.0 + y.t, y.yaw_rad.unwrap()).unwrap();
        }
        w.finish().unwrap();
    }
    let err = bag_fails(&back);
    assert!(err.contains("goes back in time at message 1"), "{err}");
    assert!(err.contains("in the wrong order"), "{err}");
}

/// The records of a ROS 1 bag from `at` on: (start, end, op), until `end`.
fn ros1_records(buf: &[u8], mut at: usize, end: usize) -> Vec<(usize, usize, u8)> {
    let u32_at = |i: usize| u32::from_le_bytes(buf[i..i + 4].try_into().unwrap()) as usize;
    let mut out = Vec::new();
    while at < end {
        let head_len = u32_at(at);
        let head = &buf[at + 4..at + 4 + head_len];
        let mut op = 0;
        let mut h = 0;
        while h < head.len() {
            let len = u32::from_le_bytes(head[h..h + 4].try_into().unwrap()) as usize;
            if let Some(v) = head[h + 4..h + 4 + len].strip_prefix(b"op=") {
                op = v[0];
            }
            h += 4 + len;
        }
        let data_at = at + 4 + head_len;
        let next = data_at + 4 + u32_at(data_at);
        out.push((at, next, op));
        at = next;
    }
    out
}

#[test]
fn reversed_time_is_refused_in_sqlite_ros1_and_rosbag2_directories() {
    let dir = scratch("bag-reversed");
    std::fs::create_dir_all(&dir).unwrap();
    // sqlite3: the recorder's timestamps reversed, so rows come out last message first.
    let db3 = fixture("square.db3", &dir);
    assert!(bag_json(&db3)["estimates"].is_array());
    {
        let db = rusqlite::Connection::open(&db3).unwrap();
        db.execute(
            "UPDATE messages SET timestamp = \
             (SELECT max(timestamp) + min(timestamp) FROM messages) - timestamp",
            [],
        )
        .unwrap();
    }
    let err = bag_fails(&db3);
    assert!(err.contains("goes back in time"), "{err}");
    // ROS 1: the message records of each (uncompressed) chunk in reverse order.
    let bag = fixture("square.bag", &dir);
    let mut bytes = std::fs::read(&bag).unwrap();
    let magic = b"#ROSBAG V2.0\n".len();
    let mut reversed_chunks = 0;
    for (start, end, op) in ros1_records(&bytes.clone(), magic, bytes.len()) {
        if op != 5 {
            continue;
        }
        let head_len = u32::from_le_bytes(bytes[start..start + 4].try_into().unwrap()) as usize;
        let data_at = start + 4 + head_len + 4;
        let inner = ros1_records(&bytes, data_at, end);
        let (messages, others): (Vec<_>, Vec<_>) = inner.iter().partition(|r| r.2 == 2);
        let mut rebuilt = Vec::new();
        for (s, e, _) in others.iter().chain(messages.iter().rev()) {
            rebuilt.extend_from_slice(&bytes[*s..*e]);
        }
        bytes[data_at..end].copy_from_slice(&rebuilt);
        reversed_chunks += 1;
    }
    assert!(reversed_chunks > 0);
    std::fs::write(&bag, &bytes).unwrap();
    let err = bag_fails(&bag);
    assert!(err.contains("goes back in time"), "{err}");
    // rosbag2: split files listed last first, or one file listed twice.
    let split = fixture("sqlite3_split", &dir);
    let meta_path = split.join("metadata.yaml");
    let meta = std::fs::read_to_string(&meta_path).unwrap();
    let (a, b) = ("sqlite3_split_0.db3", "sqlite3_split_1.db3");
    assert!(meta.contains(a) && meta.contains(b));
    for listed in [
        meta.replace(a, "@").replace(b, a).replace('@', b),
        meta.replace(b, a),
    ] {
        std::fs::write(&meta_path, &listed).unwrap();
        let err = bag_fails(&split);
        assert!(err.contains("goes back in time"), "{err}");
    }
}

#[test]
fn export_writes_through_a_link_keeps_crlf_and_an_immutable_file_is_refused_before_writing() {
    let dir = scratch("export-link");
    std::fs::create_dir_all(dir.join("src")).unwrap();
    std::fs::create_dir_all(dir.join("install")).unwrap();
    let bag = dir.join("s.mcap");
    simulated_bag(
        &bag,
        &["--heading-sigma-deg", "0", "--runs", "1", "--side-m", "1"],
    );
    let (ok, bag_json, err) = odocal(&["bag", bag.to_str().unwrap(), "--json"]);
    assert!(ok, "{err}");
    let result = dir.join("bag.json");
    std::fs::write(&result, bag_json).unwrap();
    // The sources' file, with CRLF line endings and no final newline, and the installed link
    // to it that `colcon build --symlink-install` makes.
    let source = dir.join("src/controllers.yaml");
    let original =
        "diff_drive_controller:\r\n  ros__parameters:\r\n    wheel_separation: 0.39\r\n    \
wheel_radius: 0.075\r\n    publish_rate: 50.0";
    std::fs::write(&source, original).unwrap();
    let link = dir.join("install/controllers.yaml");
    std::os::unix::fs::symlink(&source, &link).unwrap();
    let export = || {
        odocal(&[
            "export",
            "--from",
            result.to_str().unwrap(),
            "--ros2",
            link.to_str().unwrap(),
            "--force",
        ])
    };
    let (ok, out, err) = export();
    assert!(ok, "{err}");
    assert!(out.contains("a link: written to"), "{out}");
    assert!(std::fs::symlink_metadata(&link)
        .unwrap()
        .file_type()
        .is_symlink());
    let text = std::fs::read_to_string(&source).unwrap();
    assert!(text.contains("wheel_separation_multiplier"), "{text}");
    assert_eq!(
        text.matches('\n').count(),
        text.matches("\r\n").count(),
        "{text:?}"
    );
    assert!(!text.ends_with('\n'), "{text:?}");
    // The backup restores the sources' file, byte for byte, through the link.
    let backup = out
        .split("odocal restore ")
        .nth(1)
        .unwrap()
        .trim()
        .trim_end_matches(')');
    let (ok, _, err) = odocal(&["restore", backup, "--yes"]);
    assert!(ok, "{err}");
    assert_eq!(std::fs::read_to_string(&source).unwrap(), original);
    assert!(std::fs::symlink_metadata(&link)
        .unwrap()
        .file_type()
        .is_symlink());
    // A file the system forbids changing is refused before anything is written or backed up.
    if std::process::Command::new("chattr")
        .args(["+i", source.to_str().unwrap()])
        .status()
        .is_ok_and(|s| s.success())
    {
        let backups = || std::fs::read_dir(dir.join("install")).unwrap().count();
        let before = backups();
        let (ok, _, err) = export();
        let _ = std::process::Command::new("chattr")
            .args(["-i", source.to_str().unwrap()])
            .status();
        assert!(!ok && err.contains("cannot be replaced"), "{err}");
        assert_eq!(backups(), before, "a backup was taken before the refusal");
        assert_eq!(std::fs::read_to_string(&source).unwrap(), original);
    } else {
        assert!(
            std::env::var_os("CI").is_none(),
            "chattr +i is needed to test an immutable file"
        );
        eprintln!("skipped the immutable file: chattr +i is not allowed here");
    }
}
