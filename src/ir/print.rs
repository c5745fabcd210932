//! Text form of expressions and equations, used by listings and snapshots.
//!
//! Constants print in Rust's shortest round-trip form, so output is
//! deterministic across machines.

use std::fmt::Write;

use super::expr::{Expr, ExprArena, ExprId};
use super::system::{EqId, EquationSystem};

/// Format a constant the way listings show it (`1000`, `1e-9`, `0.5`).
pub fn number(x: f64) -> String {
    if x == 0.0 {
        return "0".into();
    }
    let a = x.abs();
    if (1e-3..1e6).contains(&a) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

fn prec(e: Expr) -> u8 {
    match e {
        Expr::Cmp(..) => 0,
        Expr::Add(..) | Expr::Sub(..) => 1,
        Expr::Mul(..) | Expr::Div(..) => 2,
        Expr::Neg(..) => 3,
        Expr::Pow(..) => 4,
        Expr::Const(b) if f64::from_bits(b) < 0.0 => 3,
        _ => 5,
    }
}

/// Append the text of expression `id` to `out`.
pub fn write_expr(sys: &EquationSystem, id: ExprId, out: &mut String) {
    write_expr_in(sys, &sys.exprs, id, out)
}

/// Like [`write_expr`] for an arena that extends the system's (a schedule's).
pub fn write_expr_in(sys: &EquationSystem, x: &ExprArena, id: ExprId, out: &mut String) {
    let e = x.get(id);
    let child = |c: ExprId, min: u8, out: &mut String| {
        let paren = prec(x.get(c)) < min;
        if paren {
            out.push('(');
        }
        write_expr_in(sys, x, c, out);
        if paren {
            out.push(')');
        }
    };
    match e {
        Expr::Const(b) => out.push_str(&number(f64::from_bits(b))),
        Expr::Var(v) => out.push_str(sys.var_name(v)),
        Expr::Param(p) => out.push_str(&sys.params[p].name),
        Expr::Time => out.push('t'),
        Expr::TimeRate => out.push_str("der(t)"),
        Expr::Source(s, order) => {
            let name = &sys.source_name(s);
            match order {
                0 => {
                    let _ = write!(out, "{name}(t)");
                }
                1 => {
                    let _ = write!(out, "der({name}(t))");
                }
                k => {
                    let _ = write!(out, "der{k}({name}(t))");
                }
            }
        }
        Expr::Neg(a) => {
            out.push('-');
            child(a, 4, out);
        }
        Expr::Add(a, b) => {
            child(a, 1, out);
            out.push_str(" + ");
            child(b, 2, out);
        }
        Expr::Sub(a, b) => {
            child(a, 1, out);
            out.push_str(" - ");
            child(b, 2, out);
        }
        Expr::Mul(a, b) => {
            child(a, 2, out);
            out.push('*');
            child(b, 3, out);
        }
        Expr::Div(a, b) => {
            child(a, 2, out);
            out.push('/');
            child(b, 3, out);
        }
        Expr::Pow(a, b) => {
            child(a, 5, out);
            out.push('^');
            child(b, 5, out);
        }
        Expr::Device(f, a) => {
            let d = &sys.diodes[f.diode as usize];
            let part = match f.part {
                crate::ir::DiodePart::Current => "id",
                crate::ir::DiodePart::Charge => "q",
            };
            let _ = write!(out, "{part}_{}{}(", d.name, "'".repeat(f.order as usize));
            write_expr_in(sys, x, a, out);
            out.push(')');
        }
        Expr::Call(f, a) => {
            out.push_str(f.name());
            out.push('(');
            write_expr_in(sys, x, a, out);
            out.push(')');
        }
        Expr::Cmp(op, a, b) => {
            child(a, 1, out);
            let _ = write!(out, " {} ", op.symbol());
            child(b, 1, out);
        }
        // As ngspice's B sources write a choice: `(c ? a : b)`.
        Expr::Select(c, a, b) => {
            out.push('(');
            write_expr_in(sys, x, c, out);
            out.push_str(" ? ");
            write_expr_in(sys, x, a, out);
            out.push_str(" : ");
            write_expr_in(sys, x, b, out);
            out.push(')');
        }
    }
}

pub fn expr(sys: &EquationSystem, id: ExprId) -> String {
    let mut s = String::new();
    write_expr(sys, id, &mut s);
    s
}

/// `lhs = rhs` of an equation.
pub fn equation(sys: &EquationSystem, eq: EqId) -> String {
    let e = &sys.eqs[eq];
    let mut s = String::new();
    write_expr(sys, e.lhs, &mut s);
    s.push_str(" = ");
    write_expr(sys, e.rhs, &mut s);
    s
}

impl EquationSystem {
    pub fn source_name(&self, s: super::SourceId) -> &str {
        &self.sources[s].name
    }
}

/// The numbered equations, unknowns, states, eliminated aliases and the
/// incidence matrix (omitted above `max_incidence` unknowns).
pub fn system(sys: &EquationSystem, max_incidence: usize) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "* {}", sys.title);
    let texts: Vec<String> = sys.eqs.ids().map(|eq| equation(sys, eq)).collect();
    let width = texts.iter().map(|t| t.len()).max().unwrap_or(0).min(60);
    let _ = writeln!(out, "equations ({}):", sys.eqs.len());
    for ((eq, e), text) in sys.eqs.iter().zip(&texts) {
        let _ = writeln!(
            out,
            "  {:>5}  {:<width$}    ; {}",
            eq.to_string(),
            text,
            e.origin.describe()
        );
    }
    let unknowns: Vec<super::VarId> = sys.unknowns().collect();
    let names = |ids: &[super::VarId]| {
        ids.iter()
            .map(|&v| sys.var_name(v))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let _ = writeln!(out, "unknowns ({}): {}", unknowns.len(), names(&unknowns));
    let states: Vec<super::VarId> = sys.states().collect();
    let _ = writeln!(out, "states ({}): {}", states.len(), names(&states));
    if !sys.eliminated.is_empty() {
        let _ = writeln!(out, "eliminated ({}):", sys.eliminated.len());
        for e in &sys.eliminated {
            let _ = writeln!(out, "  {e}");
        }
    }
    if unknowns.len() > max_incidence {
        let _ = writeln!(
            out,
            "incidence: omitted ({} unknowns; use --format json)",
            unknowns.len()
        );
        return out;
    }
    let _ = writeln!(out, "incidence (rows: equations; columns: unknowns):");
    for (k, &v) in unknowns.iter().enumerate() {
        let _ = writeln!(out, "  c{k:<3} {}", sys.var_name(v));
    }
    let mut col = vec![usize::MAX; sys.vars.len()];
    for (k, &v) in unknowns.iter().enumerate() {
        col[v.0 as usize] = k;
    }
    let _ = write!(out, "  {:>5} ", "");
    for k in 0..unknowns.len() {
        let _ = write!(out, "{}", k % 10);
    }
    out.push('\n');
    let (mut vars, mut stack) = (Vec::new(), Vec::new());
    for eq in sys.eqs.ids() {
        sys.eq_vars(eq, &mut vars, &mut stack);
        let mut row = vec!['.'; unknowns.len()];
        for v in &vars {
            let c = col[v.0 as usize];
            if c != usize::MAX {
                row[c] = 'x';
            }
        }
        let _ = writeln!(
            out,
            "  {:>5} {}",
            eq.to_string(),
            row.iter().collect::<String>()
        );
    }
    out
}

/// The same content as [`system`], as JSON for tools.
pub fn system_json(sys: &EquationSystem) -> serde_json::Value {
    use serde_json::json;
    let (mut vars, mut stack) = (Vec::new(), Vec::new());
    let eqs: Vec<serde_json::Value> = sys
        .eqs
        .iter()
        .map(|(id, e)| {
            sys.eq_vars(id, &mut vars, &mut stack);
            let unknowns: Vec<String> = vars
                .iter()
                .filter(|&&v| sys.vars[v].is_unknown())
                .map(|&v| sys.var_name(v).to_string())
                .collect();
            json!({
                "id": id.to_string(),
                "text": equation(sys, id),
                "lhs": expr(sys, e.lhs),
                "rhs": expr(sys, e.rhs),
                "origin": e.origin.describe(),
                "elements": e.origin.elements(),
                "unknowns": unknowns,
            })
        })
        .collect();
    let var_list: Vec<serde_json::Value> = sys
        .vars
        .iter()
        .map(|(id, v)| {
            json!({
                "id": id.to_string(),
                "name": sys.var_name(id),
                "kind": v.kind,
                "role": v.role,
                "unknown": v.is_unknown(),
                "alias": v.alias.map(|a| expr(sys, a)),
            })
        })
        .collect();
    let params: Vec<serde_json::Value> = sys
        .params
        .values()
        .map(|p| json!({"name": p.name, "value": p.value}))
        .collect();
    json!({
        "title": sys.title,
        "equations": eqs,
        "variables": var_list,
        "unknowns": sys.unknowns().map(|v| sys.var_name(v).to_string()).collect::<Vec<_>>(),
        "states": sys.states().map(|v| sys.var_name(v).to_string()).collect::<Vec<_>>(),
        "params": params,
        "eliminated": sys.eliminated,
    })
}
