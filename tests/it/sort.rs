//! The causalizer: the seeds' examples come out as the seeds show them, every
//! sorted system is (block) lower-triangular, and the assignments evaluated
//! in order satisfy every original equation — on the fixtures and on random
//! circuits.

use std::collections::HashMap;

use kausal::analysis::{self, Causalization, Schedule, Solved, Step};
use kausal::back::{interp, listing};
use kausal::build::{Kvl, Options};
use kausal::diag::{self, ToDiagnostic};
use kausal::io::FsLoader;
use kausal::ir::{EquationSystem, OriginKind, VarId};
use kausal::pipeline::{self, Sorted};
use proptest::prelude::*;

use crate::{goldens, netlists, root, stem};

fn sort_opts(build: Options) -> pipeline::SortOptions {
    pipeline::SortOptions {
        build,
        ..Default::default()
    }
}

fn sorted(file: &str, opts: Options) -> Sorted {
    let path = root().join("netlists").join(file);
    match pipeline::sort(&path, &FsLoader, &sort_opts(opts)) {
        Ok(s) => s,
        Err(f) => panic!(
            "{file}: {:?}",
            f.errors().map(|d| &d.message).collect::<Vec<_>>()
        ),
    }
}

/// For each unknown (by name): the origin of the equation that computes it.
fn computed_from(s: &Sorted) -> HashMap<String, String> {
    let sys = s.system();
    s.schedule
        .assignments()
        .map(|a| {
            (
                sys.var_name(a.var).to_string(),
                sys.eqs[a.eq].origin.describe(),
            )
        })
        .collect()
}

fn expect_from(map: &HashMap<String, String>, pairs: &[(&str, &str)]) {
    for (var, origin) in pairs {
        assert_eq!(
            map.get(*var).map(String::as_str),
            Some(*origin),
            "`{var}` should be computed from `{origin}`"
        );
    }
}

#[test]
fn seed_a_sorts_as_in_seed_000() {
    let s = sorted(
        "seed_a_rc_rl.cir",
        Options {
            kvl: Kvl::Loops,
            alias: true,
            ..Default::default()
        },
    );
    let sys = s.system();
    // uR2 := R2*iL; uR1 := u1 - uC; uL := uC - uR2; i := uR1/R1;
    // iC := i - iL; duC/dt := iC/C; diL/dt := uL/L.
    let text: Vec<String> = s
        .schedule
        .assignments()
        .map(|a| match a.solved {
            Solved::Explicit(e) => {
                let mut t = format!("{} := ", sys.var_name(a.var));
                kausal::ir::print::write_expr_in(sys, &sys.exprs, e, &mut t);
                t
            }
            Solved::Implicit(_) => panic!("seed A is explicit"),
        })
        .collect();
    for want in [
        "u_R2 := R2*i_L1",
        "u_R1 := V1(t) - u_C1",
        "u_L1 := u_C1 - u_R2",
        "i_R1 := u_R1/R1",
        "i_C1 := i_R1 - i_L1",
        "der(u_C1) := i_C1/C1",
        "der(i_L1) := u_L1/L1",
    ] {
        assert!(
            text.contains(&want.to_string()),
            "missing `{want}` in {text:?}"
        );
    }
    assert_eq!(text.len(), 7);
    assert!(s.causal.tears.is_empty());
}

#[test]
fn seed_b_is_lower_triangular_as_in_seed_001() {
    let s = sorted("seed_b_cellier12.cir", Options::default());
    assert_eq!(s.system().eqs.len(), 12);
    assert!(s.causal.tears.is_empty() && s.schedule.blocks().next().is_none());
    let m = computed_from(&s);
    expect_from(
        &m,
        &[
            ("u_V0", "V0"),
            ("v(2)", "branch of C1"),
            ("u_R2", "branch of R2"),
            ("u_L1", "branch of L1"),
            ("v(1)", "branch of V0"),
            ("i_R2", "R2"),
            ("u_R1", "branch of R1"),
            ("i_R1", "R1"),
            ("i_C1", "KCL at node 2"),
            ("i_V0", "KCL at node 1"),
            ("der(i_L1)", "L1"),
            ("der(u_C1)", "C1"),
        ],
    );
}

#[test]
fn seed_c_tears_i1_as_in_seed_001() {
    let s = sorted("seed_c_algebraic_loop.cir", Options::default());
    let sys = s.system();
    let blocks: Vec<_> = s.schedule.blocks().collect();
    assert_eq!(blocks.len(), 1);
    let b = blocks[0];
    let tears: Vec<&str> = b.tears.iter().map(|&v| sys.var_name(v)).collect();
    assert_eq!(tears, ["i_R1"], "the seed tears i1, the current of R1");
    assert_eq!(
        sys.eqs[b.residuals[0].eq].origin.describe(),
        "KCL at node 2"
    );
    assert!(b.linear);
    assert_eq!(b.elements, ["R1", "R2", "R3"]);
    let m = computed_from(&s);
    expect_from(
        &m,
        &[
            ("u_V0", "V0"),
            ("i_R1", "KCL at node 2"),
            ("u_R1", "R1"),
            ("i_R2", "R2"),
            ("i_R3", "R3"),
            ("i_V0", "KCL at node 1"),
            ("der(i_L1)", "L1"),
        ],
    );
    // The seed's loop form: same tearing variable and residual.
    let s = sorted(
        "seed_c_algebraic_loop.cir",
        Options {
            kvl: Kvl::Loops,
            alias: true,
            ..Default::default()
        },
    );
    let sys = s.system();
    let b = s.schedule.blocks().next().expect("a block");
    assert_eq!(sys.var_name(b.tears[0]), "i_R1");
    assert_eq!(
        sys.eqs[b.residuals[0].eq].origin.describe(),
        "KCL at node 2"
    );
    assert_eq!(b.n_eqs(), 6, "the seed's loop has six equations");
}

#[test]
fn controlled_source_ring_is_named_and_torn() {
    let s = sorted("controlled_loop.cir", Options::default());
    let b = s
        .schedule
        .blocks()
        .next()
        .expect("the ring is an algebraic loop");
    for g in ["G1", "G2", "G3", "G4", "G5", "R1", "R5"] {
        assert!(
            b.elements.iter().any(|e| e == g),
            "{g} missing from {:?}",
            b.elements
        );
    }
    assert!(b.linear);
    assert_eq!(b.tears.len(), 1);
    let text = listing::text(s.system(), &s.schedule);
    assert!(text.contains("algebraic loop through RIN, G1, R1, G2, R2, G3, R3, G4, R4, G5, R5"));
}

/// Every assignment reads only unknowns computed before it, except that
/// inside a block the tearing variables are guessed first and residuals come
/// last. Returns the violations.
fn check_order(sys: &EquationSystem, c: &Causalization, s: &Schedule) -> Vec<String> {
    let mut known = vec![false; sys.vars.len()];
    for (v, var) in sys.vars.iter() {
        known[v.0 as usize] = !var.is_unknown();
    }
    let mut bad = Vec::new();
    let check = |a: &kausal::analysis::Assignment, known: &Vec<bool>, bad: &mut Vec<String>| {
        for w in c.graph.eq_vars(a.eq) {
            if w != a.var && !known[w.0 as usize] {
                bad.push(format!(
                    "{} reads {} before it is computed",
                    a.eq,
                    sys.var_name(w)
                ));
            }
        }
    };
    for step in &s.steps {
        match step {
            Step::Assign(a) => {
                check(a, &known, &mut bad);
                known[a.var.0 as usize] = true;
            }
            Step::Block(b) => {
                for &t in &b.tears {
                    known[t.0 as usize] = true;
                }
                for a in &b.inner {
                    check(a, &known, &mut bad);
                    known[a.var.0 as usize] = true;
                }
                for a in &b.residuals {
                    check(a, &known, &mut bad);
                }
            }
        }
    }
    if s.assignments().count() != sys.eqs.len() {
        bad.push("not every equation is scheduled".into());
    }
    bad
}

/// Random state values, run the schedule, then check every equation.
fn check_equations(sys: &EquationSystem, s: &Schedule, seed: u64) -> Result<(), String> {
    let mut vals = vec![0.0; sys.vars.len()];
    let mut x = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    for v in sys.states() {
        x = x
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let r = ((x >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0;
        // Junction charges are a tenth of a picocoulomb: a few tenths of a
        // volt on picofarad junctions (more forward-biases a transistor's
        // junctions to currents beyond any circuit's).
        let scale = if sys.vars[v].kind == kausal::ir::VarKind::Charge {
            1e-13
        } else {
            1.0
        };
        vals[v.0 as usize] = r * scale;
    }
    // Aliases are computed from their expressions after the run.
    let t = 1.234e-4;
    let floors: HashMap<_, f64> = interp::run(sys, s, &mut vals, t)
        .map_err(|e| e.to_string())?
        .into_iter()
        .collect();
    for (v, var) in sys.vars.iter() {
        if let Some(a) = var.alias {
            vals[v.0 as usize] = interp::eval(sys, &sys.exprs, a, &vals, t);
        }
    }
    for (eq, e) in sys.eqs.iter() {
        let l = interp::eval(sys, &sys.exprs, e.lhs, &vals, t);
        let r = interp::eval(sys, &sys.exprs, e.rhs, &vals, t);
        // Judged against the size of the terms, not of their sum (a KCL
        // sum of milliamperes cancels to zero).
        let size = |e| interp::magnitude(sys, &sys.exprs, e, &vals, t);
        let scale = size(e.lhs).max(size(e.rhs)).max(1e-3);
        // A loop-closing equation cannot beat its tears' rounding.
        let floor = floors.get(&eq).copied().unwrap_or(0.0);
        let ok = (l - r).abs() <= (1e-9 * scale).max(floor);
        if !ok {
            return Err(format!(
                "{eq} `{}`: {l} != {r} (terms of size {scale:.3e}, rounding floor {floor:.1e})",
                kausal::ir::print::equation(sys, eq)
            ));
        }
    }
    Ok(())
}

#[test]
fn every_fixture_sorts_or_explains_why_not() {
    for path in netlists() {
        for (kvl, alias, suffix) in [(Kvl::Nodes, false, ""), (Kvl::Loops, true, "")] {
            let opts = Options {
                kvl,
                alias,
                ..Default::default()
            };
            let text = match pipeline::sort(&path, &FsLoader, &sort_opts(opts)) {
                Ok(s) => {
                    let sys = s.system();
                    assert_eq!(
                        check_order(sys, &s.causal, &s.schedule),
                        Vec::<String>::new(),
                        "{}",
                        path.display()
                    );
                    if let Err(e) = check_equations(sys, &s.schedule, 7) {
                        panic!("{} ({kvl:?}): {e}", path.display());
                    }
                    listing::text(sys, &s.schedule)
                }
                Err(f) => f
                    .diagnostics
                    .iter()
                    .filter(|d| d.is_error())
                    .map(|d| diag::render(&f.sources, d, Default::default()))
                    .collect::<Vec<_>>()
                    .join("\n"),
            };
            if kvl == Kvl::Nodes {
                goldens("sorted")
                    .bind(|| insta::assert_snapshot!(format!("{}{suffix}", stem(&path)), text));
            }
        }
    }
}

#[test]
fn singular_seed_d_names_the_constraint() {
    let path = root().join("netlists/seed_d_singular.cir");
    let (_, built) = pipeline::equations(&path, &FsLoader, Options::default())
        .ok()
        .unwrap();
    let err = analysis::causalize(&built.system, analysis::Options::default()).unwrap_err();
    let d = err.to_diagnostic();
    assert!(
        d.message.contains("0 = i_I1 + i_I3 + i_L2 + i_C1"),
        "{}",
        d.message
    );
    assert!(d.message.contains("KCL at node 1"));
}

/// A random circuit that is well posed for almost any values: every node has
/// a resistor to ground, sources and storage elements sit on top.
pub(crate) fn circuit() -> impl Strategy<Value = String> {
    let elem = (
        0u8..9,
        1usize..7,
        0usize..7,
        1u32..1000,
        0usize..7,
        0usize..7,
    );
    (2usize..7, prop::collection::vec(elem, 1..14)).prop_map(|(n, elems)| {
        let mut s = String::from("random circuit\n");
        for k in 1..=n {
            s.push_str(&format!("RG{k} {k} 0 {}\n", 100 * k));
        }
        let mut vsrc: Vec<String> = Vec::new();
        for (i, (kind, a, b, val, c, d)) in elems.into_iter().enumerate() {
            let (a, b) = (a % (n + 1), b % (n + 1));
            let (c, d) = (c % (n + 1), d % (n + 1));
            if a == b {
                continue;
            }
            let v = val as f64;
            match kind {
                0 | 1 => s.push_str(&format!("R{i} {a} {b} {v}\n")),
                2 => s.push_str(&format!("C{i} {a} {b} {}n\n", v)),
                3 => s.push_str(&format!("L{i} {a} {b} {}u\n", v)),
                4 => {
                    // A source in series with a resistor keeps loops of
                    // voltage sources from forming.
                    s.push_str(&format!("V{i} {a} m{i} SIN(0 1 {v}k)\nRV{i} m{i} {b} 10\n"));
                    vsrc.push(format!("V{i}"));
                }
                5 => s.push_str(&format!("I{i} {a} {b} PULSE(0 1m 0 1u 1u 1m 2m)\n")),
                6 => s.push_str(&format!("G{i} {a} {b} {c} {d} {}m\n", v / 2000.0)),
                7 if c != d => {
                    s.push_str(&format!("E{i} {a} e{i} {c} {d} 0.3\nRE{i} e{i} {b} 50\n"))
                }
                8 if !vsrc.is_empty() => {
                    let ctrl = &vsrc[i % vsrc.len()];
                    s.push_str(&format!("F{i} {a} {b} {ctrl} 0.4\n"));
                }
                _ => {}
            }
        }
        s.push_str(".tran 1u 1m\n.end\n");
        s
    })
}

/// Sort `text` and check the order and the equations at a random point.
fn random_circuit_checks(text: &str, kvl: Kvl, alias: bool) -> Result<(), String> {
    let path = std::path::Path::new("random.cir");
    let el = match pipeline::elaborate_text("random.cir", path, text.to_string(), &FsLoader) {
        Ok(el) => el,
        Err(f) => {
            let errors: Vec<_> = f.errors().map(|d| &d.message).collect();
            return Err(format!("generated circuit does not elaborate: {errors:?}"));
        }
    };
    let built = kausal::build::build(
        &el.circuit,
        Options {
            kvl,
            alias,
            ..Default::default()
        },
    );
    // Capacitor loops are reduced (Pantelides); unfixable faults are the
    // diagnostics' business, not a sorting failure.
    let opts = pipeline::SortOptions {
        build: Options {
            kvl,
            alias,
            ..Default::default()
        },
        ..Default::default()
    };
    let sorted = match pipeline::sort_built(el, built, &opts) {
        Ok(s) => s,
        // Only unfixable circuit faults may stop the sorting.
        Err(f) if f.errors().all(|d| d.code == "K0311") => return Ok(()),
        Err(f) => {
            return Err(format!(
                "{:?}",
                f.errors().map(|d| &d.message).collect::<Vec<_>>()
            ));
        }
    };
    let sys = sorted.system();
    let (c, s) = (&sorted.causal, &sorted.schedule);
    let order = check_order(sys, c, s);
    if !order.is_empty() {
        return Err(format!("{order:?}"));
    }
    match check_equations(sys, s, 11) {
        // A numerically singular loop (e.g. a controlled source exactly
        // cancelling) is not a sorting error; anything else is.
        Err(e) if !e.contains("singular Jacobian") => Err(e),
        _ => Ok(()),
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, failure_persistence: None, ..ProptestConfig::default() })]
    #[test]
    fn sorted_random_circuits_satisfy_their_equations(text in circuit(), kvl in prop_oneof![Just(Kvl::Nodes), Just(Kvl::Loops)], alias in any::<bool>()) {
        let checked = random_circuit_checks(&text, kvl, alias);
        prop_assert!(checked.is_ok(), "{}\n{text}", checked.unwrap_err());
    }
}

/// Cases from the property test: loops through controlled sources whose
/// equations the reference interpreter must not leave 4e-9 relative (a
/// residual judged against the cancelling sum, not its terms) or 5e-11 A off
/// KCL.
#[test]
fn random_circuit_regressions() {
    let cases = [
        (
            "random circuit\nRG1 1 0 100\nRG2 2 0 200\nRG3 3 0 300\nRG4 4 0 400\nRG5 5 0 500\n\
             RG6 6 0 600\nI0 2 1 PULSE(0 1m 0 1u 1u 1m 2m)\nL1 4 6 1u\nE2 2 e2 2 0 0.3\n\
             RE2 e2 1 50\nR3 3 5 403\nV4 4 m4 SIN(0 1 54k)\nRV4 m4 2 10\nG5 4 2 1 2 0.0005m\n\
             V6 2 m6 SIN(0 1 53k)\nRV6 m6 5 10\nC7 6 4 1n\n.tran 1u 1m\n.end\n",
            Kvl::Loops,
            false,
        ),
        (
            "random circuit\nRG1 1 0 100\nRG2 2 0 200\nRG3 3 0 300\nRG4 4 0 400\nRG5 5 0 500\n\
             RG6 6 0 600\nG0 2 1 5 0 0.036m\nV1 3 m1 SIN(0 1 15k)\nRV1 m1 2 10\nR2 6 2 708\n\
             G3 3 0 2 1 0.0005m\nF4 1 2 V1 0.4\nG5 5 6 2 3 0.0005m\nE6 5 e6 1 0 0.3\n\
             RE6 e6 0 50\nL7 1 2 1u\n.tran 1u 1m\n.end\n",
            Kvl::Nodes,
            false,
        ),
        (
            "random circuit\nRG1 1 0 100\nRG2 2 0 200\nRG3 3 0 300\nRG4 4 0 400\nRG5 5 0 500\n\
             C0 4 5 1n\nC1 5 0 89n\nC2 4 5 34n\n.tran 1u 1m\n.end\n",
            Kvl::Nodes,
            false,
        ),
    ];
    for (text, kvl, alias) in cases {
        if let Err(e) = random_circuit_checks(text, kvl, alias) {
            panic!("{e}\n{text}");
        }
    }
}

#[test]
fn tearing_off_reports_the_loop_with_its_elements() {
    let path = root().join("netlists/seed_c_algebraic_loop.cir");
    let (_, built) = pipeline::equations(&path, &FsLoader, Options::default())
        .ok()
        .unwrap();
    let err = analysis::causalize(&built.system, analysis::Options { tearing: false }).unwrap_err();
    let d = err.to_diagnostic();
    assert!(
        d.message.contains("algebraic loop of 7 equations"),
        "{}",
        d.message
    );
    let texts: Vec<String> = d.labels.iter().map(|l| l.message.clone()).collect();
    assert!(texts.iter().any(|t| t.contains("i_R1")), "{texts:?}");
}

#[test]
fn states_are_never_computed() {
    for file in ["seed_a_rc_rl.cir", "transformer_k.cir", "diode_bridge.cir"] {
        let s = sorted(file, Options::default());
        let sys = s.system();
        for a in s.schedule.assignments() {
            assert!(sys.vars[a.var].is_unknown());
            assert!(!matches!(
                sys.eqs[a.eq].origin.kind,
                OriginKind::Derivative { .. }
            ));
        }
        let states: Vec<VarId> = sys.states().collect();
        assert!(!states.is_empty());
    }
}
