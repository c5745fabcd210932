//! Bond graphs: snapshots of every netlist's bond graph, causality and
//! read-off equations (with the cross-check), the cross-check agreeing on
//! every netlist and failing on a wrong assignment, and the seeds' examples
//! as the seeds draw them.

use kausal::bondgraph::{self, Analysis, Stroke, VertexKind, check::Item, scap};
use kausal::io::FsLoader;
use kausal::pipeline::{self, SortOptions, Sorted};

use crate::{cir_files, goldens, kausal, netlists, root, stem};

fn sorted_with(file: &str, opts: &SortOptions) -> Sorted {
    let path = root().join("netlists").join(file);
    match pipeline::sort(&path, &FsLoader, opts) {
        Ok(s) => s,
        Err(f) => panic!(
            "{file}: {:?}",
            f.errors().map(|d| &d.message).collect::<Vec<_>>()
        ),
    }
}

fn sorted(file: &str) -> Sorted {
    sorted_with(file, &SortOptions::default())
}

fn analysed(s: &Sorted) -> Analysis {
    bondgraph::analyse(&s.elaborated.circuit)
}

/// The element names of the storage ports in derivative causality.
fn derivative(a: &Analysis) -> Vec<String> {
    let mut v: Vec<String> = a
        .causality
        .derivative()
        .filter_map(|s| s.state)
        .map(|k| a.graph.element_name(k.elem).to_string())
        .collect();
    v.sort();
    v
}

/// The element names whose states index reduction removed.
fn removed(s: &Sorted) -> Vec<String> {
    let mut v: Vec<String> = s
        .reduction
        .iter()
        .flat_map(|r| &r.removed)
        .map(|r| s.built.system.vars[r.state].origin.describe())
        .collect();
    v.sort();
    v
}

/// The sorted equations read off the graph, as text.
fn read_off(a: &Analysis) -> Vec<String> {
    let mut out = Vec::new();
    for step in &a.equations.steps {
        match step {
            bondgraph::equations::Step::Assign(k) => out.push(a.equations.print(*k)),
            bondgraph::equations::Step::Loop(l) => {
                out.extend(l.eqs.iter().map(|&k| a.equations.print(k)))
            }
        }
    }
    out
}

#[test]
fn bond_graphs_of_every_netlist() {
    for path in netlists() {
        let el = pipeline::elaborate_file(&path, &FsLoader)
            .ok()
            .unwrap_or_else(|| panic!("{} elaborates", path.display()));
        let a = bondgraph::analyse(&el.circuit);
        let check = pipeline::sort(&path, &FsLoader, &SortOptions::default())
            .ok()
            .map(|s| bondgraph::check(&s, &a));
        let text = bondgraph::text(&a, check.as_ref());
        goldens("bondgraph").bind(|| insta::assert_snapshot!(stem(&path), text));
    }
}

/// The acceptance test of the cross-check: on every netlist the bond
/// graph's causality agrees with the colouring and index reduction.
#[test]
fn the_cross_check_agrees_on_every_netlist() {
    let mut bad = Vec::new();
    for path in netlists() {
        let s = match pipeline::sort(&path, &FsLoader, &SortOptions::default()) {
            Ok(s) => s,
            Err(f) => panic!(
                "{}: {:?}",
                path.display(),
                f.errors().map(|d| &d.message).collect::<Vec<_>>()
            ),
        };
        let a = analysed(&s);
        let check = bondgraph::check(&s, &a);
        for f in check.findings.iter().filter(|f| !f.agrees) {
            bad.push(format!("{}: {}: {}", stem(&path), f.item.title(), f.text));
        }
        // Every storage port is integral or derivative, and the numbers add
        // up to the storage the graph has.
        assert_eq!(
            a.causality.integral().count() + a.causality.derivative().count(),
            a.causality.storage.len(),
            "{}",
            path.display()
        );
        assert!(
            a.causality.conflicts.is_empty(),
            "{}: a sortable circuit has no causal conflict: {:?}",
            path.display(),
            a.causality.conflicts
        );
    }
    assert!(bad.is_empty(), "the views disagree:\n{}", bad.join("\n"));
}

/// The cross-check is not vacuous: given an assignment SCAP would not
/// make (cv_loop's C2 turned to integral causality, so that two bonds set
/// node b's effort), it reports the disagreement.
#[test]
fn the_cross_check_fails_on_a_wrong_assignment() {
    let s = sorted("cv_loop.cir");
    let a = analysed(&s);
    assert!(bondgraph::check(&s, &a).agrees());
    let c2 = a
        .causality
        .derivative()
        .next()
        .expect("cv_loop has a storage port in derivative causality");
    let mut strokes = a.causality.strokes.clone();
    let flip = |x: Stroke| match x {
        Stroke::Head => Stroke::Tail,
        Stroke::Tail => Stroke::Head,
    };
    strokes[c2.bond.0 as usize] = strokes[c2.bond.0 as usize].map(flip);
    let wrong = scap::evaluate(&a.graph, strokes);
    assert_eq!(wrong.derivative().count(), 0);
    assert!(!wrong.conflicts.is_empty(), "two bonds set v(b)");
    let equations = bondgraph::read_off(&a.graph, &wrong);
    let check = bondgraph::check::check_with(&s, &a.graph, &wrong, &equations);
    assert!(!check.agrees());
    let differ: Vec<Item> = check
        .findings
        .iter()
        .filter(|f| !f.agrees)
        .map(|f| f.item)
        .collect();
    assert!(differ.contains(&Item::States), "{differ:?}");
    assert!(differ.contains(&Item::Dependent), "{differ:?}");
    let e = bondgraph::BondGraphError::disagreement(&check).expect("a disagreement");
    assert!(e.to_string().contains("states"), "{e}");
    // And the other way: seed A with its inductor forced into derivative
    // causality has one state too few.
    let s = sorted("seed_a_rc_rl.cir");
    let a = analysed(&s);
    let l1 = a
        .causality
        .storage
        .iter()
        .find(|p| a.graph.vertices[p.vertex].kind == VertexKind::I)
        .unwrap();
    let mut strokes = a.causality.strokes.clone();
    strokes[l1.bond.0 as usize] = strokes[l1.bond.0 as usize].map(flip);
    let wrong = scap::evaluate(&a.graph, strokes);
    let equations = bondgraph::read_off(&a.graph, &wrong);
    let check = bondgraph::check::check_with(&s, &a.graph, &wrong, &equations);
    let states = &check.findings[0];
    assert_eq!(states.item, Item::States);
    assert!(!states.agrees, "{}", states.text);
}

/// Seed 000's RC–RL circuit: every storage element integral, no loop, and
/// the equations read off the causal graph are seed 000's seven
/// assignments (with v(b) for uC, which the capacitor gives the junction).
#[test]
fn seed_a_is_integral_throughout() {
    let s = sorted("seed_a_rc_rl.cir");
    let a = analysed(&s);
    assert_eq!(derivative(&a), Vec::<String>::new());
    assert_eq!(a.causality.integral().count(), 2);
    assert!(a.causality.conflicts.is_empty());
    assert_eq!(a.equations.loops().count(), 0);
    assert_eq!(
        read_off(&a),
        [
            "u_V1 := V1(t)",
            "v(b) := u_C1",
            "u_R2 := R2*i_L1",
            "u_R1 := u_V1 - v(b)",
            "i_R1 := u_R1/R1",
            "i_C1 := i_R1 - i_L1",
            "der(u_C1) := i_C1/C1",
            "u_L1 := v(b) - u_R2",
            "der(i_L1) := u_L1/L1",
        ]
    );
    // The textbook graph: Se into a 1-junction with R1, a 0-junction with
    // C1, a 1-junction with R2 and L1; nothing else.
    let mut kinds: Vec<&str> = a
        .graph
        .live_vertices()
        .map(|(_, v)| v.kind.symbol())
        .collect();
    kinds.sort();
    assert_eq!(kinds, ["0", "1", "1", "C", "I", "R", "R", "Se"]);
    assert!(bondgraph::check(&s, &a).agrees());
}

/// Seed 003's Se–R–L–C example simplifies to one 1-junction (Slika 7c) and
/// is in integral causality throughout (Slika 8).
#[test]
fn seed_003_simplifies_to_one_junction_in_integral_causality() {
    let s = sorted("seed_003_se_r_l_c.cir");
    let a = analysed(&s);
    let g = &a.graph;
    let mut kinds: Vec<&str> = g.live_vertices().map(|(_, v)| v.kind.symbol()).collect();
    kinds.sort();
    assert_eq!(kinds, ["1", "C", "I", "R", "Se"]);
    let rules: Vec<bondgraph::Rule> = g.simplified.iter().map(|s| s.rule).collect();
    for r in [bondgraph::Rule::A, bondgraph::Rule::B, bondgraph::Rule::C] {
        assert!(rules.contains(&r), "{r:?} applied: {rules:?}");
    }
    assert_eq!(derivative(&a), Vec::<String>::new());
    assert_eq!(a.causality.integral().count(), 2);
    // The inductor sets the common flow; R, C and the source take it.
    assert_eq!(
        read_off(&a),
        [
            "u_V1 := V1(t)",
            "der(u_C1) := i_L1/C1",
            "u_R1 := R1*i_L1",
            "u_L1 := u_V1 - u_R1 - u_C1",
            "der(i_L1) := u_L1/L1",
        ]
    );
    assert!(bondgraph::check(&s, &a).agrees());
}

/// Seed D: one inductor in derivative causality, L2, the one whose
/// integrator Pantelides removes; the loop through the derivatives is the
/// colouring's block.
#[test]
fn seed_d_has_one_inductor_in_derivative_causality() {
    let s = sorted("seed_d_singular.cir");
    let a = analysed(&s);
    assert_eq!(derivative(&a), ["L2"]);
    assert_eq!(removed(&s), ["L2"]);
    let loops: Vec<Vec<&str>> = a
        .equations
        .loops()
        .map(|l| {
            l.elements
                .iter()
                .map(|&e| a.graph.element_name(e))
                .collect()
        })
        .collect();
    assert_eq!(loops, [["L1", "L2"]]);
    assert!(bondgraph::check(&s, &a).agrees());
}

/// A loop of a voltage source and two capacitors: C2 in derivative
/// causality, the state Pantelides removes.
#[test]
fn cv_loop_has_c2_in_derivative_causality() {
    let s = sorted("cv_loop.cir");
    let a = analysed(&s);
    assert_eq!(derivative(&a), ["C2"]);
    assert_eq!(removed(&s), ["C2"]);
    let c2 = a.causality.derivative().next().unwrap();
    assert!(!c2.chosen, "propagation, not a choice, put C2 there");
    assert!(bondgraph::check(&s, &a).agrees());
}

/// Four junction charges in a ring away from ground (two paralleled BJTs
/// behind base resistors): the loop of junctions alone reaches the states
/// only through each charge's own law (`v = Q^-1(q)`), and SCAP puts the
/// charge index reduction removes in derivative causality. The loops of the
/// two views still differ: the read-off differentiates the dependent
/// charge's whole chain (the transport currents' laws among it) and solves
/// it with the loop, where the colouring differentiates the constraint alone.
#[test]
fn a_ring_of_junction_charges_has_a_dependent_charge() {
    let s = sorted("hard/bjt_paralleled.cir");
    let a = analysed(&s);
    assert_eq!(derivative(&a), ["Q1a:bc"]);
    assert_eq!(removed(&s), ["Q1a:bc"]);
    let check = bondgraph::check(&s, &a);
    let agrees: Vec<(Item, bool)> = check.findings.iter().map(|f| (f.item, f.agrees)).collect();
    assert_eq!(
        agrees,
        [
            (Item::States, true),
            (Item::Dependent, true),
            (Item::Arbitrary, true),
            (Item::Loops, false),
            (Item::Laws, true)
        ]
    );
}

/// An inductor cutset with a current source: the inductor in derivative
/// causality, as Pantelides has it; two in series, both.
#[test]
fn inductor_cutsets_with_current_sources() {
    for (file, expected) in [
        ("li_cutset.cir", vec!["L1"]),
        ("series_inductors_isrc.cir", vec!["L1", "L2"]),
    ] {
        let s = sorted(file);
        let a = analysed(&s);
        assert_eq!(derivative(&a), expected, "{file}");
        assert_eq!(removed(&s), expected, "{file}");
        assert!(bondgraph::check(&s, &a).agrees(), "{file}");
    }
}

/// When index reduction keeps the other capacitor (`--prefer-state C2`),
/// SCAP in netlist order still puts C2 in derivative causality; the check
/// finds SCAP's equally valid assignment with C1 there and says so.
#[test]
fn a_different_but_equally_valid_choice_is_named() {
    let s = sorted_with(
        "cv_loop.cir",
        &SortOptions {
            prefer_state: vec!["C2".into()],
            ..Default::default()
        },
    );
    assert_eq!(removed(&s), ["C1"]);
    let a = analysed(&s);
    assert_eq!(derivative(&a), ["C2"]);
    let check = bondgraph::check(&s, &a);
    assert!(check.agrees(), "{:?}", check.findings);
    let dependent = &check.findings[1];
    assert!(
        dependent.text.contains("equally valid"),
        "{}",
        dependent.text
    );
    let (alt, _) = check.alternative.as_ref().expect("the alternative");
    let names: Vec<&str> = alt
        .derivative()
        .filter_map(|p| p.state)
        .map(|k| a.graph.element_name(k.elem))
        .collect();
    assert_eq!(names, ["C1"]);
}

/// A diode bridge whose resistors, chosen in netlist order, would leave a
/// junction that nothing can set: SCAP goes back and turns the latest
/// choices, and ends without a conflict, in agreement with the equations.
#[test]
fn scap_goes_back_where_a_choice_leads_to_a_conflict() {
    let s = sorted("bench/vacask_graetz.cir");
    let a = analysed(&s);
    assert!(
        a.causality.conflicts.is_empty(),
        "{:?}",
        a.causality.conflicts
    );
    assert!(
        a.causality.arbitrary().any(|d| d.turned),
        "a choice was turned"
    );
    assert_eq!(a.causality.integral().count(), 5);
    assert!(bondgraph::check(&s, &a).agrees());
}

/// Perfect coupling: the winding past the field's rank is in derivative
/// causality by its law (SCAP 1b), as the build keeps no flux of it.
#[test]
fn a_perfectly_coupled_field_keeps_one_flux() {
    let s = sorted("perfect_coupling.cir");
    let a = analysed(&s);
    assert_eq!(derivative(&a), ["L2"]);
    let l2 = a.causality.derivative().next().unwrap();
    assert!(l2.chosen, "fixed by the field's law, not by propagation");
    assert!(bondgraph::check(&s, &a).agrees());
}

/// E and F that form an ideal transformer are one TF; two cross-coupled G
/// that lose no power are one GY.
#[test]
fn controlled_source_pairs_are_transformers_and_gyrators() {
    for (file, kind, label) in [
        ("transformer_ef_leakage.cir", VertexKind::Tf, "F1·E1"),
        ("gyrator_inductor.cir", VertexKind::Gy, "G1·G2"),
    ] {
        let s = sorted(file);
        let a = analysed(&s);
        let found: Vec<&str> = a
            .graph
            .live_vertices()
            .filter(|(_, v)| v.kind == kind)
            .map(|(_, v)| v.label.as_str())
            .collect();
        assert_eq!(found, [label], "{file}");
        assert!(bondgraph::check(&s, &a).agrees(), "{file}");
    }
}

/// Circuits the equations cannot sort (loops of voltage sources, cutsets
/// of current sources, floating nodes) still give a bond graph, with a
/// causal conflict: the two views agree that the circuit is faulty.
#[test]
fn faulty_circuits_have_causal_conflicts() {
    for path in cir_files("netlists/faults") {
        let Ok(el) = pipeline::elaborate_file(&path, &FsLoader) else {
            continue;
        };
        let a = bondgraph::analyse(&el.circuit);
        assert!(
            pipeline::sort(&path, &FsLoader, &SortOptions::default()).is_err(),
            "{} does not sort",
            path.display()
        );
        assert!(
            !a.causality.conflicts.is_empty(),
            "{}: no causal conflict",
            path.display()
        );
        let check = bondgraph::check::check_unsorted(&a, "it does not sort");
        assert!(check.agrees(), "{}", path.display());
        let _ = bondgraph::text(&a, Some(&check));
        let _ = bondgraph::dot(&a);
    }
}

/// The DOT drawing: strokes at the end that takes the effort, derivative
/// causality in red.
#[test]
fn the_drawing_marks_strokes_and_derivative_causality() {
    let s = sorted("cv_loop.cir");
    let a = analysed(&s);
    let dot = bondgraph::dot(&a);
    assert!(dot.starts_with("digraph bondgraph {"), "{dot}");
    let c2 = a.causality.derivative().next().unwrap();
    let bond = &a.graph.bonds[c2.bond];
    let line = dot
        .lines()
        .find(|l| {
            l.trim_start()
                .starts_with(&format!("{} -> {}", bond.tail, bond.head))
        })
        .expect("C2's bond is drawn");
    assert!(line.contains("color=red"), "{line}");
    // C2 takes the effort: the stroke is at C2's end, the head.
    assert!(line.contains("arrowhead=teelvee"), "{line}");
    assert_eq!(dot.matches(" -> ").count(), a.graph.live_bonds().count());
}

#[test]
fn the_command_line_draws_checks_and_writes_json() {
    let seed_a = root().join("netlists/seed_a_rc_rl.cir");
    let seed_a = seed_a.to_str().unwrap();
    let out = kausal(&["bondgraph", seed_a, "--check"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("cross-check with the colouring and index reduction: agree"),
        "{text}"
    );
    let out = kausal(&["bondgraph", seed_a, "--format", "json", "--check"]);
    assert!(out.status.success());
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["check"]["agrees"], true);
    assert_eq!(v["bonds"].as_array().unwrap().len(), 7);
    assert!(
        v["equations"]
            .as_array()
            .unwrap()
            .iter()
            .any(|e| e["text"] == "der(i_L1) := u_L1/L1")
    );
    // A faulty circuit: the conflict as a warning, the check agreeing.
    let v_loop = root().join("netlists/faults/v_loop.cir");
    let out = kausal(&["bondgraph", v_loop.to_str().unwrap(), "--check"]);
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("K0600"));
}

/// SVG through Graphviz's `dot`, which must be installed.
#[test]
fn the_command_line_renders_svg() {
    let ok = std::process::Command::new("dot")
        .arg("-V")
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(
        ok,
        "Graphviz's dot is not installed: `kausal bondgraph --svg` needs it (apt-get install -y graphviz)"
    );
    let dir = tempfile::tempdir().unwrap();
    let svg = dir.path().join("seed_a.svg");
    let seed_a = root().join("netlists/seed_a_rc_rl.cir");
    let out = kausal(&[
        "bondgraph",
        seed_a.to_str().unwrap(),
        "--svg",
        svg.to_str().unwrap(),
        "-o",
        dir.path().join("seed_a.txt").to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(&svg).unwrap();
    assert!(text.contains("<svg"), "{text}");
    assert!(text.contains("I:L1"), "{text}");
}

/// The two views of a random circuit (resistors to ground at every node,
/// sources, storage and controlled sources on top): a sortable circuit's
/// check agrees; one the equations refuse has a causal conflict.
fn random_views_agree(text: &str) -> Result<(), String> {
    let path = std::path::Path::new("random.cir");
    let Ok(el) = pipeline::elaborate_text("random.cir", path, text.to_string(), &FsLoader) else {
        return Err("generated circuit does not elaborate".into());
    };
    let a = bondgraph::analyse(&el.circuit);
    let _ = bondgraph::dot(&a);
    let built = kausal::build::build(&el.circuit, Default::default());
    match pipeline::sort_built(el, built, &SortOptions::default()) {
        Ok(s) => {
            let check = bondgraph::check(&s, &a);
            let bad: Vec<String> = check
                .findings
                .iter()
                .filter(|f| !f.agrees)
                .map(|f| format!("{}: {}", f.item.title(), f.text))
                .collect();
            if bad.is_empty() {
                Ok(())
            } else {
                Err(bad.join("\n"))
            }
        }
        Err(_) if !a.causality.conflicts.is_empty() => Ok(()),
        Err(f) => Err(format!(
            "the equations refuse it ({:?}), the bond graph has no conflict",
            f.errors().map(|d| &d.message).collect::<Vec<_>>()
        )),
    }
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig { cases: 256, failure_persistence: None, ..Default::default() })]
    #[test]
    fn random_circuits_agree_in_both_views(text in crate::sort::circuit()) {
        let r = random_views_agree(&text);
        proptest::prop_assert!(r.is_ok(), "{}\n{text}", r.unwrap_err());
    }
}

/// Three capacitors in a loop between nodes that only resistors tie to
/// ground: propagation sets every junction once and leaves all three
/// integral, but the read-off equations then hold a loop of junctions alone
/// (the three voltages sum to zero). The last capacitor goes into
/// derivative causality, as Pantelides removes its state, and its
/// derivative is written from the loop: `der(u_C2) = der(u_C0) + der(u_C1)`.
#[test]
fn a_loop_of_capacitors_away_from_sources_is_found() {
    let text = "capacitor loop\nRG1 1 0 100\nRG2 2 0 200\nRG3 3 0 300\nC0 1 3 1n\nC1 3 2 1n\nC2 1 2 1n\n.tran 1u 1m\n.end\n";
    let path = std::path::Path::new("loop.cir");
    let el = pipeline::elaborate_text("loop.cir", path, text.into(), &FsLoader)
        .ok()
        .unwrap();
    let a = bondgraph::analyse(&el.circuit);
    assert_eq!(derivative(&a), ["C2"]);
    assert_eq!(a.causality.forced.len(), 1);
    assert!(
        read_off(&a).contains(&"der(u_C2) := der(u_C0) + der(u_C1)".to_string()),
        "{:?}",
        read_off(&a)
    );
    let built = kausal::build::build(&el.circuit, Default::default());
    let s = pipeline::sort_built(el, built, &SortOptions::default())
        .ok()
        .unwrap();
    assert_eq!(removed(&s), ["C2"]);
    assert!(bondgraph::check(&s, &a).agrees());
}
