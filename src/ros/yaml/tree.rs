//! A YAML text as a tree of nodes that know where they stand in the text, so that a value can
//! be replaced (or an entry inserted) by splicing bytes and everything else stays as written.
//!
//! yaml-rust2's event parser gives each event a start marker only, in characters (line 1-based,
//! column 0-based); its `index()` counts characters and drifts after non-ASCII block scalars, so
//! byte offsets are computed here from line and column. The ends the splicer needs — of a
//! single-line plain or quoted scalar, of an alias, of a flow collection — are found by reading
//! the text; where an end cannot be known (block scalars, block collections, a plain scalar over
//! several lines) it is `None` and nothing is spliced there. The events are pulled one at a time
//! (the parser's own `load` recurses), nesting and size are bounded, anchors are recorded with
//! the aliases that use them, duplicate keys are kept (rcl accepts them; callers judge).

use std::collections::HashMap;
use yaml_rust2::parser::{Event, Parser};
use yaml_rust2::scanner::{Marker, ScanError, TScalarStyle};

/// Index of a node in [`Tree::nodes`].
pub(crate) type NodeId = usize;

/// Deepest nesting accepted: parameter files nest about eight levels; the bound keeps the
/// recursive walks over a tree far from the end of a thread's stack.
pub(crate) const MAX_DEPTH: usize = 64;

/// Most nodes accepted: a parameter file has hundreds; the bound keeps a 16 MiB file of one-
/// character scalars from taking gigabytes.
pub(crate) const MAX_NODES: usize = 200_000;

/// What a node is.
#[derive(Debug, Clone)]
pub(crate) enum Kind {
    /// A scalar: its value, style, and the byte after its text when that is known.
    Scalar {
        value: String,
        style: TScalarStyle,
        end: Option<usize>,
    },
    /// `*name`: the anchor it refers to, and the byte after its text.
    Alias { anchor: usize, end: usize },
    /// A mapping's entries in order (duplicates kept); for a flow mapping, the byte of its `}`.
    Map {
        entries: Vec<(NodeId, NodeId)>,
        close: Option<usize>,
    },
    /// A sequence's items; for a flow sequence, the byte of its `]`.
    Seq {
        items: Vec<NodeId>,
        close: Option<usize>,
    },
}

/// A node and where it is.
#[derive(Debug, Clone)]
pub(crate) struct Node {
    pub kind: Kind,
    /// Anchor id (`&name`), 0 for none.
    pub anchor: usize,
    /// The resolved tag (`tag:yaml.org,2002:float`), if the node has one.
    pub tag: Option<String>,
    /// The collection holding it.
    pub parent: Option<NodeId>,
    /// Byte of the event's marker: a scalar's first character (its quote), an alias's `*`,
    /// a flow collection's bracket; for a block collection, somewhere on its first line.
    pub start: usize,
    /// 1-based line of `start`.
    pub line: usize,
}

impl Node {
    /// The byte after the node's text, when it is known.
    pub fn end(&self) -> Option<usize> {
        match &self.kind {
            Kind::Scalar { end, .. } => *end,
            Kind::Alias { end, .. } => Some(*end),
            Kind::Map { close, .. } | Kind::Seq { close, .. } => close.map(|c| c + 1),
        }
    }

    /// The scalar's value, if it is a scalar.
    pub fn scalar(&self) -> Option<&str> {
        match &self.kind {
            Kind::Scalar { value, .. } => Some(value),
            _ => None,
        }
    }
}

/// Why a text is not a tree.
#[derive(Debug, thiserror::Error)]
pub enum TreeError {
    /// Not YAML.
    #[error("not YAML: {0}")]
    Scan(#[source] ScanError),
    /// Nested deeper than `MAX_DEPTH` (64) levels (at this 1-based line).
    #[error("line {0}: nested deeper than {MAX_DEPTH} levels")]
    TooDeep(usize),
    /// More than `MAX_NODES` (200 000) nodes (at this line).
    #[error("line {0}: more than {MAX_NODES} values")]
    TooBig(usize),
}

/// Every document of a YAML text; see the module.
#[derive(Debug, Clone)]
pub(crate) struct Tree {
    pub nodes: Vec<Node>,
    /// Each document's root.
    pub docs: Vec<NodeId>,
    /// The node each anchor id names.
    pub anchors: HashMap<usize, NodeId>,
    /// The lines of the aliases of each anchor id.
    pub aliases: HashMap<usize, Vec<usize>>,
}

/// Byte offsets of line starts, to turn markers into byte offsets.
struct Lines<'s> {
    src: &'s str,
    starts: Vec<usize>,
    ascii: bool,
    /// The last marker converted (line, column, byte): markers mostly move forward, so a long
    /// line of multi-byte text is walked once rather than from its start for every marker.
    cursor: (usize, usize, usize),
}

impl<'s> Lines<'s> {
    fn new(src: &'s str) -> Self {
        let mut starts = vec![0];
        starts.extend(src.match_indices('\n').map(|(i, _)| i + 1));
        Lines {
            src,
            starts,
            ascii: src.is_ascii(),
            cursor: (0, 0, 0),
        }
    }

    /// The byte a marker points at (line 1-based, column in characters).
    fn byte_of(&mut self, m: &Marker) -> usize {
        let Some(&start) = m.line().checked_sub(1).and_then(|l| self.starts.get(l)) else {
            return self.src.len();
        };
        if self.ascii {
            return (start + m.col()).min(self.src.len());
        }
        let (line, col, byte) = self.cursor;
        let (from_col, from_byte) = if line == m.line() && col <= m.col() {
            (col, byte)
        } else {
            (0, start)
        };
        let byte = self.src[from_byte..]
            .char_indices()
            .nth(m.col() - from_col)
            .map_or(self.src.len(), |(b, _)| from_byte + b);
        self.cursor = (m.line(), m.col(), byte);
        byte
    }
}

/// The byte after a scalar's text starting at `start`, when it can be known.
fn scalar_end(src: &str, start: usize, value: &str, style: TScalarStyle) -> Option<usize> {
    let rest = src.get(start..)?;
    match style {
        // A single-line plain scalar is its own text; an empty one has none (its marker is at
        // the next token), and one over several lines was folded.
        TScalarStyle::Plain => {
            (!value.is_empty() && !value.contains(['\n', '\r']) && rest.starts_with(value))
                .then_some(start + value.len())
        }
        TScalarStyle::SingleQuoted => {
            let b = rest.as_bytes();
            let mut i = 1;
            while i < b.len() {
                if b[i] == b'\'' {
                    if b.get(i + 1) == Some(&b'\'') {
                        i += 2;
                        continue;
                    }
                    return Some(start + i + 1);
                }
                i += 1;
            }
            None
        }
        TScalarStyle::DoubleQuoted => {
            let b = rest.as_bytes();
            let mut i = 1;
            while i < b.len() {
                match b[i] {
                    b'\\' => i += 2,
                    b'"' => return Some(start + i + 1),
                    _ => i += 1,
                }
            }
            None
        }
        TScalarStyle::Literal | TScalarStyle::Folded => None,
    }
}

/// The byte after an alias `*name` starting at `start`.
fn alias_end(src: &str, start: usize) -> usize {
    let rest = src.get(start + 1..).unwrap_or("");
    let len = rest
        .find(|c: char| c.is_whitespace() || ",[]{}".contains(c))
        .unwrap_or(rest.len());
    start + 1 + len
}

/// An open collection while the events are read.
struct Open {
    id: NodeId,
    /// For a mapping: the key read, waiting for its value.
    key: Option<NodeId>,
}

impl Tree {
    /// Reads every document of `src` (without a byte-order mark).
    pub fn parse(src: &str) -> Result<Tree, TreeError> {
        let mut lines = Lines::new(src);
        let mut tree = Tree {
            nodes: Vec::new(),
            docs: Vec::new(),
            anchors: HashMap::new(),
            aliases: HashMap::new(),
        };
        let mut open: Vec<Open> = Vec::new();
        let mut parser = Parser::new_from_str(src);
        loop {
            let (event, mark) = parser.next_token().map_err(TreeError::Scan)?;
            let start = lines.byte_of(&mark);
            let node = |kind: Kind, anchor: usize, tag: Option<yaml_rust2::parser::Tag>| Node {
                kind,
                anchor,
                tag: tag.map(|t| format!("{}{}", t.handle, t.suffix)),
                parent: None,
                start,
                line: mark.line(),
            };
            let (new, collection) = match event {
                Event::StreamEnd => break,
                Event::MappingEnd | Event::SequenceEnd => {
                    if let Some(done) = open.pop() {
                        // A flow collection ends at its bracket; a block one at the next token.
                        let at = src.as_bytes().get(start);
                        match &mut tree.nodes[done.id].kind {
                            Kind::Map { close, .. } if at == Some(&b'}') => *close = Some(start),
                            Kind::Seq { close, .. } if at == Some(&b']') => *close = Some(start),
                            _ => {}
                        }
                    }
                    continue;
                }
                Event::Scalar(value, style, anchor, tag) => {
                    let end = scalar_end(src, start, &value, style);
                    (node(Kind::Scalar { value, style, end }, anchor, tag), false)
                }
                Event::Alias(anchor) => {
                    tree.aliases.entry(anchor).or_default().push(mark.line());
                    let end = alias_end(src, start);
                    (node(Kind::Alias { anchor, end }, 0, None), false)
                }
                Event::MappingStart(anchor, tag) => {
                    let kind = Kind::Map {
                        entries: Vec::new(),
                        close: None,
                    };
                    (node(kind, anchor, tag), true)
                }
                Event::SequenceStart(anchor, tag) => {
                    let kind = Kind::Seq {
                        items: Vec::new(),
                        close: None,
                    };
                    (node(kind, anchor, tag), true)
                }
                Event::Nothing | Event::StreamStart | Event::DocumentStart | Event::DocumentEnd => {
                    continue
                }
            };
            if tree.nodes.len() >= MAX_NODES {
                return Err(TreeError::TooBig(mark.line()));
            }
            let id = tree.nodes.len();
            let anchor = new.anchor;
            tree.nodes.push(new);
            if anchor != 0 {
                tree.anchors.insert(anchor, id);
            }
            match open.last_mut() {
                None => tree.docs.push(id),
                Some(parent) => {
                    tree.nodes[id].parent = Some(parent.id);
                    match (&mut tree.nodes[parent.id].kind, parent.key.take()) {
                        (Kind::Map { entries, .. }, Some(key)) => entries.push((key, id)),
                        (Kind::Map { .. }, None) => parent.key = Some(id),
                        (Kind::Seq { items, .. }, _) => items.push(id),
                        _ => {}
                    }
                }
            }
            if collection {
                if open.len() >= MAX_DEPTH {
                    return Err(TreeError::TooDeep(mark.line()));
                }
                open.push(Open { id, key: None });
            }
        }
        Ok(tree)
    }

    /// The node itself, or for an alias the node its anchor names.
    pub fn resolve(&self, id: NodeId) -> NodeId {
        match self.nodes[id].kind {
            Kind::Alias { anchor, .. } => self.anchors.get(&anchor).copied().unwrap_or(id),
            _ => id,
        }
    }

    /// The entries of a mapping (after following an alias), or none.
    pub fn entries(&self, id: NodeId) -> &[(NodeId, NodeId)] {
        match &self.nodes[self.resolve(id)].kind {
            Kind::Map { entries, .. } => entries,
            _ => &[],
        }
    }

    /// The items of a sequence (after following an alias), or none.
    pub fn items(&self, id: NodeId) -> &[NodeId] {
        match &self.nodes[self.resolve(id)].kind {
            Kind::Seq { items, .. } => items,
            _ => &[],
        }
    }

    /// The scalar at `id` (after following an alias), unless it is YAML's null (`~`, `null`,
    /// or nothing, unquoted) or not a scalar.
    pub fn text(&self, id: NodeId) -> Option<&str> {
        match &self.nodes[self.resolve(id)].kind {
            Kind::Scalar { value, style, .. } => {
                let null = *style == TScalarStyle::Plain
                    && matches!(value.as_str(), "" | "~" | "null" | "Null" | "NULL");
                (!null).then_some(value.as_str())
            }
            _ => None,
        }
    }

    /// The value of `key` in mapping `map` (the first, if the key is there twice).
    pub fn get(&self, map: NodeId, key: &str) -> Option<NodeId> {
        self.entries(map)
            .iter()
            .find(|(k, _)| self.nodes[*k].scalar() == Some(key))
            .map(|&(_, v)| v)
    }

    /// The first node from `id` up to the root carrying an anchor that an alias uses: what
    /// changing `id` would change elsewhere too. Returns that node and the first alias's line.
    pub fn shared_ancestor(&self, id: NodeId) -> Option<(NodeId, usize)> {
        let mut at = Some(id);
        while let Some(n) = at {
            let node = &self.nodes[n];
            if node.anchor != 0 {
                if let Some(&line) = self.aliases.get(&node.anchor).and_then(|l| l.first()) {
                    return Some((n, line));
                }
            }
            at = node.parent;
        }
        None
    }

    /// The line where node `id`'s anchor is written: a block collection's marker is on its
    /// first entry's line, its `&name` on its key's.
    pub fn anchor_line(&self, id: NodeId) -> usize {
        let node = &self.nodes[id];
        let block = matches!(
            node.kind,
            Kind::Map { close: None, .. } | Kind::Seq { close: None, .. }
        );
        let key = node.parent.and_then(|p| match &self.nodes[p].kind {
            Kind::Map { entries, .. } => entries.iter().find(|e| e.1 == id).map(|e| e.0),
            _ => None,
        });
        match key {
            Some(k) if block => self.nodes[k].line,
            _ => node.line,
        }
    }

    /// Whether node `a` of this tree and node `b` of `other` say the same (values, styles,
    /// tags, anchors and structure; not where they are).
    pub fn same(&self, a: NodeId, other: &Tree, b: NodeId) -> bool {
        let (x, y) = (&self.nodes[a], &other.nodes[b]);
        if x.anchor != y.anchor || x.tag != y.tag {
            return false;
        }
        match (&x.kind, &y.kind) {
            (
                Kind::Scalar {
                    value: v1,
                    style: s1,
                    ..
                },
                Kind::Scalar {
                    value: v2,
                    style: s2,
                    ..
                },
            ) => v1 == v2 && s1 == s2,
            (Kind::Alias { anchor: a1, .. }, Kind::Alias { anchor: a2, .. }) => a1 == a2,
            (
                Kind::Map {
                    entries: e1,
                    close: c1,
                },
                Kind::Map {
                    entries: e2,
                    close: c2,
                },
            ) => {
                c1.is_some() == c2.is_some()
                    && e1.len() == e2.len()
                    && e1.iter().zip(e2).all(|(&(k1, v1), &(k2, v2))| {
                        self.same(k1, other, k2) && self.same(v1, other, v2)
                    })
            }
            (
                Kind::Seq {
                    items: i1,
                    close: c1,
                },
                Kind::Seq {
                    items: i2,
                    close: c2,
                },
            ) => {
                c1.is_some() == c2.is_some()
                    && i1.len() == i2.len()
                    && i1.iter().zip(i2).all(|(&p, &q)| self.same(p, other, q))
            }
            _ => false,
        }
    }

    /// Whether every document of this tree says the same as `other`'s ([`Tree::same`]).
    pub fn same_documents(&self, other: &Tree) -> bool {
        self.docs.len() == other.docs.len()
            && self
                .docs
                .iter()
                .zip(&other.docs)
                .all(|(&a, &b)| self.same(a, other, b))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn text_of<'a>(src: &'a str, t: &Tree, id: NodeId) -> &'a str {
        &src[t.nodes[id].start..t.nodes[id].end().unwrap()]
    }

    #[test]
    fn spans_are_bytes_even_after_non_ascii_text() {
        // Multi-byte characters before the values (the marker counts characters).
        let src = "note: |\n  ééé ☃\nk: 'it''s' # c\r\nq: \"a\\\"b\"\nv: &a 1.5\nw: *a\nf: {x: [1, 2] }\n";
        let t = Tree::parse(src).unwrap();
        let root = t.docs[0];
        let get = |k: &str| t.get(root, k).unwrap();
        assert_eq!(
            t.nodes[get("note")].end(),
            None,
            "a block scalar has no end"
        );
        assert_eq!(text_of(src, &t, get("k")), "'it''s'");
        assert_eq!(text_of(src, &t, get("q")), "\"a\\\"b\"");
        assert_eq!(text_of(src, &t, get("v")), "1.5");
        assert_eq!(text_of(src, &t, get("w")), "*a");
        assert_eq!(text_of(src, &t, get("f")), "{x: [1, 2] }");
        assert_eq!(t.shared_ancestor(get("v")).map(|(_, l)| l), Some(6));
        assert_eq!(t.resolve(get("w")), get("v"));
    }

    #[test]
    fn empty_and_folded_plain_scalars_have_no_end() {
        let src = "a:\nb: x\n  y\nc: 2\n";
        let t = Tree::parse(src).unwrap();
        let root = t.docs[0];
        assert_eq!(t.nodes[t.get(root, "a").unwrap()].end(), None);
        assert_eq!(t.nodes[t.get(root, "b").unwrap()].end(), None);
        assert_eq!(text_of(src, &t, t.get(root, "c").unwrap()), "2");
    }

    #[test]
    fn nesting_and_size_are_bounded_without_recursion() {
        let deep = "[".repeat(200);
        assert!(matches!(
            Tree::parse(&deep),
            Err(TreeError::TooDeep(_) | TreeError::Scan(_))
        ));
        let deep_block: String = (0..100)
            .map(|i| format!("{}k{i}:\n", " ".repeat(i)))
            .collect();
        assert!(matches!(
            Tree::parse(&deep_block),
            Err(TreeError::TooDeep(_))
        ));
        // One long line of multi-byte text: each marker is converted in constant time.
        let wide = format!("[é, {}]", "1,".repeat(MAX_NODES));
        let started = std::time::Instant::now();
        assert!(matches!(Tree::parse(&wide), Err(TreeError::TooBig(1))));
        assert!(
            started.elapsed().as_secs_f64() < 10.0,
            "{:?}",
            started.elapsed()
        );
    }

    #[test]
    fn documents_and_duplicate_keys_are_kept() {
        let src = "/**:\n  a: 1\n/**:\n  b: 2\n---\nc: 3\n";
        let t = Tree::parse(src).unwrap();
        assert_eq!(t.docs.len(), 2);
        assert_eq!(t.entries(t.docs[0]).len(), 2);
        assert!(t.same_documents(&Tree::parse(src).unwrap()));
        assert!(!t.same_documents(&Tree::parse(&src.replace("c: 3", "c: 4")).unwrap()));
    }
}
