//! Grammar-aware fuzzing of `sort` + `sim`, in process.
//!
//! Takes the suite's netlists (and earlier fuzz findings) as seeds, mutates
//! them at the token and line level (extreme or malformed numbers, swapped
//! nodes, other element letters, duplicated, deleted and reordered lines,
//! inserted directives, other `.tran` arguments, K couplings with k = 1),
//! and runs each mutant through `pipeline::sort_text` and `sim::simulate_to`
//! under `catch_unwind`, with a step budget and a cap on output rows.
//!
//! ```text
//! cargo run --release --example fuzz_grammar -- N [--seed S] [--out DIR]
//!     [--seeds DIR]... [--max-steps K] [--slow SECS] [--hang SECS]
//! ```
//!
//! Deterministic given the seed (a xorshift generator). Prints the inputs
//! run, accepted, refused (by code), simulation results (by code), panics,
//! errors without a location, the slowest input and those over `--slow`
//! seconds; writes every finding to `--out` (default `/work/fuzz-out/grammar`).
//! An input that runs past `--hang` seconds is written there as `hang-*.cir`
//! and ends the run (exit code 3).

use std::collections::BTreeMap;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use kausal::diag::{ToDiagnostic, render};
use kausal::pipeline::{SortOptions, sort_text};
use kausal::sim::{Options, simulate_to};

/// xorshift64* (deterministic, no dependency).
struct Rng(u64);

impl Rng {
    fn new(seed: u64) -> Rng {
        Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
    fn next(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            (self.next() % n as u64) as usize
        }
    }
    fn pick<'a, T>(&mut self, xs: &'a [T]) -> &'a T {
        &xs[self.below(xs.len())]
    }
    fn chance(&mut self, num: u64, den: u64) -> bool {
        self.next() % den < num
    }
    /// A number of random sign and magnitude 10^-40..10^40, in SPICE text.
    fn magnitude(&mut self) -> String {
        let e = self.below(81) as i32 - 40;
        let m = 1.0 + (self.below(9000) as f64) / 1000.0;
        let sign = if self.chance(1, 4) { "-" } else { "" };
        format!("{sign}{m}e{e}")
    }
}

/// Numbers that are not numbers (or not finite).
const MALFORMED: &[&str] = &[
    "1k1k",
    "1..2",
    "1e",
    "e5",
    "0x10",
    "1_000",
    "'2*'",
    "{p}",
    "NaN",
    "inf",
    "-inf",
    "1e999",
    "-1e999",
    "{sqrt(-1)}",
    "{log(0)}",
    "{1/0}",
    "{0/0}",
    "{1e300*1e300}",
    "{-1}",
];

/// Values that stress the numerics.
const EXTREMES: &[&str] = &[
    "0",
    "-0",
    "1e308",
    "-1e308",
    "1e-308",
    "5e-324",
    "1e-999",
    "1e-30",
    "1e30",
    "-1",
    "1meg",
    "1MEG",
    "1mil",
    "1f",
    "1t",
    "1g",
    "1e-15",
    "1e15",
    "18446744073709551616",
    "4294967296",
    "0.000000000000000000000000000000000001",
];

const ELEMENT_LETTERS: &[char] = &[
    'R', 'C', 'L', 'V', 'I', 'E', 'F', 'G', 'H', 'D', 'K', 'X', 'B', 'S', 'T', 'M', 'Q', 'J', 'W',
    'Z', 'A', 'O', 'U', 'P',
];

const DIRECTIVES: &[&str] = &[
    ".ic v({n})={v}",
    ".ic v({n})=0 v({m})={v}",
    ".nodeset v({n})={v}",
    ".options reltol=1e-12",
    ".options abstol=1e-20 vntol=1e-15",
    ".options gmin=0",
    ".options method=gear maxord=6",
    ".option itl4=1",
    ".options temp={v}",
    ".temp {v}",
    ".include /dev/null",
    ".include /nonexistent/x.lib",
    ".include .",
    ".lib /dev/null sect",
    ".tran {v} {w}",
    ".tran 1n 1 uic",
    ".tran 1u 1m 0 1e-30",
    ".param p={v}",
    ".param p={{p}}",
    ".save all",
    ".save v({n}) i(V1)",
    ".probe v({n},{m})",
    ".print tran v({n})",
    ".end",
    ".ends",
    ".subckt sub {n} {m}",
    ".global {n}",
    ".func f(x) {{x*x}}",
    ".model DX D(IS={v} N=1 RS=0 CJO=1p BV=5 IBV=1m)",
    ".model DX D(IS=1e-14 N={v})",
    ".model DY D(TT={v})",
    ".control",
    ".endc",
    "D9 {n} {m} DX",
    "V9 {n} {m} PULSE(0 {v} 0 {w} {w} {w} {w})",
    "V9 {n} {m} SIN(0 {v} {w} 0 {v})",
    "V9 {n} {m} EXP(0 {v} 0 {w} {w} {w})",
    "V9 {n} {m} PWL(0 0 {w} {v} {w} 0)",
    "I9 {n} {m} PULSE(0 {v} 0 {w} {w} {w} {w})",
    "R9 {n} {m} {v}",
    "C9 {n} {m} {v} ic={v}",
    "L9 {n} {m} {v} ic={v}",
    "E9 {n} {m} {n} 0 {v}",
    "G9 {n} {m} {m} 0 {v}",
    "F9 {n} {m} V1 {v}",
    "H9 {n} {m} V1 {v}",
    "X9 {n} {m} sub",
    "+ {v}",
    "* comment {v}",
    "",
];

const TRAN_ARGS: &[&str] = &[
    "1f 1",
    "1 1f",
    "1n 1e6",
    "1u 1m 0.5m",
    "1u 1m 2m",
    "1u 1m 1m",
    "1p 1 0 1e-30",
    "1e-300 1e300",
    "0 1m",
    "-1u 1m",
    "1u -1m",
    "1u 0",
    "1u 1m uic",
    "1u 1m 0 1u uic",
    "1u 1m 0 0",
    "1u 1m 0 -1",
    "1u",
    "",
    "1u 1m 0 1n 5",
    "10 10",
    "1e-20 1e-18",
    "1m 1e4",
    "1u 1m 0.999999999m",
];

const K_VALUES: &[&str] = &[
    "1",
    "1",
    "1",
    "-1",
    "0.99999999",
    "1.0000001",
    "0",
    "0.5",
    "-0.999",
];

fn is_element(line: &str) -> bool {
    line.chars().next().is_some_and(|c| c.is_ascii_alphabetic())
}

fn is_numberish(tok: &str) -> bool {
    let t = tok.trim_start_matches(['-', '+', '(']);
    t.starts_with(|c: char| c.is_ascii_digit())
        || (t.starts_with('.') && t[1..].starts_with(|c: char| c.is_ascii_digit()))
        || t.contains('=')
}

/// Nodes of the element lines (tokens 1 and 2 of two-terminal elements, and
/// the control nodes of E/G), for swapping and for directives.
fn nodes(lines: &[String]) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for l in lines {
        if !is_element(l) {
            continue;
        }
        for t in l.split_whitespace().skip(1).take(2) {
            if !out.iter().any(|n| n == t) {
                out.push(t.to_string());
            }
        }
    }
    if out.is_empty() {
        out.push("n1".into());
    }
    out
}

fn fill(rng: &mut Rng, template: &str, ns: &[String]) -> String {
    let mut s = template.replace("{{", "\u{1}").replace("}}", "\u{2}");
    while let Some(i) = s.find("{n}") {
        let n = rng.pick(ns).clone();
        s.replace_range(i..i + 3, &n);
    }
    while let Some(i) = s.find("{m}") {
        let m = if rng.chance(1, 5) {
            "0".to_string()
        } else {
            rng.pick(ns).clone()
        };
        s.replace_range(i..i + 3, &m);
    }
    while let Some(i) = s.find("{v}") {
        let v = value(rng);
        s.replace_range(i..i + 3, &v);
    }
    while let Some(i) = s.find("{w}") {
        let w = rng.magnitude().trim_start_matches('-').to_string();
        s.replace_range(i..i + 3, &w);
    }
    s.replace('\u{1}', "{").replace('\u{2}', "}")
}

fn value(rng: &mut Rng) -> String {
    match rng.below(8) {
        0 => rng.pick(MALFORMED).to_string(),
        1..=3 => rng.pick(EXTREMES).to_string(),
        _ => rng.magnitude(),
    }
}

/// One mutation of `lines`; `other` is another seed (for splicing).
fn mutate(rng: &mut Rng, lines: &mut Vec<String>, other: &[String]) {
    if lines.is_empty() {
        lines.push("title".into());
    }
    let n = lines.len();
    let elements: Vec<usize> = (1..n).filter(|&k| is_element(&lines[k])).collect();
    let pick_elem = |rng: &mut Rng| -> usize {
        if elements.is_empty() {
            rng.below(n)
        } else {
            *rng.pick(&elements)
        }
    };
    match rng.below(16) {
        // Replace a value with an extreme or malformed number.
        0..=2 => {
            let k = pick_elem(rng);
            let mut toks: Vec<String> = lines[k].split_whitespace().map(String::from).collect();
            let idx: Vec<usize> = (1..toks.len())
                .filter(|&i| is_numberish(&toks[i]))
                .collect();
            if idx.is_empty() {
                toks.push(value(rng));
            } else {
                let i = *rng.pick(&idx);
                let v = value(rng);
                toks[i] = match toks[i].split_once('=') {
                    Some((key, _)) => format!("{key}={v}"),
                    None if toks[i].starts_with('(') => format!("({v}"),
                    None => v,
                };
            }
            lines[k] = toks.join(" ");
        }
        // Swap two nodes of an element, or replace one by another node.
        3 => {
            let k = pick_elem(rng);
            let ns = nodes(lines);
            let mut toks: Vec<String> = lines[k].split_whitespace().map(String::from).collect();
            if toks.len() >= 3 {
                if rng.chance(1, 2) {
                    toks.swap(1, 2);
                } else {
                    let i = 1 + rng.below(2);
                    toks[i] = match rng.below(4) {
                        0 => "0".into(),
                        1 => "gnd".into(),
                        2 => format!("new{}", rng.below(5)),
                        _ => rng.pick(&ns).clone(),
                    };
                }
            }
            lines[k] = toks.join(" ");
        }
        // Change an element's letter.
        4 => {
            let k = pick_elem(rng);
            if !lines[k].is_empty() {
                let c = *rng.pick(ELEMENT_LETTERS);
                let rest: String = lines[k].chars().skip(1).collect();
                lines[k] = format!("{c}{rest}");
            }
        }
        // Duplicate a line (same name: a duplicate element).
        5 => {
            let k = rng.below(n);
            let l = lines[k].clone();
            lines.insert(rng.below(n + 1), l);
        }
        // Delete a line.
        6 => {
            if n > 1 {
                lines.remove(1 + rng.below(n - 1));
            }
        }
        // Swap or move lines (the title too).
        7 => {
            let (a, b) = (rng.below(n), rng.below(n));
            if rng.chance(1, 2) {
                lines.swap(a, b);
            } else {
                let l = lines.remove(a);
                lines.insert(b.min(lines.len()), l);
            }
        }
        // Insert a directive or element.
        8..=9 => {
            let ns = nodes(lines);
            let t = *rng.pick(DIRECTIVES);
            let l = fill(rng, t, &ns);
            lines.insert(1 + rng.below(n), l);
        }
        // Change the `.tran` arguments.
        10 => {
            let args = if rng.chance(1, 3) {
                let ns: [String; 0] = [];
                fill(rng, "{w} {w}", &ns)
            } else {
                rng.pick(TRAN_ARGS).to_string()
            };
            match lines
                .iter()
                .position(|l| l.to_ascii_lowercase().starts_with(".tran"))
            {
                Some(k) => lines[k] = format!(".tran {args}"),
                None => lines.insert(1.min(n), format!(".tran {args}")),
            }
        }
        // Couple two inductors (k = 1 most often), adding them if needed.
        11 => {
            let ls: Vec<String> = lines
                .iter()
                .filter(|l| l.starts_with(['L', 'l']))
                .filter_map(|l| l.split_whitespace().next().map(String::from))
                .collect();
            let ns = nodes(lines);
            let (a, b) = if ls.len() >= 2 && rng.chance(3, 4) {
                let a = rng.pick(&ls).clone();
                let b = rng.pick(&ls).clone();
                (a, b)
            } else {
                let (p, q) = (rng.pick(&ns).clone(), rng.pick(&ns).clone());
                lines.insert(1.min(n), format!("Lk1 {p} 0 {}", rng.magnitude()));
                lines.insert(1.min(n), format!("Lk2 {q} 0 1m"));
                ("Lk1".into(), "Lk2".into())
            };
            let kv = *rng.pick(K_VALUES);
            let name = format!("K{}", rng.below(100));
            lines.insert(1.min(lines.len()), format!("{name} {a} {b} {kv}"));
        }
        // Splice a line of another seed.
        12 => {
            if !other.is_empty() {
                let l = rng.pick(other).clone();
                lines.insert(1 + rng.below(n), l);
            }
        }
        // Character level: insert a special character, delete a span.
        13 => {
            let k = rng.below(n);
            let l = &mut lines[k];
            let chars: Vec<char> = l.chars().collect();
            let i = rng.below(chars.len() + 1);
            let c = *rng.pick(&[
                '(', ')', '{', '}', '=', '+', '.', '*', ' ', '\'', '-', 'e', '0', ',', ';', '$',
                '\u{e9}', '\t', '"', '\\',
            ]);
            let mut s: String = chars[..i].iter().collect();
            s.push(c);
            s.extend(&chars[i..]);
            *l = s;
        }
        14 => {
            let k = rng.below(n);
            let chars: Vec<char> = lines[k].chars().collect();
            let a = rng.below(chars.len() + 1);
            let b = (a + 1 + rng.below(8)).min(chars.len());
            lines[k] = chars[..a].iter().chain(&chars[b.max(a)..]).collect();
        }
        // Replace a source's waveform.
        _ => {
            let srcs: Vec<usize> = (1..n)
                .filter(|&k| lines[k].starts_with(['V', 'v', 'I', 'i']))
                .collect();
            if let Some(&k) = srcs.get(rng.below(srcs.len().max(1))) {
                let toks: Vec<&str> = lines[k].split_whitespace().take(3).collect();
                let ns: [String; 0] = [];
                let template = rng_pick_wave(rng.below(6));
                let wave = fill(rng, template, &ns);
                lines[k] = format!("{} {wave}", toks.join(" "));
            }
        }
    }
}

fn rng_pick_wave(k: usize) -> &'static str {
    [
        "PULSE(0 {v} 0 {w} {w} {w} {w})",
        "PULSE({v} {v} {w} 0 0 {w} {w} {v})",
        "SIN({v} {v} {w} {w} {v} {v})",
        "EXP({v} {v} {w} {w} {w} {w})",
        "PWL(0 {v} {w} {v} {w} {v})",
        "DC {v}",
    ][k]
}

/// The seeds: every `.cir` under the given directories (recursively).
fn collect(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return;
    };
    let mut entries: Vec<PathBuf> = rd.filter_map(|e| e.ok().map(|e| e.path())).collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            collect(&p, out);
        } else if p.extension().is_some_and(|e| e == "cir") {
            out.push(p);
        }
    }
}

#[derive(Default)]
struct Outcome {
    /// `None`: sorted; `Some(code)`: refused with this first error.
    refused: Option<String>,
    /// Codes of errors that carry no location.
    unlocated: Vec<String>,
    /// The simulation: "ok" or the error's code, and whether its message
    /// names the time or an element.
    sim: Option<(String, bool, String)>,
}

fn run_one(name: &str, text: &str, max_steps: usize, max_rows: usize) -> Outcome {
    let mut out = Outcome::default();
    match sort_text(name, text.to_string(), &SortOptions::default()) {
        Err(f) => {
            for d in &f.diagnostics {
                let _ = render(&f.sources, d, Default::default());
                if d.is_error() {
                    if out.refused.is_none() {
                        out.refused = Some(d.code.to_string());
                    }
                    if d.span().is_none() {
                        out.unlocated.push(format!("{}: {}", d.code, d.message));
                    }
                }
            }
            if out.refused.is_none() {
                out.refused = Some("(no error)".into());
            }
        }
        Ok(sorted) => {
            let sources = &sorted.elaborated.sources;
            for d in &sorted.elaborated.warnings {
                let _ = render(sources, d, Default::default());
            }
            let opts = Options {
                max_steps: Some(max_steps),
                ..Default::default()
            };
            let mut rows = 0usize;
            let mut sink = |_t: f64, _row: &[f64]| -> std::io::Result<()> {
                rows += 1;
                if rows > max_rows {
                    return Err(std::io::Error::other("fuzz: row cap"));
                }
                Ok(())
            };
            out.sim = Some(match simulate_to(&sorted, &opts, &mut sink) {
                Ok(w) => {
                    for d in &w.warnings {
                        let _ = render(sources, d, Default::default());
                    }
                    ("ok".into(), true, String::new())
                }
                Err(e) => {
                    let d = e.to_diagnostic();
                    let _ = render(sources, &d, Default::default());
                    let msg = d.message.clone();
                    let names = sorted
                        .elaborated
                        .circuit
                        .elements
                        .iter()
                        .any(|(_, el)| msg.contains(el.name.as_str()));
                    // A time, an element, or a place in the netlist.
                    let located = msg.contains("t = ") || names || !d.labels.is_empty();
                    let code = if msg.contains("fuzz: row cap") {
                        format!("{} (row cap)", d.code)
                    } else {
                        d.code.to_string()
                    };
                    (code, located, msg)
                }
            });
        }
    }
    out
}

/// The counts of a campaign.
#[derive(Default)]
struct Tally {
    done: u64,
    accepted: u64,
    refused: BTreeMap<String, u64>,
    /// Code: (runs, runs whose diagnostic names neither a time nor an element
    /// nor points into the netlist).
    sims: BTreeMap<String, (u64, u64)>,
    unlocated: BTreeMap<String, u64>,
    panics: BTreeMap<String, u64>,
    over_slow: u64,
    max_time: (f64, String),
}

impl Tally {
    fn print(&self, seed: u64, el: f64, slow: f64, out_dir: &Path) {
        println!("== fuzz_grammar seed {seed}");
        println!(
            "inputs {} in {el:.1} s ({:.0}/s)",
            self.done,
            self.done as f64 / el
        );
        println!("accepted (sorted) {}", self.accepted);
        println!("refused {}", self.refused.values().sum::<u64>());
        for (c, n) in &self.refused {
            println!("  {c} {n}");
        }
        println!("simulations (code: runs, without time, element or place)");
        for (c, (n, u)) in &self.sims {
            println!("  {c} {n} {u}");
        }
        println!(
            "errors without a location {}",
            self.unlocated.values().sum::<u64>()
        );
        for (c, n) in &self.unlocated {
            println!("  {c} {n}");
        }
        println!("panics {}", self.panics.values().sum::<u64>());
        for (c, n) in &self.panics {
            println!("  {n} {c}");
        }
        println!(
            "max time {:.3} s (input {})",
            self.max_time.0, self.max_time.1
        );
        println!("inputs over {slow} s: {}", self.over_slow);
        println!("findings in {}", out_dir.display());
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut n_inputs: u64 = 10_000;
    let mut seed: u64 = 1;
    let mut out_dir = PathBuf::from("/work/fuzz-out/grammar");
    let mut seed_dirs: Vec<PathBuf> = Vec::new();
    let mut max_steps = 20_000usize;
    let mut slow = 5.0f64;
    let mut hang = 120.0f64;
    let mut seed_limit = 1.0f64;
    let mut replay: Option<PathBuf> = None;
    let mut i = 0;
    while i < args.len() {
        let a = args[i].as_str();
        let mut val = || {
            i += 1;
            args.get(i).cloned().unwrap_or_default()
        };
        match a {
            "--seed" => seed = val().parse().expect("--seed N"),
            "--out" => out_dir = PathBuf::from(val()),
            "--seeds" => seed_dirs.push(PathBuf::from(val())),
            "--max-steps" => max_steps = val().parse().expect("--max-steps N"),
            "--slow" => slow = val().parse().expect("--slow SECS"),
            "--hang" => hang = val().parse().expect("--hang SECS"),
            "--seed-limit" => seed_limit = val().parse().expect("--seed-limit SECS"),
            "--replay" => replay = Some(PathBuf::from(val())),
            _ => n_inputs = a.parse().expect("N: the number of inputs"),
        }
        i += 1;
    }
    if seed_dirs.is_empty() {
        seed_dirs.push(PathBuf::from("netlists"));
        seed_dirs.push(PathBuf::from("/work/shared/fuzz-findings"));
    }
    std::fs::create_dir_all(&out_dir).expect("create the findings directory");
    let max_rows = 100_000;

    // A panic's message goes to the report, not to stderr.
    let last_panic: Arc<Mutex<String>> = Arc::new(Mutex::new(String::new()));
    {
        let last_panic = last_panic.clone();
        std::panic::set_hook(Box::new(move |info| {
            *last_panic.lock().unwrap() = info.to_string();
        }));
    }

    // Watchdog: an input that runs past `hang` seconds ends the run (with
    // the counts so far).
    let tally = Arc::new(Mutex::new(Tally::default()));
    let started_ms = Arc::new(AtomicU64::new(u64::MAX));
    let epoch = Instant::now();
    let t_start = Instant::now();
    {
        let started_ms = started_ms.clone();
        let tally = tally.clone();
        let current = out_dir.join("current.cir");
        let out_dir = out_dir.clone();
        std::thread::spawn(move || {
            loop {
                std::thread::sleep(Duration::from_millis(500));
                let s = started_ms.load(Ordering::Relaxed);
                let now = epoch.elapsed().as_millis() as u64;
                if s != u64::MAX && now.saturating_sub(s) as f64 > hang * 1e3 {
                    let dest = out_dir.join(format!("hang-{}.cir", now));
                    let _ = std::fs::copy(&current, &dest);
                    println!("HANG: an input ran over {hang} s: {}", dest.display());
                    let el = t_start.elapsed().as_secs_f64();
                    tally.lock().unwrap().print(seed, el, slow, &out_dir);
                    std::process::exit(3);
                }
            }
        });
    }

    // Seeds: time each once; those slower than `seed_limit` are reported and
    // not mutated (their mutants would take the campaign's time).
    let mut paths = Vec::new();
    for d in &seed_dirs {
        collect(d, &mut paths);
    }
    let mut seeds: Vec<(String, Vec<String>)> = Vec::new();
    for p in &paths {
        let Ok(bytes) = std::fs::read(p) else {
            continue;
        };
        let text = String::from_utf8_lossy(&bytes).into_owned();
        let name = p.display().to_string();
        let t0 = Instant::now();
        let _ = catch_unwind(AssertUnwindSafe(|| {
            run_one(&name, &text, max_steps, max_rows)
        }));
        let dt = t0.elapsed().as_secs_f64();
        if dt > seed_limit {
            println!("seed {name}: {dt:.2} s, not mutated");
            continue;
        }
        seeds.push((name, text.lines().map(String::from).collect()));
    }
    println!("{} seeds of {}", seeds.len(), paths.len());

    let mut rng = Rng::new(seed);
    let mut pool: Vec<(String, Vec<String>)> = seeds.clone();
    let mut seen: std::collections::HashSet<String> = std::collections::HashSet::new();
    let current = out_dir.join("current.cir");
    // `--replay DIR`: run the files of DIR (a libFuzzer corpus) as they are.
    let replayed: Vec<Vec<u8>> = replay.as_ref().map_or_else(Vec::new, |d| {
        let mut files: Vec<PathBuf> = std::fs::read_dir(d)
            .expect("--replay DIR")
            .filter_map(|e| e.ok().map(|e| e.path()))
            .collect();
        files.sort();
        files.iter().filter_map(|f| std::fs::read(f).ok()).collect()
    });
    if replay.is_some() {
        n_inputs = replayed.len() as u64;
    }
    for k in 0..n_inputs {
        if replay.is_some() {
            // As the libFuzzer target: inputs that are not UTF-8 are skipped.
            let Ok(text) = std::str::from_utf8(&replayed[k as usize]) else {
                continue;
            };
            let t0 = Instant::now();
            let r = catch_unwind(AssertUnwindSafe(|| {
                run_one("fuzz.cir", text, max_steps, max_rows)
            }));
            let dt = t0.elapsed().as_secs_f64();
            let mut guard = tally.lock().unwrap();
            let t = &mut *guard;
            t.done += 1;
            if dt > t.max_time.0 {
                t.max_time = (dt, format!("{k} (replayed)"));
            }
            match r {
                Err(_) => {
                    *t.panics
                        .entry(last_panic.lock().unwrap().clone())
                        .or_default() += 1
                }
                Ok(o) => {
                    for u in &o.unlocated {
                        *t.unlocated
                            .entry(u.split(':').next().unwrap_or("").to_string())
                            .or_default() += 1;
                    }
                    match &o.refused {
                        Some(code) => *t.refused.entry(code.clone()).or_default() += 1,
                        None => t.accepted += 1,
                    }
                    if let Some((code, located, _)) = &o.sim {
                        let e = t.sims.entry(code.clone()).or_default();
                        e.0 += 1;
                        e.1 += u64::from(!located);
                    }
                }
            }
            continue;
        }
        let (name, base) = {
            let src = if rng.chance(1, 3) { &pool } else { &seeds };
            src[rng.below(src.len())].clone()
        };
        let other = &seeds[rng.below(seeds.len())].1;
        let mut lines = base;
        let most = if rng.chance(1, 8) { 8 } else { 2 };
        let times = 1 + rng.below(most);
        for _ in 0..times {
            mutate(&mut rng, &mut lines, other);
        }
        let mut text = lines.join("\n");
        text.push('\n');
        let _ = std::fs::write(&current, &text);
        started_ms.store(epoch.elapsed().as_millis() as u64, Ordering::Relaxed);
        let t0 = Instant::now();
        let r = catch_unwind(AssertUnwindSafe(|| {
            run_one(&name, &text, max_steps, max_rows)
        }));
        let dt = t0.elapsed().as_secs_f64();
        started_ms.store(u64::MAX, Ordering::Relaxed);
        let mut guard = tally.lock().unwrap();
        let t = &mut *guard;
        t.done += 1;
        let base_name = Path::new(&name)
            .file_stem()
            .map_or("x".into(), |s| s.to_string_lossy().into_owned());
        if dt > t.max_time.0 {
            t.max_time = (dt, format!("{k} ({base_name})"));
        }
        if dt > slow {
            t.over_slow += 1;
            let f = out_dir.join(format!("slow-{k}-{:.0}s-{base_name}.cir", dt));
            let _ = std::fs::write(&f, &text);
        }
        let mut key = String::new();
        match r {
            Err(_) => {
                let msg = last_panic.lock().unwrap().clone();
                let loc = msg.lines().next().unwrap_or("").to_string();
                let c = t.panics.entry(loc.clone()).or_default();
                *c += 1;
                if *c <= 5 {
                    let f = out_dir.join(format!("panic-{k}-{base_name}.cir"));
                    let _ = std::fs::write(&f, &text);
                    let _ = std::fs::write(f.with_extension("txt"), &msg);
                }
                key = format!("panic {loc}");
            }
            Ok(o) => {
                for u in &o.unlocated {
                    let code = u.split(':').next().unwrap_or("").to_string();
                    let c = t.unlocated.entry(code.clone()).or_default();
                    *c += 1;
                    if *c <= 3 {
                        let f = out_dir.join(format!("unlocated-{code}-{k}-{base_name}.cir"));
                        let _ = std::fs::write(&f, &text);
                        let _ = std::fs::write(f.with_extension("txt"), u);
                    }
                }
                if let Some(code) = &o.refused {
                    *t.refused.entry(code.clone()).or_default() += 1;
                    key = format!("refused {code}");
                } else {
                    t.accepted += 1;
                }
                if let Some((code, located, msg)) = &o.sim {
                    let e = t.sims.entry(code.clone()).or_default();
                    e.0 += 1;
                    if !located {
                        e.1 += 1;
                        if e.1 <= 3 {
                            let f = out_dir.join(format!("simnoloc-{code}-{k}-{base_name}.cir"));
                            let _ = std::fs::write(&f, &text);
                            let _ = std::fs::write(f.with_extension("txt"), msg);
                        }
                    }
                    key = format!("sim {code}");
                }
            }
        }
        // A mutant with an outcome not seen before joins the pool.
        if seen.insert(key) && pool.len() < 10_000 {
            pool.push((name, text.lines().map(String::from).collect()));
        }
        if (k + 1) % 5000 == 0 {
            let el = t_start.elapsed().as_secs_f64();
            println!(
                "#{} {:.0} inputs/s accepted {} panics {} slow {} max {:.2} s",
                k + 1,
                (k + 1) as f64 / el,
                t.accepted,
                t.panics.values().sum::<u64>(),
                t.over_slow,
                t.max_time.0
            );
        }
    }
    let el = t_start.elapsed().as_secs_f64();
    let _ = std::fs::remove_file(&current);
    tally.lock().unwrap().print(seed, el, slow, &out_dir);
}
