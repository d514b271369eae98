//! The one list of every backend, by kind: drives, heading sources on ports of their own, and
//! stores on their own. A new backend is its module (exporting a [`DriveBackend`],
//! [`HeadingBackend`] or [`StoreBackend`]) plus one line here; the spec parser, the combination
//! rules, the command line's errors and `odocal restore` learn it from these lists.

use crate::base::drive_backend::{DriveBackend, DriveOpen, HeadingPart, OpenDrive, StorePart};
use crate::base::heading_backend::HeadingBackend;
use crate::base::port_spec::PortSpec;
use crate::base::store_backend::StoreBackend;

/// The drives, tried in this order; the one that takes a bare port (odocal's protocol) is
/// also what a text of no other form is.
pub const DRIVE_BACKENDS: &[&DriveBackend] = &[
    &crate::hal::base::DRIVE_BACKEND,
    &crate::ros::live::DRIVE_BACKEND,
    &crate::roboclaw::DRIVE_BACKEND,
    &SIMULATED,
];

/// The heading sources on ports of their own.
pub const HEADING_BACKENDS: &[&HeadingBackend] = &[&crate::nmea::HEADING_BACKEND];

/// The parameter stores that open on their own (`odocal restore --to`, a backup's store).
pub const STORE_BACKENDS: &[&StoreBackend] = &[
    &crate::hal::base::STORE_BACKEND,
    &crate::roboclaw::profile::STORE_BACKEND,
    &crate::ros::yaml::STORE_BACKEND,
];

/// The built-in simulated robot, `mock`: its compass and its parameters are its own settings,
/// so it refuses a heading source, a store, a heading kind, a compass deviation, a baud rate
/// and ROS settings by name rather than ignore them. The command line opens it (as `odocal
/// demo` does); [`crate::spec::BaseSpec::open`] does not.
pub const SIMULATED: DriveBackend = DriveBackend {
    name: "mock",
    what: "the built-in simulated robot",
    form: "mock",
    options: &[],
    recognise: |text| (text == "mock").then(|| Ok(PortSpec::bare("mock"))),
    bare_port: false,
    heading: HeadingPart::OwnOnly,
    store: StorePart::Own,
    settings: None,
    check: |_| Ok(()),
    ready: |_| Ok(()),
    place: |_| "the built-in simulated robot".into(),
    open: |_: DriveOpen| -> OpenDrive {
        Box::pin(async {
            Err(
                "the built-in simulated robot is opened by `odocal demo` or a routine file \
                 with drive = \"mock\""
                    .into(),
            )
        })
    },
};

/// The drive whose heading sensor `odocal heading` reads alone, without the robot (a
/// controller of odocal's protocol: its compass answers over the same link), and the one
/// `status` and `params` talk to.
pub const CONTROLLER: &DriveBackend = &crate::hal::base::DRIVE_BACKEND;

/// The store backend that keeps a drive's robot profile (`profile:PATH`).
pub const PROFILE: &StoreBackend = &crate::roboclaw::profile::STORE_BACKEND;

/// The forms of a list, joined for a message (`a, b or c`).
pub fn forms<'a>(forms: impl IntoIterator<Item = &'a str>) -> String {
    let forms: Vec<&str> = forms.into_iter().collect();
    match forms.split_last() {
        Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
        Some((last, _)) => (*last).to_string(),
        None => String::new(),
    }
}
