//! Waveform files: CSV (`time,v(out),...`) and ngspice's ASCII raw format,
//! rendered to text; the caller writes them (atomically).

use std::fmt::Write;

use super::Waveforms;

/// CSV with a `time,<vector>...` header, one row per time point, numbers in
/// their shortest round-trip form (zmij: a tenth of `format!`'s time, and
/// formatting is a large share of a small circuit's run).
pub fn csv(w: &Waveforms) -> String {
    let mut out = String::with_capacity(w.time.len() * (w.names.len() + 1) * 12);
    csv_header(&mut out, &w.names);
    let mut row = Vec::with_capacity(w.data.len());
    for (k, &t) in w.time.iter().enumerate() {
        row.clear();
        row.extend(w.data.iter().map(|col| col[k]));
        csv_row(&mut out, t, &row);
    }
    out
}

/// The CSV header line: `time,<name>...`.
pub fn csv_header(out: &mut String, names: &[String]) {
    out.push_str("time");
    for n in names {
        out.push(',');
        out.push_str(n);
    }
    out.push('\n');
}

/// One CSV row, appended to `out`.
pub fn csv_row(out: &mut String, t: f64, values: &[f64]) {
    let mut buf = zmij::Buffer::new();
    out.push_str(buf.format(t));
    for &v in values {
        out.push(',');
        // `+ 0.0` prints -0 as 0.
        out.push_str(buf.format(v + 0.0));
    }
    out.push('\n');
}

/// ngspice's ASCII raw file (`Plotname: Transient Analysis`).
pub fn raw_ascii(w: &Waveforms, title: &str) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "Title: {title}");
    let _ = writeln!(out, "Date: kausal");
    let _ = writeln!(out, "Plotname: Transient Analysis");
    let _ = writeln!(out, "Flags: real");
    let _ = writeln!(out, "No. Variables: {}", w.names.len() + 1);
    let _ = writeln!(out, "No. Points: {}", w.time.len());
    let _ = writeln!(out, "Variables:");
    let _ = writeln!(out, "\t0\ttime\ttime");
    for (k, n) in w.names.iter().enumerate() {
        let kind = if n.starts_with("i(") {
            "current"
        } else {
            "voltage"
        };
        let _ = writeln!(out, "\t{}\t{n}\t{kind}", k + 1);
    }
    let _ = writeln!(out, "Values:");
    for (k, t) in w.time.iter().enumerate() {
        let _ = writeln!(out, " {k}\t{t:.15e}");
        for col in &w.data {
            let _ = writeln!(out, "\t{:.15e}", col[k]);
        }
    }
    out
}
