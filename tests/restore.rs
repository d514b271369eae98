//! `odocal restore BACKUP`: a backup put back into the store it came from — a controller of
//! our protocol over a PTY, a robot profile, a controller's YAML — through the one write path
//! (a new backup of what is there first, then write, read back, commit, read back). A dry run
//! and a declined prompt write nothing and leave no file behind; a malformed backup, or one of
//! another kind of store, is refused with a clear error; two backups taken in the same second
//! are two files.

mod common;

use common::{odocal, odocal_json, scratch, spawn_mock};
use odocal::base::transaction::{backup_store, read_backup, BackupError, Transaction};
use odocal::base::{same_within, ParamStore};
use odocal::kinematics::WheelParams;
use odocal::roboclaw::profile::ProfileStore;
use odocal::ros::yaml::YamlStore;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The files in `dir`.
fn files(dir: &Path) -> BTreeSet<PathBuf> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect()
}

fn name(path: &Path) -> String {
    path.file_name().unwrap().to_string_lossy().into_owned()
}

/// A readable UTC time at the end of a backup's name (`…2026-11-25T14-03-07Z.json`, or
/// `…Z-2.json` for a second one in the same second), and no epoch milliseconds.
fn assert_utc_name(path: &Path, prefix: &str) {
    let name = name(path);
    assert!(name.starts_with(prefix), "{name} starts with {prefix}");
    let stem = name.strip_suffix(".json").unwrap_or(&name);
    let stem = match stem.rsplit_once('-') {
        Some((head, n)) if n.parse::<u32>().is_ok() && head.ends_with('Z') => head,
        _ => stem,
    };
    let stamp = &stem[stem.len().saturating_sub(20)..];
    let b = stamp.as_bytes();
    assert!(
        b.len() == 20
            && b[4] == b'-'
            && b[10] == b'T'
            && b[13] == b'-'
            && b[19] == b'Z'
            && stamp[..4].parse::<u32>().is_ok_and(|y| y >= 2024),
        "{name}: no readable UTC time at its end"
    );
}

/// A calibration's worth of change: a wider wheelbase and a smaller right wheel.
fn changed(p: &WheelParams) -> WheelParams {
    let mut c = *p;
    c.wheelbase_m *= 1.03;
    c.right_wheel_diameter_m *= 0.99;
    c
}

/// A new scratch directory `name` holding the test robot's profile; returns both.
fn profile_in(name: &str) -> (PathBuf, PathBuf) {
    let dir = scratch(name);
    std::fs::create_dir_all(&dir).unwrap();
    let profile = dir.join("robot.toml");
    std::fs::write(&profile, common::ROBOCLAW_PROFILE).unwrap();
    (dir, profile)
}

type Open = fn(&Path) -> Arc<dyn ParamStore>;

fn open_profile(path: &Path) -> Arc<dyn ParamStore> {
    Arc::new(ProfileStore::open(path).unwrap())
}

fn open_yaml(path: &Path) -> Arc<dyn ParamStore> {
    Arc::new(YamlStore::open(path, "diff_drive_controller").unwrap())
}

/// A file store's round trip: a backup of its original parameters where the caller asks (a
/// run's report directory), then a change through a transaction; `odocal restore` of that
/// backup shows, declines, and puts the whole file back as it was, byte for byte.
async fn file_store_is_restored(test: &str, file_name: &str, text: &str, open: Open) {
    let dir = scratch(test);
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join(file_name);
    std::fs::write(&file, text).unwrap();
    let store = open(&file);
    let resolution = store.resolution();
    let original = store.read().await.unwrap();
    // The backup goes where it is asked to (a run's report directory), named after the file.
    let report = dir.join("report");
    let mut tx = Transaction::begin(store.clone(), &report).await.unwrap();
    let backup = tx.backup_path().unwrap().to_path_buf();
    assert_eq!(backup.parent(), Some(report.as_path()));
    assert_utc_name(&backup, &format!("{file_name}.odocal-backup-"));
    assert_eq!(read_backup(&backup).unwrap().text.as_deref(), Some(text));
    let backup_text = std::fs::read(&backup).unwrap();
    tx.apply(&changed(&original)).await.unwrap();
    drop(tx);
    let b = backup.to_str().unwrap();
    let changed_text = std::fs::read(&file).unwrap();
    let before = files(&dir);

    // A dry run shows old → new and writes nothing, makes nothing.
    let (ok, _, err) = odocal(&["restore", b, "--dry-run"]);
    assert!(ok, "{err}");
    assert!(
        err.contains("wheelbase") && err.contains("dry run"),
        "{err}"
    );
    assert_eq!(std::fs::read(&file).unwrap(), changed_text);
    assert_eq!(files(&dir), before);
    // Declined (stdin is empty): nothing written, no backup, no file left behind.
    let (ok, _, err) = odocal(&["restore", b]);
    assert!(!ok && err.contains("declined"), "{err}");
    assert!(
        err.contains("wheelbase"),
        "the change is shown first: {err}"
    );
    assert_eq!(std::fs::read(&file).unwrap(), changed_text);
    assert_eq!(files(&dir), before);

    // Restored: the file is as it was, byte for byte; what it held is in a new backup beside
    // it, and the first backup is as it was.
    let out = odocal_json(&["restore", b, "--yes", "--json"]);
    assert_eq!(out["written"], true, "{out}");
    assert_eq!(std::fs::read_to_string(&file).unwrap(), text);
    let restored = open(&file).read().await.unwrap();
    assert!(
        same_within(&restored, &original, &resolution),
        "{restored:?} vs {original:?}"
    );
    let second = PathBuf::from(out["backup"].as_str().unwrap());
    assert_eq!(second.parent(), Some(dir.as_path()));
    assert_utc_name(&second, &format!("{file_name}.odocal-backup-"));
    assert_ne!(second, backup);
    let kept = read_backup(&second).unwrap();
    assert!(same_within(&kept.active, &changed(&original), &resolution));
    assert_eq!(std::fs::read(&backup).unwrap(), backup_text);
    let prefix = format!("{file_name}.odocal-backup-");
    for new in files(&dir).difference(&before) {
        assert!(name(new).starts_with(&prefix), "a stray file: {new:?}");
    }
    // Again: the store holds them already, nothing is written or made.
    let now = files(&dir);
    let out = odocal_json(&["restore", b, "--yes", "--json"]);
    assert_eq!(out["written"], false, "{out}");
    assert_eq!(files(&dir), now);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[tokio::test]
async fn a_robot_profile_is_restored_from_its_backup() {
    file_store_is_restored(
        "restore-profile",
        "robot.toml",
        common::ROBOCLAW_PROFILE,
        open_profile,
    )
    .await;
}

#[tokio::test]
async fn a_controller_yaml_is_restored_from_its_backup() {
    file_store_is_restored(
        "restore-yaml",
        "diff_drive.yaml",
        common::DIFF_DRIVE_YAML,
        open_yaml,
    )
    .await;
}

#[test]
fn a_controller_over_a_pty_is_restored_from_its_backup() {
    let dir = scratch("restore-device");
    std::fs::create_dir_all(&dir).unwrap();
    let d = dir.to_str().unwrap();
    let (mut mock, port) = spawn_mock(&[]);
    let get = |source: &str| {
        odocal_json(&[
            "params", "get", "--port", &port, "--source", source, "--json",
        ])["wheelbase_m"]
            .as_f64()
            .unwrap()
    };
    let original = get("active");
    let (ok, _, err) = odocal(&[
        "params",
        "set",
        "--port",
        &port,
        "--wheelbase-m",
        "0.41",
        "--backup-dir",
        d,
    ]);
    assert!(ok, "{err}");
    let before = files(&dir);
    assert_eq!(before.len(), 1, "{before:?}");
    let backup = before.iter().next().unwrap().clone();
    assert!(name(&backup).starts_with("odocal-backup-"), "{backup:?}");
    let b = backup.to_str().unwrap();

    let (ok, _, err) = odocal(&["restore", b, "--dry-run"]);
    assert!(ok && err.contains("dry run"), "{err}");
    assert_eq!(get("active"), 0.41);
    let (ok, _, err) = odocal(&["restore", b]);
    assert!(!ok && err.contains("declined"), "{err}");
    assert_eq!(get("active"), 0.41);
    assert_eq!(files(&dir), before, "declining leaves no file");

    // The port is found in the backup; the device's backup goes beside the one restored.
    let out = odocal_json(&["restore", b, "--yes", "--json"]);
    assert_eq!(out["written"], true, "{out}");
    assert_eq!(get("active"), original);
    assert_eq!(get("stored"), original, "committed");
    let second = PathBuf::from(out["backup"].as_str().unwrap());
    assert_eq!(second.parent(), Some(dir.as_path()));
    assert_eq!(read_backup(&second).unwrap().active.wheelbase_m, 0.41);
    assert_eq!(files(&dir).len(), 2);

    // A backup of another controller is refused, naming the way to force it.
    let mut other = read_backup(&second).unwrap();
    other.store.id = "someone-else-1234".into();
    let foreign = dir.join("foreign.json");
    std::fs::write(&foreign, serde_json::to_string(&other).unwrap()).unwrap();
    let (ok, _, err) = odocal(&["restore", foreign.to_str().unwrap(), "--yes"]);
    assert!(!ok && err.contains("--any-device"), "{err}");
    assert_eq!(get("active"), original);
    drop(mock.stdin.take());
    let _ = mock.wait();
    std::fs::remove_dir_all(&dir).unwrap();
}

#[tokio::test]
async fn malformed_backups_and_backups_of_another_kind_are_refused_clearly() {
    let (dir, profile) = profile_in("restore-refused");
    let yaml = dir.join("diff_drive.yaml");
    std::fs::write(&yaml, common::DIFF_DRIVE_YAML).unwrap();
    let (good, _) = backup_store(open_profile(&profile).as_ref(), &dir)
        .await
        .unwrap();
    let cases: [(&str, String, &str); 4] = [
        (
            "not-json.json",
            "not json at all".into(),
            "is not a backup odocal wrote",
        ),
        (
            "junk.json",
            "{\"active\": 3}".into(),
            "is not a backup odocal wrote",
        ),
        (
            "negative.json",
            std::fs::read_to_string(&good)
                .unwrap()
                .replace("\"wheelbase_m\": 0.39", "\"wheelbase_m\": -0.39"),
            "no robot has",
        ),
        ("missing.json", String::new(), "cannot read the backup"),
    ];
    for (file, text, says) in &cases {
        let path = dir.join(file);
        if !text.is_empty() {
            std::fs::write(&path, text).unwrap();
        }
        let typed = read_backup(&path).unwrap_err();
        assert!(
            matches!(
                (&typed, *file),
                (BackupError::Malformed { .. }, "not-json.json" | "junk.json")
                    | (BackupError::Invalid { .. }, "negative.json")
                    | (BackupError::Read { .. }, "missing.json")
            ),
            "{file}: {typed:?}"
        );
        let (ok, _, err) = odocal(&["restore", path.to_str().unwrap(), "--yes"]);
        assert!(
            !ok && err.contains(file) && err.contains(says),
            "{file}: {err}"
        );
    }
    // A profile's backup offered to a YAML: another kind of store, refused even when forced.
    let yaml_text = std::fs::read(&yaml).unwrap();
    let to = format!("ros-yaml:{}", yaml.display());
    let g = good.to_str().unwrap();
    let (ok, _, err) = odocal(&["restore", g, "--to", &to, "--yes", "--any-device"]);
    assert!(
        !ok && err.contains("robot-profile") && err.contains("ros2-control-yaml"),
        "{err}"
    );
    assert_eq!(std::fs::read(&yaml).unwrap(), yaml_text);
    // A store that is not one.
    let (ok, _, err) = odocal(&["restore", g, "--to", "mock", "--yes"]);
    assert!(!ok && err.contains("not a parameter store"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[tokio::test]
async fn a_second_backup_in_the_same_second_keeps_the_first() {
    let (dir, profile) = profile_in("restore-same-second");
    let store = open_profile(&profile);
    // Taken back to back they almost always share a second; when the clock ticks between
    // them, try again (a few times at most).
    for _ in 0..5 {
        let (first, _) = backup_store(store.as_ref(), &dir).await.unwrap();
        let first_text = std::fs::read(&first).unwrap();
        let (second, _) = backup_store(store.as_ref(), &dir).await.unwrap();
        assert_ne!(first, second);
        assert_eq!(std::fs::read(&first).unwrap(), first_text, "first kept");
        let same_second = name(&first).replace(".json", "-2.json");
        if name(&second) == same_second {
            assert!(read_backup(&second).is_ok());
            std::fs::remove_dir_all(&dir).unwrap();
            return;
        }
        // Another second: the names are freed for the next try.
        std::fs::remove_file(&first).unwrap();
        std::fs::remove_file(&second).unwrap();
    }
    panic!("no two backups landed in the same second in five tries");
}

#[test]
fn two_demo_runs_keep_their_backups_in_their_own_report_directories() {
    let root = scratch("restore-demo-dirs");
    let dir = root.join("report");
    let d = dir.to_str().unwrap();
    for _ in 0..2 {
        let (ok, _, err) = odocal(&["demo", "--report-dir", d, "--seed", "4"]);
        assert!(ok, "{err}");
    }
    for run in [dir.clone(), root.join("report-2")] {
        let backups: Vec<_> = files(&run)
            .into_iter()
            .filter(|f| name(f).starts_with("odocal-backup-"))
            .collect();
        assert_eq!(backups.len(), 1, "{run:?}: {backups:?}");
        assert_utc_name(&backups[0], "odocal-backup-");
        assert!(run.join("report.json").is_file(), "{run:?}");
    }
    assert_eq!(files(&root).len(), 2, "nothing else: {:?}", files(&root));
    std::fs::remove_dir_all(&root).unwrap();
}

/// Copies of a file that earlier versions of odocal made beside it on every write
/// (`robot.toml.odocal-backup-<UTC time>`, no `.json`) restore too: the file is found by the
/// copy's name, its format by reading it, and it goes back whole.
#[tokio::test]
async fn copies_earlier_versions_made_beside_the_file_restore() {
    for (test, file_name, text, open) in [
        (
            "restore-copy-profile",
            "robot.toml",
            common::ROBOCLAW_PROFILE,
            open_profile as Open,
        ),
        (
            "restore-copy-yaml",
            "diff_drive.yaml",
            common::DIFF_DRIVE_YAML,
            open_yaml as Open,
        ),
    ] {
        let dir = scratch(test);
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join(file_name);
        std::fs::write(&file, text).unwrap();
        let copy = dir.join(format!("{file_name}.odocal-backup-2026-11-01T10-00-00Z"));
        std::fs::write(&copy, text).unwrap();
        // A calibration since: new parameters in the file.
        let store = open(&file);
        let original = store.read().await.unwrap();
        let mut tx = Transaction::begin(store, &dir.join("report"))
            .await
            .unwrap();
        tx.apply(&changed(&original)).await.unwrap();
        let calibrated = std::fs::read_to_string(&file).unwrap();
        let c = copy.to_str().unwrap();
        let (ok, _, err) = odocal(&["restore", c, "--dry-run"]);
        assert!(
            ok && err.contains("wheelbase") && err.contains("dry run"),
            "{err}"
        );
        assert_eq!(std::fs::read_to_string(&file).unwrap(), calibrated);
        let out = odocal_json(&["restore", c, "--yes", "--json"]);
        assert_eq!(out["written"], true, "{out}");
        assert_eq!(std::fs::read_to_string(&file).unwrap(), text);
        // What the file held is kept in a backup of today's format beside it.
        let kept = read_backup(Path::new(out["backup"].as_str().unwrap())).unwrap();
        assert_eq!(kept.text.as_deref(), Some(calibrated.as_str()));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

/// A file named like such a copy that reads as neither a profile nor a controller's YAML is
/// refused with both reasons, and the file it names is left alone.
#[test]
fn a_copy_that_reads_as_neither_format_is_refused_and_nothing_changes() {
    let dir = scratch("restore-copy-neither");
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("robot.toml");
    std::fs::write(&file, common::ROBOCLAW_PROFILE).unwrap();
    let copy = dir.join("robot.toml.odocal-backup-2026-11-01T10-00-00Z");
    std::fs::write(&copy, "this: [is not\n a profile = or a controller").unwrap();
    let before = files(&dir);
    for extra in [&["--dry-run"][..], &["--yes"][..]] {
        let mut args = vec!["restore", copy.to_str().unwrap()];
        args.extend(extra);
        let (ok, _, err) = odocal(&args);
        assert!(!ok, "{extra:?}: {err}");
        assert!(
            err.contains("named like a copy odocal made of")
                && err.contains("robot profile")
                && err.contains("controller's YAML"),
            "{err}"
        );
    }
    assert_eq!(
        std::fs::read_to_string(&file).unwrap(),
        common::ROBOCLAW_PROFILE
    );
    assert_eq!(files(&dir), before, "no file made or removed");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A backup edited to hold what no robot has (a 50 m wheelbase, a 1 nm wheel) is refused by
/// the dry run exactly as by the real run, before anything is backed up or written (issue 29).
#[tokio::test]
async fn a_backup_beyond_the_physical_bounds_is_refused_by_the_dry_run_as_by_the_real_run() {
    let (dir, file) = profile_in("restore-unphysical");
    let store = open_profile(&file);
    let tx = Transaction::begin(store, &dir.join("report"))
        .await
        .unwrap();
    let backup = tx.backup_path().unwrap().to_path_buf();
    drop(tx);
    let record: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&backup).unwrap()).unwrap();
    for (field, value, name) in [
        ("wheelbase_m", 50.0, "wheelbase_m"),
        ("left_wheel_diameter_m", 1e-9, "left_wheel_diameter_m"),
    ] {
        let mut edited = record.clone();
        edited["active"][field] = serde_json::json!(value);
        let path = dir.join(format!("edited-{field}.json"));
        std::fs::write(&path, serde_json::to_string_pretty(&edited).unwrap()).unwrap();
        let before = files(&dir);
        let report_before = files(&dir.join("report"));
        for extra in [&["--dry-run"][..], &["--yes"][..]] {
            let mut args = vec!["restore", path.to_str().unwrap()];
            args.extend(extra);
            let (ok, _, err) = odocal(&args);
            assert!(!ok, "{field} {extra:?}: {err}");
            assert!(
                err.contains("no robot has") && err.contains(name),
                "{field} {extra:?}: {err}"
            );
        }
        assert_eq!(files(&dir), before, "{field}: no file made");
        assert_eq!(
            files(&dir.join("report")),
            report_before,
            "{field}: no backup"
        );
        assert_eq!(
            std::fs::read_to_string(&file).unwrap(),
            common::ROBOCLAW_PROFILE
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A dry run makes the store's own write check, as the real run does before its question: a
/// controller YAML whose multiplier became an anchor another line repeats (odocal cannot write
/// it keeping the rest) is refused by both, and the file is left as it is.
#[tokio::test]
async fn a_dry_run_refuses_a_store_the_real_run_cannot_write() {
    let dir = scratch("restore-unwritable-yaml");
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("diff_drive.yaml");
    std::fs::write(&file, common::DIFF_DRIVE_YAML).unwrap();
    let tx = Transaction::begin(open_yaml(&file), &dir.join("report"))
        .await
        .unwrap();
    let backup = tx.backup_path().unwrap().to_path_buf();
    drop(tx);
    let anchored = format!(
        "{}    wheel_separation_multiplier: &m 1.02\n    left_wheel_radius_multiplier: *m\n",
        common::DIFF_DRIVE_YAML
    );
    std::fs::write(&file, &anchored).unwrap();
    let before = files(&dir);
    for extra in ["--dry-run", "--yes"] {
        let (ok, _, err) = odocal(&["restore", backup.to_str().unwrap(), extra]);
        assert!(!ok, "{extra}: {err}");
        assert!(err.contains("anchor"), "{extra}: {err}");
    }
    assert_eq!(std::fs::read_to_string(&file).unwrap(), anchored);
    assert_eq!(files(&dir), before, "no file made");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[tokio::test(flavor = "multi_thread")]
async fn a_backup_edited_to_name_another_robots_file_is_refused_and_never_pours_its_text_there() {
    let dir = scratch("restore-other-file");
    let (a, b) = (dir.join("a"), dir.join("b"));
    std::fs::create_dir_all(&a).unwrap();
    std::fs::create_dir_all(&b).unwrap();
    let file_a = a.join("diff_drive.yaml");
    let file_b = b.join("diff_drive.yaml");
    std::fs::write(&file_a, common::DIFF_DRIVE_YAML).unwrap();
    // Robot B's file: another robot's settings beside the same controller.
    let text_b = format!(
        "# robot B\n{}",
        common::DIFF_DRIVE_YAML.replace("0.39", "0.52")
    );
    std::fs::write(&file_b, &text_b).unwrap();
    let (backup, _) = backup_store(open_yaml(&file_a).as_ref(), &a).await.unwrap();
    // The backup's `file` edited to name robot B's file.
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&backup).unwrap()).unwrap();
    json["file"] = serde_json::json!(file_b);
    std::fs::write(&backup, json.to_string()).unwrap();
    let backup_s = backup.to_str().unwrap();
    for extra in ["--dry-run", "--yes"] {
        let (ok, _, err) = odocal(&["restore", backup_s, extra]);
        assert!(!ok, "{extra}: {err}");
        assert!(err.contains("another robot's file?"), "{extra}: {err}");
    }
    assert_eq!(std::fs::read_to_string(&file_b).unwrap(), text_b);
    // Allowed by the user: B's parameters only, never A's whole text.
    let to = format!(
        "ros-yaml:{}?controller=diff_drive_controller",
        file_b.display()
    );
    for args in [
        vec!["restore", backup_s, "--yes", "--any-device"],
        vec!["restore", backup_s, "--yes", "--to", to.as_str()],
    ] {
        let (ok, _, err) = odocal(&args);
        assert!(ok, "{args:?}: {err}");
        assert!(err.contains("its parameters only"), "{args:?}: {err}");
        let now = std::fs::read_to_string(&file_b).unwrap();
        assert!(
            now.starts_with("# robot B\n") && now.contains("0.52"),
            "{args:?}: {now}"
        );
    }
    // Without the file's text (an older backup), where it lies is all it can be judged by.
    let mut bare = json.clone();
    bare.as_object_mut().unwrap().remove("text");
    let bare_path = b.join("old.json");
    std::fs::write(&bare_path, bare.to_string()).unwrap();
    let (ok, _, err) = odocal(&["restore", bare_path.to_str().unwrap(), "--yes"]);
    assert!(!ok && err.contains("holds no text of the file"), "{err}");
    // Beside its own file, it restores the whole file as before.
    json["file"] = serde_json::json!(file_a);
    std::fs::write(&backup, json.to_string()).unwrap();
    let (ok, _, err) = odocal(&["restore", backup_s, "--yes"]);
    assert!(ok, "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A store on a full disk: it reads and stages as the file store under it does, and its commit
/// (where a file store writes its file) fails as a full disk fails a write.
struct FullDisk(Arc<dyn ParamStore>);

#[async_trait::async_trait]
impl ParamStore for FullDisk {
    fn info(&self) -> odocal::base::ComponentInfo {
        self.0.info()
    }
    async fn read(&self) -> Result<WheelParams, odocal::base::BaseError> {
        self.0.read().await
    }
    async fn write(&self, params: &WheelParams) -> Result<WheelParams, odocal::base::BaseError> {
        self.0.write(params).await
    }
    async fn commit(&self) -> Result<(), odocal::base::BaseError> {
        Err(odocal::base::BaseError::Backend {
            component: "store".into(),
            source: Box::new(std::io::Error::from(std::io::ErrorKind::StorageFull)),
        })
    }
    async fn read_committed(&self) -> Result<Option<WheelParams>, odocal::base::BaseError> {
        self.0.read_committed().await
    }
    fn resolution(&self) -> WheelParams {
        self.0.resolution()
    }
    fn file(&self) -> Option<PathBuf> {
        self.0.file()
    }
    fn written_keys(&self) -> &'static [&'static str] {
        self.0.written_keys()
    }
}

/// A write that fails on a full disk: the transaction reports it, the rollback cannot write
/// either and says what the store holds (its original: nothing was written), the file is as
/// it was byte for byte, and the backup taken first restores it.
#[tokio::test]
async fn a_store_on_a_full_disk_fails_its_write_and_keeps_the_file_and_its_backup() {
    let dir = scratch("restore-full-disk-store");
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("diff_drive.yaml");
    std::fs::write(&file, common::DIFF_DRIVE_YAML).unwrap();
    let store: Arc<dyn ParamStore> = Arc::new(FullDisk(open_yaml(&file)));
    let original = store.read().await.unwrap();
    let mut tx = Transaction::begin(store.clone(), &dir.join("report"))
        .await
        .unwrap();
    let backup = tx.backup_path().unwrap().to_path_buf();
    let err = tx.apply(&changed(&original)).await.unwrap_err().to_string();
    assert!(err.contains("no storage space"), "{err}");
    assert!(tx.written());
    let (_, committed) = tx.what_the_store_holds().await;
    assert!(
        matches!(committed, odocal::base::transaction::Holds::Original),
        "{committed}"
    );
    // Putting the original back needs a write too: it fails the same way, and says so.
    let err = tx.rollback().await.unwrap_err().to_string();
    assert!(err.contains("no storage space"), "{err}");
    drop(tx);
    assert_eq!(
        std::fs::read_to_string(&file).unwrap(),
        common::DIFF_DRIVE_YAML
    );
    assert!(same_within(
        &open_yaml(&file).read().await.unwrap(),
        &original,
        &store.resolution()
    ));
    // Only the backup was made, and it holds the file's text.
    assert_eq!(
        files(&dir),
        BTreeSet::from([file.clone(), dir.join("report")])
    );
    assert_eq!(files(&dir.join("report")), BTreeSet::from([backup.clone()]));
    assert_eq!(
        read_backup(&backup).unwrap().text.as_deref(),
        Some(common::DIFF_DRIVE_YAML)
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A controller's YAML in a directory of its own named after `test`, backed up into its
/// `report/` and then changed by a transaction: the directory, the file, the backup.
async fn changed_yaml_with_backup(test: &str) -> (PathBuf, PathBuf, PathBuf) {
    let dir = scratch(test);
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("diff_drive.yaml");
    std::fs::write(&file, common::DIFF_DRIVE_YAML).unwrap();
    let mut tx = Transaction::begin(open_yaml(&file), &dir.join("report"))
        .await
        .unwrap();
    let backup = tx.backup_path().unwrap().to_path_buf();
    let original = open_yaml(&file).read().await.unwrap();
    tx.apply(&changed(&original)).await.unwrap();
    (dir, file, backup)
}

/// `odocal restore` on a disk that takes no more than the file already holds (a process file
/// size limit, as a full disk refuses a write): the backup of what the store holds cannot be
/// written, so nothing is written, no empty or cut-off backup is left, and the error says why.
#[cfg(unix)]
#[tokio::test]
async fn a_backup_a_full_disk_refuses_leaves_no_file_and_writes_nothing() {
    use std::os::unix::process::CommandExt;
    let (dir, file, backup) = changed_yaml_with_backup("restore-full-disk-backup").await;
    let changed_text = std::fs::read(&file).unwrap();
    let before = files(&dir);
    let limit = changed_text.len() as u64;
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_odocal"));
    cmd.args(["restore", backup.to_str().unwrap(), "--yes"]);
    // SAFETY: only async-signal-safe calls between fork and exec.
    unsafe {
        cmd.pre_exec(move || {
            // A write past the limit then fails with EFBIG instead of killing the process.
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            let lim = libc::rlimit {
                rlim_cur: limit,
                rlim_max: limit,
            };
            if libc::setrlimit(libc::RLIMIT_FSIZE, &lim) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let out = cmd.output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(err.contains("backup"), "{err}");
    assert!(err.to_lowercase().contains("too large"), "{err}");
    assert!(err.contains("nothing was changed (free space"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(std::fs::read(&file).unwrap(), changed_text);
    assert_eq!(files(&dir), before, "a backup file left behind");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// SIGTERM or SIGHUP while `restore` waits for its answer: nothing is written, no file is
/// made, and odocal says so and leaves with status 130 (not killed outright, mid-way).
#[cfg(unix)]
#[tokio::test]
async fn a_signal_at_restores_question_leaves_with_nothing_written() {
    use std::io::{BufRead, Read};
    let (dir, file, backup) = changed_yaml_with_backup("restore-signal-question").await;
    let changed_text = std::fs::read(&file).unwrap();
    let before = files(&dir);
    for signal in ["TERM", "HUP"] {
        let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_odocal"))
            .args(["restore", backup.to_str().unwrap()])
            .stdin(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .stdout(std::process::Stdio::null())
            .spawn()
            .unwrap();
        let mut err = std::io::BufReader::new(child.stderr.take().unwrap());
        let mut said = Vec::new();
        // The question ends without a newline: read up to its `[y/N]`.
        while !String::from_utf8_lossy(&said).contains("[y/N]") {
            let mut byte = [0u8; 1];
            if err.read(&mut byte).unwrap() == 0 {
                break;
            }
            said.push(byte[0]);
        }
        let ok = std::process::Command::new("kill")
            .args([&format!("-{signal}"), &child.id().to_string()])
            .status()
            .unwrap()
            .success();
        assert!(ok);
        let mut rest = String::new();
        for line in err.lines() {
            rest.push_str(&line.unwrap());
            rest.push('\n');
        }
        let status = child.wait().unwrap();
        let text = format!("{}{rest}", String::from_utf8_lossy(&said));
        assert_eq!(status.code(), Some(130), "{signal}: {text}");
        assert!(
            text.contains(&format!("SIG{signal}: nothing was written; leaving")),
            "{text}"
        );
        assert_eq!(std::fs::read(&file).unwrap(), changed_text);
        assert_eq!(files(&dir), before, "{signal}: a file made");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
