//! Writing the multipliers back into the controller's YAML: each new value spliced into the
//! text where its key is (or a line inserted for a missing one), every other byte kept, the result
//! parsed again and compared; what cannot be changed in place without changing something else
//! is refused with the reason ([`Unkeepable`]) and the line.

use super::*;

/// Why a multiplier cannot be changed in place.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Unkeepable {
    /// Its value is an alias: the number lives at the anchor, which other places share.
    #[error("it is the alias `{alias}` of the anchor at line {anchor_line}; change it there, or write the number here")]
    Alias {
        /// The alias as written (`*one`).
        alias: String,
        /// The anchor's line.
        anchor_line: usize,
    },
    /// It is inside an anchored node that an alias repeats elsewhere.
    #[error("the alias at line {alias_line} repeats the anchor at line {anchor_line} that holds it: changing it would change that too")]
    SharedAnchor {
        /// The anchored node's line.
        anchor_line: usize,
        /// The first alias's line.
        alias_line: usize,
    },
    /// It has a tag a decimal number would contradict.
    #[error("it is tagged `{tag}`; odocal writes a decimal number (untagged or `!!float`)")]
    Tag {
        /// The tag.
        tag: String,
    },
    /// Its text cannot be located exactly.
    #[error("its value's text cannot be located exactly (a value over several lines?); write it on one line")]
    NoSpan,
    /// The key is missing and there is no place to insert it.
    #[error(
        "it is missing and the section has no line to put it after; add `{key}: 1.0` yourself"
    )]
    NoPlace {
        /// The key.
        key: &'static str,
    },
}

/// Formats a multiplier, always with a decimal point (ROS 2 parameters are typed: `1` would be
/// an integer, which a double parameter refuses): ten decimals, which keeps effective lengths
/// to well under a nanometre, or a mantissa with a point and an exponent far from 1.
pub(super) fn format_multiplier(v: f64) -> String {
    if (1e-3..1e7).contains(&v) {
        format!("{v:.10}")
    } else {
        let s = format!("{v:.10e}");
        s.replacen("e", ".0e", usize::from(!s.contains('.')))
    }
}

/// One splice: bytes `at..end` become `text`.
pub(super) struct Edit {
    pub(super) at: usize,
    pub(super) end: usize,
    pub(super) text: String,
}

/// What a merge does to the text, and what the tree must then read.
pub(super) struct Plan {
    pub(super) edits: Vec<Edit>,
    /// Scalars whose value changes.
    pub(super) replaced: Vec<(NodeId, String)>,
    /// Entries inserted into the parameters' mapping at this index.
    pub(super) inserted: Option<(usize, Vec<(&'static str, String)>)>,
}

/// The end of the line holding byte `from` (before its `\r\n` or `\n`, or the end of the
/// text) and its line break, if nothing but blanks and a comment follow `from` there.
pub(super) fn line_end_after(src: &str, from: usize) -> Option<(usize, &'static str)> {
    let rest = src.get(from..)?;
    let (content, eol) = match rest.find('\n') {
        Some(n) if rest[..n].ends_with('\r') => (&rest[..n - 1], "\r\n"),
        Some(n) => (&rest[..n], "\n"),
        None if src.contains("\r\n") => (rest, "\r\n"),
        None => (rest, "\n"),
    };
    let tail = content.trim_start_matches([' ', '\t']);
    (tail.is_empty() || tail.starts_with('#')).then_some((from + content.len(), eol))
}

/// The column of a block mapping's key, as spaces, if only indentation (and sequence dashes)
/// come before it on its line.
pub(super) fn key_indent(src: &str, key: &Node) -> Option<String> {
    let line_start = src[..key.start].rfind('\n').map_or(0, |n| n + 1);
    let prefix = &src[line_start..key.start];
    prefix
        .chars()
        .all(|c| c == ' ' || c == '-')
        .then(|| " ".repeat(prefix.chars().count()))
}

impl Located<'_> {
    pub(super) fn unkeepable(
        &self,
        key: &'static str,
        line: usize,
        reason: Unkeepable,
    ) -> YamlError {
        YamlError::Unkeepable {
            path: self.path.to_path_buf(),
            controller: self.controller.into(),
            key,
            line,
            reason,
        }
    }

    /// Refuses a change at `id` (for `key`) that would change what an alias repeats.
    pub(super) fn not_shared(
        &self,
        key: &'static str,
        line: usize,
        id: NodeId,
    ) -> Result<(), YamlError> {
        match self.tree.shared_ancestor(id) {
            Some((anchored, alias_line)) => Err(self.unkeepable(
                key,
                line,
                Unkeepable::SharedAnchor {
                    anchor_line: self.tree.anchor_line(anchored),
                    alias_line,
                },
            )),
            None => Ok(()),
        }
    }

    /// The splices that write `values` (formatted) into `src`; see [`merge_multipliers`].
    pub(super) fn plan(&self, src: &str, values: &[String; 3]) -> Result<Plan, YamlError> {
        let tree = self.tree;
        let mut plan = Plan {
            edits: Vec::new(),
            replaced: Vec::new(),
            inserted: None,
        };
        let mut missing = Vec::new();
        for (key, value) in MULTIPLIER_KEYS.into_iter().zip(values) {
            let Some(&(k, v)) = self.keys.get(key) else {
                missing.push((key, value.clone()));
                continue;
            };
            let line = tree.nodes[k].line;
            let end = self.replaceable_end(src, key, line, v)?;
            plan.edits.push(Edit {
                at: tree.nodes[v].start,
                end,
                text: value.clone(),
            });
            plan.replaced.push((v, value.clone()));
        }
        let Some(&(first_missing, _)) = missing.first() else {
            return Ok(plan);
        };
        let section_line = tree.nodes[self.section.key].line;
        self.check_insertable(src, first_missing, section_line)?;
        let Kind::Map { entries, close } = &tree.nodes[self.params].kind else {
            return Err(self.no_place(first_missing, section_line));
        };
        let (edit, index) = match *close {
            Some(close) => (
                self.flow_insertion(entries, close, &missing)
                    .ok_or_else(|| self.no_place(first_missing, section_line))?,
                entries.len(),
            ),
            None => self
                .block_insertion(src, entries, &missing)
                .ok_or_else(|| self.no_place(first_missing, section_line))?,
        };
        plan.edits.push(edit);
        plan.inserted = Some((index, missing));
        Ok(plan)
    }

    /// The end of the text of `key`'s value `v` (its key at `line`), to be replaced by a
    /// number; refused when the value is an alias, has another tag than `!!float`, is shared
    /// by an alias, or is not a plain scalar whose end is known.
    fn replaceable_end(
        &self,
        src: &str,
        key: &'static str,
        line: usize,
        v: NodeId,
    ) -> Result<usize, YamlError> {
        let tree = self.tree;
        let node = &tree.nodes[v];
        if let Kind::Alias { end, .. } = node.kind {
            let anchor_line = tree.anchor_line(tree.resolve(v));
            let alias = src.get(node.start..end).unwrap_or("*").to_string();
            return Err(self.unkeepable(key, line, Unkeepable::Alias { alias, anchor_line }));
        }
        if let Some(tag) = node.tag.as_ref().filter(|t| *t != FLOAT_TAG) {
            let tag = tag.clone();
            return Err(self.unkeepable(key, line, Unkeepable::Tag { tag }));
        }
        self.not_shared(key, line, v)?;
        node.end()
            .filter(|_| {
                matches!(
                    node.kind,
                    Kind::Scalar {
                        style: TScalarStyle::Plain,
                        ..
                    }
                )
            })
            .ok_or_else(|| self.unkeepable(key, line, Unkeepable::NoSpan))
    }

    /// Refuses inserting `first_missing` (and the other missing keys) into the parameters'
    /// mapping when the section's value is an alias or an alias repeats the mapping.
    fn check_insertable(
        &self,
        src: &str,
        first_missing: &'static str,
        section_line: usize,
    ) -> Result<(), YamlError> {
        let tree = self.tree;
        if let Kind::Alias { end, .. } = tree.nodes[self.section.params].kind {
            let alias = src
                .get(tree.nodes[self.section.params].start..end)
                .unwrap_or("*")
                .to_string();
            let anchor_line = tree.anchor_line(self.params);
            return Err(self.unkeepable(
                first_missing,
                section_line,
                Unkeepable::Alias { alias, anchor_line },
            ));
        }
        self.not_shared(first_missing, section_line, self.params)
    }

    /// The refusal of `first_missing` when the parameters' mapping has no place to insert it.
    fn no_place(&self, first_missing: &'static str, section_line: usize) -> YamlError {
        self.unkeepable(
            first_missing,
            section_line,
            Unkeepable::NoPlace { key: first_missing },
        )
    }

    /// The splice that inserts `missing` into a flow mapping whose `}` is at `close`; `None`
    /// when the end of its last value is not known.
    fn flow_insertion(
        &self,
        entries: &[(NodeId, NodeId)],
        close: usize,
        missing: &[(&'static str, String)],
    ) -> Option<Edit> {
        // Flow: after the last value (a trailing comma stays valid), or inside `{}`.
        let (at, text) = match entries.last() {
            None => (
                close,
                missing
                    .iter()
                    .map(entry_line)
                    .collect::<Vec<_>>()
                    .join(", "),
            ),
            Some(&(_, v)) => (
                self.tree.nodes[v].end()?,
                missing
                    .iter()
                    .map(|m| format!(", {}", entry_line(m)))
                    .collect(),
            ),
        };
        Some(Edit { at, end: at, text })
    }

    /// The splice that inserts `missing` into a block mapping, and the index the new entries
    /// take among `entries`; `None` when no entry has a place after it.
    fn block_insertion(
        &self,
        src: &str,
        entries: &[(NodeId, NodeId)],
        missing: &[(&'static str, String)],
    ) -> Option<(Edit, usize)> {
        let tree = self.tree;
        // Block: a new line after an entry whose value ends its line, at that entry's key's
        // column; the last multiplier there is, else the nominal values, else any entry.
        let by_position = |a: &&(NodeId, NodeId), b: &&(NodeId, NodeId)| {
            tree.nodes[b.1].start.cmp(&tree.nodes[a.1].start)
        };
        let named = |names: &[&str]| -> Vec<&(NodeId, NodeId)> {
            let mut v: Vec<_> = entries
                .iter()
                .filter(|(k, _)| tree.nodes[*k].scalar().is_some_and(|k| names.contains(&k)))
                .collect();
            v.sort_by(by_position);
            v
        };
        let mut all: Vec<_> = entries.iter().collect();
        all.sort_by(by_position);
        let candidates = named(&MULTIPLIER_KEYS)
            .into_iter()
            .chain(named(&["wheel_radius"]))
            .chain(named(&["wheel_separation"]))
            .chain(all);
        for &(k, v) in candidates {
            let Some((at, eol)) = tree.nodes[v].end().and_then(|e| line_end_after(src, e)) else {
                continue;
            };
            let Some(indent) = key_indent(src, &tree.nodes[k]) else {
                continue;
            };
            let text = missing
                .iter()
                .map(|m| format!("{eol}{indent}{}", entry_line(m)))
                .collect();
            let index = entries
                .iter()
                .position(|e| e.0 == k)
                .map_or(entries.len(), |i| i + 1);
            return Some((Edit { at, end: at, text }, index));
        }
        None
    }
}

/// A mapping entry as a line of YAML: `key: value`.
fn entry_line((key, value): &(&str, String)) -> String {
    format!("{key}: {value}")
}

/// Sets the multipliers in `controller`'s parameters in `text`, keeping every other byte.
///
/// A multiplier there has its value replaced (a `!!float` tag, an anchor and a trailing comment
/// stay); a missing one is inserted after the section's last multiplier (else after
/// `wheel_radius`) at its indentation, or as `, key: value` at the end of a flow mapping.
/// Values always have a decimal point. The result is parsed again: the controller's section
/// must be found as before, hold exactly the values written, and every other value, key,
/// style, tag and anchor of every document must read as before.
pub fn merge_multipliers(
    text: &str,
    controller: &str,
    m: &Multipliers,
    path: &Path,
) -> Result<String, YamlError> {
    let (bom, src) = split_bom(text);
    let tree = parse_tree(src, path)?;
    let located = locate(&tree, controller, path)?;
    // A file odocal cannot read it does not edit.
    located.config()?;
    for (key, v) in MULTIPLIER_KEYS.into_iter().zip(m.values()) {
        if !(v.is_finite() && v > 0.0) {
            return Err(located.bad(key, format!("cannot be set to {v}: not a positive number")));
        }
    }
    let values = m.values().map(format_multiplier);
    let plan = located.plan(src, &values)?;
    let mut out = src.to_string();
    let mut edits = plan.edits;
    edits.sort_by_key(|e| std::cmp::Reverse(e.at));
    for e in &edits {
        out.replace_range(e.at..e.end, &e.text);
    }
    // The proof: the new text says what was meant, and nothing else changed.
    let unverified = |detail: String| YamlError::Unverified {
        path: path.to_path_buf(),
        detail,
    };
    let mut expected = tree.clone();
    for (id, value) in plan.replaced {
        if let Kind::Scalar { value: v, .. } = &mut expected.nodes[id].kind {
            *v = value;
        }
    }
    if let Some((index, entries)) = plan.inserted {
        let params = located.params;
        let mut ids = Vec::new();
        for (key, value) in entries {
            for text in [key.to_string(), value] {
                expected.nodes.push(Node {
                    kind: Kind::Scalar {
                        value: text,
                        style: TScalarStyle::Plain,
                        end: None,
                    },
                    anchor: 0,
                    tag: None,
                    parent: Some(params),
                    start: 0,
                    line: 0,
                });
                ids.push(expected.nodes.len() - 1);
            }
        }
        if let Kind::Map { entries, .. } = &mut expected.nodes[params].kind {
            let pairs: Vec<_> = ids.chunks(2).map(|p| (p[0], p[1])).collect();
            entries.splice(index..index, pairs);
        }
    }
    let after = Tree::parse(&out).map_err(|e| unverified(format!("it does not parse: {e:?}")))?;
    let back = locate(&after, controller, path)?.config()?;
    let read = [
        back.separation_multiplier,
        back.left_radius_multiplier,
        back.right_radius_multiplier,
    ];
    for ((key, got), want) in MULTIPLIER_KEYS.into_iter().zip(read).zip(&values) {
        if want.parse::<f64>().ok() != Some(got) {
            return Err(unverified(format!("`{key}` reads {got}, not {want}")));
        }
    }
    if !expected.same_documents(&after) {
        return Err(unverified(
            "something besides the multipliers changed".into(),
        ));
    }
    Ok(format!("{bom}{out}"))
}

/// The core schema's float tag (`!!float`), the one tag a written decimal keeps true.
const FLOAT_TAG: &str = "tag:yaml.org,2002:float";
