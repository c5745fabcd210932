//! Cross-validation against live ngspice: every suite circuit passes at
//! normalized error 1e-3 with kausal's default settings; a perturbed model is
//! caught; a missing, failing or garbled ngspice gives a clear error.

use std::io::Write;
use std::path::Path;

use kausal::io::FsLoader;
use kausal::pipeline::{self, SortOptions};
use kausal::validate::{self, ValidateError};

use crate::{goldens, netlists, root, stem};

/// ngspice must be there: the suite fails, never skips, without it.
fn require_ngspice() {
    let ok = std::process::Command::new(validate::ngspice_program())
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(
        ok,
        "ngspice is not installed: the cross-validation tests need it (apt-get install -y ngspice)"
    );
}

/// Circuits ngspice cannot simulate: seed D's inductor cutset is exactly
/// the structure ngspice's MNA cannot start (a singular matrix); an `AKO:`
/// model is read by ngspice only in its PSpice compatibility mode, which
/// `an_ako_model_agrees_with_ngspice_in_its_pspice_mode` sets.
const NGSPICE_CANNOT: &[&str] = &["seed_d_singular", "ako_models"];

/// A normalized error as an even power of ten (stable across machines);
/// rounding noise is all one bucket.
fn bucket(x: f64) -> String {
    if x < 1e-9 {
        return "<1e-9".into();
    }
    let p = x.log10().ceil() as i32;
    format!("<1e{}", p + p.rem_euclid(2))
}

/// The rectifiers of the hard set agree too. Their diodes' series
/// resistance carries the junction-charge error into the current (δq/(C·RS)):
/// a charge tolerance of 1e-17 C leaves the SIN rectifier's i(V1) 1.8e-3 off
/// at any rtol, and interpolating the charges as they are between steps
/// leaves the lightly loaded half-wave's reverse current 2.0e-3 off.
#[test]
fn hard_rectifiers_agree_with_ngspice() {
    require_ngspice();
    for name in [
        "sin_rectifier",
        "fast_edges_diode",
        "rectifier_big_cap",
        "halfwave_light_load",
        "clamp_leakage",
    ] {
        hard_case_validates(name);
    }
}

/// `netlists/hard/NAME.cir` passes `kausal validate` on every signal.
fn hard_case_validates(name: &str) {
    let rel = format!("netlists/hard/{name}.cir");
    let sorted = pipeline::sort(Path::new(&rel), &FsLoader, &SortOptions::default())
        .ok()
        .unwrap_or_else(|| panic!("{name} sorts"));
    let report = validate::validate(Path::new(&rel), &sorted, &validate::Options::default())
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    for s in &report.signals {
        assert!(s.pass, "{name} {}: {:.3e}", s.name, s.max_norm);
    }
}

/// Ladders torn into more than 48 variables, whose block Jacobians are
/// gathered by coloured tangent runs and factored sparse: diodes to ground
/// every third section (a Newton block) and a resistor/VCCS ladder (a
/// constant Jacobian, factored once). Dense LUs would take 12 s on the
/// 2000-section diode ladder; a mis-coloured column would stall Newton or move
/// the far nodes. Large linear loops are solved whole (every unknown, every
/// equation), which a resistor mesh needs.
#[test]
fn large_algebraic_loops_agree_with_ngspice() {
    require_ngspice();
    let dir = tempfile::tempdir().unwrap();
    let n = 240;
    // "rc": diodes, and R-C shunts whose 80 capacitor voltages make the
    // ODE sparse: diffsol's Jacobian comes from J·v, whose block solves are
    // cached per point (J·v must work before a point's cache is valid).
    for shunt in ["diode", "vccs", "rc"] {
        let mut text = format!("{shunt} ladder\nV1 n0 0 SIN(0 5 1k)\n");
        for k in 1..=n {
            text.push_str(&format!("R{k} n{} n{k} 10\n", k - 1));
            text.push_str(&match (shunt, k % 3) {
                ("diode" | "rc", 0) => format!("D{k} n{k} 0 DX\n"),
                ("vccs", 0) => format!("G{k} n{k} 0 n{k} 0 1m\n"),
                ("rc", 1) => format!("Rc{k} n{k} m{k} 1k\nCm{k} m{k} 0 10n\n"),
                _ => format!("Rs{k} n{k} 0 100k\n"),
            });
        }
        text.push_str(&format!(
            "C1 n{n} 0 1u\n.model DX D(IS=1e-14)\n.tran 10u 2m\n.save v(n1) v(n{}) v(n{n})\n.end\n",
            n / 2
        ));
        let path = dir.path().join(format!("{shunt}.cir"));
        std::fs::write(&path, &text).unwrap();
        let sorted = pipeline::sort(&path, &FsLoader, &SortOptions::default())
            .ok()
            .unwrap_or_else(|| panic!("{shunt} ladder sorts"));
        let tears = sorted.schedule.blocks().map(|b| b.tears.len()).max();
        assert!(tears > Some(48), "{shunt}: {tears:?} tears");
        let report = validate::validate(&path, &sorted, &validate::Options::default())
            .unwrap_or_else(|e| panic!("{shunt}: {e}"));
        assert_eq!(report.signals.len(), 3);
        for s in &report.signals {
            assert!(s.pass, "{shunt} {}: {:.3e}", s.name, s.max_norm);
        }
    }
    // A mesh: its torn Jacobian fills in, so it is solved whole (ngspice
    // needs 156 s on 100×100, kausal 2 s).
    let path = dir.path().join("mesh.cir");
    let mesh = kausal::generate::r_mesh(20, 20)
        .replace(".tran", ".save v(n0_1) v(n10_10) v(n19_19)\n.tran");
    std::fs::write(&path, mesh).unwrap();
    let sorted = pipeline::sort(&path, &FsLoader, &SortOptions::default())
        .ok()
        .expect("the mesh sorts");
    let report = validate::validate(&path, &sorted, &validate::Options::default())
        .unwrap_or_else(|e| panic!("mesh: {e}"));
    assert_eq!(report.signals.len(), 3);
    for s in &report.signals {
        assert!(s.pass, "mesh {}: {:.3e}", s.name, s.max_norm);
    }
}

/// `kausal validate` on netlist text written to a scratch file.
fn validate_text(name: &str, text: &str) -> validate::Report {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    std::fs::write(&path, text).unwrap();
    let sorted = pipeline::sort(&path, &FsLoader, &SortOptions::default())
        .ok()
        .unwrap_or_else(|| panic!("{name} sorts"));
    validate::validate(&path, &sorted, &validate::Options::default())
        .unwrap_or_else(|e| panic!("{name}: {e}"))
}

/// ngspice's last time point can be TSTOP plus an ulp (4.233000000000001e-2
/// for `.tran 0.1058m 42.33m`); kausal's value there is its value at TSTOP.
/// A NaN there (kausal does not extrapolate) would be an infinite error,
/// failing every signal of 5 in 60 fuzzed rectifiers.
#[test]
fn a_reference_point_an_ulp_past_tstop_is_compared_at_tstop() {
    require_ngspice();
    let report = validate_text(
        "rc_end.cir",
        "RC, TSTOP off ngspice's step grid\nV1 in 0 SIN(0 1 118.1)\nR1 in out 1k\n\
         C1 out 0 1u\n.tran 0.0001058 0.04233\n.end\n",
    );
    let last = report.reference.time.last().copied().unwrap_or(0.0);
    assert!(last > 0.04233, "ngspice ends at {last:e}, not past TSTOP");
    for s in &report.signals {
        assert!(s.pass, "{}: {:.3e}", s.name, s.max_norm);
    }
}

/// A source corner that the reference steps on an ulp late (1.3800000000000001e-7
/// for a PWL corner at 1.38e-7) is still a corner: a capacitor across the
/// source makes i(V1) jump there, and comparing kausal's value after the
/// corner with ngspice's before it failed i(V1) by its whole jump.
#[test]
fn a_corner_an_ulp_off_is_compared_one_sided() {
    require_ngspice();
    let report = validate_text(
        "cpwl.cir",
        "C across a PWL source\nV1 n1 0 PWL(0 0 1.38e-07 1.79 5.53e-07 -2.78 1.11e-06 0)\n\
         C3 0 n1 6.073e-06\nR1 n1 0 1k\n.tran 6.918e-09 1.384e-06\n.end\n",
    );
    assert!(
        !report.reference.time.contains(&1.38e-7),
        "ngspice stepped exactly on the corner: the test needs it an ulp off"
    );
    for s in &report.signals {
        assert!(s.pass, "{}: {:.3e}", s.name, s.max_norm);
    }
}

/// A signal that is zero but for rounding is compared on the absolute floor
/// (1e-9), not on its own range: on a reference ranging over 2e-16, kausal's
/// rounding would be a normalized error of 1 (3 of 80 fuzzed linear circuits
/// have such a signal). A real error on a small signal still fails.
#[test]
fn rounding_is_not_its_own_scale() {
    let time = [0.0, 1.0, 2.0, 3.0];
    let noise = [0.0, 2.2e-16, 0.0, -1.1e-16];
    let r = validate::compare("v(n3)", &noise, &[0.0; 4], &time, 1e-3);
    assert!(r.pass, "normalized {:e}", r.max_norm);
    let small = [0.0, 1e-11, 2e-11, 1e-11];
    let off = [0.0, 1e-11, 2e-11, 3e-11];
    assert!(!validate::compare("i(d1)", &small, &off, &time, 1e-3).pass);
}

/// Operating points that Newton from all-zero cannot reach without junction
/// limiting: zeners in breakdown, a clamp in a high-gain loop (without
/// limiting the solve stops silently at a point violating KCL by 2 mA), a
/// bridge from 300 V; and without FET limiting, 50 CMOS inverters in a row.
/// A stack of cut-off NMOS whose DC Jacobian rounding made singular (floored
/// gate capacitances beside junction charges). Each starts where ngspice's
/// operating point is.
#[test]
fn hard_operating_points_agree_with_ngspice() {
    require_ngspice();
    for name in [
        "dc_zener_regulator",
        "dc_clamped_inverter",
        "dc_bridge_300v",
        "dc_current_into_zener",
        "dc_clamp_rounding",
        "dc_inverter_chain_50",
        "dc_off_nmos_stack",
    ] {
        hard_case_validates(name);
    }
}

/// Junction charges in a loop away from ground and every source (two
/// paralleled BJTs behind base resistors): on node potentials the loop hid
/// its constraint and its block was singular at t = 0. Found on the
/// circuit's graph, one charge gets the loop's KVL and loses its state.
#[test]
fn a_hidden_loop_of_junction_charges_agrees_with_ngspice() {
    require_ngspice();
    hard_case_validates("bjt_paralleled");
}

/// An ECL Schmitt trigger whose loop through a follower's junction charges
/// ends each Newton solve at a rounding-level residual (2e-16 A) that no
/// damped step lowers: that is a solved loop, not a failure.
#[test]
fn a_loop_solved_to_rounding_agrees_with_ngspice() {
    require_ngspice();
    hard_case_validates("ecl_schmitt");
}

/// A BJT loop that is affine in its tears once the states are held, through
/// a select (the high-injection factor's guarded square root): solved as
/// linear, not by a damped Newton that read rounding amplified by a
/// femtofarad substrate capacitance as no convergence (K0500 at t = 0).
#[test]
fn a_loop_affine_under_a_select_agrees_with_ngspice() {
    require_ngspice();
    hard_case_validates("bjt_high_injection");
}

/// A regulator loop (no states) whose one tear's residual is flat where
/// the pass transistor is cut off: Newton has no slope there, and the root
/// is bracketed between tears of opposite residual.
#[test]
fn a_loop_with_a_flat_residual_agrees_with_ngspice() {
    require_ngspice();
    hard_case_validates("mos_regulator_dropout");
}

/// The same regulator fed through a resistance, a loop of several tears:
/// the pass transistor's current in its own frame is not torn (it would
/// make the residual jump wherever VDS changes sign, as it does in
/// dropout; torn there, Newton stopped the run at 0.27 ms).
#[test]
fn a_loop_through_a_switching_frame_agrees_with_ngspice() {
    require_ngspice();
    hard_case_validates("mos_regulator_source_r");
}

/// CMOS inverters without gate capacitance: each output node is an
/// algebraic loop through both transistors, computed forward from the
/// output node's potential. Torn at one unknown (the PMOS bulk junction's
/// voltage, that potential less VDD: every unknown of a small nonlinear
/// block is a candidate), not at four of the transistors' own quantities,
/// where Newton failed (K0402 at 5.2 us).
#[test]
fn an_inverter_loop_torn_at_one_unknown_agrees_with_ngspice() {
    require_ngspice();
    hard_case_validates("cmos_buffer_algebraic");
}

/// The SDIRK methods restart at a breakpoint with at most the step they
/// would have taken next. At the end of the inverter chain's input edge
/// diffsol's probe gave TR-BDF2 a first step 300 times that, which its
/// embedded error estimate passed wrong by volts: the run then stopped
/// with K0402 at 1.7 ns (ESDIRK34 too), or went on from the wrong state.
#[test]
fn the_sdirk_methods_restart_an_inverter_chain_at_its_edges() {
    require_ngspice();
    let rel = "netlists/mos1_inverter_chain.cir";
    let sorted = pipeline::sort(Path::new(rel), &FsLoader, &SortOptions::default())
        .ok()
        .expect("the inverter chain sorts");
    for method in [kausal::sim::Method::TrBdf2, kausal::sim::Method::Esdirk34] {
        let opts = validate::Options {
            sim: kausal::sim::Options {
                method: Some(method),
                ..Default::default()
            },
            ..Default::default()
        };
        let report = validate::validate(Path::new(rel), &sorted, &opts)
            .unwrap_or_else(|e| panic!("{method:?}: {e}"));
        for s in &report.signals {
            assert!(s.pass, "{method:?} {}: {:.3e}", s.name, s.max_norm);
        }
    }
}

#[test]
fn the_suite_agrees_with_ngspice() {
    require_ngspice();
    let mut table = String::new();
    let mut failures = Vec::new();
    for path in netlists() {
        let name = stem(&path);
        if NGSPICE_CANNOT.contains(&name.as_str()) {
            continue;
        }
        let rel = path.strip_prefix(root()).unwrap();
        let sorted = pipeline::sort(rel, &FsLoader, &SortOptions::default())
            .ok()
            .unwrap_or_else(|| panic!("{name} sorts"));
        let report = match validate::validate(rel, &sorted, &validate::Options::default()) {
            Ok(r) => r,
            Err(e) => panic!("{name}: {e}"),
        };
        for s in &report.signals {
            table.push_str(&format!(
                "{name:<28} {:<14} {:>7}  ngspice default {:>7}  {}\n",
                s.name,
                bucket(s.max_norm),
                s.ngspice_default_norm.map_or("-".into(), bucket),
                if s.pass { "ok" } else { "FAIL" }
            ));
            if !s.pass {
                failures.push(format!("{name} {}: {:.3e}", s.name, s.max_norm));
            }
        }
    }
    assert!(
        failures.is_empty(),
        "signals off ngspice's reference: {failures:?}"
    );
    goldens("validate").bind(|| insta::assert_snapshot!("suite", table));
}

/// `ako_models.cir` against ngspice, which reads `AKO:` only in its PSpice
/// compatibility mode: with `set ngbehavior=psa` in a `.spiceinit` beside
/// the netlist (which validate's ngspice reads, as ngspice run in that
/// directory does) it agrees; without, ngspice refuses the model.
#[test]
fn an_ako_model_agrees_with_ngspice_in_its_pspice_mode() {
    require_ngspice();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ako_models.cir");
    std::fs::copy(root().join("netlists/ako_models.cir"), &path).unwrap();
    let sorted = pipeline::sort(&path, &FsLoader, &SortOptions::default())
        .ok()
        .unwrap();
    let opts = validate::Options::default();
    match validate::validate(&path, &sorted, &opts) {
        Err(e) => assert!(e.to_string().contains("ngspice"), "{e}"),
        Ok(r) => panic!(
            "ngspice read AKO in its default mode:\n{}",
            validate::table(&r)
        ),
    }
    std::fs::write(dir.path().join(".spiceinit"), "set ngbehavior=psa\n").unwrap();
    let report = validate::validate(&path, &sorted, &opts).unwrap_or_else(|e| panic!("{e}"));
    assert!(report.pass, "{}", validate::table(&report));
}

#[test]
fn a_one_percent_resistor_error_is_caught() {
    require_ngspice();
    let path = root().join("netlists/rc_lowpass_step.cir");
    let text = std::fs::read_to_string(&path).unwrap();
    let bad = text.replace("R1 in out 1k", "R1 in out 1.01k");
    assert_ne!(bad, text, "the fixture has R1 in out 1k");
    let el = pipeline::elaborate_text("bad.cir", &path, bad, &FsLoader)
        .ok()
        .unwrap();
    let built = kausal::build::build(&el.circuit, Default::default());
    let sorted = pipeline::sort_built(el, built, &SortOptions::default())
        .ok()
        .unwrap();
    let report = validate::validate(&path, &sorted, &validate::Options::default()).unwrap();
    assert!(!report.pass, "a 1 % error in R1 must fail validation");
    let failed: Vec<&str> = report
        .signals
        .iter()
        .filter(|s| !s.pass)
        .map(|s| s.name.as_str())
        .collect();
    assert!(failed.contains(&"v(out)"), "{failed:?}");
    assert!(validate::table(&report).contains("FAIL"));
}

/// A stand-in for ngspice: a shell script.
fn fake(dir: &Path, name: &str, body: &str) -> String {
    let p = dir.join(name);
    let mut f = std::fs::File::create(&p).unwrap();
    writeln!(f, "#!/bin/sh\n{body}").unwrap();
    drop(f);
    let mut perm = std::fs::metadata(&p).unwrap().permissions();
    std::os::unix::fs::PermissionsExt::set_mode(&mut perm, 0o755);
    std::fs::set_permissions(&p, perm).unwrap();
    p.display().to_string()
}

/// An ngspice that never finishes (it can shrink its step without end at a
/// tight reltol) is stopped at the time limit with a clear error, not waited
/// for: `validate` would hang on 3 of 60 fuzzed RLC circuits.
#[test]
fn an_ngspice_that_never_finishes_is_stopped() {
    let dir = tempfile::tempdir().unwrap();
    let net = root().join("netlists/rc_lowpass_step.cir");
    let stuck = fake(dir.path(), "stuck-ngspice", "echo running; exec sleep 60");
    let started = std::time::Instant::now();
    let e = validate::exec_within(&stuck, &net, None, std::time::Duration::from_secs(1))
        .err()
        .expect("stopped");
    assert!(matches!(e, ValidateError::TimedOut { .. }), "{e}");
    assert!(
        started.elapsed() < std::time::Duration::from_secs(20),
        "waited {:?}",
        started.elapsed()
    );
    assert!(e.to_string().contains("did not finish within 1 s"), "{e}");
}

#[test]
fn missing_failing_and_garbled_ngspice_give_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let net = root().join("netlists/rc_lowpass_step.cir");
    let missing = dir.path().join("no-such-ngspice").display().to_string();
    match validate::run_program(&missing, &net, None) {
        Err(ValidateError::Missing { .. }) => {}
        other => panic!("{other:?}"),
    }
    let e = validate::run_program(&missing, &net, None).unwrap_err();
    assert!(e.to_string().contains("apt-get install ngspice"), "{e}");
    // ngspice fails: its own message is shown.
    let failing = fake(
        dir.path(),
        "failing",
        "echo 'Error: unknown subckt: x9' >&2; exit 1",
    );
    match validate::run_program(&failing, &net, None) {
        Err(ValidateError::Failed { output, .. }) => {
            assert!(output.contains("unknown subckt"), "{output}")
        }
        other => panic!("{other:?}"),
    }
    // ngspice succeeds but writes nothing.
    let silent = fake(dir.path(), "silent", "exit 0");
    assert!(matches!(
        validate::run_program(&silent, &net, None),
        Err(ValidateError::NoData { .. })
    ));
    // ngspice writes a garbled raw file ($3 is the raw path: -b -r PATH netlist).
    let garbled = fake(
        dir.path(),
        "garbled",
        "printf 'Title: x\\nNo. Variables: 2\\nNo. Points: 9\\nBinary:\\n' > \"$3\"",
    );
    match validate::run_program(&garbled, &net, None) {
        Err(ValidateError::Malformed(m)) => assert!(!m.is_empty()),
        other => panic!("{other:?}"),
    }
}

/// An interrupted `kausal validate` stops its ngspice and removes ngspice's
/// scratch directory (netlist, raw file) from `$TMPDIR`: it leaves neither.
#[cfg(unix)]
#[test]
fn an_interrupted_validation_leaves_no_scratch() {
    require_ngspice();
    let work = tempfile::tempdir().unwrap();
    let tmp = work.path().join("tmp");
    std::fs::create_dir(&tmp).unwrap();
    let net = work.path().join("long.cir");
    // ngspice needs seconds on it: long enough to be interrupted anywhere.
    std::fs::write(&net, kausal::generate::rc_ladder(50_000)).unwrap();
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_kausal"))
        .args(["validate", net.to_str().unwrap()])
        .env("TMPDIR", &tmp)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let entries = || std::fs::read_dir(&tmp).unwrap().count();
    let status = crate::interrupt_when(
        &mut child,
        || entries() > 0,
        std::time::Duration::from_secs(120),
        "a scratch directory in $TMPDIR",
    );
    assert_eq!(status.code(), Some(130), "{status:?}");
    // A surviving ngspice would write its raw file into a recreated path or
    // fail; either way nothing may reappear.
    std::thread::sleep(std::time::Duration::from_millis(300));
    let left: Vec<_> = std::fs::read_dir(&tmp)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name())
        .collect();
    assert!(left.is_empty(), "left in $TMPDIR: {left:?}");
}

/// Every grounded voltage source of the suite has ngspice's value at each
/// of ngspice's own time points, corners and period boundaries included
/// (the waveform formulas of vsrcload.c; a PULSE whose TR + PW + TF overruns
/// its period holds V2 at TD + PER, which the comparison's one-sided corners
/// would not see).
#[test]
fn source_waveforms_match_ngspice_at_its_time_points() {
    use kausal::elab::{ElementKind, GROUND};
    require_ngspice();
    let mut checked = 0;
    for path in netlists() {
        let name = stem(&path);
        if NGSPICE_CANNOT.contains(&name.as_str()) {
            continue;
        }
        let sorted = pipeline::sort(&path, &FsLoader, &SortOptions::default())
            .ok()
            .unwrap_or_else(|| panic!("{name} sorts"));
        let c = &sorted.elaborated.circuit;
        let sources: Vec<(String, kausal::ir::Waveform)> = c
            .elements
            .values()
            .filter_map(|e| match &e.kind {
                ElementKind::VSource { wave } if e.nodes[1] == GROUND && e.nodes[0] != GROUND => {
                    Some((format!("v({})", c.nodes[e.nodes[0]].name), (**wave).clone()))
                }
                _ => None,
            })
            .collect();
        if sources.is_empty() {
            continue;
        }
        let raw = validate::run_ngspice(&path, None).unwrap_or_else(|e| panic!("{name}: {e}"));
        for (vector, wave) in &sources {
            let Some(k) = raw.names.iter().position(|n| n == vector) else {
                continue;
            };
            for (&t, &v) in raw.time.iter().zip(&raw.data[k]) {
                let ours = wave.eval(t, 0);
                assert!(
                    (ours - v).abs() <= 1e-9 * (1.0 + v.abs()),
                    "{name} {vector} at t = {t:e}: kausal's source gives {ours}, ngspice {v}"
                );
            }
            checked += 1;
        }
    }
    assert!(checked >= 20, "only {checked} sources compared");
}

/// Where ngspice's trapezoidal rule gives up at every reference tolerance
/// ("timestep too small"), the reference is Gear's method, and the report
/// says so (a stand-in ngspice refuses any run without `method=gear`).
#[test]
fn the_reference_falls_back_to_gear() {
    require_ngspice();
    let (ok, out) = validate_with_stand_in(
        "trap-fails",
        &format!("if grep -q 'method=gear' \"$net\"; then exec ngspice \"$@\"; fi\n{TOO_SMALL}"),
    );
    assert!(ok, "{out}");
    assert!(out.contains("at reltol=1e-8 with method=gear"), "{out}");
    assert!(out.contains("verdict: pass"), "{out}");
}

/// `kausal validate` on `netlists/rc_lowpass_step.cir` with a stand-in
/// ngspice running `body` (`$net` is the netlist it was given).
fn validate_with_stand_in(name: &str, body: &str) -> (bool, String) {
    let dir = tempfile::tempdir().unwrap();
    let stand_in = fake(
        dir.path(),
        name,
        &format!("for a; do net=\"$a\"; done\n{body}"),
    );
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_kausal"))
        .args(["validate", "netlists/rc_lowpass_step.cir"])
        .current_dir(root())
        .env("KAUSAL_NGSPICE", &stand_in)
        .output()
        .unwrap();
    let text = format!(
        "{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

const TOO_SMALL: &str = "echo 'doAnalyses: TRAN:  Timestep too small; time = 1e-9' >&2\nexit 1";

/// Where ngspice's steps collapse at picovolt and attocoulomb floors with
/// either method (digital MOS decks: `mux8`, `cram`), the reference is run at
/// ngspice's default absolute tolerances with the tight reltol, and the
/// report says so.
#[test]
fn the_reference_falls_back_to_ngspices_default_absolute_tolerances() {
    require_ngspice();
    let (ok, out) = validate_with_stand_in(
        "floors-fail",
        &format!("if grep -q 'vntol=1e-12' \"$net\"; then {TOO_SMALL}; fi\nexec ngspice \"$@\""),
    );
    assert!(ok, "{out}");
    assert!(
        out.contains("at reltol=1e-8 and ngspice's default abstol=1e-12 vntol=1e-6 chgtol=1e-14"),
        "{out}"
    );
    assert!(out.contains("verdict: pass"), "{out}");
}

/// Where no tight ngspice run finishes but its default run does, the
/// reference is kausal's own run at a hundredth of its tolerances, confirmed
/// by ngspice's default run; a default run that disagrees (here a stand-in
/// that simulates R1 10 % high) confirms nothing and the verdict fails.
#[test]
fn the_reference_falls_back_to_kausal_confirmed_by_ngspice() {
    require_ngspice();
    let (ok, out) = validate_with_stand_in(
        "tight-fails",
        &format!("if grep -q 'reltol=' \"$net\"; then {TOO_SMALL}; fi\nexec ngspice \"$@\""),
    );
    assert!(ok, "{out}");
    assert!(
        out.contains(
            "against kausal at rtol=1.00e-9 atol=1.00e-11 V, cross-checked by ngspice's default run"
        ),
        "{out}"
    );
    assert!(out.contains("Timestep too small"), "{out}");
    assert!(out.contains("confirmed\n"), "{out}");
    assert!(out.contains("verdict: pass"), "{out}");

    let (ok, out) = validate_with_stand_in(
        "tight-fails-default-wrong",
        &format!(
            "if grep -q 'reltol=' \"$net\"; then {TOO_SMALL}; fi\nsed -i 's/^R1 in out 1k/R1 in out 1.1k/' \"$net\"\nexec ngspice \"$@\""
        ),
    );
    assert!(!ok, "{out}");
    assert!(out.contains("NOT confirmed"), "{out}");
    assert!(out.contains("verdict: FAIL"), "{out}");
}

/// ngspice reads kausal's binary raw file (`-o FILE.raw`) as its own: its
/// `load` gives the point count and, printed to its full precision, the
/// values kausal wrote.
#[test]
fn ngspice_loads_a_kausal_raw_file() {
    require_ngspice();
    let dir = tempfile::tempdir().unwrap();
    let raw = dir.path().join("bridge.raw");
    let bridge = root().join("netlists/diode_bridge.cir");
    let r = crate::kausal(&["sim", bridge.to_str().unwrap(), "-o", raw.to_str().unwrap()]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let ours = validate::raw::parse(&std::fs::read(&raw).unwrap()).unwrap();
    let last = ours.time.len() - 1;
    let (name, col) = (&ours.names[0], &ours.data[0]);
    let deck = dir.path().join("load.sp");
    std::fs::write(
        &deck,
        format!(
            "load a kausal raw file\n.control\nset numdgt=15\nload {}\n\
             print length(time) {name}[{}] {name}[{last}]\n.endc\n.end\n",
            raw.display(),
            last / 2,
        ),
    )
    .unwrap();
    let out = std::process::Command::new(validate::ngspice_program())
        .arg("-b")
        .arg(&deck)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    let value = |key: &str| -> f64 {
        let line = text
            .lines()
            .find(|l| l.trim_start().starts_with(key))
            .unwrap_or_else(|| panic!("no `{key}` in ngspice's output:\n{text}"));
        line.split('=').nth(1).unwrap().trim().parse().unwrap()
    };
    assert_eq!(value("length(time)"), ours.time.len() as f64);
    for k in [last / 2, last] {
        let theirs = value(&format!("{name}[{k}]"));
        assert!(
            (theirs - col[k]).abs() <= 1e-13 * col[k].abs().max(1e-12),
            "{name}[{k}]: ngspice read {theirs}, kausal wrote {}",
            col[k]
        );
    }
}
