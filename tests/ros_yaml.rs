//! The controller YAML as real robots lay it out (`tests/fixtures/ros2_control/`: the layouts
//! of public ros2_control configurations, in our own text and values): calibrating through the
//! YAML store, through the store the ROS base uses (live, against a mock robot of that
//! layout), and `odocal export --ros2 … --force` write the three multipliers and leave every
//! other byte as it was. Each `expected/` file is its layout with only the multiplier values (and, where
//! they were missing, their lines) written by hand. Files that cannot be kept are refused by
//! both with the reason and the line, and nothing is written.

mod common;

use odocal::base::transaction::Transaction;
use odocal::base::{BaseError, ParamStore};
use odocal::kinematics::WheelParams;
use odocal::mock::rosbridge::{MockRosConfig, MockRosbridge, ParamValue};
use odocal::ros::live::{connect, RosBaseConfig};
use odocal::ros::yaml::{
    merge_multipliers, DiffDriveConfig, Multipliers, YamlError, YamlStore, MULTIPLIER_KEYS,
};
use proptest::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Each layout and the controller to calibrate in it.
const LAYOUTS: [(&str, &str); 12] = [
    // ros2_control_demos diffbot, Humble: the controller also listed under controller_manager.
    ("diffbot_humble.yaml", "diffbot_base_controller"),
    // …and Jazzy/master: `type:` inside the controller's own parameters.
    ("diffbot_jazzy.yaml", "diffbot_base_controller"),
    // TurtleBot 4 / Create 3 simulation: every node under `/**:`.
    ("create3_sim.yaml", "diffdrive_controller"),
    // Husarion ROSbot: `/**/rosbot_base_controller:` keys, nested limits.
    ("rosbot_prefixed.yaml", "rosbot_base_controller"),
    // …the newer `/**:` nesting with two drive controllers and flow mappings.
    ("rosbot_nested.yaml", "differential_drive_controller"),
    // Clearpath Husky, generated: a namespace key above the nodes, dotted keys.
    ("clearpath_generated.yaml", "platform_velocity_controller"),
    // Clearpath Jackal: `/j100_0000/platform_velocity_controller:` as one key, by its full name.
    (
        "clearpath_namespaced.yaml",
        "j100_0000/platform_velocity_controller",
    ),
    // A Nav2 parameter file with many nodes.
    ("nav2_several_nodes.yaml", "diff_cont"),
    // Flow style, two multipliers missing.
    ("flow_style.yaml", "diff_drive_controller"),
    // A directive, several documents, anchors and aliases, a `!!float` tag.
    ("anchors_documents.yaml", "base_controller"),
    // articubot_one: the multipliers commented out.
    ("articubot_missing.yaml", "diff_cont"),
    // TurtleBot 3: two top-level `/**:` keys.
    ("turtlebot3_two_wildcards.yaml", "diff_drive_controller"),
];

/// The multipliers every expected file holds.
const WRITTEN: Multipliers = Multipliers {
    wheel_separation_multiplier: 1.0234,
    left_wheel_radius_multiplier: 0.9987,
    right_wheel_radius_multiplier: 1.0012,
};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/ros2_control")
        .join(name)
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// A fresh copy of fixture `name` in `dir`.
fn copy(dir: &Path, name: &str) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let to = dir.join(name.replace('/', "_"));
    std::fs::copy(fixture(name), &to).unwrap();
    to
}

/// The effective parameters [`WRITTEN`] gives on the file's nominal geometry.
fn calibrated(cfg: &DiffDriveConfig) -> WheelParams {
    WheelParams {
        left_wheel_diameter_m: 2.0 * cfg.wheel_radius_m * WRITTEN.left_wheel_radius_multiplier,
        right_wheel_diameter_m: 2.0 * cfg.wheel_radius_m * WRITTEN.right_wheel_radius_multiplier,
        wheelbase_m: cfg.wheel_separation_m * WRITTEN.wheel_separation_multiplier,
        counts_per_wheel_rev: odocal::ros::yaml::RAD_PER_REV,
    }
}

/// The backups of `file` odocal wrote into `dir` (`<file name>.odocal-backup-….json`), each
/// with the whole file as it was.
fn backups_in(dir: &Path, file: &Path) -> Vec<String> {
    let name = file.file_name().unwrap().to_string_lossy().into_owned();
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut found: Vec<PathBuf> = entries
        .filter_map(|e| e.ok())
        .filter(|e| {
            e.file_name()
                .to_string_lossy()
                .starts_with(&format!("{name}.odocal-backup-"))
        })
        .map(|e| e.path())
        .collect();
    found.sort();
    found
        .iter()
        .map(|b| {
            let record = odocal::base::transaction::read_backup(b).unwrap();
            record.text.expect("a file's backup holds the file")
        })
        .collect()
}

/// The routine's path through `store` on the copy `file` of layout `name`: pre-flight and
/// backup, write, read back, commit, read back; only the multipliers change, the original is
/// kept beside the file.
async fn calibrate_through(store: Arc<dyn ParamStore>, file: &Path, name: &str, controller: &str) {
    let cfg = DiffDriveConfig::load(file, controller).unwrap_or_else(|e| panic!("{e}"));
    let backups = file.parent().unwrap().join("backups");
    let mut tx = Transaction::begin(store.clone(), &backups)
        .await
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    assert_eq!(*tx.original(), cfg.effective(), "{name}");
    // The backup goes where the caller asks (a run's report directory), none beside the file.
    assert_eq!(
        tx.backup_path().and_then(Path::parent),
        Some(backups.as_path())
    );
    tx.apply(&calibrated(&cfg))
        .await
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    assert_eq!(
        read(file),
        read(&fixture(&format!("expected/{name}"))),
        "{name}: only the multipliers change"
    );
    let kept = backups_in(&backups, file);
    assert_eq!(kept.len(), 1, "{name}");
    assert_eq!(kept[0], read(&fixture(name)), "{name}: the original");
    assert!(
        backups_in(file.parent().unwrap(), file).is_empty(),
        "{name}"
    );
    let back = DiffDriveConfig::load(file, controller).unwrap();
    assert_eq!(
        [
            back.separation_multiplier,
            back.left_radius_multiplier,
            back.right_radius_multiplier
        ],
        [1.0234, 0.9987, 1.0012],
        "{name}"
    );
    assert_eq!(
        store.read_committed().await.unwrap(),
        Some(back.effective())
    );
}

#[tokio::test]
async fn every_layout_is_calibrated_through_the_store_changing_only_the_multipliers() {
    let dir = common::scratch("ros-yaml-store");
    for (name, controller) in LAYOUTS {
        let file = copy(&dir, name);
        let store = Arc::new(YamlStore::open(&file, controller).unwrap());
        calibrate_through(store, &file, name, controller).await;
    }
}

/// Each layout through the store the ROS base itself uses (`odocal::ros::live::connect`'s, with
/// `--ros-set-live`), against a mock robot whose controller is the layout's (its name, its
/// namespace, its wheels): the file is written as through the YAML store, and the running
/// controller takes the same multipliers through its `set_parameters`. Nothing moves.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_layout_is_calibrated_through_the_ros_base_store_and_set_live() {
    let dir = common::scratch("ros-yaml-ros-store");
    for (name, controller) in LAYOUTS {
        let file = copy(&dir.join(name.trim_end_matches(".yaml")), name);
        let cfg = DiffDriveConfig::load(&file, controller).unwrap();
        let mock = MockRosConfig::with_ratios(cfg, 1.0, 1.0).unwrap();
        let server = MockRosbridge::spawn(mock, "127.0.0.1:0".parse().unwrap())
            .await
            .unwrap();
        let base = connect(&RosBaseConfig {
            url: server.url(),
            yaml: file.clone(),
            controller: controller.into(),
            set_live: true,
            ..RosBaseConfig::default()
        })
        .await
        .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(base.store.info().details["set_live"], true, "{name}");
        calibrate_through(base.store.clone(), &file, name, controller).await;
        for (key, want) in MULTIPLIER_KEYS.iter().zip([
            WRITTEN.wheel_separation_multiplier,
            WRITTEN.left_wheel_radius_multiplier,
            WRITTEN.right_wheel_radius_multiplier,
        ]) {
            match server.state().parameter(key) {
                Some(ParamValue::Double(d)) => {
                    assert!((d - want).abs() < 1e-9, "{name}: {key} {d}, not {want}")
                }
                other => panic!("{name}: {key} {other:?}"),
            }
        }
        assert_eq!(server.state().counters.commands, 0, "{name}: nothing moved");
    }
}

#[test]
fn export_merges_into_every_layout_changing_only_the_multipliers() {
    let dir = common::scratch("ros-yaml-export");
    for (name, controller) in LAYOUTS {
        let file = copy(&dir, name);
        let cfg = DiffDriveConfig::load(&file, controller).unwrap();
        // A routine report's two parameter sets are all `export` needs of it.
        let report = dir.join(format!("{name}.report.json"));
        let json = serde_json::json!({
            "original_params": cfg.effective(),
            "final_params": calibrated(&cfg),
        });
        std::fs::write(&report, json.to_string()).unwrap();
        let (ok, out, err) = common::odocal(&[
            "export",
            "--from",
            report.to_str().unwrap(),
            "--ros2",
            file.to_str().unwrap(),
            "--controller",
            controller,
            "--force",
        ]);
        assert!(ok, "{name}: {err}");
        assert!(out.contains("merged the routine calibration"), "{out}");
        assert_eq!(
            read(&file),
            read(&fixture(&format!("expected/{name}"))),
            "{name}: only the multipliers change"
        );
        // One backup for the write, beside the file, holding it as it was.
        let kept = backups_in(&dir, &file);
        assert_eq!(kept.len(), 1, "{name}");
        assert_eq!(kept[0], read(&fixture(name)), "{name}");
    }
}

/// The refused files: whether odocal can read them, and what the refusal must say.
const REFUSED: [(&str, bool, &[&str]); 5] = [
    (
        "refused/alias_multiplier.yaml",
        true,
        &[
            "line 9",
            "`wheel_separation_multiplier`",
            "alias `*unity`",
            "line 4",
        ],
    ),
    (
        "refused/controller_twice.yaml",
        false,
        &["parameters in 2 places", "lines 3, 9", "keep one"],
    ),
    (
        "refused/duplicate_multiplier.yaml",
        false,
        &[
            "`wheel_separation_multiplier` is in",
            "twice (lines 5 and 7)",
        ],
    ),
    (
        "refused/block_scalar.yaml",
        false,
        &["line 5", "right_wheel_radius_multiplier", "block scalar"],
    ),
    (
        "refused/int_tag.yaml",
        true,
        &[
            "line 5",
            "left_wheel_radius_multiplier",
            "tagged `tag:yaml.org,2002:int`",
        ],
    ),
];

#[tokio::test]
async fn files_that_cannot_be_kept_are_refused_with_the_reason_and_nothing_is_written() {
    let dir = common::scratch("ros-yaml-refused");
    for (name, reads, says) in REFUSED {
        let file = copy(&dir, name);
        let controller = "diff_drive_controller";
        let says_all = |e: &str| says.iter().all(|s| e.contains(s));
        // Through the store: refused on opening, or by the pre-flight before any backup.
        let refusal = match YamlStore::open(&file, controller) {
            Ok(store) => {
                assert!(reads, "{name} must not read");
                let e = Transaction::begin(Arc::new(store), &dir.join("backups"))
                    .await
                    .err()
                    .unwrap_or_else(|| panic!("{name}: must be refused"));
                assert!(matches!(e, BaseError::Unwritable { .. }), "{name}: {e}");
                e.to_string()
            }
            Err(e) => {
                assert!(!reads, "{name}: {e}");
                e.to_string()
            }
        };
        assert!(says_all(&refusal), "{name}: {refusal}");
        // Through export: the same reason, the file as it was, no copy beside it.
        let report = dir.join("report.json");
        let p = WheelParams::nominal(0.15, 0.39, odocal::ros::yaml::RAD_PER_REV);
        let json = serde_json::json!({ "original_params": p, "final_params": p });
        std::fs::write(&report, json.to_string()).unwrap();
        let (ok, _, err) = common::odocal(&[
            "export",
            "--from",
            report.to_str().unwrap(),
            "--ros2",
            file.to_str().unwrap(),
            "--force",
        ]);
        assert!(!ok && says_all(&err), "{name}: {err}");
        assert_eq!(read(&file), read(&fixture(name)), "{name}: unchanged");
        assert!(
            backups_in(file.parent().unwrap(), &file).is_empty(),
            "{name}"
        );
    }
    assert!(
        !dir.join("backups").exists(),
        "no backup of a store refused before it"
    );
}

#[test]
fn a_wrong_controller_name_lists_the_diff_drive_controllers_the_file_has() {
    for (name, wrong, found) in [
        (
            "nav2_several_nodes.yaml",
            "diff_drive_controller",
            &["diff_cont"][..],
        ),
        // The mecanum controller is not a diff drive.
        (
            "rosbot_nested.yaml",
            "rosbot_base_controller",
            &["differential_drive_controller"][..],
        ),
        (
            "clearpath_namespaced.yaml",
            "j100_0001/platform_velocity_controller",
            &["j100_0000/platform_velocity_controller"][..],
        ),
        (
            "diffbot_humble.yaml",
            "diff_drive_controller",
            &["diffbot_base_controller"][..],
        ),
    ] {
        match DiffDriveConfig::load(&fixture(name), wrong) {
            Err(YamlError::NoController { found: f, .. }) => assert_eq!(f, found, "{name}"),
            other => panic!("{name}: {other:?}"),
        }
    }
    let (ok, _, err) = common::odocal(&[
        "export",
        "--from",
        "/nonexistent",
        "--ros2",
        fixture("nav2_several_nodes.yaml").to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("cannot read /nonexistent"), "{err}");
    // The same list reaches the command line (`calibrate` and `bag` read the YAML this way).
    let (ok, _, err) = common::odocal(&[
        "mock-rosbridge",
        "--ros-yaml",
        fixture("nav2_several_nodes.yaml").to_str().unwrap(),
        "--port",
        "0",
    ]);
    assert!(
        !ok && err.contains("the diff-drive controllers in it: diff_cont"),
        "{err}"
    );
}

/// A mutation of a layout: a character inserted, or a range deleted.
#[derive(Debug, Clone)]
enum Mutation {
    Insert(usize, char),
    Delete(usize, usize),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    let chars = prop::sample::select(vec![
        ' ', '\n', '\t', ':', '-', '#', '&', '*', '!', '{', '}', '[', ']', ',', '\'', '"', '|',
        '>', '?', '%', 'é', '0', '.', '\r',
    ]);
    prop_oneof![
        (any::<usize>(), chars).prop_map(|(at, c)| Mutation::Insert(at, c)),
        (any::<usize>(), 0usize..40).prop_map(|(at, n)| Mutation::Delete(at, n)),
    ]
}

fn apply(text: &str, mutations: &[Mutation]) -> String {
    let mut chars: Vec<char> = text.chars().collect();
    for m in mutations {
        match *m {
            Mutation::Insert(at, c) => chars.insert(at % (chars.len() + 1), c),
            Mutation::Delete(at, n) => {
                let at = at % (chars.len() + 1);
                chars.drain(at..(at + n).min(chars.len()));
            }
        }
    }
    chars.into_iter().collect()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]

    /// Broken layouts end in a result or a named error, never a panic; a merge that succeeds
    /// reads back with the values written.
    #[test]
    fn mutated_layouts_are_read_and_merged_or_refused_without_panicking(
        layout in 0..LAYOUTS.len(),
        mutations in prop::collection::vec(mutation(), 1..4),
    ) {
        let (name, controller) = LAYOUTS[layout];
        let text = apply(&read(&fixture(name)), &mutations);
        let path = Path::new(name);
        let _ = DiffDriveConfig::parse(&text, controller, path);
        if let Ok(out) = merge_multipliers(&text, controller, &WRITTEN, path) {
            let back = DiffDriveConfig::parse(&out, controller, path).unwrap();
            prop_assert_eq!(back.separation_multiplier, 1.0234);
            prop_assert_eq!(back.left_radius_multiplier, 0.9987);
            prop_assert_eq!(back.right_radius_multiplier, 1.0012);
        }
    }
}
