//! Integration tests, one module per stage. Fixtures live in `netlists/`,
//! snapshots in `goldens/<stage>/`.

mod codegen;
mod equations;
pub mod errors;
mod front;
mod hard;
mod simulate;
mod singular;
mod sort;
mod validate;

use std::path::{Path, PathBuf};

/// The repository root.
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Every `netlists/*.cir` file, sorted.
pub fn netlists() -> Vec<PathBuf> {
    cir_files("netlists")
}

/// Every `*.cir` file of a directory of the repository, sorted.
pub fn cir_files(dir: &str) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(root().join(dir))
        .unwrap_or_else(|e| panic!("{dir}/: {e}"))
        .map(|e| e.expect("readable dir entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "cir"))
        .collect();
    v.sort();
    v
}

/// insta settings that keep snapshots in `goldens/<stage>/`.
pub fn goldens(stage: &str) -> insta::Settings {
    let mut s = insta::Settings::clone_current();
    s.set_snapshot_path(root().join("goldens").join(stage));
    s.set_prepend_module_to_snapshot(false);
    s.set_omit_expression(true);
    s
}

/// The file name without extension, for snapshot names.
pub fn stem(p: &Path) -> String {
    p.file_stem().unwrap().to_string_lossy().into_owned()
}
