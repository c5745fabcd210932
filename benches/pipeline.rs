//! Parse + elaborate + build on generated RC ladders (10^3 to 10^5
//! sections), whole and stage by stage.

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use kausal::build::{self, Options};
use kausal::io::FsLoader;
use kausal::{elab, front, pipeline};
use std::path::Path;

#[global_allocator]
static ALLOC: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn front_to_equations(c: &mut Criterion) {
    // As the CLI runs (see `io::no_huge_pages`).
    kausal::io::no_huge_pages();
    let mut g = c.benchmark_group("parse+build rc_ladder");
    g.sample_size(10);
    for n in [1_000usize, 10_000, 100_000] {
        let text = kausal::generate::rc_ladder(n);
        g.throughput(Throughput::Elements(n as u64));
        g.bench_with_input(BenchmarkId::new("all", n), &text, |b, text| {
            b.iter(|| {
                let el = pipeline::elaborate_text(
                    "ladder.cir",
                    Path::new("ladder.cir"),
                    text.clone(),
                    &FsLoader,
                )
                .ok()
                .expect("ladder elaborates");
                let built = build::build(&el.circuit, Options::default());
                assert!(built.system.eqs.len() > 4 * n);
                built
            })
        });
        let (sources, _) = front::load(
            "ladder.cir",
            Path::new("ladder.cir"),
            text.clone(),
            &FsLoader,
        );
        g.bench_with_input(BenchmarkId::new("parse", n), &sources, |b, sources| {
            b.iter(|| front::parse(sources).0.stmts.len())
        });
        let (ast, _) = front::parse(&sources);
        g.bench_with_input(BenchmarkId::new("elaborate", n), &ast, |b, ast| {
            b.iter(|| elab::elaborate(ast).0.elements.len())
        });
        let (circuit, _) = elab::elaborate(&ast);
        g.bench_with_input(BenchmarkId::new("build", n), &circuit, |b, circuit| {
            b.iter(|| build::build(circuit, Options::default()).system.eqs.len())
        });
    }
    g.finish();
}

criterion_group!(benches, front_to_equations);
criterion_main!(benches);
