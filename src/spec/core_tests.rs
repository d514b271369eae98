//! The spec parser of a build without a backend (`--no-default-features`, which CI tests):
//! every text, flag and setting that names a backend is refused with the feature it needs,
//! never read as something else.
#![cfg(not(any(
    feature = "odocal-protocol",
    feature = "ros",
    feature = "roboclaw",
    feature = "nmea"
)))]

use super::flags::{RobotFlags, RosFlags};
use super::*;

/// `result`'s error names `features` (and says how to rebuild).
fn names<T>(result: Result<T, SpecError>, features: &[&str]) {
    match result {
        Err(SpecError::NotBuilt(e)) => {
            assert_eq!(e.features, features, "{e}");
            let flag = format!("`--features {}`", features.join(","));
            assert!(e.to_string().contains(&flag), "{e}");
        }
        Err(other) => panic!("expected a refusal naming {features:?}, got: {other}"),
        Ok(_) => panic!("expected a refusal naming {features:?}, got a value"),
    }
}

#[test]
fn a_drive_of_a_backend_left_out_names_its_feature() {
    for (text, features) in [
        ("/dev/ttyUSB0", &["odocal-protocol"][..]),
        ("odocal:/dev/ttyUSB0?baud=9600", &["odocal-protocol"]),
        ("rosbridge://localhost:9090", &["ros"]),
        ("ws://localhost:9090", &["ros"]),
        ("roboclaw:/dev/ttyACM0?address=128", &["roboclaw"]),
        ("mock", &["mock", "odocal-protocol"]),
    ] {
        names(text.parse::<DriveSpec>(), features);
    }
    // A text of no backend's form is the parser's own error, not a feature's.
    let e = "".parse::<DriveSpec>().unwrap_err();
    assert!(matches!(e, SpecError::Parse { .. }), "{e}");
}

#[test]
fn heading_sources_and_stores_of_backends_left_out_name_their_features() {
    names("nmea:/dev/ttyUSB1".parse::<HeadingSpec>(), &["nmea"]);
    assert_eq!("drive".parse::<HeadingSpec>().unwrap(), HeadingSpec::Drive);
    names("profile:robot.toml".parse::<StoreSpec>(), &["roboclaw"]);
    names(StoreSpec::profile(Path::new("robot.toml")), &["roboclaw"]);
    assert_eq!("drive".parse::<StoreSpec>().unwrap(), StoreSpec::Drive);
    names(StoreLocation::parse("ros-yaml:c.yaml", 115_200), &["ros"]);
    names(
        StoreLocation::parse("/dev/ttyUSB0", 115_200),
        &["odocal-protocol"],
    );
    // A drive's text is no store in any build: the parser's own error, not a feature's.
    let e = StoreLocation::parse("rosbridge://h:1", 115_200).unwrap_err();
    assert!(matches!(e, SpecError::Parse { .. }), "{e}");
}

#[test]
fn a_ros_robot_given_with_its_settings_or_flags_names_its_feature() {
    let file = RoutineFile::from_toml(
        "[robot]\ndrive = \"rosbridge://h:1\"\n[robot.ros]\nyaml = \"c.yaml\"\n",
    )
    .unwrap();
    names(file.robot.spec(), &["ros"]);
    let flags = RobotFlags {
        base: Some("rosbridge://h:1".into()),
        ros: RosFlags {
            ros_yaml: Some("c.yaml".into()),
            ..Default::default()
        },
        ..Default::default()
    };
    names(flags.spec(RobotSection::default()), &["ros"]);
    assert_eq!(flags.rosbridge_url(), None);
}

#[tokio::test]
async fn a_heading_sensor_read_alone_names_its_feature() {
    names(open_heading("nmea:/dev/ttyUSB1", 4800).await, &["nmea"]);
    names(
        open_heading("/dev/ttyUSB1", 115_200).await,
        &["odocal-protocol"],
    );
}
