//! Where a run stops and reports: source breakpoints, the `.tran` output grid
//! (computed point by point) and the rows handed to the caller.

use super::*;

/// The breakpoints: where a source's value or slope jumps, inside (t0, t1).
/// The integrator stops and restarts at each. There is no step cap (TMAX):
/// error control keeps the accuracy, and diffsol's stop handling can leave
/// a sub-ulp step after a stop.
pub(super) fn breakpoints(sys: &EquationSystem, t0: f64, t1: f64) -> Vec<f64> {
    let mut hard: Vec<f64> = sys
        .sources
        .values()
        .flat_map(|s| s.wave.breakpoints(t1))
        .filter(|&t| t > t0 && t < t1)
        .collect();
    hard.sort_by(f64::total_cmp);
    hard.dedup_by(|a, b| (*a - *b).abs() <= 1e-12 * t1.abs().max(1e-30));
    hard
}

/// Output times: `.tran`'s uniform grid, computed point by point (a long
/// run at a fine TSTEP must not hold its grid in memory: memory stays
/// bounded by the circuit), or times given.
#[derive(Clone, Debug)]
pub(super) enum Grid {
    /// `start + k·step` for `k < n`, then `stop` when it is not on the grid.
    Uniform {
        start: f64,
        step: f64,
        n: usize,
        stop: Option<f64>,
    },
    Times(Vec<f64>),
}

impl Grid {
    /// The output times of `.tran tstep tstop tstart`.
    pub(super) fn of(tran: &crate::elab::Tran) -> Grid {
        let k = ((tran.tstop - tran.tstart) / tran.tstep + 1e-9).floor() as usize;
        let last = tran.tstart + k as f64 * tran.tstep;
        Grid::Uniform {
            start: tran.tstart,
            step: tran.tstep,
            n: k + 1,
            stop: (tran.tstop - last > 1e-9 * tran.tstep).then_some(tran.tstop),
        }
    }

    pub(super) fn len(&self) -> usize {
        match self {
            Grid::Uniform { n, stop, .. } => n + usize::from(stop.is_some()),
            Grid::Times(t) => t.len(),
        }
    }

    /// The `k`-th time (`k < len()`).
    pub(super) fn at(&self, k: usize) -> f64 {
        match *self {
            Grid::Uniform {
                start,
                step,
                n,
                stop,
            } => {
                if k < n {
                    start + k as f64 * step
                } else {
                    stop.unwrap_or(f64::NAN)
                }
            }
            Grid::Times(ref t) => t[k],
        }
    }

    pub(super) fn first(&self) -> Option<f64> {
        (self.len() > 0).then(|| self.at(0))
    }

    pub(super) fn last(&self) -> Option<f64> {
        self.len().checked_sub(1).map(|k| self.at(k))
    }
}

/// Where output rows go as they are computed (time, one value per output).
pub type RowSink<'s> = &'s mut dyn FnMut(f64, &[f64]) -> std::io::Result<()>;

/// The output rows of a run: kept (columns) or handed to a sink.
pub(super) struct Rows<'s> {
    pub(super) time: Vec<f64>,
    pub(super) data: Vec<Vec<f64>>,
    pub(super) sink: Option<RowSink<'s>>,
    pub(super) last: Option<f64>,
}

impl<'s> Rows<'s> {
    pub(super) fn new(n_out: usize, sink: Option<RowSink<'s>>) -> Rows<'s> {
        Rows {
            time: Vec::new(),
            data: vec![Vec::new(); n_out],
            sink,
            last: None,
        }
    }

    pub(super) fn push(&mut self, t: f64, out: &[f64]) -> Result<(), SimError> {
        self.last = Some(t);
        let out = &out[..self.data.len().min(out.len())];
        match &mut self.sink {
            Some(sink) => sink(t, out).map_err(|e| SimError::Write {
                path: None,
                source: std::rc::Rc::new(e),
            }),
            None => {
                self.time.push(t);
                for (col, &v) in self.data.iter_mut().zip(out) {
                    col.push(v);
                }
                Ok(())
            }
        }
    }

    pub(super) fn into_waveforms(self, stats: Stats) -> Waveforms {
        Waveforms {
            names: Vec::new(),
            time: self.time,
            data: self.data,
            stats,
            warnings: Vec::new(),
            events: Vec::new(),
        }
    }
}
