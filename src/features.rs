//! The error that names a Cargo feature this build left out. Each
//! backend is a feature (all on by default); a text that names a backend this build left out —
//! a drive, a heading source, a store, a bag's storage or compression — is refused with
//! [`NotBuilt`], which says which feature to turn on, rather than read as something else.
//! The command line leaves out the commands and flags of a backend it was built without;
//! [`left_out`] names the feature of one a user typed.

/// The commands and flags of the command line that a build may leave out, with the features
/// each needs (a flag's name is the same in every command that has it).
pub const COMMAND_LINE: &[(&str, &[&str])] = &[
    ("demo", &["mock", "odocal-protocol"]),
    ("mock-device", &["mock", "odocal-protocol"]),
    ("kit-device", &["mock", "odocal-protocol"]),
    ("params", &["odocal-protocol"]),
    ("conformance", &["conformance"]),
    ("export", &["ros"]),
    ("bag", &["ros"]),
    ("mock-rosbridge", &["mock", "ros"]),
    ("mock-roboclaw", &["mock", "roboclaw"]),
    ("ports", &["serial"]),
    // `fit`'s bag (and how it reads one) and controller YAML; `simulate` and `replay` write
    // bags.
    ("--bag", &["ros"]),
    ("--reference", &["ros"]),
    ("--base-frame", &["ros"]),
    ("--joint-states-topic", &["ros"]),
    ("--left-joint", &["ros"]),
    ("--right-joint", &["ros"]),
    ("--ros-yaml", &["ros"]),
    ("--controller", &["ros"]),
    ("--write-bag", &["ros"]),
];

/// Each feature and whether this build has it.
const FEATURES: &[(&str, bool)] = &[
    ("odocal-protocol", cfg!(feature = "odocal-protocol")),
    ("ros", cfg!(feature = "ros")),
    ("bag-sqlite", cfg!(feature = "bag-sqlite")),
    ("bag-compression", cfg!(feature = "bag-compression")),
    ("roboclaw", cfg!(feature = "roboclaw")),
    ("nmea", cfg!(feature = "nmea")),
    ("mock", cfg!(feature = "mock")),
    ("conformance", cfg!(feature = "conformance")),
    ("serial", cfg!(feature = "serial")),
];

/// Whether this build has the feature `name` (`false` for a name that is not a feature).
pub fn built(name: &str) -> bool {
    FEATURES.iter().any(|(feature, on)| *feature == name && *on)
}

/// `Err` naming the features of the flag `word` of [`COMMAND_LINE`] when it was `given` and
/// this build left it out (a flag a build keeps so that it can say so).
pub fn refuse_if_left_out(word: &str, given: bool) -> Result<(), NotBuilt> {
    match left_out(word) {
        Some(not_built) if given => Err(not_built),
        _ => Ok(()),
    }
}

/// The command or flag `word` (as typed: `bag`, `--write-bag`, `--bag=x.mcap`) of
/// [`COMMAND_LINE`] that this build left out, with the features it needs; `None` for a word
/// this build has, or no build has (the parser's own error says that).
pub fn left_out(word: &str) -> Option<NotBuilt> {
    let name = word.split('=').next().unwrap_or(word);
    let (_, features) = COMMAND_LINE.iter().find(|(n, _)| *n == name)?;
    let missing = features.iter().any(|f| !built(f));
    let what = if name.starts_with("--") {
        format!("the flag `{name}`")
    } else {
        format!("`odocal {name}`")
    };
    missing.then(|| NotBuilt::new(what, features))
}

/// The command or flag the parser's error `e` is about, when this build left it out
/// ([`left_out`]): an unknown command or flag may be one of a backend this build lacks.
#[cfg(feature = "cli")]
pub fn left_out_in(e: &clap::Error) -> Option<NotBuilt> {
    left_out(typed(e)?)
}

/// The unknown command or flag the parser's error `e` names, as typed (a flag without its
/// value).
#[cfg(feature = "cli")]
fn typed(e: &clap::Error) -> Option<&str> {
    use clap::error::{ContextKind, ContextValue};
    let word = |kind| match e.get(kind) {
        Some(ContextValue::String(word)) => Some(word.as_str()),
        _ => None,
    };
    // A stray word where no command is taken is not a command left out: only flags there.
    (word(ContextKind::InvalidSubcommand))
        .or_else(|| word(ContextKind::InvalidArg).filter(|w| w.starts_with("--")))
}

/// Something this build of odocal cannot do because it was built without `features`.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error(
    "{what} needs {}, which this odocal was built without: rebuild it with `--features {}` \
     (the default features have every backend)",
    needs(features),
    features.join(",")
)]
pub struct NotBuilt {
    /// What was asked for, as the user gave it (a spec, a flag, a file's format).
    pub what: String,
    /// The features it needs, all of them.
    pub features: &'static [&'static str],
}

impl NotBuilt {
    /// `what` needs `features`.
    pub fn new(what: impl Into<String>, features: &'static [&'static str]) -> Self {
        Self {
            what: what.into(),
            features,
        }
    }
}

/// "the `ros` feature", "the `mock` and `odocal-protocol` features".
fn needs(features: &[&str]) -> String {
    let quoted: Vec<String> = features.iter().map(|f| format!("`{f}`")).collect();
    match quoted.split_last() {
        Some((last, [])) => format!("the {last} feature"),
        Some((last, rest)) => format!("the {} and {last} features", rest.join(", ")),
        None => "a feature".to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_feature_a_command_needs_is_one_and_a_left_out_word_is_named() {
        for (name, features) in COMMAND_LINE {
            for f in *features {
                let declared = format!("\n{f} = [");
                assert!(
                    include_str!("../Cargo.toml").contains(&declared),
                    "{name}: {f} is not a feature of Cargo.toml"
                );
            }
            // Left out exactly when one of its features is.
            let out = !features.iter().all(|f| built(f));
            assert_eq!(left_out(name).is_some(), out, "{name}");
        }
        for (feature, _) in FEATURES {
            let declared = format!("\n{feature} = [");
            assert!(
                include_str!("../Cargo.toml").contains(&declared),
                "{feature}"
            );
        }
        assert!(!built("no-such-feature"));
        assert_eq!(left_out("no-such-command"), None);
        assert_eq!(left_out("--no-such-flag"), None);
    }

    #[cfg(feature = "cli")]
    #[test]
    fn the_parser_names_the_unknown_command_or_flag_as_typed() {
        let cli = || {
            clap::Command::new("odocal")
                .subcommand_required(true)
                .subcommand(clap::Command::new("fit").arg(clap::arg!(--json)))
        };
        let e = cli()
            .try_get_matches_from(["odocal", "bag", "x.mcap"])
            .unwrap_err();
        assert_eq!(typed(&e), Some("bag"), "{e}");
        let e = cli()
            .try_get_matches_from(["odocal", "fit", "--write-bag=a.mcap"])
            .unwrap_err();
        // (The flag without its value.)
        assert_eq!(typed(&e), Some("--write-bag"), "{e}");
        // A stray word, even one that names a command left out, is the parser's own error.
        let e = cli()
            .try_get_matches_from(["odocal", "fit", "bag"])
            .unwrap_err();
        assert_eq!(typed(&e), None, "{e}");
        assert_eq!(left_out_in(&e), None);
    }

    #[cfg(not(feature = "ros"))]
    #[test]
    fn a_flag_with_its_value_is_named_without_it() {
        let e = left_out("--write-bag=run.mcap").unwrap();
        assert!(e
            .to_string()
            .starts_with("the flag `--write-bag` needs the `ros` feature"));
        assert_eq!(refuse_if_left_out("--bag", false), Ok(()));
        assert!(refuse_if_left_out("--bag", true).is_err());
        let e = left_out("bag").unwrap();
        assert!(
            e.to_string()
                .starts_with("`odocal bag` needs the `ros` feature"),
            "{e}"
        );
    }

    #[test]
    fn the_message_names_the_feature_and_how_to_turn_it_on() {
        let e = NotBuilt::new("`rosbridge://localhost:9090`", &["ros"]);
        assert_eq!(
            e.to_string(),
            "`rosbridge://localhost:9090` needs the `ros` feature, which this odocal was built \
             without: rebuild it with `--features ros` (the default features have every backend)"
        );
        let two = NotBuilt::new("`mock`", &["mock", "odocal-protocol"]);
        assert!(
            two.to_string()
                .starts_with("`mock` needs the `mock` and `odocal-protocol` features,"),
            "{two}"
        );
        assert!(two
            .to_string()
            .contains("`--features mock,odocal-protocol`"));
    }
}
