//! Integration tests, one module per stage. Fixtures live in `netlists/`,
//! snapshots in `goldens/<stage>/`.

mod bondgraph;
mod codegen;
mod equations;
pub mod errors;
mod front;
mod hard;
mod hostile;
mod simulate;
mod singular;
mod sort;
mod tidy;
mod validate;

use std::path::{Path, PathBuf};

/// Wait (at most `limit`) until `ready`, with `child` still running, then
/// send it SIGINT and reap it.
#[cfg(unix)]
pub fn interrupt_when(
    child: &mut std::process::Child,
    ready: impl Fn() -> bool,
    limit: std::time::Duration,
    what: &str,
) -> std::process::ExitStatus {
    let waited = std::time::Instant::now();
    while !ready() {
        assert!(
            child.try_wait().unwrap().is_none(),
            "it ended before it was interrupted"
        );
        assert!(waited.elapsed() < limit, "{what} did not happen");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    // SAFETY: a plain kill(2) of our own child, which has not been reaped.
    let killed = unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGINT) };
    assert_eq!(killed, 0);
    child.wait().unwrap()
}

/// The repository root.
/// Run the `kausal` binary with `args` to completion.
pub fn kausal(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_kausal"))
        .args(args)
        .output()
        .expect("the kausal binary runs")
}

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
