//! One evaluation of f(t, y) on an RC ladder of 10^5 sections: the compiled
//! tape against a hand-written Rust loop computing the same derivatives.

use criterion::{Criterion, criterion_group, criterion_main};
use kausal::pipeline::{self, SortOptions};
use kausal::tape;

#[global_allocator]
static ALLOC: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn eval(c: &mut Criterion) {
    // As the CLI runs (see `io::no_huge_pages`).
    kausal::io::no_huge_pages();
    let n = 100_000usize;
    let text = kausal::generate::rc_ladder(n);
    let s = pipeline::sort_text("ladder.cir", text, &SortOptions::default())
        .ok()
        .expect("the ladder sorts");
    let t = tape::compile(s.system(), &s.schedule, &[]);
    assert_eq!(t.states.len(), n);
    let y: Vec<f64> = (0..n).map(|k| (k as f64 * 0.37).sin()).collect();
    let mut dy = vec![0.0; n];
    let mut regs = t.registers();
    let time = 0.5;
    // The hand-written derivative of the same ladder (see generate::rc_ladder).
    let r = 1e3;
    let cap: Vec<f64> = (1..=n).map(|k| [1e-9, 1e-8, 1e-7, 1e-6][k % 4]).collect();
    let vin = 1.0; // PULSE(0 1 1u 1u 1u 1 2) at t = 0.5
    let hand = |y: &[f64], dy: &mut [f64]| {
        for k in 0..n {
            let left = if k == 0 { vin } else { y[k - 1] };
            let out = if k + 1 < n {
                (y[k] - y[k + 1]) / r
            } else {
                0.0
            };
            dy[k] = ((left - y[k]) / r - out) / cap[k];
        }
    };
    // Both compute the same thing.
    t.rhs(&mut regs, time, &y, &mut dy).unwrap();
    let mut dh = vec![0.0; n];
    hand(&y, &mut dh);
    for k in 0..n {
        assert!(
            (dy[k] - dh[k]).abs() <= 1e-9 * dh[k].abs().max(1.0),
            "{k}: {} vs {}",
            dy[k],
            dh[k]
        );
    }
    let mut g = c.benchmark_group("f(t, y) rc_ladder 1e5");
    g.bench_function("kausal tape", |b| {
        b.iter(|| t.rhs(&mut regs, time, &y, &mut dy).unwrap())
    });
    g.bench_function("hand-written loop", |b| b.iter(|| hand(&y, &mut dh)));
    g.finish();
}

criterion_group!(benches, eval);
criterion_main!(benches);
