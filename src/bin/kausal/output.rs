//! Everything the subcommands write: diagnostics on standard error, command
//! output to a file (atomically) or standard output, and the CSV streamed
//! while a simulation runs. A closed standard output (`| head`) is never an
//! error.

use std::collections::HashMap;
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};

use kausal::diag::{self, Diagnostic, RenderOptions, SourceMap};
use kausal::io::AtomicFile;
use kausal::pipeline::Sorted;
use kausal::sim;

use crate::error::Error;

/// Diagnostics of one code shown in full before the rest are counted (a
/// chain of 3000 inductors in a cutset gives 3000 K0310 warnings).
const SAME_CODE_SHOWN: usize = 10;

/// Colour on a terminal, none in pipes and tests.
fn render_opts() -> RenderOptions {
    RenderOptions {
        color: std::io::stderr().is_terminal(),
    }
}

/// Print diagnostics on standard error: at most [`SAME_CODE_SHOWN`] of each
/// code, then how many more of each code were left out.
pub fn print_diags(sources: &SourceMap, diags: &[Diagnostic]) {
    let opts = render_opts();
    let mut err = std::io::stderr().lock();
    let mut seen: HashMap<diag::Code, usize> = HashMap::new();
    for d in diags {
        let n = seen.entry(d.code).or_default();
        *n += 1;
        if *n <= SAME_CODE_SHOWN {
            let _ = writeln!(err, "{}", diag::render(sources, d, opts));
        }
    }
    let mut more: Vec<(&str, usize)> = seen
        .into_iter()
        .filter(|&(_, n)| n > SAME_CODE_SHOWN)
        .map(|(code, n)| (code.id, n - SAME_CODE_SHOWN))
        .collect();
    more.sort();
    for (code, n) in more {
        let _ = writeln!(
            err,
            "{code}: {n} more like the {SAME_CODE_SHOWN} above, not shown\n"
        );
    }
}

/// Write command output to a file (atomically) or standard output.
pub fn emit(out: Option<&PathBuf>, text: &str) -> Result<(), Error> {
    emit_with(out, |w| w.write_all(text.as_bytes()))
}

/// [`emit`] of output that `write` produces piece by piece (a listing of
/// 10^6 equations is not gathered into one string first).
pub fn emit_with(
    out: Option<&PathBuf>,
    write: impl FnOnce(&mut dyn Write) -> std::io::Result<()>,
) -> Result<(), Error> {
    match out {
        Some(path) => {
            let mut f = AtomicFile::create(path).map_err(Error::write(path))?;
            write(&mut f).map_err(Error::write(path))?;
            f.commit().map_err(Error::write(path))
        }
        None => {
            let mut stdout = std::io::BufWriter::with_capacity(1 << 16, std::io::stdout().lock());
            write(&mut stdout)
                .and_then(|_| stdout.flush())
                .or_else(|e| {
                    // A closed pipe (`| head`) is not an error.
                    if e.kind() == std::io::ErrorKind::BrokenPipe {
                        Ok(())
                    } else {
                        Err(Error::Stdout(e))
                    }
                })
        }
    }
}

/// Pretty JSON with a final newline.
pub fn json(value: &impl serde::Serialize) -> Result<String, Error> {
    let mut s = serde_json::to_string_pretty(value)?;
    s.push('\n');
    Ok(s)
}

/// The format of `kausal sim`'s waveform file.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum WaveFormat {
    /// `time,<vector>...` rows of shortest round-trip numbers.
    Csv,
    /// ngspice's binary raw file (what `ngspice -b -r` writes).
    RawBinary,
}

impl WaveFormat {
    /// A `.raw` file is ngspice's binary raw format; anything else CSV.
    pub fn of(out: Option<&PathBuf>) -> WaveFormat {
        match out.and_then(|p| p.extension()) {
            Some(e) if e.eq_ignore_ascii_case("raw") => WaveFormat::RawBinary,
            _ => WaveFormat::Csv,
        }
    }
}

/// Simulate, writing rows as they come: into a file committed by the
/// caller (renamed over `out` only once the run succeeded) or to standard
/// output (a closed pipe, `| head`, ends the writing, not the run). A raw
/// file's point count, unknown until the end, is written over its header's
/// padding then; so a raw file goes to a file, never a pipe.
pub fn stream_waves(
    sorted: &mut Sorted,
    prepared: sim::Prepared,
    opts: &sim::Options,
    out: Option<&PathBuf>,
    format: WaveFormat,
) -> Result<(sim::Waveforms, Option<AtomicFile>), sim::SimError> {
    let names: Vec<String> = sim::outputs(sorted, &opts.probes)?
        .into_iter()
        .map(|o| o.0)
        .collect();
    let shown = out.map_or(Path::new("-"), |p| p.as_path());
    let write_err = |e: std::io::Error| sim::SimError::Write {
        path: Some(shown.to_path_buf()),
        source: std::rc::Rc::new(e),
    };
    let title = sorted.elaborated.circuit.title.clone();
    // One row writer for every destination.
    // The offset of a raw file's point count, and the count.
    let mut prepared = Some(prepared);
    let mut run = |w: &mut dyn Write| -> Result<(sim::Waveforms, usize, usize), sim::SimError> {
        let mut head = String::new();
        let count_at = match format {
            WaveFormat::Csv => {
                sim::output::csv_header(&mut head, &names);
                0
            }
            WaveFormat::RawBinary => sim::output::raw_header(&mut head, &names, &title, None, true),
        };
        w.write_all(head.as_bytes()).map_err(write_err)?;
        let mut line = String::new();
        let mut bytes = Vec::new();
        let mut points = 0;
        let mut sink = |t: f64, v: &[f64]| {
            points += 1;
            match format {
                WaveFormat::Csv => {
                    line.clear();
                    sim::output::csv_row(&mut line, t, v);
                    w.write_all(line.as_bytes())
                }
                WaveFormat::RawBinary => {
                    bytes.clear();
                    sim::output::raw_binary_row(&mut bytes, t, v);
                    w.write_all(&bytes)
                }
            }
        };
        let prepared = prepared.take().expect("one run");
        // The equation system and circuit go once the operating point is
        // found: the integrator's memory takes their place.
        let mut wf = sim::run_prepared_releasing(
            sorted,
            prepared,
            opts,
            Some(&mut sink),
            crate::return_freed_memory,
        )?;
        w.flush().map_err(write_err)?;
        wf.names = names.clone();
        Ok((wf, count_at, points))
    };
    match out {
        Some(path) => {
            let mut file = AtomicFile::create(path).map_err(write_err)?;
            if format == WaveFormat::RawBinary && file.is_direct() {
                return Err(write_err(std::io::Error::other(
                    "a raw file's point count is written into its header at the end, \
                     which a pipe or a device cannot take: write it to a file (or use CSV)",
                )));
            }
            let (w, count_at, points) = run(&mut file)?;
            if format == WaveFormat::RawBinary {
                let count = sim::output::raw_points(points);
                file.overwrite_at(count_at as u64, count.as_bytes())
                    .map_err(write_err)?;
            }
            Ok((w, Some(file)))
        }
        None => {
            let stdout = std::io::BufWriter::with_capacity(1 << 16, std::io::stdout().lock());
            let mut pipe = PipeOk {
                inner: stdout,
                open: true,
            };
            Ok((run(&mut pipe)?.0, None))
        }
    }
}

/// Standard output for streamed rows: once the reader has gone (`| head`),
/// further writes are dropped, not errors; the run finishes.
struct PipeOk<W: Write> {
    inner: W,
    open: bool,
}

impl<W: Write> PipeOk<W> {
    fn guard(&mut self, r: std::io::Result<()>) -> std::io::Result<()> {
        match r {
            Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => {
                self.open = false;
                Ok(())
            }
            r => r,
        }
    }
}

impl<W: Write> Write for PipeOk<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.write_all(buf).map(|_| buf.len())
    }
    fn write_all(&mut self, buf: &[u8]) -> std::io::Result<()> {
        if !self.open {
            return Ok(());
        }
        let r = self.inner.write_all(buf);
        self.guard(r)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        if !self.open {
            return Ok(());
        }
        let r = self.inner.flush();
        self.guard(r)
    }
}
