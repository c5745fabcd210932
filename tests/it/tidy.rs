//! Tidy checks over the source tree: the layers of the crate import only
//! downwards, and every module says what it owns.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The library's top-level modules, lowest layer first. A module may use
/// only modules listed before it.
const LAYERS: &[&str] = &[
    "diag",
    "ir",
    "numeric",
    "front",
    "io",
    "elab",
    "build",
    "analysis",
    "back",
    "tape",
    "pipeline",
    "bondgraph",
    "sim",
    "validate",
    "generate",
    "bench",
    "error",
];

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The top-level module a file of `src/` belongs to (`None` for the crate
/// root and the binary).
fn module_of(src: &Path, file: &Path) -> Option<String> {
    let rel = file.strip_prefix(src).unwrap();
    let first = rel.components().next()?.as_os_str().to_str()?.to_string();
    let name = first.trim_end_matches(".rs").to_string();
    (rel.components().count() > 1 || first.ends_with(".rs"))
        .then_some(name)
        .filter(|n| LAYERS.contains(&n.as_str()))
}

/// The modules a source text refers to as `crate::name`, outside comments.
fn crate_refs(text: &str) -> BTreeSet<String> {
    let mut refs = BTreeSet::new();
    for line in text.lines() {
        let code = line.split("//").next().unwrap_or("");
        let mut rest = code;
        while let Some(at) = rest.find("crate::") {
            let tail = &rest[at + "crate::".len()..];
            let name: String = tail
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            // `crate::name!` is a macro, not a module.
            if !tail[name.len()..].starts_with('!') {
                refs.insert(name);
            }
            rest = tail;
        }
    }
    refs
}

/// Each module's uses of other modules: module → used module → a file that
/// uses it.
fn module_graph(src: &Path) -> BTreeMap<String, BTreeMap<String, PathBuf>> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let mut graph: BTreeMap<String, BTreeMap<String, PathBuf>> = BTreeMap::new();
    for file in files {
        let Some(module) = module_of(src, &file) else {
            continue;
        };
        let text = std::fs::read_to_string(&file).unwrap();
        for used in crate_refs(&text) {
            if used != module {
                graph
                    .entry(module.clone())
                    .or_default()
                    .entry(used)
                    .or_insert_with(|| file.clone());
            }
        }
    }
    graph
}

/// Imports that go up or across the layers, as messages.
fn upward_imports(graph: &BTreeMap<String, BTreeMap<String, PathBuf>>) -> Vec<String> {
    let rank = |m: &str| LAYERS.iter().position(|l| *l == m);
    let mut bad = Vec::new();
    for (module, uses) in graph {
        for (used, file) in uses {
            match (rank(module), rank(used)) {
                (Some(a), Some(b)) if b < a => {}
                (Some(_), Some(_)) => bad.push(format!(
                    "{} imports `{used}`, which is not below `{module}` in LAYERS",
                    file.display()
                )),
                _ => bad.push(format!(
                    "{}: `{module}` or `{used}` is missing from LAYERS",
                    file.display()
                )),
            }
        }
    }
    bad
}

#[test]
fn layers_import_only_downwards() {
    let src = super::root().join("src");
    let graph = module_graph(&src);
    assert!(graph.contains_key("sim"), "the scan found the modules");
    let bad = upward_imports(&graph);
    assert!(
        bad.is_empty(),
        "import cycle or layer breach:\n{}",
        bad.join("\n")
    );
    // Every top-level module of the library is in LAYERS.
    let lib = std::fs::read_to_string(src.join("lib.rs")).unwrap();
    for line in lib.lines() {
        if let Some(m) = line.strip_prefix("pub mod ") {
            let m = m.trim_end_matches(';');
            assert!(LAYERS.contains(&m), "module `{m}` is missing from LAYERS");
        }
    }
}

#[test]
fn the_layer_check_catches_a_cycle() {
    // sim uses tape; tape using sim closes a cycle.
    let mut graph = BTreeMap::new();
    graph.insert(
        "sim".to_string(),
        BTreeMap::from([("tape".to_string(), PathBuf::from("src/sim/mod.rs"))]),
    );
    assert!(upward_imports(&graph).is_empty());
    graph.insert(
        "tape".to_string(),
        BTreeMap::from([("sim".to_string(), PathBuf::from("src/tape/mod.rs"))]),
    );
    let bad = upward_imports(&graph);
    assert_eq!(bad.len(), 1, "{bad:?}");
    assert!(bad[0].contains("src/tape/mod.rs imports `sim`"), "{bad:?}");
    let refs = crate_refs("use crate::ir::X; // crate::sim\ncrate::entity_id!(A);");
    assert_eq!(refs, BTreeSet::from(["ir".to_string()]));
}

#[test]
fn every_module_says_what_it_owns() {
    let mut files = Vec::new();
    rust_files(&super::root().join("src"), &mut files);
    let mut missing: Vec<String> = files
        .iter()
        .filter(|f| {
            let text = std::fs::read_to_string(f).unwrap();
            // Runtime preludes of generated code are included as text.
            !text.starts_with("//!") && !f.to_string_lossy().contains("prelude")
        })
        .map(|f| f.display().to_string())
        .collect();
    missing.sort();
    assert!(
        missing.is_empty(),
        "files without a `//!` module doc:\n{}",
        missing.join("\n")
    );
}

/// Diagnostic codes are written once, in `diag/codes.rs`; everywhere else
/// names them by constant, and every code of the table is used.
#[test]
fn diagnostic_codes_live_in_one_table() {
    let src = super::root().join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let is_code =
        |w: &str| w.len() == 5 && w.starts_with('K') && w[1..].bytes().all(|b| b.is_ascii_digit());
    let mut literals = Vec::new();
    let mut uses = String::new();
    for file in &files {
        let text = std::fs::read_to_string(file).unwrap();
        if file.ends_with("diag/codes.rs") {
            continue;
        }
        uses.push_str(&text);
        for (n, line) in text.lines().enumerate() {
            let code = line.split("//").next().unwrap_or("");
            for piece in code.split('"').skip(1).step_by(2) {
                if is_code(piece) {
                    literals.push(format!("{}:{}: \"{piece}\"", file.display(), n + 1));
                }
            }
        }
    }
    assert!(
        literals.is_empty(),
        "diagnostic codes written as literals (name them from kausal::diag::codes):\n{}",
        literals.join("\n")
    );
    let table = std::fs::read_to_string(src.join("diag/codes.rs")).unwrap();
    let unused: Vec<&str> = table
        .lines()
        .filter_map(|l| l.trim().split_once(" = \""))
        .map(|(name, _)| name)
        .filter(|name| !uses.contains(&format!("codes::{name}")))
        .collect();
    assert!(unused.is_empty(), "codes nothing emits: {unused:?}");
    assert!(kausal::diag::codes::ALL.len() > 70);
}
