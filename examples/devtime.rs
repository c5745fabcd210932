use kausal::pipeline::{self, SortOptions};
use std::time::Instant;
fn main() {
    let text = std::fs::read_to_string("netlists/hard/rectifier_big_cap.cir").unwrap();
    let s = pipeline::sort_text("x.cir", text, &SortOptions::default())
        .ok()
        .unwrap();
    let p = &s.system().diodes[0];
    let n = 10_000_000;
    let mut acc = 0.0;
    let c = Instant::now();
    for k in 0..n {
        let v = -5.0 + (k % 1000) as f64 * 1e-3;
        acc += p.charge(v)[1];
    }
    println!(
        "charge reverse {:.1} ns",
        c.elapsed().as_secs_f64() / n as f64 * 1e9
    );
    let c = Instant::now();
    for k in 0..n {
        let v = 0.7 + (k % 1000) as f64 * 1e-5;
        acc += p.charge(v)[1];
    }
    println!(
        "charge forward {:.1} ns",
        c.elapsed().as_secs_f64() / n as f64 * 1e9
    );
    let c = Instant::now();
    for k in 0..n {
        let v = -5.0 + (k % 1000) as f64 * 1e-3;
        acc += p.current(v)[0];
    }
    println!(
        "current reverse {:.1} ns",
        c.elapsed().as_secs_f64() / n as f64 * 1e9
    );
    let c = Instant::now();
    for k in 0..n {
        let v = 0.7 + (k % 1000) as f64 * 1e-5;
        acc += p.current(v)[0];
    }
    println!(
        "current forward {:.1} ns {}",
        c.elapsed().as_secs_f64() / n as f64 * 1e9,
        acc > 0.0
    );
}
