//! Fuzz the whole `sim` path: sort the text, then simulate it with a small
//! step budget, so that every input is bounded. Any input must give
//! diagnostics or waveforms, never a panic; every error of parsing,
//! elaboration and sorting must point into the netlist (a span).
#![no_main]

use kausal::diag::{ToDiagnostic, render};
use kausal::pipeline::{SortOptions, sort_text};
use kausal::sim::{Options, simulate_to};
use libfuzzer_sys::fuzz_target;

/// Steps a run may take: the run ends with K0409-style "no progress"
/// (TooManySteps) after this many.
const MAX_STEPS: usize = 20_000;
/// Output rows a run may write. kausal only warns (K0295) about a `.tran`
/// of more than 10^8 points; the sink stops the run after this many rows
/// (the run then ends with a write error), so a fine TSTEP stays bounded.
const MAX_ROWS: usize = 100_000;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    match sort_text("fuzz.cir", text.to_string(), &SortOptions::default()) {
        Err(f) => {
            for d in &f.diagnostics {
                let _ = render(&f.sources, d, Default::default());
                assert!(
                    !d.is_error() || d.span().is_some(),
                    "error without a location: {} {}",
                    d.code,
                    d.message
                );
            }
        }
        Ok(sorted) => {
            let sources = &sorted.elaborated.sources;
            for d in &sorted.elaborated.warnings {
                let _ = render(sources, d, Default::default());
            }
            for e in &sorted.faults {
                let _ = render(sources, &e.to_diagnostic(), Default::default());
            }
            let opts = Options {
                max_steps: Some(MAX_STEPS),
                ..Default::default()
            };
            let mut rows = 0usize;
            let mut sink = |_t: f64, _row: &[f64]| -> std::io::Result<()> {
                rows += 1;
                if rows > MAX_ROWS {
                    return Err(std::io::Error::other("fuzz: row cap"));
                }
                Ok(())
            };
            match simulate_to(&sorted, &opts, &mut sink) {
                Ok(w) => {
                    for d in &w.warnings {
                        let _ = render(sources, d, Default::default());
                    }
                }
                Err(e) => {
                    let _ = render(sources, &e.to_diagnostic(), Default::default());
                }
            }
        }
    }
});
