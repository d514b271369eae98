//! The one list of every backend, by kind: drives, heading sources on ports of their own, and
//! stores on their own. A new backend is its module (exporting a [`DriveBackend`],
//! [`HeadingBackend`] or [`StoreBackend`]) plus one line here; the spec parser, the combination
//! rules, the command line's errors and `odocal restore` learn it from these lists.

use crate::base::drive_backend::{DriveBackend, DriveOpen, HeadingPart, OpenDrive, StorePart};
use crate::base::heading_backend::HeadingBackend;
use crate::base::port_spec::PortSpec;
use crate::base::store_backend::StoreBackend;
use crate::features::NotBuilt;

/// The drives, tried in this order; the one that takes a bare port (odocal's protocol) is
/// also what a text of no other form is.
pub const DRIVE_BACKENDS: &[&DriveBackend] = &[
    #[cfg(feature = "odocal-protocol")]
    &crate::hal::base::DRIVE_BACKEND,
    #[cfg(feature = "ros")]
    &crate::ros::live::DRIVE_BACKEND,
    #[cfg(feature = "roboclaw")]
    &crate::roboclaw::DRIVE_BACKEND,
    #[cfg(all(feature = "mock", feature = "odocal-protocol"))]
    &SIMULATED,
];

/// The heading sources on ports of their own.
pub const HEADING_BACKENDS: &[&HeadingBackend] = &[
    #[cfg(feature = "nmea")]
    &crate::nmea::HEADING_BACKEND,
];

/// The parameter stores that open on their own (`odocal restore --to`, a backup's store).
pub const STORE_BACKENDS: &[&StoreBackend] = &[
    #[cfg(feature = "odocal-protocol")]
    &crate::hal::base::STORE_BACKEND,
    #[cfg(feature = "roboclaw")]
    &crate::roboclaw::profile::STORE_BACKEND,
    #[cfg(feature = "ros")]
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
    status: None,
};

/// The drive whose heading sensor `odocal heading` reads alone, without the robot (a
/// controller of odocal's protocol: its compass answers over the same link), and the one
/// `status` and `params` talk to.
#[cfg(feature = "odocal-protocol")]
pub const CONTROLLER: &DriveBackend = &crate::hal::base::DRIVE_BACKEND;

/// The store backend that keeps a drive's robot profile (`profile:PATH`), when built.
#[cfg(feature = "roboclaw")]
pub const PROFILE: Option<&StoreBackend> = Some(&crate::roboclaw::profile::STORE_BACKEND);
/// The store backend that keeps a drive's robot profile: not built.
#[cfg(not(feature = "roboclaw"))]
pub const PROFILE: Option<&StoreBackend> = None;

/// Where a text names a backend.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// A drive (`--port`, `--base`, `drive`), or the controller `odocal heading` reads alone.
    Drive,
    /// A heading source on a port of its own (`--heading`, `heading`).
    Heading,
    /// A store (`store`, `--to`, a backup's store).
    Store,
}

/// A backend as the texts that name it, whether this build has it or not: what a text naming
/// one it left out is refused with ([`not_built`]), instead of being read as something else
/// (a `roboclaw:` drive as a serial port, say).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Optional {
    /// What it is, for messages.
    pub what: &'static str,
    /// The features it needs.
    pub features: &'static [&'static str],
    /// Where its texts name it.
    pub roles: &'static [Role],
    /// The schemes of its texts (`rosbridge` of `rosbridge://…`, `profile` of `profile:PATH`).
    pub schemes: &'static [&'static str],
    /// A whole text that names it (`mock`).
    pub exact: Option<&'static str>,
    /// A bare port names it (a text of no other form).
    pub bare_port: bool,
    /// The kind of store its backups record.
    pub store_kind: Option<&'static str>,
    /// This build has it.
    pub built: bool,
}

/// Every backend a feature leaves out, one row per role it plays (the store kinds are the
/// backends' `KIND`s, written here because a backend that is not built cannot be named).
pub const OPTIONAL: &[Optional] = &[
    Optional {
        what: "a controller of odocal's protocol",
        features: &["odocal-protocol"],
        roles: &[Role::Drive, Role::Store],
        schemes: &["odocal"],
        exact: None,
        bare_port: true,
        store_kind: Some("odocal-protocol"),
        built: cfg!(feature = "odocal-protocol"),
    },
    Optional {
        what: "a ROS robot (rosbridge)",
        features: &["ros"],
        roles: &[Role::Drive],
        schemes: &["rosbridge", "ws"],
        exact: None,
        bare_port: false,
        store_kind: None,
        built: cfg!(feature = "ros"),
    },
    Optional {
        what: "a controller's ros2_control YAML",
        features: &["ros"],
        roles: &[Role::Store],
        schemes: &["ros-yaml"],
        exact: None,
        bare_port: false,
        store_kind: Some("ros2-control-yaml"),
        built: cfg!(feature = "ros"),
    },
    Optional {
        what: "a RoboClaw",
        features: &["roboclaw"],
        roles: &[Role::Drive],
        schemes: &["roboclaw"],
        exact: None,
        bare_port: false,
        store_kind: None,
        built: cfg!(feature = "roboclaw"),
    },
    Optional {
        what: "a robot profile",
        features: &["roboclaw"],
        roles: &[Role::Store],
        schemes: &["profile"],
        exact: None,
        bare_port: false,
        store_kind: Some("robot-profile"),
        built: cfg!(feature = "roboclaw"),
    },
    Optional {
        what: "an NMEA 0183 compass",
        features: &["nmea"],
        roles: &[Role::Heading],
        schemes: &["nmea"],
        exact: None,
        bare_port: false,
        store_kind: None,
        built: cfg!(feature = "nmea"),
    },
    Optional {
        what: "the built-in simulated robot",
        features: &["mock", "odocal-protocol"],
        roles: &[Role::Drive],
        schemes: &[],
        exact: Some("mock"),
        bare_port: false,
        store_kind: None,
        built: cfg!(all(feature = "mock", feature = "odocal-protocol")),
    },
];

impl Optional {
    /// `text` names this backend by its scheme or whole (not by being a bare port).
    pub fn names(&self, text: &str) -> bool {
        let scheme = text.split_once(':').map(|(s, _)| s);
        self.exact == Some(text) || self.schemes.iter().any(|s| scheme == Some(*s))
    }

    /// The error for `text`, which names this backend.
    fn refusal(&self, text: &str) -> NotBuilt {
        NotBuilt::new(format!("`{text}` ({})", self.what), self.features)
    }
}

/// `text` names (by scheme or whole) a backend of `table` that is not built, in any role: it is
/// not a bare port.
pub fn names_one_left_out(table: &[Optional], text: &str) -> bool {
    table.iter().any(|b| !b.built && b.names(text.trim()))
}

/// Why `text`, given as a `role`, cannot be read in this build, when it names (by scheme or
/// whole) a backend of `table` for that role that is not built.
pub fn not_built(table: &[Optional], role: Role, text: &str) -> Option<NotBuilt> {
    let text = text.trim();
    table
        .iter()
        .find(|b| !b.built && b.roles.contains(&role) && b.names(text))
        .map(|b| b.refusal(text))
}

/// Why the bare port `text` cannot be read in this build: the backend of bare ports in
/// `table` is not built.
pub fn bare_port_not_built(table: &[Optional], text: &str) -> Option<NotBuilt> {
    let text = text.trim();
    table
        .iter()
        .find(|b| !b.built && b.bare_port)
        .map(|b| b.refusal(text))
}

/// Why a backup of store kind `kind` cannot be opened in this build.
pub fn store_kind_not_built(table: &[Optional], kind: &str) -> Option<NotBuilt> {
    table
        .iter()
        .find(|b| !b.built && b.store_kind == Some(kind))
        .map(|b| {
            NotBuilt::new(
                format!("a backup of a {kind} store ({})", b.what),
                b.features,
            )
        })
}

/// Why `needed` (a heading source a drive needs, say) cannot be given in this build: every
/// backend of `role` in `table` is left out; the features of the first.
pub fn role_not_built(table: &[Optional], role: Role, needed: &str) -> Option<NotBuilt> {
    let mut of_role = table.iter().filter(|b| b.roles.contains(&role));
    let first = of_role.clone().next()?;
    of_role
        .all(|b| !b.built)
        .then(|| NotBuilt::new(needed, first.features))
}

/// The forms of a list, joined for a message (`a, b or c`).
pub fn forms<'a>(forms: impl IntoIterator<Item = &'a str>) -> String {
    let forms: Vec<&str> = forms.into_iter().collect();
    match forms.split_last() {
        Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
        Some((last, _)) => (*last).to_string(),
        None => String::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Texts of each optional backend, where they name it, and the feature each needs.
    const TEXTS: [(&str, Role, &[&str]); 9] = [
        ("rosbridge://h:1", Role::Drive, &["ros"]),
        ("ws://h:1", Role::Drive, &["ros"]),
        ("ros-yaml:c.yaml", Role::Store, &["ros"]),
        ("roboclaw:/dev/x", Role::Drive, &["roboclaw"]),
        ("profile:r.toml", Role::Store, &["roboclaw"]),
        ("nmea:/dev/y", Role::Heading, &["nmea"]),
        ("odocal:/dev/z", Role::Drive, &["odocal-protocol"]),
        ("odocal:/dev/z", Role::Store, &["odocal-protocol"]),
        ("mock", Role::Drive, &["mock", "odocal-protocol"]),
    ];

    /// The table and the backends of the full build agree both ways: each text of [`TEXTS`]
    /// is read by a built backend of its role, and each built backend's scheme (or name) is
    /// in a row of the table with that role.
    #[cfg(all(
        feature = "odocal-protocol",
        feature = "ros",
        feature = "roboclaw",
        feature = "nmea",
        feature = "mock"
    ))]
    #[test]
    fn the_table_and_the_built_backends_agree() {
        let scheme = |text: &str| text.split_once(':').map(|(s, _)| s.to_string());
        for (text, role, _) in TEXTS {
            assert!(OPTIONAL.iter().any(|b| b.built && b.names(text)), "{text}");
            let read = match role {
                Role::Drive => DRIVE_BACKENDS.iter().any(|b| (b.recognise)(text).is_some()),
                Role::Heading => HEADING_BACKENDS
                    .iter()
                    .any(|b| scheme(text).as_deref() == Some(b.scheme)),
                Role::Store => STORE_BACKENDS
                    .iter()
                    .any(|b| scheme(text).as_deref() == Some(b.scheme)),
            };
            assert!(read, "{text} is no built backend's {role:?}");
        }
        let row = |role: Role, text: String| {
            OPTIONAL
                .iter()
                .any(|b| b.roles.contains(&role) && b.names(&text))
        };
        for b in DRIVE_BACKENDS {
            let named =
                row(Role::Drive, format!("{}:x", b.name)) || row(Role::Drive, b.name.into());
            assert!(named, "drive {} has no row", b.name);
        }
        for b in HEADING_BACKENDS {
            assert!(
                row(Role::Heading, format!("{}:x", b.scheme)),
                "heading {}",
                b.scheme
            );
        }
        for b in STORE_BACKENDS {
            assert!(
                row(Role::Store, format!("{}:x", b.scheme)),
                "store {}",
                b.scheme
            );
            let kind = OPTIONAL.iter().any(|o| o.store_kind == Some(b.kind));
            assert!(kind, "store kind {}", b.kind);
        }
        assert!(not_built(OPTIONAL, Role::Drive, "rosbridge://h:1").is_none());
        assert!(bare_port_not_built(OPTIONAL, "/dev/ttyUSB0").is_none());
        assert!(role_not_built(OPTIONAL, Role::Heading, "a compass").is_none());
    }

    /// With every backend left out, each text is refused with the feature it needs where it
    /// names a backend, and not where it does not (a drive's text as a store); a text of no
    /// backend's form is left to the parser's own message.
    #[test]
    fn a_text_of_a_backend_left_out_names_its_feature() {
        let none: Vec<Optional> = OPTIONAL
            .iter()
            .map(|b| Optional { built: false, ..*b })
            .collect();
        for (text, role, features) in TEXTS {
            let e = not_built(&none, role, text).unwrap();
            assert_eq!(e.features, features, "{text}");
            assert!(e.to_string().starts_with(&format!("`{text}` (")), "{e}");
            assert!(names_one_left_out(&none, text), "{text}");
        }
        assert!(not_built(&none, Role::Store, "roboclaw:/dev/x").is_none());
        assert!(not_built(&none, Role::Drive, "profile:r.toml").is_none());
        assert!(not_built(&none, Role::Drive, "nmea:/dev/y").is_none());
        let bare = bare_port_not_built(&none, "/dev/ttyUSB0").unwrap();
        assert_eq!(bare.features, ["odocal-protocol"]);
        assert!(not_built(&none, Role::Drive, "/dev/ttyUSB0").is_none());
        assert!(!names_one_left_out(&none, "serial:/dev/x"));
        let kind = store_kind_not_built(&none, "robot-profile").unwrap();
        assert_eq!(kind.features, ["roboclaw"]);
        assert!(store_kind_not_built(&none, "simulated").is_none());
        let compass = role_not_built(&none, Role::Heading, "a heading source").unwrap();
        assert_eq!(compass.features, ["nmea"]);
    }
}
