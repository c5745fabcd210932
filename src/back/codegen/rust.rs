//! The Rust writer: the syntax hooks of generated Rust and its runtime
//! prelude (`prelude.rs`, copied into every file). Fixed-size array views
//! of `v` and `p` let constant indices go without bounds checks.

use std::fmt::Write;

use super::{Driver, Sizes, Sweep, Syntax, num, prelude_body};
use crate::ir::{Cmp, Func};

/// `prelude.rs` as it stands on disk, its header included.
pub(super) const PRELUDE_FILE: &str = include_str!("prelude.rs");

/// The prelude compiled as a module of the tests, so that the compiler and
/// clippy check the code that generated files copy. rustfmt keeps away: the
/// copied text is part of the output.
#[cfg(test)]
#[rustfmt::skip]
#[path = "prelude.rs"]
mod prelude_check;

/// The fixed-size views of `v` and `p` at the top of a generated function
/// (constant indices then need no bounds checks).
const ARRAY_VIEWS: &str = "    let v: &mut [f64; N_VARS] = v.try_into().expect(\"N_VARS values in v\");\n    let p: &[f64; NP] = p.try_into().expect(\"NP parameters\");\n";

/// Generated Rust.
pub(super) struct Rust;

impl Syntax for Rust {
    fn prelude(&self, out: &mut String) {
        out.push_str("#![allow(dead_code, unused_parens, unused_variables, clippy::all)]\n");
        out.push_str(prelude_body(PRELUDE_FILE));
    }

    fn float(&self, lit: &str) -> String {
        format!("({lit}f64)")
    }

    fn pow(&self, a: String, b: String) -> String {
        format!("{a}.powf({b})")
    }

    fn call(&self, f: Func, arg: String) -> String {
        format!("{arg}.{}()", f.name())
    }

    fn cmp(&self, op: Cmp, a: String, b: String) -> String {
        format!(
            "(if {a} {} {b} {{ 1.0f64 }} else {{ 0.0f64 }})",
            op.symbol()
        )
    }

    fn select(&self, c: String, a: String, b: String) -> String {
        format!("(if {c} != 0.0f64 {{ {a} }} else {{ {b} }})")
    }

    /// `signum`: ±1 by the sign bit, as C's copysign.
    fn sign(&self, x: String) -> String {
        format!("{x}.signum()")
    }

    fn counted_loop(&self, len: usize) -> String {
        format!("for k in 0..{len}")
    }

    fn states_loop(&self, body: &str) -> String {
        format!("    for k in 0..N_STATES {{ {body} }}")
    }

    fn constants(&self, out: &mut String, np: usize, list: &str, sizes: Sizes) {
        let _ = writeln!(
            out,
            "pub const NP: usize = {np};\npub const P: [f64; NP] = [{list}];"
        );
        let _ = writeln!(out, "pub const N_STATES: usize = {};", sizes.n_states);
        let _ = writeln!(out, "pub const N_VARS: usize = {};", sizes.n_vars);
    }

    fn pwl_repeat(&self, local: &str, r: &str, last: &str, period: &str) -> String {
        format!("if {local} >= {last} {{ {r} + ({local} - {r}) % {period} }} else {{ {local} }}")
    }

    fn pwl(&self, tau: &str, points: &[(f64, f64)]) -> String {
        let pts: Vec<String> = points
            .iter()
            .map(|(a, b)| format!("({}, {})", num(*a), num(*b)))
            .collect();
        format!("pwl({tau}, o, &[{}])", pts.join(", "))
    }

    fn source_fn(&self, out: &mut String, name: &str, id: u32, body: &str) {
        let _ = writeln!(
            out,
            "/// {name} (t)\nfn src_{id}(t: f64, o: u8) -> f64 {{ let _ = (t, o); {body} }}"
        );
    }

    fn diode_fn(&self, out: &mut String, name: &str, k: usize, args: &str) {
        let _ = writeln!(
            out,
            "/// Diode {name}.\nfn diode_{k}(part: u8, o: u8, x: f64) -> f64 {{ diode(part, o, x, {args}) }}"
        );
    }

    fn resid_head(&self, k: usize) -> String {
        format!(
            "fn resid_{k}(t: f64, y: &[f64], p: &[f64], v: &mut [f64], r: &mut [f64]) {{\n    let _ = (t, y, p);\n{ARRAY_VIEWS}"
        )
    }

    fn resid_tan_head(&self, k: usize) -> String {
        format!(
            "fn resid_{k}_tan(t: f64, y: &[f64], p: &[f64], v: &[f64], dv: &mut [f64], dr: &mut [f64]) {{\n    let _ = (t, y, p, v);\n"
        )
    }

    fn block_fn(&self, k: usize, _n: usize) -> Driver {
        Driver {
            sig: format!("fn block_{k}(t: f64, y: &[f64], p: &[f64; NP], v: &mut [f64; N_VARS])"),
            call: format!(
                "newton(&TEARS, v, &mut |v: &mut [f64], r: &mut [f64]| resid_{k}(t, y, p, v, r), &mut |v: &[f64], dv: &mut [f64], dr: &mut [f64]| resid_{k}_tan(t, y, p, v, dv, dr));"
            ),
        }
    }

    fn block_tan_fn(&self, k: usize, _n: usize) -> Driver {
        Driver {
            sig: format!(
                "fn block_{k}_tan(t: f64, y: &[f64], p: &[f64; NP], v: &[f64; N_VARS], dv: &mut [f64; N_VARS])"
            ),
            call: format!(
                "tangent_solve(&TEARS, dv, &mut |dv: &mut [f64], dr: &mut [f64]| resid_{k}_tan(t, y, p, v, dv, dr));"
            ),
        }
    }

    fn tears_table(&self, n: usize, list: &str) -> String {
        format!("const TEARS: [usize; {n}] = [{list}];")
    }

    fn part_head(&self, c: usize) -> String {
        format!(
            "#[inline(never)]\nfn part_{c}(t: f64, y: &[f64], p: &[f64; NP], v: &mut [f64; N_VARS]) {{\n    let _ = (t, y, p);"
        )
    }

    fn tan_head(&self, c: usize) -> String {
        format!(
            "#[inline(never)]\nfn tan_{c}(t: f64, y: &[f64], p: &[f64; NP], v: &[f64; N_VARS], dv: &mut [f64; N_VARS]) {{\n    let _ = (t, y, p, v);"
        )
    }

    fn state_tables(&self, out: &mut String, n_states: usize, states: &str, ders: &str) {
        let _ = writeln!(
            out,
            "\n/// The variable of each state, and of its derivative.\nconst STATE_VAR: [usize; {n_states}] = [{states}];\nconst DER_VAR: [usize; {n_states}] = [{ders}];"
        );
    }

    fn doc(&self, out: &mut String, doc: &str) {
        out.push('\n');
        for line in doc.lines() {
            let _ = writeln!(out, "/// {line}");
        }
    }

    fn rhs(&self) -> Sweep {
        Sweep {
            sig: "pub fn rhs(t: f64, y: &[f64], p: &[f64], v: &mut [f64], dy: &mut [f64])",
            prologue: ARRAY_VIEWS,
        }
    }

    fn jac_mul(&self) -> Sweep {
        Sweep {
            sig: "pub fn jac_mul(t: f64, y: &[f64], p: &[f64], v: &mut [f64], dv: &mut [f64], w: &[f64], jw: &mut [f64])",
            prologue: "    rhs(t, y, p, v, jw);\n    let v: &[f64; N_VARS] = (&*v).try_into().expect(\"N_VARS values in v\");\n    let dv: &mut [f64; N_VARS] = dv.try_into().expect(\"N_VARS values in dv\");\n    let p: &[f64; NP] = p.try_into().expect(\"NP parameters\");\n",
        }
    }
}
