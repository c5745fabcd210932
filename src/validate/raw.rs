//! ngspice raw files (ASCII and binary, real data): names and columns.

/// Waveforms read from a raw file.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RawData {
    pub title: String,
    /// Vector names as ngspice writes them (`v(out)`, `i(v1)`), lower-case.
    pub names: Vec<String>,
    pub time: Vec<f64>,
    /// One column per name.
    pub data: Vec<Vec<f64>>,
}

/// Parse a raw file; the error says what is wrong with it. A file of
/// several plots (an `.op` or an `.ac` before the `.tran`) gives its
/// transient one; complex plots (AC analyses) are skipped.
pub fn parse(bytes: &[u8]) -> Result<RawData, String> {
    let mut pos = 0;
    let mut first = None;
    let mut complex = false;
    while pos < bytes.len() {
        let (plot, transient, end) = parse_plot(bytes, pos)?;
        match plot {
            Some(plot) if transient => return Ok(plot),
            Some(plot) => {
                first.get_or_insert(plot);
            }
            None => complex = true,
        }
        if end <= pos {
            break;
        }
        pos = end;
        // Blank lines between plots.
        while pos < bytes.len() && bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
    }
    first.ok_or_else(|| {
        if complex {
            "complex data only (an AC analysis, no transient one)".into()
        } else {
            "no `Values:` or `Binary:` section".into()
        }
    })
}

/// The plot whose header starts at `pos`: its data (`None` for complex
/// data, which is skipped), whether it is a transient analysis, and where
/// it ends.
fn parse_plot(bytes: &[u8], mut pos: usize) -> Result<(Option<RawData>, bool, usize), String> {
    let mut header = Vec::new();
    let mut binary = None;
    // Header lines up to `Values:` or `Binary:`.
    while pos < bytes.len() {
        let end = bytes[pos..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(bytes.len(), |i| pos + i);
        let line = String::from_utf8_lossy(&bytes[pos..end])
            .trim_end_matches('\r')
            .to_string();
        pos = (end + 1).min(bytes.len());
        if line.starts_with("Values:") {
            binary = Some(false);
            break;
        }
        if line.starts_with("Binary:") {
            binary = Some(true);
            break;
        }
        header.push(line);
    }
    let binary = binary.ok_or("no `Values:` or `Binary:` section")?;
    let field = |key: &str| -> Option<String> {
        header
            .iter()
            .find_map(|l| l.strip_prefix(key).map(|v| v.trim().to_string()))
    };
    let title = field("Title:").unwrap_or_default();
    let transient =
        field("Plotname:").is_some_and(|p| p.to_ascii_lowercase().contains("transient"));
    let complex = field("Flags:").is_some_and(|f| f.contains("complex"));
    let n_vars: usize = field("No. Variables:")
        .ok_or("missing `No. Variables:`")?
        .parse()
        .map_err(|_| "bad `No. Variables:`")?;
    let n_points: usize = field("No. Points:")
        .ok_or("missing `No. Points:`")?
        .parse()
        .map_err(|_| "bad `No. Points:`")?;
    let vstart = header
        .iter()
        .position(|l| l.starts_with("Variables:"))
        .ok_or("missing `Variables:`")?;
    let mut names = Vec::with_capacity(n_vars);
    for l in header.iter().skip(vstart + 1).take(n_vars) {
        let mut parts = l.split_whitespace();
        let _idx = parts.next();
        let name = parts.next().ok_or("bad variable line")?;
        names.push(name.to_ascii_lowercase());
    }
    if names.len() != n_vars || n_vars == 0 {
        return Err(format!(
            "expected {n_vars} variables, found {}",
            names.len()
        ));
    }
    if complex {
        // Each value is a pair: 16 bytes, or one `re,im` token.
        if binary {
            pos = binary_end(bytes, pos, n_points, n_vars, 16)?;
        } else {
            let mut nums = Tokens { bytes, pos };
            for p in 0..n_points * (n_vars + 1) {
                nums.next()
                    .ok_or(format!("complex point {} is short", p / (n_vars + 1)))?;
            }
            pos = nums.pos;
        }
        return Ok((None, false, pos));
    }
    let end = if binary {
        binary_end(bytes, pos, n_points, n_vars, 8)?
    } else {
        bytes.len()
    };
    // A value takes at least a byte: a header's count reserves no more
    // than the file holds.
    let mut cols = vec![Vec::with_capacity(n_points.min(end - pos)); n_vars];
    if binary {
        for p in 0..n_points {
            for (v, col) in cols.iter_mut().enumerate() {
                let at = pos + (p * n_vars + v) * 8;
                let mut b = [0u8; 8];
                b.copy_from_slice(&bytes[at..at + 8]);
                col.push(f64::from_le_bytes(b));
            }
        }
        pos = end;
    } else {
        let mut nums = Tokens { bytes, pos };
        for p in 0..n_points {
            let idx = nums.next().ok_or(format!("point {p} is missing"))?;
            if idx.parse::<usize>().ok() != Some(p) {
                return Err(format!("point {p}: expected its index, found `{idx}`"));
            }
            for col in cols.iter_mut() {
                let v = nums.next().ok_or(format!("point {p} is short"))?;
                col.push(
                    v.parse()
                        .map_err(|_| format!("point {p}: `{v}` is not a number"))?,
                );
            }
        }
        pos = nums.pos;
    }
    let time = cols.remove(0);
    names.remove(0);
    if transient && time.windows(2).any(|w| w[1] < w[0]) {
        return Err("time is not increasing".into());
    }
    let plot = RawData {
        title,
        names,
        time,
        data: cols,
    };
    Ok((Some(plot), transient, pos))
}

/// Where `n_points` rows of `n_vars` binary values of `width` bytes from
/// `pos` end; an error if the file is shorter.
fn binary_end(
    bytes: &[u8],
    pos: usize,
    n_points: usize,
    n_vars: usize,
    width: usize,
) -> Result<usize, String> {
    let have = bytes.len() - pos;
    match n_points
        .checked_mul(n_vars)
        .and_then(|n| n.checked_mul(width))
    {
        Some(need) if need <= have => Ok(pos + need),
        Some(need) => Err(format!("binary data is truncated: {have} of {need} bytes")),
        None => Err(format!("{n_points} points of {n_vars} variables overflow")),
    }
}

/// Whitespace-separated tokens of `bytes` from `pos`, which follows them.
struct Tokens<'b> {
    bytes: &'b [u8],
    pos: usize,
}

impl<'b> Iterator for Tokens<'b> {
    type Item = std::borrow::Cow<'b, str>;
    fn next(&mut self) -> Option<Self::Item> {
        let b = self.bytes;
        while self.pos < b.len() && b[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        let start = self.pos;
        while self.pos < b.len() && !b[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        (self.pos > start).then(|| String::from_utf8_lossy(&b[start..self.pos]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ascii_and_binary_agree() {
        let ascii = "Title: t\nPlotname: Transient Analysis\nFlags: real\nNo. Variables: 2\nNo. Points: 2\nVariables:\n\t0\ttime\ttime\n\t1\tv(a)\tvoltage\nValues:\n 0\t0.0\n\t1.5\n 1\t1e-3\n\t2.5\n";
        let a = parse(ascii.as_bytes()).unwrap();
        assert_eq!(a.names, ["v(a)"]);
        assert_eq!(a.time, [0.0, 1e-3]);
        assert_eq!(a.data[0], [1.5, 2.5]);
        let mut bin = ascii.split("Values:").next().unwrap().as_bytes().to_vec();
        bin.extend_from_slice(b"Binary:\n");
        for v in [0.0f64, 1.5, 1e-3, 2.5] {
            bin.extend_from_slice(&v.to_le_bytes());
        }
        assert_eq!(parse(&bin).unwrap(), a);
        // An operating point before the transient: the transient is read.
        let op = "Title: t\nPlotname: Operating Point\nFlags: real\nNo. Variables: 1\nNo. Points: 1\nVariables:\n\t0\tv(a)\tvoltage\nBinary:\n";
        let mut both = op.as_bytes().to_vec();
        both.extend_from_slice(&7.0f64.to_le_bytes());
        both.extend_from_slice(&bin);
        assert_eq!(parse(&both).unwrap(), a);
        let mut both = op.replace("Binary:", "Values:").into_bytes();
        both.extend_from_slice(b" 0\t7.0\n");
        both.extend_from_slice(ascii.as_bytes());
        assert_eq!(parse(&both).unwrap(), a);
        assert!(parse(b"Title: x\n").is_err());
        assert!(
            parse(&bin[..bin.len() - 3])
                .unwrap_err()
                .contains("truncated")
        );
        // An AC analysis (complex: a pair per value) before the transient
        // is skipped, binary or ASCII; alone, it is no transient.
        let ac = "Title: t\nPlotname: AC Analysis\nFlags: complex\nNo. Variables: 2\nNo. Points: 2\nVariables:\n\t0\tfrequency\tfrequency\n\t1\tv(a)\tvoltage\nBinary:\n";
        let mut both = ac.as_bytes().to_vec();
        for v in [1.0f64, 0.0, 0.5, -0.5, 10.0, 0.0, 0.25, -0.75] {
            both.extend_from_slice(&v.to_le_bytes());
        }
        let ac_only = both.clone();
        both.extend_from_slice(&bin);
        assert_eq!(parse(&both).unwrap(), a);
        let mut both = ac.replace("Binary:", "Values:").into_bytes();
        both.extend_from_slice(b" 0\t1.0,0.0\n\t5e-1,-5e-1\n 1\t1e1,0\n\t0.25,-0.75\n");
        both.extend_from_slice(ascii.as_bytes());
        assert_eq!(parse(&both).unwrap(), a);
        assert!(parse(&ac_only).unwrap_err().contains("complex"));
        // A header that claims more points than the file holds (or than
        // memory could) is an error, not an allocation.
        for n in ["1000000000000000000", "18446744073709551615"] {
            let huge = ascii
                .replace("No. Points: 2", &format!("No. Points: {n}"))
                .replace("Values:", "Binary:");
            let huge = huge.split("Binary:").next().unwrap().to_string() + "Binary:\n";
            assert!(parse(huge.as_bytes()).is_err());
            let text = ascii.replace("No. Points: 2", &format!("No. Points: {n}"));
            assert!(parse(text.as_bytes()).unwrap_err().contains("missing"));
        }
    }
}
