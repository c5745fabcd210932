//! Fuzz the front end, elaboration, equation building and the causalizer:
//! any input must give diagnostics or results, never a panic.
#![no_main]

use kausal::build::{self, Kvl, Options};
use kausal::io::FsLoader;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = std::path::Path::new("fuzz.cir");
    match kausal::pipeline::elaborate_text("fuzz.cir", path, text.to_string(), &FsLoader) {
        Ok(el) => {
            for kvl in [Kvl::Nodes, Kvl::Loops] {
                let built = build::build(&el.circuit, Options { kvl, alias: true });
                if let Ok(c) = kausal::analysis::causalize(&built.system, Default::default()) {
                    let _ = kausal::analysis::schedule(&built.system, &c);
                }
            }
        }
        Err(f) => {
            for d in &f.diagnostics {
                let _ = kausal::diag::render(&f.sources, d, Default::default());
            }
        }
    }
});
