//! The colour-edge causalizer of seeds 000/001.
//!
//! Every edge starts black. An equation with exactly one black edge colours
//! it red (the equation will be solved for that unknown), colours the
//! unknown's other black edges blue, and takes the lowest free number. An
//! unknown with exactly one black edge colours it red, colours its equation's
//! other black edges blue, and gives that equation the highest free number.
//! Per-node black-edge counters and two work queues make this O(edges).
//!
//! The engine can also run a *trial* (used by tearing): the same propagation
//! with an undo log, rolled back afterwards, that only counts what it causalized.

use serde::Serialize;

use super::graph::{EdgeIdx, StructureGraph};
use crate::ir::{EqId, VarId};

const NONE: u32 = u32::MAX;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum EdgeColour {
    Black,
    Red,
    Blue,
}

/// Which rule assigned an equation to an unknown.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Rule {
    /// The equation had one black edge (lowest free number).
    Equation,
    /// The unknown had one black edge (highest free number).
    Unknown,
    /// Tearing: the unknown is guessed and the equation becomes its residual.
    Tear,
}

impl Rule {
    fn code(self) -> u8 {
        match self {
            Rule::Equation => 1,
            Rule::Unknown => 2,
            Rule::Tear => 3,
        }
    }

    pub(crate) fn from_code(c: u8) -> Option<Rule> {
        match c {
            1 => Some(Rule::Equation),
            2 => Some(Rule::Unknown),
            3 => Some(Rule::Tear),
            _ => None,
        }
    }
}

/// One assignment made by the colouring, in the order made.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct TraceStep {
    /// Pass of the outer loop (an alternation of the two rules).
    pub pass: u32,
    pub rule: Rule,
    pub eq: EqId,
    pub var: VarId,
    /// The equation's sort number (1-based).
    pub number: u32,
}

#[derive(Clone, Copy)]
enum Undo {
    Colour(EdgeIdx, EdgeColour),
    EqBlack(u32, u32),
    VarBlack(u32, u32),
    EqVar(u32, u32),
    VarEq(u32, u32),
}

/// The state of a colouring run over a [`StructureGraph`].
pub struct Colouring<'g> {
    pub g: &'g StructureGraph,
    pub colour: Vec<EdgeColour>,
    pub eq_black: Vec<u32>,
    pub var_black: Vec<u32>,
    /// The unknown each equation is solved for (`u32::MAX`: none yet).
    eq_var: Vec<u32>,
    /// The equation that computes each unknown.
    var_eq: Vec<u32>,
    /// Sort numbers, 1-based; 0 while unnumbered.
    pub number: Vec<u32>,
    rules: Vec<u8>,
    low: u32,
    high: u32,
    eq_queue: Vec<u32>,
    var_queue: Vec<u32>,
    pub trace: Vec<TraceStep>,
    /// Equations left with no black edge while unassigned (constraints).
    pub constraints: Vec<EqId>,
    /// Unknowns left with no black edge while uncomputed.
    pub orphans: Vec<VarId>,
    pass: u32,
    undo: Option<Vec<Undo>>,
    /// The undo log's buffer, kept between trials: a trial in a block of
    /// 10^6 equations logs millions of changes, and a fresh log would be
    /// regrown (copied) every time.
    undo_spare: Vec<Undo>,
    trial_count: usize,
    /// Edges along which solving needs a nonlinear inversion (filled by
    /// tearing for the equations of the block at hand; false elsewhere).
    pub nonlinear: Vec<bool>,
    trial_inversions: usize,
    /// In strict mode a rule that would solve along a nonlinear edge tears
    /// instead: the unknown is guessed and the equation becomes its residual,
    /// evaluated forward (no `ln` of a diode current that may be negative).
    pub strict: bool,
    /// Tears made by strict mode since last taken.
    pub auto_tears: Vec<(EqId, VarId)>,
}

/// What a finished colouring leaves behind.
pub struct Parts {
    pub colour: Vec<EdgeColour>,
    pub trace: Vec<TraceStep>,
    pub number: Vec<u32>,
    /// The unknown of each equation and the equation of each unknown
    /// (`u32::MAX`: none).
    pub eq_var: Vec<u32>,
    pub var_eq: Vec<u32>,
    /// The rule that assigned each equation (0: none; see [`Rule`]).
    pub rules: Vec<u8>,
    pub constraints: Vec<EqId>,
    pub orphans: Vec<VarId>,
}

impl<'g> Colouring<'g> {
    pub fn into_parts(self) -> Parts {
        Parts {
            colour: self.colour,
            trace: self.trace,
            number: self.number,
            eq_var: self.eq_var,
            var_eq: self.var_eq,
            rules: self.rules,
            constraints: self.constraints,
            orphans: self.orphans,
        }
    }

    pub fn new(g: &'g StructureGraph) -> Colouring<'g> {
        let n_eqs = g.n_eqs();
        let n_vars = g.n_vars();
        let eq_black: Vec<u32> = (0..n_eqs)
            .map(|e| g.eq_start[e + 1] - g.eq_start[e])
            .collect();
        let var_black: Vec<u32> = (0..n_vars)
            .map(|v| g.var_start[v + 1] - g.var_start[v])
            .collect();
        let mut c = Colouring {
            g,
            colour: vec![EdgeColour::Black; g.n_edges()],
            eq_queue: Vec::new(),
            var_queue: Vec::new(),
            eq_black,
            var_black,
            eq_var: vec![NONE; n_eqs],
            var_eq: vec![NONE; n_vars],
            number: vec![0; n_eqs],
            rules: vec![0; n_eqs],
            low: 1,
            high: n_eqs as u32,
            trace: Vec::with_capacity(n_eqs),
            constraints: Vec::new(),
            orphans: Vec::new(),
            pass: 0,
            undo: None,
            undo_spare: Vec::new(),
            trial_count: 0,
            nonlinear: vec![false; g.n_edges()],
            trial_inversions: 0,
            strict: false,
            auto_tears: Vec::new(),
        };
        for e in 0..n_eqs {
            match c.eq_black[e] {
                0 => c.constraints.push(EqId(e as u32)),
                1 => c.eq_queue.push(e as u32),
                _ => {}
            }
        }
        // The seed handles unknowns in reverse list order; a stack pops them so.
        for v in 0..n_vars {
            if !g.is_unknown[v] {
                continue;
            }
            match c.var_black[v] {
                0 => c.orphans.push(VarId(v as u32)),
                1 => c.var_queue.push(v as u32),
                _ => {}
            }
        }
        c
    }

    pub fn assigned_var(&self, e: EqId) -> Option<VarId> {
        let v = self.eq_var[e.0 as usize];
        (v != NONE).then_some(VarId(v))
    }

    pub fn assigned_eq(&self, v: VarId) -> Option<EqId> {
        let e = self.var_eq[v.0 as usize];
        (e != NONE).then_some(EqId(e))
    }

    pub fn is_done(&self, e: EqId) -> bool {
        self.eq_var[e.0 as usize] != NONE
    }

    /// Equations still unassigned.
    pub fn remaining(&self) -> impl Iterator<Item = EqId> + '_ {
        (0..self.eq_var.len())
            .filter(|&e| self.eq_var[e] == NONE)
            .map(|e| EqId(e as u32))
    }

    #[inline]
    fn set_colour(&mut self, k: EdgeIdx, c: EdgeColour) {
        if let Some(u) = &mut self.undo {
            u.push(Undo::Colour(k, self.colour[k as usize]));
        }
        self.colour[k as usize] = c;
    }

    #[inline]
    fn set_eq_black(&mut self, e: u32, n: u32) {
        if let Some(u) = &mut self.undo {
            u.push(Undo::EqBlack(e, self.eq_black[e as usize]));
        }
        self.eq_black[e as usize] = n;
    }

    #[inline]
    fn set_var_black(&mut self, v: u32, n: u32) {
        if let Some(u) = &mut self.undo {
            u.push(Undo::VarBlack(v, self.var_black[v as usize]));
        }
        self.var_black[v as usize] = n;
    }

    /// Colour edge (e, v) red, every other black edge of e and of v blue, and
    /// update the counters and queues.
    fn assign(&mut self, e: u32, v: u32, red: EdgeIdx, rule: Rule) {
        let trial = self.undo.is_some();
        self.set_colour(red, EdgeColour::Red);
        if let Some(u) = &mut self.undo {
            u.push(Undo::EqVar(e, self.eq_var[e as usize]));
            u.push(Undo::VarEq(v, self.var_eq[v as usize]));
        }
        self.eq_var[e as usize] = v;
        self.var_eq[v as usize] = e;
        let g = self.g;
        // The other unknowns of e are now computed elsewhere.
        for k in g.eq_edges(EqId(e)) {
            if k == red || self.colour[k as usize] != EdgeColour::Black {
                continue;
            }
            self.set_colour(k, EdgeColour::Blue);
            let w = g.edge_var[k as usize].0;
            let n = self.var_black[w as usize] - 1;
            self.set_var_black(w, n);
            if self.var_eq[w as usize] == NONE {
                match n {
                    1 => self.var_queue.push(w),
                    0 if !trial => self.orphans.push(VarId(w)),
                    _ => {}
                }
            }
        }
        // The other equations of v now know it.
        for &k in g.var_edge_ids(VarId(v)) {
            if k == red || self.colour[k as usize] != EdgeColour::Black {
                continue;
            }
            self.set_colour(k, EdgeColour::Blue);
            let f = g.edge_eq[k as usize].0;
            let n = self.eq_black[f as usize] - 1;
            self.set_eq_black(f, n);
            if self.eq_var[f as usize] == NONE {
                match n {
                    1 => self.eq_queue.push(f),
                    0 if !trial => self.constraints.push(EqId(f)),
                    _ => {}
                }
            }
        }
        self.set_eq_black(e, 0);
        self.set_var_black(v, 0);
        if trial {
            self.trial_count += 1;
            if !self.strict {
                self.trial_inversions += usize::from(self.nonlinear[red as usize]);
            }
            return;
        }
        let number = match rule {
            Rule::Equation | Rule::Tear => {
                self.low += 1;
                self.low - 1
            }
            Rule::Unknown => {
                self.high -= 1;
                self.high + 1
            }
        };
        self.number[e as usize] = number;
        self.rules[e as usize] = rule.code();
        self.trace.push(TraceStep {
            pass: self.pass,
            rule,
            eq: EqId(e),
            var: VarId(v),
            number,
        });
    }

    /// `rule`, or a tear when strict mode forbids solving along edge `k`.
    fn rule_for(&mut self, k: EdgeIdx, rule: Rule) -> Rule {
        if self.strict && self.nonlinear[k as usize] {
            if self.undo.is_some() {
                self.trial_inversions += 1;
            } else {
                let (e, v) = (self.g.edge_eq[k as usize], self.g.edge_var[k as usize]);
                self.auto_tears.push((e, v));
            }
            Rule::Tear
        } else {
            rule
        }
    }

    fn black_edge_of_eq(&self, e: u32) -> Option<EdgeIdx> {
        self.g
            .eq_edges(EqId(e))
            .find(|&k| self.colour[k as usize] == EdgeColour::Black)
    }

    fn black_edge_of_var(&self, v: u32) -> Option<EdgeIdx> {
        self.g
            .var_edge_ids(VarId(v))
            .iter()
            .copied()
            .find(|&k| self.colour[k as usize] == EdgeColour::Black)
    }

    /// Apply both rules until neither applies. Returns whether anything was assigned.
    pub fn propagate(&mut self) -> bool {
        let mut any = false;
        loop {
            self.pass += 1;
            let mut progressed = false;
            // Equation rule: FIFO keeps the seeds' "all such equations, in order".
            let mut head = 0;
            while head < self.eq_queue.len() {
                let e = self.eq_queue[head];
                head += 1;
                if self.eq_var[e as usize] != NONE || self.eq_black[e as usize] != 1 {
                    continue;
                }
                let Some(k) = self.black_edge_of_eq(e) else {
                    continue;
                };
                let v = self.g.edge_var[k as usize].0;
                let rule = self.rule_for(k, Rule::Equation);
                self.assign(e, v, k, rule);
                progressed = true;
            }
            self.eq_queue.clear();
            self.pass += 1;
            while let Some(v) = self.var_queue.pop() {
                if self.var_eq[v as usize] != NONE || self.var_black[v as usize] != 1 {
                    continue;
                }
                let Some(k) = self.black_edge_of_var(v) else {
                    continue;
                };
                let e = self.g.edge_eq[k as usize].0;
                if self.eq_var[e as usize] != NONE {
                    continue;
                }
                let rule = self.rule_for(k, Rule::Unknown);
                self.assign(e, v, k, rule);
                progressed = true;
                if !self.eq_queue.is_empty() {
                    // Let the equation rule run before more unknowns are taken.
                    break;
                }
            }
            any |= progressed;
            if !progressed && self.eq_queue.is_empty() && self.var_queue.is_empty() {
                return any;
            }
        }
    }

    /// Tear: treat `v` as known by pairing it with residual equation `e`.
    pub fn tear(&mut self, e: EqId, v: VarId) {
        let k = self
            .g
            .eq_edges(e)
            .find(|&k| self.g.edge_var[k as usize] == v)
            .expect("the tearing variable occurs in its residual equation");
        self.pass += 1;
        self.assign(e.0, v.0, k, Rule::Tear);
    }

    /// How many equations tearing `v` with residual `e` would causalize
    /// (including `e`), and how many of those need a nonlinear inversion,
    /// without changing anything.
    pub fn trial_tear(&mut self, e: EqId, v: VarId) -> (usize, usize) {
        debug_assert!(self.eq_queue.is_empty() && self.var_queue.is_empty());
        let mut log = std::mem::take(&mut self.undo_spare);
        log.clear();
        self.undo = Some(log);
        self.trial_count = 0;
        self.trial_inversions = 0;
        let k = self
            .g
            .eq_edges(e)
            .find(|&k| self.g.edge_var[k as usize] == v)
            .expect("candidate occurs in its equation");
        self.assign(e.0, v.0, k, Rule::Tear);
        let pass = self.pass;
        self.propagate();
        self.pass = pass;
        let count = self.trial_count;
        let mut log = self.undo.take().unwrap_or_default();
        for u in log.drain(..).rev() {
            match u {
                Undo::Colour(k, c) => self.colour[k as usize] = c,
                Undo::EqBlack(e, n) => self.eq_black[e as usize] = n,
                Undo::VarBlack(v, n) => self.var_black[v as usize] = n,
                Undo::EqVar(e, x) => self.eq_var[e as usize] = x,
                Undo::VarEq(v, x) => self.var_eq[v as usize] = x,
            }
        }
        self.undo_spare = log;
        self.eq_queue.clear();
        self.var_queue.clear();
        (count, self.trial_inversions)
    }

    /// Whether any unknown is still uncomputed.
    pub fn n_assigned(&self) -> usize {
        self.trace.len()
    }

    /// Black edges of equation `e` (its still-unknown unknowns).
    pub fn black_vars(&self, e: EqId) -> impl Iterator<Item = VarId> + '_ {
        self.g
            .eq_edges(e)
            .filter(|&k| self.colour[k as usize] == EdgeColour::Black)
            .map(|k| self.g.edge_var[k as usize])
    }
}
