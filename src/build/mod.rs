//! Circuit → acausal [`EquationSystem`]: one constitutive equation per
//! element, Kirchhoff's laws, and (optionally) alias elimination.
//!
//! Default (nodal) formulation: per element a branch voltage `u_X` and current
//! `i_X`, node potentials `v(n)`, `u_X = v(a) - v(b)` per branch, KCL at every
//! node but ground. Ground's potential is the constant 0 (the `v(0) = 0`
//! equation is substituted at build time). The loop formulation writes KVL on
//! the fundamental loops of a normal spanning tree instead of branch equations.
//! Capacitor voltages and inductor currents are the states.
//!
//! It knows the circuit and the IR, nothing of sorting or simulation.

mod alias;
pub mod coupling;
mod tree;

use std::collections::HashMap;

use crate::elab::{Circuit, ElemId, ElementKind, GROUND, NodeId};
use crate::ir::{
    EquationSystem, ExprId, KvlLoop, Name, Origin, OriginKind, SourceFn, VarId, VarKind, Waveform,
    joined,
};

pub use crate::ir::{VT_27C, thermal_voltage};

/// How Kirchhoff's voltage law is written.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub enum Kvl {
    /// Node potentials and one branch equation per element.
    #[default]
    Nodes,
    /// KVL on the fundamental loops of a spanning tree (no node potentials).
    Loops,
}

/// Options for [`build`].
#[derive(Clone, Copy, Debug, Default)]
pub struct Options {
    pub kvl: Kvl,
    /// Eliminate `x = y`, `x = -y` and `x = known` equations.
    pub alias: bool,
    /// Junction and device charges are algebraic, `q = Q(u)`, and carry no
    /// current (`i = I`): the circuit at DC, whose unknowns are then its
    /// node voltages and branch currents alone (the operating point's
    /// image, see `sim::ic`).
    pub algebraic_charges: bool,
}

/// The variables of one element.
#[derive(Clone, Copy, Debug)]
pub struct ElemVars {
    pub u: VarId,
    pub i: VarId,
}

/// The system plus the maps from circuit entities to its variables.
#[derive(Clone, Debug, Default)]
pub struct Built {
    pub system: EquationSystem,
    /// Branch voltage and current of each element (`None` for K).
    pub elem_vars: Vec<Option<ElemVars>>,
    /// Expression of each node's potential (ground: the constant 0).
    pub node_pot: Vec<ExprId>,
    /// Coupled inductors with a singular inductance matrix, written with
    /// fluxes as states (see [`coupling`]).
    pub reduced: Vec<coupling::Reduced>,
    /// The K elements of each coupled group whose inductance matrix is
    /// indefinite (see [`coupling::Groups::indefinite`]).
    pub indefinite: Vec<Vec<ElemId>>,
    /// The state of each pivot of `reduced`: `fluxes[g][k]` is the
    /// magnetizing current `im` of pivot `k` of group `g`.
    pub fluxes: Vec<Vec<VarId>>,
    /// The circuit's loops and cutsets with no state kept by choice, where
    /// the branch equations needed them (`Kvl::Nodes`): the sort reuses them.
    pub faults: Option<Vec<crate::elab::topology::Fault>>,
    /// The charge state `q` of each junction charge (diodes' and
    /// transistors' charge branches).
    pub charges: HashMap<ElemId, VarId>,
}

/// Build the equations of `circuit`.
pub fn build(circuit: &Circuit, opts: Options) -> Built {
    let n = circuit.elements.len() + circuit.nodes.len();
    let groups = coupling::classify(circuit);
    let mut b = Builder {
        c: circuit,
        sys: {
            // A flat circuit's system has about four expressions, two
            // variables and two equations per element or node, and the
            // schedule adds about one expression per equation to the same
            // arena: room for both, so that the arena is not doubled for
            // the schedule's few (on an RC ladder of 10^5 sections it was,
            // at 1.2·10^6 of 1.5·10^6 expressions, and the copy stayed
            // resident: 15 MB of `kausal sim`'s peak, with the growth of
            // its hash table).
            let mut sys = EquationSystem::with_capacity(6 * n, 2 * n, 2 * n);
            sys.title = circuit.title.clone();
            sys.params = crate::ir::IdVec::with_capacity(n);
            // Transistors' junction functions first: their index in the
            // circuit is their device-function index.
            sys.diodes = circuit.junctions.clone();
            sys
        },
        names: circuit.elements.values().map(|e| e.name.clone()).collect(),
        node_names: circuit.nodes.values().map(|n| n.name.clone()).collect(),
        reduced: groups.singular,
        fluxes: Vec::new(),
        intermediates: HashMap::new(),
        charges: HashMap::new(),
        floor: None,
        algebraic_charges: opts.algebraic_charges,
    };
    let elem_vars = b.element_vars();
    let node_pot = match opts.kvl {
        Kvl::Nodes => b.node_potentials(),
        Kvl::Loops => tree::potentials_from_tree(&mut b.sys, circuit, &elem_vars),
    };
    b.element_equations(&elem_vars, &node_pot);
    b.kcl(&elem_vars);
    let faults = match opts.kvl {
        Kvl::Nodes => Some(b.branch_equations(&elem_vars, &node_pot)),
        Kvl::Loops => {
            tree::loop_equations(&mut b.sys, circuit, &elem_vars, &node_pot);
            None
        }
    };
    let mut built = Built {
        system: b.sys,
        elem_vars,
        node_pot,
        reduced: b.reduced,
        indefinite: groups.indefinite,
        fluxes: b.fluxes,
        faults,
        charges: b.charges,
    };
    if opts.alias {
        alias::eliminate(&mut built, circuit);
    }
    built
}

struct Builder<'c> {
    c: &'c Circuit,
    sys: EquationSystem,
    /// Element names, shared by every origin that mentions them.
    names: Vec<Name>,
    /// Node names, as `names` (a node's potential and its KCL).
    node_names: Vec<Name>,
    reduced: Vec<coupling::Reduced>,
    fluxes: Vec<Vec<VarId>>,
    /// The variable of each device intermediate, by element.
    intermediates: HashMap<ElemId, VarId>,
    /// The charge state of each junction charge, by element.
    charges: HashMap<ElemId, VarId>,
    /// The factor on capacitance floors, once a floor asks for it.
    floor: Option<crate::ir::ParamId>,
    /// See [`Options::algebraic_charges`].
    algebraic_charges: bool,
}

impl Builder<'_> {
    fn elem_origin(&self, id: ElemId) -> Origin {
        Origin {
            kind: OriginKind::Element {
                name: self.names[id.0 as usize].clone(),
            },
        }
    }
}

impl Builder<'_> {
    fn element_vars(&mut self) -> Vec<Option<ElemVars>> {
        let mut out = Vec::with_capacity(self.c.elements.len());
        for (id, e) in self.c.elements.iter() {
            if matches!(e.kind, ElementKind::Coupling { .. }) {
                out.push(None);
                continue;
            }
            if let ElementKind::Intermediate { .. } = e.kind {
                let v =
                    self.sys
                        .add_var(e.name.clone(), VarKind::BranchVoltage, self.elem_origin(id));
                self.intermediates.insert(id, v);
                out.push(None);
                continue;
            }
            let origin = self.elem_origin(id);
            let u = self.sys.add_var(
                joined(&["u_", &e.name]),
                VarKind::BranchVoltage,
                origin.clone(),
            );
            let i = self
                .sys
                .add_var(joined(&["i_", &e.name]), VarKind::BranchCurrent, origin);
            match e.kind {
                ElementKind::Capacitor { .. }
                | ElementKind::DeviceBranch {
                    capacitance: Some(_),
                    ..
                } => {
                    self.sys.add_state(u);
                }
                ElementKind::Inductor { .. } if !self.in_reduced(id) => {
                    self.sys.add_state(i);
                }
                _ => {}
            }
            out.push(Some(ElemVars { u, i }));
        }
        // A reduced group's states: its pivots' magnetizing currents.
        for g in 0..self.reduced.len() {
            let pivots = self.reduced[g].pivots.clone();
            let vars = pivots
                .iter()
                .map(|&p| {
                    let e = self.reduced[g].members[p];
                    let im = self.sys.add_var(
                        joined(&["im_", &self.c.elements[e].name]),
                        VarKind::BranchCurrent,
                        self.elem_origin(e),
                    );
                    self.sys.add_state(im);
                    im
                })
                .collect();
            self.fluxes.push(vars);
        }
        out
    }

    fn in_reduced(&self, id: ElemId) -> bool {
        self.reduced.iter().any(|g| g.members.contains(&id))
    }

    /// The equations of the reduced groups (see [`coupling`]).
    fn reduced_equations(&mut self, vars: &[Option<ElemVars>]) {
        let reduced = std::mem::take(&mut self.reduced);
        for (g, group) in reduced.iter().enumerate() {
            let ev = |k: usize| vars[group.members[k].0 as usize].expect("an inductor has vars");
            let name = |k: usize| self.c.elements[group.members[k]].name.clone();
            for (j, &p) in group.pivots.iter().enumerate() {
                let im = self.fluxes[g][j];
                // u_p = L_pp·der(im_p)
                let l = self.value_param(&name(p), group.l_pivot[j]);
                let der = self.der_of(im);
                let x = &mut self.sys.exprs;
                let (u, rhs) = (x.var(ev(p).u), x.mul(l, der));
                let origin = self.elem_origin(group.members[p]);
                self.sys.add_eq(u, rhs, origin.clone());
                // im_p = Σ_j (L_pj/L_pp)·i_j
                let mut terms = Vec::new();
                for (k, &a) in group.flux[j].iter().enumerate() {
                    if a == 0.0 {
                        continue;
                    }
                    let i = self.sys.exprs.var(ev(k).i);
                    terms.push(if k == p {
                        i
                    } else {
                        let c = self.value_param(&format!("n_{}_{}", name(p), name(k)), a);
                        self.sys.exprs.mul(c, i)
                    });
                }
                let x = &mut self.sys.exprs;
                let (lhs, rhs) = (x.var(im), x.sum(terms));
                self.sys.add_eq(lhs, rhs, origin);
            }
            // u_q = Σ_p C_qp·u_p
            for (q, row) in &group.ratio {
                let mut terms = Vec::new();
                for (j, &c) in row.iter().enumerate() {
                    let p = group.pivots[j];
                    if c == 0.0 {
                        continue;
                    }
                    let c = self.value_param(&format!("c_{}_{}", name(*q), name(p)), c);
                    let u = self.sys.exprs.var(ev(p).u);
                    terms.push(self.sys.exprs.mul(c, u));
                }
                let x = &mut self.sys.exprs;
                let (lhs, rhs) = (x.var(ev(*q).u), x.sum(terms));
                let origin = self.elem_origin(group.members[*q]);
                self.sys.add_eq(lhs, rhs, origin);
            }
        }
        self.reduced = reduced;
    }

    fn node_potentials(&mut self) -> Vec<ExprId> {
        let mut pots = Vec::with_capacity(self.c.nodes.len());
        for (id, n) in self.c.nodes.iter() {
            if id == GROUND {
                pots.push(self.sys.exprs.constant(0.0));
                continue;
            }
            let v = self.sys.add_var(
                joined(&["v(", &n.name, ")"]),
                VarKind::Potential,
                Origin {
                    kind: OriginKind::Node {
                        name: self.node_names[id.0 as usize].clone(),
                    },
                },
            );
            pots.push(self.sys.exprs.var(v));
        }
        pots
    }

    fn value_param(&mut self, name: &str, value: f64) -> ExprId {
        let p = self.sys.add_param(name.to_string(), value);
        self.sys.exprs.param(p)
    }

    fn source_expr(&mut self, name: &str, wave: &Waveform) -> ExprId {
        match wave {
            Waveform::Dc { value } => {
                let p = self.sys.add_source_param(name.to_string(), *value);
                self.sys.exprs.param(p)
            }
            w => {
                let s = self.sys.sources.push(SourceFn {
                    name: name.to_string(),
                    wave: w.clone(),
                });
                self.sys.exprs.source(s, 0)
            }
        }
    }

    fn element_equations(&mut self, vars: &[Option<ElemVars>], pots: &[ExprId]) {
        // Mutual inductances seen by each inductor: (other inductor, M param).
        let mut mutual: HashMap<ElemId, Vec<(ElemId, ExprId)>> = HashMap::new();
        for (_, e) in self.c.elements.iter() {
            if let ElementKind::Coupling { l1, l2, k } = e.kind
                && !self.in_reduced(l1)
            {
                let (ElementKind::Inductor { l: la, .. }, ElementKind::Inductor { l: lb, .. }) =
                    (&self.c.elements[l1].kind, &self.c.elements[l2].kind)
                else {
                    continue;
                };
                let m = self.value_param(&format!("M_{}", e.name), k * (la * lb).sqrt());
                mutual.entry(l1).or_default().push((l2, m));
                mutual.entry(l2).or_default().push((l1, m));
            }
        }
        for (id, e) in self.c.elements.iter() {
            if let ElementKind::Intermediate { expr, controls, .. } = &e.kind {
                let rhs = self.behavioural(id, expr, controls, vars, pots);
                let lhs = self.sys.exprs.var(self.intermediates[&id]);
                self.sys.add_eq(lhs, rhs, self.elem_origin(id));
                continue;
            }
            let Some(ev) = vars[id.0 as usize] else {
                continue;
            };
            let x = &mut self.sys.exprs;
            let u = x.var(ev.u);
            let i = x.var(ev.i);
            let ctrl_v = |n: &[NodeId], x: &mut crate::ir::ExprArena| {
                x.sub(pots[n[2].0 as usize], pots[n[3].0 as usize])
            };
            let (lhs, rhs) = match &e.kind {
                ElementKind::Resistor { r } => {
                    let p = self.value_param(&e.name, *r);
                    let rhs = self.sys.exprs.mul(p, i);
                    (u, rhs)
                }
                ElementKind::Capacitor { c, .. } => {
                    let p = self.value_param(&e.name, *c);
                    let der = self.der_of(ev.u);
                    let rhs = self.sys.exprs.mul(p, der);
                    (i, rhs)
                }
                ElementKind::Inductor { .. } if self.in_reduced(id) => continue,
                ElementKind::Inductor { l, .. } => {
                    let p = self.value_param(&e.name, *l);
                    let der = self.der_of(ev.i);
                    let mut rhs = self.sys.exprs.mul(p, der);
                    for &(other, m) in mutual.get(&id).map(Vec::as_slice).unwrap_or(&[]) {
                        let Some(ov) = vars[other.0 as usize] else {
                            continue;
                        };
                        let d = self.der_of(ov.i);
                        let t = self.sys.exprs.mul(m, d);
                        rhs = self.sys.exprs.add(rhs, t);
                    }
                    (u, rhs)
                }
                ElementKind::VSource { wave } => (u, self.source_expr(&e.name, wave)),
                ElementKind::ISource { wave } => (i, self.source_expr(&e.name, wave)),
                ElementKind::Vcvs { gain } => {
                    let p = self.value_param(&e.name, *gain);
                    let cv = ctrl_v(&e.nodes, &mut self.sys.exprs);
                    (u, self.sys.exprs.mul(p, cv))
                }
                ElementKind::Vccs { gm } => {
                    let p = self.value_param(&e.name, *gm);
                    let cv = ctrl_v(&e.nodes, &mut self.sys.exprs);
                    (i, self.sys.exprs.mul(p, cv))
                }
                ElementKind::Cccs { gain, ctrl } => {
                    let p = self.value_param(&e.name, *gain);
                    let ci = self.ctrl_current(vars, *ctrl);
                    (i, self.sys.exprs.mul(p, ci))
                }
                ElementKind::Ccvs { r, ctrl } => {
                    let p = self.value_param(&e.name, *r);
                    let ci = self.ctrl_current(vars, *ctrl);
                    (u, self.sys.exprs.mul(p, ci))
                }
                ElementKind::Diode { model, area } => {
                    self.diode(id, ev, model, *area);
                    continue;
                }
                ElementKind::Behavioural {
                    current,
                    expr,
                    controls,
                } => {
                    let rhs = self.behavioural(id, expr, controls, vars, pots);
                    (if *current { i } else { u }, rhs)
                }
                ElementKind::DeviceBranch {
                    current,
                    charge,
                    capacitance,
                    controls,
                    ..
                } => {
                    self.device_branch(
                        id,
                        ev,
                        [current, charge, capacitance].map(|x| x.as_deref()),
                        controls,
                        vars,
                        pots,
                    );
                    continue;
                }
                ElementKind::Coupling { .. } => continue,
                ElementKind::Intermediate { .. } => continue,
                // i = g·u, the conductance g a register the simulator sets.
                ElementKind::Switch { sw, .. } => {
                    let g = if sw.initially_on { sw.ron } else { sw.roff };
                    let p = self.sys.add_switch_param(joined(&["g_", &e.name]), 1.0 / g);
                    let g = self.sys.exprs.param(p);
                    (i, self.sys.exprs.mul(g, u))
                }
            };
            self.sys.add_eq(lhs, rhs, self.elem_origin(id));
        }
        self.reduced_equations(vars);
    }

    /// A B source's expression over node potentials, controlling currents
    /// and time, as written.
    fn behavioural(
        &mut self,
        elem: ElemId,
        e: &crate::elab::BExpr,
        controls: &[ElemId],
        vars: &[Option<ElemVars>],
        pots: &[ExprId],
    ) -> ExprId {
        use crate::elab::{Arith, BNode};
        let mut ids: Vec<ExprId> = Vec::with_capacity(e.nodes.len());
        for n in &e.nodes {
            let at = |k: u32| ids[k as usize];
            let id = match *n {
                BNode::Num(v) => self.sys.exprs.constant(v),
                BNode::Floor(v) => {
                    let sys = &mut self.sys;
                    let p = *self
                        .floor
                        .get_or_insert_with(|| sys.add_floor_param("floor_factor".into()));
                    let (v, p) = (sys.exprs.constant(v), sys.exprs.param(p));
                    sys.exprs.mul(v, p)
                }
                BNode::Time => self.sys.exprs.time(),
                BNode::Pot(node) => pots[node.0 as usize],
                BNode::Current(k) => self.ctrl_current(vars, controls[k as usize]),
                BNode::Volt(k) => {
                    let ctrl = controls[k as usize];
                    match vars.get(ctrl.0 as usize).copied().flatten() {
                        Some(cv) => self.sys.exprs.var(cv.u),
                        None => match self.intermediates.get(&ctrl) {
                            Some(&v) => self.sys.exprs.var(v),
                            None => self.sys.exprs.constant(0.0),
                        },
                    }
                }
                BNode::Junction {
                    junction,
                    part,
                    arg,
                } => {
                    let f = crate::ir::DeviceFn {
                        diode: junction,
                        part,
                        order: 0,
                    };
                    self.sys.exprs.intern(crate::ir::Expr::Device(f, at(arg)))
                }
                BNode::Neg(a) => self.sys.exprs.neg(at(a)),
                BNode::Arith(op, a, b) => {
                    let (a, b) = (at(a), at(b));
                    let x = &mut self.sys.exprs;
                    match op {
                        Arith::Add => x.add(a, b),
                        Arith::Sub => x.sub(a, b),
                        Arith::Mul => x.mul(a, b),
                        Arith::Div => x.div(a, b),
                        Arith::Pow => x.pow(a, b),
                    }
                }
                BNode::Cmp(op, a, b) => {
                    let c = self.sys.exprs.cmp(op, at(a), at(b));
                    let k = ids.len() as u32;
                    if e.events.contains(&k)
                        && matches!(self.sys.exprs.get(c), crate::ir::Expr::Cmp(..))
                    {
                        self.sys
                            .events
                            .push((c, self.names[elem.0 as usize].clone()));
                    }
                    c
                }
                BNode::Select(c, a, b) => self.sys.exprs.select(at(c), at(a), at(b)),
                BNode::Call(f, a) => self.sys.exprs.call(f, at(a)),
                // A state held equal to the operand: its derivative is the
                // operand's, which index reduction writes out by
                // differentiating the constraint.
                BNode::Ddt(a) => {
                    let name = format!("ddt{}_{}", ids.len(), self.names[elem.0 as usize]);
                    let origin = self.elem_origin(elem);
                    let s = self
                        .sys
                        .add_var(name, VarKind::BranchVoltage, origin.clone());
                    self.sys.add_state(s);
                    let lhs = self.sys.exprs.var(s);
                    self.sys.add_eq(lhs, at(a), origin);
                    self.der_of(s)
                }
            };
            ids.push(id);
        }
        ids.pop().unwrap_or_else(|| self.sys.exprs.constant(0.0))
    }

    /// A transistor's branch: `i = I + der(q)` and `q = Q`, the charge `q`
    /// its state (as a diode's junction charge, see [`Builder::diode`]);
    /// with a capacitance `C`, `i = I + C·der(u)`, the branch voltage `u`
    /// its state (as a capacitor's).
    fn device_branch(
        &mut self,
        id: ElemId,
        ev: ElemVars,
        [current, charge, capacitance]: [Option<&crate::elab::BExpr>; 3],
        controls: &[ElemId],
        vars: &[Option<ElemVars>],
        pots: &[ExprId],
    ) {
        let origin = self.elem_origin(id);
        let mut rhs = match current {
            Some(c) => self.behavioural(id, c, controls, vars, pots),
            None => self.sys.exprs.constant(0.0),
        };
        if let Some(q) = charge {
            let name = joined(&["q_", &self.c.elements[id].name]);
            let qv = self.sys.add_var(name, VarKind::Charge, origin.clone());
            self.charges.insert(id, qv);
            let law = self.behavioural(id, q, controls, vars, pots);
            if !self.algebraic_charges {
                let der = self.sys.add_state(qv);
                let dq = self.sys.exprs.var(der);
                rhs = self.sys.exprs.add(rhs, dq);
            }
            let qx = self.sys.exprs.var(qv);
            self.sys.add_eq(qx, law, origin.clone());
        }
        if let Some(c) = capacitance {
            let c = self.behavioural(id, c, controls, vars, pots);
            let du = self.der_of(ev.u);
            let t = self.sys.exprs.mul(c, du);
            rhs = self.sys.exprs.add(rhs, t);
        }
        let i = self.sys.exprs.var(ev.i);
        self.sys.add_eq(i, rhs, origin);
    }

    fn der_of(&mut self, state: VarId) -> ExprId {
        match self.sys.vars[state].role {
            crate::ir::VarRole::State { der } => self.sys.exprs.var(der),
            _ => unreachable!("capacitor voltages and inductor currents are states"),
        }
    }

    fn ctrl_current(&mut self, vars: &[Option<ElemVars>], ctrl: ElemId) -> ExprId {
        match vars.get(ctrl.0 as usize).copied().flatten() {
            Some(cv) => self.sys.exprs.var(cv.i),
            // Elaboration guarantees a valid controlling source.
            None => self.sys.exprs.constant(0.0),
        }
    }

    /// ngspice's level-1 diode. Without stored charge: `i = id(uj)`. With it
    /// (CJO or TT): the junction charge `q` is the state, as in SPICE's
    /// charge-based formulation, `i = id(uj) + der(q)` and `q = q(uj)` (which
    /// gives `uj` back by a Newton solve with junction limiting): in charge
    /// the diode is nearly linear, where in voltage it is exponential. With
    /// RS > 0, `u = uj + RS*i`; else `uj` is the branch voltage.
    fn diode(&mut self, id: ElemId, ev: ElemVars, m: &crate::elab::DiodeModel, area: f64) {
        use crate::elab::thermal::{CELSIUS_K, Thermal};
        use crate::ir::{DeviceFn, DiodePart, Expr};
        let name = self.c.elements[id].name.clone();
        // At TEMP, from the model's TNOM (ngspice's diotemp.c, TLEV 0):
        // the saturation current, the junction potential and capacitance.
        let options = &self.c.options;
        let th = Thermal::new(
            m.tnom.or(options.tnom).unwrap_or(27.0) + CELSIUS_K,
            options.temp.unwrap_or(27.0) + CELSIUS_K,
        );
        let vte = m.n * th.vt;
        let is = th.diode_saturation(m.is, m.n, m.eg, m.xti) * area;
        let vj = th.potential(m.vj);
        let params = crate::ir::DiodeParams {
            name: name.to_string(),
            is,
            vte,
            bv: m
                .bv
                .map(|bv| crate::ir::DiodeParams::match_breakdown(bv, m.ibv * area, is, vte)),
            gmin: 1e-12,
            cjo: m.cjo * area * th.capacitance(m.m, m.vj),
            vj,
            m: m.m,
            fc: m.fc,
            tt: m.tt,
            fwd: crate::ir::DiodeParams::forward_constants(vj, m.m, m.fc),
        };
        let charge = params.has_charge();
        let k = self.sys.diodes.len() as u32;
        self.sys.diodes.push(params);
        let origin = self.elem_origin(id);
        let uj = if m.rs > 0.0 {
            let j = self
                .sys
                .add_var(format!("uj_{name}"), VarKind::BranchVoltage, origin.clone());
            let rs = self.value_param(&format!("{name}.rs"), m.rs / area);
            let x = &mut self.sys.exprs;
            let (u, i, ju) = (x.var(ev.u), x.var(ev.i), x.var(j));
            let drop = x.mul(rs, i);
            let rhs = x.add(ju, drop);
            self.sys.add_eq(u, rhs, origin.clone());
            j
        } else {
            ev.u
        };
        let f = |part, order| DeviceFn {
            diode: k,
            part,
            order,
        };
        let ujx = self.sys.exprs.var(uj);
        let current = self
            .sys
            .exprs
            .intern(Expr::Device(f(DiodePart::Current, 0), ujx));
        let i = self.sys.exprs.var(ev.i);
        if charge {
            let q = self
                .sys
                .add_var(format!("q_{name}"), VarKind::Charge, origin.clone());
            self.charges.insert(id, q);
            // At DC (algebraic charges) the charge carries no current.
            let rhs = if self.algebraic_charges {
                current
            } else {
                let der = self.sys.add_state(q);
                let dq = self.sys.exprs.var(der);
                self.sys.exprs.add(current, dq)
            };
            let x = &mut self.sys.exprs;
            let qx = x.var(q);
            let law = x.intern(Expr::Device(f(DiodePart::Charge, 0), ujx));
            self.sys.add_eq(i, rhs, origin.clone());
            self.sys.add_eq(qx, law, origin);
        } else {
            self.sys.add_eq(i, current, origin);
        }
    }

    /// KCL at every node but ground: currents in = currents out.
    fn kcl(&mut self, vars: &[Option<ElemVars>]) {
        let n = self.c.nodes.len();
        // Terminals by node in compressed form: (current, enters the node).
        let mut start = vec![0u32; n + 1];
        for (id, e) in self.c.elements.iter() {
            if vars[id.0 as usize].is_some() {
                start[e.nodes[0].0 as usize + 1] += 1;
                start[e.nodes[1].0 as usize + 1] += 1;
            }
        }
        for k in 0..n {
            start[k + 1] += start[k];
        }
        let mut fill = start.clone();
        let mut terms = vec![(VarId(0), false); start[n] as usize];
        for (id, e) in self.c.elements.iter() {
            let Some(ev) = vars[id.0 as usize] else {
                continue;
            };
            for (node, enters) in [(e.nodes[0], false), (e.nodes[1], true)] {
                let slot = &mut fill[node.0 as usize];
                terms[*slot as usize] = (ev.i, enters);
                *slot += 1;
            }
        }
        for (id, _) in self.c.nodes.iter() {
            if id == GROUND {
                continue;
            }
            let k = id.0 as usize;
            let here = &terms[start[k] as usize..start[k + 1] as usize];
            if here.is_empty() {
                continue;
            }
            let x = &mut self.sys.exprs;
            let lhs_terms: Vec<ExprId> = here.iter().filter(|t| t.1).map(|t| x.var(t.0)).collect();
            let rhs_terms: Vec<ExprId> = here.iter().filter(|t| !t.1).map(|t| x.var(t.0)).collect();
            let lhs = x.sum(lhs_terms);
            let rhs = x.sum(rhs_terms);
            self.sys.add_eq(
                lhs,
                rhs,
                Origin {
                    kind: OriginKind::Kcl {
                        node: self.node_names[id.0 as usize].clone(),
                    },
                },
            );
        }
    }

    /// `u_X = v(a) - v(b)` for every element, except a capacitor that a loop
    /// of capacitors and voltage sources fixes: its equation is the loop's
    /// KVL, `u_C = ±u_…` over the rest of the loop (which implies its
    /// branch equation through theirs). Written on node potentials, a loop
    /// that touches neither ground nor a source-fixed node would hide its
    /// constraint: the two potentials would match the two branch equations,
    /// index reduction would never start, and the loop's block would be
    /// singular at run time (two parallel capacitors between internal nodes).
    fn branch_equations(
        &mut self,
        vars: &[Option<ElemVars>],
        pots: &[ExprId],
    ) -> Vec<crate::elab::topology::Fault> {
        let mut loops: HashMap<ElemId, Vec<(ElemId, f64)>> = HashMap::new();
        let faults = crate::elab::topology::faults(self.c, &[]);
        for f in &faults {
            if let crate::elab::topology::Fault::CapacitorLoop { elements, fixed } = f
                && let Some(path) = loop_path(self.c, elements, *fixed)
            {
                loops.insert(*fixed, path);
            }
        }
        for (id, e) in self.c.elements.iter() {
            let Some(ev) = vars[id.0 as usize] else {
                continue;
            };
            if let Some(path) = loops.get(&id) {
                let x = &mut self.sys.exprs;
                let u = x.var(ev.u);
                let terms: Vec<ExprId> = path
                    .iter()
                    .filter_map(|&(el, sign)| {
                        let v = x.var(vars[el.0 as usize]?.u);
                        Some(if sign < 0.0 { x.neg(v) } else { v })
                    })
                    .collect();
                let rhs = x.sum(terms);
                let elements = path
                    .iter()
                    .map(|&(el, _)| self.names[el.0 as usize].clone())
                    .collect();
                self.sys.add_eq(
                    u,
                    rhs,
                    Origin {
                        kind: OriginKind::Kvl(Box::new(KvlLoop {
                            link: self.names[id.0 as usize].clone(),
                            elements,
                        })),
                    },
                );
                continue;
            }
            let x = &mut self.sys.exprs;
            let u = x.var(ev.u);
            let rhs = x.sub(pots[e.nodes[0].0 as usize], pots[e.nodes[1].0 as usize]);
            self.sys.add_eq(
                u,
                rhs,
                Origin {
                    kind: OriginKind::Branch {
                        name: self.names[id.0 as usize].clone(),
                    },
                },
            );
        }
        faults
    }
}

/// The rest of the loop `elements` from `fixed`'s first node to its second,
/// each element with the sign of its branch voltage along the way:
/// `u_fixed = Σ sign·u_e`. `None` if the elements do not close a loop.
fn loop_path(c: &Circuit, elements: &[ElemId], fixed: ElemId) -> Option<Vec<(ElemId, f64)>> {
    let (start, end) = (c.elements[fixed].nodes[0], c.elements[fixed].nodes[1]);
    // The loop's elements at each of its nodes (two each on a simple loop).
    let mut at_node: HashMap<NodeId, Vec<usize>> = HashMap::with_capacity(elements.len());
    for (k, &el) in elements.iter().enumerate() {
        if el != fixed {
            for &n in &c.elements[el].nodes[..2] {
                at_node.entry(n).or_default().push(k);
            }
        }
    }
    let mut path = Vec::with_capacity(elements.len());
    let mut used = vec![false; elements.len()];
    let mut at = start;
    while at != end {
        let k = *at_node.get(&at)?.iter().find(|&&k| !used[k])?;
        used[k] = true;
        let el = elements[k];
        let [a, b] = [c.elements[el].nodes[0], c.elements[el].nodes[1]];
        // Walking a → b adds v(a) - v(b) = u_el; b → a subtracts it.
        let (sign, next) = if a == at { (1.0, b) } else { (-1.0, a) };
        path.push((el, sign));
        at = next;
    }
    Some(path)
}
