//! The causal bond graph as Graphviz DOT: junctions as `0` and `1` (the
//! potential or difference they stand for beside them), elements as
//! `Se:V1`, `R:R1`; every bond a line with the half-arrow of its power
//! direction at its head and the causal stroke (a bar) at the end that takes
//! the effort. Storage in derivative causality is red, conflicts magenta,
//! arbitrary choices blue. The library returns the text; the command line
//! runs `dot` for SVG.

use std::fmt::Write;

use super::scap::{Causality, Stroke};
use super::{Analysis, BondId, VertexId, VertexKind};

const DERIVATIVE: &str = "red";
const CONFLICT: &str = "magenta";
const ARBITRARY: &str = "blue";

fn quote(s: &str) -> String {
    let mut q = String::with_capacity(s.len() + 2);
    q.push('"');
    for ch in s.chars() {
        match ch {
            '"' | '\\' => {
                q.push('\\');
                q.push(ch);
            }
            '\n' => q.push_str("\\n"),
            _ => q.push(ch),
        }
    }
    q.push('"');
    q
}

/// The colour of a bond, if it is marked.
fn colour(c: &Causality, b: BondId) -> Option<&'static str> {
    if c.conflicts.iter().any(|x| x.bonds.contains(&b)) {
        Some(CONFLICT)
    } else if c.derivative().any(|s| s.bond == b) {
        Some(DERIVATIVE)
    } else if c.arbitrary().any(|d| d.bond == b) {
        Some(ARBITRARY)
    } else {
        None
    }
}

/// The colour of a vertex: a storage element in derivative causality, a
/// vertex with a conflict.
fn vertex_colour(c: &Causality, v: VertexId) -> Option<&'static str> {
    if c.conflicts.iter().any(|x| x.vertex == v) {
        Some(CONFLICT)
    } else if c.derivative().any(|s| s.vertex == v) {
        Some(DERIVATIVE)
    } else {
        None
    }
}

/// The causal bond graph of `a` as DOT text.
pub fn dot(a: &Analysis) -> String {
    let (g, c) = (&a.graph, &a.causality);
    let mut t = String::new();
    let _ = writeln!(t, "digraph bondgraph {{");
    let _ = writeln!(
        t,
        "  graph [rankdir=LR, fontname=\"Helvetica\", fontsize=12, labelloc=t, label={}];",
        quote(&format!(
            "{}\ncausal strokes (bar) at the end that takes the effort; red: derivative causality, magenta: conflict, blue: arbitrary",
            g.title
        ))
    );
    let _ = writeln!(
        t,
        "  node [fontname=\"Helvetica\", fontsize=12, shape=plaintext];"
    );
    let _ = writeln!(
        t,
        "  edge [fontname=\"Helvetica\", fontsize=8, arrowsize=1.1, fontcolor=\"gray40\"];"
    );
    for (v, x) in g.live_vertices() {
        let mut attrs = Vec::new();
        if x.kind.is_junction() {
            attrs.push(format!("label={}", quote(x.kind.symbol())));
            attrs.push(format!("xlabel={}", quote(&x.label)));
            attrs.push("fontsize=16".to_string());
            attrs.push("width=0.3".to_string());
            attrs.push("height=0.3".to_string());
        } else {
            attrs.push(format!("label={}", quote(&g.vertex_name(v))));
            if matches!(x.kind, VertexKind::MSe | VertexKind::MSf | VertexKind::MR)
                && !x.signals.is_empty()
            {
                let sig: Vec<String> = x.signals.iter().map(|&(_, s)| g.signal_name(s)).collect();
                attrs.push(format!(
                    "tooltip={}",
                    quote(&format!("reads {}", sig.join(", ")))
                ));
            }
        }
        if let Some(col) = vertex_colour(c, v) {
            attrs.push(format!("fontcolor={col}"));
        }
        let _ = writeln!(t, "  {v} [{}];", attrs.join(", "));
    }
    for (b, bond) in g.live_bonds() {
        let _ = writeln!(
            t,
            "  {} -> {} [{}];",
            bond.tail,
            bond.head,
            bond_attrs(c, a, b).join(", ")
        );
    }
    let _ = writeln!(t, "}}");
    t
}

fn bond_attrs(c: &Causality, a: &Analysis, b: BondId) -> Vec<String> {
    let mut attrs = vec![format!("label={}", quote(&b.0.to_string()))];
    // The half-arrow is the head's; the stroke goes at the end that takes
    // the effort, nearest its vertex.
    match c.strokes.get(b.0 as usize).copied().flatten() {
        Some(Stroke::Head) => attrs.push("arrowhead=teelvee".to_string()),
        Some(Stroke::Tail) => {
            attrs.push("dir=both".to_string());
            attrs.push("arrowtail=tee".to_string());
            attrs.push("arrowhead=lvee".to_string());
        }
        None => attrs.push("arrowhead=lvee".to_string()),
    }
    if let Some(col) = colour(c, b) {
        attrs.push(format!("color={col}"));
        attrs.push("penwidth=1.6".to_string());
    }
    let e = a.equations.bond_var(b, super::Var::Effort);
    let f = a.equations.bond_var(b, super::Var::Flow);
    attrs.push(format!(
        "tooltip={}",
        quote(&format!("{b}: e = {e}, f = {f}"))
    ));
    attrs
}
