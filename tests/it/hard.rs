//! Numerical stability on the hard cases of `netlists/hard/`: no blow-up,
//! bounded energy drift on the LC tank, and errors that shrink as the
//! tolerance tightens. Properties, never timings.

use std::path::PathBuf;

use kausal::bench;
use kausal::io::FsLoader;
use kausal::pipeline::{self, SortOptions, Sorted};
use kausal::sim::{self, Method};

fn hard(name: &str) -> PathBuf {
    crate::root().join("netlists/hard").join(name)
}

fn sorted(name: &str) -> Sorted {
    pipeline::sort(&hard(name), &FsLoader, &SortOptions::default())
        .unwrap_or_else(|_| panic!("{name} sorts"))
}

/// The largest absolute difference of two signals on the same points.
fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

fn sim(s: &Sorted, method: Method, rtol: f64) -> sim::Waveforms {
    let o = sim::Options {
        method: Some(method),
        rtol: Some(rtol),
        ..Default::default()
    };
    sim::simulate(s, &o).expect("simulates")
}

/// Every hard case simulates at default settings with finite outputs
/// bounded by a physical limit of its sources.
#[test]
fn hard_cases_do_not_blow_up() {
    // (netlist, bound on every voltage output in V)
    let cases = [
        ("stiff_rc_ladder.cir", 1.0),
        ("lc_tank_1000_periods.cir", 1.0),
        ("rectifier_big_cap.cir", 12.0),
        ("sin_rectifier.cir", 5.0),
        ("fast_edges_diode.cir", 5.0),
        ("pwl_sharp.cir", 2.0),
        ("rc_line_10k.cir", 1.0),
        ("rlc_ladder_1k.cir", 1.0),
        ("ecl_schmitt.cir", 5.2),
        ("bjt_high_injection.cir", 9.0),
    ];
    for (name, bound) in cases {
        let s = sorted(name);
        let w =
            sim::simulate(&s, &sim::Options::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
        for (k, n) in w.names.iter().enumerate() {
            for &v in &w.data[k] {
                assert!(v.is_finite(), "{name}: {n} is not finite");
                if n.starts_with("v(") {
                    assert!(
                        v.abs() <= bound * 1.05,
                        "{name}: {n} = {v} beyond the sources' bound {bound}"
                    );
                }
            }
        }
    }
}

/// The bridge rectifiers at every tolerance of the benchmark and every stiff
/// solver: diode switching leaves kinks in the solver's history, which once
/// ended BDF runs with repeated error-test failures. No node may leave the
/// source's amplitude: at rtol 1e-2 BDF once charged the 10 V bridge's
/// capacitor to 43 V (a Newton iterate accepted too early at a turn-on).
#[test]
fn bridge_rectifiers_run_at_every_tolerance() {
    // (netlist, the source's amplitude in V)
    for (name, amplitude) in [
        ("rectifier_big_cap.cir", 12.0),
        ("../diode_bridge.cir", 10.0),
    ] {
        let s = sorted(name);
        for method in [
            Method::Bdf,
            Method::TrBdf2,
            Method::Esdirk34,
            Method::Circuit,
            Method::Gear2,
        ] {
            for rtol in [1e-2, 1e-3, 1e-4, 1e-5] {
                let w = sim(&s, method, rtol);
                for (k, n) in w.names.iter().enumerate() {
                    let worst = w.data[k].iter().fold(0.0f64, |m, v| m.max(v.abs()));
                    assert!(
                        worst.is_finite(),
                        "{name} {method:?} rtol {rtol}: {n} not finite"
                    );
                    assert!(
                        !n.starts_with("v(") || worst <= amplitude,
                        "{name} {method:?} rtol {rtol}: |{n}| reaches {worst} V \
                         beyond the source's {amplitude} V"
                    );
                }
            }
        }
    }
}

/// kausal's circuit integrator on the bridge rectifiers, at its loosest
/// tolerance of the benchmark (1e-2): every output within 3e-3 (V or A) of
/// a tight BDF run, the error of ngspice at its defaults there (BENCHMARKS.md).
/// Its steps end on the output points, and its error is measured against
/// each state's largest magnitude so far: a diode's charge passing through
/// zero or decaying after turn-off is not followed to a relative accuracy
/// no output shows, one for which BDF takes 60–110 steps per switching event.
#[test]
fn circuit_integrator_on_the_bridges() {
    for name in ["rectifier_big_cap.cir", "../diode_bridge.cir"] {
        let s = sorted(name);
        let reference = sim(&s, Method::Bdf, 1e-8);
        let w = sim(&s, Method::Circuit, 1e-2);
        assert_eq!(w.time, reference.time, "{name}: output points");
        for (k, n) in w.names.iter().enumerate() {
            let err = max_diff(&w.data[k], &reference.data[k]);
            assert!(err <= 3e-3, "{name}: {n} is {err:e} off a tight BDF run");
        }
        // Steps end on the output points, a few more at the switching.
        let points = w.time.len();
        assert!(
            w.stats.steps >= points - 1 && w.stats.steps < 2 * points,
            "{name}: {} steps for {points} points",
            w.stats.steps
        );
    }
}

/// With TMAX equal to the output spacing (ngspice's cap when TSTEP is below
/// span/50, which the benchmarks give both sides), every interval between
/// output points is one step of the circuit integrator, a few more where
/// the diodes switch. A step short of the next point by rounding only once
/// split each interval into two half steps: 1.6 times ngspice's steps.
#[test]
fn circuit_integrator_takes_one_step_per_capped_interval() {
    for (name, tmax) in [("sin_rectifier.cir", 1e-6), ("rectifier_big_cap.cir", 1e-4)] {
        let s = sorted(name);
        let mut evals = [0; 2];
        for (k, method) in [Method::Circuit, Method::Gear2].into_iter().enumerate() {
            let o = sim::Options {
                method: Some(method),
                rtol: Some(1e-3),
                tmax: Some(tmax),
                ..Default::default()
            };
            let w = sim::simulate(&s, &o).expect("simulates");
            let intervals = w.time.len() - 1;
            // gear2 takes up to a fifth more: at a diode's turn-on its
            // predictor spans the whole step, Newton fails there more
            // often than on TR-BDF2's two stages, and a step cut by four
            // regrows by two per step.
            let most = if method == Method::Gear2 { 125 } else { 105 };
            assert!(
                w.stats.steps >= intervals && w.stats.steps * 100 <= intervals * most,
                "{name} {method:?}: {} steps for {intervals} intervals of TMAX",
                w.stats.steps
            );
            evals[k] = w.stats.rhs_evals;
        }
        // gear2's steps are one implicit stage where TR-BDF2's are two:
        // fewer evaluations of f, about half on `sin_rectifier` (5,283
        // against 10,227), a fifth fewer on `rectifier_big_cap` (4,571
        // against 5,873: its stages need two Newton iterates on average,
        // TR-BDF2's 1.45, as the whole step's predictor misses more across
        // a conducting junction than its second stage's).
        assert!(
            evals[1] * 10 <= evals[0] * 8,
            "{name}: gear2 evaluated f {} times, circuit {}",
            evals[1],
            evals[0]
        );
    }
}

/// The diode bridge floats at each zero crossing of its source (every diode
/// off, its nodes set by the junctions' depletion charges, orders of
/// magnitude below the diffusion charges of their conduction): the circuit
/// integrator's error there shrinks with its tolerance (measured against
/// each charge's peak alone it stayed 1.5e-3 V at every rtol).
#[test]
fn circuit_integrator_error_shrinks_on_a_floating_bridge() {
    let s = pipeline::sort(
        &crate::root().join("netlists/diode_bridge.cir"),
        &FsLoader,
        &SortOptions::default(),
    )
    .unwrap_or_else(|_| panic!("diode_bridge.cir sorts"));
    let reference = sim(&s, Method::Bdf, 1e-9);
    for method in [Method::Circuit, Method::Gear2] {
        let errs: Vec<f64> = [1e-3, 1e-5, 1e-7]
            .iter()
            .map(|&rtol| {
                let w = sim(&s, method, rtol);
                assert_eq!(w.time, reference.time);
                w.data
                    .iter()
                    .zip(&reference.data)
                    .map(|(a, b)| max_diff(a, b))
                    .fold(0.0, f64::max)
            })
            .collect();
        assert!(
            errs[1] < errs[0] && errs[2] * 20.0 <= errs[0] && errs[2] <= 1e-4,
            "{method:?}: errors {errs:?} at rtol 1e-3, 1e-5, 1e-7"
        );
    }
}

/// A clamp's nA reverse current behind a 7 Ω series resistance, where a
/// junction charge's Newton error reaches the current amplified by
/// 1/(C·RS): the circuit integrator at rtol 1e-7 within 1e-4 of each
/// output's range of a tight BDF run (one Newton iterate, with the error
/// measured in the charge alone, leaves i(V2) 0.7 % of its range off).
#[test]
fn circuit_integrator_converges_junction_currents() {
    let s = sorted("clamp_leakage.cir");
    let reference = sim(&s, Method::Bdf, 1e-10);
    let w = sim(&s, Method::Circuit, 1e-7);
    assert_eq!(w.time, reference.time);
    for (k, n) in w.names.iter().enumerate() {
        let r = &reference.data[k];
        let range = r.iter().fold(f64::NEG_INFINITY, |m, v| m.max(*v))
            - r.iter().fold(f64::INFINITY, |m, v| m.min(*v));
        let err = max_diff(&w.data[k], r);
        assert!(
            err <= 1e-4 * range.max(1e-300),
            "{n} is {err:e} off a tight BDF run (range {range:e})"
        );
    }
}

/// Where the tape says `f` depends on the states nonlinearly only through
/// junctions ([`kausal::tape::Tape::jacobian_follows_junctions`], on
/// which the circuit integrator keeps one Jacobian and trusts a single
/// Newton iterate), following really is exact: the Jacobian at one point,
/// each junction's column rescaled by its `Q′` and its diagonal moved by its
/// `g_d`, is the Jacobian at another point and time, on every netlist of
/// the repository small enough for the circuit integrator. And a circuit
/// with a resistive diode is not taken for one.
#[test]
fn junction_following_is_exact_where_the_tape_claims_it() {
    use kausal::tape::{self, Tape};
    fn jacobian(t: &Tape, time: f64, y: &[f64]) -> Vec<f64> {
        let n = y.len();
        let (mut regs, mut dregs) = (t.init.clone(), Vec::new());
        let cols: Vec<usize> = (0..n).collect();
        let (mut j, mut dy) = (vec![0.0; n * n], vec![0.0; n]);
        t.jacobian_columns(&mut regs, &mut dregs, time, y, &cols, &mut j, &mut dy)
            .expect("evaluates");
        j
    }
    let mut paths: Vec<PathBuf> = ["netlists", "netlists/hard"]
        .iter()
        .flat_map(|d| std::fs::read_dir(crate::root().join(d)).expect("netlists"))
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "cir"))
        .collect();
    paths.sort();
    let (mut exact, mut with_junctions) = (Vec::new(), 0);
    for path in &paths {
        let Ok(s) = pipeline::sort(path, &FsLoader, &SortOptions::default()) else {
            continue;
        };
        let t = tape::compile(s.system(), &s.schedule, &[]);
        let n = t.states.len();
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        if !t.jacobian_follows_junctions() {
            exact.push((name, false));
            continue;
        }
        exact.push((name.clone(), true));
        if n == 0 || n > sim::DENSE_STATES {
            continue;
        }
        let junctions = t.charge_states();
        with_junctions += usize::from(junctions.iter().any(Option::is_some));
        for trial in 0..4 {
            let tr = trial as f64;
            let (mut ya, mut yb, mut va, mut vb) =
                (vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0.0; n]);
            for k in 0..n {
                let kf = k as f64;
                let (a, b) = (0.1 * (kf + 1.0) * (tr + 1.0), 0.3 * tr - 0.07 * (kf + 2.0));
                match junctions[k] {
                    // Junction voltages from reverse bias to conduction.
                    Some(ci) => {
                        let p = &t.diodes[ci.diode as usize];
                        (va[k], vb[k]) = (0.2 * a - 0.1, 0.15 * b + 0.45);
                        (ya[k], yb[k]) = (p.charge(va[k])[0], p.charge(vb[k])[0]);
                    }
                    None => (ya[k], yb[k]) = (a, b),
                }
            }
            let mut j = jacobian(&t, 1.3e-4 * (tr + 1.0), &ya);
            let jb = jacobian(&t, 7.1e-4 * (tr + 2.0), &yb);
            for k in 0..n {
                if let Some(ci) = junctions[k] {
                    let p = &t.diodes[ci.diode as usize];
                    let (ca, cb) = (p.charge(va[k])[1], p.charge(vb[k])[1]);
                    let (ga, gb) = (p.current(va[k])[1], p.current(vb[k])[1]);
                    for i in 0..n {
                        j[i * n + k] *= ca / cb;
                    }
                    j[k * n + k] += (ga - gb) / cb;
                }
            }
            let scale = jb.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for (i, (x, y)) in j.iter().zip(&jb).enumerate() {
                assert!(
                    (x - y).abs() <= 1e-9 * y.abs() + 1e-12 * scale,
                    "{name}: entry ({}, {}) followed to {x:e}, computed {y:e}",
                    i / n,
                    i % n
                );
            }
        }
    }
    assert!(
        with_junctions >= 10,
        "{with_junctions} circuits with junctions checked"
    );
    let claims = |n: &str| exact.iter().find(|(m, _)| m == n).map(|(_, e)| *e);
    assert_eq!(claims("rectifier_big_cap.cir"), Some(true));
    // Resistive diodes (no CJO, no TT): a nonlinear block of the states.
    assert_eq!(claims("nodeset_bistable.cir"), Some(false));
}

/// The lossless LC tank over 1000 periods at default settings: within 1e-3 V
/// of cos(w0 t) and its energy within 0.2 % of the initial 0.5 uJ.
#[test]
fn lc_tank_keeps_amplitude_phase_and_energy() {
    let s = sorted("lc_tank_1000_periods.cir");
    let w = sim::simulate(&s, &sim::Options::default()).expect("simulates");
    let w0 = 1.0 / (1e-3f64 * 1e-6).sqrt();
    let v = &w.data[0];
    let err = w
        .time
        .iter()
        .zip(v)
        .map(|(&t, &y)| (y - (w0 * t).cos()).abs())
        .fold(0.0, f64::max);
    assert!(err <= 1e-3, "max |v - cos(w0 t)| = {err:e}");
    let text = std::fs::read_to_string(hard("lc_tank_1000_periods.cir")).unwrap();
    let terms = bench::energy_terms(&text).expect("the netlist states its energy");
    assert_eq!(bench::extra_solvers(&text), [Method::Tsit5]);
    let drift = bench::energy_drift(&terms, &w.names, &w.data).expect("energy computable");
    assert!(drift <= 2e-3, "energy drift {drift:e}");
}

/// Tighter tolerance, smaller error against the exact solution, for every
/// solver the benchmark runs on it, the explicit Tsit5 included (a factor of
/// noise allowed between neighbours, and an overall decrease of at least 20x
/// over three decades).
#[test]
fn lc_tank_error_decreases_with_tolerance() {
    let s = sorted("lc_tank_1000_periods.cir");
    let w0 = 1.0 / (1e-3f64 * 1e-6).sqrt();
    for m in [
        Method::Bdf,
        Method::TrBdf2,
        Method::Esdirk34,
        Method::Tsit5,
        Method::Circuit,
    ] {
        let errs: Vec<f64> = [1e-4, 1e-5, 1e-6, 1e-7]
            .iter()
            .map(|&tol| {
                let w = sim(&s, m, tol);
                w.time
                    .iter()
                    .zip(&w.data[0])
                    .map(|(&t, &y)| (y - (w0 * t).cos()).abs())
                    .fold(0.0, f64::max)
            })
            .collect();
        for p in errs.windows(2) {
            assert!(p[1] <= 1.5 * p[0], "{m:?}: errors {errs:?}");
        }
        assert!(errs[3] * 20.0 <= errs[0], "{m:?}: errors {errs:?}");
    }
}

/// The same property on the stiff ladder, the pulse-driven diode and the
/// sharp PWL against kausal's tight reference, via `kausal bench`'s own
/// measurement (so the benchmark's error is known to be really measured).
#[test]
fn bench_errors_decrease_with_tolerance() {
    let opts = bench::Options {
        tolerances: vec![1e-3, 1e-4, 1e-5, 1e-6],
        repeats: 1,
        ngspice: false,
        ..Default::default()
    };
    for name in [
        "stiff_rc_ladder.cir",
        "fast_edges_diode.cir",
        "pwl_sharp.cir",
    ] {
        let b = bench::bench_circuit(&hard(name), &opts, &|_| {}).expect("benchmarks");
        assert!(b.non_monotone.is_empty(), "{name}: {:?}", b.non_monotone);
        for m in [
            "kausal bdf",
            "kausal tr-bdf2",
            "kausal esdirk34",
            "kausal circuit",
        ] {
            let (e, steps): (Vec<f64>, Vec<usize>) = b
                .points
                .iter()
                .filter(|p| p.solver == m)
                .map(|p| (p.error, p.steps))
                .unzip();
            assert_eq!(e.len(), 4, "{name} {m}: {:?}", b.points);
            assert!(e.iter().all(|x| x.is_finite()), "{name} {m}: {e:?}");
            // Under the bench's step cap (TSTEP below span/50, as ngspice
            // runs it) a method whose every step is the cap takes the same
            // steps at every tolerance, and its error cannot move.
            let cap_bound = steps
                .iter()
                .all(|&n| n.abs_diff(steps[0]) * 100 <= steps[0]);
            assert!(
                e[3] < e[0] || cap_bound,
                "{name} {m}: errors {e:?} do not shrink (steps {steps:?})"
            );
        }
    }
}

/// The whole job is timed as a `kausal sim` process: the bench runs the
/// executable it is given (a missing one fails the point, naming it), and
/// the process writes the CSV a user would get.
#[test]
fn bench_whole_job_is_a_kausal_process() {
    let base = bench::Options {
        tolerances: vec![1e-4],
        methods: vec![Method::Bdf],
        repeats: 1,
        ngspice: false,
        ..Default::default()
    };
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("netlists/rc_lowpass_step.cir");
    let real = bench::Options {
        exe: Some(env!("CARGO_BIN_EXE_kausal").into()),
        ..base.clone()
    };
    let b = bench::bench_circuit(&path, &real, &|_| {}).expect("benchmarks");
    let p = &b.points[0];
    assert!(p.failed.is_none(), "{:?}", p.failed);
    assert!(
        p.total_seconds > 0.0 && p.total_seconds.is_finite(),
        "{p:?}"
    );
    let missing = bench::Options {
        exe: Some(PathBuf::from("/nonexistent/no-such-kausal")),
        ..base
    };
    let b = bench::bench_circuit(&path, &missing, &|_| {}).expect("benchmarks");
    let why = b.points[0].failed.as_deref().unwrap_or_default();
    assert!(why.contains("no-such-kausal"), "{why}");
}

/// The analytic solutions the netlists state (`* kausal-exact:`) are the
/// benchmark's reference there; kausal at rtol 1e-11 agrees with each.
#[test]
fn exact_references_agree_with_kausal() {
    let opts = bench::Options {
        tolerances: vec![1e-4],
        methods: vec![Method::Bdf],
        repeats: 1,
        ngspice: false,
        ..Default::default()
    };
    let base = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("netlists");
    for (name, bound) in [
        ("rc_lowpass_step.cir", 1e-8),
        ("rlc_series_underdamped.cir", 1e-8),
        ("cv_loop.cir", 1e-7),
        ("li_cutset.cir", 1e-12),
        ("hard/lc_tank_1000_periods.cir", 2e-5),
    ] {
        let b = bench::bench_circuit(&base.join(name), &opts, &|_| {}).expect("benchmarks");
        assert!(b.reference.starts_with("exact"), "{name}: {}", b.reference);
        let check = b.exact_check.expect("an exact reference");
        assert!(
            check <= bound,
            "{name}: kausal is {check:e} from the exact solution"
        );
    }
}

/// A malformed `kausal-exact` line is an error naming its line and column.
#[test]
fn malformed_exact_line_is_located() {
    let text = "title\n* kausal-exact: v(out) = 1 - exp(-t/\n";
    let e = bench::Exact::from_netlist(text).unwrap_err();
    assert!(e.starts_with("line 2, column "), "{e}");
    let e = bench::Exact::from_netlist("t\n* kausal-exact: x = 2*t\n").unwrap_err();
    assert!(e.contains("no output vector"), "{e}");
    assert!(
        bench::Exact::from_netlist("t\n* a comment\n")
            .unwrap()
            .is_none()
    );
}

/// A transformer's leakage inductance rings with a diode's junction
/// capacitance at ~7 MHz (Q ~ 10^5) through the run: kausal follows it and
/// says why it took 10^5 steps, naming the mode's states. The circuits of the
/// benchmark set, whose steps are few, get no such warning.
#[test]
fn a_ringing_mode_is_named() {
    let s = sorted("transformer_ringing.cir");
    let w = sim::simulate(&s, &sim::Options::default()).expect("simulates");
    let k0409: Vec<&kausal::diag::Diagnostic> =
        w.warnings.iter().filter(|d| d.code == "K0409").collect();
    assert_eq!(k0409.len(), 1, "{:?}", w.warnings);
    let m = &k0409[0].message;
    assert!(m.contains("i_Ls2") && m.contains("q_D2"), "{m}");
    // The tank: 2 % of 10 mH with 26 pF, ~6-8 MHz.
    let freq: f64 = m
        .split("rings at ")
        .nth(1)
        .and_then(|r| r.split(' ').next())
        .and_then(|f| f.parse().ok())
        .unwrap_or_else(|| panic!("no frequency in {m}"));
    assert!((5e6..1e7).contains(&freq), "{m}");
    for name in ["rectifier_big_cap.cir", "lc_tank_1000_periods.cir"] {
        let w = sim::simulate(&sorted(name), &sim::Options::default()).expect("simulates");
        assert!(
            w.warnings.iter().all(|d| d.code != "K0409"),
            "{name}: {:?}",
            w.warnings
        );
    }
}

/// A MOS inverter chain with source and drain resistances takes many short
/// steps at its edges, but its modes are all real (RC and transconductance
/// only): its Jacobian, junction charges in coulombs beside voltages, gave
/// a 4e14 Hz "ringing mode" with Q ≈ 6400 when its eigenvalues were solved
/// unbalanced. No K0409 for it.
#[test]
fn real_modes_of_a_badly_scaled_jacobian_are_not_ringing() {
    let w =
        sim::simulate(&sorted("mos_chain_rs.cir"), &sim::Options::default()).expect("simulates");
    assert!(
        w.stats.steps >= 20 * 1201,
        "the chain no longer takes enough steps to be diagnosed: {}",
        w.stats.steps
    );
    assert!(
        w.warnings.iter().all(|d| d.code != "K0409"),
        "{:?}",
        w.warnings
    );
}

/// BDF at a loose rtol on a high-Q oscillator is warned about before the run
/// (K0410: the LC tank grows 170-fold at rtol 1e-2); not with tr-bdf2, not at
/// rtol 1e-3, and not on the underdamped RLC (Q ≈ 3).
#[test]
fn bdf_at_loose_rtol_on_an_oscillator_is_warned() {
    let warns = |s: &Sorted, method, rtol| {
        sim(s, method, rtol)
            .warnings
            .iter()
            .any(|d| d.code == "K0410")
    };
    let tank = sorted("lc_tank_1000_periods.cir");
    assert!(warns(&tank, Method::Bdf, 1e-2));
    assert!(!warns(&tank, Method::Bdf, 1e-3));
    assert!(!warns(&tank, Method::TrBdf2, 1e-2));
    let path = crate::root().join("netlists/rlc_series_underdamped.cir");
    let rlc = pipeline::sort(&path, &FsLoader, &SortOptions::default())
        .ok()
        .expect("sorts");
    assert!(!warns(&rlc, Method::Bdf, 1e-2));
}

/// A torn loop whose Newton correction at its solution is rounding carried
/// through a large slope (`high_side_driver.cir`) ends where that correction
/// or its residuals are within their rounding bounds; before, its damping
/// crept by steps of λ ≈ 1e-10 for 200 iterations and the run stopped at
/// t = 0 (K0402). At the switch's turn-off the damping refused a full step
/// that lowers both residuals 50-fold, and under the SDIRK methods it crept
/// by λ ≈ 3e-5 on corrections of 1.8e-10 of their tear: each once stopped
/// the run. ngspice's tight runs of it stop at 10 ns (timestep too small at
/// reltol 1e-8 to 1e-6), so the reference is kausal's own at rtol 1e-9:
/// every signal of BDF's, TR-BDF2's and ESDIRK34's runs at the default rtol
/// within 1e-3 of its range.
#[test]
fn a_loop_at_its_rounding_floor_runs_through_a_high_side_driver() {
    let s = sorted("high_side_driver.cir");
    let tight = sim(&s, Method::Bdf, 1e-9);
    for method in [Method::Bdf, Method::TrBdf2, Method::Esdirk34] {
        let o = sim::Options {
            method: Some(method),
            ..Default::default()
        };
        let w = sim::simulate(&s, &o).unwrap_or_else(|e| panic!("{method:?}: {e}"));
        assert_eq!(w.time.len(), tight.time.len());
        for (k, n) in w.names.iter().enumerate() {
            let r = &tight.data[k];
            let top = r.iter().cloned().fold(f64::MIN, f64::max);
            let range = top - r.iter().cloned().fold(f64::MAX, f64::min);
            if range == 0.0 {
                continue;
            }
            let err = max_diff(&w.data[k], r) / range;
            assert!(
                err <= 1e-3,
                "{method:?} {n}: {err:.3e} of its range off the tight run"
            );
        }
    }
}
