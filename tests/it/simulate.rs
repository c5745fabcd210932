//! Simulation: analytic solutions, the seed examples, and clear errors for
//! bad numerical situations (with no partial output file).

use std::path::Path;

use kausal::io::FsLoader;
use kausal::pipeline::{self, SortOptions, Sorted};
use kausal::sim::{self, DcFailure, Method, SimError};

use crate::root;

fn sort_text(text: &str) -> Sorted {
    let path = Path::new("mem.cir");
    let el = match pipeline::elaborate_text("mem.cir", path, text.to_string(), &FsLoader) {
        Ok(el) => el,
        Err(f) => panic!("{:?}", f.errors().map(|d| &d.message).collect::<Vec<_>>()),
    };
    let built = kausal::build::build(&el.circuit, Default::default());
    pipeline::sort_built(el, built, &SortOptions::default())
        .ok()
        .expect("sorts")
}

fn sort_file(name: &str) -> Sorted {
    let path = root().join("netlists").join(name);
    pipeline::sort(&path, &FsLoader, &SortOptions::default())
        .ok()
        .expect("sorts")
}

fn run(text: &str, probe: &str, method: Option<Method>, rtol: f64) -> (Vec<f64>, Vec<f64>) {
    let s = sort_text(text);
    let opts = sim::Options {
        method,
        rtol: Some(rtol),
        atol: Some(1e-14),
        probes: vec![probe.to_string()],
        ..Default::default()
    };
    let w = sim::simulate(&s, &opts).unwrap_or_else(|e| panic!("{e}"));
    (w.time, w.data[0].clone())
}

/// Max error over the signal's range.
fn norm_err(t: &[f64], y: &[f64], exact: impl Fn(f64) -> f64) -> f64 {
    let ex: Vec<f64> = t.iter().map(|&t| exact(t)).collect();
    let (lo, hi) = ex
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    let err = y
        .iter()
        .zip(&ex)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    err / (hi - lo)
}

#[test]
fn rc_discharge_matches_the_analytic_solution() {
    let text = "rc\nR1 a 0 1k\nC1 a 0 1u ic=1\n.tran 10u 5m uic\n.end\n";
    for m in [Method::Bdf, Method::TrBdf2, Method::Esdirk34, Method::Tsit5] {
        let (t, v) = run(text, "v(a)", Some(m), 1e-10);
        let e = norm_err(&t, &v, |t| (-t / 1e-3).exp());
        assert!(e <= 1e-6, "{m:?}: {e:e}");
    }
}

#[test]
fn rlc_and_lc_match_their_analytic_solutions() {
    // Series RLC from v_C(0) = 1, i(0) = 0: underdamped.
    let (r, l, c) = (10.0f64, 1e-3f64, 1e-6f64);
    let text = format!("rlc\nR1 a b {r}\nL1 b 0 {l}\nC1 a 0 {c} ic=1\n.tran 1u 2m uic\n.end\n");
    let a = r / (2.0 * l);
    let w0 = 1.0 / (l * c).sqrt();
    let wd = (w0 * w0 - a * a).sqrt();
    let (t, v) = run(&text, "v(a)", None, 1e-10);
    let e = norm_err(&t, &v, |t| {
        (-a * t).exp() * ((wd * t).cos() + a / wd * (wd * t).sin())
    });
    assert!(e <= 1e-6, "RLC: {e:e}");
    // Lossless LC: cos(w0 t) over 10 periods.
    let text = "lc\nL1 a 0 1m\nC1 a 0 1u ic=1\n.tran 1u 2m uic\n.end\n";
    let (t, v) = run(text, "v(a)", Some(Method::Esdirk34), 1e-11);
    let e = norm_err(&t, &v, |t| (w0 * t).cos());
    assert!(e <= 1e-6, "LC: {e:e}");
}

#[test]
fn the_seed_examples_simulate() {
    for file in [
        "seed_a_rc_rl",
        "seed_b_cellier12",
        "seed_c_algebraic_loop",
        "seed_d_singular",
    ] {
        let path = root().join(format!("netlists/{file}.cir"));
        let s = pipeline::sort(&path, &FsLoader, &SortOptions::default())
            .ok()
            .unwrap();
        let w =
            sim::simulate(&s, &sim::Options::default()).unwrap_or_else(|e| panic!("{file}: {e}"));
        assert!(w.time.len() > 100, "{file}");
        assert!(w.data.iter().flatten().all(|v| v.is_finite()), "{file}");
    }
}

#[test]
fn seed_d_conserves_its_constraint() {
    // I1 + iC + iL2 + I3 = 0 holds along the run (the constraint is one of
    // the sorted equations after index reduction).
    let path = root().join("netlists/seed_d_singular.cir");
    let s = pipeline::sort(&path, &FsLoader, &SortOptions::default())
        .ok()
        .unwrap();
    let opts = sim::Options {
        probes: ["i(i1)", "i(c1)", "i(l2)", "i(i3)"]
            .map(String::from)
            .to_vec(),
        ..Default::default()
    };
    let w = sim::simulate(&s, &opts).unwrap();
    let mut worst = 0.0f64;
    for k in 0..w.time.len() {
        let terms: Vec<f64> = w.data.iter().map(|c| c[k]).collect();
        let sum: f64 = terms.iter().sum();
        let scale = terms.iter().map(|x| x.abs()).fold(1e-3, f64::max);
        worst = worst.max(sum.abs() / scale);
    }
    assert!(worst <= 1e-9, "constraint drift {worst:e}");
}

#[test]
fn an_exploding_circuit_ends_with_a_clear_error() {
    // A negative resistor across a capacitor: v grows as exp(t / 1 us).
    let s = sort_text("unstable\nR1 a 0 -1\nC1 a 0 1u ic=1\n.tran 1u 1 uic\n.end\n");
    let e = sim::simulate(&s, &sim::Options::default()).unwrap_err();
    match &e {
        SimError::NonFinite { t, .. }
        | SimError::StepUnderflow { t, .. }
        | SimError::Solver { t, .. } => {
            assert!(*t > 1e-4 && *t < 1e-2, "{e}")
        }
        other => panic!("{other}"),
    }
    let msg = e.to_string();
    assert!(msg.contains("t = "), "{msg}");
    // Named by its variable, never by an internal index.
    if matches!(
        e,
        SimError::StepUnderflow { .. } | SimError::NonFinite { .. }
    ) {
        assert!(msg.contains("`u_C1`"), "{msg}");
    }
}

#[test]
fn newton_failure_names_the_loop_and_leaves_no_file() {
    // A diode with a negative saturation current cannot carry the forward
    // current the source forces through it: no solution exists.
    let text = "impossible\nI1 0 a 1m\nD1 a 0 dn\n.model dn D(IS=-1e-14)\n.tran 1u 1m\n.end\n";
    let s = sort_text(text);
    let e = sim::simulate(&s, &sim::Options::default()).unwrap_err();
    let msg = e.to_string();
    assert!(msg.contains("D1"), "{msg}");
    // The CLI writes nothing when the run fails.
    let dir = tempfile::tempdir().unwrap();
    let net = dir.path().join("impossible.cir");
    std::fs::write(&net, text).unwrap();
    let out = dir.path().join("out.csv");
    let status = crate::kausal(&["sim", net.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert!(!status.status.success());
    assert!(!out.exists(), "no partial output");
    assert!(String::from_utf8_lossy(&status.stderr).contains("D1"));
}

/// A run interrupted by the user (SIGINT) leaves neither an output nor its
/// temporary file, and exits with 130; the old output stays as it was.
#[cfg(unix)]
#[test]
fn an_interrupted_run_leaves_nothing_behind() {
    let dir = tempfile::tempdir().unwrap();
    let net = dir.path().join("long.cir");
    // Long enough to be interrupted on any machine (seconds of solving).
    std::fs::write(&net, kausal::generate::rc_ladder(50_000)).unwrap();
    let out = dir.path().join("out.csv");
    std::fs::write(&out, "old\n").unwrap();
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_kausal"))
        .args(["sim", net.to_str().unwrap(), "-o", out.to_str().unwrap()])
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let temporaries = || {
        std::fs::read_dir(dir.path())
            .unwrap()
            .filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().starts_with(".tmp"))
            .count()
    };
    let status = crate::interrupt_when(
        &mut child,
        || temporaries() > 0,
        std::time::Duration::from_secs(60),
        "a temporary output",
    );
    assert_eq!(status.code(), Some(130), "{status:?}");
    assert_eq!(temporaries(), 0, "the temporary output was left behind");
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "old\n");
}

#[test]
fn csv_and_raw_output_follow_ngspice_names() {
    let path = root().join("netlists/subckt_rc_filter.cir");
    let s = pipeline::sort(&path, &FsLoader, &SortOptions::default())
        .ok()
        .unwrap();
    // `.print v(in) v(mid) v(out)` prints; ngspice stores every vector.
    let opts = sim::Options {
        probes: vec!["v(in)".into(), "v(mid)".into(), "v(out)".into()],
        ..Default::default()
    };
    let w = sim::simulate(&s, &opts).unwrap();
    let csv = sim::output::csv(&w);
    assert!(
        csv.starts_with("time,v(in),v(mid),v(out)\n"),
        "{}",
        &csv[..60]
    );
    let raw = sim::output::raw_ascii(&w, "t");
    let parsed = kausal::validate::raw::parse(raw.as_bytes()).unwrap();
    assert_eq!(parsed.names, ["v(in)", "v(mid)", "v(out)"]);
    assert_eq!(parsed.time.len(), w.time.len());
    // Every non-ground node and V-source current when nothing is requested.
    let text = "t\nV1 a 0 1\nR1 a b 1k\nX1 b sub\n.subckt sub p\nR2 p n 1k\nVm n 0 0\n.ends\n.tran 1u 10u\n.end\n";
    let s = sort_text(text);
    let w = sim::simulate(&s, &sim::Options::default()).unwrap();
    assert_eq!(w.names, ["v(a)", "v(b)", "v(x1.n)", "i(v1)", "i(v.x1.vm)"]);
}

/// A port named twice in a `.subckt` is the node of its first position, as
/// ngspice binds it (measured: ngspice-39 gives 0.5 V on node 3 below), with
/// warning K0288; the node at the later position exists only where other
/// elements use it, so a deck like Xyce's `bug_784.cir` has no `v(2)`, as
/// ngspice's raw file has none. Fails when the later position wins (node 3
/// at 1 V) or when the unused node is made anyway.
#[test]
fn a_port_named_twice_is_its_first_node() {
    let text = "dup\nV1 1 0 1\nR1 1 3 1\nR2 2 0 5\nX1 3 2 suba\n.subckt suba b b\nr1 b 0 1\n.ends\n.tran 1n 10n\n.end\n";
    let s = sort_text(text);
    assert!(
        s.elaborated.warnings.iter().any(|d| d.code == "K0288"),
        "warned"
    );
    let w = sim::simulate(&s, &sim::Options::default()).unwrap();
    let k = w.names.iter().position(|n| n == "v(3)").unwrap();
    assert!(
        (w.data[k][0] - 0.5).abs() < 1e-12,
        "v(3) = {}",
        w.data[k][0]
    );
    let text =
        "dup\nR1 1 0 1\nX1 1 2 suba\n.tran 1n 10n\n.subckt suba b b\nr1 b 0 1\n.ends\n.end\n";
    let w = sim::simulate(&sort_text(text), &sim::Options::default()).unwrap();
    assert_eq!(w.names, ["v(1)"]);
}

/// An instance's node bound to a port its subcircuit never uses (an IC's
/// unconnected pin, written `?` by eSim) is not in the circuit, as ngspice
/// makes a node only where an element names it: the netlist runs, and the
/// node is among neither the nodes nor the default vectors. Fails when the
/// node is kept (it is floating, K0311).
#[test]
fn a_node_only_an_unused_port_names_is_left_out() {
    let text = "pins\nV1 a 0 1\nX1 a b ? amp\nRL b 0 1k\n.subckt amp in out nc\nR1 in out 1k\n.ends\n.tran 1n 10n\n.end\n";
    let s = sort_text(text);
    assert!(s.elaborated.circuit.find_node("?").is_none());
    let w = sim::simulate(&s, &sim::Options::default()).unwrap();
    assert_eq!(w.names, ["v(a)", "v(b)", "i(v1)"]);
    let k = w.names.iter().position(|n| n == "v(b)").unwrap();
    assert!(
        (w.data[k][0] - 0.5).abs() < 1e-12,
        "v(b) = {}",
        w.data[k][0]
    );
}

/// A DC start of a circuit large enough for the sparse integrator (more than
/// `sim::DENSE_STATES` states) solves the operating point with the sparse LU:
/// a resistive divider along an RC ladder; with `.ic` holding the first node,
/// the divider starts there.
#[test]
fn a_large_circuit_starts_from_its_dc_operating_point() {
    // Beyond the dense solve's reach too (it stopped at 4000 states).
    let n = 4100;
    let mut text = String::from("ladder from DC\nV1 n0 0 PULSE(1 0 1m 1u 1u 1 2)\n");
    for k in 1..=n {
        text.push_str(&format!("R{k} n{} n{k} 1k\nC{k} n{k} 0 1n\n", k - 1));
    }
    text.push_str(&format!("Rl n{n} 0 1Meg\n"));
    let with_ic = format!("{text}.ic v(n1)=0.5\n.tran 10u 20u\n.end\n");
    let current = 0.5 / ((n - 1) as f64 * 1e3 + 1e6);
    for (node, k) in [("n1", 1.0), (&*format!("n{n}"), n as f64)] {
        let (_, y) = run(&with_ic, &format!("v({node})"), None, 1e-7);
        let exact = 0.5 - (k - 1.0) * 1e3 * current;
        assert!(
            (y[0] - exact).abs() <= 1e-9,
            "with .ic: v({node}) = {} at t = 0, expected {exact}",
            y[0]
        );
    }
    text.push_str(".tran 10u 20u\n.end\n");
    // Every section drops 1k * I, I = 1 V / (n * 1k + 1M).
    let current = 1.0 / (n as f64 * 1e3 + 1e6);
    for (node, k) in [("n1", 1.0), (&*format!("n{n}"), n as f64)] {
        let (_, y) = run(&text, &format!("v({node})"), None, 1e-7);
        let exact = 1.0 - k * 1e3 * current;
        assert!(
            (y[0] - exact).abs() <= 1e-9,
            "v({node}) = {} at t = 0, expected {exact}",
            y[0]
        );
    }
}

/// The CSV is streamed while the run goes: a run that fails half-way leaves
/// the old file as it was and no temporary file beside it; a run that
/// succeeds writes what the in-memory path (taken with `--raw`) writes.
#[test]
fn streamed_csv_is_whole_or_absent() {
    let dir = tempfile::tempdir().unwrap();
    let run = crate::kausal;
    // A negative resistor: rows stream until v explodes near t = 1 ms.
    let net = dir.path().join("unstable.cir");
    std::fs::write(
        &net,
        "unstable\nR1 a 0 -1\nC1 a 0 1u ic=1\n.tran 1u 1 uic\n.end\n",
    )
    .unwrap();
    let out = dir.path().join("out.csv");
    std::fs::write(&out, "old\n").unwrap();
    let r = run(&["sim", net.to_str().unwrap(), "-o", out.to_str().unwrap()]);
    assert!(!r.status.success());
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "old\n");
    let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
    assert_eq!(left.len(), 2, "only the netlist and the old file: {left:?}");
    // Streamed to a file, to standard output, and kept (with --raw): equal.
    let bridge = root().join("netlists/diode_bridge.cir");
    let b = bridge.to_str().unwrap();
    let f1 = dir.path().join("a.csv");
    let f2 = dir.path().join("b.csv");
    let raw = dir.path().join("b.raw");
    assert!(
        run(&["sim", b, "--all-steps", "-o", f1.to_str().unwrap()])
            .status
            .success()
    );
    let piped = run(&["sim", b, "--all-steps"]);
    assert!(piped.status.success());
    let kept = run(&[
        "sim",
        b,
        "--all-steps",
        "-o",
        f2.to_str().unwrap(),
        "--raw",
        raw.to_str().unwrap(),
    ]);
    assert!(kept.status.success());
    let a = std::fs::read(&f1).unwrap();
    assert!(a.len() > 100_000);
    assert_eq!(a, piped.stdout);
    assert_eq!(a, std::fs::read(&f2).unwrap());
}

/// Where the DC image with algebraic charges is singular (a NAND's stack
/// node that only capacitances hold), the image with charge states is the
/// next stage, before continuation and stepping on the states, which found
/// the same point after more work (Xyce's gm1 spent 2.3 s failing in them
/// before the image took 5 ms). The waveform is validated against ngspice
/// with the rest of the suite.
#[test]
fn a_singular_dc_image_hands_over_to_the_image_with_charge_states() {
    use kausal::sim::DcStage;
    let s = sort_file("mos3_nand_floating_stack.cir");
    let w = sim::simulate(&s, &sim::Options::default()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(
        w.stats.dc_stages,
        [
            DcStage::Newton,
            DcStage::AlgebraicImage,
            DcStage::ChargeImage
        ]
    );
    assert_eq!(w.stats.dc_found, Some(DcStage::ChargeImage));
    // A circuit Newton solves alone says so.
    let s = sort_file("diode_bridge.cir");
    let w = sim::simulate(&s, &sim::Options::default()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(w.stats.dc_stages, [DcStage::Newton]);
    assert_eq!(w.stats.dc_found, Some(DcStage::Newton));
}

/// `-o FILE.raw` is ngspice's binary raw file, streamed: every value is
/// the CSV's to the bit, the streamed file is the kept one (`--raw`) byte
/// for byte, a failed run leaves no file, and a destination that cannot be
/// rewound for the point count is an error before the run, not a wrong file.
#[test]
fn a_raw_output_file_holds_the_csv_values_in_binary() {
    let dir = tempfile::tempdir().unwrap();
    let run = crate::kausal;
    let bridge = root().join("netlists/diode_bridge.cir");
    let b = bridge.to_str().unwrap();
    let csv = dir.path().join("a.csv");
    let streamed = dir.path().join("a.raw");
    let kept = dir.path().join("b.raw");
    let ascii = dir.path().join("c.raw");
    for args in [
        vec!["-o", csv.to_str().unwrap()],
        vec!["-o", streamed.to_str().unwrap()],
        vec![
            "-o",
            kept.to_str().unwrap(),
            "--raw",
            ascii.to_str().unwrap(),
        ],
    ] {
        let r = run(&[&["sim", b, "--all-steps"][..], &args].concat());
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    }
    let bytes = std::fs::read(&streamed).unwrap();
    assert!(
        bytes == std::fs::read(&kept).unwrap(),
        "streamed and kept differ"
    );
    let raw = kausal::validate::raw::parse(&bytes).unwrap();
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(
        header[1..],
        raw.names.iter().map(|n| n.as_str()).collect::<Vec<_>>()[..]
    );
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|x| x.parse().unwrap()).collect())
        .collect();
    assert!(rows.len() > 1000, "{} rows", rows.len());
    assert_eq!(rows.len(), raw.time.len());
    for (k, row) in rows.iter().enumerate() {
        assert_eq!(row[0].to_bits(), raw.time[k].to_bits(), "time at row {k}");
        for (j, col) in raw.data.iter().enumerate() {
            assert_eq!(row[j + 1], col[k], "{} at row {k}", raw.names[j]);
        }
    }
    // Not half-written: a run that fails leaves nothing at the path.
    let net = dir.path().join("unstable.cir");
    std::fs::write(
        &net,
        "unstable\nR1 a 0 -1\nC1 a 0 1u ic=1\n.tran 1u 1 uic\n.end\n",
    )
    .unwrap();
    let failed = dir.path().join("failed.raw");
    let r = run(&["sim", net.to_str().unwrap(), "-o", failed.to_str().unwrap()]);
    assert!(!r.status.success());
    assert!(!failed.exists());
    // A device cannot take the count at the end.
    #[cfg(unix)]
    {
        let dev = dir.path().join("dev.raw");
        std::os::unix::fs::symlink("/dev/null", &dev).unwrap();
        let r = run(&["sim", b, "-o", dev.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(1), "{err}");
        assert!(err.contains("pipe or a device"), "{err}");
    }
}

/// Without `uic`, every `.ic` node is held in the operating point, as
/// ngspice holds it, and released at t = 0: one with no capacitor (which
/// then jumps), one between two resistors; a capacitor's `ic=` is not used.
/// The values are ngspice 39's (`netlists/ic_free_node.cir` is in the
/// validate suite).
#[test]
fn every_ic_node_is_held_in_the_operating_point() {
    let text = std::fs::read_to_string(root().join("netlists/ic_free_node.cir")).unwrap();
    let s = sort_text(&text);
    let opts = sim::Options {
        times: Some(vec![0.0, 1e-12]),
        probes: ["v(a)", "v(b)", "v(c)", "v(k)", "i(l1)"]
            .map(String::from)
            .to_vec(),
        ..Default::default()
    };
    let w = sim::simulate(&s, &opts).unwrap();
    assert!(w.warnings.is_empty(), "{:?}", w.warnings);
    let at = |k: usize| -> Vec<f64> { w.data.iter().map(|d| d[k]).collect() };
    // The operating point (ngspice's): the nodes held; C1 at v(b), not its
    // ic=3; L1 carries the held v(a) through 2k.
    let vb = 1.873001;
    let op = [2.0, vb, 0.0, 0.4, 1e-3];
    // Released: C1, C2 and L1 keep their values, the resistive nodes move
    // (KCL at a with v(c) = v(a) - 2 and L1's 1 mA).
    let va = (2.0 + vb) / 4.0;
    let released = [va, vb, va - 2.0, 0.5, 1e-3];
    for (k, expected) in [op, released].iter().enumerate() {
        for ((got, want), name) in at(k).iter().zip(expected).zip(&w.names) {
            assert!(
                (got - want).abs() <= 1e-6 * want.abs().max(1e-3),
                "{name} at t = {}: {got}, expected {want}",
                w.time[k]
            );
        }
    }
}

/// The `.ic` operating point is solved on an image of the circuit, which
/// keeps the transistors' junction functions (their bulk and base
/// junctions): a latch of two CMOS inverters (MOS level 2) and a BJT stage
/// held by `.ic` start where they are held (this panicked on a junction the
/// image had lost).
#[test]
fn an_ic_holds_transistor_circuits() {
    let latch = "latch\n.model n nmos level=2 vto=0.7 kp=1e-4 cj=3e-4 cjsw=1e-10\n\
        .model p pmos level=2 vto=-0.7 kp=5e-5 cj=3e-4 cjsw=1e-10\nvdd 1 0 3\n\
        mp1 3 2 1 1 p l=1u w=5u ad=5p pd=6u as=5p ps=6u\nmn1 3 2 0 0 n l=1u w=5u ad=5p pd=6u as=5p ps=6u\n\
        mp2 2 3 1 1 p l=1u w=5u ad=5p pd=6u as=5p ps=6u\nmn2 2 3 0 0 n l=1u w=5u ad=5p pd=6u as=5p ps=6u\n\
        .ic v(2)=2 v(3)=0\n.tran 0.1n 10n\n.end\n";
    let bjt = "stage\n.model q npn is=1e-15 bf=100 cje=1p cjc=1p\nvcc 1 0 5\nrc 1 c 1k\nrb b 0 10k\n\
        q1 c b 0 q\ncb b 0 1n\n.ic v(b)=0.7\n.tran 1n 100n\n.end\n";
    for (text, node, held) in [(latch, "v(2)", 2.0), (bjt, "v(b)", 0.7)] {
        let s = sort_text(text);
        let opts = sim::Options {
            times: Some(vec![0.0]),
            probes: vec![node.to_string()],
            ..Default::default()
        };
        let w = sim::simulate(&s, &opts).unwrap_or_else(|e| panic!("{e}"));
        assert!(
            (w.data[0][0] - held).abs() < 1e-6,
            "{node}: {}",
            w.data[0][0]
        );
    }
}

/// An `.ic` that cannot be held (a voltage source fixes its node) is
/// reported, naming the node, which keeps the source's value; the other
/// `.ic` is held; with `uic` nothing is reported.
#[test]
fn an_ic_that_cannot_be_held_is_reported() {
    let text = "ic on a driven node\nV1 a 0 1\nR1 a b 1k\nC1 b 0 1u\n.ic v(a)=0.2 v(b)=0.1\n.tran 10u 1m\n.end\n";
    let w = sim::simulate(&sort_text(text), &sim::Options::default()).unwrap();
    assert_eq!(w.warnings.len(), 1, "{:?}", w.warnings);
    let d = &w.warnings[0];
    assert_eq!(d.code, "K0408");
    assert!(
        d.message.contains("`.ic v(a)`") && !d.message.contains("v(b)"),
        "{}",
        d.message
    );
    let at0 = |name: &str| w.data[w.names.iter().position(|n| n == name).unwrap()][0];
    assert_eq!((at0("v(a)"), at0("v(b)")), (1.0, 0.1));
    let uic = text.replace(".tran 10u 1m", ".tran 10u 1m uic");
    let w = sim::simulate(&sort_text(&uic), &sim::Options::default()).unwrap();
    assert!(w.warnings.is_empty(), "{:?}", w.warnings);
}

/// A `.tran` TMAX far below the run (here 1e-308 s, 10^305 steps) is
/// raised to the run's length over 10^7 (warning K0298), so the run ends;
/// no stop per TMAX is precomputed either.
#[test]
fn a_tiny_tmax_runs() {
    let text = "tmax\nV1 a 0 SIN(0 1 1k)\nR1 a b 1k\nC1 b 0 1u\n.tran 10u 2m 0 1e-308\n.end\n";
    let (t, y) = run(text, "v(b)", None, 1e-7);
    assert_eq!(t.len(), 201);
    assert!(y.iter().all(|v| v.abs() < 1.0), "{y:?}");
}

/// Tolerances out of range are errors, not a run that never ends (a NaN
/// rtol stalls the step control) or one without error control.
#[test]
fn tolerances_out_of_range_are_rejected() {
    let text = "tol\nV1 a 0 SIN(0 1 1k)\nR1 a b 1k\nC1 b 0 1u\n.tran 10u 2m\n.end\n";
    let s = sort_text(text);
    for (rtol, atol) in [
        (Some(f64::NAN), None),
        (Some(0.0), None),
        (Some(2.0), None),
        (None, Some(0.0)),
        (None, Some(f64::INFINITY)),
    ] {
        let opts = sim::Options {
            rtol,
            atol,
            ..Default::default()
        };
        let e = sim::simulate(&s, &opts).unwrap_err();
        assert!(matches!(e, SimError::BadTolerance { .. }), "{e}");
    }
    let cli = crate::kausal;
    let net = root().join("netlists/rc_lowpass_step.cir");
    let net = net.to_str().unwrap();
    for (bad, flag) in [
        ("--rtol=nan", "--rtol"),
        ("--rtol=1", "--rtol"),
        ("--atol=-1e-9", "--atol"),
    ] {
        let out = cli(&["sim", net, bad]);
        assert!(!out.status.success(), "{bad}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(flag) && err.contains("invalid value"), "{err}");
    }
}

/// A 3·10^4-resistor series chain is one algebraic loop of 9·10^4
/// equations: it sorts (also with alias elimination, whose alias chain is as
/// long, and in the loop formulation, whose node potentials are sums as
/// deep) and runs in time linear in its size, on a test thread's stack: a
/// recursive strongly-connected-components search or alias lookup would
/// overflow the stack, and two quadratic scans would take 27 s at 10^5.
#[test]
fn a_long_series_chain_sorts_and_runs() {
    let n = 30_000;
    let mut text = String::from("series chain\nV1 n0 0 1\n");
    for k in 1..=n {
        text.push_str(&format!("R{k} n{} n{k} 1\n", k - 1));
    }
    text.push_str(&format!("C1 n{n} 0 1u ic=0\n.tran 1m 10m uic\n.end\n"));
    for (alias, kvl) in [
        (false, kausal::build::Kvl::Nodes),
        (true, kausal::build::Kvl::Nodes),
        // Node potentials as tree-path sums 3·10^4 deep (and substituted).
        (false, kausal::build::Kvl::Loops),
        (true, kausal::build::Kvl::Loops),
    ] {
        let el =
            pipeline::elaborate_text("chain.cir", Path::new("chain.cir"), text.clone(), &FsLoader)
                .ok()
                .unwrap();
        let built = kausal::build::build(
            &el.circuit,
            kausal::build::Options {
                alias,
                kvl,
                ..Default::default()
            },
        );
        let s = pipeline::sort_built(el, built, &SortOptions::default())
            .ok()
            .expect("sorts");
        let opts = sim::Options {
            probes: vec![format!("v(n{n})")],
            ..Default::default()
        };
        let w = sim::simulate(&s, &opts).unwrap();
        // One RC: tau = n * 1 ohm * 1 uF = 30 ms.
        let tau = n as f64 * 1e-6;
        for (t, v) in w.time.iter().zip(&w.data[0]) {
            let exact = 1.0 - (-t / tau).exp();
            assert!(
                (v - exact).abs() < 1e-6,
                "alias {alias}, {kvl:?}: v({t}) = {v}, want {exact}"
            );
        }
    }
}

/// Two capacitors in parallel between internal nodes: a loop that touches
/// neither ground nor a source. On node potentials the two branch
/// equations can take the two potentials; in the loop formulation C2's KVL
/// is a difference of two paths to ground whose common part cancels only in
/// value. Either way, unless the loop is found, index reduction never starts
/// and the loop's block is singular at t = 0 (K0402). Every formulation
/// reduces it to one state and gives the same waveform.
#[test]
fn a_capacitor_loop_between_internal_nodes_is_reduced_in_every_formulation() {
    let path = root().join("netlists/parallel_caps_floating.cir");
    let mut first: Option<Vec<f64>> = None;
    for (alias, kvl) in [
        (false, kausal::build::Kvl::Nodes),
        (true, kausal::build::Kvl::Nodes),
        (false, kausal::build::Kvl::Loops),
        (true, kausal::build::Kvl::Loops),
    ] {
        let (el, built) = pipeline::equations(
            &path,
            &FsLoader,
            kausal::build::Options {
                alias,
                kvl,
                ..Default::default()
            },
        )
        .ok()
        .unwrap();
        let s = pipeline::sort_built(el, built, &SortOptions::default())
            .ok()
            .expect("sorts");
        assert!(s.reduction.is_some(), "alias {alias}, {kvl:?}: not reduced");
        assert_eq!(s.system().states().count(), 1, "alias {alias}, {kvl:?}");
        let opts = sim::Options {
            probes: vec!["v(a)".into(), "v(b)".into()],
            ..Default::default()
        };
        let w = sim::simulate(&s, &opts).unwrap_or_else(|e| panic!("{alias} {kvl:?}: {e}"));
        let v: Vec<f64> = w.data.concat();
        match &first {
            None => first = Some(v),
            Some(f) => {
                let worst = f
                    .iter()
                    .zip(&v)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max);
                assert!(worst < 1e-6, "alias {alias}, {kvl:?}: {worst:e} off");
            }
        }
    }
}

/// A loop that is singular in the transient but not in the `.ic` operating
/// point (there the inductor into it is a short to a held node): f is NaN at
/// t = 0, and a first step sized from it is NaN, which never fails a
/// step-size test, so the run would never end. It must stop at once with
/// the loop named; the test kills it after 20 s.
#[test]
fn a_loop_singular_from_the_start_is_an_error_not_a_hang() {
    let dir = tempfile::tempdir().unwrap();
    let net = dir.path().join("sing.cir");
    std::fs::write(
        &net,
        "singular after the hold\nV1 in 0 1\nR1 in a 1k\nR2 a 0 1k\nL1 a f 1m\n\
         R6 f 0 1k\nGz f 0 f 0 -1m\nC1 a 0 1n\n.ic v(a)=0.5\n.tran 1n 10n\n.end\n",
    )
    .unwrap();
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_kausal"))
        .args([
            "sim",
            net.to_str().unwrap(),
            "-o",
            dir.path().join("o.csv").to_str().unwrap(),
        ])
        .stderr(std::process::Stdio::piped())
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let start = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > std::time::Duration::from_secs(20) {
            child.kill().unwrap();
            panic!("the run did not end");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("singular Jacobian in algebraic loop") && err.contains("Gz"),
        "{err}"
    );
    assert!(!dir.path().join("o.csv").exists());
}

/// A resistive ladder tears into one variable every few sections (each
/// guess carried too far would amplify its error ~2.6× a section): 100 of
/// them, past the dense limit, so its constant Jacobian is gathered by
/// coloured tangent runs and factored sparse. The node voltages must be the
/// ladder's own (a tridiagonal solve here), and the columns of each colour
/// must not have been mixed up: a wrong entry moves them by far more than
/// rounding. Half the shunts are VCCSs (`G n 0 n 0`), which give the block
/// terms the resistor laws do not.
#[test]
fn a_resistive_ladder_with_many_tears_is_solved_sparse() {
    let n = 150;
    let mut text = String::from("ladder\nV1 n0 0 1\n");
    for k in 1..=n {
        text.push_str(&format!("R{k} n{} n{k} 1k\n", k - 1));
        if k % 2 == 0 {
            text.push_str(&format!("G{k} n{k} 0 n{k} 0 1u\n"));
        } else {
            text.push_str(&format!("Rs{k} n{k} 0 1Meg\n"));
        }
    }
    text.push_str(&format!("C1 n{n} 0 1n\n.tran 1u 10u\n.end\n"));
    let s = sort_text(&text);
    let tears = s
        .schedule
        .blocks()
        .map(|b| b.tears.len())
        .max()
        .unwrap_or(0);
    assert!(tears > 48, "{tears} tears: the dense path would be taken");
    // A linear loop that large is solved whole, and the listing says so.
    assert!(s.schedule.blocks().any(|b| b.solved_whole()));
    let listing = kausal::back::listing::text(s.system(), &s.schedule);
    assert!(listing.contains("(solved whole:"), "{listing}");
    let probes: Vec<usize> = vec![1, 2, 75, 76, n];
    let opts = sim::Options {
        probes: probes.iter().map(|k| format!("v(n{k})")).collect(),
        ..Default::default()
    };
    let w = sim::simulate(&s, &opts).unwrap_or_else(|e| panic!("{e}"));
    // KCL at node k: (v[k-1] - v[k])/R - v[k]/Rs - (v[k] - v[k+1])/R = 0
    // (the capacitor is open at DC, and stays so), by the Thomas algorithm.
    // Shunts of 1 MΩ: the far end still has 1 % of the source.
    let (r, rs) = (1e3, 1e6);
    let (mut c, mut d) = (vec![0.0; n + 1], vec![0.0; n + 1]);
    for k in 1..=n {
        let diag = if k < n {
            2.0 / r + 1.0 / rs
        } else {
            1.0 / r + 1.0 / rs
        };
        let (lower, upper) = (-1.0 / r, if k < n { -1.0 / r } else { 0.0 });
        let rhs = if k == 1 { 1.0 / r } else { 0.0 };
        let m = diag - lower * if k > 1 { c[k - 1] } else { 0.0 };
        c[k] = upper / m;
        d[k] = (rhs - lower * if k > 1 { d[k - 1] } else { 0.0 }) / m;
    }
    let mut v = vec![0.0; n + 2];
    for k in (1..=n).rev() {
        v[k] = d[k] - c[k] * v[k + 1];
    }
    for (j, &k) in probes.iter().enumerate() {
        for (t, got) in w.time.iter().zip(&w.data[j]) {
            assert!(
                (got - v[k]).abs() <= 1e-9 * v[1],
                "v(n{k}) at {t}: {got:e}, want {:e}",
                v[k]
            );
        }
    }
}

/// A node with 3·10^4 elements: its KCL sum is chains of 64 terms added
/// pairwise, not one chain 3·10^4 deep (which would overflow the stack of
/// the recursive passes over expressions at 10^5); the divider's value is exact.
#[test]
fn a_node_with_many_elements_sorts_and_runs() {
    let n = 30_000;
    let mut text = String::from("star\nV1 in 0 1\nR0 in a 1k\n");
    for k in 1..=n {
        text.push_str(&format!("R{k} a 0 30meg\n"));
    }
    text.push_str("C1 a 0 1u\n.tran 1m 2m\n.end\n");
    let (_, y) = run(&text, "v(a)", None, 1e-7);
    let parallel = 30e6 / n as f64;
    let exact = parallel / (1e3 + parallel);
    for v in y {
        assert!((v - exact).abs() < 1e-9, "v(a) = {v}, want {exact}");
    }
}

/// A node that only capacitors reach has no DC operating point: the error
/// names it and the capacitors (it said "a node or loop has no DC path"),
/// also when `.ic` holds another node, and for an island of two nodes.
#[test]
fn a_node_without_dc_path_is_named() {
    let base = "float\nV1 a 0 1\nR1 a b 1k\nC1 b m 1u\nC2 m 0 1u\n";
    let island = "island\nV1 a 0 1\nR1 a b 1k\nC1 b m 1u\nR2 m n 1k\nC2 n 0 1u\n";
    for (text, words) in [
        (
            format!("{base}.tran 10u 1m\n.end\n"),
            vec!["`m` has", "C1, C2 connect it"],
        ),
        (
            format!("{base}.ic v(b)=0.5\n.tran 10u 1m\n.end\n"),
            vec!["`m` has", "C1, C2 connect it"],
        ),
        (
            format!("{island}.tran 10u 1m\n.end\n"),
            vec!["`m`, `n` have", "C1, R2, C2 connect them"],
        ),
    ] {
        let e = sim::simulate(&sort_text(&text), &sim::Options::default()).unwrap_err();
        let msg = e.to_string();
        assert!(matches!(e, SimError::DcFailed { .. }), "{msg}");
        for w in words {
            assert!(msg.contains(w), "`{w}` in: {msg}");
        }
    }
}

/// `.nodeset` picks the operating point: a bistable circuit stays at its
/// unstable zero without it and sits on the upper clamp with it (ngspice
/// 39.3: 5.861519 V; the validate suite compares the waveforms).
#[test]
fn nodeset_picks_the_operating_point() {
    let text = std::fs::read_to_string(root().join("netlists/nodeset_bistable.cir")).unwrap();
    let (_, with) = run(&text, "v(out)", None, 1e-7);
    assert!((with[0] - 5.861519).abs() < 1e-5, "{}", with[0]);
    assert!((with[with.len() - 1] - 5.861519).abs() < 1e-5);
    let without = text.replace(".nodeset v(out)=6", "");
    let (_, free) = run(&without, "v(out)", None, 1e-7);
    assert!(free.iter().all(|v| v.abs() < 1e-9), "{free:?}");
}

/// The `.tran` card's TMAX caps every step of every method (ngspice's
/// meaning of the fourth argument); without it the steps follow the error
/// test and are far longer on this RC.
#[test]
fn tmax_caps_every_step() {
    let card = |tmax: &str| {
        format!(
            "tmax\nV1 in 0 PULSE(0 1 0.1m 1u 1u 0.5m 1m)\nR1 in out 1k\nC1 out 0 100n\n.tran 10u 3m 0 {tmax}\n.end\n"
        )
    };
    let capped = sort_text(&card("1u"));
    let free = sort_text(&card(""));
    for method in [
        Method::Bdf,
        Method::TrBdf2,
        Method::Esdirk34,
        Method::Tsit5,
        Method::Circuit,
        Method::Gear2,
    ] {
        let opts = sim::Options {
            method: Some(method),
            all_steps: true,
            ..Default::default()
        };
        let w = sim::simulate(&capped, &opts).expect("runs");
        let longest = w.time.windows(2).map(|p| p[1] - p[0]).fold(0.0, f64::max);
        assert!(
            longest <= 1e-6 * (1.0 + 1e-6),
            "{method:?}: a step of {longest:e} s with TMAX = 1 µs"
        );
        assert!(w.stats.steps >= 3000, "{method:?}: {} steps", w.stats.steps);
        let w = sim::simulate(&free, &opts).expect("runs");
        assert!(
            w.stats.steps < 3000,
            "{method:?} without TMAX: {} steps",
            w.stats.steps
        );
    }
}

/// A lightly damped network under a slow drive (issue 22, class 1): BDF's
/// orders 3 to 5 are not A-stable near the imaginary axis, so its step was
/// held at the modes' stability limit (1e-10 s over 300 ms: the default run
/// did not finish in 10 minutes). The stall is detected from the held step
/// and order, and ESDIRK34 finishes the run in a few thousand steps.
#[test]
fn a_stalled_bdf_run_goes_on_with_an_l_stable_method() {
    let s = sort_file("coupled_tline.cir");
    let w = sim::simulate(&s, &sim::Options::default()).expect("runs");
    let at = w
        .stats
        .switched_at
        .expect("BDF stalled and ESDIRK34 took over");
    assert!(at > 1e-3 && at < 2e-3, "switched at {at:e}");
    assert!(w.stats.steps < 20_000, "{} steps", w.stats.steps);
    assert!(
        w.warnings
            .iter()
            .any(|d| d.code == kausal::diag::codes::BDF_STALLED),
        "the switch is reported"
    );
    assert_eq!(*w.time.last().unwrap(), 0.3);
}

/// A TMAX-bound run (VACASK's rc: TMAX 1 µs over 1 s) takes about
/// span/TMAX steps with BDF and is no stall: a soft stop every step reset
/// BDF's count of equal steps (2.2e6 steps), and the stall test read the
/// TMAX pace as a held step (ESDIRK34 took over).
#[test]
fn a_tmax_bound_run_takes_span_over_tmax_steps_with_bdf() {
    let path = root().join("netlists/bench/vacask_rc.cir");
    let s = pipeline::sort(&path, &FsLoader, &SortOptions::default())
        .unwrap_or_else(|_| panic!("vacask_rc sorts"));
    let opts = sim::Options {
        probes: vec!["v(2)".into()],
        ..Default::default()
    };
    let w = sim::simulate(&s, &opts).expect("runs");
    assert_eq!(w.stats.switched_at, None, "no stall under TMAX");
    assert!(
        w.stats.steps > 1_000_000 && w.stats.steps < 1_100_000,
        "{} steps for 1e6 TMAX intervals",
        w.stats.steps
    );
}

/// Under TMAX, BDF's step grows onto TMAX and no further: grown past it and
/// cut back to the stop time, the step ran on a Newton matrix factored for
/// the longer step. A linear network then factored its matrix every other
/// step (10,223 factorizations in 20,058 steps), and VACASK's graetz bridge,
/// whose junction charges sit behind 42 mΩ (h·λ about 10^6), failed Newton
/// on one step in ten (2,326 in 23,143 over 20 ms; 947 in 21,787 now).
#[test]
fn a_tmax_bound_step_keeps_its_newton_matrix() {
    let stats = |text: &str| {
        let s = sort_text(text);
        sim::simulate(&s, &sim::Options::default())
            .expect("runs")
            .stats
    };
    let st = stats(
        "stiff linear network under TMAX\nvs in 0 sin 0 20 50\nr1 in a 0.042\n\
         c1 a 0 26p\nr2 a b 1k\nc2 b 0 100u\n.tran 1u 20m 0 1u\n.end\n",
    );
    let (lu, steps) = (st.lu_factorizations, st.steps);
    assert!(lu * 5 < steps, "{lu} factorizations in {steps} steps");
    let path = root().join("netlists/bench/vacask_graetz.cir");
    let text = std::fs::read_to_string(path).expect("graetz is in the repository");
    let st = stats(&text.replace(".tran 1u 1 0 1u", ".tran 1u 20m 0 1u"));
    let (fails, steps) = (st.newton_fails, st.steps);
    assert!(
        fails * 15 < steps,
        "{fails} Newton failures in {steps} steps"
    );
}

/// A junction charge's tolerance is the voltage tolerance on its own
/// capacitance: against 1 pF alone it was below the rounding `f` carries
/// (ulps of 7 V node voltages over the junctions' series resistances), so
/// at a constant bias the integrator's Newton corrected noise and cut the
/// step: 70,702 steps, 39,746 Newton failures over 10 µs (30 steps now).
#[test]
fn a_circuit_at_rest_takes_few_steps() {
    let s = sort_file("bjt_ttl_idle.cir");
    let w = sim::simulate(&s, &sim::Options::default()).expect("runs");
    assert!(w.stats.steps < 200, "{} steps", w.stats.steps);
}

/// A run whose pace can never reach TSTOP (a 1 GHz sine over a second)
/// ends after one pace window with a diagnostic that says where it got to,
/// instead of running for ever.
#[test]
fn a_run_that_cannot_finish_ends_with_a_diagnostic() {
    let s = sort_text("fast\nV1 a 0 SIN(0 1 1G)\nR1 a b 1k\nC1 b 0 1p\n.tran 1m 1\n.end\n");
    for method in [Method::Bdf, Method::TrBdf2, Method::Circuit, Method::Gear2] {
        let opts = sim::Options {
            method: Some(method),
            ..Default::default()
        };
        match sim::simulate(&s, &opts) {
            Err(e @ SimError::TooManySteps { projected, .. }) => {
                assert!(projected.is_some_and(|p| p > 1e9), "{method:?}: {e}");
            }
            other => panic!("{method:?}: expected TooManySteps, got {other:?}"),
        }
    }
    let opts = sim::Options {
        max_steps: Some(100),
        ..Default::default()
    };
    let s = sort_file("rc_lowpass_step.cir");
    assert!(matches!(
        sim::simulate(&s, &opts),
        Err(SimError::TooManySteps { steps: 101, .. })
    ));
}

/// Switches in a circuit with nothing to integrate change state at their
/// controls' crossings, located between the output points by bisection in
/// time: S1 on a PWL ramp, S2 on a sine, each crossing at its analytic time
/// (it was refused: K0417).
#[test]
fn switches_without_states_change_at_their_crossings() {
    let s = sort_file("switch_stateless.cir");
    let w = sim::simulate(&s, &sim::Options::default()).unwrap_or_else(|e| panic!("{e}"));
    let span = 3e-3;
    let w_sin = 2.0 * std::f64::consts::PI * 1e3;
    let (up, down) = (
        0.6f64.asin() / w_sin,
        (std::f64::consts::PI - 0.4f64.asin()) / w_sin,
    );
    let mut exact = vec![("S1", 0.625e-3, true), ("S1", 1.575e-3, false)];
    for k in 0..3 {
        let base = k as f64 * 1e-3;
        exact.push(("S2", base + up, true));
        exact.push(("S2", base + down, false));
    }
    exact.sort_by(|a, b| a.1.total_cmp(&b.1));
    assert_eq!(w.events.len(), exact.len(), "{:?}", w.events);
    for (e, (name, t, on)) in w.events.iter().zip(&exact) {
        assert_eq!((e.element.as_str(), e.on), (*name, *on), "{e:?}");
        assert!(
            (e.t - t).abs() <= 1e-9 * span,
            "{name} at {:e}, the crossing is at {t:e}",
            e.t
        );
    }
    // Between the events the outputs are the resistive divider's: at 0.7 ms
    // S1 is on (10 ohm under 1 kohm) and S2 off.
    let k = w
        .time
        .iter()
        .position(|&t| (t - 0.7e-3).abs() < 1e-12)
        .unwrap();
    let col = |name: &str| w.names.iter().position(|n| n == name).unwrap();
    let vs = (w_sin * 0.7e-3).sin();
    let va = w.data[col("v(a)")][k];
    assert!((va - vs * 10.0 / 1010.0).abs() < 1e-9, "v(a) = {va}");
}

/// The operating point's work is bounded: where its blocks' Newton solves
/// cost much per evaluation, Newton, continuation, GMIN and source stepping
/// end together with a diagnostic once the limit is spent (a 700-equation
/// block of an op-amp macromodel took 342 s to fail without it). Here a
/// limit far below what 50 inverters need.
#[test]
fn an_operating_point_that_runs_out_of_work_says_so() {
    let s = sort_file("hard/dc_inverter_chain_50.cir");
    let opts = sim::Options {
        dc_work: Some(100_000),
        ..Default::default()
    };
    match sim::simulate(&s, &opts) {
        Err(SimError::DcFailed {
            reason: DcFailure::WorkLimit { work: 100_000, .. },
        }) => {}
        other => panic!("expected the DC work limit, got {other:?}"),
    }
    // The wall-clock limit beside it (an instruction of junction functions
    // costs far more than one of arithmetic): a deadline already past ends
    // the solve the same way (here the operating point `.ic` holds, which
    // has no fallback; the DC image after a failed solve on the states has
    // a quarter of the limit of its own).
    let s = sort_text(
        "held\nV1 a 0 1\nR1 a b 1k\nD1 b 0 dm\nC1 b 0 1n\n.model dm D\n.ic v(b)=0.5\n.tran 1n 10n\n.end\n",
    );
    let opts = sim::Options {
        dc_deadline: Some(std::time::Instant::now()),
        ..Default::default()
    };
    // Its diagnostic points at the `.ic` line (see
    // `a_failed_held_operating_point_points_at_its_ic`).
    match sim::simulate(&s, &opts) {
        Err(SimError::HeldDcFailed { cause, .. })
            if matches!(
                *cause,
                SimError::DcFailed {
                    reason: DcFailure::WorkLimit { .. },
                }
            ) => {}
        other => panic!("expected the DC time limit, got {other:?}"),
    }
}

/// What is stored follows ngspice: `.print` selects nothing (every node
/// voltage and source current is stored, and the printed vectors that are
/// not among them); `.save` selects; `.save … all` and the probe `all`
/// (`kausal sim --save all`) add every default vector.
#[test]
fn save_selects_what_is_stored_and_print_does_not() {
    let card = |cards: &str| {
        format!(
            "t\nV1 a 0 SIN(0 1 1k)\nR1 a b 1k\nC1 b 0 1u\nR2 b c 1k\nC2 c 0 1u\n.tran 10u 1m\n{cards}.end\n"
        )
    };
    let names = |cards: &str, probes: &[&str]| {
        let s = sort_text(&card(cards));
        let opts = sim::Options {
            probes: probes.iter().map(|p| p.to_string()).collect(),
            ..Default::default()
        };
        sim::simulate(&s, &opts).unwrap().names
    };
    let all = ["v(a)", "v(b)", "v(c)", "i(v1)"];
    assert_eq!(names("", &[]), all);
    assert_eq!(names(".print tran v(c)\n", &[]), all);
    assert_eq!(
        names(".print tran v(b,c)\n", &[]),
        ["v(a)", "v(b)", "v(c)", "i(v1)", "v(b,c)"]
    );
    assert_eq!(names(".save v(b)\n.print tran v(c)\n", &[]), ["v(b)"]);
    assert_eq!(
        names(".save i(r1) all\n", &[]),
        ["v(a)", "v(b)", "v(c)", "i(v1)", "i(r1)"]
    );
    assert_eq!(names(".save v(b)\n", &["all"]), all);
    assert_eq!(names(".save v(b)\n", &["v(c)"]), ["v(c)"]);
}

/// Steps that land on breakpoints count against the budget: a PULSE of
/// 70 fs period over 4 ms is 4·10^6 corners (it took 4·10^6 steps under a
/// budget of 2·10^4 before).
#[test]
fn breakpoint_steps_count_against_the_budget() {
    let s =
        sort_text("t\nV1 a 0 PULSE(0 1 0 1u 1u 1u 70f)\nR1 a b 1k\nC1 b 0 1n\n.tran 2u 4m\n.end\n");
    let opts = sim::Options {
        max_steps: Some(20_000),
        ..Default::default()
    };
    match sim::simulate(&s, &opts) {
        Err(SimError::TooManySteps { steps, .. }) => assert!(steps <= 20_001, "{steps}"),
        other => panic!("expected TooManySteps, got {other:?}"),
    }
}

/// Seed 004's fixed-step RK4 on the stiff RC ladder (time constants 1 ns to
/// 1 s): kausal states the longest stable step (set by the 1 ns section),
/// and that bound is the real one: at 0.98 of it the run through the
/// pulse's edge stays bounded and matches BDF, at 1.02 of it the run blows
/// up, with an error that names the bound. Both runs end at 1.02 ms, just
/// past the edge at 1 ms (7.5·10^5 steps).
#[test]
fn rk4_is_stable_just_below_its_stated_bound_and_blows_up_just_above() {
    let s = sort_file("hard/stiff_rc_ladder.cir");
    let times: Vec<f64> = (0..=102).map(|k| k as f64 * 1e-5).collect();
    let opts = |method, step| sim::Options {
        method: Some(method),
        step,
        probes: vec!["v(n1)".into(), "v(n5)".into()],
        times: Some(times.clone()),
        ..Default::default()
    };
    // The bound the run states (a short run before the edge, all at rest).
    let probe = sim::simulate(
        &s,
        &sim::Options {
            times: Some(vec![0.0, 1e-5]),
            ..opts(Method::Rk4, Some(1e-6))
        },
    )
    .expect("at rest");
    let bound = probe.stats.stable_step.expect("the bound is estimated");
    // The 1 ns section (1 kΩ into 1 pF, loaded by the next) sets it:
    // 2.785/|λ| with |λ| a little above 1/(1 ns).
    assert!(bound > 1e-9 && bound < 2.785e-9, "{bound}");
    let stable = sim::simulate(&s, &opts(Method::Rk4, Some(0.98 * bound))).expect("stable");
    let note = stable
        .warnings
        .iter()
        .find(|d| d.code == kausal::diag::codes::FIXED_STEP_BOUND)
        .expect("the bound is stated");
    assert!(note.message.contains("within it"), "{}", note.message);
    let reference = sim::simulate(
        &s,
        &sim::Options {
            method: Some(Method::Bdf),
            ..opts(Method::Bdf, None)
        },
    )
    .expect("bdf");
    for (a, b) in stable.data.iter().zip(&reference.data) {
        let err = a
            .iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        assert!(err < 1e-4, "rk4 below its bound against bdf: {err}");
    }
    match sim::simulate(&s, &opts(Method::Rk4, Some(1.02 * bound))) {
        Err(SimError::BlewUp { t, .. }) => assert!(t > 1e-3 && t < 1.02e-3, "{t}"),
        other => panic!(
            "expected a blow-up just above the bound: {:?}",
            other.map(|w| w.stats)
        ),
    }
    // Fixed-step methods need their step, and only they take one.
    assert!(matches!(
        sim::simulate(&s, &opts(Method::Rk4, None)),
        Err(SimError::FixedStep(_))
    ));
    assert!(matches!(
        sim::simulate(&s, &opts(Method::Bdf, Some(1e-6))),
        Err(SimError::FixedStep(_))
    ));
}

/// `ddt()` in a B source is the exact derivative of its operand: index
/// reduction differentiates the state held equal to it (ngspice's `ddt` is a
/// backward difference over its own steps, first-order accurate, so this
/// is checked against the analytic derivative, not against ngspice).
#[test]
fn ddt_in_a_b_source_is_the_exact_derivative() {
    let text = "ddt\nV1 1 0 SIN(0 1 1k)\nR1 1 0 1k\nB2 2 0 V = 1e-3*ddt(v(1)) + 0.5*v(1)\nR2 2 0 1k\n.tran 10u 2m\n.end\n";
    let (t, y) = run(text, "v(2)", None, 1e-7);
    let w = 2.0 * std::f64::consts::PI * 1e3;
    // After t = 0, where the operating point (DC: derivatives are zero)
    // holds.
    let err = t
        .iter()
        .zip(&y)
        .filter(|(t, _)| **t > 0.0)
        .map(|(&t, &v)| (v - (1e-3 * w * (w * t).cos() + 0.5 * (w * t).sin())).abs())
        .fold(0.0, f64::max);
    assert!(err < 1e-6, "{err}");
}

/// A comparison written in a B source is a state event: it holds its value
/// through a step, and its crossings are located. A 1 kHz sine is above
/// 0.999 V for 14 us of each period, narrower than the steps the RC between
/// the windows allows; every crossing is an event at the analytic time, and
/// the capacitor's voltage is what the windows' charge gives. Evaluated as it
/// falls, the comparison was stepped over in four windows of five (v(x)
/// 14.2 mV at the end, not 71.0 mV).
#[test]
fn b_source_comparisons_are_located_events() {
    let s = sort_file("hard/b_narrow_window.cir");
    let w = sim::simulate(&s, &sim::Options::default()).unwrap_or_else(|e| panic!("{e}"));
    let (f, vt, span) = (1e3, 0.999f64, 5e-3);
    let phase = vt.asin();
    let windows: Vec<(f64, f64)> = (0..5)
        .map(|k| {
            let base = k as f64 / f;
            let w = 2.0 * std::f64::consts::PI * f;
            (base + phase / w, base + (std::f64::consts::PI - phase) / w)
        })
        .collect();
    let exact: Vec<(f64, bool)> = windows
        .iter()
        .flat_map(|&(a, b)| [(a, true), (b, false)])
        .collect();
    assert_eq!(w.events.len(), exact.len(), "{:?}", w.events);
    for (e, (t, on)) in w.events.iter().zip(&exact) {
        assert_eq!(e.on, *on, "{e:?}");
        assert_eq!(e.element, "b1");
        assert!(
            (e.t - t).abs() <= 1e-9 * span,
            "{:?} at {:e}, the crossing is at {t:e}",
            e.condition,
            e.t
        );
    }
    // 1 mA into 1 uF inside the windows, decaying through 1 Mohm (1 s).
    let (i_c, tau) = (1e-3 / 1e-6, 1.0);
    let exact_last: f64 = windows
        .iter()
        .map(|&(a, b)| i_c * tau * ((-(span - b) / tau).exp() - (-(span - a) / tau).exp()))
        .sum();
    let x = w.names.iter().position(|n| n == "v(x)").unwrap();
    let last = *w.data[x].last().unwrap();
    assert!(
        (last - exact_last).abs() <= 1e-4 * exact_last,
        "v(x) = {last}, the windows give {exact_last}"
    );
}

/// A comparator that drives its own input back across its threshold (no
/// hysteresis) slides along it: ngspice takes 7.5e5 steps there. The run
/// stops at once with a diagnostic naming the comparison and its element.
#[test]
fn a_sliding_comparison_ends_with_a_diagnostic() {
    let s = sort_text(
        "sliding mode\nv1 in 0 pulse(0 5 10u 1u 1u 1 2)\nr1 in x 1k\nb1 x 0 i = v(x) > 2.5 ? 4m : 0\nc1 x 0 1n\n.tran 1u 1m\n.end\n",
    );
    match sim::simulate(&s, &sim::Options::default()) {
        Err(e @ sim::SimError::Chatter { .. }) => {
            let text = e.to_string();
            assert!(text.contains("`v(x) > 2.5` in b1"), "{text}");
            let sim::SimError::Chatter { t, .. } = e else {
                unreachable!()
            };
            // v(x) reaches 2.5 V near 11.2 us.
            assert!((t - 1.1234e-5).abs() < 1e-8, "{t:e}");
        }
        other => panic!("expected a chatter diagnostic, got {other:?}"),
    }
}

/// A switch never steps over a threshold crossing: a 1 kHz sine is above
/// the switch's threshold (0.99 V) for 4.5 % of each period, a window the
/// integrator's steps would straddle; each of its ten crossings is an event
/// at the analytic time, to 1e-9 of the span, and each changes the switch's
/// state (the capacitor charges only inside the windows).
#[test]
fn switch_events_land_on_every_threshold_crossing() {
    let s = sort_file("switch_narrow_window.cir");
    let w = sim::simulate(&s, &sim::Options::default()).unwrap_or_else(|e| panic!("{e}"));
    let (f, vt, span) = (1e3, 0.99f64, 5e-3);
    let phase = vt.asin();
    let exact: Vec<(f64, bool)> = (0..5)
        .flat_map(|k| {
            let base = k as f64 / f;
            [
                (base + phase / (2.0 * std::f64::consts::PI * f), true),
                (
                    base + (std::f64::consts::PI - phase) / (2.0 * std::f64::consts::PI * f),
                    false,
                ),
            ]
        })
        .collect();
    assert_eq!(w.events.len(), exact.len(), "{:?}", w.events);
    for (e, (t, on)) in w.events.iter().zip(&exact) {
        assert_eq!(e.on, *on, "{e:?}");
        assert!(
            (e.t - t).abs() <= 1e-9 * span,
            "{} at {:e}, the crossing is at {t:e}",
            e.element,
            e.t
        );
    }
    // Between windows the capacitor only discharges through its 1 MΩ: its
    // voltage after the last window is what five windows of charging give.
    let x = w.names.iter().position(|n| n == "v(x)").unwrap();
    let last = *w.data[x].last().unwrap();
    assert!(last > 4.0 && last < 5.0, "v(x) = {last}");
}

/// Three windings coupled by `k12` and `k13` (`k23 = 0`): one flux fewer
/// than windings is a note (K0330), coefficients no magnetic circuit has a
/// warning naming both K elements (K0331), a regular matrix neither; every
/// one simulates.
#[test]
fn coupling_matrices_are_told_apart_by_their_shape() {
    // k13 = 0: no K13 line (ngspice takes k in (0, 1]).
    let deck = |k12: f64, k13: f64| {
        let k13 = if k13 > 0.0 {
            format!("K13 L1 L3 {k13}\n")
        } else {
            String::new()
        };
        format!(
            "three windings\nV1 a 0 sin(0 1 1k)\nR1 a b 10\nL1 b 0 1m\nL2 c 0 1m\nL3 d 0 1m\n\
             R2 c 0 100\nR3 d 0 100\nK12 L1 L2 {k12}\n{k13}.tran 10u 1m\n.end\n"
        )
    };
    for (k12, k13, want) in [(1.0, 0.0, "K0330"), (1.0, 0.9957, "K0331"), (0.9, 0.1, "")] {
        let s = sort_text(&deck(k12, k13));
        let found: Vec<_> = (s.elaborated.warnings.iter())
            .filter(|d| d.code == "K0330" || d.code == "K0331")
            .collect();
        let codes: Vec<&str> = found.iter().map(|d| d.code.id).collect();
        assert_eq!(codes.join(","), want, "k12 = {k12}, k13 = {k13}");
        if want == "K0331" {
            let m = &found[0].message;
            assert!(m.contains("K12") && m.contains("K13"), "{m}");
        }
        sim::simulate(&s, &sim::Options::default())
            .unwrap_or_else(|e| panic!("k12 = {k12}, k13 = {k13}: {e}"));
    }
}

/// A capacitive divider on a PULSE source: the state's slope is the
/// source's, which steps at each corner. The step that lands on a corner
/// sees the slope before it (left-sided, once the run's end is set there),
/// the run that starts there the slope after it; without that, every step
/// onto a corner failed its error test until it was too short to reach it
/// (measured: 315 rejected steps on this circuit, 75 with it).
#[test]
fn a_step_onto_a_source_corner_sees_the_slope_before_it() {
    let s = sort_text(
        "corner\nV1 in 0 PULSE(0 1 1u 1u 1u 3u 10u)\nC1 in a 1n\nC2 a 0 1n\nR1 a 0 10k\n.tran 0.1u 20u\n.end\n",
    );
    let t = kausal::tape::compile(s.system(), &s.schedule, &[]);
    assert_eq!(t.states.len(), 1);
    let mut regs = t.registers();
    let (y, mut dy) = (vec![0.0], vec![0.0]);
    // The end of the rise (2 µs): 1 V/µs before it, flat after it; the
    // divider passes half of the jump to the state's slope.
    let corner = 2e-6;
    let mut slope = |end: f64, at: f64| {
        t.set_slope_end(end);
        t.rhs(&mut regs, at, &y, &mut dy).unwrap();
        dy[0]
    };
    let right = slope(f64::INFINITY, corner);
    let left = slope(corner, corner);
    assert!(
        ((left - right).abs() - 0.5e6).abs() < 1e-6 * 0.5e6,
        "{left} {right}"
    );
    // Before the run's end nothing changes.
    assert_eq!(slope(corner, 1.5e-6), slope(f64::INFINITY, 1.5e-6));
    t.set_slope_end(f64::INFINITY);
}

/// A CMOS inverter's gate node joins its Meyer and junction capacitances in
/// a loop that index reduction tears. What the loop's residuals read of the
/// states alone (the junctions' currents and charges, the capacitances) is
/// computed once ahead of the block, not in each Newton iteration and
/// Jacobian column: no device function is left in a block's body.
#[test]
fn a_loops_state_only_terms_are_computed_ahead_of_it() {
    let s = sort_text(
        "inverter\nVDD vdd 0 5\nVIN in 0 PULSE(0 5 1n 1n 1n 5n 10n)\nRIN in g 1k\n\
         M1 out g 0 0 N L=5u W=100u\nM2 out g vdd vdd P L=5u W=200u\nC1 out 0 0.1p\n\
         .model N NMOS (LEVEL=1 VTO=1 KP=2e-5 TOX=6e-8 CBD=0.1p CBS=0.1p CGSO=2p CGDO=2p CGBO=4p)\n\
         .model P PMOS (LEVEL=1 VTO=-1 KP=1e-5 TOX=6e-8 CBD=0.1p CBS=0.1p CGSO=2p CGDO=2p CGBO=4p)\n\
         .tran 0.1n 20n\n.end\n",
    );
    let t = kausal::tape::compile(s.system(), &s.schedule, &[]);
    assert!(
        t.blocks.iter().any(|b| b.tears.len() > 1),
        "the gate loop is torn"
    );
    for b in t.blocks.iter().filter(|b| b.charge_inverse.is_none()) {
        assert!(
            !b.body
                .iter()
                .any(|i| matches!(i, kausal::tape::Instr::Device { .. })),
            "block {} evaluates a device in its body",
            b.index
        );
    }
    let run = sim::simulate(&s, &sim::Options::default()).unwrap();
    assert!(run.time.last().is_some_and(|&t| (t - 20e-9).abs() < 1e-15));
}

/// The Jacobian's pattern is computed within a bound on the entries it
/// makes, which names the loop that couples the most states when it is
/// passed: the diode bridge's loop reads all five states, and a bound one
/// below its pattern's size is passed where the default is not. A circuit whose torn loop couples
/// thousands of states (CircuitSim90's `dac.cir`: 6,362, 9 GB before it
/// aborted) ends with K0419 in seconds instead.
#[test]
fn a_dense_jacobian_is_refused_within_its_bound() {
    let s = sort_file("bench/vacask_graetz.cir");
    let t = kausal::tape::compile(s.system(), &s.schedule, &[]);
    let pattern = t.jacobian_pattern().expect("within the default bound");
    let limit = pattern.len() - 1;
    let dense = t
        .jacobian_pattern_within(limit)
        .expect_err("past the bound");
    assert_eq!((dense.states, dense.limit), (5, limit));
    let (_, elements, n) = dense.block.expect("the bridge's loop");
    assert_eq!(n, 5);
    assert!(elements.iter().any(|e| e == "d1"), "{elements:?}");
}

/// The sparse Jacobian is computed compressed, every colour of the column
/// colouring a direction of one tangent pass: each entry of the pattern
/// equals the column-by-column Jacobian's, also when the scratch holds the
/// tangents of a wider pass (only the inputs' tangents are cleared).
#[test]
fn a_compressed_jacobian_equals_its_columns() {
    let s = sort_file("hard/dc_inverter_chain_50.cir");
    let t = kausal::tape::compile(s.system(), &s.schedule, &[]);
    let n = t.states.len();
    let pattern = t.jacobian_pattern().expect("sparse");
    let mut rows = vec![Vec::new(); n];
    for &(i, j) in &pattern {
        rows[i].push(j as u32);
    }
    let (colour, m) = kausal::numeric::colour::colour_columns(n, &rows);
    let m = m as usize;
    assert!(m < n, "{m} colours for {n} columns");
    // Every gate capacitance and junction charge at 0 V.
    let y = vec![0.0; n];
    let (mut regs, mut dregs) = (t.registers(), Vec::new());
    let all: Vec<usize> = (0..n).collect();
    let (mut full, mut f) = (vec![0.0; n * n], vec![0.0; n]);
    t.jacobian_columns(&mut regs, &mut dregs, 0.0, &y, &all, &mut full, &mut f)
        .unwrap();
    let mut packed = vec![0.0; n * m];
    let mut g = vec![0.0; n];
    t.jacobian_compressed(
        &mut regs,
        &mut dregs,
        0.0,
        &y,
        &colour,
        0..m,
        &mut packed,
        &mut g,
    )
    .unwrap();
    // f itself, from the blocks' warm starts: the same up to rounding.
    for (a, b) in f.iter().zip(&g) {
        assert!((a - b).abs() <= 1e-12 * a.abs().max(1e-300), "{a} {b}");
    }
    for &(i, j) in &pattern {
        let (a, b) = (full[i * n + j], packed[i * m + colour[j] as usize]);
        assert!(
            (a - b).abs() <= 1e-9 * a.abs().max(1e-300),
            "∂f{i}/∂y{j}: {a} by columns, {b} compressed"
        );
    }
    // Entries outside the pattern are zero.
    let nonzero = full.iter().filter(|v| **v != 0.0).count();
    assert!(nonzero <= pattern.len(), "{nonzero} > {}", pattern.len());
}

/// PSpice's `AKO:` model is its original's parameters, then its own (a
/// later value wins): `ako_models.cir` simulates exactly as the circuit
/// with the merged card written out, and not as the original model.
#[test]
fn an_ako_model_is_its_original_with_its_own_parameters_after() {
    let text = std::fs::read_to_string(root().join("netlists/ako_models.cir")).unwrap();
    let card = ".model QHI AKO:QBASE NPN(BF=300 IS=2e-15)";
    let base = "IS=1e-15 BF=100 VAF=50 RB=50";
    assert!(text.contains(card) && text.contains(base));
    let merged = text.replace(card, &format!(".model QHI NPN({base} BF=300 IS=2e-15)"));
    let unmodified = text.replace(card, &format!(".model QHI NPN({base})"));
    let wave = |t: &str| {
        let w = sim::simulate(&sort_text(t), &sim::Options::default())
            .unwrap_or_else(|e| panic!("{e}"));
        let c2 = w.names.iter().position(|n| n == "v(c2)").unwrap();
        w.data[c2].clone()
    };
    let ako = wave(&text);
    assert_eq!(ako, wave(&merged));
    // BF 300 and IS 2e-15 draw more collector current: v(c2) sits lower.
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let (lower, plain) = (mean(&ako), mean(&wave(&unmodified)));
    assert!(lower < plain - 0.2, "v(c2): {lower} against {plain}");
}

/// An output vector that names no node or source is left out with a
/// warning, as ngspice leaves it out (Xyce's decks print `v(*)` and
/// `i(X1:L1)`), and the run writes the others.
#[test]
fn outputs_naming_nothing_are_left_out() {
    let s = sort_text(
        "left out\nV1 a 0 1\nR1 a b 1k\nC1 b 0 1u\n.save v(b) v(elsewhere) i(r9)\n.tran 1u 1m\n.end\n",
    );
    let codes: Vec<&str> = s.elaborated.warnings.iter().map(|d| d.code.id).collect();
    assert!(
        codes.contains(&"K0214") && codes.contains(&"K0215"),
        "{codes:?}"
    );
    let w = sim::simulate(&s, &sim::Options::default()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(w.names, ["v(b)"]);
}

/// PSpice's expression syntax, as ngspice's PSpice mode reads it (TI's
/// TLC555 library writes all of it): a `{…}` expression continued over `+`
/// lines with a comment line between, `&` and `|` for `&&` and `||`, `~`
/// for `!`, braces nested as parentheses, and `vt`, the thermal voltage at
/// 27 °C, predefined. Each was refused before (K0102, K0109, K0200).
#[test]
fn pspice_expressions_go_on_over_continuation_lines() {
    let text = "pspice\nV1 a 0 2\nR1 a 0 1k\nB1 b 0 V={ IF( (V(a) > {1}) & (V(a) < 3) | ~(1),\n* a comment between\n+ 2*vt,\n+ 0) }\nR2 b 0 1k\n.tran 1u 10u\n.end\n";
    let w = sim::simulate(&sort_text(text), &sim::Options::default()).unwrap();
    let k = w.names.iter().position(|n| n == "v(b)").unwrap();
    let vt = 300.15 * 8.6173303e-5;
    assert!(
        (w.data[k][0] - 2.0 * vt).abs() < 1e-12,
        "v(b) = {}",
        w.data[k][0]
    );
    // LIMIT clamps between its bounds in either order (the TLC555's bias
    // current is `LIMIT(x, upper, 0)`; read as lo = upper, hi = 0 it was 0).
    for (x, want) in [(3.0, 2.0), (-1.0, 0.0), (1.5, 1.5)] {
        let text = format!(
            "limit\nV1 a 0 {x}\nR1 a 0 1k\nB1 b 0 V={{limit(v(a), 2, 0) + limit(v(a), 0, 2)}}\nR2 b 0 1k\n.tran 1u 10u\n.end\n"
        );
        let w = sim::simulate(&sort_text(&text), &sim::Options::default()).unwrap();
        let k = w.names.iter().position(|n| n == "v(b)").unwrap();
        assert_eq!(w.data[k][0], 2.0 * want, "limit of {x}");
    }
    let text = "own vt\n.param vt=1\nV1 b 0 {vt}\nR1 b 0 1k\n.tran 1u 10u\n.end\n";
    let w = sim::simulate(&sort_text(text), &sim::Options::default()).unwrap();
    let k = w.names.iter().position(|n| n == "v(b)").unwrap();
    assert_eq!(w.data[k][0], 1.0, "a .param vt replaces the predefined one");
}

/// PSpice's VSWITCH: with VON and VOFF, a resistance that goes from ROFF
/// to RON smoothly as the control goes from VOFF to VON (ngspice's
/// `pswitch`, logarithmic: the geometric mean halfway); with VT and VH,
/// ngspice's hysteretic SW. Refused before (K0203).
#[test]
fn a_vswitch_moves_its_resistance_with_its_control() {
    let r_at = |vc: f64, model: &str| {
        let text = format!(
            "vswitch\nV2 a 0 1\nS1 a 0 c 0 swm\nV1 c 0 {vc}\n.model swm vswitch({model})\n.tran 1u 10u\n.end\n"
        );
        let w = sim::simulate(&sort_text(&text), &sim::Options::default()).unwrap();
        let k = w.names.iter().position(|n| n == "i(v2)").unwrap();
        -1.0 / w.data[k][0]
    };
    let smooth = "von=1 voff=0 ron=10 roff=1meg";
    for (vc, r) in [
        (-1.0, 1e6),
        (0.0, 1e6),
        (0.5, 1e7f64.sqrt()),
        (1.0, 10.0),
        (3.0, 10.0),
    ] {
        let got = r_at(vc, smooth);
        assert!((got / r - 1.0).abs() < 1e-9, "at {vc} V: {got} Ω, not {r}");
    }
    // Monotone between, in the order VOFF → VON whichever is larger.
    let (a, b) = (r_at(0.3, smooth), r_at(0.7, smooth));
    assert!(1e6 > a && a > 1e7f64.sqrt() && 1e7f64.sqrt() > b && b > 10.0);
    let reversed = "von=0 voff=1 ron=10 roff=1meg";
    assert!((r_at(0.0, reversed) / 10.0 - 1.0).abs() < 1e-9);
    assert!((r_at(0.7, reversed) / a - 1.0).abs() < 1e-9);
    let hysteretic = "vt=0.5 vh=0.1 ron=10 roff=1meg";
    assert!((r_at(1.0, hysteretic) / 10.0 - 1.0).abs() < 1e-9);
    assert!((r_at(0.5, hysteretic) / 1e6 - 1.0).abs() < 1e-9);
}

/// ngspice's level-6 MOSFET (Sakurai–Newton, `mos6load.c`), at the
/// operating point against its equations worked by hand: above threshold
/// `von = VTO − σ·vds`, `vgon = vgs − von`, `vdsat = KV·vgon^NV`, the
/// saturation current `KC·W/L·vgon^NC·(1 + λ·vds)`, times `(2 − r)·r`,
/// `r = vds/vdsat`, below vdsat. Refused before (K0223).
#[test]
fn a_level_6_mosfet_follows_the_nth_power_law() {
    let id_at = |vgs: f64, vds: f64| {
        let text = format!(
            "mos6\nVG g 0 {vgs}\nVD d 0 {vds}\nM1 d g 0 0 nm L=2u W=4u\n.model nm nmos level=6 vto=1 kc=1e-4 nc=1.5 kv=2 nv=0.5 lambda0=0.01 sigma=0.05\n.tran 1n 10n\n.end\n"
        );
        let w = sim::simulate(&sort_text(&text), &sim::Options::default()).unwrap();
        let k = w.names.iter().position(|n| n == "i(vd)").unwrap();
        -w.data[k][0]
    };
    let hand = |vgs: f64, vds: f64| {
        let vgon: f64 = vgs - (1.0 - 0.05 * vds);
        if vgon <= 0.0 {
            return 0.0;
        }
        let (vdsat, sat) = (
            2.0 * vgon.sqrt(),
            1e-4 * 2.0 * vgon.powf(1.5) * (1.0 + 0.01 * vds),
        );
        let r = vds / vdsat;
        if r < 1.0 { sat * (2.0 - r) * r } else { sat }
    };
    for (vgs, vds) in [(3.0, 5.0), (3.0, 1.0), (2.0, 0.2), (0.5, 1.0)] {
        let (got, want) = (id_at(vgs, vds), hand(vgs, vds));
        assert!(
            // The drain junction's GMIN (1e-12 S) leaks a few picoamperes.
            (got - want).abs() <= 1e-9 * want.abs() + 1e-11,
            "vgs {vgs}, vds {vds}: {got} A, not {want}"
        );
    }
}

/// An operating point that does not exist (a B source draws `atan(v) + 2`
/// from a node that only a capacitor joins: no voltage makes it zero) names
/// where the residual was largest when Newton gave up, as every unsolvable
/// circuit's diagnostic names its elements. A fuzz finding, a 1.26e20 Ω
/// collector load, whose base-collector junction's charge has no solution
/// Newton on the states reaches, finds its operating point on the DC image
/// with algebraic charges: the source's 50 µA drawn from the base through
/// GMIN alone, at about −5·10^7 V (ngspice's GMIN and source stepping fail
/// on it).
#[test]
fn a_failed_operating_point_names_where_newton_is_worst() {
    let text = "nosol\nv1 in 0 1\nr2 in b 1k\nc2 b 0 1n\nb1 a 0 i=atan(v(a))+2\nc1 a 0 1n\n.tran 1u 10u\n.end\n";
    let err = sim::simulate(&sort_text(text), &sim::Options::default()).unwrap_err();
    let SimError::DcFailed { reason } = &err else {
        panic!("{err}");
    };
    assert!(
        matches!(
            reason,
            DcFailure::NoConvergence { at: Some(_), .. } | DcFailure::Stalled { at: Some(_), .. }
        ),
        "{err}"
    );
    assert!(err.to_string().contains("largest at `c1`"), "{err}");
    let text = "hi\nvcc vcc 0 dc 9\nib b 0 sin(50u 300u 2meg)\nrc vcc c 1.26e20\nrf c b 47k\nq1 c b 0 npnhi\n.model npnhi npn is=5e-14 bf=120 br=0.5 ikf=0.1 ikr=10 ise=2e-11 isc=1e-15 rb=22 rc=2 vaf=80 var=50\n+ tf=2e-10 tr=5e-5 cje=8p cjc=6p cjs=2e-15 mjs=0.5 vjs=0.75 vtf=500\n.tran 2n 2u\n.end\n";
    let w = sim::simulate(&sort_text(text), &sim::Options::default()).expect("an operating point");
    let vb = w.data[w.names.iter().position(|n| n == "v(b)").unwrap()][0];
    assert!((vb / -5e7 - 1.0).abs() < 0.01, "v(b) = {vb}");
}

/// A DC Jacobian singular where Newton stopped, though every node has a DC
/// path, names the element whose state it depends least on (a fuzz
/// finding: a 4.5e37 H inductor coupled at k ≈ 1 to a 1 mH one). Named
/// nothing before.
#[test]
fn a_singular_operating_point_names_what_it_depends_least_on() {
    let text = "doubler\nK69 Lk1 Lk2 0.99999999\nLk2 in 0 1m\nLk1 x 0 4.468e37\nRx x 0 1\nV1 in 0 SIN(0 5 1k)\nC1 in a 1u\nD1 0 a dm\nD2 a out dm\nC2 out 0 1u\nRl out 0 100k\n.model dm D(IS=2.52n N=1.752 RS=0.568 CJO=4p VJ=0.75 M=0.4 TT=20n)\n.tran 10u 20m\n.end\n";
    let err = sim::simulate(&sort_text(text), &sim::Options::default()).unwrap_err();
    assert!(
        matches!(err, SimError::DcSingular { at: Some(_), .. }),
        "{err}"
    );
    assert!(err.to_string().contains("depends least on `Lk"), "{err}");
    // A state whose perturbed evaluation fails (its loops have no solution
    // there) is passed over, not the end of the search: the 741 follower
    // with one transistor of area 1e-308 (a grammar-fuzzing finding) named
    // nothing. At area 1e-308 its saturation current (1e-322) is subnormal,
    // which the run flushes to zero: its junction's loop is singular, and
    // says so by its name; at 1e-290 the search runs as it did.
    let deck = std::fs::read_to_string(root().join("netlists/ua741_follower.cir")).unwrap();
    let with_area = |area: &str| {
        let text = deck.replace("\nQ5 n5 n7 n8 QN\n", &format!("\nQ5 n5 n7 n8 QN {area}\n"));
        assert_ne!(text, deck);
        sim::simulate(&sort_text(&text), &sim::Options::default()).unwrap_err()
    };
    let err = with_area("1e-290");
    assert!(
        matches!(err, SimError::DcSingular { at: Some(_), .. }),
        "{err}"
    );
    let err = with_area("1e-308");
    assert!(err.to_string().contains("through Q5:bc"), "{err}");
}

/// The same past 500 states, where finite differences over every state
/// would cost an evaluation each: the element comes from the coloured
/// sparse Jacobian (a node whose conductances cancel, `Ga` against `Ra`,
/// beside a 510-section RC line). Named nothing before (a 10^4-section line
/// of the grammar fuzzer).
#[test]
fn a_large_singular_operating_point_names_what_it_depends_least_on() {
    let mut text = String::from(
        "cancelling conductances\nV1 n0 0 DC 1\nCa a 0 1n\nRa a 0 1k\nGa a 0 a 0 -1m\nIa 0 a 1m\n",
    );
    for k in 1..=510 {
        text.push_str(&format!("R{k} n{} n{k} 1k\nC{k} n{k} 0 1n\n", k - 1));
    }
    text.push_str(".tran 1u 10m\n.end\n");
    let err = sim::simulate(&sort_text(&text), &sim::Options::default()).unwrap_err();
    assert!(
        matches!(err, SimError::DcSingular { at: Some(_), .. }),
        "{err}"
    );
    assert!(err.to_string().contains("depends least on `Ca`"), "{err}");
}

/// A netlist without `.tran` is pointed at: its title line carries the
/// diagnostic's label (K0400 had no location before).
#[test]
fn a_netlist_without_tran_is_pointed_at() {
    use kausal::diag::ToDiagnostic;
    let err = sim::simulate(
        &sort_text("no tran here\nR1 a 0 1k\nV1 a 0 1\n.end\n"),
        &sim::Options::default(),
    )
    .unwrap_err();
    let SimError::NoTran { title } = err else {
        panic!("{err}");
    };
    assert_eq!((title.start, title.end), (0, 12));
    assert_eq!(err.to_diagnostic().labels.len(), 1);
}

/// `.ic` on a bipolar circuit whose DC image with charge states cannot
/// hold it (a diode-connected transistor's junction charge is no state of
/// that image, so it cannot be mapped back) is held on the image with
/// algebraic charges, which maps every charge by name: the µA741 follower
/// with its input stage's `n5` held 32 mV off its own operating point
/// starts where ngspice's `.ic` puts it. Before, K0408 dropped the `.ic`
/// and the output started at 0.3 mV instead of 6.37 V.
#[test]
fn an_ic_on_a_bipolar_op_amp_is_held() {
    let text = std::fs::read_to_string(crate::root().join("netlists/ua741_follower.cir"))
        .unwrap()
        .replace(".tran 10u 3m", ".ic v(n5)=-13.9\n.tran 10u 3m");
    let w = sim::simulate(&sort_text(&text), &sim::Options::default()).expect("runs");
    assert!(
        w.warnings
            .iter()
            .all(|d| d.code != kausal::diag::codes::IC_NOT_HELD),
        "the .ic was dropped"
    );
    let at0 = |name: &str| w.data[w.names.iter().position(|n| n == name).unwrap()][0];
    assert!(
        (at0("v(n5)") + 13.9).abs() < 1e-9,
        "v(n5) = {}",
        at0("v(n5)")
    );
    // ngspice-39 at t = 0 (its `.ic` holds the node through 1e10 S).
    assert!(
        (at0("v(out)") - 6.367537).abs() < 1e-3,
        "v(out) = {}",
        at0("v(out)")
    );
}

/// `--method gear2` is second order with BDF2's error constant: on a
/// linear RC low-pass driven by a sine (exact solution known) at steps set
/// by TMAX, halving TMAX divides its error by about four, and its error is
/// several times TR-BDF2's at the same steps (its local error constant is
/// 5.5 times TR-BDF2's, 2/9 against 0.040 h³y'''; the global errors
/// measured here differ by 8.0). Wrong variable-step coefficients make it
/// first order (a ratio of two).
#[test]
fn gear2_is_second_order_at_capped_steps() {
    let (tau, w) = (1e-4, 2.0 * std::f64::consts::PI * 1e3);
    let exact = |t: f64| {
        let a = 1.0 / tau;
        let k = a / (a * a + w * w);
        k * (a * (w * t).sin() - w * (w * t).cos()) + k * w * (-a * t).exp()
    };
    let error = |method: Method, tmax: &str| {
        let s = sort_text(&format!(
            "rc\nV1 in 0 SIN(0 1 1k)\nR1 in out 1k\nC1 out 0 100n\n.tran {tmax} 5m 0 {tmax}\n.end\n"
        ));
        let o = sim::Options {
            method: Some(method),
            rtol: Some(1e-2),
            ..Default::default()
        };
        let w = sim::simulate(&s, &o).expect("simulates");
        let k = w.names.iter().position(|n| n == "v(out)").expect("v(out)");
        w.time
            .iter()
            .zip(&w.data[k])
            .map(|(&t, &v)| (v - exact(t)).abs())
            .fold(0.0, f64::max)
    };
    let (coarse, fine) = (error(Method::Gear2, "20u"), error(Method::Gear2, "10u"));
    let ratio = coarse / fine;
    assert!(
        (3.5..=4.5).contains(&ratio),
        "errors {coarse:e} at TMAX 20 µs, {fine:e} at 10 µs: ratio {ratio}"
    );
    let trbdf2 = error(Method::Circuit, "10u");
    let ratio = fine / trbdf2;
    assert!(
        (4.0..=10.0).contains(&ratio),
        "gear2 {fine:e} against TR-BDF2 {trbdf2:e} at TMAX 10 µs: ratio {ratio}"
    );
}

/// An operating point with `.ic` nodes held that fails, and names no element
/// (Newton on a JFET amplifier with its gate held at 6.7·10^31 V, a fuzz
/// finding), points at the `.ic` line: one label on each held node, saying
/// the value it was held at. Before, K0406 had no location.
#[test]
fn a_failed_held_operating_point_points_at_its_ic() {
    use kausal::diag::ToDiagnostic;
    let text = std::fs::read_to_string(crate::root().join("netlists/jfet_amp.cir"))
        .unwrap()
        .replacen('\n', "\n.ic v(d)=0 v(g)=6.69e31\n", 1);
    let err = sim::simulate(&sort_text(&text), &sim::Options::default()).unwrap_err();
    let SimError::HeldDcFailed { held, .. } = &err else {
        panic!("{err}");
    };
    let line = text.find(".ic").expect("the .ic line");
    let spans: Vec<&str> = held
        .iter()
        .map(|(s, _)| &text[s.start as usize..s.end as usize])
        .collect();
    assert_eq!(spans, ["v(d)", "v(g)"], "{err}");
    assert!(held.iter().all(|(s, _)| s.start as usize > line), "{err}");
    assert_eq!(held[1].1, "v(g) = 6.69e31 V");
    let d = err.to_diagnostic();
    assert_eq!(d.labels.len(), 2);
    assert!(err.to_string().contains("with `.ic` holding"), "{err}");
}

/// An operating point that runs out of its work limit says where Newton's
/// first attempt left its largest residual (a fuzz finding: a BJT inverter
/// on a 1.48e22 V supply through a negative collector resistor spent the
/// 90 s and named nothing).
#[test]
fn an_operating_point_out_of_work_names_where_newton_was_worst() {
    let text = std::fs::read_to_string(crate::root().join("netlists/bjt_rtl_inverter.cir"))
        .unwrap()
        .replace("VCC vcc 0 5", "VCC vcc 0 1.48e22")
        .replace("RC c vcc 1k", "RC c vcc -8.315e-2");
    let opts = sim::Options {
        dc_work: Some(30_000_000),
        ..Default::default()
    };
    let err = sim::simulate(&sort_text(&text), &opts).unwrap_err();
    let SimError::DcFailed {
        reason: DcFailure::WorkLimit { at: Some(at), .. },
    } = &err
    else {
        panic!("{err}");
    };
    assert!(at.starts_with("`Q1"), "{err}");
    assert!(err.to_string().contains("largest residual at `Q1"), "{err}");
}

/// After an evaluation of `f`, the outputs are read from its registers and
/// only the output-only steps computed (`Tape::outputs_after_rhs`, what the
/// circuit integrator writes at a step's end): every variable of the
/// system, asked for as an output, equals what the output program computes
/// from the states alone, through private blocks (a junction charge's
/// inversion, a loop nothing else in `f` reads), torn gate loops, the
/// bridge's linear loop and a loop only outputs need (the VCVS amplifier's
/// feedback, whose constant Jacobian's solve settles its body only where
/// something reads it).
#[test]
fn outputs_after_an_evaluation_equal_the_output_programs() {
    use kausal::tape::OutputRef;
    for name in [
        "diode_bridge.cir",
        "bench/vacask_mul.cir",
        "mos3_inverter_chain.cir",
        "bjt_opamp_follower.cir",
        "switch_buck.cir",
        "vcvs_amp.cir",
    ] {
        let s = sort_file(name);
        let sys = s.system();
        let outputs: Vec<OutputRef> = sys.vars.ids().map(OutputRef::Var).collect();
        let t = kausal::tape::compile(sys, &s.schedule, &outputs);
        assert!(
            t.tail_code.len() < t.out_code.len(),
            "{name}: the tail computes less than the output program"
        );
        let n = t.states.len();
        let mut regs = t.registers();
        let mut dy = vec![0.0; n];
        let (mut ours, mut theirs) = (vec![0.0; outputs.len()], vec![0.0; outputs.len()]);
        for (k, scale) in [0.0, 1e-3, 0.3].into_iter().enumerate() {
            // Voltages of a fraction of a volt, charges of femtocoulombs.
            let y: Vec<f64> = t
                .states
                .iter()
                .enumerate()
                .map(|(i, &v)| {
                    let unit = match sys.vars[v].kind {
                        kausal::ir::VarKind::Charge => 1e-15,
                        kausal::ir::VarKind::BranchCurrent => 1e-3,
                        _ => 1.0,
                    };
                    scale * unit * if (i + k) % 2 == 0 { 1.0 } else { -0.5 }
                })
                .collect();
            let at = 1e-7 * k as f64;
            t.rhs(&mut regs, at, &y, &mut dy).unwrap();
            t.outputs_after_rhs(&mut regs, at, &mut ours).unwrap();
            t.outputs(&mut regs, at, &y, &mut theirs).unwrap();
            for (o, (&a, &b)) in ours.iter().zip(&theirs).enumerate() {
                let OutputRef::Var(v) = outputs[o] else {
                    unreachable!()
                };
                assert!(
                    (a - b).abs() <= 1e-9 * (a.abs().max(b.abs())) + 1e-12 * (1.0 + a.abs()),
                    "{name}, scale {scale}: {} is {a:e} after f, {b:e} from the states",
                    sys.var_name(v)
                );
            }
        }
    }
}

/// A run that releases the equation system and circuit once its operating
/// point is found (what `kausal sim` does) gives the same waveforms, bit for
/// bit, as one that keeps them: dense and sparse, with junctions, `.ic`
/// nodes, and under kausal's own integrator; and its sorted circuit keeps
/// its sources and title.
#[test]
fn releasing_the_ir_changes_no_output() {
    let mut ladder = String::from("ladder of 80 sections\nV1 n0 0 PULSE(0 1 1u 1u 1u 1m 2m)\n");
    for k in 1..=80 {
        ladder += &format!("R{k} n{} n{k} 1k\nC{k} n{k} 0 1n\n", k - 1);
    }
    ladder += ".tran 1u 200u\n.end\n";
    let cases: Vec<(Sorted, Option<Method>)> = vec![
        (sort_text(&ladder), None),
        (sort_file("diode_bridge.cir"), None),
        (sort_file("diode_bridge.cir"), Some(Method::Gear2)),
        (sort_file("ic_in_subckt.cir"), None),
        (sort_file("mos1_inverter_chain.cir"), None),
        (sort_file("rc_lowpass_step.cir"), Some(Method::TrBdf2)),
    ];
    for (mut sorted, method) in cases {
        let opts = sim::Options {
            method,
            ..Default::default()
        };
        let title = sorted.elaborated.circuit.title.clone();
        let kept = sim::simulate(&sorted, &opts).expect("runs");
        let p = sim::prepare(&sorted, &opts).expect("prepares");
        let released =
            sim::run_prepared_releasing(&mut sorted, p, &opts, None, || {}).expect("runs");
        assert!(
            sorted.system().vars.is_empty(),
            "{title}: the system is kept"
        );
        assert_eq!(sorted.elaborated.circuit.title, title);
        assert_eq!(kept.names, released.names, "{title}");
        assert_eq!(kept.time, released.time, "{title}");
        assert_eq!(kept.data, released.data, "{title}");
        assert_eq!(kept.stats.steps, released.stats.steps, "{title}");
    }
    // A failure after the release still names its variable.
    let mut s = sort_text("unstable\nR1 a 0 -1\nC1 a 0 1u ic=1\n.tran 1u 1 uic\n.end\n");
    let opts = sim::Options::default();
    let kept = sim::simulate(&s, &opts).unwrap_err().to_string();
    let p = sim::prepare(&s, &opts).expect("prepares");
    let released = sim::run_prepared_releasing(&mut s, p, &opts, None, || {})
        .unwrap_err()
        .to_string();
    assert_eq!(kept, released);
}
