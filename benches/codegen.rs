//! Generated source of a 10^4-section RC ladder: how long rustc (-O) and
//! cc (-O2) take to compile it (target: under 10 s).

use criterion::{Criterion, criterion_group, criterion_main};
use kausal::back::codegen::{self, Lang};
use kausal::pipeline::{self, SortOptions};
use std::process::Command;

fn compile(c: &mut Criterion) {
    // As the CLI runs (see `io::no_huge_pages`).
    kausal::io::no_huge_pages();
    let n = 10_000usize;
    let text = kausal::generate::rc_ladder(n);
    let s = pipeline::sort_text("ladder.cir", text, &SortOptions::default())
        .ok()
        .expect("the ladder sorts");
    let dir = tempfile::tempdir().expect("a temporary directory");
    let mut g = c.benchmark_group("compile generated rc_ladder 1e4");
    g.sample_size(10);
    for (lang, file, cmd, args) in [
        (
            Lang::Rust,
            "gen.rs",
            "rustc",
            &[
                "--edition",
                "2021",
                "--crate-type",
                "lib",
                "-O",
                "-o",
                "gen.rlib",
            ][..],
        ),
        (Lang::C, "gen.c", "cc", &["-O2", "-c", "-o", "gen.o"][..]),
    ] {
        let src = codegen::emit(s.system(), &s.schedule, lang);
        std::fs::write(dir.path().join(file), &src).expect("source written");
        g.bench_function(cmd, |b| {
            b.iter(|| {
                let out = Command::new(cmd)
                    .args(args)
                    .arg(file)
                    .current_dir(dir.path())
                    .output()
                    .expect("the compiler runs");
                assert!(
                    out.status.success(),
                    "{cmd}: {}",
                    String::from_utf8_lossy(&out.stderr)
                );
            })
        });
    }
    g.finish();
}

criterion_group!(benches, compile);
criterion_main!(benches);
