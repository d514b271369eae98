//! Where a node's parameters are in a ROS 2 parameter file, by the file's structure.
//!
//! The grammar (rcl_yaml_param_parser): keys down to a `ros__parameters:` key name the node, as
//! one key (`/robot/diff_drive_controller:`) or nested (`/**:` then `diff_drive_controller:`),
//! with `/**` and `*` as wildcards; what is under `ros__parameters` is parameters, so the
//! controller named again under `controller_manager.ros__parameters.<name>.type` is a parameter
//! of the controller manager, never the controller's section. Every document is searched, a
//! key may appear twice (TurtleBot 3's two top-level `/**:` keys; rcl merges them), and anchors
//! are followed.

use super::tree::{Kind, NodeId, Tree, MAX_DEPTH};

/// One node's `ros__parameters:` entry.
#[derive(Debug, Clone)]
pub(crate) struct Section {
    /// The node's name, segment by segment, as the keys above spell it (`["**", "ctrl"]`).
    pub node: Vec<String>,
    /// The `ros__parameters` key.
    pub key: NodeId,
    /// Its value as written (an alias stays an alias).
    pub params: NodeId,
}

/// The keys that make a section look like a `diff_drive_controller`'s.
const DIFF_DRIVE_KEYS: [&str; 4] = [
    "wheel_separation",
    "wheel_radius",
    "left_wheel_names",
    "right_wheel_names",
];

/// The controller type `controller_manager` is told to load.
const DIFF_DRIVE_TYPE: &str = "diff_drive_controller/DiffDriveController";

fn is_wildcard(segment: &str) -> bool {
    segment == "*" || segment == "**"
}

/// Every `ros__parameters` entry of every document, in file order.
pub(crate) fn sections(tree: &Tree) -> Vec<Section> {
    let mut out = Vec::new();
    for &doc in &tree.docs {
        walk(tree, doc, &mut Vec::new(), &mut out, 0);
    }
    out
}

fn walk(tree: &Tree, map: NodeId, prefix: &mut Vec<String>, out: &mut Vec<Section>, depth: usize) {
    // Aliases may be followed into what contains them: the depth bounds that too.
    if depth > MAX_DEPTH {
        return;
    }
    for &(k, v) in tree.entries(map) {
        let Some(key) = tree.nodes[k].scalar() else {
            continue;
        };
        if key == "ros__parameters" {
            out.push(Section {
                node: prefix.clone(),
                key: k,
                params: v,
            });
            continue;
        }
        if matches!(tree.nodes[tree.resolve(v)].kind, Kind::Map { .. }) {
            let before = prefix.len();
            prefix.extend(key.split('/').filter(|s| !s.is_empty()).map(String::from));
            walk(tree, v, prefix, out, depth + 1);
            prefix.truncate(before);
        }
    }
}

/// Whether namespace `pattern` (with `*` for one segment and `**` for any number) covers
/// `names`.
fn namespace_matches(pattern: &[String], names: &[&str]) -> bool {
    // fits[i][j]: pattern[i..] covers names[j..].
    let (p, n) = (pattern.len(), names.len());
    let mut fits = vec![vec![false; n + 1]; p + 1];
    fits[p][n] = true;
    for i in (0..p).rev() {
        for j in (0..=n).rev() {
            fits[i][j] = match pattern[i].as_str() {
                "**" => fits[i + 1][j] || (j < n && fits[i][j + 1]),
                "*" => j < n && fits[i + 1][j + 1],
                s => j < n && s == names[j] && fits[i + 1][j + 1],
            };
        }
    }
    fits[0][0]
}

/// Whether a section's parameters hold one of the geometry keys odocal reads.
fn has_geometry(tree: &Tree, s: &Section) -> bool {
    tree.entries(s.params).iter().any(|&(k, _)| {
        tree.nodes[k]
            .scalar()
            .is_some_and(|k| super::READ_KEYS.contains(&k))
    })
}

/// The sections that give `controller` its parameters: the node's last segment is its name (a
/// namespace given as `ns/name` must be covered by the section's), or a wildcard when that
/// section sets one of the keys odocal reads (a `/**: ros__parameters: {use_sim_time: …}`
/// applies to every node but says nothing of the geometry).
pub(crate) fn controller_sections<'t>(
    tree: &Tree,
    all: &'t [Section],
    controller: &str,
) -> Vec<&'t Section> {
    let wanted: Vec<&str> = controller.split('/').filter(|s| !s.is_empty()).collect();
    let Some((name, namespace)) = wanted.split_last() else {
        return Vec::new();
    };
    all.iter()
        .filter(|s| {
            let Some((last, ns)) = s.node.split_last() else {
                return false;
            };
            let named = last == name || (is_wildcard(last) && has_geometry(tree, s));
            named && (namespace.is_empty() || namespace_matches(ns, namespace))
        })
        .collect()
}

/// A node's name as `--controller` takes it: its segments without wildcards.
fn display_name(node: &[String]) -> String {
    node.iter()
        .filter(|s| !is_wildcard(s))
        .cloned()
        .collect::<Vec<_>>()
        .join("/")
}

/// Every node with parameters (`/ns/node` when namespaced), once each, in file order.
pub(crate) fn node_names(all: &[Section]) -> Vec<String> {
    let mut names: Vec<String> = Vec::new();
    for s in all {
        let name = match s.node.as_slice() {
            [one] => one.clone(),
            more => format!("/{}", more.join("/")),
        };
        if name != "/" && !names.contains(&name) {
            names.push(name);
        }
    }
    names
}

/// The diff-drive controllers a file mentions, in file order: sections that look like one
/// (a geometry key or wheel names, or `type: diff_drive_controller/DiffDriveController`), and
/// the controllers `controller_manager` is told to load with that type (`<name>: {type: …}` or
/// `<name>.type: …`).
pub(crate) fn diff_drive_controllers(tree: &Tree, all: &[Section]) -> Vec<String> {
    let mut found: Vec<String> = Vec::new();
    let mut add = |name: String| {
        if !name.is_empty() && !found.contains(&name) {
            found.push(name);
        }
    };
    let is_type = |id: NodeId| tree.nodes[tree.resolve(id)].scalar() == Some(DIFF_DRIVE_TYPE);
    for s in all {
        let Some((last, ns)) = s.node.split_last() else {
            continue;
        };
        let entries = tree.entries(s.params);
        if last == "controller_manager" {
            for &(k, v) in entries {
                let Some(key) = tree.nodes[k].scalar() else {
                    continue;
                };
                let named = match key.strip_suffix(".type") {
                    Some(name) if is_type(v) => Some(name),
                    _ => tree.get(v, "type").filter(|&t| is_type(t)).map(|_| key),
                };
                if let Some(name) = named {
                    let mut node = ns.to_vec();
                    node.push(name.to_string());
                    add(display_name(&node));
                }
            }
            continue;
        }
        let looks = entries.iter().any(|&(k, v)| {
            tree.nodes[k]
                .scalar()
                .is_some_and(|k| DIFF_DRIVE_KEYS.contains(&k) || (k == "type" && is_type(v)))
        });
        if looks && !is_wildcard(last) {
            add(display_name(&s.node));
        }
    }
    found
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(src: &str, controller: &str) -> Vec<Vec<String>> {
        let t = Tree::parse(src).unwrap();
        let all = sections(&t);
        controller_sections(&t, &all, controller)
            .iter()
            .map(|s| s.node.clone())
            .collect()
    }

    #[test]
    fn nodes_are_found_at_any_depth_and_in_any_spelling() {
        let src = "\
controller_manager:
  ros__parameters:
    ctrl:
      type: diff_drive_controller/DiffDriveController
/**:
  ctrl:
    ros__parameters: {wheel_radius: 1}
---
/robot/ctrl:
  ros__parameters: {a: 1}
/**/other:
  ros__parameters: {wheel_radius: 1}
";
        assert_eq!(
            names(src, "ctrl"),
            vec![vec!["**", "ctrl"], vec!["robot", "ctrl"]]
        );
        assert_eq!(names(src, "/robot/ctrl"), names(src, "ctrl"));
        assert_eq!(names(src, "elsewhere/ctrl"), vec![vec!["**", "ctrl"]]);
        let t = Tree::parse(src).unwrap();
        assert_eq!(
            diff_drive_controllers(&t, &sections(&t)),
            vec!["ctrl", "other"]
        );
    }

    #[test]
    fn namespaces_match_with_wildcards() {
        let p = |s: &[&str]| s.iter().map(|x| x.to_string()).collect::<Vec<_>>();
        assert!(namespace_matches(&p(&["**"]), &["a", "b"]));
        assert!(namespace_matches(&p(&["**"]), &[]));
        assert!(namespace_matches(&p(&["a", "*"]), &["a", "b"]));
        assert!(!namespace_matches(&p(&["a", "*"]), &["a"]));
        assert!(namespace_matches(&p(&["**", "b"]), &["a", "b"]));
        assert!(!namespace_matches(&p(&["c"]), &["a"]));
    }
}
