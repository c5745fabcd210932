//! Structural singularities: circuit faults named by their elements,
//! Pantelides' index reduction (seed example D step by step), and the
//! fixable circuits sorting with fewer states than storage elements.

use kausal::analysis::{self, StructuralError, pantelides};
use kausal::build::Options;
use kausal::diag::ToDiagnostic;
use kausal::elab::ElementKind;
use kausal::io::FsLoader;
use kausal::ir::{OriginKind, print};
use kausal::pipeline::{self, SortOptions};

use crate::errors::check_annotations;
use crate::{goldens, root, stem};

fn sort(file: &str, prefer: &[&str]) -> Result<pipeline::Sorted, Box<pipeline::Failed>> {
    let opts = SortOptions {
        prefer_state: prefer.iter().map(|s| s.to_string()).collect(),
        ..Default::default()
    };
    pipeline::sort(&root().join(file), &FsLoader, &opts)
}

#[test]
fn unfixable_faults_are_errors_that_name_the_elements() {
    let files = crate::cir_files("netlists/faults");
    assert!(files.len() >= 5);
    for path in files {
        let rel = path.strip_prefix(root()).unwrap().to_path_buf();
        let f = match pipeline::sort(&rel, &FsLoader, &SortOptions::default()) {
            Ok(_) => panic!("{} should not sort", rel.display()),
            Err(f) => f,
        };
        assert!(f.errors().next().is_some());
        let rendered = check_annotations(&rel, &f.sources, &f.diagnostics);
        goldens("faults").bind(|| insta::assert_snapshot!(stem(&rel), rendered));
    }
}

/// Storage elements of a circuit.
fn n_storage(s: &pipeline::Sorted) -> usize {
    s.elaborated
        .circuit
        .elements
        .values()
        .filter(|e| {
            matches!(
                e.kind,
                ElementKind::Capacitor { .. } | ElementKind::Inductor { .. }
            )
        })
        .count()
}

#[test]
fn fixable_faults_are_reported_and_reduced() {
    let cases: [(&str, &str, &[&str]); 5] = [
        (
            "cv_loop.cir",
            "C2's voltage is fixed by V1 and C1",
            &["V1", "C1", "C2"],
        ),
        (
            "parallel_caps.cir",
            "C1 and C2 form a loop of capacitors",
            &["C1", "C2"],
        ),
        (
            "li_cutset.cir",
            "L1 is in a cutset with current source I1",
            &["L1", "I1"],
        ),
        (
            "series_inductors_isrc.cir",
            "L2 is in a cutset with L1",
            &["L1", "L2"],
        ),
        (
            "seed_d_singular.cir",
            "L2 is in a cutset with L1 and current sources I1, I2 and I3",
            &["L2", "I1", "I3"],
        ),
    ];
    for (file, message, names) in cases {
        let s = sort(&format!("netlists/{file}"), &[]).unwrap_or_else(|f| {
            panic!(
                "{file}: {:?}",
                f.errors().map(|d| &d.message).collect::<Vec<_>>()
            )
        });
        let msgs: Vec<String> = s.faults.iter().map(|f| f.message()).collect();
        assert!(msgs.iter().any(|m| m.contains(message)), "{file}: {msgs:?}");
        let all = msgs.join(" ");
        for n in names {
            assert!(all.contains(n), "{file}: `{n}` not named in {msgs:?}");
        }
        let red = s.reduction.as_ref().expect("index reduction ran");
        let n_states = s.system().states().count();
        assert!(n_states < n_storage(&s), "{file}: {n_states} states");
        assert_eq!(n_states + red.removed.len(), n_storage(&s));
        assert_eq!(kausal::ir::verify(s.system()), vec![]);
    }
}

#[test]
fn seed_d_is_reduced_as_in_seed_001() {
    let s = sort("netlists/seed_d_singular.cir", &[]).ok().unwrap();
    let orig = &s.built.system;
    let red = s.reduction.as_ref().unwrap();
    let sys = &red.system;
    // The constraint: KCL at node 1, every unknown known.
    assert_eq!(red.constraints.len(), 1);
    let g = red.constraints[0];
    assert_eq!(print::equation(orig, g), "0 = i_I1 + i_I3 + i_L2 + i_C1");
    assert_eq!(orig.eqs[g].origin.describe(), "KCL at node 1");
    // Five added equations: the constraint, the three sources, iC = iL1 + I2.
    let of: Vec<String> = red
        .differentiated
        .iter()
        .map(|d| orig.eqs[d.of].origin.describe())
        .collect();
    let mut sorted_of = of.clone();
    sorted_of.sort();
    assert_eq!(
        sorted_of,
        ["I1", "I2", "I3", "KCL at node 1", "KCL at node 2"]
    );
    let texts: Vec<String> = red
        .differentiated
        .iter()
        .map(|d| print::equation(sys, d.eq))
        .collect();
    assert!(
        texts.contains(&"0 = der(i_I1) + der(i_I3) + der(i_L2) + der(i_C1)".to_string()),
        "{texts:?}"
    );
    assert!(
        texts.contains(&"der(i_C1) = der(i_I2) + der(i_L1)".to_string()),
        "{texts:?}"
    );
    for d in &red.differentiated {
        assert!(
            matches!(sys.eqs[d.eq].origin.kind, OriginKind::Derivative { of, .. } if of == d.of)
        );
    }
    // iL2 loses its integrator.
    assert_eq!(red.removed.len(), 1);
    assert_eq!(sys.var_name(red.removed[0].state), "i_L2");
    let states: Vec<&str> = sys.states().map(|v| sys.var_name(v)).collect();
    assert_eq!(states, ["i_L1", "u_C1"]);
    // The re-sort finds a 7x7 algebraic loop and tears it.
    let blocks: Vec<_> = s.schedule.blocks().collect();
    assert_eq!(blocks.len(), 1);
    assert_eq!(blocks[0].n_eqs(), 7);
    assert_eq!(blocks[0].tears.len(), 1);
    assert!(blocks[0].linear);
    let mut text = kausal::back::listing::index_reduction(orig, red);
    text.push_str(&kausal::back::listing::text(sys, &s.schedule));
    goldens("singular").bind(|| insta::assert_snapshot!("seed_d_singular", text));
}

#[test]
fn prefer_state_chooses_which_capacitor_keeps_its_state() {
    let s = sort("netlists/parallel_caps.cir", &[]).ok().unwrap();
    let states: Vec<&str> = s
        .system()
        .states()
        .map(|v| s.system().var_name(v))
        .collect();
    assert_eq!(states, ["u_C1"]);
    let s = sort("netlists/parallel_caps.cir", &["C2"]).ok().unwrap();
    let states: Vec<&str> = s
        .system()
        .states()
        .map(|v| s.system().var_name(v))
        .collect();
    assert_eq!(states, ["u_C2"]);
    assert!(
        s.faults[0]
            .message()
            .contains("C1's voltage is fixed by C2"),
        "{}",
        s.faults[0].message()
    );
    let f = sort("netlists/parallel_caps.cir", &["C9"]).err().unwrap();
    assert!(f.errors().any(|d| d.message.contains("C9")));
    // An element without a state is named, not silently passed over.
    let f = sort("netlists/parallel_caps.cir", &["R1"]).err().unwrap();
    assert!(
        f.errors()
            .any(|d| d.code == "K0321" && d.message.contains("`R1`")),
        "{:?}",
        f.errors().map(|d| &d.message).collect::<Vec<_>>()
    );
}

#[test]
fn index_reduction_is_bounded() {
    // Every round removes a state, so the rounds are bounded by the system;
    // the bound itself is an error, not a hang (here: no round allowed, as
    // one round handles both inductors' constraints).
    let path = root().join("netlists/series_inductors_isrc.cir");
    let (_, built) = pipeline::equations(&path, &FsLoader, Options::default())
        .ok()
        .unwrap();
    let opts = pantelides::Options {
        max_rounds: Some(0),
        ..Default::default()
    };
    let err = analysis::reduce_index(&built.system, &opts).unwrap_err();
    assert!(matches!(err, StructuralError::IndexLimit { .. }), "{err}");
    assert!(err.to_diagnostic().message.contains("did not finish"));
    let red = analysis::reduce_index(&built.system, &pantelides::Options::default())
        .unwrap()
        .unwrap();
    assert_eq!(red.removed.len(), 2);
}

/// `kausal sort` on netlist text (which must succeed): its standard error.
fn sort_stderr(text: &str) -> String {
    let dir = tempfile::tempdir().unwrap();
    let net = dir.path().join("net.cir");
    std::fs::write(&net, text).unwrap();
    let out = crate::kausal(&["sort", net.to_str().unwrap()]);
    assert!(out.status.success());
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// A chain of 30 inductors in a cutset with a current source gives 30
/// K0310 warnings: the CLI shows ten and counts the rest.
#[test]
fn repeated_warnings_are_counted_not_repeated() {
    let mut text = String::from("cutset chain\nI1 0 n0 1m\n");
    for k in 1..=30 {
        text.push_str(&format!("L{k} n{} n{k} 1u\n", k - 1));
    }
    text.push_str("R0 n30 0 1\n.tran 1u 10u\n.end\n");
    let err = sort_stderr(&text);
    assert_eq!(err.matches("⚠").count(), 10, "{err}");
    assert!(err.contains("K0310: 20 more like the 10 above"), "{err}");
}

/// One fault of 100 elements (a loop of a source and 100 capacitors) names
/// and labels 24 of them and counts the rest: it printed a labelled line
/// for each.
#[test]
fn a_long_loop_is_named_in_part() {
    let mut text = String::from("series loop\nV1 n0 0 1\n");
    for k in 1..=100 {
        text.push_str(&format!("C{k} n{} n{k} 1u\n", k - 1));
    }
    text.push_str("R0 n100 0 1\nC0 n100 0 1u\n.tran 1u 10u\n.end\n");
    let err = sort_stderr(&text);
    assert!(err.contains("C23, and 78 more form a loop"), "{err}");
    assert_eq!(err.matches("in the loop").count(), 24, "{err}");
}

/// `kausal check` goes through the structural analysis: a loop of voltage
/// sources is an error there (it said ok), a clean netlist reports its size.
#[test]
fn check_reports_structural_errors() {
    let check = |file: &str| crate::kausal(&["check", root().join(file).to_str().unwrap()]);
    let bad = check("netlists/faults/shorted_v.cir");
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("error"));
    let good = check("netlists/rc_with_ic.cir");
    assert!(good.status.success());
    let err = String::from_utf8_lossy(&good.stderr);
    assert!(
        err.contains("ok (5 elements, 3 nodes, 13 equations, 2 states)"),
        "{err}"
    );
}

/// A diode without series resistance across voltage sources (fuzz finding
/// 07): the sources fix its voltage, kausal continues the exponential
/// linearly beyond 50 N·Vt where ngspice evaluates it, and K0312 says so,
/// naming the diode and the sources; with RS, or a resistor in series, the
/// junction is not forced and nothing is said.
#[test]
fn a_diode_forced_by_voltage_sources_is_named() {
    let sort_text = |text: &str| {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("forced.cir");
        std::fs::write(&path, text).unwrap();
        pipeline::sort(&path, &FsLoader, &SortOptions::default())
            .unwrap_or_else(|f| panic!("{:?}", f.errors().map(|d| &d.message).collect::<Vec<_>>()))
    };
    let forced = "forced\nV1 a 0 PWL(0 0 1m 14)\nV2 a b 1\nD1 b 0 dm\nR1 a 0 1k\n.model dm d(is=1e-9 n=2)\n.tran 10u 1m\n.end\n";
    let s = sort_text(forced);
    let msgs: Vec<String> = s.faults.iter().map(|f| f.message()).collect();
    let m = msgs
        .iter()
        .find(|m| m.contains("D1 has no series resistance"))
        .unwrap_or_else(|| panic!("{msgs:?}"));
    assert!(m.contains("V1 and V2 fix its voltage"), "{m}");
    assert!(
        s.faults
            .iter()
            .any(|f| f.to_diagnostic().code == kausal::diag::codes::FORCED_JUNCTION)
    );
    for free in [
        forced.replace("d(is=1e-9 n=2)", "d(is=1e-9 n=2 rs=1)"),
        forced.replace("D1 b 0 dm", "D1 b c dm\nRS c 0 1"),
    ] {
        let s = sort_text(&free);
        assert!(
            s.faults
                .iter()
                .all(|f| !f.message().contains("series resistance")),
            "{free}"
        );
    }
}

/// Three inductor cutsets, two fixed by current-controlled sources and the
/// third through them (fuzz finding 09 without its K lines, its sources made
/// smooth): each cutset names a different inductor as the one it fixes, the
/// narrowest cutsets first (the one through L1, L2 and L3 is left L1 or L3
/// once L2's own cutset has taken L2).
#[test]
fn each_inductor_cutset_fixes_a_different_inductor() {
    let text = "cutsets through controlled sources\nV2 n12 n1 SIN(-2 6 100k)\nV3 0 n13 SIN(-5 0.5 50k)\nL1 n10 n11 300u\nR6 n10 n7 5.7k\nV4 n2 n13 SIN(0 -3.8 100k)\nR7 n5 n4 1.7k\nR8 n13 n8 560\nC1 n4 n7 6.5n\nC2 n13 n3 100n\nL2 n12 n9 2.7m\nR9 n1 n5 1.3k\nF1 n7 n9 V3 0.58\nC3 n13 n6 12n\nL3 n8 n7 180u\nC4 n6 n3 1.5n\nF3 n11 n2 V4 -0.066\n.tran 0.5u 60u\n.end\n";
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cutsets.cir");
    std::fs::write(&path, text).unwrap();
    let msgs: Vec<String> = match pipeline::sort(&path, &FsLoader, &SortOptions::default()) {
        Ok(s) => s.faults.iter().map(|f| f.message()).collect(),
        Err(f) => f.diagnostics.iter().map(|d| d.message.clone()).collect(),
    };
    for l in [
        "L1 is in a cutset",
        "L2 is in a cutset",
        "L3 is in a cutset",
    ] {
        assert!(msgs.iter().any(|m| m.contains(l)), "{l}: {msgs:?}");
    }
}
