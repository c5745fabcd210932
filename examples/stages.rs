//! The in-process cost of each stage of `kausal sim` on one netlist:
//! parse and elaborate, build the equations, sort, prepare (compile the
//! tape), and run (operating point and integration).
//!
//! `cargo run --release --example stages -- NETLIST RTOL`
//!
//! One run each; the stages' split of a whole process, where `kausal bench`
//! and `/usr/bin/time` give the whole.

use kausal::pipeline::{self, SortOptions};
use kausal::sim;
use std::time::Instant;

#[global_allocator]
static ALLOC: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() {
    kausal::io::no_huge_pages();
    let args: Vec<String> = std::env::args().collect();
    let path = std::path::Path::new(&args[1]);
    let rtol: f64 = args[2].parse().unwrap();
    let t0 = Instant::now();
    let el = pipeline::elaborate_file(path, &kausal::io::FsLoader)
        .ok()
        .unwrap();
    let t1 = Instant::now();
    let built = kausal::build::build(&el.circuit, Default::default());
    let t2 = Instant::now();
    let s = pipeline::sort_built(el, built, &SortOptions::default())
        .ok()
        .unwrap();
    let t3 = Instant::now();
    let opts = sim::Options {
        rtol: Some(rtol),
        ..Default::default()
    };
    let p = sim::prepare(&s, &opts).unwrap();
    let t4 = Instant::now();
    let w = sim::run_prepared(&s, p, &opts, None).unwrap();
    let t5 = Instant::now();
    let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
    println!(
        "parse+elab {:.1} build {:.1} sort {:.1} prepare {:.1} run {:.1} ms; steps {} f {} LU {}",
        ms(t0, t1),
        ms(t1, t2),
        ms(t2, t3),
        ms(t3, t4),
        ms(t4, t5),
        w.stats.steps,
        w.stats.rhs_evals,
        w.stats.lu_factorizations
    );
}
