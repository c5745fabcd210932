//! The C writer: the syntax hooks of generated ISO C99 and its runtime
//! prelude (`prelude.c`, copied into every file). ISO C has no empty arrays
//! or initializers, so every table holds at least one entry.

use std::fmt::Write;

use super::{Driver, Sizes, Sweep, Syntax, num, prelude_body};
use crate::ir::{Cmp, Func};

/// `prelude.c` as it stands on disk, its header included.
pub(super) const PRELUDE_FILE: &str = include_str!("prelude.c");

/// Generated C.
pub(super) struct C;

impl Syntax for C {
    fn prelude(&self, out: &mut String) {
        out.push_str(prelude_body(PRELUDE_FILE));
    }

    fn float(&self, lit: &str) -> String {
        format!("({lit})")
    }

    fn pow(&self, a: String, b: String) -> String {
        format!("pow({a}, {b})")
    }

    fn cmp(&self, op: Cmp, a: String, b: String) -> String {
        format!("({a} {} {b} ? 1.0 : 0.0)", op.symbol())
    }

    fn select(&self, c: String, a: String, b: String) -> String {
        format!("({c} != 0.0 ? {a} : {b})")
    }

    fn call(&self, f: Func, arg: String) -> String {
        let name = match f {
            Func::Ln => "log",
            Func::Abs => "fabs",
            other => other.name(),
        };
        format!("{name}({arg})")
    }

    fn sign(&self, x: String) -> String {
        format!("copysign(1.0, {x})")
    }

    fn counted_loop(&self, len: usize) -> String {
        format!("for (size_t k = 0; k < {len}; k++)")
    }

    fn states_loop(&self, body: &str) -> String {
        format!("    for (int k = 0; k < N_STATES; k++) {body}")
    }

    fn constants(&self, out: &mut String, np: usize, list: &str, sizes: Sizes) {
        let _ = writeln!(out, "const double P[{np}] = {{{list}}};");
        let _ = writeln!(
            out,
            "#define N_STATES {}\n#define N_VARS {}",
            sizes.n_states, sizes.n_vars
        );
    }

    /// The remainder is of a positive number: fmod agrees with Rust's `%`.
    fn pwl_repeat(&self, local: &str, r: &str, last: &str, period: &str) -> String {
        format!("({local} >= {last} ? {r} + fmod({local} - {r}, {period}) : {local})")
    }

    fn pwl(&self, tau: &str, points: &[(f64, f64)]) -> String {
        let ts: Vec<String> = points.iter().map(|p| num(p.0)).collect();
        let ys: Vec<String> = points.iter().map(|p| num(p.1)).collect();
        format!(
            "pwl({tau}, o, (const double[]){{{}}}, (const double[]){{{}}}, {})",
            ts.join(", "),
            ys.join(", "),
            points.len()
        )
    }

    fn source_fn(&self, out: &mut String, name: &str, id: u32, body: &str) {
        let _ = writeln!(
            out,
            "/* {name} (t) */\nstatic double src_{id}(double t, int o) {{ (void)t; (void)o; return {body}; }}"
        );
    }

    fn diode_fn(&self, out: &mut String, name: &str, k: usize, args: &str) {
        let _ = writeln!(
            out,
            "/* Diode {name} */\nstatic double diode_{k}(int part, int o, double x) {{ return diode(part, o, x, {args}); }}"
        );
    }

    fn resid_head(&self, k: usize) -> String {
        format!(
            "static void resid_{k}(double t, const double *y, const double *p, double *v, double *r) {{\n    (void)t; (void)y; (void)p;\n"
        )
    }

    fn resid_tan_head(&self, k: usize) -> String {
        format!(
            "static void resid_{k}_tan(double t, const double *y, const double *p, const double *v, double *dv, double *dr) {{\n    (void)t; (void)y; (void)p; (void)v;\n"
        )
    }

    fn block_fn(&self, k: usize, n: usize) -> Driver {
        Driver {
            sig: format!(
                "static void block_{k}(double t, const double *y, const double *p, double *v)"
            ),
            call: format!("newton({n}, tears, t, y, p, v, resid_{k}, resid_{k}_tan, N_VARS);"),
        }
    }

    fn block_tan_fn(&self, k: usize, n: usize) -> Driver {
        Driver {
            sig: format!(
                "static void block_{k}_tan(double t, const double *y, const double *p, const double *v, double *dv)"
            ),
            call: format!("tangent_solve({n}, tears, t, y, p, v, dv, resid_{k}_tan, N_VARS);"),
        }
    }

    fn tears_table(&self, n: usize, list: &str) -> String {
        format!("static const int tears[{n}] = {{{list}}};")
    }

    fn part_head(&self, c: usize) -> String {
        format!(
            "__attribute__((noinline)) static void part_{c}(double t, const double *y, const double *p, double *v) {{\n    (void)t; (void)y; (void)p;"
        )
    }

    fn tan_head(&self, c: usize) -> String {
        format!(
            "__attribute__((noinline)) static void tan_{c}(double t, const double *y, const double *p, const double *v, double *dv) {{\n    (void)t; (void)y; (void)p; (void)v;"
        )
    }

    /// A stateless circuit's tables hold one unused 0.
    fn state_tables(&self, out: &mut String, n_states: usize, states: &str, ders: &str) {
        let ns = n_states.max(1);
        let (states, ders) = if n_states == 0 {
            ("0", "0")
        } else {
            (states, ders)
        };
        let _ = writeln!(
            out,
            "\n/* The variable of each state, and of its derivative. */\nstatic const int STATE_VAR[{ns}] = {{{states}}};\nstatic const int DER_VAR[{ns}] = {{{ders}}};"
        );
    }

    /// A block comment, without the backticks of Markdown.
    fn doc(&self, out: &mut String, doc: &str) {
        let doc = doc.replace('`', "").replace('\n', "\n   ");
        let _ = writeln!(out, "\n/* {doc} */");
    }

    fn rhs(&self) -> Sweep {
        Sweep {
            sig: "void rhs(double t, const double *y, const double *p, double *v, double *dy)",
            prologue: "",
        }
    }

    fn jac_mul(&self) -> Sweep {
        Sweep {
            sig: "void jac_mul(double t, const double *y, const double *p, double *v, double *dv, const double *w, double *jw)",
            prologue: "    rhs(t, y, p, v, jw);\n",
        }
    }
}

#[cfg(test)]
mod tests {
    use std::process::Command;

    /// The C prelude compiles as ISO C99 with every warning an error, by the
    /// system's C compiler (`cc`).
    #[test]
    fn prelude_compiles_as_c99() {
        let file = concat!(env!("CARGO_MANIFEST_DIR"), "/src/back/codegen/prelude.c");
        let out = Command::new("cc")
            .args(["-std=c99", "-Wall", "-Werror", "-fsyntax-only", file])
            .output()
            .unwrap_or_else(|e| {
                panic!(
                    "no C compiler: `cc` could not be run ({e}); install one (Debian: apt-get install gcc)"
                )
            });
        assert!(
            out.status.success(),
            "cc rejects {file}:\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
}
