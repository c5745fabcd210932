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

/// Return freed memory to the system at once from here on, not 10 ms
/// later (`kausal sim` only): a simulation frees its causalization, its
/// schedule, then its equation system and circuit just before the
/// integrator allocates, and with the delay they were resident together (a
/// 10^4-section ladder peaked at 48 MB against 34 MB, 10^5 at 299 MB
/// against 254 MB, its time unchanged within noise). Not for every
/// command: `kausal sort` of 10^6 equations, which frees and allocates as
/// it goes, took 10 to 15 % longer with it (system time 0.7 → 0.9 s).
pub(crate) fn purge_freed_memory_at_once() {
    // SAFETY: mi_option_set takes an option index and a value and only
    // stores the value in mimalloc's option table.
    unsafe { libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, 0) }
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
