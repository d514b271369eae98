//! The ros2_control YAML file as a parameter store.
//!
//! `diff_drive_controller` keeps the geometry in its parameters in a YAML file:
//! `wheel_separation`, `wheel_radius`, `wheel_separation_multiplier`,
//! `left_wheel_radius_multiplier`, `right_wheel_radius_multiplier`, `left_wheel_names`, …. The
//! controller's odometry uses `b = wheel_separation · wheel_separation_multiplier` and per
//! wheel `r = wheel_radius · <side>_wheel_radius_multiplier`; odocal's [`WheelParams`] for such
//! a robot are those effective values, with wheel angles (rad) as its "counts"
//! (`counts_per_wheel_rev` = 2π).
//!
//! The controller's parameters are found by the file's structure: any nesting of
//! namespace keys (`/**:`, `/robot/ctrl:`), any document, flow or block style, anchors; the
//! controller named under `controller_manager` is not its section. Reading and writing use the
//! same search, and a file where it is not one clear place is refused with the reason.
//!
//! Calibration writes back only the **multipliers** (computed from the new effective values,
//! so they compose with the ones the file already had); the nominal values stay as the URDF
//! and the robot's description have them. The new values are spliced into the text — every
//! other byte stays — a missing multiplier is inserted as a line of the section (or `, key:
//! value` in a flow mapping), and the result is parsed again and must say exactly what was
//! meant, everything else unchanged ([`merge_multipliers`]). What cannot be changed in place
//! without changing something else (an alias, an anchor used elsewhere, a tag other than
//! `!!float`, a value over several lines) is refused, naming the line. The file is replaced
//! atomically, after the transaction's backup (which holds the whole file) was taken.

mod locate;
mod merge;
pub(crate) mod tree;

use crate::base::port_spec::PortSpec;
use crate::base::store_backend::{OpenStore, StoreBackend};
use crate::base::{FileStore, ParamFile};
use crate::kinematics::WheelParams;
use locate::Section;
pub use merge::*;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
pub use tree::TreeError;
use tree::{Kind, Node, NodeId, Tree};
use yaml_rust2::scanner::{ScanError, TScalarStyle};

/// Wheel angle units per revolution: the "counts" of a ROS robot are radians.
pub const RAD_PER_REV: f64 = 2.0 * std::f64::consts::PI;

/// The multiplier keys odocal writes.
pub const MULTIPLIER_KEYS: [&str; 3] = [
    "wheel_separation_multiplier",
    "left_wheel_radius_multiplier",
    "right_wheel_radius_multiplier",
];

/// The geometry keys odocal reads: the nominal values and the multipliers.
const READ_KEYS: [&str; 5] = [
    "wheel_separation",
    "wheel_radius",
    MULTIPLIER_KEYS[0],
    MULTIPLIER_KEYS[1],
    MULTIPLIER_KEYS[2],
];

/// A YAML file that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum YamlError {
    /// Reading or writing the file failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// Not valid YAML.
    #[error("{}: line {line}: not valid YAML: {}", path.display(), source.info())]
    Parse {
        /// The file.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// The parser's error.
        #[source]
        source: ScanError,
    },
    /// Nested deeper, or with more nodes, than a parameter file has.
    #[error("{}: line {line}: {what}: not a parameter file odocal reads", path.display())]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// 1-based line.
        line: usize,
        /// What exceeds the bound.
        what: String,
    },
    /// No parameters for the controller.
    #[error("{}: no parameters of `{controller}` (a `ros__parameters:` under a key naming it); {}", path.display(), match (found.is_empty(), nodes.is_empty()) { (false, _) => format!("the diff-drive controllers in it: {} (give the name with --controller)", found.join(", ")), (true, false) => format!("it names no diff-drive controller, only parameters of {}", nodes.join(", ")), (true, true) => "it has no `ros__parameters:` at all".to_string() })]
    NoController {
        /// The file.
        path: PathBuf,
        /// The controller looked for.
        controller: String,
        /// The diff-drive controllers the file does have (sections that look like one, and
        /// `controller_manager` entries of type `diff_drive_controller/DiffDriveController`).
        found: Vec<String>,
        /// Every node the file has parameters for.
        nodes: Vec<String>,
    },
    /// The controller's parameters are in more than one place.
    #[error("{}: `{controller}` has parameters in {} places (`ros__parameters:` at lines {}); ROS merges them, so which one to change is not clear: keep one", path.display(), lines.len(), join_lines(lines))]
    Ambiguous {
        /// The file.
        path: PathBuf,
        /// The controller.
        controller: String,
        /// The lines of each `ros__parameters:`.
        lines: Vec<usize>,
    },
    /// A key is in the controller's parameters twice.
    #[error("{}: `{key}` is in `{controller}`'s parameters twice (lines {} and {}); which one ROS takes is not clear: keep one", path.display(), lines[0], lines[1])]
    DuplicateKey {
        /// The file.
        path: PathBuf,
        /// The controller.
        controller: String,
        /// The key.
        key: String,
        /// Where it is.
        lines: [usize; 2],
    },
    /// A required key is missing or not a number.
    #[error("{}: line {line}: `{controller}.ros__parameters.{key}` {problem}", path.display())]
    BadKey {
        /// The file.
        path: PathBuf,
        /// The controller.
        controller: String,
        /// The key.
        key: &'static str,
        /// The line of the value (of the section, when the key is missing).
        line: usize,
        /// What is wrong.
        problem: String,
    },
    /// A multiplier cannot be written without changing something else in the file.
    #[error("{}: line {line}: cannot write `{key}` of `{controller}` in place: {reason}", path.display())]
    Unkeepable {
        /// The file.
        path: PathBuf,
        /// The controller.
        controller: String,
        /// The multiplier.
        key: &'static str,
        /// The line of its value (or of the section, for one to insert).
        line: usize,
        /// Why.
        reason: Unkeepable,
    },
    /// The merged text does not read back as meant (odocal's own check; nothing is written).
    #[error("{}: the merged text would not read back as meant ({detail}); nothing was written", path.display())]
    Unverified {
        /// The file.
        path: PathBuf,
        /// What differed.
        detail: String,
    },
}

/// A `diff_drive_controller` section.
#[derive(Debug, Clone, PartialEq)]
pub struct DiffDriveConfig {
    /// The controller's name (its section).
    pub controller: String,
    /// `wheel_separation` (m).
    pub wheel_separation_m: f64,
    /// `wheel_radius` (m).
    pub wheel_radius_m: f64,
    /// `wheel_separation_multiplier`.
    pub separation_multiplier: f64,
    /// `left_wheel_radius_multiplier`.
    pub left_radius_multiplier: f64,
    /// `right_wheel_radius_multiplier`.
    pub right_radius_multiplier: f64,
    /// `left_wheel_names`.
    pub left_wheel_names: Vec<String>,
    /// `right_wheel_names`.
    pub right_wheel_names: Vec<String>,
    /// `cmd_vel_timeout` (s): the controller stops the wheels when commands stop this long.
    pub cmd_vel_timeout_s: Option<f64>,
}

/// The three multipliers for a set of effective parameters.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Multipliers {
    /// `wheel_separation_multiplier`.
    pub wheel_separation_multiplier: f64,
    /// `left_wheel_radius_multiplier`.
    pub left_wheel_radius_multiplier: f64,
    /// `right_wheel_radius_multiplier`.
    pub right_wheel_radius_multiplier: f64,
}

impl Multipliers {
    fn values(&self) -> [f64; 3] {
        [
            self.wheel_separation_multiplier,
            self.left_wheel_radius_multiplier,
            self.right_wheel_radius_multiplier,
        ]
    }
}

/// The text without a UTF-8 byte-order mark, and the mark (yaml-rust2 would read it as part
/// of the first key).
fn split_bom(text: &str) -> (&str, &str) {
    match text.strip_prefix('\u{feff}') {
        Some(body) => ("\u{feff}", body),
        None => ("", text),
    }
}

fn parse_tree(body: &str, path: &Path) -> Result<Tree, YamlError> {
    Tree::parse(body).map_err(|e| match e {
        TreeError::Scan(source) => YamlError::Parse {
            path: path.to_path_buf(),
            line: source.marker().line(),
            source,
        },
        TreeError::TooDeep(line) => YamlError::TooLarge {
            path: path.to_path_buf(),
            line,
            what: format!("nested deeper than {} levels", tree::MAX_DEPTH),
        },
        TreeError::TooBig(line) => YamlError::TooLarge {
            path: path.to_path_buf(),
            line,
            what: format!("more than {} values", tree::MAX_NODES),
        },
    })
}

/// The controller's parameters in a parsed file: the one place both reading and writing use.
struct Located<'t> {
    tree: &'t Tree,
    path: &'t Path,
    controller: &'t str,
    section: Section,
    /// The parameters' mapping (an alias followed).
    params: NodeId,
    /// Each key, and its value.
    keys: HashMap<&'t str, (NodeId, NodeId)>,
}

/// Finds `controller`'s parameters in `tree` by its structure; see the module.
fn locate<'t>(
    tree: &'t Tree,
    controller: &'t str,
    path: &'t Path,
) -> Result<Located<'t>, YamlError> {
    let all = locate::sections(tree);
    let matched = locate::controller_sections(tree, &all, controller);
    let section = match matched.as_slice() {
        [one] => (*one).clone(),
        [] => {
            return Err(YamlError::NoController {
                path: path.to_path_buf(),
                controller: controller.into(),
                found: locate::diff_drive_controllers(tree, &all),
                nodes: locate::node_names(&all),
            })
        }
        several => {
            return Err(YamlError::Ambiguous {
                path: path.to_path_buf(),
                controller: controller.into(),
                lines: several.iter().map(|s| tree.nodes[s.key].line).collect(),
            })
        }
    };
    let params = tree.resolve(section.params);
    if !matches!(tree.nodes[params].kind, Kind::Map { .. }) {
        return Err(YamlError::BadKey {
            path: path.to_path_buf(),
            controller: controller.into(),
            key: "ros__parameters",
            line: tree.nodes[section.key].line,
            problem: "is not a mapping of parameters".into(),
        });
    }
    let mut keys: HashMap<&str, (NodeId, NodeId)> = HashMap::new();
    for &(k, v) in tree.entries(params) {
        let Some(key) = tree.nodes[k].scalar() else {
            continue;
        };
        if let Some(&(first, _)) = keys.get(key) {
            return Err(YamlError::DuplicateKey {
                path: path.to_path_buf(),
                controller: controller.into(),
                key: key.into(),
                lines: [tree.nodes[first].line, tree.nodes[k].line],
            });
        }
        keys.insert(key, (k, v));
    }
    Ok(Located {
        tree,
        path,
        controller,
        section,
        params,
        keys,
    })
}

/// A plain scalar's number as rcl would read it (an integer or a float), or why it is none.
fn plain_number(node: &Node) -> Result<f64, String> {
    let Kind::Scalar { value, style, .. } = &node.kind else {
        return Err(match node.kind {
            Kind::Map { .. } => "is a mapping, not a number".into(),
            _ => "is a sequence, not a number".into(),
        });
    };
    match style {
        TScalarStyle::Plain => {}
        TScalarStyle::SingleQuoted | TScalarStyle::DoubleQuoted => {
            return Err(format!(
                "is the string {value:?} (quoted): ROS reads a string, not a number"
            ))
        }
        TScalarStyle::Literal | TScalarStyle::Folded => {
            return Err("is a block scalar (`|` or `>`): ROS reads a string, not a number".into())
        }
    }
    if let Some(tag) = &node.tag {
        if !tag.ends_with(":float") && !tag.ends_with(":int") {
            return Err(format!("is tagged `{tag}`, not a number"));
        }
    }
    value
        .parse::<f64>()
        .ok()
        .filter(|x| x.is_finite())
        .ok_or_else(|| format!("is {value:?}, not a number"))
}

impl Located<'_> {
    fn line_of(&self, key: &str) -> usize {
        self.keys
            .get(key)
            .map_or(self.tree.nodes[self.section.key].line, |&(k, _)| {
                self.tree.nodes[k].line
            })
    }

    fn bad(&self, key: &'static str, problem: String) -> YamlError {
        YamlError::BadKey {
            path: self.path.to_path_buf(),
            controller: self.controller.into(),
            key,
            line: self.line_of(key),
            problem,
        }
    }

    /// A positive number under `key`, or `default` when the key is missing.
    fn number(&self, key: &'static str, default: Option<f64>) -> Result<f64, YamlError> {
        let Some(&(_, v)) = self.keys.get(key) else {
            return default.ok_or_else(|| self.bad(key, "is missing".into()));
        };
        let x =
            plain_number(&self.tree.nodes[self.tree.resolve(v)]).map_err(|p| self.bad(key, p))?;
        if x > 0.0 {
            Ok(x)
        } else {
            Err(self.bad(key, format!("must be a positive number, is {x}")))
        }
    }

    /// A sequence of strings under `key` (empty when missing).
    fn names(&self, key: &str) -> Vec<String> {
        let Some(&(_, v)) = self.keys.get(key) else {
            return Vec::new();
        };
        match &self.tree.nodes[self.tree.resolve(v)].kind {
            Kind::Seq { items, .. } => items
                .iter()
                .filter_map(|&i| self.tree.nodes[self.tree.resolve(i)].scalar())
                .map(String::from)
                .collect(),
            _ => Vec::new(),
        }
    }

    fn config(&self) -> Result<DiffDriveConfig, YamlError> {
        Ok(DiffDriveConfig {
            controller: self.controller.into(),
            wheel_separation_m: self.number("wheel_separation", None)?,
            wheel_radius_m: self.number("wheel_radius", None)?,
            separation_multiplier: self.number(MULTIPLIER_KEYS[0], Some(1.0))?,
            left_radius_multiplier: self.number(MULTIPLIER_KEYS[1], Some(1.0))?,
            right_radius_multiplier: self.number(MULTIPLIER_KEYS[2], Some(1.0))?,
            left_wheel_names: self.names("left_wheel_names"),
            right_wheel_names: self.names("right_wheel_names"),
            cmd_vel_timeout_s: self.number("cmd_vel_timeout", None).ok(),
        })
    }
}

impl DiffDriveConfig {
    /// Reads `controller`'s parameters from YAML text (`path` names the file in errors).
    pub fn parse(text: &str, controller: &str, path: &Path) -> Result<Self, YamlError> {
        let tree = parse_tree(split_bom(text).1, path)?;
        locate(&tree, controller, path)?.config()
    }

    /// Reads a file.
    pub fn load(path: &Path, controller: &str) -> Result<Self, YamlError> {
        let text = read_bounded(path)?;
        Self::parse(&text, controller, path)
    }

    /// The effective parameters the controller's odometry uses.
    pub fn effective(&self) -> WheelParams {
        WheelParams {
            left_wheel_diameter_m: 2.0 * self.wheel_radius_m * self.left_radius_multiplier,
            right_wheel_diameter_m: 2.0 * self.wheel_radius_m * self.right_radius_multiplier,
            wheelbase_m: self.wheel_separation_m * self.separation_multiplier,
            counts_per_wheel_rev: RAD_PER_REV,
        }
    }

    /// The multipliers that make the effective parameters `p`, on this file's nominal values.
    pub fn multipliers_for(&self, p: &WheelParams) -> Multipliers {
        Multipliers {
            wheel_separation_multiplier: p.wheelbase_m / self.wheel_separation_m,
            left_wheel_radius_multiplier: p.left_wheel_diameter_m / (2.0 * self.wheel_radius_m),
            right_wheel_radius_multiplier: p.right_wheel_diameter_m / (2.0 * self.wheel_radius_m),
        }
    }
}

/// Reads a YAML file, refusing anything larger than a configuration file can be (16 MiB).
fn read_bounded(path: &Path) -> Result<String, YamlError> {
    crate::io::read_bounded(path, crate::io::MAX_TEXT_FILE).map_err(|source| YamlError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// The controller's YAML as a [`FileStore`] format: `controller`'s section, whose effective
/// geometry is the parameters; writing changes only the multipliers ([`merge_multipliers`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ControllerYaml {
    /// The controller's name (its section).
    pub controller: String,
}

/// The kind of store a controller's YAML is, in descriptions and backups.
pub const KIND: &str = "ros2-control-yaml";

/// The controller a `ros-yaml:` store (and a ROS robot) names unless told.
pub const DEFAULT_CONTROLLER: &str = "diff_drive_controller";

/// A controller's ros2_control YAML as a store on its own:
/// `ros-yaml:PATH[?controller=diff_drive_controller]`, its multipliers as [`YamlStore`]
/// writes them.
pub const STORE_BACKEND: StoreBackend = StoreBackend {
    kind: KIND,
    what: "a controller's ros2_control YAML",
    scheme: "ros-yaml",
    form: "ros-yaml:PATH[?controller=diff_drive_controller]",
    options: &["controller"],
    bare_port: false,
    complete: |spec| {
        spec.or_option("controller", DEFAULT_CONTROLLER);
        Ok(())
    },
    of_backup: |backup, file| {
        let file = file.ok_or("which file")?;
        let mut spec = PortSpec::bare(file.to_str().ok_or("a file name that is UTF-8")?);
        let controller = StoreBackend::detail(backup, "controller").ok_or("which controller")?;
        spec.or_option("controller", controller);
        Ok(spec)
    },
    show: |spec| spec.text("ros-yaml"),
    open: |spec: PortSpec| -> OpenStore {
        Box::pin(async move {
            let controller = spec
                .options
                .get("controller")
                .map_or(DEFAULT_CONTROLLER, |c| c);
            Ok(
                std::sync::Arc::new(YamlStore::open(Path::new(&spec.port), controller)?)
                    as std::sync::Arc<dyn crate::base::ParamStore>,
            )
        })
    },
};

impl ParamFile for ControllerYaml {
    type Content = DiffDriveConfig;
    type Error = YamlError;

    fn kind(&self) -> &'static str {
        KIND
    }

    fn written_keys(&self) -> &'static [&'static str] {
        &MULTIPLIER_KEYS
    }

    fn id(&self, path: &Path) -> String {
        format!("{}#{}", path.display(), self.controller)
    }

    fn details(&self, path: &Path) -> serde_json::Value {
        serde_json::json!({
            "file": path,
            "controller": self.controller,
            // The backup's parameters carry `counts_per_wheel_rev` 2π: say why it is no count.
            "counts_per_wheel_rev": "2π: ros2_control gives wheel positions in radians, so one \
                                     count is one radian",
        })
    }

    fn parse(&self, text: &str, path: &Path) -> Result<DiffDriveConfig, YamlError> {
        DiffDriveConfig::parse(text, &self.controller, path)
    }

    fn params(content: &DiffDriveConfig) -> WheelParams {
        content.effective()
    }

    fn render(&self, text: &str, params: &WheelParams, path: &Path) -> Result<String, YamlError> {
        // Multipliers on the file's own nominal values, rounded as they will be written.
        let cfg = DiffDriveConfig::parse(text, &self.controller, path)?;
        merge_multipliers(text, &self.controller, &cfg.multipliers_for(params), path)
    }

    fn refuse(&self, _current: &WheelParams, params: &WheelParams) -> Option<String> {
        ((params.counts_per_wheel_rev - RAD_PER_REV).abs() > 1e-9).then(|| {
            format!(
                "a ROS robot's wheel angles are radians: counts per revolution must stay 2π, got {}",
                params.counts_per_wheel_rev
            )
        })
    }

    fn io_error(&self, path: &Path, source: std::io::Error) -> YamlError {
        YamlError::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// The controller's YAML file as a [`crate::base::ParamStore`]: `write` stages effective
/// parameters (and updates the section a ROS drive integrates its odometry with), `commit`
/// rewrites the multipliers in the file ([`FileStore`]).
pub type YamlStore = FileStore<ControllerYaml>;

impl FileStore<ControllerYaml> {
    /// Opens `controller`'s section of `path` (which must parse).
    pub fn open(path: &Path, controller: &str) -> Result<Self, YamlError> {
        FileStore::with_format(
            ControllerYaml {
                controller: controller.into(),
            },
            path,
        )
    }
}

/// Line numbers as a list for a message ("3, 7, 12").
fn join_lines(lines: &[usize]) -> String {
    lines
        .iter()
        .map(usize::to_string)
        .collect::<Vec<_>>()
        .join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    const FILE: &str = "\
# robot controllers
controller_manager:
  ros__parameters:
    update_rate: 50  # Hz

diff_drive_controller:
  ros__parameters:
    left_wheel_names: [\"left_wheel_joint\"]
    right_wheel_names: [\"right_wheel_joint\"]
    wheel_separation: 0.39
    wheel_radius: 0.075
    wheel_separation_multiplier: 1.0  # tuned 2024
    publish_rate: 50.0
    cmd_vel_timeout: 0.5
";

    const M: Multipliers = Multipliers {
        wheel_separation_multiplier: 0.976,
        left_wheel_radius_multiplier: 1.004,
        right_wheel_radius_multiplier: 0.996,
    };

    fn merge(text: &str) -> Result<String, YamlError> {
        merge_multipliers(text, "diff_drive_controller", &M, Path::new("f.yaml"))
    }

    /// `text` with each `(old, new)` replaced once, in order: the expected merge result.
    fn with(text: &str, changes: &[(&str, &str)]) -> String {
        let mut out = text.to_string();
        for (old, new) in changes {
            assert!(out.contains(old), "{old:?} not in {out}");
            out = out.replacen(old, new, 1);
        }
        out
    }

    #[test]
    fn the_section_reads_into_effective_parameters() {
        let c = DiffDriveConfig::parse(FILE, "diff_drive_controller", Path::new("f.yaml")).unwrap();
        assert_eq!(c.left_wheel_names, vec!["left_wheel_joint"]);
        assert_eq!(c.cmd_vel_timeout_s, Some(0.5));
        let p = c.effective();
        assert!((p.left_wheel_diameter_m - 0.15).abs() < 1e-15);
        assert!((p.wheelbase_m - 0.39).abs() < 1e-15);
        assert!((p.left_m_per_count() - 0.075).abs() < 1e-15);
    }

    #[test]
    fn a_missing_controller_lists_the_controllers_there_are() {
        let text = format!(
            "{FILE}\
/**:
  controller_manager:
    ros__parameters:
      base: {{type: diff_drive_controller/DiffDriveController}}
      arm.type: joint_trajectory_controller/JointTrajectoryController
      tracks.type: diff_drive_controller/DiffDriveController
"
        );
        let e = DiffDriveConfig::parse(&text, "diff_cont", Path::new("f.yaml")).unwrap_err();
        let YamlError::NoController { found, .. } = &e else {
            panic!("{e}");
        };
        assert_eq!(found, &["diff_drive_controller", "base", "tracks"]);
        assert!(e.to_string().contains("--controller"), "{e}");
        // No diff-drive controller at all: the nodes it does have.
        let e = DiffDriveConfig::parse(
            "controller_manager:\n  ros__parameters: {}\n/**/imu:\n  ros__parameters: {}\n",
            "diff_cont",
            Path::new("f.yaml"),
        )
        .unwrap_err();
        assert!(
            e.to_string().ends_with(
                "it names no diff-drive controller, only parameters of controller_manager, /**/imu"
            ),
            "{e}"
        );
        let e = DiffDriveConfig::parse("a: [1,\n", "x", Path::new("f.yaml")).unwrap_err();
        assert!(matches!(e, YamlError::Parse { line: 2, .. }), "{e}");
    }

    #[test]
    fn merging_changes_only_the_multipliers_and_composes_with_existing_ones() {
        let path = Path::new("f.yaml");
        let c = DiffDriveConfig::parse(FILE, "diff_drive_controller", path).unwrap();
        let mut p = c.effective();
        p.wheelbase_m *= 0.976;
        p.right_wheel_diameter_m *= 0.992;
        let m = c.multipliers_for(&p);
        let out = merge_multipliers(FILE, "diff_drive_controller", &m, path).unwrap();
        // The one multiplier there changes in place; the two missing ones follow it.
        let expected = with(
            FILE,
            &[(
                "wheel_separation_multiplier: 1.0  # tuned 2024\n",
                "wheel_separation_multiplier: 0.9760000000  # tuned 2024\n    \
                 left_wheel_radius_multiplier: 1.0000000000\n    \
                 right_wheel_radius_multiplier: 0.9920000000\n",
            )],
        );
        assert_eq!(out, expected);
        let back = DiffDriveConfig::parse(&out, "diff_drive_controller", path).unwrap();
        assert!((back.effective().wheelbase_m - p.wheelbase_m).abs() < 1e-12);
        // Calibrating again composes: the new multipliers multiply the written ones.
        let mut p2 = back.effective();
        p2.wheelbase_m *= 1.01;
        let m2 = back.multipliers_for(&p2);
        assert!((m2.wheel_separation_multiplier - 0.976 * 1.01).abs() < 1e-12);
    }

    #[test]
    fn the_controller_listed_under_controller_manager_is_not_its_section() {
        // ros2_control_demos' humble layout: the first line reading `diffbot:` is the
        // controller manager's entry, the section comes after.
        let text = "\
controller_manager:
  ros__parameters:
    update_rate: 10
    diffbot:
      type: diff_drive_controller/DiffDriveController

diffbot:
  ros__parameters:
    wheel_separation: 0.10
    wheel_radius: 0.015
    wheel_separation_multiplier: 1.0
    left_wheel_radius_multiplier: 1.0
    right_wheel_radius_multiplier: 1.0
";
        let out = merge_multipliers(text, "diffbot", &M, Path::new("f.yaml")).unwrap();
        let expected = with(
            text,
            &[
                (
                    "separation_multiplier: 1.0",
                    "separation_multiplier: 0.9760000000",
                ),
                (
                    "left_wheel_radius_multiplier: 1.0",
                    "left_wheel_radius_multiplier: 1.0040000000",
                ),
                (
                    "right_wheel_radius_multiplier: 1.0",
                    "right_wheel_radius_multiplier: 0.9960000000",
                ),
            ],
        );
        assert_eq!(out, expected);
    }

    #[test]
    fn flow_mappings_crlf_and_a_byte_order_mark_are_kept() {
        let flow = "\u{feff}diff_drive_controller: {ros__parameters: {wheel_separation: 0.39,\r\n  wheel_radius: 0.075, wheel_separation_multiplier: !!float 1}}\r\n";
        let out = merge(flow).unwrap();
        let expected = with(
            flow,
            &[(
                "!!float 1}}",
                "!!float 0.9760000000, left_wheel_radius_multiplier: 1.0040000000, \
                 right_wheel_radius_multiplier: 0.9960000000}}",
            )],
        );
        assert_eq!(out, expected);
        let crlf = FILE.replace('\n', "\r\n");
        let out = merge(&crlf).unwrap();
        assert!(
            out.contains(
                "# tuned 2024\r\n    left_wheel_radius_multiplier: 1.0040000000\r\n    right"
            ),
            "{out}"
        );
        assert_eq!(out.matches('\n').count(), crlf.matches('\n').count() + 2);
        assert!(!out.replace("\r\n", "").contains('\n'), "only CRLF breaks");
        // An empty flow mapping takes the keys without a comma.
        let empty = "diff_drive_controller:\n  ros__parameters: {wheel_separation: 0.39, wheel_radius: 0.075, x: {}}\n";
        assert!(merge(empty).unwrap().ends_with(
            "x: {}, wheel_separation_multiplier: 0.9760000000, left_wheel_radius_multiplier: \
             1.0040000000, right_wheel_radius_multiplier: 0.9960000000}\n"
        ));
    }

    #[test]
    fn values_always_have_a_decimal_point() {
        assert_eq!(format_multiplier(1.0), "1.0000000000");
        assert_eq!(format_multiplier(0.976), "0.9760000000");
        assert_eq!(format_multiplier(1e-5), "1.0000000000e-5");
        assert_eq!(format_multiplier(2.5e8), "2.5000000000e8");
        for v in [1e-5, 2.5e8, 3e-300] {
            assert_eq!(format_multiplier(v).parse::<f64>().unwrap(), v);
        }
        let no_point = Multipliers {
            wheel_separation_multiplier: 1e-20,
            ..M
        };
        let out =
            merge_multipliers(FILE, "diff_drive_controller", &no_point, Path::new("f")).unwrap();
        assert!(
            out.contains("wheel_separation_multiplier: 1.0000000000e-20  #"),
            "{out}"
        );
        let bad = Multipliers {
            left_wheel_radius_multiplier: f64::NAN,
            ..M
        };
        let e = merge_multipliers(FILE, "diff_drive_controller", &bad, Path::new("f")).unwrap_err();
        assert!(
            matches!(
                e,
                YamlError::BadKey {
                    key: "left_wheel_radius_multiplier",
                    ..
                }
            ),
            "{e}"
        );
    }

    /// The refusal for `text`, which must also leave reading as `reads` says.
    fn refusal(text: &str, reads: bool) -> YamlError {
        let read = DiffDriveConfig::parse(text, "diff_drive_controller", Path::new("f.yaml"));
        assert_eq!(read.is_ok(), reads, "{read:?}");
        merge(text).unwrap_err()
    }

    const HEAD: &str = "diff_drive_controller:\n  ros__parameters:\n    wheel_separation: 0.39\n    wheel_radius: 0.075\n";

    #[test]
    fn what_cannot_be_kept_is_refused_with_the_reason_and_the_line() {
        // The value is an alias: the number is at the anchor, which others share.
        let e = refusal(
            &format!("defaults:\n  one: &one 1.0\n{HEAD}    wheel_separation_multiplier: *one\n"),
            true,
        );
        assert!(
            matches!(&e, YamlError::Unkeepable { line: 7, reason: Unkeepable::Alias { alias, anchor_line: 2 }, .. } if alias == "*one"),
            "{e}"
        );
        assert!(
            e.to_string().contains("line 7") && e.to_string().contains("*one"),
            "{e}"
        );
        // The value is an anchor another place repeats.
        let e = refusal(
            &format!("{HEAD}    left_wheel_radius_multiplier: &m 1.0\n    right_wheel_radius_multiplier: *m\n"),
            true,
        );
        assert!(
            matches!(
                e,
                YamlError::Unkeepable {
                    key: "left_wheel_radius_multiplier",
                    reason: Unkeepable::SharedAnchor {
                        anchor_line: 5,
                        alias_line: 6
                    },
                    ..
                }
            ),
            "{e}"
        );
        // The whole parameter mapping is an anchor repeated by another controller: inserting
        // into it would change that one too.
        let e = refusal(
            "diff_drive_controller:\n  ros__parameters: &p\n    wheel_separation: 0.39\n    wheel_radius: 0.075\nother:\n  ros__parameters: *p\n",
            true,
        );
        assert!(
            matches!(
                e,
                YamlError::Unkeepable {
                    reason: Unkeepable::SharedAnchor { alias_line: 6, .. },
                    ..
                }
            ),
            "{e}"
        );
        // Parameters given as an alias.
        let e = refusal(
            "base: &p {wheel_separation: 0.39, wheel_radius: 0.075}\ndiff_drive_controller:\n  ros__parameters: *p\n",
            true,
        );
        assert!(
            matches!(
                e,
                YamlError::Unkeepable {
                    line: 3,
                    reason: Unkeepable::Alias { anchor_line: 1, .. },
                    ..
                }
            ),
            "{e}"
        );
        // A tag a decimal would contradict.
        let e = refusal(
            &format!("{HEAD}    wheel_separation_multiplier: !!int 1\n"),
            true,
        );
        assert!(
            matches!(&e, YamlError::Unkeepable { line: 5, reason: Unkeepable::Tag { tag }, .. } if tag.ends_with("int")),
            "{e}"
        );
        // Block and multi-line scalars, quoted numbers: ROS reads strings; not even read.
        for (value, says) in [
            ("|\n      1.0", "block scalar"),
            ("1.0\n      2", "not a number"),
            ("\"1.0\"", "quoted"),
            ("!!str 1.0", "tagged"),
        ] {
            let e = refusal(
                &format!("{HEAD}    wheel_separation_multiplier: {value}\n"),
                false,
            );
            assert!(
                matches!(e, YamlError::BadKey { line: 5, .. }) && e.to_string().contains(says),
                "{e}"
            );
        }
        // The controller twice (rcl merges; which to change?), in two documents too.
        let e = refusal(&format!("{HEAD}---\n/**/diff_drive_controller:\n  ros__parameters:\n    use_sim_time: true\n"), false);
        assert!(
            matches!(&e, YamlError::Ambiguous { lines, .. } if lines == &[2, 7]),
            "{e}"
        );
        // A wildcard section setting the geometry applies to the controller too.
        let e = refusal(
            &format!("{HEAD}/**:\n  ros__parameters:\n    wheel_radius: 0.08\n"),
            false,
        );
        assert!(
            matches!(&e, YamlError::Ambiguous { lines, .. } if lines == &[2, 6]),
            "{e}"
        );
        // A duplicate key among the parameters.
        let e = refusal(&format!("{HEAD}    wheel_radius: 0.08\n"), false);
        assert!(
            matches!(&e, YamlError::DuplicateKey { key, lines: [4, 5], .. } if key == "wheel_radius"),
            "{e}"
        );
        // Too deep to be a parameter file.
        let deep: String = (0..80)
            .map(|i| format!("{}k{i}:\n", "  ".repeat(i)))
            .collect();
        assert!(matches!(refusal(&deep, false), YamlError::TooLarge { .. }));
    }

    #[test]
    fn wildcard_sections_without_geometry_and_other_controllers_do_not_interfere() {
        let text = format!(
            "/**:\n  ros__parameters:\n    use_sim_time: true\n{HEAD}    wheel_separation_multiplier: 1.0\n\
             mecanum:\n  ros__parameters:\n    wheel_separation_multiplier: 1.0\n"
        );
        let out = merge(&text).unwrap();
        let expected = with(
            &text,
            &[(
                "    wheel_separation_multiplier: 1.0\n",
                "    wheel_separation_multiplier: 0.9760000000\n    \
                 left_wheel_radius_multiplier: 1.0040000000\n    \
                 right_wheel_radius_multiplier: 0.9960000000\n",
            )],
        );
        assert_eq!(out, expected);
    }

    #[tokio::test]
    async fn a_file_that_cannot_be_rewritten_is_refused_before_anything_and_owes_no_rollback() {
        use crate::base::transaction::{Rollback, Transaction};
        use crate::base::{BaseError, ParamStore};
        use std::sync::Arc;
        let dir = std::env::temp_dir().join(format!("odocal-yaml-tx-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("controllers.yaml");
        let backups = dir.join("backups");
        let shared = format!("{HEAD}    left_wheel_radius_multiplier: &m 1.0\n    right_wheel_radius_multiplier: *m\n");
        // Readable, not writable: refused by `begin`, before a backup or anything else.
        std::fs::write(&file, &shared).unwrap();
        let store: Arc<dyn ParamStore> =
            Arc::new(YamlStore::open(&file, "diff_drive_controller").unwrap());
        let e = Transaction::begin(store, &backups).await.err().unwrap();
        assert!(matches!(e, BaseError::Unwritable { .. }), "{e}");
        assert!(
            e.to_string().contains("line 5") && e.to_string().contains("nothing was changed"),
            "{e}"
        );
        assert!(!backups.exists());
        // A file that turns unwritable after `begin`: the write is refused and nothing is owed
        // (no "restoring the backup failed … nothing to restore").
        std::fs::write(&file, FILE).unwrap();
        let store: Arc<dyn ParamStore> =
            Arc::new(YamlStore::open(&file, "diff_drive_controller").unwrap());
        let mut tx = Transaction::begin(store.clone(), &backups).await.unwrap();
        std::fs::write(&file, &shared).unwrap();
        let mut p = *tx.original();
        p.wheelbase_m *= 0.99;
        let e = tx.apply(&p).await.unwrap_err();
        assert!(matches!(e, BaseError::Unwritable { .. }), "{e}");
        assert!(!tx.written());
        assert_eq!(tx.rollback().await.unwrap(), Rollback::NothingWritten);
        assert_eq!(std::fs::read_to_string(&file).unwrap(), shared);
        // A directory that takes no new file is refused too (not as root, who may write anyway).
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::write(&file, FILE).unwrap();
            let store = YamlStore::open(&file, "diff_drive_controller").unwrap();
            std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o555)).unwrap();
            let probe = std::fs::File::create(dir.join("probe")).is_err();
            let e = store.check_write(&store.read().await.unwrap()).await;
            std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o755)).unwrap();
            if probe {
                let e = e.unwrap_err();
                assert!(e.to_string().contains("no new file can be created"), "{e}");
            }
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}
