//! A whole transient of the free-step RC ladder (`generate::rc_ladder_free`,
//! 10^4 and 10^5 sections, 1 kΩ and 1 nF, `.tran 20u 1m`): kausal's BDF in process
//! against a hand-written BDF2 loop of the same circuit over the same span and
//! the same number of steps. The loop is the floor of an implicit method on
//! this circuit: the tridiagonal matrix C·(3/2)/h + G is factored once (fixed
//! step), and each step forms its right-hand side, solves, and measures its
//! error estimate (corrector minus predictor), with nothing else. Both are
//! reported per state per step (`issue 23`: within 10×).

use criterion::{Criterion, criterion_group, criterion_main};
use kausal::pipeline::{self, SortOptions};
use kausal::sim::{self, Method};
use std::hint::black_box;
use std::time::Instant;

#[global_allocator]
static ALLOC: mimalloc::MiMalloc = mimalloc::MiMalloc;

const R: f64 = 1e3;
const C: f64 = 1e-9;
const SPAN: f64 = 1e-3;

/// The ladder's source, `PULSE(0 1 0 1u 1u 0.5m 1m)`, over one period.
fn vin(t: f64) -> f64 {
    let (tr, tf, pw) = (1e-6, 1e-6, 0.5e-3);
    if t < tr {
        t / tr
    } else if t < tr + pw {
        1.0
    } else if t < tr + pw + tf {
        1.0 - (t - tr - pw) / tf
    } else {
        0.0
    }
}

/// Fixed-step BDF2 (its first step backward Euler) on the ladder, `steps`
/// steps over `SPAN`; returns the last state and the largest error estimate
/// so that nothing is optimised away.
struct Bdf2 {
    /// The LU factors of the BDF2 matrix (Thomas): the modified upper
    /// diagonal and the reciprocal pivots. The first step's (backward Euler)
    /// factors are the `be_` pair.
    upper: Vec<f64>,
    inv_pivot: Vec<f64>,
    be_upper: Vec<f64>,
    be_inv_pivot: Vec<f64>,
    h: f64,
    n: usize,
}

impl Bdf2 {
    fn new(n: usize, steps: usize) -> Self {
        let h = SPAN / steps as f64;
        let (upper, inv_pivot) = Self::factor(n, 1.5 * C / h);
        let (be_upper, be_inv_pivot) = Self::factor(n, C / h);
        Self {
            upper,
            inv_pivot,
            be_upper,
            be_inv_pivot,
            h,
            n,
        }
    }

    /// Thomas factors of `diag_c + G` (G: the ladder's conductance matrix,
    /// node k joined to k-1 and k+1 through R, node 1 to the source).
    fn factor(n: usize, diag_c: f64) -> (Vec<f64>, Vec<f64>) {
        let g = 1.0 / R;
        let mut upper = vec![0.0; n];
        let mut inv_pivot = vec![0.0; n];
        let mut prev_upper = 0.0;
        for k in 0..n {
            let diag = diag_c + if k + 1 < n { 2.0 * g } else { g };
            let off = -g;
            let pivot = diag - off * prev_upper;
            inv_pivot[k] = 1.0 / pivot;
            upper[k] = if k + 1 < n { off / pivot } else { 0.0 };
            prev_upper = upper[k];
        }
        (upper, inv_pivot)
    }

    /// Solves in place with the given factors (forward, then back).
    fn solve(upper: &[f64], inv_pivot: &[f64], x: &mut [f64]) {
        let n = x.len();
        let off = -1.0 / R;
        let mut prev = 0.0;
        for k in 0..n {
            x[k] = (x[k] - off * prev) * inv_pivot[k];
            prev = x[k];
        }
        for k in (0..n - 1).rev() {
            x[k] -= upper[k] * x[k + 1];
        }
    }

    fn run(&self, steps: usize) -> (f64, f64) {
        // The far nodes go subnormal as in kausal's run, which flushes them
        // to zero (`numeric::subnormal`); the floor runs in the same mode.
        let _flush = kausal::numeric::subnormal::flush_subnormals();
        let (h, n) = (self.h, self.n);
        let mut y_old = vec![0.0; n];
        let mut y = vec![0.0; n];
        let mut x = vec![0.0; n];
        let mut worst = 0.0f64;
        for step in 1..=steps {
            let t = step as f64 * h;
            let src = vin(t) / R;
            if step == 1 {
                for k in 0..n {
                    x[k] = C / h * y[k];
                }
                x[0] += src;
                Self::solve(&self.be_upper, &self.be_inv_pivot, &mut x);
            } else {
                for k in 0..n {
                    x[k] = C / h * (2.0 * y[k] - 0.5 * y_old[k]);
                }
                x[0] += src;
                Self::solve(&self.upper, &self.inv_pivot, &mut x);
            }
            // The error estimate: corrector minus the linear predictor
            // 2·y_n − y_{n−1}, as a weighted RMS norm (rtol 1e-3, atol 1e-9).
            let mut sum = 0.0;
            for k in 0..n {
                let pred = 2.0 * y[k] - y_old[k];
                let w = 1e-3 * x[k].abs() + 1e-9;
                let e = (x[k] - pred) / w;
                sum += e * e;
            }
            worst = worst.max((sum / n as f64).sqrt());
            std::mem::swap(&mut y_old, &mut y);
            std::mem::swap(&mut y, &mut x);
        }
        (y[0], worst)
    }
}

fn step(c: &mut Criterion) {
    kausal::io::no_huge_pages();
    for n in [10_000, 100_000] {
        ladder(c, n);
    }
}

fn ladder(c: &mut Criterion, n: usize) {
    let text = kausal::generate::rc_ladder_free(n);
    let sorted = pipeline::sort_text("ladder.cir", text, &SortOptions::default())
        .ok()
        .expect("the ladder sorts");
    let opts = sim::Options {
        method: Some(Method::Bdf),
        rtol: Some(1e-3),
        ..Default::default()
    };
    let w = sim::simulate(&sorted, &opts).expect("the ladder simulates");
    let steps = w.stats.steps;
    assert_eq!(w.stats.states, n);

    // The loop is right: node 1 follows the source's pulse as kausal has it.
    let hand = Bdf2::new(n, steps);
    let (n1_end, _) = hand.run(steps);
    let k_n1 = w.names.iter().position(|n| n == "v(n1)").expect("v(n1)");
    let kausal_end = *w.data[k_n1].last().expect("rows");
    assert!(
        (n1_end - kausal_end).abs() < 5e-3,
        "hand loop v(n1)(1 ms) = {n1_end}, kausal {kausal_end}"
    );

    // One timed pass of each for the per-state per-step figure (criterion's
    // own figures follow).
    let t0 = Instant::now();
    let w = sim::simulate(&sorted, &opts).expect("runs");
    let kausal_s = t0.elapsed().as_secs_f64();
    let t0 = Instant::now();
    black_box(hand.run(steps));
    let hand_s = t0.elapsed().as_secs_f64();
    let per = |s: f64| s / (steps as f64 * n as f64) * 1e9;
    eprintln!(
        "rc_ladder_free {n}: {steps} steps; kausal bdf (whole simulate, {} LU factorizations) {:.1} ns/state/step, hand-written BDF2 {:.2} ns/state/step, ratio {:.0}×",
        w.stats.lu_factorizations,
        per(kausal_s),
        per(hand_s),
        kausal_s / hand_s
    );

    let mut g = c.benchmark_group(format!("transient rc_ladder_free {n}"));
    g.sample_size(10);
    g.bench_function("kausal bdf rtol 1e-3", |b| {
        b.iter(|| sim::simulate(&sorted, &opts).expect("runs"))
    });
    g.bench_function("hand-written BDF2, same steps", |b| {
        b.iter(|| black_box(hand.run(steps)))
    });
    g.finish();
}

criterion_group!(benches, step);
criterion_main!(benches);
