//! Colour-edge sorting on generated circuits of 10^3 to 10^6 equations:
//! RC ladders (no loops: pure colouring), resistor meshes with one
//! capacitor per node (algebraic loops: BLT and tearing), and index
//! reduction of inductor cutset chains and parallel capacitors (each
//! Pantelides round handles every independent constraint).

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use kausal::analysis::{self, StructureGraph};
use kausal::build::{self, Options};
use kausal::io::FsLoader;
use kausal::ir::EquationSystem;
use kausal::pipeline;
use std::path::Path;

#[global_allocator]
static ALLOC: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn system(text: String) -> EquationSystem {
    let el = pipeline::elaborate_text("gen.cir", Path::new("gen.cir"), text, &FsLoader)
        .ok()
        .expect("generated circuits elaborate");
    build::build(&el.circuit, Options::default()).system
}

fn ladders(c: &mut Criterion) {
    // As the CLI runs (see `io::no_huge_pages`).
    kausal::io::no_huge_pages();
    let mut g = c.benchmark_group("sort rc_ladder");
    g.sample_size(10);
    // Five equations per section.
    for n_eqs in [1_000usize, 10_000, 100_000, 1_000_000] {
        let sys = system(kausal::generate::rc_ladder(n_eqs / 5));
        g.throughput(Throughput::Elements(sys.eqs.len() as u64));
        g.bench_with_input(BenchmarkId::new("causalize", n_eqs), &sys, |b, sys| {
            b.iter(|| analysis::causalize(sys, analysis::Options::default()).expect("ladders sort"))
        });
        g.bench_with_input(BenchmarkId::new("graph only", n_eqs), &sys, |b, sys| {
            b.iter(|| StructureGraph::build(sys))
        });
        let c = analysis::causalize(&sys, analysis::Options::default()).unwrap();
        // The first run adds the solved forms to the arena; the timed runs
        // find them there (as a second schedule of the same system would).
        let mut sys = sys;
        g.bench_function(BenchmarkId::new("schedule", n_eqs), |b| {
            b.iter(|| analysis::schedule(&mut sys, &c))
        });
    }
    g.finish();
}

fn meshes(c: &mut Criterion) {
    // As the CLI runs (see `io::no_huge_pages`).
    kausal::io::no_huge_pages();
    let mut g = c.benchmark_group("sort rc_mesh");
    g.sample_size(10);
    for side in [10usize, 30, 100, 300] {
        let sys = system(kausal::generate::rc_mesh(side, side));
        g.throughput(Throughput::Elements(sys.eqs.len() as u64));
        g.bench_with_input(
            BenchmarkId::new("causalize", sys.eqs.len()),
            &sys,
            |b, sys| {
                b.iter(|| {
                    analysis::causalize(sys, analysis::Options::default()).expect("meshes sort")
                })
            },
        );
    }
    g.finish();
}

fn index_reduction(c: &mut Criterion) {
    kausal::io::no_huge_pages();
    let mut g = c.benchmark_group("sort index reduction");
    g.sample_size(10);
    for n in [300usize, 3_000, 30_000] {
        for (name, text) in [
            (
                "inductor cutset chain",
                kausal::generate::inductor_cutset_chain(n),
            ),
            (
                "parallel capacitors",
                kausal::generate::parallel_capacitors(n),
            ),
        ] {
            let sys = system(text);
            g.throughput(Throughput::Elements(n as u64));
            g.bench_with_input(BenchmarkId::new(name, n), &sys, |b, sys| {
                b.iter(|| {
                    analysis::reduce_index(sys, &Default::default())
                        .expect("index reduction succeeds")
                })
            });
        }
    }
    g.finish();
}

criterion_group!(benches, ladders, meshes, index_reduction);
criterion_main!(benches);
