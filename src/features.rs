//! The error that names a Cargo feature this build left out. Each
//! backend is a feature (all on by default); a text that names a backend this build left out —
//! a drive, a heading source, a store, a bag's storage or compression — is refused with
//! [`NotBuilt`], which says which feature to turn on, rather than read as something else.

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
