//! Human-readable and tool-readable forms of a causalized system: the sorted
//! listing in the seeds' style, the colouring trace, JSON, Graphviz DOT of the
//! coloured bipartite graph, and the sorted incidence matrix.

use std::fmt::Write;

use serde_json::json;

use crate::analysis::{Assignment, Block, Causalization, EdgeColour, Rule, Schedule, Solved, Step};
use crate::ir::{EquationSystem, ExprArena, ExprId, VarId, print};

/// Print an expression of the schedule's arena (a superset of the system's).
fn expr(sys: &EquationSystem, x: &ExprArena, e: ExprId) -> String {
    // The printer reads names from the system and nodes from the arena.
    let mut out = String::new();
    write_expr(sys, x, e, &mut out);
    out
}

fn write_expr(sys: &EquationSystem, x: &ExprArena, e: ExprId, out: &mut String) {
    print::write_expr_in(sys, x, e, out);
}

/// Summary figures of a schedule.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Summary {
    pub equations: usize,
    pub states: usize,
    pub blocks: usize,
    pub largest_block: usize,
    pub tearing_variables: Vec<String>,
    pub implicit: usize,
}

pub fn summary(sys: &EquationSystem, s: &Schedule) -> Summary {
    let blocks: Vec<&Block> = s.blocks().collect();
    Summary {
        equations: sys.eqs.len(),
        states: sys.states().count(),
        blocks: blocks.len(),
        largest_block: blocks.iter().map(|b| b.n_eqs()).max().unwrap_or(0),
        tearing_variables: blocks
            .iter()
            .flat_map(|b| b.tears.iter().map(|&v| sys.var_name(v).to_string()))
            .collect(),
        implicit: s
            .assignments()
            .filter(|a| matches!(a.solved, Solved::Implicit(_)))
            .count(),
    }
}

fn block_header(b: &Block) -> String {
    let kind = if b.linear { "linear" } else { "nonlinear" };
    format!(
        "algebraic loop through {} ({} equations, {kind})",
        shortened(&b.elements, ELEMENTS_SHOWN),
        b.n_eqs()
    )
}

/// Elements a block header names before "and N more" (a loop of 10^5
/// resistors printed a 600 kB line).
pub const ELEMENTS_SHOWN: usize = 24;

/// The first `shown` names joined, then how many more there are.
pub fn shortened<S: AsRef<str>>(names: &[S], shown: usize) -> String {
    let mut out = names
        .iter()
        .take(shown)
        .map(AsRef::as_ref)
        .collect::<Vec<_>>()
        .join(", ");
    if names.len() > shown {
        let _ = write!(out, ", and {} more", names.len() - shown);
    }
    out
}

/// Padding for the listing's columns, copied a slice at a time.
const SPACES: &str = "                                                                        ";

/// `n` in decimal, right-aligned in `width` columns (the listing writes a
/// million of these: `write!` costs several times more).
fn push_right(out: &mut String, mut n: usize, width: usize) {
    let mut digits = [0u8; 20];
    let mut k = digits.len();
    loop {
        k -= 1;
        digits[k] = b'0' + (n % 10) as u8;
        n /= 10;
        if n == 0 {
            break;
        }
    }
    let len = digits.len() - k;
    out.push_str(&SPACES[..width.saturating_sub(len).min(SPACES.len())]);
    // ASCII digits only.
    out.push_str(std::str::from_utf8(&digits[k..]).unwrap_or_default());
}

/// The numbered sorted assignments with blocks marked, then a summary.
pub fn text(sys: &EquationSystem, s: &Schedule) -> String {
    let mut out = Vec::new();
    // Writing into a vector cannot fail, and every piece is a `str`.
    let _ = write_text(sys, s, &mut out);
    String::from_utf8(out).unwrap_or_else(|e| String::from_utf8_lossy(e.as_bytes()).into_owned())
}

/// One row of a listing chunk: an assignment's text ends at `mid` and its
/// note (`; eq7 branch of R1`) at `end`; the padding between them waits for
/// the widest row of the whole listing. A plain row (a block's header or
/// end) has no note: `mid == end`.
struct Row {
    mid: usize,
    end: usize,
    /// The assignment's width in characters; `None` for a plain row.
    chars: Option<usize>,
}

/// Consecutive steps' rows, formatted into one buffer.
struct Chunk {
    buf: String,
    rows: Vec<Row>,
}

/// Listings with at least this many rows are formatted in parallel chunks.
const PARALLEL_ROWS: usize = 1 << 16;

/// Rows a step prints with a number (a block's header and end have none).
fn numbered_rows(step: &Step) -> usize {
    match step {
        Step::Assign(_) => 1,
        Step::Block(b) => b.inner.len() + b.residuals.len(),
    }
}

/// Format `steps`, whose first numbered row is `first + 1`.
fn chunk(sys: &EquationSystem, steps: &[Step], first: usize) -> Chunk {
    let n_rows: usize = steps.iter().map(|st| numbered_rows(st) + 2).sum();
    let mut c = Chunk {
        buf: String::with_capacity(n_rows * 64),
        rows: Vec::with_capacity(n_rows),
    };
    let mut k = first;
    let mut line = |c: &mut Chunk, a: &Assignment, indent: &str, note: &str| {
        k += 1;
        let buf = &mut c.buf;
        let start = buf.len();
        let name = &sys.var_name(a.var);
        push_right(buf, k, 5);
        buf.push_str("  ");
        buf.push_str(indent);
        match a.solved {
            Solved::Explicit(e) => {
                buf.push_str(name);
                buf.push_str(" := ");
                write_expr(sys, &sys.exprs, e, buf);
            }
            Solved::Implicit(e) => {
                buf.push_str("0 = ");
                write_expr(sys, &sys.exprs, e, buf);
                let _ = write!(buf, "  (solved numerically for {name})");
            }
        }
        buf.push_str(note);
        let text = &buf[start..];
        // Most listings are ASCII: count characters only when they are not.
        let chars = if text.is_ascii() {
            text.len()
        } else {
            text.chars().count()
        };
        let mid = buf.len();
        buf.push_str("    ; eq");
        push_right(buf, a.eq.0 as usize, 0);
        buf.push(' ');
        let _ = sys.eqs[a.eq].origin.write_description(buf);
        c.rows.push(Row {
            mid,
            end: buf.len(),
            chars: Some(chars),
        });
    };
    let plain = |c: &mut Chunk| {
        let end = c.buf.len();
        c.rows.push(Row {
            mid: end,
            end,
            chars: None,
        });
    };
    for step in steps {
        match step {
            Step::Assign(a) => line(&mut c, a, "", ""),
            Step::Block(b) => {
                let tears: Vec<&str> = b.tears.iter().map(|&v| sys.var_name(v)).collect();
                let whole = if b.solved_whole() {
                    format!(" (solved whole: {} unknowns, sparse LU)", b.n_eqs())
                } else {
                    String::new()
                };
                let _ = write!(
                    c.buf,
                    "       block {}: {}; tearing: {}{whole}",
                    b.index,
                    block_header(b),
                    shortened(&tears, ELEMENTS_SHOWN)
                );
                plain(&mut c);
                for a in &b.inner {
                    line(&mut c, a, "  ", "");
                }
                for a in &b.residuals {
                    line(&mut c, a, "  ", "  (residual)");
                }
                let _ = write!(c.buf, "       end of block {}", b.index);
                plain(&mut c);
            }
        }
    }
    c
}

/// [`text`] written to `w` as it is formatted: a listing of 10^6 equations
/// is never held twice. Large listings are formatted on up to four threads,
/// in chunks of consecutive steps.
pub fn write_text<W: std::io::Write + ?Sized>(
    sys: &EquationSystem,
    s: &Schedule,
    w: &mut W,
) -> std::io::Result<()> {
    let rows: usize = s.steps.iter().map(numbered_rows).sum();
    let threads = if rows < PARALLEL_ROWS {
        1
    } else {
        std::thread::available_parallelism().map_or(1, |n| n.get().min(4))
    };
    write_chunked(sys, s, threads, rows, w)
}

/// [`write_text`] in `threads` chunks; `rows` is the number of numbered rows.
fn write_chunked<W: std::io::Write + ?Sized>(
    sys: &EquationSystem,
    s: &Schedule,
    threads: usize,
    rows: usize,
    w: &mut W,
) -> std::io::Result<()> {
    // Cut the steps where each chunk has about the same number of rows.
    let mut bounds = vec![(0, 0)];
    let mut seen = 0;
    for (i, st) in s.steps.iter().enumerate() {
        seen += numbered_rows(st);
        if bounds.len() < threads && seen * threads >= rows * bounds.len() {
            bounds.push((i + 1, seen));
        }
    }
    let spans: Vec<(usize, usize, usize)> = (0..bounds.len())
        .map(|j| {
            let end = bounds.get(j + 1).map_or(s.steps.len(), |b| b.0);
            (bounds[j].0, end, bounds[j].1)
        })
        .collect();
    let chunks: Vec<Chunk> = if spans.len() == 1 {
        vec![chunk(sys, &s.steps, 0)]
    } else {
        std::thread::scope(|scope| {
            // A chunk whose thread cannot be started is formatted here.
            let handles: Vec<_> = spans
                .iter()
                .map(|&(a, b, first)| {
                    let work = move || chunk(sys, &s.steps[a..b], first);
                    std::thread::Builder::new()
                        .spawn_scoped(scope, work)
                        .map_err(|_| work)
                })
                .collect();
            handles
                .into_iter()
                .map(|h| match h {
                    Ok(h) => h.join().unwrap_or_else(|e| std::panic::resume_unwind(e)),
                    Err(work) => work(),
                })
                .collect()
        })
    };
    let width = (chunks.iter().flat_map(|c| &c.rows))
        .filter_map(|r| r.chars)
        .max()
        .unwrap_or(0)
        .min(72);
    writeln!(w, "* {}", sys.title)?;
    writeln!(w, "sorted assignments:")?;
    for c in &chunks {
        let mut start = 0;
        for row in &c.rows {
            w.write_all(&c.buf.as_bytes()[start..row.mid])?;
            if let Some(chars) = row.chars {
                // `width` is at most 72, the length of `SPACES`.
                let pad = width.saturating_sub(chars).min(SPACES.len());
                w.write_all(&SPACES.as_bytes()[..pad])?;
                w.write_all(&c.buf.as_bytes()[row.mid..row.end])?;
            }
            w.write_all(b"\n")?;
            start = row.end;
        }
    }
    let sm = summary(sys, s);
    let mut out = String::new();
    let _ = write!(
        out,
        "summary: {} equations, {} state{}, {} algebraic block{}",
        sm.equations,
        sm.states,
        if sm.states == 1 { "" } else { "s" },
        sm.blocks,
        if sm.blocks == 1 { "" } else { "s" }
    );
    if sm.blocks > 0 {
        let _ = write!(out, " (largest: {} equations)", sm.largest_block);
    }
    let _ = write!(
        out,
        ", {} tearing variable{}",
        sm.tearing_variables.len(),
        if sm.tearing_variables.len() == 1 {
            ""
        } else {
            "s"
        }
    );
    if !sm.tearing_variables.is_empty() {
        let _ = write!(out, " ({})", shortened(&sm.tearing_variables, 8));
    }
    if sm.implicit > 0 {
        let _ = write!(out, ", {} implicit", sm.implicit);
    }
    out.push('\n');
    w.write_all(out.as_bytes())
}

/// The colouring trace: every rule firing in order, stalls and tears.
pub fn trace(sys: &EquationSystem, c: &Causalization) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "colouring trace:");
    let mut stalls = c.stalls.iter().peekable();
    let mut tears = c.tears.iter();
    for (k, step) in c.trace.iter().enumerate() {
        while let Some(st) = stalls.next_if(|st| st.after == k) {
            let sizes: Vec<String> = st.blocks.iter().map(|b| b.eqs.len().to_string()).collect();
            let _ = writeln!(
                out,
                "  stall after {} assignments: {} block{} left (sizes {})",
                st.after,
                st.blocks.len(),
                if st.blocks.len() == 1 { "" } else { "s" },
                sizes.join(", ")
            );
            for b in &st.blocks {
                let eqs: Vec<String> = b.eqs.iter().map(|e| e.to_string()).collect();
                let vars: Vec<&str> = b.vars.iter().map(|&v| sys.var_name(v)).collect();
                let _ = writeln!(
                    out,
                    "    block {{{}}} in {{{}}}",
                    eqs.join(", "),
                    vars.join(", ")
                );
            }
        }
        let rule = match step.rule {
            Rule::Equation => "equation rule",
            Rule::Unknown => "unknown rule ",
            Rule::Tear => "tearing      ",
        };
        let _ = write!(
            out,
            "  pass {:>3}  {rule}  {:>5} -> {:<14} number {}",
            step.pass,
            step.eq.to_string(),
            sys.var_name(step.var),
            step.number
        );
        if step.rule == Rule::Tear
            && let Some(t) = tears.next()
        {
            let _ = write!(
                out,
                "   (causalizes {} equations; {} candidates)",
                t.gain, t.candidates
            );
        }
        out.push('\n');
    }
    out
}

fn assignment_json(sys: &EquationSystem, a: &Assignment, k: &mut usize) -> serde_json::Value {
    *k += 1;
    let e = &sys.eqs[a.eq];
    let (form, text) = match a.solved {
        Solved::Explicit(x) => ("explicit", expr(sys, &sys.exprs, x)),
        Solved::Implicit(x) => ("implicit", expr(sys, &sys.exprs, x)),
    };
    json!({
        "position": *k,
        "eq": a.eq.to_string(),
        "number": a.number,
        "rule": a.rule,
        "var": sys.var_name(a.var),
        "form": form,
        "expr": text,
        "equation": print::equation(sys, a.eq),
        "origin": e.origin.describe(),
        "elements": e.origin.elements(),
    })
}

pub fn json(sys: &EquationSystem, c: &Causalization, s: &Schedule) -> serde_json::Value {
    let mut k = 0;
    let steps: Vec<serde_json::Value> = s
        .steps
        .iter()
        .map(|step| match step {
            Step::Assign(a) => json!({"assign": assignment_json(sys, a, &mut k)}),
            Step::Block(b) => {
                let inner: Vec<_> = b.inner.iter().map(|a| assignment_json(sys, a, &mut k)).collect();
                let res: Vec<_> = b.residuals.iter().map(|a| assignment_json(sys, a, &mut k)).collect();
                json!({"block": {
                    "index": b.index,
                    "description": block_header(b),
                    "elements": b.elements,
                    "linear": b.linear,
                    "solved_whole": b.solved_whole(),
                    "tearing": b.tears.iter().map(|&v| sys.var_name(v).to_string()).collect::<Vec<_>>(),
                    "inner": inner,
                    "residuals": res,
                }})
            }
        })
        .collect();
    let trace: Vec<serde_json::Value> = c
        .trace
        .iter()
        .map(|t| json!({"pass": t.pass, "rule": t.rule, "eq": t.eq.to_string(), "var": sys.var_name(t.var), "number": t.number}))
        .collect();
    let stalls: Vec<serde_json::Value> = c
        .stalls
        .iter()
        .map(|st| {
            json!({
                "after": st.after,
                "blocks": st.blocks.iter().map(|b| json!({
                    "eqs": b.eqs.iter().map(|e| e.to_string()).collect::<Vec<_>>(),
                    "vars": b.vars.iter().map(|&v| sys.var_name(v).to_string()).collect::<Vec<_>>(),
                })).collect::<Vec<_>>(),
            })
        })
        .collect();
    let tears: Vec<serde_json::Value> = c
        .tears
        .iter()
        .map(|t| json!({"var": sys.var_name(t.var), "residual": t.eq.to_string(), "causalizes": t.gain, "candidates": t.candidates}))
        .collect();
    json!({
        "title": sys.title,
        "steps": steps,
        "summary": summary(sys, s),
        "trace": trace,
        "stalls": stalls,
        "tears": tears,
    })
}

fn dot_escape(s: &str) -> String {
    s.replace('\\', "\\\\").replace('"', "\\\"")
}

/// The coloured bipartite graph: equations (boxes, with their sort numbers)
/// and unknowns (ellipses); red edges solve, blue edges read.
pub fn dot(sys: &EquationSystem, c: &Causalization) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "graph kausal {{");
    let _ = writeln!(out, "  rankdir=LR; node [fontname=\"Helvetica\"];");
    let _ = writeln!(out, "  label=\"{}\";", dot_escape(&sys.title));
    for (eq, _) in sys.eqs.iter() {
        let _ = writeln!(
            out,
            "  {eq} [shape=box, label=\"{}: {}\"];",
            c.number(eq),
            dot_escape(&print::equation(sys, eq))
        );
    }
    for (v, var) in sys.vars.iter() {
        if var.is_unknown() {
            let tear = c.tears.iter().any(|t| t.var == v);
            let _ = writeln!(
                out,
                "  {v} [shape=ellipse, label=\"{}\"{}];",
                dot_escape(sys.var_name(v)),
                if tear { ", peripheries=2" } else { "" }
            );
        }
    }
    let g = &c.graph;
    for (k, (&v, &eq)) in g.edge_var.iter().zip(&g.edge_eq).enumerate() {
        let colour = match c.colours[k] {
            EdgeColour::Red => "red",
            EdgeColour::Blue => "blue",
            EdgeColour::Black => "black",
        };
        let width = if c.colours[k] == EdgeColour::Red {
            ", penwidth=2"
        } else {
            ""
        };
        let _ = writeln!(out, "  {eq} -- {v} [color={colour}{width}];");
    }
    out.push_str("}\n");
    out
}

/// The incidence matrix with rows in schedule order and columns in the order
/// the unknowns are computed: `#` where a row computes its unknown, `x` where
/// it reads one, `|` marks block boundaries. Lower-triangular without loops.
pub fn incidence(sys: &EquationSystem, c: &Causalization, s: &Schedule) -> String {
    let order: Vec<&Assignment> = s.assignments().collect();
    let mut col = vec![usize::MAX; sys.vars.len()];
    // Inside a block the tearing variables come first: they are guessed.
    let mut cols: Vec<VarId> = Vec::new();
    for step in &s.steps {
        match step {
            Step::Assign(a) => cols.push(a.var),
            Step::Block(b) => {
                cols.extend(b.tears.iter().copied());
                cols.extend(b.inner.iter().map(|a| a.var));
            }
        }
    }
    for (k, &v) in cols.iter().enumerate() {
        col[v.0 as usize] = k;
    }
    let mut out = String::new();
    let _ = writeln!(
        out,
        "sorted incidence (rows: assignments in order; columns: unknowns as computed):"
    );
    for (k, &v) in cols.iter().enumerate() {
        let _ = writeln!(out, "  c{k:<4} {}", sys.var_name(v));
    }
    let _ = write!(out, "  {:>6} ", "");
    for k in 0..cols.len() {
        let _ = write!(out, "{}", k % 10);
    }
    out.push('\n');
    for a in order {
        let mut row = vec!['.'; cols.len()];
        for v in c.graph.eq_vars(a.eq) {
            let k = col[v.0 as usize];
            if k != usize::MAX {
                row[k] = if v == a.var { '#' } else { 'x' };
            }
        }
        let _ = writeln!(
            out,
            "  {:>6} {}",
            a.eq.to_string(),
            row.iter().collect::<String>()
        );
    }
    out
}

/// What index reduction did: constraints, removed integrators, the
/// differentiated equations (with the equation each came from), final states.
pub fn index_reduction(orig: &EquationSystem, red: &crate::analysis::IndexReduction) -> String {
    let sys = &red.system;
    let mut out = String::new();
    let _ = writeln!(out, "index reduction (Pantelides):");
    for r in &red.removed {
        let _ = writeln!(
            out,
            "  constraint {}: {}    ; {}",
            r.constraint,
            print::equation(orig, r.constraint),
            orig.eqs[r.constraint].origin.describe()
        );
        let _ = writeln!(
            out,
            "    integrator of {} removed: {} and {} are algebraic unknowns",
            sys.var_name(r.state),
            sys.var_name(r.state),
            sys.var_name(r.der)
        );
    }
    let _ = writeln!(
        out,
        "  differentiated equations ({}):",
        red.differentiated.len()
    );
    for d in &red.differentiated {
        let _ = writeln!(
            out,
            "    {:>5}  {}    ; d/dt of {}",
            d.eq.to_string(),
            print::equation(sys, d.eq),
            d.of
        );
    }
    let states: Vec<&str> = sys.states().map(|v| sys.var_name(v)).collect();
    let _ = writeln!(out, "  states ({}): {}", states.len(), states.join(", "));
    out
}

pub fn index_reduction_json(
    orig: &EquationSystem,
    red: &crate::analysis::IndexReduction,
) -> serde_json::Value {
    let sys = &red.system;
    json!({
        "constraints": red.removed.iter().map(|r| json!({
            "eq": r.constraint.to_string(),
            "equation": print::equation(orig, r.constraint),
            "origin": orig.eqs[r.constraint].origin.describe(),
            "removed_integrator": sys.var_name(r.state),
            "now_algebraic": [sys.var_name(r.state).to_string(), sys.var_name(r.der).to_string()],
        })).collect::<Vec<_>>(),
        "differentiated": red.differentiated.iter().map(|d| json!({
            "eq": d.eq.to_string(),
            "equation": print::equation(sys, d.eq),
            "of": d.of.to_string(),
        })).collect::<Vec<_>>(),
        "states": sys.states().map(|v| sys.var_name(v).to_string()).collect::<Vec<_>>(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Chunks formatted apart (on threads) give the listing one chunk gives:
    /// row numbers continue across chunks and one width pads them all.
    #[test]
    fn chunked_listing_equals_the_whole() {
        // A resistive loop (a block with tears) between RC sections whose
        // rows differ in width.
        let mut net = String::from("chunks\nV1 n0 0 PULSE(0 1 0 1u 1u 1m 2m)\n");
        for i in 1..=40 {
            net.push_str(&format!("R{i} n{} n{i} 1k\nC{i} n{i} 0 1n\n", i - 1));
        }
        net.push_str("R100 n40 m 1k\nR101 m 0 {1k*2}\nR102 m n40 3k\n.tran 1u 1m\n.end\n");
        let path = std::path::Path::new("chunks.cir");
        let (sources, _) = crate::front::load("chunks.cir", path, net, &crate::io::FsLoader);
        let (ast, errors) = crate::front::parse(&sources);
        assert!(errors.is_empty());
        let (circuit, errors) = crate::elab::elaborate(&ast);
        assert!(errors.is_empty());
        let mut sys = crate::build::build(&circuit, Default::default()).system;
        let Ok(causal) = crate::analysis::causalize(&sys, Default::default()) else {
            panic!("the circuit does not sort");
        };
        let s = &crate::analysis::schedule(&mut sys, &causal);
        let sys = &sys;
        let rows: usize = s.steps.iter().map(numbered_rows).sum();
        let whole = text(sys, s);
        for threads in [2, 3, 7] {
            let mut out = Vec::new();
            write_chunked(sys, s, threads, rows, &mut out).expect("writes");
            assert_eq!(
                String::from_utf8(out).expect("text"),
                whole,
                "{threads} chunks"
            );
        }
        assert!(
            whole.contains("end of block 1") && whole.contains("   41  "),
            "{whole}"
        );
    }
}
