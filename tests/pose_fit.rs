//! Calibration against a pose reference (`odocal fit`): simulated drives with a known truth,
//! the refusals, the conventions named, the OptiOdom free sets cross-validated, and the command
//! line's contract.

mod common;

use odocal::calibration::pose_calibration::{calibrate_from_poses, dead_reckon, PoseCalibration};
use odocal::calibration::pose_fit::{fit_poses, FitConfig, Param, PoseFit};
use odocal::calibration::pose_reference::{Geometry, PoseRecording, ReferenceKind};
use odocal::calibration::CalibrationError;
use odocal::offline::dataset::OptiOdomSet;
use odocal::offline::pose_csv::{write_poses, write_wheels};
use odocal::sim::driving::{simulate_drive, DrivingConfig, DrivingPattern};

const NOMINAL: Geometry = Geometry {
    left_diameter_m: 0.1,
    right_diameter_m: 0.1,
    wheelbase_m: 0.3,
};

fn drive(config: DrivingConfig) -> PoseRecording {
    simulate_drive(&config).expect("simulates").recording
}

fn truth_of(config: &DrivingConfig) -> [(Param, f64); 7] {
    [
        (Param::LeftDiameter, config.truth.left_diameter_m),
        (Param::RightDiameter, config.truth.right_diameter_m),
        (Param::Wheelbase, config.truth.wheelbase_m),
        (Param::SensorX, config.sensor_x_m),
        (Param::SensorY, config.sensor_y_m),
        (Param::SensorYaw, config.sensor_yaw_rad),
        (Param::TimeOffset, config.delay_s),
    ]
}

/// Normal driving under the reference: 10 Hz, 3 mm / 0.3°, 1 % outliers, a lever arm
/// and 60 ms of delay (the simulator's defaults). Accuracy bounds of the issue, and the truth
/// within 3σ of every parameter (the coverage over 200 seeds is the example
/// `pose_fit_coverage`'s).
#[test]
fn normal_driving_under_an_absolute_reference_gives_the_truth_within_its_errors() {
    for seed in 0..4 {
        let config = DrivingConfig {
            seed,
            ..DrivingConfig::default()
        };
        let fit = fit_poses(&drive(config.clone()), &FitConfig::full(NOMINAL)).expect("fits");
        assert_eq!(
            fit.kind.kind,
            ReferenceKind::Absolute,
            "{}",
            fit.kind.reason
        );
        for (p, truth) in truth_of(&config) {
            let (v, s) = (fit.value(p), fit.std(p).expect("fitted"));
            let bound = match p {
                Param::LeftDiameter | Param::RightDiameter | Param::Wheelbase => 0.002 * truth,
                Param::SensorX | Param::SensorY => 0.005,
                Param::SensorYaw => 1f64.to_radians(),
                Param::TimeOffset => 0.015,
            };
            assert!(
                (v - truth).abs() < bound,
                "seed {seed} {}: {v} vs {truth}",
                p.name()
            );
            assert!(
                (v - truth).abs() < 3.0 * s,
                "seed {seed} {}: {v} vs {truth}, σ {s}",
                p.name()
            );
        }
        // 1 % of 3000 samples are outliers of 15–45 cm: every one is found.
        assert!(
            (20..=50).contains(&fit.outliers),
            "{} outliers",
            fit.outliers
        );
    }
}

/// Chained scan matching (1 mm and 0.1° per increment, 2 % gross failures that stay in the
/// chain): three independent drives of one robot agree within their stated 2σ, and each is
/// within 0.5 % of the truth.
#[test]
fn three_drives_under_chained_scan_matching_agree_within_their_errors() {
    let fits: Vec<PoseFit> = (0..3)
        .map(|i| {
            let config = DrivingConfig {
                seed: 1000 + i,
                ..DrivingConfig::with_reference(ReferenceKind::Relative)
            };
            let fit = fit_poses(&drive(config), &FitConfig::full(NOMINAL)).expect("fits");
            assert_eq!(
                fit.kind.kind,
                ReferenceKind::Relative,
                "{}",
                fit.kind.reason
            );
            fit
        })
        .collect();
    let truth = DrivingConfig::default().truth;
    for (p, t) in [
        (Param::LeftDiameter, truth.left_diameter_m),
        (Param::RightDiameter, truth.right_diameter_m),
        (Param::Wheelbase, truth.wheelbase_m),
    ] {
        for f in &fits {
            assert!(
                (f.value(p) / t - 1.0).abs() < 0.005,
                "{}: {} vs {t}",
                p.name(),
                f.value(p)
            );
        }
        for i in 0..3 {
            for j in (i + 1)..3 {
                let (a, b) = (&fits[i], &fits[j]);
                let s = (a.std(p).unwrap().powi(2) + b.std(p).unwrap().powi(2)).sqrt();
                assert!(
                    (a.value(p) - b.value(p)).abs() < 2.0 * s,
                    "{}: drives {i} and {j} differ by {} with σ {s}",
                    p.name(),
                    a.value(p) - b.value(p)
                );
            }
        }
    }
}

/// A position-only reference (GNSS): no yaw, so no mounting yaw, the rest as before.
#[test]
fn a_position_only_reference_fits_the_geometry_and_the_lever_arm() {
    let config = DrivingConfig {
        seed: 7,
        position_only: true,
        ..DrivingConfig::default()
    };
    let fit = fit_poses(&drive(config.clone()), &FitConfig::full(NOMINAL)).expect("fits");
    assert!(fit.std(Param::SensorYaw).is_none());
    for (p, truth) in truth_of(&config) {
        if p == Param::SensorYaw {
            continue;
        }
        let (v, s) = (fit.value(p), fit.std(p).expect("fitted"));
        assert!(
            (v - truth).abs() < 3.0 * s,
            "{}: {v} vs {truth} ± {s}",
            p.name()
        );
    }
}

/// With 4096-count encoders over ten minutes: quantisation must not count as turning.
fn refusal(pattern: DrivingPattern) -> String {
    let rec = drive(DrivingConfig {
        seed: 3,
        pattern,
        encoder_counts_per_rev: Some(4096.0),
        duration_s: 600.0,
        ..DrivingConfig::default()
    });
    let err = calibrate_from_poses(&[("drive".into(), rec)], &FitConfig::full(NOMINAL))
        .expect_err("refused");
    assert!(matches!(err, CalibrationError::NotObserved { .. }), "{err}");
    err.to_string()
}

#[test]
fn a_drive_that_observes_too_little_is_refused_with_what_to_drive() {
    let straight = refusal(DrivingPattern::StraightOnly);
    assert!(straight.contains("turn both ways"), "{straight}");
    assert!(straight.contains("wheelbase"), "{straight}");
    let one_way = refusal(DrivingPattern::TurnOneWay);
    assert!(one_way.contains("turn both ways"), "{one_way}");
    assert!(one_way.contains("° right"), "{one_way}");
}

fn diagnosis(edit: impl Fn(&mut PoseRecording)) -> String {
    let mut rec = drive(DrivingConfig {
        seed: 5,
        ..DrivingConfig::default()
    });
    edit(&mut rec);
    calibrate_from_poses(&[("drive".into(), rec)], &FitConfig::full(NOMINAL))
        .expect_err("refused")
        .to_string()
}

#[test]
fn swapped_wheels_a_clockwise_yaw_and_a_yaw_in_degrees_are_named() {
    let swapped = diagnosis(|r| {
        for w in &mut r.wheels {
            std::mem::swap(&mut w.left_rad, &mut w.right_rad);
        }
    });
    assert!(swapped.contains("swapped"), "{swapped}");
    let clockwise = diagnosis(|r| {
        for p in &mut r.poses {
            p.yaw_rad = p.yaw_rad.map(|y| -y);
        }
    });
    assert!(clockwise.contains("clockwise positive"), "{clockwise}");
    let degrees = diagnosis(|r| {
        for p in &mut r.poses {
            p.yaw_rad = p.yaw_rad.map(f64::to_degrees);
        }
    });
    assert!(degrees.contains("degrees"), "{degrees}");
}

fn free_set(id: &str) -> Option<OptiOdomSet> {
    let root = common::optiodom("free")?;
    Some(OptiOdomSet::load(root.join("free").join(id)).expect("loads"))
}

fn calibrate_set(set: &OptiOdomSet) -> PoseCalibration {
    let recordings = set.pose_recordings();
    let config = FitConfig {
        kind: Some(ReferenceKind::Absolute),
        ..FitConfig::full(Geometry::from(&set.configured))
    };
    calibrate_from_poses(&recordings, &config).expect("calibrates")
}

/// Real data: fitted on one OptiOdom free set, the other set's runs dead-reckon closer to the
/// motion capture's final positions (mean over the runs) than with the nominal geometry and
/// than with the two-multiplier baseline, both ways round.
#[test]
fn an_optiodom_free_set_fitted_dead_reckons_the_other_better_than_nominal_and_baseline() {
    let (Some(a), Some(b)) = (free_set("020120212354"), free_set("030120210001")) else {
        return;
    };
    for (fit_on, evaluate) in [(&a, &b), (&b, &a)] {
        let calibration = calibrate_set(fit_on);
        let runs: Vec<_> = evaluate
            .pose_recordings()
            .iter()
            .filter_map(|(name, p)| dead_reckon(name, p, &calibration))
            .collect();
        assert_eq!(runs.len(), evaluate.runs.len());
        let mean = |f: &dyn Fn(&odocal::calibration::pose_calibration::DeadReckoning) -> f64| {
            runs.iter().map(f).sum::<f64>() / runs.len() as f64
        };
        let fitted = mean(&|r| r.calibrated_m);
        // The geometry's share alone, with no mounting or offset, as the others have none.
        let geometry_only = mean(&|r| r.calibrated_geometry_only_m);
        let nominal = mean(&|r| r.nominal_m);
        let baseline = mean(&|r| r.baseline_m.expect("baseline"));
        assert!(
            fitted < nominal.min(baseline) && geometry_only < nominal.min(baseline),
            "fitted on {}, evaluated on {}: {fitted:.4} m ({geometry_only:.4} m by the geometry \
             alone) vs nominal {nominal:.4} m and baseline {baseline:.4} m",
            fit_on.id,
            evaluate.id
        );
    }
}

/// The contract: `odocal fit --wheels W.csv --poses P.csv --wheel-diameter-m D --wheelbase-m B
/// --json` prints the top-level fields, near the simulated truth.
#[test]
fn the_command_line_contract_on_csv_files() {
    let config = DrivingConfig {
        seed: 11,
        ..DrivingConfig::default()
    };
    let rec = drive(config.clone());
    let dir = common::scratch("pose_fit_contract");
    std::fs::create_dir_all(&dir).expect("scratch");
    let (w, p) = (dir.join("wheels.csv"), dir.join("poses.csv"));
    write_wheels(&w, &rec.wheels).expect("writes");
    write_poses(&p, &rec.poses).expect("writes");
    let (w, p) = (w.to_str().unwrap(), p.to_str().unwrap());
    let json = common::odocal_json(&[
        "fit",
        "--wheels",
        w,
        "--poses",
        p,
        "--wheel-diameter-m",
        "0.1",
        "--wheelbase-m",
        "0.3",
        "--json",
    ]);
    for (key, truth) in [
        ("left_wheel_diameter_m", config.truth.left_diameter_m),
        ("right_wheel_diameter_m", config.truth.right_diameter_m),
        ("wheelbase_m", config.truth.wheelbase_m),
        ("sensor_x_m", config.sensor_x_m),
        ("sensor_y_m", config.sensor_y_m),
        ("sensor_yaw_rad", config.sensor_yaw_rad),
        ("time_offset_s", config.delay_s),
    ] {
        let v = json[key]
            .as_f64()
            .unwrap_or_else(|| panic!("{key} in {json}"));
        let s = json[format!("{key}_std")]
            .as_f64()
            .unwrap_or_else(|| panic!("{key}_std in {json}"));
        assert!((v - truth).abs() < 4.0 * s, "{key}: {v} vs {truth} ± {s}");
    }
    let e_d = json["e_d"].as_f64().expect("e_d");
    let e_b = json["e_b"].as_f64().expect("e_b");
    assert!((e_d - config.truth.right_diameter_m / config.truth.left_diameter_m).abs() < 1e-3);
    assert!((e_b - config.truth.wheelbase_m / 0.3).abs() < 1e-3);
    // Without the geometry the message names the flags.
    let (ok, _, err) = common::odocal(&["fit", "--wheels", w, "--poses", p, "--json"]);
    assert!(!ok);
    assert!(err.contains("--wheel-diameter-m"), "{err}");
    // `--report DIR`: fit.json (what --json prints) and the plots.
    let report = dir.join("report");
    let (ok, _, err) = common::odocal(&[
        "fit",
        "--wheels",
        w,
        "--poses",
        p,
        "--wheel-diameter-m",
        "0.1",
        "--wheelbase-m",
        "0.3",
        "--report",
        report.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let reported: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(report.join("fit.json")).expect("fit.json"))
            .expect("JSON");
    assert_eq!(reported["wheelbase_m"], json["wheelbase_m"]);
    for (file, title) in [
        ("pose_paths.svg", "path in the reference"),
        ("pose_errors.svg", "distance from the reference"),
        ("pose_mounting.svg", "the reference frame in base_link"),
    ] {
        let svg = std::fs::read_to_string(report.join(file)).expect(file);
        assert!(svg.starts_with("<svg") && svg.contains(title), "{file}");
    }
    // `odocal export` writes the fitted geometry into the controller's YAML (a backup beside
    // it first), and `odocal restore` of that backup puts the file back byte for byte.
    let fit_json = report.join("fit.json");
    let yaml = dir.join("diff_drive.yaml");
    let original = common::DIFF_DRIVE_YAML;
    std::fs::write(&yaml, original).expect("writes");
    let (y, f) = (yaml.to_str().unwrap(), fit_json.to_str().unwrap());
    let (ok, out, err) = common::odocal(&["export", "--from", f, "--ros2", y, "--force"]);
    assert!(ok, "{err}");
    let written = odocal::ros::yaml::DiffDriveConfig::load(&yaml, "diff_drive_controller")
        .expect("a controller YAML")
        .effective();
    for (key, v) in [
        ("left_wheel_diameter_m", written.left_wheel_diameter_m),
        ("right_wheel_diameter_m", written.right_wheel_diameter_m),
        ("wheelbase_m", written.wheelbase_m),
    ] {
        let fitted = json[key].as_f64().expect("fitted");
        assert!((v - fitted).abs() < 1e-9 * fitted, "{key}: {v} vs {fitted}");
    }
    let backup = out
        .split("odocal restore ")
        .nth(1)
        .and_then(|rest| rest.split(')').next())
        .unwrap_or_else(|| panic!("the undo command in {out}"));
    let (ok, _, err) = common::odocal(&["restore", backup, "--yes"]);
    assert!(ok, "{err}");
    assert_eq!(std::fs::read_to_string(&yaml).expect("reads"), original);
}

/// The same drive from a bag, its reference as each pose type a ROS robot publishes: the fit
/// equals the CSV's (same samples, stamps on a ROS clock), and `odocal fit --bag` prints it.
#[test]
fn a_drive_from_a_bag_with_a_pose_topic_fits_as_from_csv() {
    use odocal::ros::bag::reference::read_pose_drive;
    use odocal::ros::bag::writer::write_pose_drive_bag;
    use odocal::ros::bag::BagOptions;
    use odocal::ros::msg::types;
    let config = DrivingConfig {
        seed: 21,
        ..DrivingConfig::default()
    };
    let mut rec = drive(config.clone());
    let full = FitConfig::full(NOMINAL);
    let from_csv = fit_poses(&rec, &full).expect("fits");
    let dir = common::scratch("pose_fit_bag");
    std::fs::create_dir_all(&dir).expect("scratch");
    for (kind, topic) in [
        (types::POSE_STAMPED, "/mocap/pose"),
        (types::POSE_WITH_COVARIANCE_STAMPED, "/amcl_pose"),
        (types::ODOMETRY, "/vio/odom"),
    ] {
        let path = dir.join(format!("{}.mcap", topic.replace('/', "_")));
        write_pose_drive_bag(&path, &rec, kind, topic, 1.7e9).expect("writes");
        let read = read_pose_drive(&path, &BagOptions::default(), topic).expect("reads");
        assert_eq!(read.recording.wheels.len(), rec.wheels.len());
        assert_eq!(read.recording.poses.len(), rec.poses.len());
        let fit = fit_poses(&read.recording, &full).expect("fits");
        for p in Param::ALL {
            let (a, b, s) = (fit.value(p), from_csv.value(p), from_csv.std(p).unwrap());
            assert!(
                (a - b).abs() < 0.05 * s,
                "{topic} {}: {a} vs {b} ± {s}",
                p.name()
            );
        }
    }
    // A stated covariance weights the samples: every tenth pose made three times noisier,
    // and stated so; the others state the simulator's own noise. The fit finds the stated
    // scale right (about 1) and keeps the truth within its errors.
    let mut state: u64 = 99;
    let mut noise = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 12f64.sqrt()
    };
    for (i, p) in rec.poses.iter_mut().enumerate() {
        let k = if i % 10 == 0 { 3.0 } else { 1.0 };
        if k > 1.0 {
            p.x_m += 0.003 * (k * k - 1.0f64).sqrt() * noise();
            p.y_m += 0.003 * (k * k - 1.0f64).sqrt() * noise();
        }
        p.stated_std = Some([0.003 * k, 0.003 * k, 0.3f64.to_radians() * k]);
    }
    let weighted = fit_poses(&rec, &full).expect("fits");
    let scale = weighted
        .stated_scale
        .expect("the stated σ weighted the samples");
    assert!((0.85..1.2).contains(&scale), "stated scale {scale}");
    let path = dir.join("stated.mcap");
    write_pose_drive_bag(
        &path,
        &rec,
        types::POSE_WITH_COVARIANCE_STAMPED,
        "/amcl_pose",
        1.7e9,
    )
    .expect("writes");
    let read = read_pose_drive(&path, &BagOptions::default(), "/amcl_pose").expect("reads");
    assert!(read.recording.poses.iter().all(|p| p.stated_std.is_some()));
    let json = common::odocal_json(&[
        "fit",
        "--bag",
        path.to_str().unwrap(),
        "--reference",
        "/amcl_pose",
        "--wheel-diameter-m",
        "0.1",
        "--wheelbase-m",
        "0.3",
        "--json",
    ]);
    let truth = config.truth.wheelbase_m;
    let (b, s) = (
        json["wheelbase_m"].as_f64().expect("wheelbase_m"),
        json["wheelbase_m_std"].as_f64().expect("its std"),
    );
    assert!((b - truth).abs() < 4.0 * s, "{b} vs {truth} ± {s}");
    // A topic of another type is named with what it carries.
    let (ok, _, err) = common::odocal(&[
        "fit",
        "--bag",
        path.to_str().unwrap(),
        "--reference",
        "/joint_states",
        "--wheel-diameter-m",
        "0.1",
        "--wheelbase-m",
        "0.3",
    ]);
    assert!(!ok);
    assert!(
        err.contains("JointState") && err.contains("PoseStamped"),
        "{err}"
    );
}

/// The same drive with its reference as the TF chain `map → odom → base_link` (the
/// localization's correction at its stamps, the controller's odometry at the wheels' rate) and
/// a static link off the chain: `--reference tf:map` fits as the CSV does.
#[test]
fn a_drive_from_a_bag_with_tf_fits_as_from_csv() {
    use odocal::ros::bag::tf::read_tf_drive;
    use odocal::ros::bag::writer::write_localization_bag;
    use odocal::ros::bag::BagOptions;
    let rec = drive(DrivingConfig {
        seed: 22,
        ..DrivingConfig::default()
    });
    let full = FitConfig::full(NOMINAL);
    let from_csv = fit_poses(&rec, &full).expect("fits");
    let dir = common::scratch("pose_fit_tf");
    std::fs::create_dir_all(&dir).expect("scratch");
    let path = dir.join("tf.mcap");
    write_localization_bag(&path, &rec, NOMINAL, 1.7e9).expect("writes");
    let read = read_tf_drive(&path, &BagOptions::default(), "map", "base_link").expect("reads");
    assert_eq!(read.chain, ["map", "odom", "base_link"]);
    assert_eq!(read.recording.poses.len(), rec.poses.len());
    let fit = fit_poses(&read.recording, &full).expect("fits");
    for p in Param::ALL {
        let (a, b, s) = (fit.value(p), from_csv.value(p), from_csv.std(p).unwrap());
        assert!((a - b).abs() < 0.25 * s, "{}: {a} vs {b} ± {s}", p.name());
    }
    let json = common::odocal_json(&[
        "fit",
        "--bag",
        path.to_str().unwrap(),
        "--reference",
        "tf:map",
        "--wheel-diameter-m",
        "0.1",
        "--wheelbase-m",
        "0.3",
        "--json",
    ]);
    let b = json["wheelbase_m"].as_f64().expect("wheelbase_m");
    assert!((b - fit.geometry.wheelbase_m).abs() < 1e-9, "{b}");
    // The same bag's /amcl_pose is the same reference.
    let amcl =
        odocal::ros::bag::reference::read_pose_drive(&path, &BagOptions::default(), "/amcl_pose")
            .expect("reads");
    assert_eq!(amcl.recording.poses.len(), rec.poses.len());
    // A fixed frame the tree does not reach is named with the links it has.
    let err = read_tf_drive(&path, &BagOptions::default(), "world", "base_link").unwrap_err();
    assert!(err.to_string().contains("map → odom"), "{err}");
    // The controller's own chain is no reference (issue 46): refused by name, nothing fitted.
    let (ok, out, err) = common::odocal(&[
        "fit",
        "--bag",
        path.to_str().unwrap(),
        "--reference",
        "tf:odom",
        "--wheel-diameter-m",
        "0.1",
        "--wheelbase-m",
        "0.3",
    ]);
    assert!(!ok, "{out}");
    assert!(
        err.contains("wheels' own odometry") && !out.contains("wheelbase_m"),
        "{out}{err}"
    );
}

/// A bag in memory: channels and their messages as raw bytes, for the readers' error paths.
struct RawBag(Vec<(odocal::ros::bag::Channel, Vec<u8>)>);

impl odocal::ros::bag::Container for RawBag {
    fn format(&self) -> &'static str {
        "test"
    }
    fn channels(&self) -> Option<Vec<odocal::ros::bag::Channel>> {
        let mut c: Vec<_> = self.0.iter().map(|(c, _)| c.clone()).collect();
        c.dedup();
        Some(c)
    }
    fn messages(
        &self,
        each: &mut dyn FnMut(
            odocal::ros::bag::RawMessage<'_>,
        ) -> Result<(), odocal::ros::bag::BagError>,
    ) -> Result<(), odocal::ros::bag::BagError> {
        for (i, (channel, data)) in self.0.iter().enumerate() {
            each(odocal::ros::bag::RawMessage {
                channel,
                log_time_ns: 1_000_000_000 + i as u64 * 20_000_000,
                data,
            })?;
        }
        Ok(())
    }
}

fn channel(topic: &str, type_name: &str) -> odocal::ros::bag::Channel {
    odocal::ros::bag::Channel {
        topic: topic.into(),
        type_name: type_name.into(),
        encoding: "cdr".into(),
    }
}

/// Bad bytes on the reference topic, a reference topic the bag lacks, and a TF tree that
/// never moves are each refused by name, with what to do; nothing panics.
#[test]
fn the_bag_readers_refuse_bad_bytes_a_missing_topic_and_a_still_tree_by_name() {
    use odocal::ros::bag::reference::read_pose_container;
    use odocal::ros::bag::tf::read_tf_container;
    use odocal::ros::bag::{BagError, BagOptions};
    use odocal::ros::msg::{cdr, types, Header, JointState, TfMessage, TransformStamped};
    let joints = |t: f64| {
        cdr::encode(&JointState {
            header: Header {
                stamp: odocal::ros::msg::Time::from_seconds(t),
                frame_id: String::new(),
            },
            name: vec!["left_wheel_joint".into(), "right_wheel_joint".into()],
            position: vec![t, 2.0 * t],
            velocity: vec![],
            effort: vec![],
        })
        .expect("encodes")
    };
    let js = channel("/joint_states", types::JOINT_STATE);
    let pose = channel("/amcl_pose", types::POSE_WITH_COVARIANCE_STAMPED);
    let mut messages: Vec<_> = (0..20)
        .map(|i| (js.clone(), joints(1.0 + i as f64 * 0.02)))
        .collect();
    // A CDR header, then bytes that are no pose.
    messages.push((pose.clone(), vec![0, 1, 0, 0, 0xff, 0xfe, 0x07]));
    let opts = BagOptions::default();
    match read_pose_container(&RawBag(messages.clone()), &opts, "/amcl_pose") {
        Err(BagError::Decode { topic, index, .. }) => {
            assert_eq!((topic.as_str(), index), ("/amcl_pose", 0));
        }
        other => panic!("bad bytes: {other:?}"),
    }
    messages.pop();
    let err = read_pose_container(&RawBag(messages.clone()), &opts, "/amcl_pose").unwrap_err();
    assert!(matches!(err, BagError::MissingTopic { .. }), "{err}");
    assert!(err.to_string().contains("/joint_states"), "{err}");
    // A tree whose every link is static is no reference.
    let tf = cdr::encode(&TfMessage {
        transforms: vec![TransformStamped {
            header: Header {
                stamp: odocal::ros::msg::Time::from_seconds(0.0),
                frame_id: "map".into(),
            },
            child_frame_id: "base_link".into(),
            ..TransformStamped::default()
        }],
    })
    .expect("encodes");
    messages.push((channel("/tf_static", types::TF_MESSAGE), tf));
    let err = read_tf_container(&RawBag(messages), &opts, "map", "base_link").unwrap_err();
    assert!(err.to_string().contains("never moves"), "{err}");
}

/// The online filter fed the same drive (its wheels as a controller with the nominal geometry
/// counts them, the poses as pose fixes, the reference's delay given) agrees with the batch
/// fit within 3σ of their combined errors on both diameters and the wheelbase, and holds the
/// truth and the mounting within its own 3σ; the outliers are gated.
#[test]
fn the_online_filter_with_pose_fixes_agrees_with_the_batch_fit() {
    use odocal::calibration::online::{OnlineConfig, ScaleSource};
    use odocal::calibration::recording::Recording;
    use odocal::calibration::tracker::Tracker;
    use odocal::kinematics::WheelParams;
    for seed in 0..3 {
        let config = DrivingConfig {
            seed,
            ..DrivingConfig::default()
        };
        let simulated = simulate_drive(&config).expect("simulates");
        let recording = simulated.recording;
        let fit = fit_poses(&recording, &FitConfig::full(NOMINAL)).expect("fits");
        let configured = WheelParams::nominal(NOMINAL.left_diameter_m, NOMINAL.wheelbase_m, 4096.0);
        let mut cfg = OnlineConfig::new(configured);
        cfg.position_sigma_m = config.position_sigma_m;
        cfg.heading_sigma_rad = config.yaw_sigma_rad;
        cfg.slip_fraction = 0.002;
        let mut tracker = Tracker::new(cfg, ScaleSource::Filter, 1.0).expect("filter");
        tracker.set_pose_delay(config.delay_s);
        tracker.feed_recording("sim", &Recording::of_pose_recording(&recording, NOMINAL));
        let online = tracker.estimate().expect("estimates");
        let scale_std = online.correction_std.expect("the scale is observed");
        let c = online.correction;
        let rows = [
            (
                Param::LeftDiameter,
                NOMINAL.left_diameter_m,
                c.left_diameter_scale,
                scale_std[0],
            ),
            (
                Param::RightDiameter,
                NOMINAL.right_diameter_m,
                c.right_diameter_scale,
                scale_std[1],
            ),
            (
                Param::Wheelbase,
                NOMINAL.wheelbase_m,
                c.wheelbase_scale,
                scale_std[2],
            ),
        ];
        for (p, nominal, factor, factor_std) in rows {
            let (value, std) = (nominal * factor, nominal * factor_std);
            let (batch, batch_std) = (fit.value(p), fit.std(p).expect("fitted"));
            let truth = truth_of(&config)[p.index()].1;
            assert!(
                (value - batch).abs() < 3.0 * std.hypot(batch_std),
                "seed {seed} {}: online {value} ± {std}, batch {batch} ± {batch_std}",
                p.name()
            );
            assert!(
                (value - truth).abs() < 3.0 * std,
                "seed {seed} {}: online {value} ± {std}, truth {truth}",
                p.name()
            );
            assert!(std < 0.002 * truth, "seed {seed} {}: σ {std}", p.name());
        }
        let (mount, mount_std) = tracker.filter().mount();
        let true_mount = [config.sensor_x_m, config.sensor_y_m, config.sensor_yaw_rad];
        for i in 0..3 {
            assert!(
                (mount[i] - true_mount[i]).abs() < 3.0 * mount_std[i],
                "seed {seed} mount {i}: {} ± {} vs {}",
                mount[i],
                mount_std[i],
                true_mount[i]
            );
        }
        let gate = tracker.filter().gate_stats();
        let (nis, fixes) = tracker.filter().nis_pose_mean();
        // Most outliers rejected (those before the start went to the batch fit), few good
        // fixes (the 99.9 % gate lets a thousandth of them go: about three), and no reset.
        assert!(
            gate.rejected <= simulated.outliers as u64 + 10
                && gate.rejected >= simulated.outliers as u64 / 2
                && gate.resets == 0,
            "seed {seed}: {gate:?}, {} outliers",
            simulated.outliers
        );
        // It started from a batch fit of the first two minutes at most (once the drive had
        // turned half a turn both ways and driven a metre straight), then took every fix but
        // the outliers, consistently.
        let started = tracker.started_from.as_ref().expect("started").span_s;
        assert!(started < 120.0, "started after {started} s");
        assert!(
            fixes > 1500 && (0.8..1.2).contains(&nis),
            "{fixes} fixes, NIS {nis}"
        );
    }
}

/// The online filter takes an absolute reference with a yaw: a chained one (scan matching) and
/// a position-only one (GNSS) are refused by name, pointing to `odocal fit`.
#[test]
fn the_online_filter_refuses_a_chained_or_position_only_reference_by_name() {
    use odocal::calibration::online::{OnlineConfig, ScaleSource};
    use odocal::calibration::recording::Recording;
    use odocal::calibration::tracker::Tracker;
    use odocal::kinematics::WheelParams;
    let chained = DrivingConfig::with_reference(ReferenceKind::Relative);
    let position_only = DrivingConfig {
        position_only: true,
        ..DrivingConfig::default()
    };
    for (config, expected) in [
        (chained, "accumulates error"),
        (position_only, "position-only"),
    ] {
        let recording = drive(config);
        let configured = WheelParams::nominal(NOMINAL.left_diameter_m, NOMINAL.wheelbase_m, 4096.0);
        let mut tracker =
            Tracker::new(OnlineConfig::new(configured), ScaleSource::Filter, 1.0).expect("filter");
        tracker.feed_recording("sim", &Recording::of_pose_recording(&recording, NOMINAL));
        let err = tracker.estimate().expect_err("refused").to_string();
        assert!(
            err.contains(expected) && err.contains("odocal fit"),
            "{err}"
        );
        assert!(tracker.started_from.is_none());
    }
}

/// The default drive with the truth 3 % off the nominal, and what the simulator knows of it.
fn three_percent_off() -> odocal::sim::driving::SimulatedDrive {
    simulate_drive(&DrivingConfig {
        truth: Geometry {
            left_diameter_m: 0.103,
            right_diameter_m: 0.1025,
            wheelbase_m: 0.309,
        },
        seed: 11,
        ..DrivingConfig::default()
    })
    .expect("simulates")
}

/// A reference built from the drive's wheels as robots build them: every fifth wheel sample,
/// stamped `late_s` after it, seen through a fixed frame (`map → odom` standing still), its
/// positions from the wheels at the nominal geometry and its heading from `heading` (the
/// wheels' own, or a gyro's: the true heading).
fn wheel_made(
    sim: &odocal::sim::driving::SimulatedDrive,
    late_s: f64,
    gyro: bool,
) -> PoseRecording {
    use odocal::calibration::pose_reference::{Odometry, ReferencePose};
    let rec = &sim.recording;
    let odo = Odometry::integrate(&rec.wheels, NOMINAL);
    let poses = odo.poses();
    let (mut x, mut y) = (0.0f64, 0.0f64);
    let mut out = rec.clone();
    out.poses.clear();
    let (ox, oy, oyaw) = (3.0, -2.0, 0.7f64);
    for i in 0..rec.wheels.len() {
        let heading = |k: usize| {
            if gyro {
                // A gyro's heading: the true one with a wobble of a milliradian.
                sim.true_path[k].1.theta + 1e-3 * (k as f64 * 1.7).sin()
            } else {
                poses[k].theta
            }
        };
        if i > 0 {
            // The wheels' distance along the heading, as a filter integrates it.
            let (dx, dy) = (poses[i].x - poses[i - 1].x, poses[i].y - poses[i - 1].y);
            let forward = dx * poses[i - 1].theta.cos() + dy * poses[i - 1].theta.sin();
            let ds = dx.hypot(dy).copysign(forward);
            let mid = 0.5 * (heading(i) + heading(i - 1));
            x += ds * mid.cos();
            y += ds * mid.sin();
        }
        if i % 5 == 0 {
            let (c, s) = (oyaw.cos(), oyaw.sin());
            out.poses.push(ReferencePose {
                time_s: rec.wheels[i].time_s + late_s,
                x_m: ox + c * x - s * y,
                y_m: oy + s * x + c * y,
                yaw_rad: Some(odocal::kinematics::wrap_angle(heading(i) + oyaw)),
                stated_std: None,
            });
        }
    }
    out
}

fn calibrate_one(rec: PoseRecording) -> Result<PoseCalibration, CalibrationError> {
    calibrate_from_poses(&[("drive".into(), rec)], &FitConfig::full(NOMINAL))
}

/// Issue 46: the controller's own odometry (on time, 40 ms late, without its heading) and a
/// filter that fuses the wheels with a gyro are named for what they are, never fitted; the
/// same drive against an independent reference is fitted.
#[test]
fn a_reference_made_from_the_wheels_is_named_never_fitted() {
    let sim = three_percent_off();
    for late_s in [0.0, 0.04] {
        let err = calibrate_one(wheel_made(&sim, late_s, false)).expect_err("refused");
        let text = err.to_string();
        assert!(
            matches!(err, CalibrationError::ReferenceFromWheels(_)),
            "{late_s} s late: {text}"
        );
        assert!(text.contains("wheels' own odometry"), "{text}");
        assert!(text.contains("/amcl_pose"), "{text}");
    }
    let mut no_heading = wheel_made(&sim, 0.0, false);
    for p in &mut no_heading.poses {
        p.yaw_rad = None;
    }
    let err = calibrate_one(no_heading).expect_err("refused");
    assert!(
        matches!(err, CalibrationError::ReferenceFromWheels(_)),
        "{err}"
    );
    let fused = calibrate_one(wheel_made(&sim, 0.0, true)).expect_err("refused");
    let text = fused.to_string();
    assert!(
        matches!(fused, CalibrationError::ReferenceFromWheels(_)),
        "{text}"
    );
    assert!(
        text.contains("gyro") && text.contains("E_d and E_b"),
        "{text}"
    );
    // What the fused heading alone measures: the truth's E_d and E_b (its diameters' mean is
    // 2.75 % over the nominal, held there, so E_b is the truth's wheelbase over that mean's).
    let figure = |name: &str| -> (f64, f64) {
        let rest = text.split(&format!("{name} = ")).nth(1).expect("a figure");
        let mut words = rest.split(' ');
        let v = words.next().and_then(|w| w.parse().ok()).expect("value");
        let s = words
            .nth(1)
            .and_then(|w| w.trim_end_matches(',').parse().ok())
            .expect("σ");
        (v, s)
    };
    let t = sim.truth;
    let mean = 0.5 * (t.left_diameter_m + t.right_diameter_m) / NOMINAL.left_diameter_m;
    for (name, truth) in [
        ("E_d", t.right_diameter_m / t.left_diameter_m),
        ("E_b", t.wheelbase_m / NOMINAL.wheelbase_m / mean),
    ] {
        let (v, s) = figure(name);
        assert!(
            (v - truth).abs() < 4.0 * s && s > 0.0,
            "{name} {v} ± {s} vs {truth}"
        );
    }
    // Live: the online filter's start refuses the controller's odometry by the same test.
    {
        use odocal::calibration::online::{OnlineConfig, ScaleSource};
        use odocal::calibration::recording::Recording;
        use odocal::calibration::tracker::Tracker;
        use odocal::kinematics::WheelParams;
        let configured = WheelParams::nominal(NOMINAL.left_diameter_m, NOMINAL.wheelbase_m, 4096.0);
        let mut tracker =
            Tracker::new(OnlineConfig::new(configured), ScaleSource::Filter, 1.0).expect("filter");
        let own = wheel_made(&sim, 0.06, false);
        tracker.feed_recording("odom", &Recording::of_pose_recording(&own, NOMINAL));
        let err = tracker.estimate().expect_err("refused").to_string();
        assert!(err.contains("wheels' own odometry"), "{err}");
        assert!(tracker.started_from.is_none());
    }
    let fit = calibrate_one(sim.recording.clone()).expect("an independent reference fits");
    assert_eq!(
        fit.recordings[0].independence.source,
        odocal::calibration::independence::ReferenceSource::Independent
    );
}

/// A heading made from the wheels beside independent positions (wheels fused with GNSS): the
/// yaw is left out, the positions alone fitted, and the truth is within the stated errors.
#[test]
fn a_heading_from_the_wheels_is_left_out_and_the_positions_fitted() {
    let sim = three_percent_off();
    let own = wheel_made(&sim, 0.06, false);
    let mut rec = sim.recording.clone();
    for (p, o) in rec.poses.iter_mut().zip(&own.poses) {
        p.yaw_rad = o.yaw_rad;
    }
    let calibration = calibrate_one(rec).expect("fits the positions");
    let fit = calibration.recordings[0].fit.as_ref().expect("fitted");
    assert!(
        fit.warnings.iter().any(|w| w.contains("yaw is left out")),
        "{:?}",
        fit.warnings
    );
    assert!(fit.residual_std_yaw_rad.is_none(), "fitted without yaw");
    for (p, truth) in [
        (Param::LeftDiameter, sim.truth.left_diameter_m),
        (Param::RightDiameter, sim.truth.right_diameter_m),
        (Param::Wheelbase, sim.truth.wheelbase_m),
    ] {
        let (v, s) = (fit.value(p), fit.std(p).expect("fitted"));
        assert!(
            (v - truth).abs() < 4.0 * s,
            "{}: {v} vs {truth} ± {s}",
            p.name()
        );
    }
}

/// Issue 46: a unit or a sign the model does not take is refused by name, with what to do.
#[test]
fn units_and_signs_are_named() {
    let sim = three_percent_off();
    let refused = |edit: &dyn Fn(&mut PoseRecording), nominal: Geometry| {
        let mut rec = sim.recording.clone();
        edit(&mut rec);
        calibrate_from_poses(&[("drive".into(), rec)], &FitConfig::full(nominal))
            .expect_err("refused")
            .to_string()
    };
    let positions = |k: f64| {
        move |r: &mut PoseRecording| {
            for p in &mut r.poses {
                p.x_m *= k;
                p.y_m *= k;
            }
        }
    };
    let wheels = |k: f64| {
        move |r: &mut PoseRecording| {
            for w in &mut r.wheels {
                w.left_rad *= k;
                w.right_rad *= k;
            }
        }
    };
    for (edit, nominal, expect) in [
        (
            Box::new(positions(1000.0)) as Box<dyn Fn(&mut PoseRecording)>,
            NOMINAL,
            "millimetres",
        ),
        (Box::new(positions(1.0 / 0.3048)), NOMINAL, "feet"),
        (
            Box::new(wheels(1.0 / std::f64::consts::TAU)),
            NOMINAL,
            "revolutions",
        ),
        (
            Box::new(wheels(180.0 / std::f64::consts::PI)),
            NOMINAL,
            "degrees",
        ),
        (
            Box::new(wheels(4096.0 / std::f64::consts::TAU)),
            NOMINAL,
            "encoder counts, about",
        ),
        (
            Box::new(|_: &mut PoseRecording| {}),
            Geometry {
                left_diameter_m: 100.0,
                right_diameter_m: 100.0,
                wheelbase_m: 300.0,
            },
            "nominal geometry is in millimetres",
        ),
        (Box::new(wheels(-1.0)), NOMINAL, "negate both wheel angles"),
    ] {
        let text = refused(&*edit, nominal);
        assert!(text.contains(expect), "{expect}: {text}");
    }
    // A 16-bit counter of 4096 counts per turn wraps every 16 turns: a jump of 100.5 rad.
    let wrapped = refused(
        &|r: &mut PoseRecording| {
            for w in r.wheels.iter_mut().skip(4000) {
                w.left_rad -= 65536.0 * std::f64::consts::TAU / 4096.0;
            }
        },
        NOMINAL,
    );
    assert!(
        wrapped.contains("counter that wraps") && wrapped.contains("jumps by -100."),
        "{wrapped}"
    );
    let counts = refused(&wheels(4096.0 / std::f64::consts::TAU), NOMINAL);
    // 4096 counts, seen through the truth's 0.2 % of turn scale against the nominal.
    let per_rev: f64 = counts
        .split("about ")
        .nth(1)
        .and_then(|t| t.split(' ').next())
        .and_then(|n| n.parse().ok())
        .expect("a count per revolution");
    assert!((4000.0..4200.0).contains(&per_rev), "{counts}");
    // Both negated and then swapped, as the old advice had it: the fit turns the reference
    // frame round, and the warning says what happened.
    let mut rec = sim.recording.clone();
    for w in &mut rec.wheels {
        (w.left_rad, w.right_rad) = (-w.right_rad, -w.left_rad);
    }
    let calibration = calibrate_one(rec).expect("fits");
    let fit = calibration.recordings[0].fit.as_ref().expect("fitted");
    assert!(
        fit.warnings.iter().any(|w| w.contains("swap them back")),
        "{:?}",
        fit.warnings
    );
    let yaw = fit.value(Param::SensorYaw);
    assert!(
        yaw > -std::f64::consts::PI && yaw <= std::f64::consts::PI,
        "{yaw}"
    );
}

/// Issue 46: one recording given twice is one piece of evidence; a kind forced against the
/// data's own test is warned of with its figure; a fit without noise states its ± as what
/// they are, with no floor under them.
#[test]
fn pooling_counts_a_recording_once_and_a_forced_kind_is_checked() {
    let sim = three_percent_off();
    let once = calibrate_one(sim.recording.clone()).expect("fits");
    let twice = calibrate_from_poses(
        &[
            ("a.csv".into(), sim.recording.clone()),
            ("link-to-a.csv".into(), sim.recording.clone()),
        ],
        &FitConfig::full(NOMINAL),
    )
    .expect("fits");
    assert_eq!(twice.summary().recordings_pooled, 1);
    assert_eq!(twice.pooled, once.pooled);
    assert!(twice.recordings[1]
        .left_out
        .as_deref()
        .is_some_and(|w| w.contains("same data as a.csv")));

    let chained = drive(DrivingConfig {
        seed: 4,
        ..DrivingConfig::with_reference(ReferenceKind::Relative)
    });
    let forced = FitConfig {
        kind: Some(ReferenceKind::Absolute),
        ..FitConfig::full(NOMINAL)
    };
    let fit = fit_poses(&chained, &forced).expect("fits");
    assert!(
        fit.warnings
            .iter()
            .any(|w| w.contains("the data say relative")),
        "{:?}",
        fit.warnings
    );
    let honest = fit_poses(&drive(DrivingConfig::default()), &forced).expect("fits");
    assert!(
        !honest.warnings.iter().any(|w| w.contains("the data say")),
        "{:?}",
        honest.warnings
    );

    let exact = calibrate_one(drive(DrivingConfig {
        position_sigma_m: 0.0,
        yaw_sigma_rad: 0.0,
        outlier_fraction: 0.0,
        ..DrivingConfig::default()
    }))
    .expect("fits");
    let fit = exact.recordings[0].fit.as_ref().expect("fitted");
    let pooled = exact.get(Param::Wheelbase).expect("pooled").std;
    assert_eq!(pooled, fit.std(Param::Wheelbase).expect("fitted"));
    assert!(pooled < 1e-9, "{pooled}");
    assert!(
        fit.warnings
            .iter()
            .any(|w| w.contains("reproduces the reference exactly")),
        "{:?}",
        fit.warnings
    );
}

/// Issue 46: a reference seconds late is named with its delay and the flag that widens the
/// search (and fitted right with it); the online filter measures a localization's 60 ms itself
/// rather than taking it as on time; a clock that drifts is named with its rate; a hole in a
/// stream is named with its length and position.
#[test]
fn a_late_or_drifting_reference_clock_is_fitted_or_named() {
    use odocal::calibration::online::{OnlineConfig, ScaleSource};
    use odocal::calibration::recording::Recording;
    use odocal::calibration::tracker::Tracker;
    use odocal::kinematics::WheelParams;
    let late = |delay_s: f64| {
        drive(DrivingConfig {
            delay_s,
            seed: 6,
            ..DrivingConfig::default()
        })
    };
    let two_s = late(2.0);
    let err = fit_poses(&two_s, &FitConfig::full(NOMINAL)).expect_err("named");
    assert!(
        matches!(err, CalibrationError::DelayBeyondSearch { .. }),
        "{err}"
    );
    assert!(err.to_string().contains("--max-time-offset-s 3.0"), "{err}");
    let widened = FitConfig {
        max_time_offset_s: 3.0,
        ..FitConfig::full(NOMINAL)
    };
    let fit = fit_poses(&two_s, &widened).expect("fits with the search widened");
    let (v, s) = (
        fit.value(Param::TimeOffset),
        fit.std(Param::TimeOffset).expect("fitted"),
    );
    assert!((v - 2.0).abs() < 4.0 * s, "{v} ± {s}");

    // Live: nothing given, the start fit measures the delay and takes it off every fix.
    let config = DrivingConfig {
        seed: 6,
        ..DrivingConfig::default()
    };
    let simulated = simulate_drive(&config).expect("simulates");
    let configured = WheelParams::nominal(NOMINAL.left_diameter_m, NOMINAL.wheelbase_m, 4096.0);
    let mut cfg = OnlineConfig::new(configured);
    cfg.position_sigma_m = config.position_sigma_m;
    cfg.heading_sigma_rad = config.yaw_sigma_rad;
    cfg.slip_fraction = 0.002;
    let mut tracker = Tracker::new(cfg, ScaleSource::Filter, 1.0).expect("filter");
    tracker.feed_recording(
        "sim",
        &Recording::of_pose_recording(&simulated.recording, NOMINAL),
    );
    assert!(
        (tracker.pose_delay_s() - config.delay_s).abs() < 0.005,
        "measured {} s, truth {} s",
        tracker.pose_delay_s(),
        config.delay_s
    );
    let online = tracker.estimate().expect("estimates");
    let std = online.correction_std.expect("observed");
    let wheelbase = NOMINAL.wheelbase_m * online.correction.wheelbase_scale;
    assert!(
        (wheelbase - config.truth.wheelbase_m).abs() < 3.0 * NOMINAL.wheelbase_m * std[2],
        "{wheelbase} ± {} vs {}",
        NOMINAL.wheelbase_m * std[2],
        config.truth.wheelbase_m
    );

    // 300 ppm: the reference's stamps fall 90 ms further behind over the five minutes.
    let rate_of = |warnings: &[String]| {
        warnings.iter().find_map(|w| {
            let ppm = w.split(" ppm").next()?.rsplit(' ').next()?;
            ppm.parse::<f64>().ok()
        })
    };
    let mut drifting = late(0.06);
    for p in &mut drifting.poses {
        p.time_s += 3e-4 * p.time_s;
    }
    let fit = fit_poses(&drifting, &FitConfig::full(NOMINAL)).expect("fits");
    let ppm = rate_of(&fit.warnings).unwrap_or_else(|| panic!("{:?}", fit.warnings));
    assert!(
        (200.0..400.0).contains(&ppm),
        "{ppm} ppm: {:?}",
        fit.warnings
    );
    let steady = fit_poses(&late(0.06), &FitConfig::full(NOMINAL)).expect("fits");
    assert_eq!(rate_of(&steady.warnings), None, "{:?}", steady.warnings);

    let mut holed = late(0.06);
    holed.wheels.retain(|w| !(100.0..103.0).contains(&w.time_s));
    let calibration = calibrate_one(holed).expect("fits");
    let warnings = &calibration.recordings[0]
        .fit
        .as_ref()
        .expect("fitted")
        .warnings;
    assert!(
        warnings
            .iter()
            .any(|w| w.contains("wheel stream has 1 hole(s)") && w.contains("3.02 s at 100.0 s")),
        "{warnings:?}"
    );
}
