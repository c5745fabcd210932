//! State events (seed 004's combined simulation): each S or W switch's
//! state, and each comparison written in a B source (`v(a) > 1`, `u(x)`), is
//! a value the integration does not see change. After every accepted step
//! the controls are read along the step's interpolant; where one crosses its
//! threshold the crossing is located by bisection, the step is cut there, the
//! switch's conductance or the comparison's value is set, and the integrator
//! restarts from the located point. A step is never taken across a crossing.

use super::*;
use std::cell::RefCell;

use crate::elab::{ElementKind, SwitchModel};
use crate::ir::Cmp;
use crate::tape::HeldCmp;

/// Interior points of a step where the controls are read besides its end:
/// a control that crosses its threshold and comes back within one step
/// (a narrow pulse at a sine's crest) is caught where one of them falls.
const SAMPLES: usize = 8;

/// A comparison that flips again within this many steps of its last flip,
/// this many times in a row, chatters (a comparator driving its own input
/// with no hysteresis slides along its threshold): the run stops there with
/// a diagnostic rather than spend its step budget on the flips.
const CHATTER_STEPS: u64 = 2;
const CHATTER_FLIPS: u32 = 50;

/// A switch's change of state, or a B source's comparison's.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct StateEvent {
    pub t: f64,
    /// The switch, or the B source.
    pub element: String,
    /// The B source's comparison (`v(x) > 1`); none for a switch.
    pub condition: Option<String>,
    /// The control's value at the event (a comparison's: the difference of
    /// its operands).
    pub control: f64,
    /// The switch's new state (on), or the comparison's (it holds).
    pub on: bool,
}

/// A located crossing: its time, the state there, the controls there.
pub(super) struct Crossing {
    pub(super) t: f64,
    pub(super) y: Vec<f64>,
    pub(super) controls: Vec<f64>,
}

/// The circuit's switches during a run.
pub(super) struct Switches {
    models: Vec<SwitchModel>,
    names: Vec<String>,
    /// Where the controls start in the tape's outputs.
    first: usize,
    pub(super) on: RefCell<Vec<bool>>,
    pub(super) events: RefCell<Vec<StateEvent>>,
    out: RefCell<Vec<f64>>,
    /// Whether the tape's comparisons are held as modes (the method locates
    /// events); else they are evaluated as they fall.
    modes: bool,
    /// Each mode's last flip (the step it came in) and how many rapid
    /// flips in a row led to it (see [`CHATTER_STEPS`]).
    flips: RefCell<Vec<(u64, u32)>>,
    /// Steps searched so far.
    steps: std::cell::Cell<u64>,
    dy: RefCell<Vec<f64>>,
}

impl Switches {
    /// The switches of `c` in element order (the order of their
    /// conductance parameters), with their controls as outputs.
    pub(super) fn of(c: &crate::elab::Circuit) -> (Vec<(SwitchModel, String)>, Vec<Output>) {
        let mut list = Vec::new();
        let mut controls = Vec::new();
        for e in c.elements.values() {
            if let ElementKind::Switch { sw, ctrl } = &e.kind {
                list.push(((**sw).clone(), e.name.to_string()));
                controls.push(match ctrl {
                    Some(ctrl) => Output::Current { elem: *ctrl },
                    None => Output::Voltage {
                        pos: e.nodes[2],
                        neg: e.nodes[3],
                    },
                });
            }
        }
        (list, controls)
    }

    /// The switches `list`, their controls at `first` in `n_out` outputs;
    /// with `modes`, the tape's comparisons held too.
    pub(super) fn new(
        list: Vec<(SwitchModel, String)>,
        (first, n_out): (usize, usize),
        modes: bool,
    ) -> Switches {
        let on = list.iter().map(|(m, _)| m.initially_on).collect();
        let (models, names) = list.into_iter().unzip();
        Switches {
            models,
            names,
            first,
            on: RefCell::new(on),
            events: RefCell::new(Vec::new()),
            out: RefCell::new(vec![0.0; n_out]),
            modes,
            flips: RefCell::new(Vec::new()),
            steps: std::cell::Cell::new(0),
            dy: RefCell::new(Vec::new()),
        }
    }

    /// No switch (comparisons aside).
    pub(super) fn is_empty(&self) -> bool {
        self.models.is_empty()
    }

    /// How many switches.
    pub(super) fn len(&self) -> usize {
        self.models.len()
    }

    /// No switch and no held comparison of `ode`'s tape: no event to search.
    fn none<M: Matrix<T = f64>>(&self, ode: &CircuitOde<M>) -> bool
    where
        M::V: HostVec,
    {
        self.models.is_empty() && (!self.modes || ode.tape.modes.is_empty())
    }

    /// Hold every comparison at its value at `(t, y)` (the run's start).
    pub(super) fn hold<M: Matrix<T = f64>>(
        &self,
        ode: &CircuitOde<M>,
        t: f64,
        y: &[f64],
    ) -> Result<(), SimError>
    where
        M::V: HostVec,
    {
        let modes = &ode.tape.modes;
        if !self.modes || modes.is_empty() {
            return Ok(());
        }
        for m in modes {
            m.held.set(f64::NAN);
        }
        let x = self.controls(ode, t, y)?;
        for (m, &x) in modes.iter().zip(&x[self.models.len()..]) {
            m.held.set(m.value(x));
        }
        *self.flips.borrow_mut() = vec![(0, 0); modes.len()];
        Ok(())
    }

    /// Every switch's conductance, from its state, into the tape's registers.
    pub(super) fn apply<M: Matrix<T = f64>>(&self, ode: &CircuitOde<M>)
    where
        M::V: HostVec,
    {
        for (k, (m, &on)) in self.models.iter().zip(self.on.borrow().iter()).enumerate() {
            ode.set_switch(k, 1.0 / if on { m.ron } else { m.roff });
        }
    }

    /// The controls at `(t, y)`: the switches', then the held
    /// comparisons' (their operands' differences, from an evaluation of f).
    fn controls<M: Matrix<T = f64>>(
        &self,
        ode: &CircuitOde<M>,
        t: f64,
        y: &[f64],
    ) -> Result<Vec<f64>, SimError>
    where
        M::V: HostVec,
    {
        let mut x = Vec::new();
        if !self.models.is_empty() {
            let mut out = self.out.borrow_mut();
            ode.outputs(t, y, &mut out)
                .map_err(|error| SimError::Eval { error })?;
            x.extend_from_slice(&out[self.first..self.first + self.models.len()]);
        }
        let modes = &ode.tape.modes;
        if self.modes && !modes.is_empty() {
            let mut dy = self.dy.borrow_mut();
            dy.resize(y.len(), 0.0);
            ode.eval(t, y, &mut dy)
                .map_err(|error| SimError::Eval { error })?;
            x.extend(modes.iter().map(|m| m.control.get()));
        }
        Ok(x)
    }

    /// Whether a switch's control in `x` is past its threshold, or a held
    /// comparison's value differs from what it holds.
    fn past(&self, modes: &[HeldCmp], x: &[f64]) -> bool {
        let on = self.on.borrow();
        let (xs, xm) = x.split_at(self.models.len());
        let switch = self
            .models
            .iter()
            .zip(xs)
            .zip(on.iter())
            .any(|((m, &x), &on)| m.next(on, x) != on);
        switch
            || modes
                .iter()
                .zip(xm)
                .any(|(m, &x)| !m.held.get().is_nan() && m.value(x) != m.held.get())
    }

    /// The operating point's states: each switch's state after its control
    /// at `y`; whether any changed.
    pub(super) fn settle<M: Matrix<T = f64>>(
        &self,
        ode: &CircuitOde<M>,
        t: f64,
        y: &[f64],
    ) -> Result<bool, SimError>
    where
        M::V: HostVec,
    {
        let x = ode.tape.in_mode(Mode::Dc, || self.controls(ode, t, y))?;
        let mut changed = false;
        let mut on = self.on.borrow_mut();
        for ((m, s), &x) in self.models.iter().zip(on.iter_mut()).zip(&x) {
            let next = m.next(*s, x);
            changed |= next != *s;
            *s = next;
        }
        drop(on);
        self.apply(ode);
        Ok(changed)
    }

    /// Each control's signed distance from changing state in `x` (positive:
    /// past its threshold, see [`Switches::past`]): the quantity whose peaks
    /// between samples [`Switches::locate`] looks for.
    fn distances(&self, modes: &[HeldCmp], x: &[f64], out: &mut Vec<f64>) {
        out.clear();
        let on = self.on.borrow();
        let (xs, xm) = x.split_at(self.models.len());
        for ((m, &x), &on) in self.models.iter().zip(xs).zip(on.iter()) {
            let d = x - m.threshold(on);
            out.push(if on { -d } else { d });
        }
        for (m, &x) in modes.iter().zip(xm) {
            let held = m.held.get();
            let holds = held == 1.0;
            out.push(match m.op {
                _ if held.is_nan() => f64::NEG_INFINITY,
                Cmp::Gt | Cmp::Ge => {
                    if holds {
                        -x
                    } else {
                        x
                    }
                }
                Cmp::Lt | Cmp::Le => {
                    if holds {
                        x
                    } else {
                        -x
                    }
                }
                Cmp::Eq => {
                    if holds {
                        x.abs()
                    } else {
                        -x.abs()
                    }
                }
                Cmp::Ne => {
                    if holds {
                        -x.abs()
                    } else {
                        x.abs()
                    }
                }
            });
        }
    }

    /// The first crossing within the step `(t0, t1]` just taken by `solver`:
    /// its time (the first point found past the threshold, within rounding
    /// of the crossing), the state there, and the controls there (for
    /// [`Switches::commit`], once the outputs before it are recorded).
    ///
    /// The controls are read at [`SAMPLES`] points. A control that rises
    /// towards its threshold and turns back between samples (a sine's crest
    /// just above it) is found from its samples: where the parabola through
    /// three neighbours peaks past the threshold, the peak is searched for.
    pub(super) fn locate<'p, M, S>(
        &self,
        ode: &CircuitOde<M>,
        solver: &S,
        t0: f64,
        t1: f64,
    ) -> Result<Option<Crossing>, SimError>
    where
        M: Matrix<T = f64>,
        M::V: HostVec,
        S: OdeSolverMethod<'p, CircuitOde<M>>,
    {
        if self.none(ode) || t1 <= t0 {
            return Ok(None);
        }
        self.steps.set(self.steps.get() + 1);
        let modes = &ode.tape.modes[..];
        let at = |t: f64| -> Result<(Vec<f64>, Vec<f64>), SimError> {
            let y = if t >= solver.state().t {
                solver.state().y.slice().to_vec()
            } else {
                solver
                    .interpolate(t)
                    .map_err(|e| solver_err(t, e))?
                    .slice()
                    .to_vec()
            };
            let x = self.controls(ode, t, &y)?;
            Ok((y, x))
        };
        // Samples (time, distances); the step's start is read only where a
        // peak is looked for.
        let mut times = vec![t0];
        let mut dist: Vec<Vec<f64>> = Vec::with_capacity(SAMPLES + 1);
        let mut scratch = Vec::new();
        let mut bracket = None;
        for j in 1..=SAMPLES {
            let t = t0 + (t1 - t0) * j as f64 / SAMPLES as f64;
            let t = if j == SAMPLES { t1 } else { t };
            let (y, x) = at(t)?;
            if self.past(modes, &x) {
                bracket = Some((times[j - 1], (t, y, x)));
                break;
            }
            self.distances(modes, &x, &mut scratch);
            if j == 1 {
                let (_, x0) = at(t0)?;
                let mut d0 = Vec::new();
                self.distances(modes, &x0, &mut d0);
                dist.push(d0);
            }
            dist.push(scratch.clone());
            times.push(t);
            if j >= 2
                && let Some((lo, hit)) = self.peak(&at, modes, &times[j - 2..], &dist[j - 2..])?
            {
                bracket = Some((lo, hit));
                break;
            }
        }
        let Some((lo, (hi, y, x))) = bracket else {
            return Ok(None);
        };
        // Bisection to the resolution of the time axis.
        let resolution = 4.0 * f64::EPSILON * hi.abs().max(t1 - t0);
        let (t, (y, controls)) = bisect(lo, (hi, (y, x)), resolution, |t| {
            let (y, x) = at(t)?;
            Ok(self.past(modes, &x).then_some((y, x)))
        })?;
        Ok(Some(Crossing { t, y, controls }))
    }

    /// A crossing between three samples `times` whose distances `dist` stay
    /// below 0: where the parabola through a control's three distances peaks
    /// above 0 within them, the peak is searched for (golden section); the
    /// first point found past is the bracket's end, the first sample its
    /// start.
    #[allow(clippy::type_complexity)]
    fn peak(
        &self,
        at: &dyn Fn(f64) -> Result<(Vec<f64>, Vec<f64>), SimError>,
        modes: &[HeldCmp],
        times: &[f64],
        dist: &[Vec<f64>],
    ) -> Result<Option<(f64, (f64, Vec<f64>, Vec<f64>))>, SimError> {
        let (ta, tb, tc) = (times[0], times[1], times[2]);
        let mut scratch = Vec::new();
        for k in 0..dist[0].len() {
            let (a, b, c) = (dist[0][k], dist[1][k], dist[2][k]);
            if !(a.is_finite() && b.is_finite() && c.is_finite()) {
                continue;
            }
            // The parabola through the three points: its vertex and value.
            let (h1, h2) = (tb - ta, tc - tb);
            let (s1, s2) = ((b - a) / h1, (c - b) / h2);
            let curv = (s2 - s1) / (h1 + h2);
            if curv >= 0.0 {
                continue;
            }
            // p(t) = b + s(t - tb) + curv (t - tb)^2 near tb, with s the
            // slope at tb.
            let slope = s1 + curv * h1;
            let tv = tb - slope / (2.0 * curv);
            if !(ta..=tc).contains(&tv) {
                continue;
            }
            let top = b - slope * slope / (4.0 * curv);
            if top <= 0.0 {
                continue;
            }
            // Golden-section search for the peak of control k.
            let g = 0.5 * (5f64.sqrt() - 1.0);
            let (mut lo, mut hi) = (ta, tc);
            let mut probe = |t: f64| -> Result<(f64, Option<(f64, Vec<f64>, Vec<f64>)>), SimError> {
                let (y, x) = at(t)?;
                if self.past(modes, &x) {
                    return Ok((f64::INFINITY, Some((t, y, x))));
                }
                self.distances(modes, &x, &mut scratch);
                Ok((scratch[k], None))
            };
            let (mut u, mut v) = (hi - g * (hi - lo), lo + g * (hi - lo));
            let (mut fu, hit) = probe(u)?;
            if let Some(hit) = hit {
                return Ok(Some((ta, hit)));
            }
            let (mut fv, hit) = probe(v)?;
            if let Some(hit) = hit {
                return Ok(Some((ta, hit)));
            }
            for _ in 0..60 {
                if fu > fv {
                    (hi, v, fv) = (v, u, fu);
                    u = hi - g * (hi - lo);
                    let (f, hit) = probe(u)?;
                    if let Some(hit) = hit {
                        return Ok(Some((ta, hit)));
                    }
                    fu = f;
                } else {
                    (lo, u, fu) = (u, v, fv);
                    v = lo + g * (hi - lo);
                    let (f, hit) = probe(v)?;
                    if let Some(hit) = hit {
                        return Ok(Some((ta, hit)));
                    }
                    fv = f;
                }
                if hi - lo <= 4.0 * f64::EPSILON * hi.abs() {
                    break;
                }
            }
        }
        Ok(None)
    }

    /// In a circuit without states (switches, resistors, sources), the first
    /// crossing in `(a, b]`: its time, within `resolution`, and the controls
    /// there. Between events the controls are functions of time alone, read
    /// at `b` and at [`SAMPLES`] points before it; the first sample past a
    /// threshold is bisected against the one before it.
    pub(super) fn first_crossing_stateless<M: Matrix<T = f64>>(
        &self,
        ode: &CircuitOde<M>,
        a: f64,
        b: f64,
        resolution: f64,
    ) -> Result<Option<(f64, Vec<f64>)>, SimError>
    where
        M::V: HostVec,
    {
        let read = |t: f64| -> Result<(bool, Vec<f64>), SimError> {
            let x = self.controls(ode, t, &[])?;
            Ok((self.past(&[], &x), x))
        };
        let mut lo = a;
        for j in 1..=SAMPLES + 1 {
            let t = if j == SAMPLES + 1 {
                b
            } else {
                a + (b - a) * j as f64 / (SAMPLES + 1) as f64
            };
            let (past, x) = read(t)?;
            if !past {
                lo = t;
                continue;
            }
            return bisect(lo, (t, x), resolution, |t| {
                let (past, x) = read(t)?;
                Ok(past.then_some(x))
            })
            .map(Some);
        }
        Ok(None)
    }

    /// Commit the crossing at `t` whose controls are `x`, then every change
    /// it causes at the same instant (a switch whose conductance moves
    /// another's control past its threshold); a chain that does not end
    /// within two changes per switch is a switch driving its own control
    /// back and forth, which no time step resolves.
    pub(super) fn commit_chain<M: Matrix<T = f64>>(
        &self,
        ode: &CircuitOde<M>,
        t: f64,
        mut x: Vec<f64>,
    ) -> Result<(), SimError>
    where
        M::V: HostVec,
    {
        for _ in 0..2 * self.models.len() + 2 {
            self.commit(ode, t, &x)?;
            x = self.controls(ode, t, &[])?;
            if !self.past(&[], &x) {
                return Ok(());
            }
        }
        let k = self
            .models
            .iter()
            .zip(self.on.borrow().iter())
            .zip(&x)
            .position(|((m, &on), &x)| m.next(on, x) != on)
            .unwrap_or(0);
        Err(SimError::Chatter {
            element: self.names.get(k).cloned().unwrap_or_default(),
            condition: "its control against its threshold".into(),
            flips: (2 * self.models.len() + 2) as u32,
            steps: 0,
            t,
        })
    }

    /// The switches whose controls `x` at `t` are past their thresholds
    /// change state there, their conductances set; the comparisons whose
    /// values differ from what they hold take their new values.
    pub(super) fn commit<M: Matrix<T = f64>>(
        &self,
        ode: &CircuitOde<M>,
        t: f64,
        x: &[f64],
    ) -> Result<(), SimError>
    where
        M::V: HostVec,
    {
        let mut on = self.on.borrow_mut();
        let mut events = self.events.borrow_mut();
        for (k, m) in self.models.iter().enumerate() {
            let next = m.next(on[k], x[k]);
            if next != on[k] {
                on[k] = next;
                events.push(StateEvent {
                    t,
                    element: self.names[k].clone(),
                    condition: None,
                    control: x[k],
                    on: next,
                });
            }
        }
        drop(on);
        self.apply(ode);
        let modes = &ode.tape.modes;
        if !self.modes || modes.is_empty() {
            return Ok(());
        }
        let mut flips = self.flips.borrow_mut();
        for ((m, &x), (last, rapid)) in modes
            .iter()
            .zip(&x[self.models.len()..])
            .zip(flips.iter_mut())
        {
            let (held, now) = (m.held.get(), m.value(x));
            if held.is_nan() || now == held {
                continue;
            }
            m.held.set(now);
            events.push(StateEvent {
                t,
                element: m.element.clone(),
                condition: Some(m.text.clone()),
                control: x,
                on: now != 0.0,
            });
            let step = self.steps.get();
            *rapid = if step - *last <= CHATTER_STEPS {
                *rapid + 1
            } else {
                0
            };
            *last = step;
            if *rapid >= CHATTER_FLIPS {
                return Err(SimError::Chatter {
                    element: m.element.clone(),
                    condition: m.text.clone(),
                    flips: CHATTER_FLIPS,
                    steps: CHATTER_STEPS,
                    t,
                });
            }
        }
        Ok(())
    }
}

/// Bisect `(lo, hi.0]`, where `hi.0` is past a threshold and `lo` is not,
/// until it is narrower than `resolution`: the first point found past and
/// what `read` gave there (`None`: not past).
fn bisect<T>(
    mut lo: f64,
    mut hi: (f64, T),
    resolution: f64,
    mut read: impl FnMut(f64) -> Result<Option<T>, SimError>,
) -> Result<(f64, T), SimError> {
    while hi.0 - lo > resolution {
        let mid = 0.5 * (lo + hi.0);
        if mid <= lo || mid >= hi.0 {
            break;
        }
        match read(mid)? {
            Some(v) => hi = (mid, v),
            None => lo = mid,
        }
    }
    Ok(hi)
}
