//! A robot profile: the TOML file that holds the geometry of a robot whose controller knows
//! none (a RoboClaw counts encoder ticks), how it is wired, and its limits — and, as a
//! [`crate::base::ParamStore`], where a calibration writes back.
//!
//! ```toml
//! [geometry]
//! left_wheel_diameter_m = 0.15
//! right_wheel_diameter_m = 0.15
//! wheelbase_m = 0.39
//! encoder_counts_per_motor_rev = 1024   # quadrature counts per motor shaft revolution
//! gear_ratio = 4.0                      # motor revolutions per wheel revolution
//!
//! [wiring]
//! left_channel = "M1"                   # the RoboClaw channel of the left wheel
//! left_encoder_sign = 1                 # -1 when the left encoder counts down driving forward
//! right_encoder_sign = 1
//!
//! [limits]
//! max_speed_m_s = 0.5
//! max_accel_m_s2 = 0.5
//! min_battery_v = 10.5
//!
//! [heading]                             # optional: what `odocal swing --save` measured
//! kind = "magnetic"
//! compass_deviation_deg = [1.5, -2.0, 0.5, 1.0]   # A1, B1, A2, B2 (kinematics::Deviation)
//! ```
//!
//! Writing back changes only the three geometry values (or, for a swing, the `[heading]`
//! table), in place (comments and everything else stay, `toml_edit`), after a backup of the
//! whole file beside it (the one backup format, [`crate::base::transaction`]), and replaces it
//! atomically.

use crate::base::port_spec::PortSpec;
use crate::base::store_backend::{OpenStore, StoreBackend};
use crate::base::write::{
    write_once, Bounds, Commit, Question, Unattended, WriteError, WritePolicy, WriteRequest,
};
use crate::base::{FileStore, HeadingKind, ParamFile, ParamStore};
use crate::kinematics::{Deviation, WheelParams};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// A profile that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ProfileError {
    /// Reading or writing failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// The rewrite failed: before anything was written, or after the backup (what the file
    /// holds then is said).
    #[error("{}: {source}", path.display())]
    Write {
        /// The profile.
        path: PathBuf,
        /// Why, and what became of the file.
        #[source]
        source: Box<crate::base::write::WriteError>,
    },
    /// Not a valid profile.
    #[error("{}: {message}", path.display())]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong (with the line where TOML gives one).
        message: String,
    },
}

/// A RoboClaw channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Channel {
    /// Motor 1.
    M1,
    /// Motor 2.
    M2,
}

/// The geometry.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Geometry {
    /// Left wheel diameter (m).
    pub left_wheel_diameter_m: f64,
    /// Right wheel diameter (m).
    pub right_wheel_diameter_m: f64,
    /// Wheelbase (m).
    pub wheelbase_m: f64,
    /// Encoder counts per motor revolution (quadrature).
    pub encoder_counts_per_motor_rev: f64,
    /// Motor revolutions per wheel revolution.
    #[serde(default = "one")]
    pub gear_ratio: f64,
}

fn one() -> f64 {
    1.0
}

/// How the robot is wired.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Wiring {
    /// The left wheel's channel (the right wheel has the other).
    pub left_channel: Channel,
    /// +1 when the left encoder counts up driving forward, -1 when it counts down.
    #[serde(default = "plus")]
    pub left_encoder_sign: i8,
    /// The same for the right encoder.
    #[serde(default = "plus")]
    pub right_encoder_sign: i8,
}

fn plus() -> i8 {
    1
}

/// Motion limits.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Limits {
    /// Fastest wheel speed any motion may command (m/s).
    pub max_speed_m_s: f64,
    /// Acceleration of every motion (m/s²).
    pub max_accel_m_s2: f64,
    /// Battery voltage below which pre-flight refuses to move (V).
    pub min_battery_v: Option<f64>,
}

/// What the profile says of the robot's heading sensor: applied whenever the robot is opened
/// with this profile (a flag overrides it).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeadingSection {
    /// What the sensor is.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kind: Option<HeadingKind>,
    /// The compass's deviation A1, B1, A2, B2 (deg), removed from every reading.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub compass_deviation_deg: Option<[f64; 4]>,
}

impl HeadingSection {
    /// The deviation in radians (zero when none is given).
    pub fn deviation(&self) -> Deviation {
        Deviation(
            self.compass_deviation_deg
                .unwrap_or_default()
                .map(f64::to_radians),
        )
    }
}

/// A robot profile.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Profile {
    /// Geometry.
    pub geometry: Geometry,
    /// Wiring.
    pub wiring: Wiring,
    /// Limits.
    pub limits: Limits,
    /// The heading sensor, when known.
    #[serde(default)]
    pub heading: HeadingSection,
}

impl Profile {
    /// Parses and checks a profile (`path` names the file in errors).
    pub fn parse(text: &str, path: &Path) -> Result<Self, ProfileError> {
        let invalid = |message: String| ProfileError::Invalid {
            path: path.to_path_buf(),
            message,
        };
        let p: Profile = toml::from_str(text).map_err(|e| {
            let line = e
                .span()
                .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1);
            invalid(match line {
                Some(l) => format!("line {l}: {}", e.message()),
                None => e.message().to_string(),
            })
        })?;
        p.params().validate().map_err(|e| invalid(e.to_string()))?;
        let g = &p.geometry;
        if !(g.encoder_counts_per_motor_rev.is_finite() && g.encoder_counts_per_motor_rev >= 1.0) {
            return Err(invalid(
                "geometry.encoder_counts_per_motor_rev must be ≥ 1".into(),
            ));
        }
        if !(g.gear_ratio.is_finite() && (0.01..=1000.0).contains(&g.gear_ratio)) {
            return Err(invalid(
                "geometry.gear_ratio must be in [0.01, 1000]".into(),
            ));
        }
        // The ranges every parameter file must meet: no 1 nm wheel, no 2^63 counts.
        p.params()
            .check_physical()
            .map_err(|e| invalid(format!("geometry: {e}")))?;
        for (k, s) in [
            ("left", p.wiring.left_encoder_sign),
            ("right", p.wiring.right_encoder_sign),
        ] {
            if s != 1 && s != -1 {
                return Err(invalid(format!(
                    "wiring.{k}_encoder_sign must be 1 or -1, got {s}"
                )));
            }
        }
        if let Some(d) = p.heading.compass_deviation_deg {
            if !d.iter().all(|c| c.is_finite() && c.abs() <= 45.0) {
                return Err(invalid(
                    "heading.compass_deviation_deg must be four numbers within ±45°".into(),
                ));
            }
        }
        let l = &p.limits;
        if !(l.max_speed_m_s.is_finite() && l.max_speed_m_s > 0.0 && l.max_speed_m_s <= 5.0) {
            return Err(invalid("limits.max_speed_m_s must be in (0, 5] m/s".into()));
        }
        if !(l.max_accel_m_s2.is_finite() && l.max_accel_m_s2 > 0.0 && l.max_accel_m_s2 <= 20.0) {
            return Err(invalid(
                "limits.max_accel_m_s2 must be in (0, 20] m/s²".into(),
            ));
        }
        if let Some(v) = l.min_battery_v {
            if !(v.is_finite() && (0.0..=100.0).contains(&v)) {
                return Err(invalid(format!(
                    "limits.min_battery_v must be in [0, 100] V, got {v}"
                )));
            }
        }
        Ok(p)
    }

    /// Reads a profile file (at most 1 MiB).
    pub fn load(path: &Path) -> Result<Self, ProfileError> {
        Self::parse(&read_bounded(path)?, path)
    }

    /// The wheel parameters (counts per wheel revolution = encoder counts × gear ratio).
    pub fn params(&self) -> WheelParams {
        let g = &self.geometry;
        WheelParams {
            left_wheel_diameter_m: g.left_wheel_diameter_m,
            right_wheel_diameter_m: g.right_wheel_diameter_m,
            wheelbase_m: g.wheelbase_m,
            counts_per_wheel_rev: g.encoder_counts_per_motor_rev * g.gear_ratio,
        }
    }
}

fn read_bounded(path: &Path) -> Result<String, ProfileError> {
    crate::io::read_bounded(path, crate::io::MAX_TEXT_FILE).map_err(|source| ProfileError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// The profile's text as an editable document (comments and layout kept).
fn document(text: &str, path: &Path) -> Result<toml_edit::DocumentMut, ProfileError> {
    text.parse()
        .map_err(|e: toml_edit::TomlError| ProfileError::Invalid {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
}

/// `text` with the geometry set to `p`'s diameters and wheelbase, everything else untouched.
pub fn with_geometry(text: &str, p: &WheelParams, path: &Path) -> Result<String, ProfileError> {
    let invalid = |message: String| ProfileError::Invalid {
        path: path.to_path_buf(),
        message,
    };
    let mut doc = document(text, path)?;
    let g = doc
        .get_mut("geometry")
        .and_then(|g| g.as_table_like_mut())
        .ok_or_else(|| invalid("no [geometry] table".into()))?;
    for (k, v) in [
        ("left_wheel_diameter_m", p.left_wheel_diameter_m),
        ("right_wheel_diameter_m", p.right_wheel_diameter_m),
        ("wheelbase_m", p.wheelbase_m),
    ] {
        // Twelve significant digits: far below a micrometre, and readable.
        let rounded: f64 = format!("{v:.12e}").parse().unwrap_or(v);
        match g.get_mut(k).and_then(|item| item.as_value_mut()) {
            Some(value) => {
                let decor = value.decor().clone();
                *value = toml_edit::Value::from(rounded);
                *value.decor_mut() = decor;
            }
            None => {
                g.insert(k, toml_edit::value(rounded));
            }
        }
    }
    let out = doc.to_string();
    // What was written must read back as a profile with these values.
    let back = Profile::parse(&out, path)?.params();
    if (back.wheelbase_m - p.wheelbase_m).abs() > 1e-9 {
        return Err(invalid("the rewritten profile does not read back".into()));
    }
    Ok(out)
}

/// `text` with its `[heading]` table set to `heading` (other keys of that table, comments and
/// every other table untouched).
pub fn with_heading(
    text: &str,
    heading: &HeadingSection,
    path: &Path,
) -> Result<String, ProfileError> {
    let invalid = |message: String| ProfileError::Invalid {
        path: path.to_path_buf(),
        message,
    };
    let mut doc = document(text, path)?;
    let table = doc
        .entry("heading")
        .or_insert(toml_edit::table())
        .as_table_like_mut()
        .ok_or_else(|| invalid("heading: must be a table ([heading])".into()))?;
    if let Some(kind) = heading.kind {
        table.insert("kind", toml_edit::value(kind.name()));
    }
    if let Some(d) = heading.compass_deviation_deg {
        let mut array = toml_edit::Array::new();
        for c in d {
            // Thousandths of a degree: the fit is not better.
            array.push((c * 1000.0).round() / 1000.0);
        }
        table.insert("compass_deviation_deg", toml_edit::value(array));
    }
    let out = doc.to_string();
    let back = Profile::parse(&out, path)?;
    if back.params() != Profile::parse(text, path)?.params() {
        return Err(invalid("the rewritten profile does not read back".into()));
    }
    Ok(out)
}

impl HeadingSection {
    /// The table a compass swing keeps: the whole deviation curve (what was already removed
    /// and what the swing found), and the kind when the sensor is magnetic.
    pub fn of_swing(kind: HeadingKind, deviation_deg: [f64; 4]) -> Self {
        HeadingSection {
            kind: (kind == HeadingKind::Magnetic).then_some(kind),
            compass_deviation_deg: Some(deviation_deg),
        }
    }
}

/// **Rewrites the profile at `path`** with its `[heading]` table set to `heading`: the file
/// is backed up beside itself first (a backup `odocal restore` takes, never replacing an
/// earlier one), then replaced atomically. Returns the backup's path.
pub async fn save_heading(path: &Path, heading: &HeadingSection) -> Result<PathBuf, ProfileError> {
    let text = read_bounded(path)?;
    let out = crate::io::keep_text_form(&text, &with_heading(&text, heading, path)?);
    let store = std::sync::Arc::new(ProfileStore::open(path)?);
    // The geometry stays; the whole file is the write (backed up, replaced, read back, put
    // back on failure: the write service).
    let current = store.read().await.map_err(|e| ProfileError::Write {
        path: path.to_path_buf(),
        source: Box::new(WriteError::Base(e)),
    })?;
    let request = WriteRequest {
        new: current,
        bounds: Bounds::Physical,
        policy: WritePolicy::Yes,
        commit: Commit::WholeFile(out),
        backup_dir: crate::io::dir_of(path),
        question: Question::Plain(String::new()),
    };
    match write_once(store, None, request, &mut Unattended).await {
        Ok(done) => Ok(done.backup),
        Err(e) => Err(ProfileError::Write {
            path: path.to_path_buf(),
            source: Box::new(e),
        }),
    }
}

/// The kind a robot profile gives in its descriptions (and backups).
pub const KIND: &str = "robot-profile";

/// A robot profile as a store on its own: `profile:PATH`.
pub const STORE_BACKEND: StoreBackend = StoreBackend {
    kind: KIND,
    what: "a robot profile",
    scheme: "profile",
    form: "profile:PATH",
    options: &[],
    bare_port: false,
    complete: |_| Ok(()),
    of_backup: |_, file| {
        let file = file.ok_or("which file")?;
        let name = file.to_str().ok_or("a file name that is UTF-8")?;
        Ok(PortSpec::bare(name))
    },
    show: |spec| spec.text("profile"),
    open: |spec: PortSpec| -> OpenStore {
        Box::pin(async move {
            Ok(
                std::sync::Arc::new(ProfileStore::open(Path::new(&spec.port))?)
                    as std::sync::Arc<dyn ParamStore>,
            )
        })
    },
};

/// The profile's format for a [`FileStore`]: its geometry is the parameters, the wiring and
/// limits come along for the drive.
#[derive(Debug, Clone, Copy, Default)]
pub struct ProfileFile;

impl ParamFile for ProfileFile {
    type Content = Profile;
    type Error = ProfileError;

    fn kind(&self) -> &'static str {
        KIND
    }

    fn written_keys(&self) -> &'static [&'static str] {
        &[
            "left_wheel_diameter_m",
            "right_wheel_diameter_m",
            "wheelbase_m",
        ]
    }

    fn id(&self, path: &Path) -> String {
        path.display().to_string()
    }

    fn details(&self, path: &Path) -> serde_json::Value {
        serde_json::json!({ "file": path })
    }

    fn parse(&self, text: &str, path: &Path) -> Result<Profile, ProfileError> {
        Profile::parse(text, path)
    }

    fn params(content: &Profile) -> WheelParams {
        content.params()
    }

    fn render(
        &self,
        text: &str,
        params: &WheelParams,
        path: &Path,
    ) -> Result<String, ProfileError> {
        with_geometry(text, params, path)
    }

    fn refuse(&self, current: &WheelParams, params: &WheelParams) -> Option<String> {
        ((params.counts_per_wheel_rev - current.counts_per_wheel_rev).abs() > 1e-9).then(|| {
            "encoder resolution and gearing are not calibrated: counts per revolution must stay"
                .into()
        })
    }

    fn io_error(&self, path: &Path, source: std::io::Error) -> ProfileError {
        ProfileError::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// The profile as a [`crate::base::ParamStore`]: `write` stages (and updates the profile a
/// drive counts with), `commit` rewrites the file ([`FileStore`]).
pub type ProfileStore = FileStore<ProfileFile>;

impl FileStore<ProfileFile> {
    /// Opens a profile.
    pub fn open(path: &Path) -> Result<Self, ProfileError> {
        FileStore::with_format(ProfileFile, path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) const EXAMPLE: &str = "\
# my robot
[geometry]
left_wheel_diameter_m = 0.15   # measured with calipers
right_wheel_diameter_m = 0.15
wheelbase_m = 0.39
encoder_counts_per_motor_rev = 1024
gear_ratio = 4.0

[wiring]
left_channel = \"M1\"
left_encoder_sign = 1
right_encoder_sign = -1

[limits]
max_speed_m_s = 0.5
max_accel_m_s2 = 0.5
min_battery_v = 10.5
";

    #[test]
    fn profiles_read_check_and_rewrite_only_the_geometry() {
        let path = Path::new("robot.toml");
        let p = Profile::parse(EXAMPLE, path).unwrap();
        assert_eq!(p.params().counts_per_wheel_rev, 4096.0);
        assert_eq!(p.wiring.right_encoder_sign, -1);
        let mut new = p.params();
        new.wheelbase_m = 0.380_638;
        new.right_wheel_diameter_m = 0.148_789;
        let out = with_geometry(EXAMPLE, &new, path).unwrap();
        assert!(
            out.contains("left_wheel_diameter_m = 0.15   # measured with calipers"),
            "{out}"
        );
        assert!(out.contains("wheelbase_m = 0.380638"), "{out}");
        assert!(
            out.contains("# my robot") && out.contains("min_battery_v = 10.5"),
            "{out}"
        );
        assert_eq!(p.heading, HeadingSection::default());
        let bad = EXAMPLE.replace("right_encoder_sign = -1", "right_encoder_sign = 2");
        let e = Profile::parse(&bad, path).unwrap_err().to_string();
        assert!(e.contains("right_encoder_sign"), "{e}");
        let e = Profile::parse("[geometry]\nwheelbase_m = \"x\"\n", path)
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 2"), "{e}");
    }

    #[test]
    fn a_swing_is_kept_in_the_heading_table_and_read_back() {
        let path = Path::new("robot.toml");
        let h = HeadingSection {
            kind: Some(HeadingKind::Magnetic),
            compass_deviation_deg: Some([1.5, -2.0, 0.5, 1.0004]),
        };
        let out = with_heading(EXAMPLE, &h, path).unwrap();
        assert!(out.starts_with(EXAMPLE), "only a table is added: {out}");
        let p = Profile::parse(&out, path).unwrap();
        assert_eq!(p.heading.kind, Some(HeadingKind::Magnetic));
        assert_eq!(p.heading.compass_deviation_deg, Some([1.5, -2.0, 0.5, 1.0]));
        assert!((p.heading.deviation().0[1] - (-2f64).to_radians()).abs() < 1e-12);
        // A second swing replaces the curve, keeping a comment beside the table.
        let commented = out.replace("[heading]", "[heading] # swung in the lab");
        let again = HeadingSection {
            kind: None,
            compass_deviation_deg: Some([0.0, 0.5, 0.0, 0.0]),
        };
        let out2 = with_heading(&commented, &again, path).unwrap();
        assert!(out2.contains("# swung in the lab"), "{out2}");
        let p2 = Profile::parse(&out2, path).unwrap();
        assert_eq!(p2.heading.compass_deviation_deg, Some([0.0, 0.5, 0.0, 0.0]));
        assert_eq!(p2.heading.kind, Some(HeadingKind::Magnetic));
        // Out of range or not a table: refused.
        let wild = format!("{EXAMPLE}\n[heading]\ncompass_deviation_deg = [90, 0, 0, 0]\n");
        let e = Profile::parse(&wild, path).unwrap_err().to_string();
        assert!(e.contains("compass_deviation_deg"), "{e}");
        let e = with_heading(&format!("heading = 3\n{EXAMPLE}"), &h, path)
            .unwrap_err()
            .to_string();
        assert!(e.contains("heading"), "{e}");
    }
}
