//! Waveform files: CSV (`time,v(out),...`) and ngspice's raw format (ASCII
//! and binary), rendered to bytes; the caller writes them (atomically).

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

/// Columns the point count of a streamed raw file is padded to: the header
/// is written before the count is known, and the count overwrites the
/// padding at the end (ngspice reads the number and ignores the spaces).
pub const RAW_POINTS_WIDTH: usize = 20;

/// ngspice's raw header (`Plotname: Transient Analysis`, real data) up to
/// and including `Values:` (ASCII) or `Binary:`. Without a point count the
/// field is blank padding; the returned offset is where the count goes.
pub fn raw_header(
    out: &mut String,
    names: &[String],
    title: &str,
    points: Option<usize>,
    binary: bool,
) -> usize {
    let _ = writeln!(out, "Title: {title}");
    let _ = writeln!(out, "Date: kausal");
    let _ = writeln!(out, "Plotname: Transient Analysis");
    let _ = writeln!(out, "Flags: real");
    let _ = writeln!(out, "No. Variables: {}", names.len() + 1);
    out.push_str("No. Points: ");
    let at = out.len();
    match points {
        Some(n) => {
            let _ = writeln!(out, "{n}");
        }
        None => {
            let _ = writeln!(out, "{:RAW_POINTS_WIDTH$}", "");
        }
    }
    let _ = writeln!(out, "Variables:");
    let _ = writeln!(out, "\t0\ttime\ttime");
    for (k, n) in names.iter().enumerate() {
        let kind = if n.starts_with("i(") {
            "current"
        } else {
            "voltage"
        };
        let _ = writeln!(out, "\t{}\t{n}\t{kind}", k + 1);
    }
    out.push_str(if binary { "Binary:\n" } else { "Values:\n" });
    at
}

/// The point count that overwrites [`raw_header`]'s padding.
pub fn raw_points(points: usize) -> String {
    format!("{points:<RAW_POINTS_WIDTH$}")
}

/// One point of a binary raw file, appended to `out`: time, then each
/// value, as little-endian doubles (ngspice's layout on the machines it
/// runs on).
pub fn raw_binary_row(out: &mut Vec<u8>, t: f64, values: &[f64]) {
    out.extend_from_slice(&t.to_le_bytes());
    for &v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

/// ngspice's binary raw file of the whole run.
pub fn raw_binary(w: &Waveforms, title: &str) -> Vec<u8> {
    // Laid out as a streamed file is, byte for byte.
    let mut head = String::new();
    let at = raw_header(&mut head, &w.names, title, None, true);
    let mut out = head.into_bytes();
    out[at..at + RAW_POINTS_WIDTH].copy_from_slice(raw_points(w.time.len()).as_bytes());
    out.reserve(w.time.len() * (w.names.len() + 1) * 8);
    let mut row = Vec::with_capacity(w.data.len());
    for (k, &t) in w.time.iter().enumerate() {
        row.clear();
        row.extend(w.data.iter().map(|col| col[k]));
        raw_binary_row(&mut out, t, &row);
    }
    out
}

/// ngspice's ASCII raw file (`Plotname: Transient Analysis`).
pub fn raw_ascii(w: &Waveforms, title: &str) -> String {
    let mut out = String::new();
    raw_header(&mut out, &w.names, title, Some(w.time.len()), false);
    for (k, t) in w.time.iter().enumerate() {
        let _ = writeln!(out, " {k}\t{t:.15e}");
        for col in &w.data {
            let _ = writeln!(out, "\t{:.15e}", col[k]);
        }
    }
    out
}
