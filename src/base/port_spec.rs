//! A backend's target as text gives it: `scheme:PORT?key=value&…`, split into the port (a
//! device path, a file, a URL) and the options the backend lists. Drives, heading sources and
//! stores on their own all share this form ([`super::drive_backend`],
//! [`super::heading_backend`], [`super::store_backend`]); each backend types its own options
//! from it, so an option that was given is a key here, never a substring of the text.

use std::collections::BTreeMap;
use std::str::FromStr;

/// A port and its options, as `scheme:PORT?k=v&k=v` gives them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PortSpec {
    /// The port (a device path, a file, a URL).
    pub port: String,
    /// Options by key (only keys the backend lists).
    pub options: BTreeMap<String, String>,
}

impl PortSpec {
    /// A port without options.
    pub fn bare(port: impl Into<String>) -> Self {
        PortSpec {
            port: port.into(),
            options: BTreeMap::new(),
        }
    }

    /// Splits `text` when it starts with `scheme:`; `None` when it does not. Only `allowed`
    /// keys are taken; a backend that takes no option gets the whole rest as its port (a file
    /// name may hold a `?`). An error says what is wrong (the caller names the text).
    pub fn parse(text: &str, scheme: &str, allowed: &[&str]) -> Option<Result<Self, String>> {
        let rest = text.strip_prefix(scheme)?.strip_prefix(':')?;
        Some(Self::split(rest, scheme, allowed))
    }

    /// `PORT?k=v&…` split into the port and the `allowed` options.
    pub fn split(rest: &str, scheme: &str, allowed: &[&str]) -> Result<Self, String> {
        let (path, query) = match allowed.is_empty() {
            true => (rest, ""),
            false => rest.split_once('?').unwrap_or((rest, "")),
        };
        if path.is_empty() {
            return Err(format!("nothing after {scheme}: (give the port or file)"));
        }
        let mut options = BTreeMap::new();
        for kv in query.split('&').filter(|s| !s.is_empty()) {
            let (k, v) = kv
                .split_once('=')
                .ok_or_else(|| format!("option {kv:?} is not key=value"))?;
            if !allowed.contains(&k) {
                return Err(format!(
                    "unknown option {k} (options: {})",
                    allowed.join(", ")
                ));
            }
            options.insert(k.to_string(), v.to_string());
        }
        Ok(PortSpec {
            port: path.to_string(),
            options,
        })
    }

    /// Option `key` as a `T`, or `default` when it is not given; an error names the option.
    pub fn option<T: FromStr>(&self, key: &str, default: T) -> Result<T, String> {
        match self.options.get(key) {
            None => Ok(default),
            Some(v) => v
                .parse()
                .map_err(|_| format!("{key}={v} is not a number in range")),
        }
    }

    /// Sets option `key` to `value` unless the text gave it (a flag's default under the
    /// text's own).
    pub fn or_option(&mut self, key: &str, value: impl ToString) {
        self.options
            .entry(key.to_string())
            .or_insert_with(|| value.to_string());
    }

    /// The text form `scheme:PORT?k=v&…` (options in key order).
    pub fn text(&self, scheme: &str) -> String {
        let query: Vec<String> = self
            .options
            .iter()
            .map(|(k, v)| format!("{k}={v}"))
            .collect();
        match query.is_empty() {
            true => format!("{scheme}:{}", self.port),
            false => format!("{scheme}:{}?{}", self.port, query.join("&")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ports_and_options_split_and_print_back() {
        let s = PortSpec::parse("x:/dev/a?baud=9600&address=129", "x", &["baud", "address"])
            .unwrap()
            .unwrap();
        assert_eq!(s.port, "/dev/a");
        assert_eq!(s.option("baud", 0u32), Ok(9600));
        assert_eq!(s.option("address", 0u8), Ok(129));
        assert_eq!(s.text("x"), "x:/dev/a?address=129&baud=9600");
        assert!(PortSpec::parse("y:/dev/a", "x", &[]).is_none());
        assert!(PortSpec::parse("x:", "x", &[]).unwrap().is_err());
        let e = PortSpec::parse("x:/a?speed=3", "x", &["baud"])
            .unwrap()
            .unwrap_err();
        assert!(e.contains("unknown option speed"), "{e}");
        assert!(s.option::<u8>("baud", 0).is_err());
        // A backend without options keeps a `?` in its file name.
        let f = PortSpec::parse("x:/r/what?.toml", "x", &[])
            .unwrap()
            .unwrap();
        assert_eq!(f.port, "/r/what?.toml");
        let mut d = PortSpec::bare("/dev/a");
        d.or_option("baud", 57_600);
        let mut given = s.clone();
        given.or_option("baud", 57_600);
        assert_eq!(
            (d.option("baud", 0u32), given.option("baud", 0u32)),
            (Ok(57_600), Ok(9600))
        );
    }
}
