//! The acausal equation system: variables, parameters, sources and equations,
//! each equation remembering where in the circuit it came from.

use super::entity::IdVec;
use super::expr::{ExprArena, ExprId};
use super::names::NameTable;
use crate::diag::Span;

crate::entity_id!(
    /// A variable: a node potential, a branch voltage or current, or a derivative.
    VarId,
    "x"
);
crate::entity_id!(
    /// An equation of the system.
    EqId,
    "eq"
);
crate::entity_id!(
    /// A named constant (element value, model parameter).
    ParamId,
    "p"
);
crate::entity_id!(
    /// An independent source's waveform, a known function of time.
    SourceId,
    "s"
);

/// What a variable measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum VarKind {
    /// Potential of a node against ground.
    Potential,
    /// Voltage across an element, from its first to its second terminal.
    BranchVoltage,
    /// Current through an element, entering at its first terminal.
    BranchCurrent,
    /// Time derivative of a state.
    Derivative,
    /// A stored charge (a junction's).
    Charge,
}

/// How the causalizer treats a variable.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case", tag = "role")]
pub enum VarRole {
    /// An algebraic unknown.
    Unknown,
    /// Known at every instant (integrated); `der` is its derivative unknown.
    State { der: VarId },
    /// The derivative of a state; an unknown.
    Derivative { of: VarId },
}

/// A variable; its display name (`u_R1`, `i_L1`, `v(a)`, `der(u_C1)`) is
/// [`EquationSystem::var_name`], kept apart in one buffer for all of them.
#[derive(Clone, Debug)]
pub struct Var {
    pub kind: VarKind,
    pub role: VarRole,
    /// The element (or node) the variable belongs to.
    pub origin: Origin,
    /// Set when alias elimination replaced the variable by this expression;
    /// it then occurs in no equation and is not an unknown.
    pub alias: Option<ExprId>,
}

impl Var {
    pub fn is_state(&self) -> bool {
        matches!(self.role, VarRole::State { .. })
    }

    /// Unknowns are what the causalizer must compute: everything but states
    /// and eliminated aliases.
    pub fn is_unknown(&self) -> bool {
        !self.is_state() && self.alias.is_none()
    }
}

/// Where an equation or variable came from, in circuit terms: one word of
/// kind and one pointer (every variable and equation holds one; with its
/// own span beside a two-word name it was 40 bytes, a third of a big
/// system's variables and equations).
#[derive(Clone, Debug, PartialEq)]
pub struct Origin {
    pub kind: OriginKind,
}

/// A circuit entity (element or node) that variables and equations come
/// from: its name and the netlist text that created it (element line, or
/// node first use), shared by reference count.
#[derive(Clone, PartialEq, Eq, Hash)]
pub struct Name(std::sync::Arc<Entity>);

#[derive(PartialEq, Eq, Hash)]
struct Entity {
    name: Box<str>,
    span: Option<Span>,
}

impl Name {
    pub fn new(name: &str, span: Option<Span>) -> Name {
        Name(std::sync::Arc::new(Entity {
            name: name.into(),
            span,
        }))
    }

    /// The netlist text that created the entity.
    pub fn span(&self) -> Option<Span> {
        self.0.span
    }

    pub fn as_str(&self) -> &str {
        &self.0.name
    }
}

impl AsRef<str> for Name {
    fn as_ref(&self) -> &str {
        &self.0.name
    }
}

impl PartialEq<str> for Name {
    fn eq(&self, other: &str) -> bool {
        *self.0.name == *other
    }
}

impl PartialEq<&str> for Name {
    fn eq(&self, other: &&str) -> bool {
        *self.0.name == **other
    }
}

/// A name with no netlist text behind it (tests, generated entities).
impl From<&str> for Name {
    fn from(name: &str) -> Name {
        Name::new(name, None)
    }
}

impl std::ops::Deref for Name {
    type Target = str;
    fn deref(&self) -> &str {
        &self.0.name
    }
}

impl std::fmt::Display for Name {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0.name)
    }
}

impl std::fmt::Debug for Name {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        std::fmt::Debug::fmt(&*self.0.name, f)
    }
}

#[derive(Clone, Debug, PartialEq)]
pub enum OriginKind {
    /// The constitutive equation of an element (`u = R*i`).
    Element { name: Name },
    /// The branch equation `u = v(a) - v(b)` of an element.
    Branch { name: Name },
    /// Kirchhoff's current law at a node.
    Kcl { node: Name },
    /// Kirchhoff's voltage law on a fundamental loop (boxed: rare, and
    /// larger than the other kinds, which every variable and equation
    /// would pay for).
    Kvl(Box<KvlLoop>),
    /// The time derivative of another equation (index reduction); `from`
    /// is that equation's entity, for its span.
    Derivative { of: EqId, from: Option<Name> },
    /// A node potential.
    Node { name: Name },
}

/// The fundamental loop closed by `link`, through `elements`.
#[derive(Clone, Debug, PartialEq)]
pub struct KvlLoop {
    pub link: Name,
    pub elements: Vec<Name>,
}

impl Origin {
    pub fn new(kind: OriginKind) -> Origin {
        Origin { kind }
    }

    /// The entity this comes from: the element, node or loop link (for a
    /// derivative, the differentiated equation's).
    pub fn entity(&self) -> Option<&Name> {
        match &self.kind {
            OriginKind::Element { name }
            | OriginKind::Branch { name }
            | OriginKind::Kcl { node: name }
            | OriginKind::Node { name } => Some(name),
            OriginKind::Kvl(l) => Some(&l.link),
            OriginKind::Derivative { from, .. } => from.as_ref(),
        }
    }

    /// The netlist text that created it (element line, or node first use).
    pub fn span(&self) -> Option<Span> {
        self.entity().and_then(Name::span)
    }

    /// The circuit entity this names, for messages: an element or node name.
    pub fn describe(&self) -> String {
        let mut out = String::new();
        let _ = self.write_description(&mut out);
        out
    }

    /// [`Origin::describe`] into a buffer (listings of 10^6 equations).
    pub fn write_description(&self, out: &mut impl std::fmt::Write) -> std::fmt::Result {
        match &self.kind {
            OriginKind::Element { name } => out.write_str(name),
            OriginKind::Branch { name } => write!(out, "branch of {name}"),
            OriginKind::Kcl { node } => write!(out, "KCL at node {node}"),
            OriginKind::Kvl(l) => write!(out, "KVL on the loop of {}", l.link),
            OriginKind::Derivative { of, .. } => write!(out, "d/dt of {of}"),
            OriginKind::Node { name } => write!(out, "node {name}"),
        }
    }

    /// The element names this origin involves.
    pub fn elements(&self) -> Vec<&str> {
        match &self.kind {
            OriginKind::Element { name } | OriginKind::Branch { name } => vec![&**name],
            OriginKind::Kvl(l) => l.elements.iter().map(|e| &**e).collect(),
            _ => Vec::new(),
        }
    }
}

/// An acausal equation `lhs = rhs`.
#[derive(Clone, Debug)]
pub struct Equation {
    pub lhs: ExprId,
    pub rhs: ExprId,
    pub origin: Origin,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Param {
    pub name: String,
    pub value: f64,
    /// The value of an independent DC source (ramped by source stepping).
    pub source: bool,
    /// A switch's conductance, which the simulator sets as the switch's
    /// state changes (a register of its own, never a constant).
    pub switch: bool,
    /// The factor on the MOSFET gate capacitances' floors (1; larger while
    /// the operating point is solved, see [`EquationSystem::add_floor_param`]).
    pub floor: bool,
}

/// A waveform of an independent source (ngspice semantics, defaults resolved).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
#[serde(rename_all = "lowercase", tag = "kind")]
pub enum Waveform {
    Dc {
        value: f64,
    },
    Pulse {
        v1: f64,
        v2: f64,
        td: f64,
        tr: f64,
        tf: f64,
        pw: f64,
        per: f64,
    },
    Sin {
        vo: f64,
        va: f64,
        freq: f64,
        td: f64,
        theta: f64,
        phase: f64,
    },
    Exp {
        v1: f64,
        v2: f64,
        td1: f64,
        tau1: f64,
        td2: f64,
        tau2: f64,
    },
    /// `vo + va·sin(2π·fc·t + mdi·sin(2π·fs·t))`.
    Sffm {
        vo: f64,
        va: f64,
        fc: f64,
        mdi: f64,
        fs: f64,
    },
    Pwl {
        points: Vec<(f64, f64)>,
        /// `r=`: past the last point the sequence from this time point on
        /// repeats forever (ngspice).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        repeat: Option<f64>,
        /// `td=`: the whole sequence is delayed by this.
        #[serde(default, skip_serializing_if = "is_zero")]
        delay: f64,
    },
}

fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

/// The highest derivative order [`sffm_derivative`] gives (index reduction
/// asks for a few at most); above it, NaN.
pub const SFFM_MAX_ORDER: u8 = 15;

/// The `order`-th time derivative of `sin(2π·fc·t + mdi·sin(2π·fs·t))`,
/// from the Taylor coefficients of both sines at `t` (for `y = sin φ`,
/// `z = cos φ`: `k·y_k = Σ j·φ_j·z_(k−j)`, `k·z_k = −Σ j·φ_j·y_(k−j)`),
/// times `order!`. On the stack: the tape evaluates it in every `f`.
pub fn sffm_derivative(t: f64, order: u8, fc: f64, mdi: f64, fs: f64) -> f64 {
    use std::f64::consts::PI;
    const N: usize = SFFM_MAX_ORDER as usize + 1;
    if order > SFFM_MAX_ORDER {
        return f64::NAN;
    }
    let n = order as usize + 1;
    let (wc, ws) = (2.0 * PI * fc, 2.0 * PI * fs);
    // The inner sine's coefficients (its argument is ws·(t + s)), and the
    // phase φ = wc·(t + s) + mdi·sin(ws·(t + s)).
    let (mut si, mut ci, mut phi) = ([0.0; N], [0.0; N], [0.0; N]);
    (si[0], ci[0]) = (ws * t).sin_cos();
    for k in 1..n {
        si[k] = ws * ci[k - 1] / k as f64;
        ci[k] = -ws * si[k - 1] / k as f64;
    }
    for k in 0..n {
        phi[k] = mdi * si[k]
            + match k {
                0 => wc * t,
                1 => wc,
                _ => 0.0,
            };
    }
    let (mut y, mut z) = ([0.0; N], [0.0; N]);
    (y[0], z[0]) = phi[0].sin_cos();
    for k in 1..n {
        let (mut sy, mut sz) = (0.0, 0.0);
        for j in 1..=k {
            sy += j as f64 * phi[j] * z[k - j];
            sz -= j as f64 * phi[j] * y[k - j];
        }
        y[k] = sy / k as f64;
        z[k] = sz / k as f64;
    }
    let factorial: f64 = (1..n).map(|k| k as f64).product();
    y[n - 1] * factorial
}

impl Waveform {
    /// The `order`-th time derivative at `t` (order 0 is the value). Piecewise
    /// waveforms take the right-hand derivative at their corners.
    pub fn eval(&self, t: f64, order: u8) -> f64 {
        use std::f64::consts::PI;
        // No time: no value (an integrator's first step from a state whose
        // derivatives overflow is NaN, and a PWL's segment search has none
        // to find).
        if t.is_nan() {
            return f64::NAN;
        }
        match *self {
            Waveform::Dc { value } => {
                if order == 0 {
                    value
                } else {
                    0.0
                }
            }
            Waveform::Pulse {
                v1,
                v2,
                td,
                tr,
                tf,
                pw,
                per,
            } => {
                if t < td {
                    return if order == 0 { v1 } else { 0.0 };
                }
                let mut tt = t - td;
                // ngspice (vsrcload.c) starts the next period only past
                // PER, so at t - TD = PER a pulse whose TR + PW + TF
                // exceeds PER still holds its value. Derivatives are the
                // right-sided ones the integrator steps on from a corner.
                let next_period = if order == 0 { tt > per } else { tt >= per };
                if per > 0.0 && next_period {
                    tt -= (tt / per).floor() * per;
                }
                // An edge so short that its slope overflows (TR = 5e-324)
                // is a jump: its value by the fraction of it gone, slope 0.
                let edge = |from: f64, to: f64, dur: f64, x: f64| {
                    let s = (to - from) / dur;
                    (
                        from + (to - from) * (x / dur),
                        if s.is_finite() { s } else { 0.0 },
                    )
                };
                let (value, slope) = if tt < tr {
                    edge(v1, v2, tr, tt)
                } else if tt < tr + pw {
                    (v2, 0.0)
                } else if tt < tr + pw + tf {
                    edge(v2, v1, tf, tt - tr - pw)
                } else {
                    (v1, 0.0)
                };
                match order {
                    0 => value,
                    1 => slope,
                    _ => 0.0,
                }
            }
            Waveform::Sin {
                vo,
                va,
                freq,
                td,
                theta,
                phase,
            } => {
                let ph = phase * PI / 180.0;
                if t < td {
                    return if order == 0 { vo + va * ph.sin() } else { 0.0 };
                }
                let s = t - td;
                let w = 2.0 * PI * freq;
                // va * exp(-theta s) * sin(w s + ph): derivatives via the complex
                // exponential, d^k/ds^k Im(exp((iw - theta) s + i ph)).
                let (re, im) = (-theta, w);
                let (mut cr, mut ci) = (1.0, 0.0);
                for _ in 0..order {
                    let nr = cr * re - ci * im;
                    let ni = cr * im + ci * re;
                    cr = nr;
                    ci = ni;
                }
                let env = (-theta * s).exp();
                let (sn, cs) = (w * s + ph).sin_cos();
                // Im((cr + i ci) * (cos + i sin)) = cr*sin + ci*cos
                let d = va * env * (cr * sn + ci * cs);
                if order == 0 { vo + d } else { d }
            }
            Waveform::Sffm {
                vo,
                va,
                fc,
                mdi,
                fs,
            } => {
                let d = va * sffm_derivative(t, order, fc, mdi, fs);
                if order == 0 { vo + d } else { d }
            }
            Waveform::Exp {
                v1,
                v2,
                td1,
                tau1,
                td2,
                tau2,
            } => {
                let mut value = if order == 0 { v1 } else { 0.0 };
                let term = |t0: f64, tau: f64, amp: f64| -> f64 {
                    let e = (-(t - t0) / tau).exp();
                    if order == 0 {
                        amp * (1.0 - e)
                    } else {
                        // d^k/dt^k (1 - e^{-(t-t0)/tau}) = -(-1/tau)^k e
                        -amp * (-1.0 / tau).powi(order as i32) * e
                    }
                };
                if t >= td1 {
                    value += term(td1, tau1, v2 - v1);
                }
                if t >= td2 {
                    value += term(td2, tau2, v1 - v2);
                }
                value
            }
            Waveform::Pwl {
                ref points,
                repeat,
                delay,
            } => {
                let Some(&(t0, y0)) = points.first() else {
                    return 0.0;
                };
                let t = pwl_time(points, repeat, delay, t);
                if t < t0 {
                    return if order == 0 { y0 } else { 0.0 };
                }
                // The segment containing t (right-continuous at corners).
                let k = points.partition_point(|&(tk, _)| tk <= t);
                if k >= points.len() {
                    let y = points[points.len() - 1].1;
                    return if order == 0 { y } else { 0.0 };
                }
                let (ta, ya) = points[k - 1];
                let (tb, yb) = points[k];
                let s = if tb > ta { (yb - ya) / (tb - ta) } else { 0.0 };
                match order {
                    0 => ya + s * (t - ta),
                    1 => s,
                    _ => 0.0,
                }
            }
        }
    }

    /// Times in `[0, t_end]` where the waveform or its slope jumps.
    pub fn breakpoints(&self, t_end: f64) -> Vec<f64> {
        let mut out = Vec::new();
        match *self {
            Waveform::Dc { .. } | Waveform::Sin { .. } | Waveform::Sffm { .. } => {}
            Waveform::Pulse {
                td,
                tr,
                tf,
                pw,
                per,
                ..
            } => {
                let mut start = td;
                let max_periods = 1_000_000usize;
                for _ in 0..max_periods {
                    if start > t_end {
                        break;
                    }
                    for c in [start, start + tr, start + tr + pw, start + tr + pw + tf] {
                        if c <= t_end {
                            out.push(c);
                        }
                    }
                    if per <= 0.0 {
                        break;
                    }
                    start += per;
                }
            }
            Waveform::Exp { td1, td2, .. } => {
                out.extend([td1, td2].into_iter().filter(|&t| t <= t_end));
            }
            Waveform::Pwl {
                ref points,
                repeat,
                delay,
            } => {
                out.extend(
                    points
                        .iter()
                        .map(|p| p.0 + delay)
                        .take_while(|&t| t <= t_end),
                );
                if let (Some(r), Some(&(last, _))) = (repeat, points.last())
                    && last > r
                {
                    // The corners of the repeated part, period after period:
                    // those after `r` (a period's start is the last one's
                    // end, already marked), shifted by k periods (not summed:
                    // no drift over many periods).
                    let period = last - r;
                    let after = points.partition_point(|p| p.0 <= r);
                    // At most 10^7 corners (a 1 ns repeat in a 1 s run would
                    // otherwise be 10^9 of them; the rest go unmarked).
                    'periods: for k in 1.. {
                        let shift = delay + k as f64 * period;
                        for p in &points[after..] {
                            let t = p.0 + shift;
                            if t > t_end || out.len() >= 10_000_000 {
                                break 'periods;
                            }
                            out.push(t);
                        }
                    }
                }
            }
        }
        out.retain(|&t| t > 0.0);
        out.sort_by(f64::total_cmp);
        out.dedup();
        out
    }
}

/// The time within a PWL sequence at circuit time `t`: `t - delay`, and past
/// the last point, folded back into `[repeat, last)` (right-continuous: at
/// the end of a period the sequence is at its repeat point again).
pub fn pwl_time(points: &[(f64, f64)], repeat: Option<f64>, delay: f64, t: f64) -> f64 {
    let t = t - delay;
    match (repeat, points.last()) {
        (Some(r), Some(&(last, _))) if last > r && t >= last => r + (t - r).rem_euclid(last - r),
        _ => t,
    }
}

/// An independent source's time function.
#[derive(Clone, Debug, PartialEq)]
pub struct SourceFn {
    /// The element name (`V1`); printed as `V1(t)`.
    pub name: String,
    pub wave: Waveform,
}

/// An acausal equation system: what the causalizer sorts.
///
/// Invariants (checked by [`super::verify`]): every expression operand precedes
/// its user; every `State` has a `Derivative` partner and back; the number of
/// equations equals the number of unknowns for a well-posed circuit (checked by
/// the analysis, not here).
#[derive(Clone, Debug, Default)]
pub struct EquationSystem {
    pub title: String,
    pub exprs: ExprArena,
    pub vars: IdVec<VarId, Var>,
    /// The name of every variable, one per entry of `vars` (a `String`
    /// each was a third of a big system's variable memory): add variables
    /// with [`EquationSystem::add_var`], which keeps both; `ir::verify`
    /// checks the count.
    pub names: NameTable<VarId>,
    pub params: IdVec<ParamId, Param>,
    pub sources: IdVec<SourceId, SourceFn>,
    pub eqs: IdVec<EqId, Equation>,
    /// Equations removed by alias elimination, as text for the listing.
    pub eliminated: Vec<String>,
    /// Diode models used by device functions.
    pub diodes: Vec<super::DiodeParams>,
    /// The comparisons a user wrote in B sources, with their element: each
    /// is a state event (its value held through a step, its crossing
    /// located), where a device's region choices are evaluated as they fall.
    pub events: Vec<(ExprId, Name)>,
    /// The variables of each equation, left to right without repeats, in
    /// compressed rows: computed once when the equation is added (its nodes
    /// are still in cache then), so that passes need not walk the DAGs.
    /// [`EquationSystem::add_eq`] and [`EquationSystem::rebuild_incidence`]
    /// keep it; `ir::verify` checks it.
    incidence_start: Vec<u32>,
    incidence: Vec<VarId>,
    /// [`Var::is_unknown`] of every variable, compact (a pass over 10^6
    /// `Var`s reads 100 MB); kept by the methods that change roles and
    /// aliases, checked by `ir::verify`.
    unknown: Vec<bool>,
    /// Buffers of `push_incidence` (one equation's variables, a DAG walk's
    /// stack), kept so that adding an equation allocates nothing.
    incidence_scratch: (Vec<VarId>, Vec<ExprId>),
}

impl EquationSystem {
    pub fn add_var(&mut self, name: impl AsRef<str>, kind: VarKind, origin: Origin) -> VarId {
        self.unknown.push(true);
        self.names.push(name.as_ref());
        self.vars.push(Var {
            kind,
            role: VarRole::Unknown,
            origin,
            alias: None,
        })
    }

    /// Make `state` a state with a fresh derivative unknown; returns the derivative.
    pub fn add_state(&mut self, state: VarId) -> VarId {
        let name = joined(&["der(", self.names.get(state), ")"]);
        self.names.push(&name);
        let origin = self.vars[state].origin.clone();
        let der = self.vars.push(Var {
            kind: VarKind::Derivative,
            role: VarRole::Derivative { of: state },
            origin,
            alias: None,
        });
        self.unknown.push(true);
        self.vars[state].role = VarRole::State { der };
        self.unknown[state.0 as usize] = false;
        der
    }

    /// A state and its derivative become algebraic unknowns (index reduction).
    pub fn demote_state(&mut self, state: VarId, der: VarId) {
        self.vars[state].role = VarRole::Unknown;
        self.vars[der].role = VarRole::Unknown;
        self.unknown[state.0 as usize] = self.vars[state].alias.is_none();
        self.unknown[der.0 as usize] = self.vars[der].alias.is_none();
    }

    /// `v` is replaced by `e` everywhere (alias elimination).
    pub fn set_alias(&mut self, v: VarId, e: ExprId) {
        self.vars[v].alias = Some(e);
        self.unknown[v.0 as usize] = false;
    }

    /// Recompute the unknown flags after variables were pushed directly.
    pub fn refresh_unknown(&mut self) {
        self.unknown = self.vars.values().map(Var::is_unknown).collect();
    }

    /// [`Var::is_unknown`] of every variable, by id.
    pub fn unknown_flags(&self) -> &[bool] {
        &self.unknown
    }

    /// An empty system with room for `exprs` expressions, `vars` variables
    /// and `eqs` equations.
    pub fn with_capacity(exprs: usize, vars: usize, eqs: usize) -> EquationSystem {
        let mut sys = EquationSystem {
            exprs: ExprArena::with_capacity(exprs),
            vars: IdVec::with_capacity(vars),
            eqs: IdVec::with_capacity(eqs),
            ..EquationSystem::default()
        };
        sys.unknown.reserve(vars);
        // Most generated names (`u_R12`, `v(n12)`) fit in 12 bytes.
        sys.names.reserve(vars, 12 * vars);
        sys.incidence_start.reserve(eqs + 1);
        sys.incidence.reserve(3 * eqs);
        sys
    }

    pub fn add_param(&mut self, name: String, value: f64) -> ParamId {
        self.params.push(Param {
            name,
            value,
            source: false,
            switch: false,
            floor: false,
        })
    }

    /// A parameter holding an independent DC source's value.
    pub fn add_source_param(&mut self, name: String, value: f64) -> ParamId {
        self.params.push(Param {
            name,
            value,
            source: true,
            switch: false,
            floor: false,
        })
    }

    /// A parameter holding a switch's conductance (its state).
    pub fn add_switch_param(&mut self, name: String, value: f64) -> ParamId {
        self.params.push(Param {
            name,
            value,
            source: false,
            switch: true,
            floor: false,
        })
    }

    /// The factor on capacitance floors: 1 in a transient, larger while the
    /// operating point is solved. The operating point does not depend on
    /// capacitances (every capacitor current is zero there), but the
    /// Jacobian's rounding does: a junction charge beside a floored gate
    /// capacitance 10^6 times smaller has its current computed as the
    /// difference of two currents amplified by that ratio, which cancels the
    /// junction's own conductance to zero (CircuitSim90's gm6: an exactly
    /// singular DC Jacobian).
    pub fn add_floor_param(&mut self, name: String) -> ParamId {
        self.params.push(Param {
            name,
            value: 1.0,
            source: false,
            switch: false,
            floor: true,
        })
    }

    pub fn add_eq(&mut self, lhs: ExprId, rhs: ExprId, origin: Origin) -> EqId {
        let id = self.eqs.push(Equation { lhs, rhs, origin });
        self.push_incidence(id);
        id
    }

    fn push_incidence(&mut self, eq: EqId) {
        if self.incidence_start.is_empty() {
            self.incidence_start.push(0);
        }
        let (mut vars, mut stack) = std::mem::take(&mut self.incidence_scratch);
        self.eq_vars(eq, &mut vars, &mut stack);
        self.incidence.extend_from_slice(&vars);
        self.incidence_start.push(self.incidence.len() as u32);
        self.incidence_scratch = (vars, stack);
    }

    /// Recompute the incidence after equations were replaced in place.
    pub fn rebuild_incidence(&mut self) {
        self.incidence_start.clear();
        self.incidence.clear();
        for eq in self.eqs.ids() {
            self.push_incidence(eq);
        }
    }

    /// The variables of `eq` (knowns included), as [`EquationSystem::eq_vars`]
    /// lists them, without walking its expressions.
    #[inline]
    pub fn incidence(&self, eq: EqId) -> &[VarId] {
        let k = eq.0 as usize;
        match (self.incidence_start.get(k), self.incidence_start.get(k + 1)) {
            (Some(&a), Some(&b)) => &self.incidence[a as usize..b as usize],
            _ => &[],
        }
    }

    pub fn states(&self) -> impl Iterator<Item = VarId> + '_ {
        self.vars
            .iter()
            .filter(|(_, v)| v.is_state())
            .map(|(id, _)| id)
    }

    pub fn unknowns(&self) -> impl Iterator<Item = VarId> + '_ {
        self.vars
            .iter()
            .filter(|(_, v)| v.is_unknown())
            .map(|(id, _)| id)
    }

    pub fn n_unknowns(&self) -> usize {
        self.vars.values().filter(|v| v.is_unknown()).count()
    }

    /// The distinct variables of an equation (unknowns and states).
    pub fn eq_vars(&self, eq: EqId, out: &mut Vec<VarId>, stack: &mut Vec<ExprId>) {
        out.clear();
        let e = &self.eqs[eq];
        self.exprs.vars_into(e.lhs, out, stack);
        self.exprs.vars_into(e.rhs, out, stack);
    }

    pub fn find_var(&self, name: &str) -> Option<VarId> {
        self.vars
            .iter()
            .map(|(id, _)| id)
            .find(|&id| self.names.get(id).eq_ignore_ascii_case(name))
    }

    /// The display name of `v` (`u_R1`, `der(u_C1)`).
    pub fn var_name(&self, v: VarId) -> &str {
        self.names.get(v)
    }
}

/// The concatenation of `parts`, allocated once (names of big systems are
/// built by the hundred thousand; `format!` costs twice as much).
pub fn joined(parts: &[&str]) -> String {
    let mut s = String::with_capacity(parts.iter().map(|p| p.len()).sum());
    for p in parts {
        s.push_str(p);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pulse_and_pwl_values() {
        let p = Waveform::Pulse {
            v1: 0.0,
            v2: 1.0,
            td: 1.0,
            tr: 1.0,
            tf: 1.0,
            pw: 2.0,
            per: 10.0,
        };
        assert_eq!(p.eval(0.5, 0), 0.0);
        assert_eq!(p.eval(1.5, 0), 0.5);
        assert_eq!(p.eval(1.5, 1), 1.0);
        assert_eq!(p.eval(3.0, 0), 1.0);
        assert_eq!(p.eval(4.5, 0), 0.5);
        assert_eq!(p.eval(11.5, 0), 0.5);
        assert_eq!(p.breakpoints(12.0), vec![1.0, 2.0, 4.0, 5.0, 11.0, 12.0]);
        // ngspice's boundaries: a pulse whose TR + PW + TF overruns its
        // period (TR = TF = TSTEP by default) still holds V2 at TD + PER;
        // the next period starts just past it, from V1, and at 2 PER.
        let whole = Waveform::Pulse {
            v1: 0.0,
            v2: 10.0,
            td: 0.0,
            tr: 0.01,
            tf: 0.01,
            pw: 10.0,
            per: 10.0,
        };
        assert_eq!(whole.eval(10.0, 0), 10.0);
        assert!((whole.eval(10.005, 0) - 5.0).abs() < 1e-9);
        assert_eq!(whole.eval(20.0, 0), 0.0);
        // The integrator steps on from a corner with the right-sided slope.
        assert!((whole.eval(10.0, 1) - 1000.0).abs() < 1e-9);
        let w = Waveform::Pwl {
            points: vec![(0.0, 0.0), (1.0, 2.0), (3.0, 0.0)],
            repeat: None,
            delay: 0.0,
        };
        assert_eq!(w.eval(0.5, 0), 1.0);
        assert_eq!(w.eval(2.0, 0), 1.0);
        assert_eq!(w.eval(2.0, 1), -1.0);
        assert_eq!(w.eval(5.0, 0), 0.0);
    }

    /// ngspice's `r=` and `td=` (values as ngspice 39 prints them).
    #[test]
    fn pwl_repeats_and_delays() {
        let pts = vec![(0.0, 0.0), (1.0, 1.0), (3.0, 0.0)];
        let pwl = |repeat, delay| Waveform::Pwl {
            points: pts.clone(),
            repeat,
            delay,
        };
        // r = 0: the whole sequence, period 3.
        let w = pwl(Some(0.0), 0.0);
        assert_eq!(w.eval(3.5, 0), 0.5);
        assert_eq!(w.eval(7.0, 0), 1.0);
        assert_eq!(w.eval(7.5, 1), -0.5);
        // r = 1: the part from 1 to 3, period 2 (a jump back to 1 V).
        let w = pwl(Some(1.0), 0.0);
        assert_eq!(w.eval(2.5, 0), 0.25);
        assert_eq!(w.eval(3.25, 0), 0.875);
        assert_eq!(w.eval(5.0, 0), 1.0);
        // td = 0.5 delays it all, repeat included.
        let w = pwl(Some(1.0), 0.5);
        assert_eq!(w.eval(0.75, 0), 0.25);
        assert_eq!(w.eval(3.75, 0), 0.875);
        assert_eq!(w.breakpoints(8.0), vec![0.5, 1.5, 3.5, 5.5, 7.5]);
        let w = pwl(Some(0.0), 0.0);
        assert_eq!(w.breakpoints(7.0), vec![1.0, 3.0, 4.0, 6.0, 7.0]);
    }

    #[test]
    fn sin_derivatives_match_finite_differences() {
        let w = Waveform::Sin {
            vo: 0.5,
            va: 2.0,
            freq: 3.0,
            td: 0.1,
            theta: 0.7,
            phase: 30.0,
        };
        let (t, h) = (0.37, 1e-6);
        for order in 0..3u8 {
            let fd = (w.eval(t + h, order) - w.eval(t - h, order)) / (2.0 * h);
            let d = w.eval(t, order + 1);
            assert!(
                (fd - d).abs() < 1e-4 * d.abs().max(1.0),
                "order {order}: {fd} vs {d}"
            );
        }
        let e = Waveform::Exp {
            v1: 0.0,
            v2: 1.0,
            td1: 0.1,
            tau1: 0.2,
            td2: 0.5,
            tau2: 0.3,
        };
        for t in [0.3, 0.7] {
            let fd = (e.eval(t + h, 0) - e.eval(t - h, 0)) / (2.0 * h);
            assert!((fd - e.eval(t, 1)).abs() < 1e-6);
        }
    }

    /// A time that is not a number gives no value, not a panic: a PWL's
    /// segment search found none before it (a fuzz finding, where an
    /// integrator's first step from overflowing derivatives was NaN).
    #[test]
    fn no_time_is_no_value() {
        let w = Waveform::Pwl {
            points: vec![(0.0, 1.0), (1.0, 2.0)],
            repeat: None,
            delay: 0.0,
        };
        for order in 0..2 {
            assert!(w.eval(f64::NAN, order).is_nan());
        }
    }

    /// SFFM's value is SPICE3's formula, and each derivative order (from
    /// Taylor coefficients) is the finite difference of the one below.
    #[test]
    fn sffm_derivatives_match_finite_differences() {
        let w = Waveform::Sffm {
            vo: 0.5,
            va: 2.0,
            fc: 3.0,
            mdi: 1.7,
            fs: 0.8,
        };
        let t = 0.37;
        let tau = 2.0 * std::f64::consts::PI;
        let exact = 0.5 + 2.0 * (tau * 3.0 * t + 1.7 * (tau * 0.8 * t).sin()).sin();
        assert!((w.eval(t, 0) - exact).abs() < 1e-12);
        let h = 1e-6;
        for order in 0..5u8 {
            let fd = (w.eval(t + h, order) - w.eval(t - h, order)) / (2.0 * h);
            let d = w.eval(t, order + 1);
            assert!(
                (fd - d).abs() < 1e-6 * d.abs().max(1.0),
                "order {}: {fd} vs {d}",
                order + 1
            );
        }
    }
}
