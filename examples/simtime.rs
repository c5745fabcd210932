use kausal::pipeline::{self, SortOptions};
use kausal::sim::{self, Method};
use std::time::Instant;

#[global_allocator]
static ALLOC: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let path = &args[1];
    let method = match args[2].as_str() {
        "bdf" => Method::Bdf,
        "circuit" => Method::Circuit,
        "tr-bdf2" => Method::TrBdf2,
        _ => panic!(),
    };
    let rtol: f64 = args[3].parse().unwrap();
    let reps: usize = args.get(4).map(|x| x.parse().unwrap()).unwrap_or(20);
    let text = std::fs::read_to_string(path).unwrap();
    let s = pipeline::sort_text("x.cir", text, &SortOptions::default())
        .ok()
        .unwrap();
    let opts = sim::Options {
        method: Some(method),
        rtol: Some(rtol),
        ..Default::default()
    };
    let mut times = Vec::new();
    let mut w = None;
    for _ in 0..reps {
        let c = Instant::now();
        w = Some(sim::simulate(&s, &opts).unwrap());
        times.push(c.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    let w = w.unwrap();
    let st = &w.stats;
    println!(
        "min {:.3} ms median {:.3} ms; steps {} rej {} f {} J {} LU {}",
        times[0],
        times[reps / 2],
        st.steps,
        st.rejected,
        st.rhs_evals,
        st.jacobians,
        st.lu_factorizations
    );
}
