//! Switch state events (seed 004's combined simulation): each S or W
//! switch's state is a register the integration does not see change. After
//! every accepted step the controls are read along the step's interpolant;
//! where one crosses its threshold the crossing is located by bisection, the
//! step is cut there, the switch's conductance is set, and the integrator
//! restarts from the located point. A step is never taken across a crossing.

use super::*;
use std::cell::RefCell;

use crate::elab::{ElementKind, SwitchModel};

/// Interior points of a step where the controls are read besides its end:
/// a control that crosses its threshold and comes back within one step
/// (a narrow pulse at a sine's crest) is caught where one of them falls.
const SAMPLES: usize = 8;

/// A switch's change of state.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct SwitchEvent {
    pub t: f64,
    pub switch: String,
    /// The control's value at the event.
    pub control: f64,
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
    pub(super) events: RefCell<Vec<SwitchEvent>>,
    out: RefCell<Vec<f64>>,
}

impl Switches {
    /// The switches of `c` in element order (the order of their
    /// conductance parameters), with their controls as outputs.
    pub(super) fn of(c: &crate::elab::Circuit) -> (Vec<(SwitchModel, String)>, Vec<Output>) {
        let mut list = Vec::new();
        let mut controls = Vec::new();
        for e in c.elements.values() {
            if let ElementKind::Switch { sw, ctrl } = &e.kind {
                list.push(((**sw).clone(), e.name.clone()));
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

    pub(super) fn new(list: Vec<(SwitchModel, String)>, first: usize, n_out: usize) -> Switches {
        let on = list.iter().map(|(m, _)| m.initially_on).collect();
        let (models, names) = list.into_iter().unzip();
        Switches {
            models,
            names,
            first,
            on: RefCell::new(on),
            events: RefCell::new(Vec::new()),
            out: RefCell::new(vec![0.0; n_out]),
        }
    }

    pub(super) fn is_empty(&self) -> bool {
        self.models.is_empty()
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

    /// The controls at `(t, y)`.
    fn controls<M: Matrix<T = f64>>(
        &self,
        ode: &CircuitOde<M>,
        t: f64,
        y: &[f64],
    ) -> Result<Vec<f64>, SimError>
    where
        M::V: HostVec,
    {
        let mut out = self.out.borrow_mut();
        ode.outputs(t, y, &mut out)
            .map_err(|error| SimError::Eval { error })?;
        Ok(out[self.first..self.first + self.models.len()].to_vec())
    }

    /// How far past its threshold the furthest control is (positive: a
    /// switch changes state), from the controls `x`.
    fn excess(&self, x: &[f64]) -> f64 {
        let on = self.on.borrow();
        self.models
            .iter()
            .zip(x)
            .zip(on.iter())
            .map(|((m, &x), &on)| {
                let d = x - m.threshold(on);
                if on { -d } else { d }
            })
            .fold(f64::NEG_INFINITY, f64::max)
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

    /// The first crossing within the step `(t0, t1]` just taken by `solver`:
    /// its time (the first point found past the threshold, within rounding
    /// of the crossing), the state there, and the controls there (for
    /// [`Switches::commit`], once the outputs before it are recorded).
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
        if self.is_empty() || t1 <= t0 {
            return Ok(None);
        }
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
        // The first sample past a threshold brackets the crossing.
        let mut lo = t0;
        let mut hit = None;
        for j in 1..=SAMPLES {
            let t = t0 + (t1 - t0) * j as f64 / SAMPLES as f64;
            let t = if j == SAMPLES { t1 } else { t };
            let (y, x) = at(t)?;
            if self.excess(&x) > 0.0 {
                hit = Some((t, y, x));
                break;
            }
            lo = t;
        }
        let Some((mut hi, mut y, mut x)) = hit else {
            return Ok(None);
        };
        // Bisection to the resolution of the time axis.
        let resolution = 4.0 * f64::EPSILON * hi.abs().max(t1 - t0);
        while hi - lo > resolution {
            let mid = 0.5 * (lo + hi);
            if mid <= lo || mid >= hi {
                break;
            }
            let (ym, xm) = at(mid)?;
            if self.excess(&xm) > 0.0 {
                (hi, y, x) = (mid, ym, xm);
            } else {
                lo = mid;
            }
        }
        Ok(Some(Crossing {
            t: hi,
            y,
            controls: x,
        }))
    }

    /// The switches whose controls `x` at `t` are past their thresholds
    /// change state there; their conductances are set.
    pub(super) fn commit<M: Matrix<T = f64>>(&self, ode: &CircuitOde<M>, t: f64, x: &[f64])
    where
        M::V: HostVec,
    {
        let mut on = self.on.borrow_mut();
        let mut events = self.events.borrow_mut();
        for (k, m) in self.models.iter().enumerate() {
            let next = m.next(on[k], x[k]);
            if next != on[k] {
                on[k] = next;
                events.push(SwitchEvent {
                    t,
                    switch: self.names[k].clone(),
                    control: x[k],
                    on: next,
                });
            }
        }
        drop((on, events));
        self.apply(ode);
    }
}
