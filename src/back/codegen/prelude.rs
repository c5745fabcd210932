//! The runtime of generated Rust source: the source waveforms (`pulse`,
//! `sine`, `sffm`, `expo`, `pwl`, with their time derivatives), ngspice's level-1
//! diode, a dense solve, the damped Newton of algebraic loops and the
//! implicit tangents of their unknowns.
//!
//! `codegen::rust` copies everything below the marker line into every
//! generated file, byte for byte: generated code calls these functions by
//! name and argument order. Tests compile this file as a module
//! (`prelude_check`), so that `cargo clippy --all-targets` checks it as code;
//! only those lints are allowed here that generated code allows anyway.
#![allow(dead_code)]
#![allow(clippy::too_many_arguments)]
// ---- everything below is copied into generated source ----

fn pulse(t: f64, o: u8, v1: f64, v2: f64, td: f64, tr: f64, tf: f64, pw: f64, per: f64) -> f64 {
    if t < td { return if o == 0 { v1 } else { 0.0 }; }
    let mut tt = t - td;
    if per > 0.0 && (if o == 0 { tt > per } else { tt >= per }) { tt -= (tt / per).floor() * per; }
    let edge = |a: f64, b: f64, d: f64, x: f64| { let s = (b - a) / d;
        (a + (b - a) * (x / d), if s.is_finite() { s } else { 0.0 }) };
    let (val, s) = if tt < tr { edge(v1, v2, tr, tt) }
        else if tt < tr + pw { (v2, 0.0) }
        else if tt < tr + pw + tf { edge(v2, v1, tf, tt - tr - pw) }
        else { (v1, 0.0) };
    match o { 0 => val, 1 => s, _ => 0.0 }
}

fn sine(t: f64, o: u8, vo: f64, va: f64, freq: f64, td: f64, theta: f64, phase: f64) -> f64 {
    let ph = phase * std::f64::consts::PI / 180.0;
    if t < td { return if o == 0 { vo + va * ph.sin() } else { 0.0 }; }
    let s = t - td;
    let w = 2.0 * std::f64::consts::PI * freq;
    let (mut cr, mut ci) = (1.0, 0.0);
    for _ in 0..o { let nr = -cr * theta - ci * w; let ni = cr * w - ci * theta; cr = nr; ci = ni; }
    let d = va * (-theta * s).exp() * (cr * (w * s + ph).sin() + ci * (w * s + ph).cos());
    if o == 0 { vo + d } else { d }
}

fn sffm(t: f64, o: u8, vo: f64, va: f64, fc: f64, mdi: f64, fs: f64) -> f64 {
    // Taylor coefficients of sin(wc·t + mdi·sin(ws·t)) up to order o (at
    // most 31; a higher order gives NaN), on the stack.
    if o > 31 { return f64::NAN; }
    let (n, wc, ws) = (o as usize + 1, 2.0 * std::f64::consts::PI * fc, 2.0 * std::f64::consts::PI * fs);
    let (mut si, mut ci, mut phi) = ([0.0; 32], [0.0; 32], [0.0; 32]);
    (si[0], ci[0]) = (ws * t).sin_cos();
    for k in 1..n { si[k] = ws * ci[k - 1] / k as f64; ci[k] = -ws * si[k - 1] / k as f64; }
    for k in 0..n { phi[k] = mdi * si[k] + if k == 0 { wc * t } else if k == 1 { wc } else { 0.0 }; }
    let (mut y, mut z) = ([0.0; 32], [0.0; 32]);
    (y[0], z[0]) = phi[0].sin_cos();
    for k in 1..n {
        let (mut sy, mut sz) = (0.0, 0.0);
        for j in 1..=k { sy += j as f64 * phi[j] * z[k - j]; sz -= j as f64 * phi[j] * y[k - j]; }
        y[k] = sy / k as f64; z[k] = sz / k as f64;
    }
    let d = va * y[n - 1] * (1..n).map(|k| k as f64).product::<f64>();
    if o == 0 { vo + d } else { d }
}

fn expo(t: f64, o: u8, v1: f64, v2: f64, td1: f64, tau1: f64, td2: f64, tau2: f64) -> f64 {
    let mut val = if o == 0 { v1 } else { 0.0 };
    let term = |t0: f64, tau: f64, amp: f64| { let e = (-(t - t0) / tau).exp();
        if o == 0 { amp * (1.0 - e) } else { -amp * (-1.0 / tau).powi(o as i32) * e } };
    if t >= td1 { val += term(td1, tau1, v2 - v1); }
    if t >= td2 { val += term(td2, tau2, v1 - v2); }
    val
}

fn pwl(t: f64, o: u8, pts: &[(f64, f64)]) -> f64 {
    if pts.is_empty() { return 0.0; }
    if t.is_nan() { return f64::NAN; }
    if t < pts[0].0 { return if o == 0 { pts[0].1 } else { 0.0 }; }
    let k = pts.partition_point(|q| q.0 <= t);
    if k >= pts.len() { return if o == 0 { pts[pts.len() - 1].1 } else { 0.0 }; }
    let ((ta, ya), (tb, yb)) = (pts[k - 1], pts[k]);
    let s = if tb > ta { (yb - ya) / (tb - ta) } else { 0.0 };
    match o { 0 => ya + s * (t - ta), 1 => s, _ => 0.0 }
}

/// ngspice's level-1 diode: [id, id', id''] or [q, q', q''].
#[allow(clippy::too_many_arguments)]
fn diode(part: u8, o: u8, v: f64, is: f64, vte: f64, bv: f64, g: f64, cjo: f64, vj: f64, m: f64, fc: f64, tt: f64) -> f64 {
    let vlin = 50.0 * vte;
    let id = if v > vlin { let e = (vlin / vte).exp(); [is * (e * (1.0 + (v - vlin) / vte) - 1.0) + g * v, is * e / vte + g, 0.0] }
        else if v >= -3.0 * vte { let e = (v / vte).exp(); [is * (e - 1.0) + g * v, is * e / vte + g, is * e / (vte * vte)] }
        else if v >= -bv { let a = 3.0 * vte / (v * std::f64::consts::E); let arg = a * a * a;
            [-is * (1.0 + arg) + g * v, 3.0 * is * arg / v + g, -12.0 * is * arg / (v * v)] }
        else { let e = (-(bv + v) / vte).exp(); [-is * e + g * v, is * e / vte + g, -is * e / (vte * vte)] };
    if part == 0 { return id[o as usize]; }
    let mut q = [tt * id[0], tt * id[1], tt * id[2]];
    if cjo != 0.0 {
        let d = fc * vj;
        if v < d { let arg = 1.0 - v / vj; let sarg = (-m * arg.ln()).exp();
            q[0] += vj * cjo * (1.0 - arg * sarg) / (1.0 - m); q[1] += cjo * sarg; q[2] += cjo * m / vj * sarg / arg; }
        else { let f1 = vj * (1.0 - (1.0 - fc).powf(1.0 - m)) / (1.0 - m); let f2 = (1.0 - fc).powf(1.0 + m);
            let f3 = 1.0 - fc * (1.0 + m); let c = cjo / f2;
            q[0] += cjo * f1 + c * (f3 * (v - d) + m / (2.0 * vj) * (v * v - d * d)); q[1] += c * (f3 + m * v / vj); q[2] += c * m / vj; }
    }
    q[o as usize]
}

/// Solve a x = b in place (`b` becomes x): Gaussian elimination with partial pivoting.
fn lin_solve(n: usize, a: &mut [f64], b: &mut [f64]) {
    for k in 0..n {
        let piv = (k..n).max_by(|&i, &j| a[i * n + k].abs().total_cmp(&a[j * n + k].abs())).unwrap_or(k);
        for j in 0..n { a.swap(k * n + j, piv * n + j); }
        b.swap(k, piv);
        for i in k + 1..n { let q = a[i * n + k] / a[k * n + k]; for j in k..n { a[i * n + j] -= q * a[k * n + j]; } b[i] -= q * b[k]; }
    }
    for k in (0..n).rev() { let mut s = b[k]; for j in k + 1..n { s -= a[k * n + j] * b[j]; } b[k] = s / a[k * n + k]; }
}

/// A loop's tangent residual: values, tangents in and out, residual tangents.
type TanFn<'a> = dyn FnMut(&[f64], &mut [f64], &mut [f64]) + 'a;

/// Damped Newton on `tears` (dense solve). The Jacobian is exact: `tan`
/// gives the residuals' tangents along one tear at a time (a finite
/// difference loses a femtofarad capacitance's column to rounding).
fn newton(
    tears: &[usize],
    v: &mut [f64],
    f: &mut dyn FnMut(&mut [f64], &mut [f64]),
    tan: &mut TanFn<'_>,
) {
    let n = tears.len();
    let (mut r, mut r1) = (vec![0.0; n], vec![0.0; n]);
    let mut dv = vec![0.0; v.len()];
    let norm = |r: &[f64]| r.iter().map(|x| x * x).sum::<f64>();
    for _ in 0..100 {
        f(v, &mut r);
        let base = norm(&r);
        if base == 0.0 { return; }
        let mut a = vec![0.0; n * n];
        for j in 0..n {
            dv[tears[j]] = 1.0;
            tan(v, &mut dv, &mut r1);
            dv[tears[j]] = 0.0;
            for i in 0..n { a[i * n + j] = r1[i]; }
        }
        let mut dx = r.clone();
        lin_solve(n, &mut a, &mut dx);
        let x0: Vec<f64> = tears.iter().map(|&t| v[t]).collect();
        let mut lambda = 1.0;
        loop {
            for j in 0..n { v[tears[j]] = x0[j] - lambda * dx[j]; }
            f(v, &mut r1);
            if norm(&r1) < base || lambda < 1e-8 { break; }
            lambda *= 0.5;
        }
        if dx.iter().zip(&x0).all(|(d, x)| (lambda * d).abs() <= 1e-14 * (1.0 + x.abs())) { return; }
    }
}

/// The tangents of a loop's unknowns `tears` by implicit differentiation:
/// `f(dv, dr)` writes the tangents inside the loop and of its residuals,
/// which are affine in the tears' tangents; they are solved for dr = 0.
/// The coefficients come from a scratch with no input tangents (a
/// difference with the inputs' residual would cancel them to rounding).
fn tangent_solve(tears: &[usize], dv: &mut [f64], f: &mut dyn FnMut(&mut [f64], &mut [f64])) {
    let n = tears.len();
    let (mut b, mut c, mut a) = (vec![0.0; n], vec![0.0; n], vec![0.0; n * n]);
    for &k in tears { dv[k] = 0.0; }
    f(dv, &mut b);
    let mut z = vec![0.0; dv.len()];
    for j in 0..n {
        z[tears[j]] = 1.0;
        f(&mut z, &mut c);
        z[tears[j]] = 0.0;
        for i in 0..n { a[i * n + j] = c[i]; }
    }
    lin_solve(n, &mut a, &mut b);
    for j in 0..n { dv[tears[j]] = -b[j]; }
    f(dv, &mut c);
}
