//! Generated test circuits (netlist text) for benchmarks and scaling runs:
//! RC ladders, RLC ladders and resistor meshes of any size.

use std::fmt::Write;

/// An RC ladder of `n` sections driven by a 1 V step: `R_k` from node k-1
/// to k, `C_k` from k to ground. Time constants spread over three decades.
pub fn rc_ladder(n: usize) -> String {
    // Capacitances cycle through 1n..1u so that time constants differ.
    ladder(
        &format!("RC ladder with {n} sections"),
        "V1 n0 0 PULSE(0 1 1u 1u 1u 1 2)",
        n,
        |k| [1e-9, 1e-8, 1e-7, 1e-6][k % 4],
        ".tran 1u 10m",
    )
}

/// The RC ladder of the speed comparisons: `n` sections of 1 kΩ and 1 nF
/// behind a 1 kHz pulse, `.save v(n1) v(n10)`, and `.tran 20u 1m`, whose
/// TSTEP (span/50) leaves ngspice's step to its error control.
pub fn rc_ladder_free(n: usize) -> String {
    ladder(
        &format!("RC ladder of {n} sections at free steps"),
        "V1 n0 0 PULSE(0 1 0 1u 1u 0.5m 1m)",
        n,
        |_| 1e-9,
        ".save v(n1) v(n10)\n.tran 20u 1m",
    )
}

/// `title`, `source` into node n0, `n` sections of 1 kΩ and `c(k)`, then
/// the `tail` cards and `.end`.
fn ladder(title: &str, source: &str, n: usize, c: impl Fn(usize) -> f64, tail: &str) -> String {
    let mut s = String::with_capacity(n * 40 + 200);
    let _ = writeln!(s, "{title}\n{source}");
    for k in 1..=n {
        let _ = writeln!(s, "R{k} n{} n{k} 1k", k - 1);
        let _ = writeln!(s, "C{k} n{k} 0 {:e}", c(k));
    }
    let _ = writeln!(s, "{tail}\n.end");
    s
}

/// An RLC ladder of `n` sections (series R–L, shunt C) with a matched load.
pub fn rlc_ladder(n: usize) -> String {
    let mut s = String::with_capacity(n * 60 + 200);
    let _ = writeln!(s, "RLC ladder with {n} sections");
    s.push_str("V1 in 0 PULSE(0 1 1n 1n 1n 1 2)\nRS in n0 50\n");
    for k in 1..=n {
        let _ = writeln!(s, "R{k} n{} m{k} 0.1", k - 1);
        let _ = writeln!(s, "L{k} m{k} n{k} 25n");
        let _ = writeln!(s, "C{k} n{k} 0 10p");
    }
    let _ = writeln!(s, "RL n{n} 0 50");
    s.push_str(".tran 1n 1u\n.end\n");
    s
}

/// A `rows` × `cols` mesh of resistors, driven at a corner: every mesh is an
/// algebraic loop (one block for the whole mesh).
pub fn r_mesh(rows: usize, cols: usize) -> String {
    let mut s = String::with_capacity(rows * cols * 60 + 200);
    let _ = writeln!(s, "Resistor mesh {rows}x{cols}");
    s.push_str("V1 n0_0 0 PULSE(0 1 1u 1u 1u 1 2)\n");
    let mut k = 0;
    for r in 0..rows {
        for c in 0..cols {
            if c + 1 < cols {
                k += 1;
                let _ = writeln!(s, "R{k} n{r}_{c} n{r}_{} 1k", c + 1);
            }
            if r + 1 < rows {
                k += 1;
                let _ = writeln!(s, "R{k} n{r}_{c} n{}_{c} 1k", r + 1);
            }
        }
    }
    let _ = writeln!(s, "RG n{}_{} 0 1k", rows - 1, cols - 1);
    s.push_str(".tran 1u 1m\n.end\n");
    s
}

/// A resistor mesh as [`r_mesh`] with a capacitor from every `stride`-th
/// node to ground: loops between the capacitors' nodes, one state each.
pub fn rc_mesh(rows: usize, cols: usize) -> String {
    let mut s = r_mesh(rows, cols);
    let end = s.rfind(".tran").unwrap_or(s.len());
    let mut caps = String::new();
    for r in 0..rows {
        for c in 0..cols {
            if (r + c) % 3 == 0 && (r, c) != (0, 0) {
                let _ = writeln!(caps, "C{r}_{c} n{r}_{c} 0 1n");
            }
        }
    }
    s.insert_str(end, &caps);
    s
}

/// `n` inductors in series with a current source: every inductor current is
/// fixed by the source (`n` cutsets for index reduction).
pub fn inductor_cutset_chain(n: usize) -> String {
    let mut s = String::with_capacity(n * 24 + 200);
    let _ = writeln!(s, "Inductor cutset chain {n}");
    s.push_str("I1 0 n0 PULSE(0 1m 0.1m 50u 50u 1m 2m)\n");
    for k in 1..=n {
        let _ = writeln!(s, "L{k} n{} n{k} 1m", k - 1);
    }
    let _ = writeln!(s, "R1 n{n} 0 100");
    s.push_str(".tran 5u 1m\n.end\n");
    s
}

/// `n` capacitors in parallel behind a resistor: `n - 1` capacitor loops
/// for index reduction.
pub fn parallel_capacitors(n: usize) -> String {
    let mut s = String::with_capacity(n * 16 + 200);
    let _ = writeln!(s, "Parallel capacitors {n}");
    s.push_str("V1 n0 0 SIN(0 1 1k)\nR0 n0 a 1\n");
    for k in 1..=n {
        let _ = writeln!(s, "C{k} a 0 1u");
    }
    s.push_str(".tran 5u 1m\n.end\n");
    s
}
