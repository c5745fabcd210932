//! Generated source: the schedule as a standalone Rust or C function
//! `rhs(t, y, p, v, dy)` — "the code of the function f(t, y) of the
//! simulation model" — and `jac_mul(t, y, p, v, dv, w, jw)`, the exact J·w:
//! each assignment's tangent `dv` from its operands' (forward-mode automatic
//! differentiation), a loop's tangents by implicit differentiation of its
//! residuals (affine in the tears' tangents: one small dense solve).
//!
//! Every statement is commented with the equation and element it comes from.
//! Values live in one array `v` indexed by variable. Runs of assignments of
//! one shape whose indices step evenly (the repeated sections of a big
//! circuit) are written as loops, and the statements are split into
//! functions of at most [`CHUNK`] statements, so that the source of a
//! 10^4-section ladder compiles in well under a second. Blocks are solved by
//! a small damped Newton in the generated code.
//!
//! This module walks the [`Schedule`] once for every language; `expr.rs`
//! writes expressions and their tangents; `rust.rs` and `c.rs` supply each
//! language's syntax (the [`Syntax`] hooks) and runtime prelude
//! (`prelude.rs`, `prelude.c`, copied into the output). Generated code
//! follows the schedule statement by statement and never reorders it.

mod c;
mod expr;
mod rust;

use std::fmt::Write;

use crate::analysis::{Assignment, Schedule, Solved, Step};
use crate::ir::{Cmp, EquationSystem, Expr, ExprArena, ExprId, Func, VarRole, Waveform};

/// Statements per generated function.
pub const CHUNK: usize = 50;

/// Consecutive assignments of one shape whose indices step evenly become a
/// loop from this many on (a big circuit's repeated sections).
pub const MIN_RUN: usize = 16;

/// The target language of [`emit`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Lang {
    Rust,
    C,
}

impl Lang {
    fn syntax(self) -> &'static dyn Syntax {
        match self {
            Lang::Rust => &rust::Rust,
            Lang::C => &c::C,
        }
    }
}

/// The syntax of one target language: every piece of text the walk writes
/// that differs between languages. The walk never asks which language it
/// writes; `rust::Rust` and `c::C` answer.
trait Syntax {
    /// What follows the file's opening comment lines: attributes and the
    /// runtime prelude.
    fn prelude(&self, out: &mut String);
    /// A floating-point literal of the digits `lit` (from [`num`]).
    fn float(&self, lit: &str) -> String;
    /// `a` to the power `b`.
    fn pow(&self, a: String, b: String) -> String;
    /// The function `f` of `arg`.
    fn call(&self, f: Func, arg: String) -> String;
    /// 1.0 where `a op b` holds, else 0.0.
    fn cmp(&self, op: Cmp, a: String, b: String) -> String;
    /// `a` where `c` is not zero, else `b` (only the chosen one evaluated).
    fn select(&self, c: String, a: String, b: String) -> String;
    /// ±1 by the sign bit of `x`.
    fn sign(&self, x: String) -> String;
    /// The head of a loop of `len` rerolled assignments over `k`.
    fn counted_loop(&self, len: usize) -> String;
    /// A statement line running `body` for each state `k`.
    fn states_loop(&self, body: &str) -> String;
    /// The parameter values `list` (`np` of them) and the sizes.
    fn constants(&self, out: &mut String, np: usize, list: &str, sizes: Sizes);
    /// The local time `local` of a repeating PWL, folded back past `last`
    /// to `r` with `period`.
    fn pwl_repeat(&self, local: &str, r: &str, last: &str, period: &str) -> String;
    /// A PWL's value (order `o`) at time `tau`.
    fn pwl(&self, tau: &str, points: &[(f64, f64)]) -> String;
    /// `src_{id}(t, o)`: the source `name`'s waveform `body`.
    fn source_fn(&self, out: &mut String, name: &str, id: u32, body: &str);
    /// `diode_{k}(part, o, x)`: the prelude's diode with the model's `args`.
    fn diode_fn(&self, out: &mut String, name: &str, k: usize, args: &str);
    /// The signature and opening lines of a block's residual `resid_{k}`.
    fn resid_head(&self, k: usize) -> String;
    /// The signature and opening lines of its tangent `resid_{k}_tan`.
    fn resid_tan_head(&self, k: usize) -> String;
    /// `block_{k}`: the Newton solve of the block's `n` tears.
    fn block_fn(&self, k: usize, n: usize) -> Driver;
    /// `block_{k}_tan`: the tangent solve of the block's `n` tears.
    fn block_tan_fn(&self, k: usize, n: usize) -> Driver;
    /// The constant table of a block's `n` tears, `list`.
    fn tears_table(&self, n: usize, list: &str) -> String;
    /// The opening of the `c`-th function of the value sweep.
    fn part_head(&self, c: usize) -> String;
    /// The opening of the `c`-th function of the tangent sweep.
    fn tan_head(&self, c: usize) -> String;
    /// The index tables `STATE_VAR` (`states`) and `DER_VAR` (`ders`).
    fn state_tables(&self, out: &mut String, n_states: usize, states: &str, ders: &str);
    /// A documentation comment of `doc`'s lines, on a line of its own.
    fn doc(&self, out: &mut String, doc: &str);
    /// The signature and prologue of `rhs`.
    fn rhs(&self) -> Sweep;
    /// The signature and prologue of `jac_mul`.
    fn jac_mul(&self) -> Sweep;
}

/// How many states and variables the generated code has.
#[derive(Clone, Copy)]
struct Sizes {
    n_states: usize,
    /// At least 1: no language needs an empty array.
    n_vars: usize,
}

/// A block's driver: its signature and the solver call after its tears.
struct Driver {
    sig: String,
    call: String,
}

/// A sweep function's signature and the lines that open its body.
struct Sweep {
    sig: &'static str,
    prologue: &'static str,
}

/// The marker line in a prelude file after which the text is copied into
/// generated source.
const PRELUDE_MARKER: &str = "---- everything below is copied into generated source ----";

/// The part of a prelude file that generated source copies: everything
/// after the line of [`PRELUDE_MARKER`].
fn prelude_body(file: &'static str) -> &'static str {
    let at = file
        .find(PRELUDE_MARKER)
        .expect("a codegen prelude has its marker line");
    let line_end = file[at..].find('\n').map_or(file.len(), |n| at + n + 1);
    &file[line_end..]
}

/// A number as a literal of both languages; non-finite values as divisions.
fn num(x: f64) -> String {
    if x.is_finite() {
        format!("{x:e}")
    } else if x.is_nan() {
        "(0.0/0.0)".into()
    } else if x > 0.0 {
        "(1.0/0.0)".into()
    } else {
        "(-1.0/0.0)".into()
    }
}

/// Placeholder for an index in an expression shape.
const HOLE: char = '#';

/// An explicit assignment with its indices taken out (see [`Gen::shaped`]).
struct Shaped {
    template: String,
    leaves: Vec<i64>,
    var: String,
    comment: String,
}

impl Shaped {
    /// The statement with the holes filled by `index(hole)`.
    fn fill(&self, mut index: impl FnMut(usize) -> String) -> String {
        let mut out = String::with_capacity(self.template.len() + 8 * self.leaves.len());
        for (h, piece) in self.template.split(HOLE).enumerate() {
            if h > 0 {
                out.push_str(&index(h - 1));
            }
            out.push_str(piece);
        }
        out
    }

    /// How many assignments from `run[0]` on share its template, with every
    /// index stepping by the same stride as from `run[0]` to `run[1]`.
    fn run_len(run: &[Shaped]) -> (usize, Vec<i64>) {
        let first = &run[0];
        let Some(second) = run.get(1).filter(|s| s.template == first.template) else {
            return (1, Vec::new());
        };
        let stride: Vec<i64> = second
            .leaves
            .iter()
            .zip(&first.leaves)
            .map(|(b, a)| b - a)
            .collect();
        let mut len = 2;
        while let Some(next) = run.get(len)
            && next.template == first.template
            && next
                .leaves
                .iter()
                .zip(&run[len - 1].leaves)
                .zip(&stride)
                .all(|((b, a), d)| b - a == *d)
        {
            len += 1;
        }
        (len, stride)
    }
}

/// Statements for a sequence of shaped assignments: runs of at least
/// [`MIN_RUN`] with one shape and evenly stepping indices as loops, in the
/// same order as the assignments.
fn reroll(run: &[Shaped], syn: &dyn Syntax, out: &mut Vec<String>) {
    let mut i = 0;
    while i < run.len() {
        let first = &run[i];
        let (len, stride) = Shaped::run_len(&run[i..]);
        if len >= MIN_RUN {
            let last = &run[i + len - 1];
            let body = first.fill(|h| match stride[h] {
                0 => first.leaves[h].to_string(),
                1 => format!("{} + k", first.leaves[h]),
                d if d > 0 => format!("{} + {d} * k", first.leaves[h]),
                d => format!("{} - {} * k", first.leaves[h], -d),
            });
            out.push(format!(
                "    {} {{ {body} }} // {len} assignments, {} .. {}: as {}",
                syn.counted_loop(len),
                first.var,
                last.var,
                first.comment
            ));
            i += len;
        } else {
            out.push(format!(
                "    {} // {} := ... from {}",
                first.fill(|h| first.leaves[h].to_string()),
                first.var,
                first.comment
            ));
            i += 1;
        }
    }
}

/// The walk's context: the system, the schedule's expressions, the syntax.
struct Gen<'a> {
    sys: &'a EquationSystem,
    x: &'a ExprArena,
    syn: &'a dyn Syntax,
}

/// A block's Newton unknowns, its assignments, and its residual equations
/// (`lhs`, `rhs`).
struct BlockParts<'s> {
    tears: Vec<u32>,
    inner: Vec<&'s Assignment>,
    residuals: Vec<(ExprId, ExprId)>,
}

impl Gen<'_> {
    fn comment(&self, a: &Assignment) -> String {
        let eq = &self.sys.eqs[a.eq];
        let text = crate::ir::print::equation(self.sys, a.eq).replace("*/", "* /");
        format!("{} ({}): {}", a.eq, eq.origin.describe(), text)
    }

    /// An explicit assignment as a shape, `v[#] = ...;` with a [`HOLE`] for
    /// each index, and the indices that fill the holes.
    fn shaped(&self, a: &Assignment, e: ExprId) -> Shaped {
        let mut leaves = vec![i64::from(a.var.0)];
        let rhs = self.expr_with(e, &mut |leaf| {
            let (arr, k) = leaf.parts();
            leaves.push(i64::from(k));
            format!("{arr}[{HOLE}]")
        });
        Shaped {
            template: format!("v[{HOLE}] = {rhs};"),
            leaves,
            var: self.sys.var_name(a.var).to_string(),
            comment: self.comment(a),
        }
    }

    /// The tangent of an explicit assignment as a shape, `dv[#] = ...;`.
    fn tangent_shaped(&self, a: &Assignment, e: ExprId) -> Shaped {
        let mut leaves = vec![i64::from(a.var.0)];
        let rhs = self
            .tangent_with(e, &mut |leaf| {
                let (arr, k) = leaf.parts();
                leaves.push(i64::from(k));
                format!("{arr}[{HOLE}]")
            })
            .unwrap_or_else(|| "0.0".into());
        Shaped {
            template: format!("dv[{HOLE}] = {rhs};"),
            leaves,
            var: format!("d {}", self.sys.var_name(a.var)),
            comment: self.comment(a),
        }
    }

    /// Statements of one step (blocks become a Newton call).
    fn step(&self, step: &Step, k: usize, out: &mut Vec<String>) {
        match step {
            Step::Assign(a) => match a.solved {
                Solved::Explicit(e) => reroll(&[self.shaped(a, e)], self.syn, out),
                Solved::Implicit(_) => out.push(format!(
                    "    block_{k}(t, y, p, v); // {} solved numerically from {}",
                    self.sys.var_name(a.var),
                    self.comment(a)
                )),
            },
            Step::Block(b) => {
                let tears: Vec<&str> = b.tears.iter().map(|&v| self.sys.var_name(v)).collect();
                out.push(format!(
                    "    block_{k}(t, y, p, v); // algebraic loop through {} (tearing {})",
                    super::listing::shortened(&b.elements, super::listing::ELEMENTS_SHOWN),
                    super::listing::shortened(&tears, super::listing::ELEMENTS_SHOWN)
                ));
            }
        }
    }

    /// A block's parts. Implicit equations inside a loop join the Newton
    /// solve.
    fn block_parts<'s>(&self, step: &'s Step) -> BlockParts<'s> {
        let mut parts = match step {
            Step::Assign(a) => {
                let eq = &self.sys.eqs[a.eq];
                BlockParts {
                    tears: vec![a.var.0],
                    inner: vec![],
                    residuals: vec![(eq.lhs, eq.rhs)],
                }
            }
            Step::Block(b) => BlockParts {
                tears: b.tears.iter().map(|v| v.0).collect(),
                inner: b.inner.iter().collect(),
                residuals: b
                    .residuals
                    .iter()
                    .map(|a| (self.sys.eqs[a.eq].lhs, self.sys.eqs[a.eq].rhs))
                    .collect(),
            },
        };
        for a in &parts.inner {
            if matches!(a.solved, Solved::Implicit(_)) {
                let eq = &self.sys.eqs[a.eq];
                parts.tears.push(a.var.0);
                parts.residuals.push((eq.lhs, eq.rhs));
            }
        }
        parts
    }

    /// The residual function and Newton driver of a block.
    fn block_fns(&self, step: &Step, k: usize, out: &mut String) {
        let parts = self.block_parts(step);
        out.push_str(&self.syn.resid_head(k));
        for a in &parts.inner {
            match a.solved {
                Solved::Explicit(e) => {
                    let _ = writeln!(
                        out,
                        "    v[{}] = {}; // {}",
                        a.var.0,
                        self.expr(e),
                        self.comment(a)
                    );
                }
                Solved::Implicit(_) => {
                    let _ = writeln!(
                        out,
                        "    // {} is a Newton unknown of this loop: {}",
                        self.sys.var_name(a.var),
                        self.comment(a)
                    );
                }
            }
        }
        for (i, (l, r)) in parts.residuals.iter().enumerate() {
            let _ = writeln!(out, "    r[{i}] = {} - {};", self.expr(*l), self.expr(*r));
        }
        let _ = writeln!(out, "}}\n");
        // Its tangent residual before the drivers: Newton's Jacobian and
        // the tangent solve both read it.
        self.resid_tan_fn(&parts, k, out);
        let driver = self.syn.block_fn(k, parts.tears.len());
        self.block_driver(out, driver, &parts.tears);
        let driver = self.syn.block_tan_fn(k, parts.tears.len());
        self.block_driver(out, driver, &parts.tears);
    }

    /// A block's driver function: its signature, its tears as a constant
    /// table, then the solver call.
    fn block_driver(&self, out: &mut String, driver: Driver, tears: &[u32]) {
        let list = tears
            .iter()
            .map(|t| t.to_string())
            .collect::<Vec<_>>()
            .join(", ");
        let table = self.syn.tears_table(tears.len(), &list);
        let Driver { sig, call } = driver;
        let _ = writeln!(out, "{sig} {{\n    {table}\n    {call}\n}}\n");
    }

    /// The tangents of a block's assignments and residuals
    /// (`resid_k_tan`), affine in its tears' tangents.
    fn resid_tan_fn(&self, parts: &BlockParts, k: usize, out: &mut String) {
        out.push_str(&self.syn.resid_tan_head(k));
        for a in &parts.inner {
            if let Solved::Explicit(e) = a.solved {
                let _ = writeln!(
                    out,
                    "    dv[{}] = {}; // d {}",
                    a.var.0,
                    self.tangent(e),
                    self.sys.var_name(a.var)
                );
            }
        }
        for (i, (l, r)) in parts.residuals.iter().enumerate() {
            let _ = writeln!(
                out,
                "    dr[{i}] = {} - {};",
                self.tangent(*l),
                self.tangent(*r)
            );
        }
        let _ = writeln!(out, "}}\n");
    }

    /// The source function of every independent source.
    fn sources(&self, out: &mut String) {
        for (id, s) in self.sys.sources.iter() {
            let body = self.waveform(&s.wave);
            self.syn.source_fn(out, &s.name, id.0, &body);
        }
    }

    /// A waveform's value (order `o`) at `t`, through the prelude's
    /// functions.
    fn waveform(&self, wave: &Waveform) -> String {
        let args = |name: &str, values: &[f64]| {
            let list: Vec<String> = values.iter().map(|&x| num(x)).collect();
            format!("{name}(t, o, {})", list.join(", "))
        };
        match wave {
            Waveform::Dc { value } => num(*value),
            &Waveform::Pulse {
                v1,
                v2,
                td,
                tr,
                tf,
                pw,
                per,
            } => args("pulse", &[v1, v2, td, tr, tf, pw, per]),
            &Waveform::Sin {
                vo,
                va,
                freq,
                td,
                theta,
                phase,
            } => args("sine", &[vo, va, freq, td, theta, phase]),
            &Waveform::Exp {
                v1,
                v2,
                td1,
                tau1,
                td2,
                tau2,
            } => args("expo", &[v1, v2, td1, tau1, td2, tau2]),
            &Waveform::Sffm {
                vo,
                va,
                fc,
                mdi,
                fs,
            } => args("sffm", &[vo, va, fc, mdi, fs]),
            Waveform::Pwl {
                points,
                repeat,
                delay,
            } => {
                // The time within the sequence (`ir::pwl_time`): delayed,
                // and folded back past the last point when it repeats (the
                // remainder is of a positive number: `%` and fmod agree).
                let local = if *delay == 0.0 {
                    "t".to_string()
                } else {
                    format!("(t - {})", num(*delay))
                };
                let tau = match (repeat, points.last()) {
                    (Some(r), Some(&(last, _))) => {
                        let (r, last, period) = (num(*r), num(last), num(last - r));
                        self.syn.pwl_repeat(&local, &r, &last, &period)
                    }
                    _ => local,
                };
                self.syn.pwl(&tau, points)
            }
        }
    }

    /// The function of every device model the expressions use (a
    /// transistor's unused junction functions, such as a depletion charge of
    /// zero capacitance, get none).
    fn diodes(&self, out: &mut String) {
        let mut used = vec![false; self.sys.diodes.len()];
        for e in self.x.nodes() {
            if let Expr::Device(f, _) = e {
                used[f.diode as usize] = true;
            }
        }
        for (k, d) in self.sys.diodes.iter().enumerate() {
            if !used[k] {
                continue;
            }
            let args = [
                d.is,
                d.vte,
                d.bv.unwrap_or(f64::INFINITY),
                d.gmin,
                d.cjo,
                d.vj,
                d.m,
                d.fc,
                d.tt,
            ]
            .map(num)
            .join(", ");
            self.syn.diode_fn(out, &d.name, k, &args);
        }
    }

    /// The residual, Newton, tangent and tangent-solve functions of every
    /// block (and of every implicit assignment, a block of one).
    fn blocks(&self, sched: &Schedule, out: &mut String) {
        for (k, step) in sched.steps.iter().enumerate() {
            let is_block = matches!(step, Step::Block(_))
                || matches!(step, Step::Assign(a) if matches!(a.solved, Solved::Implicit(_)));
            if is_block {
                out.push('\n');
                self.block_fns(step, k, out);
            }
        }
    }

    /// The statements of the value sweep and, beside them in the same
    /// order, of the tangent sweep: dv of every assignment from the tangents
    /// of its operands; a block's by its tangent solve. Repeated sections
    /// become loops.
    fn statements(&self, sched: &Schedule) -> (Vec<String>, Vec<String>) {
        let (mut stmts, mut tstmts) = (Vec::new(), Vec::new());
        let (mut run, mut trun) = (Vec::new(), Vec::new());
        for (k, step) in sched.steps.iter().enumerate() {
            if let Step::Assign(a) = step
                && let Solved::Explicit(e) = a.solved
            {
                run.push(self.shaped(a, e));
                trun.push(self.tangent_shaped(a, e));
                continue;
            }
            reroll(&run, self.syn, &mut stmts);
            reroll(&trun, self.syn, &mut tstmts);
            run.clear();
            trun.clear();
            self.step(step, k, &mut stmts);
            tstmts.push(format!("    block_{k}_tan(t, y, p, v, dv);"));
        }
        reroll(&run, self.syn, &mut stmts);
        reroll(&trun, self.syn, &mut tstmts);
        (stmts, tstmts)
    }
}

/// A function that sweeps the chunk functions: `sweep` with `doc`, the
/// states' values (`src`) into their variables of `regs`, the calls
/// `name_k(args)`, and the derivatives' values out into `dst`; `arrays` is
/// `(regs, src, dst)`.
fn sweep_fn(
    out: &mut String,
    syn: &dyn Syntax,
    doc: &str,
    sweep: Sweep,
    arrays: (&str, &str, &str),
    calls: (&str, usize, &str),
) {
    let (regs, src, dst) = arrays;
    let (name, n, args) = calls;
    syn.doc(out, doc);
    let _ = writeln!(out, "{} {{", sweep.sig);
    out.push_str(sweep.prologue);
    let _ = writeln!(
        out,
        "{}",
        syn.states_loop(&format!("{regs}[STATE_VAR[k]] = {src}[k];"))
    );
    for c in 0..n {
        let _ = writeln!(out, "    {name}_{c}({args});");
    }
    let store = syn.states_loop(&format!("{dst}[k] = {regs}[DER_VAR[k]];"));
    let _ = writeln!(out, "{store}\n}}");
}

/// The statements as functions of at most [`CHUNK`] each, opened by
/// `head(k)`; how many.
fn chunk_fns(out: &mut String, stmts: &[String], head: impl Fn(usize) -> String) -> usize {
    let mut n = 0;
    for (c, chunk) in stmts.chunks(CHUNK).enumerate() {
        let _ = writeln!(out, "\n{}", head(c));
        for s in chunk {
            let _ = writeln!(out, "{s}");
        }
        out.push_str("}\n");
        n += 1;
    }
    n
}

/// The opening comments, the prelude, the parameters and the sizes.
fn header(out: &mut String, sys: &EquationSystem, syn: &dyn Syntax, n_states: usize) {
    let cm = "//";
    let _ = writeln!(
        out,
        "{cm} Generated by kausal from \"{}\". Do not edit.",
        sys.title.replace('\n', " ")
    );
    let _ = writeln!(
        out,
        "{cm} f(t, y) of the sorted equations: {n_states} states, {} equations.",
        sys.eqs.len()
    );
    syn.prelude(out);
    let _ = writeln!(out, "\n{cm} Parameters p[k], in order:");
    for (id, p) in sys.params.iter() {
        let _ = writeln!(out, "{cm}   p[{}] = {} = {}", id.0, p.name, num(p.value));
    }
    let vals: Vec<String> = sys.params.values().map(|p| num(p.value)).collect();
    let np = vals.len().max(1);
    let list = if vals.is_empty() {
        "0.0".to_string()
    } else {
        vals.join(", ")
    };
    let sizes = Sizes {
        n_states,
        n_vars: sys.vars.len().max(1),
    };
    syn.constants(out, np, &list, sizes);
}

/// The index tables of the states and their derivatives, and the two sweep
/// functions `rhs` (over `chunks` value functions) and `jac_mul` (over
/// `tchunks` tangent functions).
fn sweeps(out: &mut String, sys: &EquationSystem, syn: &dyn Syntax, chunks: usize, tchunks: usize) {
    let states: Vec<_> = sys.states().collect();
    let ders: Vec<u32> = states
        .iter()
        .map(|&s| match sys.vars[s].role {
            VarRole::State { der } => der.0,
            _ => unreachable!("states have derivatives"),
        })
        .collect();
    // States in and derivatives out through index tables (loops, not one
    // statement each: a big circuit's rhs stays small).
    let table = |ids: &[u32]| {
        ids.iter()
            .map(|i| i.to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let st = table(&states.iter().map(|s| s.0).collect::<Vec<_>>());
    syn.state_tables(out, states.len(), &st, &table(&ders));
    sweep_fn(
        out,
        syn,
        "dy/dt = f(t, y): `v` is scratch of N_VARS values (it keeps Newton's warm start).",
        syn.rhs(),
        ("v", "y", "dy"),
        ("part", chunks, "t, y, p, v"),
    );
    // jac_mul: the values at (t, y) by rhs, then the tangent sweep.
    sweep_fn(
        out,
        syn,
        "J(t, y) w, exact: the tangents of the sorted assignments (forward mode),\nloops by implicit differentiation. `v` and `dv` are scratch of N_VARS values.",
        syn.jac_mul(),
        ("dv", "w", "jw"),
        ("tan", tchunks, "t, y, p, v, dv"),
    );
}

/// The generated source.
pub fn emit(sys: &EquationSystem, sched: &Schedule, lang: Lang) -> String {
    let syn = lang.syntax();
    let g = Gen {
        sys,
        x: &sys.exprs,
        syn,
    };
    let states: Vec<_> = sys.states().collect();
    let mut out = String::new();
    header(&mut out, sys, syn, states.len());
    let _ = writeln!(out, "// States y[k]:");
    for (k, &s) in states.iter().enumerate() {
        let _ = writeln!(out, "//   y[{k}] = {} (v[{}])", sys.var_name(s), s.0);
    }
    g.sources(&mut out);
    g.diodes(&mut out);
    g.blocks(sched, &mut out);
    let (stmts, tstmts) = g.statements(sched);
    let tchunks = chunk_fns(&mut out, &tstmts, |c| syn.tan_head(c));
    let chunks = chunk_fns(&mut out, &stmts, |c| syn.part_head(c));
    sweeps(&mut out, sys, syn, chunks, tchunks);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each prelude file has its marker, and what is copied starts on a
    /// fresh line.
    #[test]
    fn preludes_are_cut_at_their_marker() {
        for file in [rust::PRELUDE_FILE, c::PRELUDE_FILE] {
            assert_eq!(file.matches(PRELUDE_MARKER).count(), 1);
            let body = prelude_body(file);
            assert!(body.starts_with('\n'), "{:?}", &body[..20]);
            assert!(!body.contains(PRELUDE_MARKER));
        }
    }
}
