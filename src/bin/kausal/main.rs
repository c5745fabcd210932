//! The `kausal` command line: the argument grammar, the dispatch to one
//! module per subcommand, and the exit code. All the work is done by the
//! library's stages; all the text is written by [`output`] and [`error`].

mod args;
mod bench;
mod bondgraph;
mod check;
mod codegen;
mod equations;
mod error;
mod output;
mod sim;
mod sort;
mod validate;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// mimalloc: building the IR of a big circuit is allocation-bound, and it
/// halves that time against the system allocator.
#[global_allocator]
static ALLOC: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// mimalloc's `mi_option_purge_delay` (its index in `mi_option_e`, the same
/// in its v2 and v3 headers; libmimalloc-sys names the options around it,
/// `eager_commit_delay` = 14 and `use_numa_nodes` = 16, but not this one).
const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

/// mimalloc's default purge delay, in milliseconds.
const DEFAULT_PURGE_DELAY_MS: std::ffi::c_long = 10;

/// Until [`return_freed_memory`], return freed memory to the system at
/// once, not 10 ms later: `kausal sim` builds and sorts its equations, frees
/// what the tape no longer needs and then its equation system and circuit,
/// and with the delay much of it stayed resident beside what came next (a
/// 10^4-section ladder peaked at 48 MB, 10^5 at 299 MB; 34 and 245 MB
/// with this). It costs system time (0.4 → 0.75 s at 10^5 sections: the
/// sort's temporary buffers given back and faulted in again); purging only
/// at the big releases saved half as much (268 MB).
pub(crate) fn purge_freed_memory_at_once() {
    set_purge_delay(0);
}

/// Return what has been freed so far, and purge with mimalloc's delay again
/// from here on: `kausal sim` calls it once it has released its equation
/// system, as the integrator starts (whose restarts free and take the same
/// buffers again).
pub(crate) fn return_freed_memory() {
    // SAFETY: mi_collect takes a flag and only walks mimalloc's heaps of the
    // calling thread, the only one that allocates here.
    unsafe { libmimalloc_sys::mi_collect(true) }
    set_purge_delay(DEFAULT_PURGE_DELAY_MS);
}

fn set_purge_delay(ms: std::ffi::c_long) {
    // SAFETY: mi_option_set takes an option index and a value and only
    // stores the value in mimalloc's option table.
    unsafe { libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, ms) }
}

#[derive(Parser)]
#[command(
    name = "kausal",
    version,
    about = "SPICE netlists to causal equations: sorted, simulated, checked against ngspice"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// The subcommands, in the order `kausal --help` lists them.
#[derive(Subcommand)]
enum Command {
    /// Parse and check a netlist, through the structural analysis (loops of
    /// sources, singular circuits); print problems only.
    Check(check::Args),
    /// Print the acausal equations, unknowns, states and incidence matrix.
    Equations(equations::Args),
    /// Simulate with kausal and with ngspice, compare signal by signal.
    Validate(validate::Args),
    /// Speed against error: kausal's solvers and ngspice's integrators at a
    /// range of tolerances, errors against a tight reference, in one run.
    Bench(bench::Args),
    /// Generate standalone source of f(t, y) (and J·w) from the sorted equations.
    Codegen(codegen::Args),
    /// Sort the equations into causal assignments (colour-edge algorithm),
    /// tear algebraic loops, and print the sorted listing.
    Sort(sort::Args),
    /// Simulate the netlist's `.tran` and write the waveforms (CSV).
    Sim(sim::Args),
    /// The circuit as a bond graph with causal strokes (SCAP), the equations
    /// read off it, and (--check) their agreement with the sorted equations.
    Bondgraph(bondgraph::Args),
}

fn main() -> ExitCode {
    kausal::io::no_huge_pages();
    kausal::io::remove_pending_on_interrupt();
    let cli = Cli::parse();
    run(cli).unwrap_or_else(error::report)
}

/// Run one subcommand: its exit code, or the error that stopped it (which
/// [`error::report`] prints).
fn run(cli: Cli) -> Result<ExitCode, error::Error> {
    match cli.command {
        Command::Check(args) => check::run(args),
        Command::Equations(args) => equations::run(args),
        Command::Validate(args) => validate::run(args),
        Command::Bench(args) => bench::run(args),
        Command::Codegen(args) => codegen::run(args),
        Command::Sort(args) => sort::run(args),
        Command::Sim(args) => sim::run(args),
        Command::Bondgraph(args) => bondgraph::run(args),
    }
}
