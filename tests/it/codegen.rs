//! Generated Rust and C compile (rustc, cc) and compute the same f(t, y) and
//! J(t, y)·w as the in-process evaluator on random inputs.

use std::io::Write;
use std::process::{Command, Stdio};

use kausal::back::codegen::{self, Lang};
use kausal::io::FsLoader;
use kausal::pipeline::{self, SortOptions};
use kausal::tape;

use crate::root;

const RUST_MAIN: &str = r#"
fn main() {
    use std::io::Read;
    let mut s = String::new();
    std::io::stdin().read_to_string(&mut s).unwrap();
    let nums: Vec<f64> = s.split_whitespace().map(|x| x.parse().unwrap()).collect();
    let (mut v, mut dv) = (vec![0.0; N_VARS], vec![0.0; N_VARS]);
    for chunk in nums.chunks(2 * N_STATES + 1) {
        let (y, w) = chunk[1..].split_at(N_STATES);
        let (mut dy, mut jw) = (vec![0.0; N_STATES], vec![0.0; N_STATES]);
        rhs(chunk[0], y, &P, &mut v, &mut dy);
        jac_mul(chunk[0], y, &P, &mut v, &mut dv, w, &mut jw);
        let out: Vec<String> = dy.iter().chain(&jw).map(|x| format!("{x:e}")).collect();
        println!("{}", out.join(" "));
    }
}
"#;

const C_MAIN: &str = r#"
#include <stdio.h>
int main(void) {
    static double v[N_VARS], dv[N_VARS], y[N_STATES + 1], w[N_STATES + 1], dy[N_STATES + 1], jw[N_STATES + 1];
    double t;
    while (scanf("%lf", &t) == 1) {
        for (int k = 0; k < N_STATES; k++) if (scanf("%lf", &y[k]) != 1) return 1;
        for (int k = 0; k < N_STATES; k++) if (scanf("%lf", &w[k]) != 1) return 1;
        rhs(t, y, P, v, dy);
        jac_mul(t, y, P, v, dv, w, jw);
        for (int k = 0; k < N_STATES; k++) printf("%.17e ", dy[k]);
        for (int k = 0; k < N_STATES; k++) printf("%.17e%s", jw[k], k + 1 < N_STATES ? " " : "\n");
    }
    return 0;
}
"#;

fn compile(lang: Lang, src: &str, dir: &std::path::Path) -> std::path::PathBuf {
    let (file, bin) = match lang {
        Lang::Rust => (dir.join("gen.rs"), dir.join("gen_rs")),
        Lang::C => (dir.join("gen.c"), dir.join("gen_c")),
    };
    std::fs::write(&file, src).unwrap();
    let out = match lang {
        Lang::Rust => Command::new("rustc")
            .args(["--edition", "2021", "-D", "warnings", "-O", "-o"])
            .arg(&bin)
            .arg(&file)
            .output(),
        // Strict ISO C: M_PI, M_E and empty initializers are not in it.
        Lang::C => Command::new("cc")
            .args([
                "-std=c99",
                "-pedantic-errors",
                "-Wall",
                "-Werror",
                "-O2",
                "-o",
            ])
            .arg(&bin)
            .arg(&file)
            .arg("-lm")
            .output(),
    }
    .expect("the compiler runs");
    assert!(
        out.status.success(),
        "{lang:?} does not compile:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    bin
}

#[test]
fn generated_rust_and_c_agree_with_the_evaluator() {
    let dir = tempfile::tempdir().unwrap();
    for file in [
        "rc_ladder_5",
        "seed_c_algebraic_loop",
        "seed_d_singular",
        "diode_bridge",
        "pwl_source",
        // Repeated and delayed: the time folding in the generated code.
        "pwl_repeat_rc",
        // SFFM, differentiated by index reduction (a capacitor across it).
        "sffm_source",
        "transformer_k",
        "sallen_key_lowpass",
        // B sources: comparisons and choices, and a torn nonlinear loop.
        "b_limiter",
        "b_multiplier",
        // Time functions differentiated by index reduction: der(t).
        "b_slope_at_start",
        // Transistors: junction functions, the base charge, IRB's base
        // resistance, a PNP mirror.
        "bjt_ce_amp",
        "bjt_diff_pair",
        // A JFET's drain current: regions as choices, both channel types.
        "jfet_amp",
        // MOSFETs: Meyer's capacitances over the frame of the moment, level
        // 3's short-channel current, terminal resistances.
        "mos_current_mirror",
        "mos3_inverter_chain",
        // Level 2: Baum's quartic in closed form (atan, cos, ln, exp, the
        // mobility factor's power) and its choices.
        "mos2_inverter_chain",
        // Generated: its repeated sections become loops in the source.
        "rlc_ladder_60",
    ] {
        let s = if file == "rlc_ladder_60" {
            let text = kausal::generate::rlc_ladder(60);
            pipeline::sort_text(file, text, &SortOptions::default())
                .ok()
                .unwrap()
        } else {
            let path = root().join(format!("netlists/{file}.cir"));
            pipeline::sort(&path, &FsLoader, &SortOptions::default())
                .ok()
                .unwrap()
        };
        let sys = s.system();
        let t = tape::compile(sys, &s.schedule, &[]);
        let n = t.states.len();
        // Random states around plausible magnitudes, a few times.
        let mut seed = 0x9e3779b97f4a7c15u64;
        let mut rand = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let mut input = String::new();
        let mut expected = Vec::new();
        let mut regs = t.registers();
        let mut dregs = vec![0.0; t.n_regs];
        // A state's typical size: junction charges are ~1e-13 C (a few
        // tenths of a volt on picofarad junctions).
        let scale: Vec<f64> = t
            .states
            .iter()
            .map(|&v| {
                if sys.vars[v].kind == kausal::ir::VarKind::Charge {
                    1e-13
                } else {
                    1.0
                }
            })
            .collect();
        for _ in 0..5 {
            let time = (rand() + 1.0) * 1e-3;
            let y: Vec<f64> = scale.iter().map(|s| rand() * s).collect();
            let w: Vec<f64> = scale.iter().map(|s| rand() * s).collect();
            let (mut dy, mut jw) = (vec![0.0; n], vec![0.0; n]);
            t.rhs(&mut regs, time, &y, &mut dy).unwrap();
            t.jac_mul(&mut regs, &mut dregs, time, &y, &w, &mut jw, None)
                .unwrap();
            input.push_str(&format!("{time:e}"));
            for v in y.iter().chain(&w) {
                input.push_str(&format!(" {v:e}"));
            }
            input.push('\n');
            dy.extend(jw);
            expected.push(dy);
        }
        for lang in [Lang::Rust, Lang::C] {
            let mut src = codegen::emit(sys, &s.schedule, lang);
            assert_eq!(
                src.contains(" assignments, "),
                file == "rlc_ladder_60",
                "{file} {lang:?}: loops exactly for the repeated sections"
            );
            src.push_str(if lang == Lang::Rust {
                RUST_MAIN
            } else {
                C_MAIN
            });
            let bin = compile(lang, &src, dir.path());
            let mut child = Command::new(&bin)
                .stdin(Stdio::piped())
                .stdout(Stdio::piped())
                .spawn()
                .unwrap();
            child
                .stdin
                .take()
                .unwrap()
                .write_all(input.as_bytes())
                .unwrap();
            let out = child.wait_with_output().unwrap();
            let text = String::from_utf8_lossy(&out.stdout);
            let rows: Vec<Vec<f64>> = text
                .lines()
                .map(|l| l.split_whitespace().map(|x| x.parse().unwrap()).collect())
                .collect();
            assert_eq!(rows.len(), expected.len(), "{file} {lang:?}: {text}");
            for (row, exp) in rows.iter().zip(&expected) {
                assert_eq!(row.len(), 2 * n, "{file} {lang:?}: f and J·w");
                for (k, (a, b)) in row.iter().zip(exp).enumerate() {
                    let what = if k < n { "f" } else { "J·w" };
                    let scale = a.abs().max(b.abs()).max(1e-9);
                    assert!(
                        (a - b).abs() <= 1e-8 * scale,
                        "{file} {lang:?}: {what}[{}]: generated {a:e}, evaluator {b:e}",
                        k % n
                    );
                }
            }
        }
    }
}

/// The evaluator's forward-mode `J v` agrees with central differences of `f`
/// on circuits with each kind of block: affine loops (factored once) and
/// scalar junction-charge inversions.
#[test]
fn evaluator_jacobian_matches_finite_differences() {
    for (file, affine, scalar) in [
        ("diode_bridge", 1, 4),
        ("diode_halfwave", 0, 1),
        ("diode_clipper", 1, 2),
        ("rc_ladder_5", 0, 0),
        ("b_limiter", 0, 0),
    ] {
        let path = root().join(format!("netlists/{file}.cir"));
        let s = pipeline::sort(&path, &FsLoader, &SortOptions::default())
            .ok()
            .unwrap();
        let sys = s.system();
        let t = tape::compile(sys, &s.schedule, &[]);
        let n_affine = t.blocks.iter().filter(|b| b.constant_jacobian).count();
        let n_scalar = t
            .blocks
            .iter()
            .filter(|b| !b.constant_jacobian && b.tears.len() == 1)
            .count();
        assert_eq!((n_affine, n_scalar), (affine, scalar), "{file}: blocks");
        // Every scalar block here is a junction-charge inversion (Halley).
        let n_charge = t
            .blocks
            .iter()
            .filter(|b| b.charge_inverse.is_some())
            .count();
        assert_eq!(n_charge, scalar, "{file}: charge inversions");
        let n = t.states.len();
        let mut regs = t.registers();
        let mut dregs = vec![0.0; t.n_regs];
        let y: Vec<f64> = t
            .states
            .iter()
            .enumerate()
            .map(|(k, &v)| {
                let x = 0.3 + 0.1 * k as f64;
                if sys.vars[v].kind == kausal::ir::VarKind::Charge {
                    x * 1e-11
                } else {
                    x
                }
            })
            .collect();
        let time = 1.3e-3;
        // The inversions hold to rounding after an evaluation, from the
        // cold start and again warm.
        for _ in 0..2 {
            let mut f = vec![0.0; n];
            t.rhs(&mut regs, time, &y, &mut f).unwrap();
            for b in &t.blocks {
                if let Some(ci) = b.charge_inverse {
                    let x = regs[b.tears[0]];
                    let q = regs[ci.target];
                    let [qx, c, _] = t.diodes[ci.diode as usize].charge(x);
                    assert!(
                        (qx - q).abs() <= 1e-12 * c * (1.0 + x.abs()),
                        "{file}: Q({x}) = {qx}, wanted {q}"
                    );
                }
            }
        }
        let unit = |j: usize| {
            let mut v = vec![0.0; n];
            v[j] = 1.0;
            v
        };
        // The columns of one Jacobian, blocks solved once and kept.
        let mut cache = tape::TangentCache::default();
        let kept: Vec<Vec<f64>> = (0..n)
            .map(|j| {
                let mut jv = vec![0.0; n];
                t.jac_mul(
                    &mut regs,
                    &mut dregs,
                    time,
                    &y,
                    &unit(j),
                    &mut jv,
                    Some(&mut cache),
                )
                .unwrap();
                jv
            })
            .collect();
        // All columns in one multi-direction pass, and f beside them.
        let cols: Vec<usize> = (0..n).collect();
        let (mut all, mut f_all, mut f) = (vec![0.0; n * n], vec![0.0; n], vec![0.0; n]);
        let mut scratch = Vec::new();
        t.jacobian_columns(
            &mut regs,
            &mut scratch,
            time,
            &y,
            &cols,
            &mut all,
            &mut f_all,
        )
        .unwrap();
        t.rhs(&mut regs, time, &y, &mut f).unwrap();
        for (a, b) in f_all.iter().zip(&f) {
            assert!(
                (a - b).abs() <= 1e-12 * b.abs(),
                "{file}: f = {a} beside the Jacobian, {b} alone"
            );
        }
        for j in 0..n {
            for i in 0..n {
                assert!(
                    (all[i * n + j] - kept[j][i]).abs() <= 1e-12 * kept[j][i].abs().max(1e-300),
                    "{file}: J[{i}][{j}] = {} in one pass, {} by columns",
                    all[i * n + j],
                    kept[j][i]
                );
            }
        }
        for j in 0..n {
            let mut jv = vec![0.0; n];
            t.jac_mul(&mut regs, &mut dregs, time, &y, &unit(j), &mut jv, None)
                .unwrap();
            for i in 0..n {
                assert!(
                    (kept[j][i] - jv[i]).abs() <= 1e-12 * jv[i].abs().max(1e-300),
                    "{file}: J[{i}][{j}] = {} with kept blocks, {} solved afresh",
                    kept[j][i],
                    jv[i]
                );
            }
            let h = 1e-6 * y[j].abs().max(1e-12);
            let (mut yp, mut ym) = (y.clone(), y.clone());
            yp[j] += h;
            ym[j] -= h;
            let (mut fp, mut fm) = (vec![0.0; n], vec![0.0; n]);
            t.rhs(&mut regs, time, &yp, &mut fp).unwrap();
            t.rhs(&mut regs, time, &ym, &mut fm).unwrap();
            for i in 0..n {
                let fd = (fp[i] - fm[i]) / (2.0 * h);
                let scale = fd.abs().max(jv[i].abs()).max(1e-30);
                assert!(
                    (fd - jv[i]).abs()
                        <= 1e-5 * scale + 1e-9 * jv.iter().fold(0.0f64, |m, x| m.max(x.abs())),
                    "{file}: J[{i}][{j}] = {} by tangents, {fd} by differences",
                    jv[i]
                );
            }
        }
    }
}
