//! The bond graph as text (the listing `kausal bondgraph` prints and the
//! goldens keep) and as JSON for tools: vertices and their laws, bonds with
//! their efforts, flows and causal strokes, the simplification rules
//! applied, SCAP's decisions, storage outcomes, conflicts, the algebraic
//! loops, and the equations read off the causal graph, sorted.

use std::fmt::Write;

use super::check::Check;
use super::equations::{ReadOff, Step};
use super::scap::{Causality, ConflictKind, Phase, Stroke};
use super::{Analysis, BondGraph, BondId, Law, Rule, Var, VertexId, VertexKind};

/// A law in a few words.
fn law(g: &BondGraph, v: VertexId) -> String {
    let x = &g.vertices[v];
    let mut s = match &x.law {
        Law::Junction => match &x.name {
            Some((n, 1)) => n.clone(),
            Some((n, _)) => format!("-{n}"),
            None => String::new(),
        },
        Law::Linear {
            param,
            value,
            negated,
        } => format!(
            "{}{param} = {}",
            if *negated { "-" } else { "" },
            number(*value)
        ),
        Law::Source { name } => format!("{name}(t)"),
        Law::Controlled { param, value } => format!("{param} = {} times", number(*value)),
        Law::Nonlinear { name } => format!("{name}(…)"),
        Law::Switch { param } => format!("{param}, set as the switch turns"),
        Law::Field(f) => {
            let mut parts = vec![f.inductance.join(", ")];
            for (a, b, m) in &f.mutual {
                parts.push(format!(
                    "{m} between {} and {}",
                    f.inductance[*a], f.inductance[*b]
                ));
            }
            if let Some(s) = &f.singular {
                let pivots: Vec<&str> =
                    s.pivots.iter().map(|&p| f.inductance[p].as_str()).collect();
                parts.push(format!(
                    "singular: the fluxes of {} are the states",
                    pivots.join(", ")
                ));
            }
            parts.join("; ")
        }
    };
    if !x.signals.is_empty() {
        let sig: Vec<String> = x
            .signals
            .iter()
            .map(|&(k, s)| {
                let n = g.signal_name(s);
                if k < 0 { format!("-{n}") } else { n }
            })
            .collect();
        let _ = write!(s, " of {}", sig.join(", "));
    }
    s
}

fn number(x: f64) -> String {
    let s = format!("{x:.6e}");
    // 1.000000e3 → 1e3, 2.200000e-6 → 2.2e-6
    match s.split_once('e') {
        Some((m, e)) => {
            let m = m.trim_end_matches('0').trim_end_matches('.');
            if e == "0" {
                m.to_string()
            } else {
                format!("{m}e{e}")
            }
        }
        None => s,
    }
}

/// The vertex at the stroke end of bond `b`.
fn stroke_vertex(g: &BondGraph, c: &Causality, b: BondId) -> Option<VertexId> {
    let bond = &g.bonds[b];
    match c.strokes.get(b.0 as usize).copied().flatten()? {
        Stroke::Head => Some(bond.head),
        Stroke::Tail => Some(bond.tail),
    }
}

fn rule_text(g: &BondGraph, s: &super::Simplification) -> String {
    let name = |v: VertexId| g.vertex_name(v);
    match s.rule {
        Rule::A => {
            let bonds: Vec<String> = s.dropped.iter().map(|b| b.to_string()).collect();
            format!(
                "8a  dropped {} (the reference node; effort zero) with its bond{} {}",
                name(s.vertex),
                if bonds.len() == 1 { "" } else { "s" },
                bonds.join(", ")
            )
        }
        Rule::B => {
            let b = s
                .bond
                .zip(s.joins)
                .map(|(b, (x, y))| format!("{b} now joins {} → {}", name(x), name(y)));
            format!(
                "8b  removed {} (one bond in, one out): {}",
                name(s.vertex),
                b.unwrap_or_default()
            )
        }
        Rule::C => format!(
            "8c  merged {} into {} (equal junctions joined by {}, removed)",
            name(s.vertex),
            s.into.map(name).unwrap_or_default(),
            s.bond.map(|b| b.to_string()).unwrap_or_default()
        ),
        Rule::D => format!(
            "8d  {} needs the difference {} already drawn: one 1-junction and 0-junction for both",
            s.elem
                .map(|e| g.element_name(e).to_string())
                .unwrap_or_default(),
            g.vertices[s.vertex].label
        ),
    }
}

fn phase_name(p: Phase) -> &'static str {
    match p {
        Phase::Source => "1a",
        Phase::Fixed => "1b",
        Phase::Preferred => "2 ",
        Phase::Arbitrary => "3 ",
        Phase::Open => "4 ",
    }
}

fn conflict_text(k: ConflictKind) -> &'static str {
    match k {
        ConflictKind::Source => "a source made to take the variable it sets",
        ConflictKind::Fixed => "a winding past the field's rank made integral",
        ConflictKind::EffortTwice => "two bonds set its effort",
        ConflictKind::EffortUnset => "no bond sets its effort",
        ConflictKind::FlowTwice => "two bonds set its flow",
        ConflictKind::FlowUnset => "no bond sets its flow",
        ConflictKind::Transformer => "effort into both ports, or out of both",
        ConflictKind::Gyrator => "effort into one port and out of the other",
    }
}

/// The text listing of an analysis (and its cross-check, when given).
pub fn text(a: &Analysis, check: Option<&Check>) -> String {
    let (g, c, r) = (&a.graph, &a.causality, &a.equations);
    let mut t = String::new();
    let _ = writeln!(t, "* {}", g.title);
    let _ = writeln!(t, "bond graph (seed 003's procedure):");
    let _ = writeln!(t, "  vertices:");
    for (v, _) in g.live_vertices() {
        let _ = writeln!(t, "    {:<18} {}", g.vertex_name(v), law(g, v));
    }
    let _ = writeln!(
        t,
        "  bonds (half-arrow tail → head; stroke at the end that takes the effort):"
    );
    let width = g
        .live_bonds()
        .map(|(_, b)| g.vertex_name(b.tail).len() + g.vertex_name(b.head).len() + 3)
        .max()
        .unwrap_or(0);
    for (b, bond) in g.live_bonds() {
        let ends = format!(
            "{} → {}",
            g.vertex_name(bond.tail),
            g.vertex_name(bond.head)
        );
        let stroke = stroke_vertex(g, c, b)
            .map(|v| g.vertex_name(v))
            .unwrap_or_else(|| "none".into());
        let _ = writeln!(
            t,
            "    {:>4}  {:<width$}  e = {:<12} f = {:<12} stroke at {stroke}{}",
            b.to_string(),
            ends,
            r.bond_var(b, Var::Effort),
            r.bond_var(b, Var::Flow),
            mark(c, b),
        );
    }
    let _ = writeln!(t, "  simplification (step 8):");
    if g.simplified.is_empty() {
        let _ = writeln!(t, "    none");
    }
    for s in &g.simplified {
        let _ = writeln!(t, "    {}", rule_text(g, s));
    }
    if !g.notes.is_empty() {
        let _ = writeln!(t, "  notes:");
        for n in &g.notes {
            let _ = writeln!(t, "    {}", n.text);
        }
    }
    causality_text(&mut t, g, c, r);
    equations_text(&mut t, g, r);
    if let Some(check) = check {
        check_text(&mut t, g, check);
    }
    let n_int = c.integral().count();
    let n_der = c.derivative().count();
    let _ = writeln!(
        t,
        "summary: {} bonds, {} vertices, {} storage port{} integral, {} derivative, {} conflict{}, {} loop{}",
        g.live_bonds().count(),
        g.live_vertices().count(),
        n_int,
        if n_int == 1 { "" } else { "s" },
        n_der,
        c.conflicts.len(),
        if c.conflicts.len() == 1 { "" } else { "s" },
        r.loops().count(),
        if r.loops().count() == 1 { "" } else { "s" },
    );
    t
}

/// A bond's mark in the listing: a storage port's causality, a conflict,
/// an arbitrary choice.
fn mark(c: &Causality, b: BondId) -> &'static str {
    if c.conflicts.iter().any(|x| x.bonds.contains(&b)) {
        return "  [conflict]";
    }
    if let Some(s) = c.storage.iter().find(|s| s.bond == b) {
        return if s.integral {
            "  [integral]"
        } else {
            "  [derivative]"
        };
    }
    if c.arbitrary().any(|d| d.bond == b) {
        return "  [arbitrary]";
    }
    ""
}

fn causality_text(t: &mut String, g: &BondGraph, c: &Causality, r: &ReadOff) {
    let _ = writeln!(t, "causality (SCAP: sources, storage, resistors):");
    for d in &c.decisions {
        let what = match (d.phase, d.turned) {
            (Phase::Source, _) if g.vertices[d.vertex].kind.is_junction() => {
                "fixed (its only bond: a source of zero)"
            }
            (Phase::Source, _) => "fixed",
            (Phase::Fixed, _)
                if matches!(g.vertices[d.vertex].kind, VertexKind::C | VertexKind::I) =>
            {
                "derivative (a loop of junctions alone fixes it)"
            }
            (Phase::Fixed, _) => "fixed by its law",
            (Phase::Preferred, false) => "integral",
            (Phase::Preferred, true) => "derivative (integral would break a constraint)",
            (Phase::Arbitrary, false) => "chosen (takes the flow)",
            (Phase::Arbitrary, true) => {
                "chosen (takes the effort: the flow would break a constraint)"
            }
            (Phase::Open, _) => "chosen",
        };
        let mut line = format!(
            "    {} {} {what} on {}",
            phase_name(d.phase),
            g.vertex_name(d.vertex),
            d.bond
        );
        if !d.propagated.is_empty() {
            let p: Vec<String> = d.propagated.iter().map(|b| b.to_string()).collect();
            let _ = write!(line, "; propagated to {}", p.join(" "));
        }
        let _ = writeln!(t, "{line}");
    }
    let _ = writeln!(t, "  storage:");
    for s in &c.storage {
        let state = s
            .state
            .map(|k| {
                let prefix = match k.kind {
                    super::StateKind::Voltage => "u_",
                    super::StateKind::Current => "i_",
                    super::StateKind::Charge => "q_",
                };
                format!("{prefix}{}", g.element_name(k.elem))
            })
            .unwrap_or_default();
        let forced = s.state.is_some_and(|k| c.forced.contains(&k));
        let how = match (s.integral, s.chosen) {
            (true, true) => "integral (preferred)",
            (true, false) => "integral (by propagation)",
            (false, true) if forced => {
                "derivative: a dependent state (a loop of junctions alone fixed it)"
            }
            (false, true) => "derivative (fixed by its law)",
            (false, false) => "derivative: a dependent state",
        };
        let _ = writeln!(t, "    {:<18} {:<12} {how}", g.vertex_name(s.vertex), state);
    }
    if c.storage.is_empty() {
        let _ = writeln!(t, "    none");
    }
    let _ = writeln!(t, "  conflicts:");
    if c.conflicts.is_empty() {
        let _ = writeln!(t, "    none");
    }
    for x in &c.conflicts {
        let bonds: Vec<String> = x.bonds.iter().map(|b| b.to_string()).collect();
        let _ = writeln!(
            t,
            "    {}: {} ({})",
            g.vertex_name(x.vertex),
            conflict_text(x.kind),
            bonds.join(", ")
        );
    }
    let _ = writeln!(t, "  algebraic loops:");
    if r.loops().count() == 0 {
        let _ = writeln!(t, "    none");
    }
    for (k, l) in r.loops().enumerate() {
        let _ = writeln!(t, "    loop {}: {}", k + 1, loop_text(g, l));
    }
}

fn loop_text(g: &BondGraph, l: &super::equations::Loop) -> String {
    let names = |vs: &[VertexId]| {
        vs.iter()
            .map(|&v| g.vertex_name(v))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let elements: Vec<&str> = l.elements.iter().map(|&e| g.element_name(e)).collect();
    let mut s = format!(
        "{} equations through {}",
        l.eqs.len(),
        if elements.is_empty() {
            "junctions only".to_string()
        } else {
            elements.join(", ")
        }
    );
    if !l.arbitrary.is_empty() {
        let _ = write!(s, "; arbitrary causality of {}", names(&l.arbitrary));
    }
    if !l.derivative.is_empty() {
        let _ = write!(s, "; derivative causality of {}", names(&l.derivative));
    }
    s
}

fn equations_text(t: &mut String, g: &BondGraph, r: &ReadOff) {
    let _ = writeln!(t, "equations read off the causal bond graph, sorted:");
    let width = r
        .equations
        .iter()
        .enumerate()
        .map(|(k, _)| r.print(k).chars().count())
        .max()
        .unwrap_or(0)
        .min(60);
    let mut n = 0;
    let mut line = |t: &mut String, k: usize, indent: &str| {
        n += 1;
        let e = &r.equations[k];
        let mut origin = g.vertex_name(e.vertex);
        if let Some(of) = e.of {
            origin = format!("d/dt of ({}) {origin}", of + 1);
        } else if e.constraint {
            origin = format!("d/dt of {origin}'s balance (the constraint)");
        }
        let _ = writeln!(
            t,
            "  {n:>3}{indent}{:<width$}  ; ({}) {origin}",
            r.print(k),
            k + 1
        );
    };
    let mut loops = 0;
    for s in &r.steps {
        match s {
            Step::Assign(k) => line(t, *k, "  "),
            Step::Loop(l) => {
                loops += 1;
                let _ = writeln!(t, "       loop {loops}: {}", loop_text(g, l));
                for &k in &l.eqs {
                    line(t, k, "    ");
                }
                let _ = writeln!(t, "       end of loop {loops}");
            }
        }
    }
    for (what, list) in [
        ("computed twice", &r.twice),
        ("computed by no equation", &r.unknown),
    ] {
        if !list.is_empty() {
            let names: Vec<String> = list
                .iter()
                .map(|&x| super::equations::print_ref(x, &|q| r.name(q)))
                .collect();
            let _ = writeln!(t, "  {what} (a causal conflict): {}", names.join(", "));
        }
    }
    if !r.too_deep.is_empty() {
        let names: Vec<String> = r
            .too_deep
            .iter()
            .map(|&x| super::equations::print_ref(x, &|q| r.name(q)))
            .collect();
        let _ = writeln!(
            t,
            "  not written: {} (differentiating along this causality needs ever higher derivatives; index reduction differentiates the loop's constraint instead)",
            names.join(", ")
        );
    }
}

fn check_text(t: &mut String, g: &BondGraph, check: &Check) {
    let _ = writeln!(
        t,
        "cross-check with the colouring and index reduction: {}",
        if check.agrees() { "agree" } else { "DIFFER" }
    );
    for f in &check.findings {
        let _ = writeln!(
            t,
            "  {:<20} {:<6} {}",
            f.item.title(),
            if f.agrees { "agree" } else { "DIFFER" },
            f.text
        );
    }
    if let Some((alt, _)) = &check.alternative {
        let der: Vec<String> = alt.derivative().map(|s| g.vertex_name(s.vertex)).collect();
        let _ = writeln!(
            t,
            "  (the findings after the first use SCAP's equally valid assignment with {} in derivative causality)",
            der.join(", ")
        );
    }
}

/// The analysis as JSON, names resolved (and the cross-check, when given).
pub fn json(a: &Analysis, check: Option<&Check>) -> serde_json::Value {
    let (g, c, r) = (&a.graph, &a.causality, &a.equations);
    let vertices: Vec<serde_json::Value> = g
        .live_vertices()
        .map(|(v, x)| {
            serde_json::json!({
                "id": v,
                "name": g.vertex_name(v),
                "kind": x.kind,
                "origin": x.origin,
                "law": law(g, v),
                "bonds": x.bonds,
            })
        })
        .collect();
    let bonds: Vec<serde_json::Value> = g
        .live_bonds()
        .map(|(b, bond)| {
            serde_json::json!({
                "id": b,
                "tail": bond.tail,
                "head": bond.head,
                "effort": r.bond_var(b, Var::Effort),
                "flow": r.bond_var(b, Var::Flow),
                "stroke": c.strokes[b.0 as usize],
                "stroke_at": stroke_vertex(g, c, b),
            })
        })
        .collect();
    let simplified: Vec<serde_json::Value> = g
        .simplified
        .iter()
        .map(|s| serde_json::json!({"rule": s.rule, "text": rule_text(g, s)}))
        .collect();
    let equations: Vec<serde_json::Value> = r
        .equations
        .iter()
        .enumerate()
        .map(|(k, e)| {
            serde_json::json!({
                "text": r.print(k),
                "vertex": e.vertex,
                "element": e.element.map(|x| g.element_name(x)),
                "law": e.law,
                "differentiates": e.of,
            })
        })
        .collect();
    let mut v = serde_json::json!({
        "title": g.title,
        "vertices": vertices,
        "bonds": bonds,
        "simplified": simplified,
        "notes": g.notes.iter().map(|n| &n.text).collect::<Vec<_>>(),
        "causality": {
            "decisions": c.decisions,
            "storage": c.storage,
            "conflicts": c.conflicts,
        },
        "equations": equations,
        "sorted": r.steps,
    });
    if let Some(check) = check {
        v["check"] = serde_json::json!({
            "agrees": check.agrees(),
            "findings": check.findings,
        });
    }
    v
}
