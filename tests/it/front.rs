//! Front end: every fixture parses, the AST printer round-trips, random
//! mutations never panic.

use kausal::front::{self, print};
use kausal::io::FsLoader;
use proptest::prelude::*;

use crate::netlists;

/// The netlist `text`, elaborated; its errors fail the test.
fn elaborate(text: &str) -> kausal::pipeline::Elaborated {
    let path = std::path::Path::new("mem.cir");
    match kausal::pipeline::elaborate_text("mem.cir", path, text.to_string(), &FsLoader) {
        Ok(el) => el,
        Err(f) => panic!("{:?}", f.errors().map(|d| &d.message).collect::<Vec<_>>()),
    }
}

fn parse_print(name: &str, path: &std::path::Path, text: String) -> (String, usize) {
    let (sources, load_errors) = front::load(name, path, text, &FsLoader);
    let (ast, errors) = front::parse(&sources);
    let n_errors = load_errors.len()
        + errors
            .iter()
            .filter(|e| e.severity() == kausal::diag::Severity::Error)
            .count();
    (print::netlist(&ast), n_errors)
}

#[test]
fn every_netlist_parses_and_round_trips() {
    let files = netlists();
    assert!(files.len() >= 4, "the seed netlists are missing");
    for path in files {
        let text = std::fs::read_to_string(&path).unwrap();
        let name = path.display().to_string();
        let (printed, n_errors) = parse_print(&name, &path, text);
        assert_eq!(n_errors, 0, "{name} has parse errors");
        // Reparse the printed text as if it were the file itself, so that
        // includes resolve the same way.
        let (reprinted, n_errors2) = parse_print(&name, &path, printed.clone());
        assert_eq!(
            n_errors2, 0,
            "{name}: printed form has parse errors:\n{printed}"
        );
        assert_eq!(printed, reprinted, "{name}: print/parse is not a fixpoint");
    }
}

#[test]
fn round_trip_preserves_values() {
    let text = "t\n.param a=2\nR1 n1 n2 {a*2}\nC1 n2 0 1u ic=0.5\nV1 n1 0 DC 1 AC 1 PULSE(0 1 1n 1n 1n 5u 10u)\n\
                .model dm D(IS=1e-14 N=1.5)\nD1 n2 0 dm\n.tran 1n 10u 0 1n uic\n.options reltol=1e-4 method=gear\n\
                .ic v(n2)=0.25\n.print tran v(n1) v(n1,n2) i(v1)\n.end\n";
    let path = std::path::Path::new("mem.cir");
    let (printed, n) = parse_print("mem.cir", path, text.to_string());
    assert_eq!(n, 0);
    for needle in [
        "{a*2}",
        "ic=0.5",
        "PULSE(0 1 1n 1n 1n 5u 10u)",
        ".model dm D(IS=1e-14 N=1.5)",
        ".tran 1n 10u 0 1n uic",
        "method=gear",
        ".ic v(n2)=0.25",
        "v(n1,n2)",
        "i(v1)",
    ] {
        assert!(
            printed.contains(needle),
            "`{needle}` missing from:\n{printed}"
        );
    }
}

/// A random edit of a netlist's text.
#[derive(Debug, Clone)]
enum Mutation {
    Insert(usize, char),
    Delete(usize, usize),
    DuplicateLine(usize),
    SwapLines(usize, usize),
    ReplaceWord(usize, String),
    Truncate(usize),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    let chars = prop_oneof![
        Just('('),
        Just(')'),
        Just('{'),
        Just('}'),
        Just('='),
        Just('+'),
        Just('\n'),
        Just('.'),
        Just('*'),
        Just(' '),
        Just('\''),
        Just('-'),
        Just('e'),
        Just('0'),
        Just('x'),
        Just('\u{e9}'),
        Just(';'),
        Just('$'),
        Just(','),
    ];
    let words = prop_oneof![
        Just(".subckt"),
        Just(".ends"),
        Just(".include"),
        Just(".param"),
        Just("PULSE("),
        Just("{1/0}"),
        Just("X1"),
        Just("0"),
        Just("1e999"),
        Just("-1"),
        Just("K1"),
        Just("F1 a 0 V1"),
        Just(".end"),
        Just("gnd"),
        Just("params:"),
        Just("ic="),
        Just(".control"),
        Just("PWL(1 0 0 1)"),
        Just("1meg"),
        Just(""),
    ];
    prop_oneof![
        (any::<usize>(), chars).prop_map(|(i, c)| Mutation::Insert(i, c)),
        (any::<usize>(), 0usize..20).prop_map(|(i, n)| Mutation::Delete(i, n)),
        any::<usize>().prop_map(Mutation::DuplicateLine),
        (any::<usize>(), any::<usize>()).prop_map(|(a, b)| Mutation::SwapLines(a, b)),
        (any::<usize>(), words).prop_map(|(i, w)| Mutation::ReplaceWord(i, w.to_string())),
        any::<usize>().prop_map(Mutation::Truncate),
    ]
}

fn apply(text: &str, m: &Mutation) -> String {
    let floor = |s: &str, i: usize| {
        let mut i = if s.is_empty() { 0 } else { i % (s.len() + 1) };
        while !s.is_char_boundary(i) {
            i -= 1;
        }
        i
    };
    match m {
        Mutation::Insert(i, c) => {
            let i = floor(text, *i);
            format!("{}{c}{}", &text[..i], &text[i..])
        }
        Mutation::Delete(i, n) => {
            let a = floor(text, *i);
            let b = floor(text, a + n);
            format!("{}{}", &text[..a], &text[b.max(a)..])
        }
        Mutation::DuplicateLine(i) | Mutation::SwapLines(i, _) | Mutation::ReplaceWord(i, _) => {
            let mut lines: Vec<String> = text.lines().map(String::from).collect();
            if lines.is_empty() {
                return text.to_string();
            }
            let k = i % lines.len();
            match m {
                Mutation::DuplicateLine(_) => {
                    let l = lines[k].clone();
                    lines.insert(k, l);
                }
                Mutation::SwapLines(_, j) => {
                    let j = j % lines.len();
                    lines.swap(k, j);
                }
                Mutation::ReplaceWord(i, w) => {
                    let mut words: Vec<String> =
                        lines[k].split_whitespace().map(String::from).collect();
                    if !words.is_empty() {
                        let n = words.len();
                        words[(i / 7) % n] = w.clone();
                    }
                    lines[k] = words.join(" ");
                }
                _ => unreachable!(),
            }
            lines.join("\n")
        }
        Mutation::Truncate(i) => text[..floor(text, *i)].to_string(),
    }
}

fn fixtures() -> &'static [(String, String)] {
    static FIXTURES: std::sync::OnceLock<Vec<(String, String)>> = std::sync::OnceLock::new();
    FIXTURES.get_or_init(load_fixtures)
}

fn load_fixtures() -> Vec<(String, String)> {
    let mut v: Vec<(String, String)> = netlists()
        .into_iter()
        .map(|p| {
            (
                p.display().to_string(),
                std::fs::read_to_string(&p).unwrap(),
            )
        })
        .collect();
    let errs = crate::root().join("netlists/errors");
    for e in std::fs::read_dir(errs).unwrap() {
        let p = e.unwrap().path();
        v.push((
            p.display().to_string(),
            std::fs::read_to_string(&p).unwrap(),
        ));
    }
    v.sort();
    v
}

/// Run every stage that accepts the text; only a panic can fail.
fn run_all(name: &str, text: String) {
    let path = std::path::Path::new(name);
    let result = kausal::pipeline::elaborate_text(name, path, text, &FsLoader);
    if let Ok(el) = result {
        for kvl in [kausal::build::Kvl::Nodes, kausal::build::Kvl::Loops] {
            let built = kausal::build::build(
                &el.circuit,
                kausal::build::Options {
                    kvl,
                    alias: true,
                    ..Default::default()
                },
            );
            assert!(kausal::ir::verify(&built.system).is_empty());
        }
        // The bond graph draws whatever elaborates.
        let a = kausal::bondgraph::analyse(&el.circuit);
        let _ = (
            kausal::bondgraph::text(&a, None),
            kausal::bondgraph::dot(&a),
        );
    } else if let Err(f) = result {
        // Rendering must cope with whatever spans the errors carry.
        for d in &f.diagnostics {
            let _ = kausal::diag::render(&f.sources, d, Default::default());
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 3000, failure_persistence: None, ..ProptestConfig::default() })]
    #[test]
    fn mutated_netlists_never_panic(k in any::<usize>(), muts in prop::collection::vec(mutation(), 1..6)) {
        let fx = fixtures();
        let (name, text) = &fx[k % fx.len()];
        let mut t = text.clone();
        for m in &muts {
            t = apply(&t, m);
        }
        run_all(name, t);
    }

    #[test]
    fn random_bytes_never_panic(s in "\\PC{0,300}") {
        run_all("random.cir", s);
    }
}

/// Expressions too deep for a recursive parser and evaluator are refused
/// with a diagnostic (they would overflow the stack and abort): nesting,
/// operator count, and `.func` chains, which are not called recursive.
#[test]
fn deep_expressions_are_refused() {
    let n = 100_000;
    let wrap = |param: &str| format!("deep\n{param}\nR1 a 0 {{p}}\nV1 a 0 1\n.tran 1u 10u\n.end\n");
    let funcs: String = (1..70)
        .map(|k| format!(".func f{k}(x) {{f{}(x)+1}}\n", k - 1))
        .collect();
    let cases = [
        (
            wrap(&format!(".param p={{{}1{}}}", "(".repeat(n), ")".repeat(n))),
            "K0122",
            "nested parentheses",
        ),
        (
            wrap(&format!(".param p={{{}}}", vec!["1"; n].join("+"))),
            "K0122",
            "operators",
        ),
        (
            wrap(&format!(".param p={{{}1}}", "-".repeat(n))),
            "K0122",
            "operators",
        ),
        (
            wrap(&format!(".func f0(x) {{x}}\n{funcs}.param p={{f69(1)}}")),
            "K0201",
            "nested more than 64 deep",
        ),
    ];
    for (text, code, words) in cases {
        let path = std::path::Path::new("deep.cir");
        let f = match kausal::pipeline::elaborate_text("deep.cir", path, text, &FsLoader) {
            Ok(_) => panic!("{code} expected"),
            Err(f) => f,
        };
        assert!(
            f.errors()
                .any(|d| d.code == code && d.message.contains(words)),
            "{code}: {:?}",
            f.errors().map(|d| &d.message).collect::<Vec<_>>()
        );
    }
}

/// Nesting that reading recurses over is bounded with a diagnostic (10^4
/// levels would overflow the stack): subcircuit definitions (64), includes (64)
/// and instance hierarchies (100). At the bounds, on a test thread's stack,
/// the netlists elaborate.
#[test]
fn deep_nesting_is_refused_at_its_bounds() {
    let dir = tempfile::tempdir().unwrap();
    let elaborate = |text: String| {
        let path = dir.path().join("top.cir");
        kausal::pipeline::elaborate_text("top.cir", &path, text, &FsLoader)
    };
    let tail = "V1 in 0 1\n.tran 1u 10u\n.end\n";
    // Definitions nested inside each other.
    let defs = |n: usize| {
        let mut t = String::from("defs\n");
        for k in 0..n {
            t.push_str(&format!(".subckt s{k} a b\n"));
        }
        t.push_str("R1 a b 1k\n");
        t.push_str(&".ends\n".repeat(n));
        t + "X0 in 0 s0\n" + tail
    };
    // Instances, each of the next subcircuit.
    let chain = |n: usize| {
        let mut t = String::from("chain\n");
        for k in 0..n {
            t.push_str(&format!(".subckt s{k} a b\n"));
            if k + 1 < n {
                t.push_str(&format!("X1 a b s{}\n", k + 1));
            } else {
                t.push_str("R1 a b 1k\n");
            }
            t.push_str(".ends\n");
        }
        t + "X0 in 0 s0\n" + tail
    };
    // Files including each other in a chain (in a directory of its own).
    let includes = |n: usize| {
        let sub = dir.path().join(format!("chain{n}"));
        std::fs::create_dir(&sub).unwrap();
        for k in 1..n {
            std::fs::write(
                sub.join(format!("inc{k}.cir")),
                format!(".include inc{}.cir\n", k + 1),
            )
            .unwrap();
        }
        std::fs::write(sub.join(format!("inc{n}.cir")), "R1 in 0 1k\n").unwrap();
        format!("includes\n.include chain{n}/inc1.cir\n{tail}")
    };
    for (what, ok, deep, code) in [
        ("definitions", defs(63), defs(200), "K0123"),
        ("instances", chain(100), chain(300), "K0219"),
        ("includes", includes(63), includes(200), "K0123"),
    ] {
        if let Err(f) = elaborate(ok) {
            panic!(
                "{what} at the bound: {:?}",
                f.errors().map(|d| &d.message).collect::<Vec<_>>()
            );
        }
        let f = elaborate(deep)
            .err()
            .unwrap_or_else(|| panic!("{what}: {code}"));
        assert!(
            f.errors()
                .any(|d| d.code == code && d.message.contains("deep")),
            "{what}: {:?}",
            f.errors().map(|d| &d.message).collect::<Vec<_>>()
        );
    }
}

/// `.print`/`.probe` items kausal does not write are left out with a
/// located warning each (ngspice skips them too); the vectors it writes are
/// kept, in order.
#[test]
fn unknown_print_items_are_warnings() {
    let path = crate::root().join("netlists/print_lenient.cir");
    let text = std::fs::read_to_string(&path).unwrap();
    let (sources, _) = front::load("print_lenient.cir", &path, text, &FsLoader);
    let (ast, errors) = front::parse(&sources);
    let warned: Vec<String> = errors
        .iter()
        .map(|e| {
            assert_eq!(e.severity(), kausal::diag::Severity::Warning, "{e}");
            sources.text(e.span()).to_string()
        })
        .collect();
    assert_eq!(warned, ["vdb(2)", "@r1[i]", "par('v(1)*2')"]);
    let printed = print::netlist(&ast);
    assert!(printed.contains(".print tran v(1) v(2) i(v1)"), "{printed}");
}

/// Every device is scaled to TEMP (ngspice's `*temp.c`), so a temperature
/// away from TNOM warns of nothing, and the BJT's temperature parameters
/// are read, not ignored (K0291); a temperature law ngspice does not have
/// is refused.
#[test]
fn temperatures_scale_every_device_silently() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.cir");
    let codes_of = |opts: &str, device: &str| -> Vec<String> {
        let text = format!("t\n{opts}\nV1 a 0 1\n{device}\n.tran 1u 10u\n.end\n");
        match kausal::pipeline::elaborate_text("t.cir", &path, text, &FsLoader) {
            Ok(el) => el.warnings.iter().map(|d| d.code.to_string()).collect(),
            Err(e) => e.errors().map(|d| d.code.to_string()).collect(),
        }
    };
    for device in [
        "M1 a a 0 0 NX\n.model NX NMOS",
        "D1 a 0 DX\n.model DX D",
        "J1 a a 0 JX\n.model JX NJF",
        "Q1 a a 0 QX\n.model QX NPN",
        "Q1 a a 0 QX\n.model QX NPN(TNOM=50 XTB=1.5 EG=1.2 XTI=2 TLEV=1 TLEVC=1 CTE=1e-3 TRB1=1e-3)",
    ] {
        for opts in [
            ".options temp=60",
            ".options tnom=25 temp=50",
            ".options temp=27",
        ] {
            let found = codes_of(opts, device);
            assert!(found.is_empty(), "{opts} {device}: {found:?}");
        }
    }
    let refused = codes_of(".options temp=60", "Q1 a a 0 QX\n.model QX NPN(TLEV=2)");
    assert!(refused.iter().any(|c| c == "K0223"), "{refused:?}");
}

/// Two ways published model cards break lines that ngspice reads on from
/// (eSim's libraries): a `+` left mid-line between parameters, and the
/// closing `)` alone on the next line. Both give the model every parameter.
#[test]
fn stray_plus_and_a_lone_closing_paren_in_a_model_are_read_as_ngspice_reads_them() {
    let text = "t\nV1 1 0 0.7\nD1 1 0 dm\n.model dm D(IS=1e-14    +    N=2\n+ RS=3\n)\n.tran 1u 10u\n.end\n";
    let el = elaborate(text);
    let model = el
        .circuit
        .elements
        .values()
        .find_map(|e| match &e.kind {
            kausal::elab::ElementKind::Diode { model, .. } => Some(model.clone()),
            _ => None,
        })
        .expect("the diode");
    assert_eq!((model.is, model.n, model.rs), (1e-14, 2.0, 3.0));
}

/// A diode's area by name (`area=`, as ngspice reads it; the CircuitSim90
/// decks write it so) is its area, times `m=`; positional, as before.
#[test]
fn a_diode_takes_its_area_by_name_or_position() {
    let text = "t\nV1 1 0 0.7\nD1 1 0 dm area=2.5\nD2 1 0 dm 3 m=2\nD3 1 0 dm area=1.5 m=4\n\
        .model dm D(IS=1e-14)\n.tran 1u 10u\n.end\n";
    let el = elaborate(text);
    assert!(
        el.warnings.is_empty(),
        "{:?}",
        el.warnings.iter().map(|d| &d.message).collect::<Vec<_>>()
    );
    let areas: Vec<f64> = el
        .circuit
        .elements
        .values()
        .filter_map(|e| match &e.kind {
            kausal::elab::ElementKind::Diode { area, .. } => Some(*area),
            _ => None,
        })
        .collect();
    assert_eq!(areas, [2.5, 6.0, 6.0]);
}

/// The transistor lines and model cards of others' netlists: SPICE2's
/// `.model Q1 NPN BF 20` (names and values without `=`), parameters after
/// the closing parenthesis, a model name that starts with a digit, a
/// substrate node told from the model by which word names a model, and
/// `IC=VBE, VCE` read past.
#[test]
fn transistor_lines_and_model_cards_are_read_as_ngspice_reads_them() {
    let text = "t\nV1 1 0 5\nR1 1 2 1k\n\
        Q1 1 2 0 2n_old\nQ2 1 2 0 sub qnew 2 off ic=0.6, 5\nJ1 1 2 0 jmod\n\
        .model 2n_old NPN BF 20 RB 100 TF .1NS CJC 2PF\n\
        .model qnew PNP(BF=20 IS=1e-15)\n+ CJE=1p, VAF=50 CJS=1p)\n.model jmod NJF(VTO=-1)\n\
        .tran 1u 10u\n.end\n";
    let el = elaborate(text);
    let c = &el.circuit;
    let names: Vec<&str> = c.elements.values().map(|e| e.name.as_str()).collect();
    for branch in [
        "Q1:be", "Q1:bc", "Q1:ce", "Q1:rb", "Q2:be", "Q2:cs", "J1:gs", "J1:ds",
    ] {
        assert!(names.contains(&branch), "{branch} in {names:?}");
    }
    // Q2's substrate is node `sub`, its area 2: twice the saturation current
    // of its base-emitter junction; the PNP's branch runs from E' to B'.
    let sub = c.find_node("sub").expect("the substrate node");
    let cs = c.elements.values().find(|e| e.name == "Q2:cs").unwrap();
    assert!(cs.nodes.contains(&sub));
    let be = c.junctions.iter().find(|j| j.name == "Q2.be").unwrap();
    assert_eq!(be.is, 2e-15);
    // SPICE2's card: BF 20 and TF 0.1 ns reached the transit-time charge.
    let q1be = c.elements.values().find(|e| e.name == "Q1:be").unwrap();
    assert!(matches!(
        &q1be.kind,
        kausal::elab::ElementKind::DeviceBranch {
            charge: Some(_),
            ..
        }
    ));
}

/// A level-2 device's intermediates follow its model card: the body
/// factor's short-channel form with XJ and NSUB, weak inversion with NFS,
/// Baum's quartic with VMAX, the mobility factor with UEXP; a plain card
/// has the threshold, Grove–Frohman's vdsat and the current only.
#[test]
fn level_2_mosfets_name_the_intermediates_their_model_needs() {
    let text = "t\nV1 1 0 5\nM1 1 1 0 0 full L=2u W=10u\nM2 1 1 0 0 plain\n\
        .model full nmos level=2 vto=0.7 tox=20n nsub=1e16 xj=0.3u delta=1 nfs=1e11 vmax=5e4 neff=2 ucrit=2e4 uexp=0.2\n\
        .model plain nmos level=2 vto=0.7 kp=5e-5 gamma=0.4 lambda=0.02\n.tran 1u 10u\n.end\n";
    let el = elaborate(text);
    let names: Vec<&str> = el
        .circuit
        .elements
        .values()
        .map(|e| e.name.as_str())
        .collect();
    let of = |dev: &str| -> Vec<&str> {
        names
            .iter()
            .filter_map(|n| n.strip_prefix(dev))
            .collect::<Vec<_>>()
    };
    let full = of("M1:");
    for tag in [
        "sarg", "barg", "vbin", "args", "argd", "gamasd", "xn", "vth", "von", "ufact", "vgsx",
        "gammad", "v1", "vdsgf", "xv", "b1", "d1", "qr", "qs", "qp", "y3", "a3", "b3", "q1",
        "x1lo", "x4hi", "x4", "xs", "vdsat", "dl", "clfact", "vdsx", "bx", "id", "ds", "gs", "gb",
    ] {
        assert!(full.contains(&tag), "M1:{tag} in {full:?}");
    }
    let plain = of("M2:");
    for tag in [
        "sarg", "von", "v1", "vdsgf", "vdsat", "clfact", "vdsx", "bx", "id",
    ] {
        assert!(plain.contains(&tag), "M2:{tag} in {plain:?}");
    }
    for tag in ["barg", "gamasd", "xn", "ufact", "xv", "y3", "vbin", "dl"] {
        assert!(!plain.contains(&tag), "no M2:{tag} in {plain:?}");
    }
    // Each intermediate once.
    let mut sorted = names.clone();
    sorted.sort_unstable();
    sorted.dedup();
    assert_eq!(sorted.len(), names.len(), "{names:?}");
}

#[test]
fn mosfet_lines_read_their_geometry_and_the_model_its_level() {
    // M1: geometry, RSH times NRS (an internal source node), no drain
    // resistance; M2 inside a subcircuit with `m=` on both; a P-channel
    // device's branches point from source to drain.
    let text = "t\nV1 1 0 5\nM1 1 1 0 0 nm L=2u W=10u AD=20p AS=20p PD=14u PS=14u NRS=2 off\n\
        M2 0 1 1 1 pm w=4u l=1u\nX1 1 0 half m=2\n\
        .subckt half a b\nM3 a a b b nm l=1u w=1u m=3\n.ends\n\
        .model nm nmos (level=1 vto=0.7 kp=1e-4 tox=10n cj=1e-4 rsh=50)\n\
        .model pm pmos level=3 vto=-0.7\n.tran 1u 10u\n.end\n";
    let el = elaborate(text);
    let c = &el.circuit;
    let names: Vec<&str> = c.elements.values().map(|e| e.name.as_str()).collect();
    for branch in [
        "M1:ds", "M1:bd", "M1:gs", "M1:gb", "M1:rs", "M2:ds", "X1.M3:ds",
    ] {
        assert!(names.contains(&branch), "{branch} in {names:?}");
    }
    // RSH·NRD with the default NRD = 1 gives a drain resistance too, so the
    // gate (on the drain's node) meets the channel through one.
    let rd = c.elements.values().find(|e| e.name == "M1:rd").unwrap();
    assert!(matches!(rd.kind, kausal::elab::ElementKind::Resistor { r } if r == 50.0));
    assert!(names.contains(&"M1:gd"), "{names:?}");
    let rs = c.elements.values().find(|e| e.name == "M1:rs").unwrap();
    assert!(matches!(rs.kind, kausal::elab::ElementKind::Resistor { r } if r == 100.0));
    // CJ times AD: the bottom junction's capacitance.
    let bd = c.junctions.iter().find(|j| j.name == "M1.bd").unwrap();
    assert!((bd.cjo - 2e-15).abs() < 1e-27, "{}", bd.cjo);
    // The multipliers of the instance and of the device: 2 · 3.
    let bd3 = c.junctions.iter().find(|j| j.name == "X1.M3.bd").unwrap();
    assert!((bd3.is - 6e-14).abs() < 1e-26, "{}", bd3.is);
    // The PMOS runs its channel branch from source (node 1) to drain (0).
    let ds = c.elements.values().find(|e| e.name == "M2:ds").unwrap();
    assert_eq!(ds.nodes[0], c.find_node("1").unwrap());
}

/// A node only device laws read is connected all the same: a MOSFET's gate
/// with no gate capacitances has no branch of its own, and once gave "only
/// one connection" beside the B source that drives it. A node that only a B
/// source's expression reads is still dangling.
#[test]
fn a_gate_without_capacitances_is_a_connection() {
    let el = elaborate(
        "gate\nVdd d 0 5\nVin in 0 1\nBg g 0 V = V(in)\nM1 d g 0 0 nm\n.model nm nmos(level=1 kp=1m)\n.tran 1u 1m\n.end\n",
    );
    let dangling: Vec<&str> = el
        .warnings
        .iter()
        .filter(|d| d.code == kausal::diag::codes::DANGLING_NODE)
        .map(|d| d.message.as_str())
        .collect();
    assert_eq!(dangling, ["node `in` has only one connection"]);
}
