//! The in-process evaluator: a schedule compiled into a flat register
//! program over an `f64` slice. No tree walking and no hashing when it runs:
//! one `match` per instruction. Assignments alias registers (`x := y` costs
//! nothing), common subexpressions share one register (the expression arena
//! is hash-consed), and algebraic blocks are solved by damped Newton on their
//! tearing variables with an analytic Jacobian from forward-mode tangents.
//!
//! Only what the scene needs is computed during integration: the state
//! derivatives, with the blocks they need. Requested outputs are computed by
//! a second program, at output points only.

use std::collections::HashMap;

use crate::analysis::{Assignment, Schedule, Solved, Step};
use crate::ir::{DeviceFn, DiodeParams, EquationSystem, Expr, ExprId, Func, VarId, Waveform};
use crate::numeric::colour::{colour_columns, members};
use crate::numeric::dense::{lu_factor, lu_solve};
use crate::numeric::newton::{self, Damping};
use crate::numeric::{DenseLu, Factored, TripletLu};

/// One instruction: `dst = op(a, b)`; operands are registers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Instr {
    Neg {
        d: u32,
        a: u32,
    },
    /// A device function (diode current or charge, or a derivative).
    Device {
        d: u32,
        f: DeviceFn,
        a: u32,
    },
    Add {
        d: u32,
        a: u32,
        b: u32,
    },
    Sub {
        d: u32,
        a: u32,
        b: u32,
    },
    Mul {
        d: u32,
        a: u32,
        b: u32,
    },
    Div {
        d: u32,
        a: u32,
        b: u32,
    },
    Pow {
        d: u32,
        a: u32,
        b: u32,
    },
    Call {
        d: u32,
        f: Func,
        a: u32,
    },
    /// The `order`-th time derivative of source `s`.
    Src {
        d: u32,
        s: u32,
        order: u8,
    },
    Time {
        d: u32,
    },
    /// Solve block `k` (see [`TapeBlock`]).
    Block {
        k: u32,
    },
}

/// An algebraic loop: guess the tearing registers, run `body`, drive the
/// residual registers to zero.
#[derive(Clone, Debug)]
pub struct TapeBlock {
    /// 1-based index in the schedule (for messages).
    pub index: usize,
    pub tears: Vec<u32>,
    pub residuals: Vec<u32>,
    pub body: Vec<Instr>,
    pub linear: bool,
    /// The circuit elements of the block, for messages.
    pub elements: Vec<String>,
    /// Tears that enter an `exp(x/vt)` (junction voltages), with the register
    /// of `vt`: their Newton steps are limited as ngspice limits junctions.
    pub junctions: Vec<(usize, u32)>,
    /// Registers the body reads or writes, each once: the tangents a
    /// Jacobian column clears before it runs.
    pub touched: Vec<u32>,
    /// Nothing outside the body reads what it computes but the tears: a
    /// converged Newton may move the tears last without re-running it.
    pub private: bool,
    /// The residuals are affine in the tears with coefficients that are
    /// constants of the tape: the Jacobian is factored once, at first use.
    pub constant_jacobian: bool,
    /// That factorization, once computed.
    lu: std::cell::OnceCell<Factored>,
    /// The sparsity of a block past [`DENSE_TEARS`], once computed (`None`
    /// inside: too dense to colour).
    pattern: std::cell::OnceCell<Option<Pattern>>,
    /// The block is `0 = q - Q(x)` for a junction charge `Q`: it is solved
    /// by Halley's method on the device's own derivatives.
    pub charge_inverse: Option<ChargeInverse>,
}

/// A junction-charge block: find `x` with `Q_diode(x) = r[target]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChargeInverse {
    pub diode: u32,
    pub target: u32,
    /// Four registers: the last voltage the inversion evaluated the junction
    /// at, and its charge, `Q′` and `Q″` there (NaN: none yet). The next
    /// inversion starts from it and takes its first step without evaluating:
    /// one junction evaluation per inversion where there were two.
    pub memo: u32,
}

impl TapeBlock {
    fn singular(&self, t: f64) -> EvalError {
        EvalError::Singular {
            block: self.index,
            elements: self.elements.clone(),
            t,
        }
    }

    fn no_convergence(&self, residual: f64, t: f64) -> EvalError {
        EvalError::NoConvergence {
            block: self.index,
            elements: self.elements.clone(),
            residual,
            t,
        }
    }
}

/// What the tangent runs of one point share: each block's factored
/// Jacobian, so that the columns of a Jacobian solve the blocks once.
#[derive(Debug, Default)]
pub struct TangentCache {
    /// The registers hold the last tangent run (set by [`Tape::jac_mul`]);
    /// whoever else writes them, or moves to another point, clears this.
    pub valid: bool,
    lus: Vec<Option<Factored>>,
}

impl TangentCache {
    /// Keep block `k`'s dense factors (copied into the slot's own buffers).
    fn keep(&mut self, k: usize, n_blocks: usize, jac: &[f64], perm: &[usize]) {
        let slot = self.slot(k, n_blocks);
        if !matches!(slot, Some(Factored::Dense(..))) {
            *slot = Some(Factored::Dense(DenseLu::default()));
        }
        if let Some(Factored::Dense(d)) = slot {
            d.lu.clear();
            d.lu.extend_from_slice(jac);
            d.perm.clear();
            d.perm.extend_from_slice(perm);
        }
    }

    fn slot(&mut self, k: usize, n_blocks: usize) -> &mut Option<Factored> {
        if self.lus.len() < n_blocks {
            self.lus.resize(n_blocks, None);
        }
        &mut self.lus[k]
    }
}

/// Why an evaluation failed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum EvalError {
    #[error(
        "Newton did not converge in algebraic loop {block} through {} (residual {residual:.3e} at t = {t:e})",
        crate::back::listing::shortened(elements, crate::back::listing::ELEMENTS_SHOWN)
    )]
    NoConvergence {
        block: usize,
        elements: Vec<String>,
        residual: f64,
        t: f64,
    },
    #[error(
        "singular Jacobian in algebraic loop {block} through {} at t = {t:e}",
        crate::back::listing::shortened(elements, crate::back::listing::ELEMENTS_SHOWN)
    )]
    Singular {
        block: usize,
        elements: Vec<String>,
        t: f64,
    },
}

/// A compiled schedule.
#[derive(Clone, Debug)]
pub struct Tape {
    pub n_regs: usize,
    /// Register of each state, in state order (the ODE's `y`).
    pub state_regs: Vec<u32>,
    /// The state variables, in the same order.
    pub states: Vec<VarId>,
    /// Register of each state's derivative (the ODE's `f`).
    pub deriv_regs: Vec<u32>,
    /// Initial register contents (parameters and constants).
    pub init: Vec<f64>,
    pub code: Vec<Instr>,
    pub blocks: Vec<TapeBlock>,
    /// Computes the outputs from the states, on its own registers.
    pub out_code: Vec<Instr>,
    /// The states `out_code` reads: (index in `y`, register).
    pub out_inputs: Vec<(usize, u32)>,
    pub out_regs: Vec<u32>,
    /// `(from, to)`: the inversion memo of a junction charge in `code` and
    /// of the same charge in `out_code`. An output point after a step
    /// starts each inversion where the step's last evaluation ended (a
    /// Halley step or none), not where the last output point did.
    memo_links: Vec<(u32, u32)>,
    pub sources: Vec<Waveform>,
    pub diodes: Vec<DiodeParams>,
    /// Assignments evaluated by `code` / only by `out_code` / never.
    pub n_in_f: usize,
    pub n_at_outputs: usize,
    pub n_unused: usize,
    /// For each register, the assignment (variable) whose value it holds,
    /// when it holds one: to name the source of a NaN.
    pub reg_var: Vec<Option<VarId>>,
    /// DC mode: sources' time derivatives read as zero (the operating point,
    /// where capacitors are open and inductors shorted whatever the sources do).
    pub dc: std::cell::Cell<bool>,
    /// Every independent source's value is multiplied by this (1 but while
    /// the DC solve ramps the sources up): waveforms as they are evaluated,
    /// DC values in their registers (see [`Tape::scale_sources`]).
    pub source_scale: std::cell::Cell<f64>,
    /// The registers of DC sources' values, and the values.
    pub source_params: Vec<(u32, f64)>,
    /// Each source's last `(t, value)` (unscaled, order 0): the Newton
    /// iterations of an implicit stage evaluate `f` at one time again and
    /// again, and a SIN source's `sin` was a twentieth of a rectifier's
    /// evaluation.
    source_memo: Vec<std::cell::Cell<(f64, f64)>>,
}

struct Compiler<'a> {
    sys: &'a EquationSystem,
    sched: &'a Schedule,
    n_regs: u32,
    init: Vec<f64>,
    memo: HashMap<ExprId, u32>,
    var_reg: Vec<u32>,
    param_reg: Vec<u32>,
    /// Constant registers (constants, parameters, reciprocals) by value.
    consts: HashMap<u64, u32>,
    reg_var: Vec<Option<VarId>>,
    blocks: Vec<TapeBlock>,
}

const NONE: u32 = u32::MAX;

impl Compiler<'_> {
    fn reg(&mut self, value: f64) -> u32 {
        let r = self.n_regs;
        self.n_regs += 1;
        self.init.push(value);
        self.reg_var.push(None);
        r
    }

    /// Emit `e` into `out` (post-order, memoized); returns its register.
    /// The register of a constant value, one per distinct value: a ladder
    /// of 10^5 equal resistors reads one `1/R`, which stays in cache.
    fn const_reg(&mut self, v: f64) -> u32 {
        if let Some(&r) = self.consts.get(&v.to_bits()) {
            return r;
        }
        let r = self.reg(v);
        self.consts.insert(v.to_bits(), r);
        r
    }

    /// The value of a constant or parameter expression.
    fn constant(&self, e: ExprId) -> Option<f64> {
        match self.sched.exprs.get(e) {
            Expr::Const(b) => Some(f64::from_bits(b)),
            Expr::Param(p) => Some(self.sys.params[p].value),
            _ => None,
        }
    }

    /// The register of `e`, its code appended to `out` (each node once).
    fn emit(&mut self, e: ExprId, out: &mut Vec<Instr>) -> u32 {
        self.emit_at(e, out, 0)
    }

    /// Whether `e` already has its register.
    fn emitted(&self, e: ExprId) -> bool {
        self.memo.contains_key(&e)
            || match self.sched.exprs.get(e) {
                Expr::Var(v) => self.var_reg[v.0 as usize] != NONE,
                Expr::Param(p) => self.param_reg[p.0 as usize] != NONE,
                _ => false,
            }
    }

    /// [`Compiler::emit`] at recursion depth `depth`. Past 128 levels (the
    /// loop formulation's node potentials are tree-path sums 10^5 deep,
    /// which overflowed the stack) the operands are emitted bottom-up with
    /// an explicit stack, each then found memoized.
    fn emit_at(&mut self, e: ExprId, out: &mut Vec<Instr>, depth: usize) -> u32 {
        if let Some(&r) = self.memo.get(&e) {
            return r;
        }
        if depth > 128 {
            let mut stack = vec![(e, false)];
            while let Some((n, expanded)) = stack.pop() {
                if n == e && expanded {
                    break;
                }
                if self.emitted(n) {
                    continue;
                }
                if expanded {
                    self.emit_at(n, out, 0);
                    continue;
                }
                stack.push((n, true));
                let x = &self.sched.exprs;
                let children = match x.get(n) {
                    Expr::Var(v) if self.var_reg[v.0 as usize] == NONE => {
                        [self.sys.vars[v].alias, None]
                    }
                    Expr::Var(_)
                    | Expr::Const(_)
                    | Expr::Param(_)
                    | Expr::Time
                    | Expr::Source(..) => [None, None],
                    op => op.operands(),
                };
                stack.extend(children.into_iter().rev().flatten().map(|c| (c, false)));
            }
        }
        let depth = depth + 1;
        let x = &self.sched.exprs;
        let r = match x.get(e) {
            Expr::Const(b) => {
                let r = self.const_reg(f64::from_bits(b));
                self.memo.insert(e, r);
                return r;
            }
            Expr::Param(p) => {
                let k = p.0 as usize;
                if self.param_reg[k] == NONE {
                    let param = &self.sys.params[p];
                    // A source's value gets a register of its own (source
                    // stepping scales it); other parameters share constants.
                    self.param_reg[k] = if param.source {
                        self.reg(param.value)
                    } else {
                        self.const_reg(param.value)
                    };
                }
                return self.param_reg[k];
            }
            Expr::Var(v) => {
                let r = self.var_reg[v.0 as usize];
                if r != NONE {
                    return r;
                }
                // An eliminated alias: its expression.
                let alias = self.sys.vars[v]
                    .alias
                    .expect("variables are computed before use");
                let r = self.emit_at(alias, out, depth);
                self.var_reg[v.0 as usize] = r;
                return r;
            }
            Expr::Time => {
                let d = self.reg(0.0);
                out.push(Instr::Time { d });
                d
            }
            Expr::Source(s, order) => {
                let d = self.reg(0.0);
                out.push(Instr::Src { d, s: s.0, order });
                d
            }
            Expr::Neg(a) => {
                let a = self.emit_at(a, out, depth);
                let d = self.reg(0.0);
                out.push(Instr::Neg { d, a });
                d
            }
            Expr::Call(f, a) => {
                let a = self.emit_at(a, out, depth);
                let d = self.reg(0.0);
                out.push(Instr::Call { d, f, a });
                d
            }
            Expr::Device(f, a) => {
                let a = self.emit_at(a, out, depth);
                let d = self.reg(0.0);
                out.push(Instr::Device { d, f, a });
                d
            }
            // Division by a constant is multiplication by its reciprocal,
            // computed once here (within an ulp of dividing; a division costs
            // several multiplications).
            Expr::Div(a, b) if self.constant(b).is_some_and(|c| c != 0.0 && c.is_finite()) => {
                let ra = self.emit_at(a, out, depth);
                let rb = self.const_reg(1.0 / self.constant(b).unwrap_or(1.0));
                let d = self.reg(0.0);
                out.push(Instr::Mul { d, a: ra, b: rb });
                d
            }
            Expr::Add(a, b)
            | Expr::Sub(a, b)
            | Expr::Mul(a, b)
            | Expr::Div(a, b)
            | Expr::Pow(a, b) => {
                let (ra, rb) = (self.emit_at(a, out, depth), self.emit_at(b, out, depth));
                let d = self.reg(0.0);
                out.push(match x.get(e) {
                    Expr::Add(..) => Instr::Add { d, a: ra, b: rb },
                    Expr::Sub(..) => Instr::Sub { d, a: ra, b: rb },
                    Expr::Mul(..) => Instr::Mul { d, a: ra, b: rb },
                    Expr::Div(..) => Instr::Div { d, a: ra, b: rb },
                    _ => Instr::Pow { d, a: ra, b: rb },
                });
                d
            }
        };
        self.memo.insert(e, r);
        r
    }

    /// Find a block's junction tears; diode thermal voltages get registers.
    /// A nested block (compiled before its enclosing one) contributes its
    /// own registers: a Jacobian column must clear those tangents too.
    fn set_touched(&mut self, k: usize) {
        let mut touched: Vec<u32> = Vec::new();
        for ins in &self.blocks[k].body {
            match *ins {
                Instr::Block { k: inner } => {
                    touched.extend_from_slice(&self.blocks[inner as usize].touched)
                }
                _ => touched.extend(sources_of(ins, &[]).into_iter().chain([dest(ins)])),
            }
        }
        touched.retain(|&x| x != NONE);
        touched.sort_unstable();
        touched.dedup();
        self.blocks[k].touched = touched;
    }

    fn set_junctions(&mut self, k: usize) {
        let diodes: Vec<u32> = self.blocks[k]
            .body
            .iter()
            .filter_map(|i| match i {
                Instr::Device { f, .. } => Some(f.diode),
                _ => None,
            })
            .collect();
        let mut regs = HashMap::new();
        for d in diodes {
            if let std::collections::hash_map::Entry::Vacant(e) = regs.entry(d) {
                let vte = self.sys.diodes[d as usize].vte;
                e.insert(self.reg(vte));
            }
        }
        let j = junctions(&self.blocks[k], &|d| regs.get(&d).copied());
        self.blocks[k].junctions = j;
    }

    /// The register of variable `v` (an alias is emitted on first use).
    fn var(&mut self, v: VarId, out: &mut Vec<Instr>) -> u32 {
        let r = self.var_reg[v.0 as usize];
        if r != NONE {
            return r;
        }
        match self.sys.vars[v].alias {
            Some(a) => {
                let r = self.emit(a, out);
                self.var_reg[v.0 as usize] = r;
                r
            }
            // Not needed by anything that ran: a constant zero.
            None => self.reg(0.0),
        }
    }

    fn assign(&mut self, a: &Assignment, out: &mut Vec<Instr>) {
        match a.solved {
            Solved::Explicit(e) => {
                let r = self.emit(e, out);
                self.var_reg[a.var.0 as usize] = r;
                if self.reg_var[r as usize].is_none() {
                    self.reg_var[r as usize] = Some(a.var);
                }
            }
            Solved::Implicit(f) => {
                // A one-equation block: guess the unknown, zero the residual.
                let t = self.reg(0.0);
                self.var_reg[a.var.0 as usize] = t;
                self.reg_var[t as usize] = Some(a.var);
                let mut body = Vec::new();
                let r = self.emit(f, &mut body);
                let k = self.blocks.len() as u32;
                self.blocks.push(TapeBlock {
                    index: 0,
                    tears: vec![t],
                    residuals: vec![r],
                    body,
                    linear: false,
                    elements: self.sys.eqs[a.eq]
                        .origin
                        .elements()
                        .into_iter()
                        .map(String::from)
                        .collect(),
                    junctions: Vec::new(),
                    touched: Vec::new(),
                    private: false,
                    constant_jacobian: false,
                    lu: std::cell::OnceCell::new(),
                    pattern: std::cell::OnceCell::new(),
                    charge_inverse: None,
                });
                let kk = k as usize;
                self.set_junctions(kk);
                self.set_touched(kk);
                out.push(Instr::Block { k });
            }
        }
    }

    fn step(&mut self, step: &Step, out: &mut Vec<Instr>) {
        match step {
            Step::Assign(a) => self.assign(a, out),
            Step::Block(b) => {
                // A large linear loop is solved whole: every unknown a Newton
                // unknown, every equation a residual. Its Jacobian then has the
                // circuit's own sparsity, where the torn one fills in (a
                // 100×100 resistor mesh: 7471 tears, 4.5 ms a solve).
                let whole = b.solved_whole();
                let unknowns: Vec<VarId> = if whole {
                    b.inner.iter().chain(&b.residuals).map(|a| a.var).collect()
                } else {
                    b.tears.clone()
                };
                let tears: Vec<u32> = unknowns
                    .iter()
                    .map(|&v| {
                        let r = self.reg(0.0);
                        self.var_reg[v.0 as usize] = r;
                        self.reg_var[r as usize] = Some(v);
                        r
                    })
                    .collect();
                let mut body = Vec::new();
                if !whole {
                    for a in &b.inner {
                        self.assign(a, &mut body);
                    }
                }
                let equations = if whole { &b.inner[..] } else { &[][..] };
                let mut residuals = Vec::new();
                for a in equations.iter().chain(&b.residuals) {
                    let eq = &self.sys.eqs[a.eq];
                    let l = self.emit(eq.lhs, &mut body);
                    let r = self.emit(eq.rhs, &mut body);
                    let d = self.reg(0.0);
                    body.push(Instr::Sub { d, a: l, b: r });
                    residuals.push(d);
                }
                let k = self.blocks.len() as u32;
                self.blocks.push(TapeBlock {
                    index: b.index,
                    tears,
                    residuals,
                    body,
                    linear: b.linear,
                    elements: b.elements.clone(),
                    junctions: Vec::new(),
                    touched: Vec::new(),
                    private: false,
                    constant_jacobian: false,
                    lu: std::cell::OnceCell::new(),
                    pattern: std::cell::OnceCell::new(),
                    charge_inverse: None,
                });
                let kk = k as usize;
                self.set_junctions(kk);
                self.set_touched(kk);
                out.push(Instr::Block { k });
            }
        }
    }
}

/// The variables a step computes and the ones it reads.
fn step_vars(
    sys: &EquationSystem,
    c: &crate::analysis::StructureGraph,
    step: &Step,
) -> (Vec<VarId>, Vec<VarId>) {
    let assigns: Vec<&Assignment> = match step {
        Step::Assign(a) => vec![a],
        Step::Block(b) => b.inner.iter().chain(&b.residuals).collect(),
    };
    let writes: Vec<VarId> = assigns.iter().map(|a| a.var).collect();
    // A block can write 10^5 variables: look them up in a set, not a scan.
    let written: std::collections::HashSet<VarId> = writes.iter().copied().collect();
    let mut reads = Vec::new();
    let (mut vars, mut stack) = (Vec::new(), Vec::new());
    for a in &assigns {
        sys.eq_vars(a.eq, &mut vars, &mut stack);
        reads.extend(vars.iter().copied().filter(|v| !written.contains(v)));
    }
    let _ = c;
    (writes, reads)
}

/// What an output computes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum OutputRef {
    /// An expression of the system's arena (a node potential).
    Expr(ExprId),
    /// The difference of two expressions (`v(a,b)`).
    Diff(ExprId, ExprId),
    /// A variable (a branch current).
    Var(VarId),
}

/// Compile `sched` of `sys`. `outputs` are evaluated at output points only.
pub fn compile(
    sys: &EquationSystem,
    graph: &crate::analysis::StructureGraph,
    sched: &Schedule,
    outputs: &[OutputRef],
) -> Tape {
    let states: Vec<VarId> = sys.states().collect();
    let mut c = Compiler {
        sys,
        sched,
        n_regs: 0,
        init: Vec::new(),
        memo: HashMap::new(),
        var_reg: vec![NONE; sys.vars.len()],
        param_reg: vec![NONE; sys.params.len()],
        consts: HashMap::new(),
        reg_var: Vec::new(),
        blocks: Vec::new(),
    };
    let state_regs: Vec<u32> = states
        .iter()
        .map(|&s| {
            let r = c.reg(0.0);
            c.var_reg[s.0 as usize] = r;
            c.reg_var[r as usize] = Some(s);
            r
        })
        .collect();
    // Which steps the derivatives need: walk the schedule backwards.
    let ders: Vec<VarId> = states
        .iter()
        .map(|&s| match sys.vars[s].role {
            crate::ir::VarRole::State { der } => der,
            _ => unreachable!("states have derivatives"),
        })
        .collect();
    let mut needed = vec![false; sys.vars.len()];
    for &d in &ders {
        needed[d.0 as usize] = true;
    }
    let info: Vec<(Vec<VarId>, Vec<VarId>)> = sched
        .steps
        .iter()
        .map(|s| step_vars(sys, graph, s))
        .collect();
    let mut in_f = vec![false; sched.steps.len()];
    for (k, (writes, reads)) in info.iter().enumerate().rev() {
        if writes.iter().any(|w| needed[w.0 as usize]) {
            in_f[k] = true;
            for r in reads {
                needed[r.0 as usize] = true;
            }
        }
    }
    // Which of the rest the outputs need: one pass over the outputs'
    // expression DAG, through aliases (the loop formulation's node
    // potentials share their tree paths: a pass per output was quadratic).
    let mut out_needed = vec![false; sys.vars.len()];
    let mut seen: std::collections::HashSet<ExprId> = std::collections::HashSet::new();
    let mut stack: Vec<ExprId> = Vec::new();
    let mark = |v: VarId, out_needed: &mut [bool], stack: &mut Vec<ExprId>| {
        if !std::mem::replace(&mut out_needed[v.0 as usize], true)
            && let Some(a) = sys.vars[v].alias
        {
            stack.push(a);
        }
    };
    for &o in outputs {
        match o {
            OutputRef::Expr(e) => stack.push(e),
            OutputRef::Diff(a, b) => stack.extend([a, b]),
            OutputRef::Var(v) => mark(v, &mut out_needed, &mut stack),
        }
        while let Some(e) = stack.pop() {
            if !seen.insert(e) {
                continue;
            }
            match sys.exprs.get(e) {
                Expr::Var(v) => mark(v, &mut out_needed, &mut stack),
                op => stack.extend(op.operands().into_iter().flatten()),
            }
        }
    }
    // Every step the outputs need, in f or not: the output program is
    // independent of `code`, so output points cost only what they read.
    let mut for_out = vec![false; sched.steps.len()];
    for (k, (writes, reads)) in info.iter().enumerate().rev() {
        if writes.iter().any(|w| out_needed[w.0 as usize]) {
            for_out[k] = true;
            for r in reads {
                out_needed[r.0 as usize] = true;
            }
        }
    }
    let at_out: Vec<bool> = for_out.iter().zip(&in_f).map(|(o, f)| *o && !f).collect();
    let mut code = Vec::new();
    for (k, step) in sched.steps.iter().enumerate() {
        if in_f[k] {
            c.step(step, &mut code);
        }
    }
    let deriv_regs: Vec<u32> = ders.iter().map(|d| c.var_reg[d.0 as usize]).collect();
    // The output program gets its own registers for everything computed.
    c.memo
        .retain(|&e, _| matches!(sched.exprs.get(e), Expr::Const(_)));
    for v in sys.vars.ids() {
        if !sys.vars[v].is_state() {
            c.var_reg[v.0 as usize] = NONE;
        }
    }
    let mut out_code = Vec::new();
    for (k, step) in sched.steps.iter().enumerate() {
        if for_out[k] {
            c.step(step, &mut out_code);
        }
    }
    let out_regs: Vec<u32> = outputs
        .iter()
        .map(|&o| match o {
            OutputRef::Expr(e) => c.emit(e, &mut out_code),
            OutputRef::Diff(a, b) => {
                let (ra, rb) = (c.emit(a, &mut out_code), c.emit(b, &mut out_code));
                let d = c.reg(0.0);
                out_code.push(Instr::Sub { d, a: ra, b: rb });
                d
            }
            OutputRef::Var(v) => c.var(v, &mut out_code),
        })
        .collect();
    let count = |flags: &[bool]| -> usize {
        sched
            .steps
            .iter()
            .zip(flags)
            .filter(|(_, f)| **f)
            .map(|(s, _)| match s {
                Step::Assign(_) => 1,
                Step::Block(b) => b.n_eqs(),
            })
            .sum()
    };
    let read: std::collections::HashSet<u32> = out_code
        .iter()
        .flat_map(|i| match i {
            Instr::Block { k } => c.blocks[*k as usize]
                .body
                .iter()
                .flat_map(|b| sources_of(b, &[]))
                .collect(),
            other => sources_of(other, &[]),
        })
        .chain(out_regs.iter().copied())
        .collect();
    let out_inputs: Vec<(usize, u32)> = state_regs
        .iter()
        .enumerate()
        .filter(|(_, r)| read.contains(r))
        .map(|(k, &r)| (k, r))
        .collect();
    set_private(
        &mut c.blocks,
        &[&code, &out_code],
        &[&deriv_regs, &out_regs],
    );
    set_constant_jacobians(&mut c.blocks, &[&code, &out_code], &state_regs);
    for k in 0..c.blocks.len() {
        c.blocks[k].charge_inverse = charge_inverse(&c.blocks[k]).map(|ci| {
            let memo = c.reg(f64::NAN);
            for _ in 1..4 {
                c.reg(f64::NAN);
            }
            ChargeInverse { memo, ..ci }
        });
    }
    let memo_links = memo_links(&c.blocks, &code, &out_code);
    let n_in_f = count(&in_f);
    let n_at_outputs = count(&at_out);
    let source_params: Vec<(u32, f64)> = sys
        .params
        .iter()
        .zip(&c.param_reg)
        .filter(|((_, p), r)| p.source && **r != NONE)
        .map(|((_, p), &r)| (r, p.value))
        .collect();
    Tape {
        n_regs: c.n_regs as usize,
        state_regs,
        states,
        deriv_regs,
        init: c.init,
        code,
        blocks: c.blocks,
        out_code,
        out_inputs,
        out_regs,
        memo_links,
        sources: sys.sources.values().map(|s| s.wave.clone()).collect(),
        diodes: sys.diodes.clone(),
        n_in_f,
        n_at_outputs,
        n_unused: sys.eqs.len() - n_in_f - n_at_outputs,
        reg_var: c.reg_var,
        dc: std::cell::Cell::new(false),
        source_scale: std::cell::Cell::new(1.0),
        source_params,
        source_memo: vec![std::cell::Cell::new((f64::NAN, 0.0)); sys.sources.len()],
    }
}

#[inline]
fn call(f: Func, x: f64) -> f64 {
    f.apply(x)
}

/// d/dx f(x).
#[inline]
fn call_deriv(f: Func, x: f64, fx: f64) -> f64 {
    match f {
        Func::Exp => fx,
        Func::Ln => 1.0 / x,
        Func::Sqrt => 0.5 / fx,
        Func::Sin => x.cos(),
        Func::Cos => -x.sin(),
        Func::Tan => 1.0 / (x.cos() * x.cos()),
        Func::Atan => 1.0 / (1.0 + x * x),
        Func::Sinh => x.cosh(),
        Func::Cosh => x.sinh(),
        Func::Tanh => 1.0 - fx * fx,
        Func::Abs => x.signum(),
    }
}

impl Tape {
    #[inline]
    fn source(&self, s: u32, t: f64, order: u8) -> f64 {
        if order > 0 && self.dc.get() {
            0.0
        } else {
            let value = if order == 0 {
                let memo = &self.source_memo[s as usize];
                let (at, v) = memo.get();
                if at == t {
                    v
                } else {
                    let v = self.sources[s as usize].eval(t, 0);
                    memo.set((t, v));
                    v
                }
            } else {
                self.sources[s as usize].eval(t, order)
            };
            value * self.source_scale.get()
        }
    }

    /// Fresh registers (parameters and constants set).
    pub fn registers(&self) -> Vec<f64> {
        self.init.clone()
    }

    /// Scale every independent source by `s`: the waveforms (through
    /// `source_scale`) and the DC values held in `regs`.
    pub fn scale_sources(&self, regs: &mut [f64], s: f64) {
        self.source_scale.set(s);
        for &(r, v) in &self.source_params {
            regs[r as usize] = v * s;
        }
    }

    fn run(&self, code: &[Instr], r: &mut [f64], t: f64) -> Result<(), EvalError> {
        for ins in code {
            match *ins {
                Instr::Neg { d, a } => r[d as usize] = -r[a as usize],
                Instr::Add { d, a, b } => r[d as usize] = r[a as usize] + r[b as usize],
                Instr::Sub { d, a, b } => r[d as usize] = r[a as usize] - r[b as usize],
                Instr::Mul { d, a, b } => r[d as usize] = r[a as usize] * r[b as usize],
                Instr::Div { d, a, b } => r[d as usize] = r[a as usize] / r[b as usize],
                Instr::Pow { d, a, b } => r[d as usize] = r[a as usize].powf(r[b as usize]),
                Instr::Call { d, f, a } => r[d as usize] = call(f, r[a as usize]),
                Instr::Device { d, f, a } => {
                    r[d as usize] =
                        self.diodes[f.diode as usize].eval(f.part, f.order, r[a as usize])
                }
                Instr::Src { d, s, order } => r[d as usize] = self.source(s, t, order),
                Instr::Time { d } => r[d as usize] = t,
                Instr::Block { k } => self.solve_block(k as usize, r, t)?,
            }
        }
        Ok(())
    }

    /// Tangents of `code` given tangents of its inputs in `dr` (registers not
    /// written by `code` keep their tangent).
    fn run_tangent(
        &self,
        code: &[Instr],
        r: &mut [f64],
        dr: &mut [f64],
        t: f64,
        mut cache: Option<&mut TangentCache>,
    ) -> Result<(), EvalError> {
        for ins in code {
            match *ins {
                Instr::Neg { d, a } => {
                    r[d as usize] = -r[a as usize];
                    dr[d as usize] = -dr[a as usize];
                }
                Instr::Add { d, a, b } => {
                    r[d as usize] = r[a as usize] + r[b as usize];
                    dr[d as usize] = dr[a as usize] + dr[b as usize];
                }
                Instr::Sub { d, a, b } => {
                    r[d as usize] = r[a as usize] - r[b as usize];
                    dr[d as usize] = dr[a as usize] - dr[b as usize];
                }
                Instr::Mul { d, a, b } => {
                    let (x, y) = (r[a as usize], r[b as usize]);
                    r[d as usize] = x * y;
                    dr[d as usize] = dr[a as usize] * y + x * dr[b as usize];
                }
                Instr::Div { d, a, b } => {
                    let (x, y) = (r[a as usize], r[b as usize]);
                    let q = x / y;
                    r[d as usize] = q;
                    dr[d as usize] = (dr[a as usize] - q * dr[b as usize]) / y;
                }
                Instr::Pow { d, a, b } => {
                    let (x, y) = (r[a as usize], r[b as usize]);
                    let p = x.powf(y);
                    r[d as usize] = p;
                    let (dx, dy) = (dr[a as usize], dr[b as usize]);
                    let mut dp = y * x.powf(y - 1.0) * dx;
                    if dy != 0.0 {
                        dp += p * x.ln() * dy;
                    }
                    dr[d as usize] = dp;
                }
                Instr::Call { d, f, a } => {
                    let x = r[a as usize];
                    let fx = call(f, x);
                    r[d as usize] = fx;
                    dr[d as usize] = call_deriv(f, x, fx) * dr[a as usize];
                }
                Instr::Device { d, f, a } => {
                    let x = r[a as usize];
                    let p = &self.diodes[f.diode as usize];
                    let (v, slope) = p.eval_with_slope(f.part, f.order, x);
                    r[d as usize] = v;
                    dr[d as usize] = slope * dr[a as usize];
                }
                Instr::Src { d, s, order } => {
                    r[d as usize] = self.source(s, t, order);
                    dr[d as usize] = 0.0;
                }
                Instr::Time { d } => {
                    r[d as usize] = t;
                    dr[d as usize] = 0.0;
                }
                Instr::Block { k } => {
                    // Value first (Newton), then the tangent of the solution by
                    // the implicit function theorem: J dt = -(dR/dx) dx.
                    let k = k as usize;
                    let b = &self.blocks[k];
                    if let Some(ci) = b.charge_inverse {
                        // Q(x) = target: dx = d(target)/Q′(x), no body runs.
                        let (x, q, res, sign) = Self::charge_regs(b);
                        let kept = match cache.as_deref() {
                            Some(c) if c.valid => c.lus.get(k).and_then(|l| l.as_ref()),
                            _ => None,
                        };
                        let slope = match kept {
                            Some(Factored::Dense(d)) => sign * d.lu[0],
                            Some(Factored::Sparse(_)) => {
                                unreachable!("a charge block has one tear")
                            }
                            None => {
                                self.solve_block(k, r, t)?;
                                let [_, c, _] = self.diodes[ci.diode as usize].charge(r[x]);
                                if let Some(cache) = cache.as_deref_mut() {
                                    cache.keep(k, self.blocks.len(), &[sign * c], &[0]);
                                }
                                c
                            }
                        };
                        if !(slope.is_finite() && slope != 0.0) {
                            return Err(b.singular(t));
                        }
                        let dq = dr[ci.target as usize];
                        dr[x] = dq / slope;
                        dr[q] = dq;
                        dr[res] = 0.0;
                        continue;
                    }
                    let n = b.tears.len();
                    let mut w = Work::take(n, r.len());
                    // Another column at the point of the last run: the block
                    // is solved and its Jacobian factored already.
                    let kept = match cache.as_deref() {
                        Some(c) if c.valid => c.lus.get(k).is_some_and(|l| l.is_some()),
                        _ => false,
                    };
                    let mut sparse = None;
                    // Whether the factors to solve with are in the cache.
                    let mut cached = kept;
                    if !kept {
                        self.solve_block(k, r, t)?;
                        if !b.constant_jacobian {
                            w.saved.extend(b.touched.iter().map(|&x| dr[x as usize]));
                            let factored = self.factor_jacobian(b, r, dr, t, &mut w);
                            for (&x, &v) in b.touched.iter().zip(&w.saved) {
                                dr[x as usize] = v;
                            }
                            sparse = factored?;
                        }
                        if let Some(c) = cache.as_deref_mut() {
                            cached = true;
                            // A constant Jacobian has its own factorization.
                            match sparse.take() {
                                Some(lu) => {
                                    *c.slot(k, self.blocks.len()) = Some(Factored::Sparse(lu));
                                }
                                None if b.constant_jacobian => {
                                    c.keep(k, self.blocks.len(), &[], &[])
                                }
                                None => c.keep(k, self.blocks.len(), &w.jac, &w.perm),
                            }
                        }
                    }
                    for &x in &b.tears {
                        dr[x as usize] = 0.0;
                    }
                    self.run_tangent(&b.body, r, dr, t, None)?;
                    w.res.extend(b.residuals.iter().map(|&x| -dr[x as usize]));
                    if b.constant_jacobian {
                        self.constant_lu(b, r, t, &mut w)?
                            .solve_in_place(&mut w.res, &mut w.tmp);
                    } else if cached
                        && let Some(lu) = cache.as_deref().and_then(|c| c.lus.get(k)?.as_ref())
                    {
                        lu.solve_in_place(&mut w.res, &mut w.tmp);
                    } else {
                        solve_factored(sparse.as_ref(), &w.jac, &w.perm, &mut w.res, &mut w.tmp);
                    }
                    for (j, &x) in b.tears.iter().enumerate() {
                        dr[x as usize] = w.res[j];
                    }
                    w.give();
                    self.run_tangent(&b.body, r, dr, t, None)?;
                }
            }
        }
        Ok(())
    }

    /// Tangents of `code` in `m` directions at once: the tangent of register
    /// `x` in direction `j` is `dr[x * m + j]`. Each instruction's value and
    /// slope are computed once for all directions (a device's exponential
    /// once, not once per column).
    fn run_tangents(
        &self,
        code: &[Instr],
        r: &mut [f64],
        dr: &mut [f64],
        m: usize,
        t: f64,
    ) -> Result<(), EvalError> {
        // dr[d] = ka·dr[a] (+ kb·dr[b]) in every direction.
        fn lin(dr: &mut [f64], m: usize, d: u32, a: (u32, f64), b: Option<(u32, f64)>) {
            let (d, a0, ka) = (d as usize * m, a.0 as usize * m, a.1);
            match b {
                Some((b, kb)) => {
                    let b0 = b as usize * m;
                    for j in 0..m {
                        dr[d + j] = ka * dr[a0 + j] + kb * dr[b0 + j];
                    }
                }
                None => {
                    for j in 0..m {
                        dr[d + j] = ka * dr[a0 + j];
                    }
                }
            }
        }
        for ins in code {
            match *ins {
                Instr::Neg { d, a } => {
                    r[d as usize] = -r[a as usize];
                    lin(dr, m, d, (a, -1.0), None);
                }
                Instr::Add { d, a, b } => {
                    r[d as usize] = r[a as usize] + r[b as usize];
                    lin(dr, m, d, (a, 1.0), Some((b, 1.0)));
                }
                Instr::Sub { d, a, b } => {
                    r[d as usize] = r[a as usize] - r[b as usize];
                    lin(dr, m, d, (a, 1.0), Some((b, -1.0)));
                }
                Instr::Mul { d, a, b } => {
                    let (x, y) = (r[a as usize], r[b as usize]);
                    r[d as usize] = x * y;
                    lin(dr, m, d, (a, y), Some((b, x)));
                }
                Instr::Div { d, a, b } => {
                    let (x, y) = (r[a as usize], r[b as usize]);
                    let q = x / y;
                    r[d as usize] = q;
                    lin(dr, m, d, (a, 1.0 / y), Some((b, -q / y)));
                }
                Instr::Pow { d, a, b } => {
                    let (x, y) = (r[a as usize], r[b as usize]);
                    let p = x.powf(y);
                    r[d as usize] = p;
                    let ka = y * x.powf(y - 1.0);
                    let b0 = b as usize * m;
                    if dr[b0..b0 + m].iter().all(|v| *v == 0.0) {
                        lin(dr, m, d, (a, ka), None);
                    } else {
                        lin(dr, m, d, (a, ka), Some((b, p * x.ln())));
                    }
                }
                Instr::Call { d, f, a } => {
                    let x = r[a as usize];
                    let fx = call(f, x);
                    r[d as usize] = fx;
                    lin(dr, m, d, (a, call_deriv(f, x, fx)), None);
                }
                Instr::Device { d, f, a } => {
                    let p = &self.diodes[f.diode as usize];
                    let (v, slope) = p.eval_with_slope(f.part, f.order, r[a as usize]);
                    r[d as usize] = v;
                    lin(dr, m, d, (a, slope), None);
                }
                Instr::Src { d, s, order } => {
                    r[d as usize] = self.source(s, t, order);
                    dr[d as usize * m..(d as usize + 1) * m].fill(0.0);
                }
                Instr::Time { d } => {
                    r[d as usize] = t;
                    dr[d as usize * m..(d as usize + 1) * m].fill(0.0);
                }
                Instr::Block { k } => {
                    // The value (Newton), the block's Jacobian factored once,
                    // then the implicit function theorem in each direction.
                    let b = &self.blocks[k as usize];
                    if let Some(ci) = b.charge_inverse {
                        self.solve_block(k as usize, r, t)?;
                        let (x, q, res, _) = Self::charge_regs(b);
                        let [_, c, _] = self.diodes[ci.diode as usize].charge(r[x]);
                        if !(c.is_finite() && c != 0.0) {
                            return Err(b.singular(t));
                        }
                        let target = ci.target as usize * m;
                        for j in 0..m {
                            let dq = dr[target + j];
                            dr[x * m + j] = dq / c;
                            dr[q * m + j] = dq;
                            dr[res * m + j] = 0.0;
                        }
                        continue;
                    }
                    let n = b.tears.len();
                    let mut w = Work::take(n, r.len());
                    self.solve_block(k as usize, r, t)?;
                    let result = (|| {
                        let mut sparse = None;
                        let constant = if b.constant_jacobian {
                            Some(self.constant_lu(b, r, t, &mut w)?)
                        } else {
                            let mut scratch = std::mem::take(&mut w.dr);
                            let got = self.factor_jacobian(b, r, &mut scratch, t, &mut w);
                            w.dr = scratch;
                            sparse = got?;
                            None
                        };
                        for &x in &b.tears {
                            dr[x as usize * m..(x as usize + 1) * m].fill(0.0);
                        }
                        self.run_tangents(&b.body, r, dr, m, t)?;
                        // Direction by direction; a tear's slot in direction
                        // j is not read by the other directions' solves.
                        for j in 0..m {
                            for (i, &res) in b.residuals.iter().enumerate() {
                                w.step[i] = -dr[res as usize * m + j];
                            }
                            match constant {
                                Some(lu) => lu.solve_in_place(&mut w.step, &mut w.tmp),
                                None => solve_factored(
                                    sparse.as_ref(),
                                    &w.jac,
                                    &w.perm,
                                    &mut w.step,
                                    &mut w.tmp,
                                ),
                            }
                            for (i, &x) in b.tears.iter().enumerate() {
                                dr[x as usize * m + j] = w.step[i];
                            }
                        }
                        self.run_tangents(&b.body, r, dr, m, t)
                    })();
                    w.give();
                    result?;
                }
            }
        }
        Ok(())
    }

    /// The registers of a charge-inversion block `0 = ±(target - Q(x))`:
    /// (x, q = Q(x), residual), and the sign of `∂residual/∂x = ±Q′(x)`.
    fn charge_regs(b: &TapeBlock) -> (usize, usize, usize, f64) {
        let [Instr::Device { d: q, .. }, Instr::Sub { d: res, a: l, .. }] = b.body[..] else {
            unreachable!("a charge inversion is [Device, Sub]")
        };
        let sign = if l == q { 1.0 } else { -1.0 };
        (b.tears[0] as usize, q as usize, res as usize, sign)
    }

    /// ∂residuals/∂tears at the current point into `jac` (row-major n×n),
    /// evaluating the body there too; leaves `dr` of the body registers dirty.
    fn block_jacobian(
        &self,
        b: &TapeBlock,
        r: &mut [f64],
        dr: &mut [f64],
        t: f64,
        jac: &mut [f64],
    ) -> Result<(), EvalError> {
        let n = b.tears.len();
        if n == 0 {
            return self.run(&b.body, r, t);
        }
        for j in 0..n {
            // Registers read by the body but not written are constants here.
            for &x in &b.touched {
                dr[x as usize] = 0.0;
            }
            dr[b.tears[j] as usize] = 1.0;
            self.run_tangent(&b.body, r, dr, t, None)?;
            for (i, &res) in b.residuals.iter().enumerate() {
                jac[i * n + j] = dr[res as usize];
            }
        }
        Ok(())
    }

    /// Damped Newton on a block's tearing variables, warm-started from their
    /// current values; on failure the warm start is left for the solver's
    /// retry.
    fn solve_block(&self, k: usize, r: &mut [f64], t: f64) -> Result<(), EvalError> {
        let b = &self.blocks[k];
        if let Some(ci) = b.charge_inverse
            && self.invert_charge(b, ci, r)
        {
            return self.settle(b, r, t);
        }
        let mut w = Work::take(b.tears.len(), r.len());
        w.start.extend(b.tears.iter().map(|&x| r[x as usize]));
        let result = if b.constant_jacobian {
            self.solve_affine(b, r, t, &mut w)
        } else if b.tears.len() == 1 {
            self.newton_scalar(b, r, t, &mut w)
        } else {
            self.newton_iterate(b, r, t, &mut w)
        };
        if result.is_err() {
            for (j, &x) in b.tears.iter().enumerate() {
                r[x as usize] = w.start[j];
            }
        }
        w.give();
        result
    }

    /// After the last correction of `b`'s tears: bring its body up to date
    /// unless nothing outside reads it (`private`).
    fn settle(&self, b: &TapeBlock, r: &mut [f64], t: f64) -> Result<(), EvalError> {
        if b.private {
            Ok(())
        } else {
            self.run(&b.body, r, t)
        }
    }

    /// The factored constant Jacobian of `b`, computed at the first call
    /// that finds it finite and regular (a failure is not remembered: the
    /// registers it was computed from may have held a failed trial point),
    /// by [`Tape::factor_jacobian`]: dense up to [`DENSE_TEARS`] tears,
    /// sparse beyond (a ladder torn every few sections couples each residual
    /// to a few neighbouring tears; its dense LU, cubic in the tears, took
    /// 50 s at 5000).
    fn constant_lu<'t>(
        &self,
        b: &'t TapeBlock,
        r: &mut [f64],
        t: f64,
        w: &mut Work,
    ) -> Result<&'t Factored, EvalError> {
        if let Some(lu) = b.lu.get() {
            return Ok(lu);
        }
        let mut dr = std::mem::take(&mut w.dr);
        let factored = self.factor_jacobian(b, r, &mut dr, t, w);
        w.dr = dr;
        let lu = match factored? {
            Some(sparse) => Factored::Sparse(sparse),
            None => Factored::Dense(DenseLu {
                lu: w.jac.clone(),
                perm: w.perm.clone(),
            }),
        };
        Ok(b.lu.get_or_init(|| lu))
    }

    /// `b`'s Jacobian at the current point, factored (the body is evaluated
    /// there too; `dr`'s tangents of the body are left dirty): dense into
    /// `w.jac` and `w.perm` (`None`), or past [`DENSE_TEARS`] sparse.
    fn factor_jacobian(
        &self,
        b: &TapeBlock,
        r: &mut [f64],
        dr: &mut [f64],
        t: f64,
        w: &mut Work,
    ) -> Result<Option<TripletLu>, EvalError> {
        let n = b.tears.len();
        if n > DENSE_TEARS {
            let entries = self.sparse_columns(b, r, dr, t)?;
            return match entries.iter().all(|e| e.2.is_finite()) {
                true => TripletLu::new(n, entries)
                    .map(Some)
                    .ok_or_else(|| b.singular(t)),
                false => Err(b.singular(t)),
            };
        }
        w.dense_jac(n);
        self.block_jacobian(b, r, dr, t, &mut w.jac)?;
        if !(w.jac.iter().all(|v| v.is_finite()) && lu_factor(n, &mut w.jac, &mut w.perm)) {
            return Err(b.singular(t));
        }
        Ok(None)
    }

    /// The nonzero entries `(residual, tear, ∂)` of `b`'s Jacobian at the
    /// current point: columns that share no residual ([`tear_pattern`],
    /// coloured once per block) in one tangent run, else one run a column.
    fn sparse_columns(
        &self,
        b: &TapeBlock,
        r: &mut [f64],
        dr: &mut [f64],
        t: f64,
    ) -> Result<Vec<(usize, usize, f64)>, EvalError> {
        let n = b.tears.len();
        let mut entries = Vec::new();
        let pattern = b.pattern.get_or_init(|| {
            tear_pattern(b).map(|rows| {
                let (colour, n_colours) = colour_columns(n, &rows);
                Pattern {
                    members: members(&colour, n_colours),
                    rows,
                    colour,
                }
            })
        });
        // Without a pattern every column is its own colour.
        let n_colours = pattern.as_ref().map_or(n, |p| p.members.len()) as u32;
        for c in 0..n_colours {
            for &x in &b.touched {
                dr[x as usize] = 0.0;
            }
            let seeds = match pattern {
                Some(p) => &p.members[c as usize][..],
                None => std::slice::from_ref(&c),
            };
            for &j in seeds {
                dr[b.tears[j as usize] as usize] = 1.0;
            }
            self.run_tangent(&b.body, r, dr, t, None)?;
            for (i, &res) in b.residuals.iter().enumerate() {
                let v = dr[res as usize];
                let j = match pattern {
                    Some(p) => p.rows[i]
                        .iter()
                        .find(|&&j| p.colour[j as usize] == c)
                        .copied(),
                    None => Some(c),
                };
                if let Some(j) = j
                    && v != 0.0
                {
                    entries.push((i, j as usize, v));
                }
            }
        }
        Ok(entries)
    }

    /// A block whose residuals are affine in the tears with a constant
    /// Jacobian: one correction from the current tears solves it.
    fn solve_affine(
        &self,
        b: &TapeBlock,
        r: &mut [f64],
        t: f64,
        w: &mut Work,
    ) -> Result<(), EvalError> {
        let lu = self.constant_lu(b, r, t, w)?;
        self.run(&b.body, r, t)?;
        for (j, &x) in b.residuals.iter().enumerate() {
            w.step[j] = r[x as usize];
        }
        if w.step.iter().all(|v| *v == 0.0) {
            return Ok(());
        }
        lu.solve_in_place(&mut w.step, &mut w.tmp);
        if w.step.iter().any(|v| !v.is_finite()) {
            return Err(b.singular(t));
        }
        for (j, &x) in b.tears.iter().enumerate() {
            r[x as usize] -= w.step[j];
        }
        self.settle(b, r, t)
    }

    /// Halley's method on `Q(x) = q` with the device's `Q′` and `Q″`, from the
    /// warm start in the tear. What a Halley step leaves is about its cube
    /// times `Q″²/(4Q′²) - Q‴/(6Q′)`, bounded here from the junction's
    /// parameters: a warm start within a few microvolts converges in one
    /// evaluation where Newton needs two. Far steps are limited as ngspice
    /// limits junctions. `false` (the tear as it was) when the iteration
    /// cannot proceed: the damped Newton takes over.
    fn invert_charge(&self, b: &TapeBlock, ci: ChargeInverse, r: &mut [f64]) -> bool {
        let p = &self.diodes[ci.diode as usize];
        let (x_reg, target) = (b.tears[0] as usize, r[ci.target as usize]);
        let memo = ci.memo as usize;
        let start = r[x_reg];
        // From the last evaluated point when there is one: its values are
        // known, so the first step is free.
        let mut x = if r[memo].is_finite() { r[memo] } else { start };
        for _ in 0..100 {
            let [q, c, c2] = if x == r[memo] {
                [r[memo + 1], r[memo + 2], r[memo + 3]]
            } else {
                let v = p.charge(x);
                r[memo] = x;
                r[memo + 1..memo + 4].copy_from_slice(&v);
                v
            };
            let f = q - target;
            if f == 0.0 {
                r[x_reg] = x;
                return true;
            }
            if !(c > 0.0 && f.is_finite() && c2.is_finite()) {
                break;
            }
            let newton = f / c;
            let k = c2 / c;
            let h = 0.5 * newton * k;
            let (step, left) = if h.abs() <= 0.5 {
                let step = newton / (1.0 - h);
                let constant = 0.25 * k * k + p.third_derivative_bound(x);
                (step, step.abs().powi(3) * constant)
            } else {
                (newton, 0.5 * newton * newton * k.abs())
            };
            let next = x - step;
            let limited = pnjlim(next, x, p.vte);
            if limited != next {
                x = limited;
                continue;
            }
            x = next;
            if left <= 1e-13 * (1.0 + x.abs()) {
                r[x_reg] = x;
                return true;
            }
        }
        r[x_reg] = start;
        false
    }

    /// Newton on a one-tear block: each iteration is one tangent run of the
    /// body, which gives the residual and its slope together. The step is
    /// damped by the same natural monotonicity test as [`Self::newton_iterate`]
    /// (checked with the residual the next iteration computes anyway) and
    /// junction tears are limited as ngspice limits them.
    fn newton_scalar(
        &self,
        b: &TapeBlock,
        r: &mut [f64],
        t: f64,
        w: &mut Work,
    ) -> Result<(), EvalError> {
        let (x, res) = (b.tears[0] as usize, b.residuals[0] as usize);
        let vt = b.junctions.first().map(|&(_, vt)| vt as usize);
        let finish = |r: &mut [f64], value: f64| {
            r[x] = value;
            self.settle(b, r, t)
        };
        // The last full step: start, correction, slope, scaled size, damping.
        let mut last: Option<(f64, f64, f64, f64, f64)> = None;
        for _ in 0..400 {
            for &z in &b.touched {
                w.dr[z as usize] = 0.0;
            }
            w.dr[x] = 1.0;
            self.run_tangent(&b.body, r, &mut w.dr, t, None)?;
            let (fx, slope, xv) = (r[res], w.dr[res], r[x]);
            if let Some((x0, step0, slope0, full0, lambda)) = last {
                let simplified = (fx / slope0).abs() / (1.0 + x0.abs());
                if !newton::monotone(simplified, full0, lambda) {
                    let lambda = lambda * 0.5;
                    if lambda < newton::MIN_DAMPING {
                        if full0 <= 1e-9 {
                            return Ok(());
                        }
                        return Err(b.no_convergence(fx.abs(), t));
                    }
                    r[x] = x0 - lambda * step0;
                    last = Some((x0, step0, slope0, full0, lambda));
                    continue;
                }
            }
            if fx == 0.0 {
                return Ok(());
            }
            let step = fx / slope;
            let full = step.abs() / (1.0 + xv.abs());
            if !full.is_finite() {
                return Err(b.singular(t));
            }
            if full <= 1e-13 {
                return finish(r, xv - step);
            }
            if let Some((_, _, _, full0, 1.0)) = last
                && newton::converged_quadratically(full0, full)
            {
                // Quadratic convergence: what this step leaves is below rounding.
                return finish(r, xv - step);
            }
            if let Some(vt) = vt {
                let vt = r[vt].abs();
                // A junction's residual curves like exp(x/vt): Newton's error
                // after this step is about step²/(2 vt). Below rounding, the
                // step is the last one.
                if vt > 0.0 && step * step <= 2e-13 * vt * (1.0 + xv.abs()) {
                    return finish(r, xv - step);
                }
                if vt > 0.0 {
                    let limited = pnjlim(xv - step, xv, vt);
                    if limited != xv - step {
                        r[x] = limited;
                        last = None;
                        continue;
                    }
                }
            }
            r[x] = xv - step;
            last = Some((xv, step, slope, full, 1.0));
        }
        Err(b.no_convergence(r[res].abs(), t))
    }

    /// Damped Newton with the natural monotonicity test (Deuflhard): a step
    /// is accepted when the simplified Newton correction at the new point,
    /// `J⁻¹ r(x_new)` with the old `J`, is shorter than the full correction.
    /// Affine invariant, so badly scaled residuals (amperes beside volts)
    /// do not mislead the damping. Allocation-free: `w` holds the buffers.
    fn newton_iterate(
        &self,
        b: &TapeBlock,
        r: &mut [f64],
        t: f64,
        w: &mut Work,
    ) -> Result<(), EvalError> {
        let no_convergence = |r: &[f64]| {
            let residual = b
                .residuals
                .iter()
                .map(|&x| r[x as usize].abs())
                .fold(0.0, f64::max);
            b.no_convergence(residual, t)
        };
        let scaled = |d: &[f64], x: &[f64]| newton::scaled_norm(d, |k| 1.0 + x[k].abs());
        let set = |r: &mut [f64], x0: &[f64], step: &[f64], lambda: f64| {
            for (j, &x) in b.tears.iter().enumerate() {
                r[x as usize] = x0[j] - lambda * step[j];
            }
        };
        // The Jacobian's tangent runs evaluate the body too.
        for _ in 0..200 {
            let mut dr = std::mem::take(&mut w.dr);
            let factored = self.factor_jacobian(b, r, &mut dr, t, w);
            w.dr = dr;
            let sparse = factored?;
            for (j, &x) in b.residuals.iter().enumerate() {
                w.step[j] = r[x as usize];
            }
            if w.step.iter().all(|v| *v == 0.0) {
                return Ok(());
            }
            solve_factored(sparse.as_ref(), &w.jac, &w.perm, &mut w.step, &mut w.tmp);
            for (j, &x) in b.tears.iter().enumerate() {
                w.x0[j] = r[x as usize];
            }
            let full = scaled(&w.step, &w.x0);
            if !full.is_finite() {
                return Err(b.singular(t));
            }
            if full <= 1e-13 {
                // Converged to rounding: take the last correction and stop.
                set(r, &w.x0, &w.step, 1.0);
                return self.settle(b, r, t);
            }
            // Junction limiting (ngspice's pnjlim) on tears inside an exp().
            // A limited step is taken as it is, as SPICE does.
            let mut limited = false;
            for &(j, vt) in &b.junctions {
                let vt = r[vt as usize].abs();
                if vt > 0.0 {
                    let new = pnjlim(w.x0[j] - w.step[j], w.x0[j], vt);
                    if new != w.x0[j] - w.step[j] {
                        limited = true;
                    }
                    w.step[j] = w.x0[j] - new;
                }
            }
            if limited {
                set(r, &w.x0, &w.step, 1.0);
                continue;
            }
            let damping = newton::damp(full, |lambda| {
                set(r, &w.x0, &w.step, lambda);
                self.run(&b.body, r, t)?;
                for (j, &x) in b.residuals.iter().enumerate() {
                    w.bar[j] = r[x as usize];
                }
                solve_factored(sparse.as_ref(), &w.jac, &w.perm, &mut w.bar, &mut w.tmp);
                // The same scaling as the full correction: a scale that moved
                // with x would make a shrinking |x| look like no progress.
                Ok(scaled(&w.bar, &w.x0))
            })?;
            let Damping::Accepted { lambda, simplified } = damping else {
                if full <= 1e-9 {
                    // Stalled at rounding level: converged as far as f64 allows.
                    return Ok(());
                }
                return Err(no_convergence(r));
            };
            if b.linear && lambda == 1.0 && b.junctions.is_empty() {
                return Ok(());
            }
            if lambda == 1.0 && newton::converged_quadratically(full, simplified) {
                // Quadratic convergence has set in: the simplified correction
                // leaves an error of order `simplified * full`, below rounding.
                for (j, &x) in b.tears.iter().enumerate() {
                    r[x as usize] -= w.bar[j];
                }
                return self.settle(b, r, t);
            }
            // Otherwise go on: the next correction (at most 1e-13) is applied
            // at the top, so the solution is as exact as f64 allows; the
            // integrator's Newton needs f to be smooth to its own tolerance.
        }
        Err(no_convergence(r))
    }

    /// `f(t, y)`: load the states, run the program, read the derivatives.
    pub fn rhs(
        &self,
        regs: &mut [f64],
        t: f64,
        y: &[f64],
        dy: &mut [f64],
    ) -> Result<(), EvalError> {
        for (k, &s) in self.state_regs.iter().enumerate() {
            regs[s as usize] = y[k];
        }
        self.run(&self.code, regs, t)?;
        for (k, &d) in self.deriv_regs.iter().enumerate() {
            dy[k] = regs[d as usize];
        }
        Ok(())
    }

    /// `J(t, y) v`, by forward-mode tangents. `dregs` is scratch. With a
    /// valid `cache` (the registers hold the last run at this same point),
    /// blocks are not solved again and their factored Jacobians are reused.
    #[allow(clippy::too_many_arguments)]
    pub fn jac_mul(
        &self,
        regs: &mut [f64],
        dregs: &mut [f64],
        t: f64,
        y: &[f64],
        v: &[f64],
        jv: &mut [f64],
        cache: Option<&mut TangentCache>,
    ) -> Result<(), EvalError> {
        dregs.iter_mut().for_each(|x| *x = 0.0);
        for (k, &s) in self.state_regs.iter().enumerate() {
            regs[s as usize] = y[k];
            dregs[s as usize] = v[k];
        }
        let mut cache = cache;
        let r = self.run_tangent(&self.code, regs, dregs, t, cache.as_deref_mut());
        if let Some(c) = cache {
            c.valid = r.is_ok();
        }
        r?;
        for (k, &d) in self.deriv_regs.iter().enumerate() {
            jv[k] = dregs[d as usize];
        }
        Ok(())
    }

    /// Columns `cols` of `∂f/∂y` at `(t, y)` in one pass (row-major into
    /// `jac`: `jac[i * cols.len() + j] = ∂f_i/∂y_cols[j]`), `f` into `dy`.
    /// `dregs` is scratch.
    #[allow(clippy::too_many_arguments)]
    pub fn jacobian_columns(
        &self,
        regs: &mut [f64],
        dregs: &mut Vec<f64>,
        t: f64,
        y: &[f64],
        cols: &[usize],
        jac: &mut [f64],
        dy: &mut [f64],
    ) -> Result<(), EvalError> {
        let m = cols.len();
        dregs.clear();
        dregs.resize(self.n_regs * m, 0.0);
        for (k, &s) in self.state_regs.iter().enumerate() {
            regs[s as usize] = y[k];
        }
        for (j, &c) in cols.iter().enumerate() {
            dregs[self.state_regs[c] as usize * m + j] = 1.0;
        }
        self.run_tangents(&self.code, regs, dregs, m, t)?;
        for (i, &d) in self.deriv_regs.iter().enumerate() {
            jac[i * m..(i + 1) * m].copy_from_slice(&dregs[d as usize * m..(d as usize + 1) * m]);
            dy[i] = regs[d as usize];
        }
        Ok(())
    }

    /// The outputs, after `rhs` has run at the same point.
    /// The outputs at `(t, y)` (independent of [`Tape::rhs`]).
    pub fn outputs(
        &self,
        regs: &mut [f64],
        t: f64,
        y: &[f64],
        out: &mut [f64],
    ) -> Result<(), EvalError> {
        for &(k, s) in &self.out_inputs {
            regs[s as usize] = y[k];
        }
        for &(from, to) in &self.memo_links {
            let (from, to) = (from as usize, to as usize);
            if regs[from].is_finite() {
                regs.copy_within(from..from + 4, to);
            }
        }
        self.run(&self.out_code, regs, t)?;
        for (k, &o) in self.out_regs.iter().enumerate() {
            out[k] = regs[o as usize];
        }
        Ok(())
    }

    /// For each state, the junction-charge inversion whose charge it is
    /// (the block that finds the junction voltage from it), if any.
    pub fn charge_states(&self) -> Vec<Option<ChargeInverse>> {
        let slot: HashMap<u32, usize> = self
            .state_regs
            .iter()
            .enumerate()
            .map(|(k, &s)| (s, k))
            .collect();
        let mut of = vec![None; self.states.len()];
        for ins in &self.code {
            if let Instr::Block { k } = *ins
                && let Some(ci) = self.blocks[k as usize].charge_inverse
                && let Some(&k) = slot.get(&ci.target)
                && of[k].is_none()
            {
                of[k] = Some(ci);
            }
        }
        of
    }

    /// Whether `f` depends on the states nonlinearly only through junctions
    /// in the way a circuit integrator can follow exactly: each junction
    /// charge `q` is read only by its inversion `v = Q⁻¹(q)`, `v` enters
    /// affinely with constant coefficients, and the junction current
    /// `i_d(v)` enters only its own charge's derivative, as `… - i_d(v)`.
    /// Then `∂f/∂q` is `∂f/∂v / Q′(v)` with `∂f/∂v` constant but for the
    /// `-g_d(v)` of its own row, and a Jacobian computed anywhere becomes the
    /// Jacobian at another point by rescaling each junction's column and
    /// diagonal (see `sim::trbdf2`). Everything else (time-varying sources,
    /// parameters) may be arbitrary functions of time.
    ///
    /// Conservative: any other use of a state (a resistive diode's block, a
    /// product of two signals, a coefficient that varies in time) answers
    /// `false`.
    pub fn jacobian_follows_junctions(&self) -> bool {
        let mut dep = vec![Dep::Const; self.n_regs];
        let charges = self.charge_states();
        for (k, &s) in self.state_regs.iter().enumerate() {
            dep[s as usize] = match charges[k] {
                Some(ci) => Dep::Charge(ci.diode),
                None => Dep::Lin,
            };
        }
        self.classify(&self.code, &mut dep);
        self.deriv_regs
            .iter()
            .enumerate()
            .all(|(k, &d)| match dep[d as usize] {
                Dep::Const | Dep::Time | Dep::Lin | Dep::Volt(_) => true,
                Dep::IdNeg(diode) => charges[k].is_some_and(|ci| ci.diode == diode),
                Dep::Charge(_) | Dep::IdPos(_) | Dep::Bad => false,
            })
    }

    /// How each register of `code` depends on the states (see
    /// [`Tape::jacobian_follows_junctions`]).
    fn classify(&self, code: &[Instr], dep: &mut [Dep]) {
        for ins in code {
            let (d, v) = match *ins {
                Instr::Neg { d, a } => (d, dep[a as usize].negate()),
                Instr::Add { d, a, b } => (d, Dep::sum(dep[a as usize], dep[b as usize])),
                Instr::Sub { d, a, b } => (d, Dep::sum(dep[a as usize], dep[b as usize].negate())),
                Instr::Mul { d, a, b } => (d, Dep::product(dep[a as usize], dep[b as usize])),
                Instr::Div { d, a, b } => match (dep[a as usize], dep[b as usize]) {
                    (x, Dep::Const) => (d, Dep::product(x, Dep::Const)),
                    (x, y) if x.timed() && y.timed() => (d, Dep::Time),
                    _ => (d, Dep::Bad),
                },
                Instr::Pow { d, a, b } => {
                    match dep[a as usize].timed() && dep[b as usize].timed() {
                        true => (d, dep[a as usize].max_timed(dep[b as usize])),
                        false => (d, Dep::Bad),
                    }
                }
                Instr::Call { d, a, .. } => (
                    d,
                    if dep[a as usize].timed() {
                        dep[a as usize]
                    } else {
                        Dep::Bad
                    },
                ),
                Instr::Device { d, f, a } => match dep[a as usize] {
                    x if x.timed() => (d, x),
                    Dep::Volt(diode)
                        if diode == f.diode
                            && f.part == crate::ir::DiodePart::Current
                            && f.order == 0 =>
                    {
                        (d, Dep::IdPos(diode))
                    }
                    _ => (d, Dep::Bad),
                },
                Instr::Src { d, .. } | Instr::Time { d } => (d, Dep::Time),
                Instr::Block { k } => {
                    self.classify_block(&self.blocks[k as usize], dep);
                    continue;
                }
            };
            dep[d as usize] = v;
        }
    }

    fn classify_block(&self, b: &TapeBlock, dep: &mut [Dep]) {
        if let Some(ci) = b.charge_inverse {
            let v = match dep[ci.target as usize] {
                Dep::Charge(diode) if diode == ci.diode => Dep::Volt(diode),
                x if x.timed() => x,
                _ => Dep::Bad,
            };
            // What the body computes besides the voltage is `Q(v)`: nothing
            // the analysis can follow if `f` reads it.
            self.classify_tears(b, dep, Dep::Bad);
            for &x in &b.tears {
                dep[x as usize] = v;
            }
            return;
        }
        // Independent of the states; else affine with constant coefficients.
        let linear = |dep: &[Dep]| {
            b.residuals.iter().all(|&r| {
                matches!(
                    dep[r as usize],
                    Dep::Const | Dep::Time | Dep::Lin | Dep::Volt(_)
                )
            })
        };
        self.classify_tears(b, dep, Dep::Time);
        if b.residuals.iter().all(|&r| dep[r as usize].timed()) {
            return;
        }
        if b.constant_jacobian {
            self.classify_tears(b, dep, Dep::Lin);
            if linear(dep) {
                return;
            }
        }
        self.classify_tears(b, dep, Dep::Bad);
    }

    /// Classify `b`'s body with its tears taken as `tear`.
    fn classify_tears(&self, b: &TapeBlock, dep: &mut [Dep], tear: Dep) {
        for &x in &b.tears {
            dep[x as usize] = tear;
        }
        self.classify(&b.body, dep);
    }

    /// The first register of `code` that became NaN or infinite from finite
    /// operands, and the variable it holds (if any).
    pub fn first_non_finite(&self, regs: &[f64]) -> Option<(usize, Option<VarId>)> {
        for ins in self
            .code
            .iter()
            .chain(self.blocks.iter().flat_map(|b| b.body.iter()))
        {
            let d = dest(ins);
            if d == NONE || regs[d as usize].is_finite() {
                continue;
            }
            let inputs_finite = sources_of(ins, &self.blocks)
                .iter()
                .all(|&s| regs[s as usize].is_finite());
            if inputs_finite {
                return Some((d as usize, self.reg_var[d as usize]));
            }
        }
        None
    }

    /// The sparsity of `∂f/∂y`: for each derivative, the states it depends on.
    pub fn jacobian_pattern(&self) -> Vec<(usize, usize)> {
        // Dependencies propagate through the program as sorted state lists.
        let mut deps: Vec<Vec<u32>> = vec![Vec::new(); self.n_regs];
        for (k, &s) in self.state_regs.iter().enumerate() {
            deps[s as usize] = vec![k as u32];
        }
        fn merge(into: &mut Vec<u32>, from: &[u32]) {
            if from.is_empty() {
                return;
            }
            let mut m = Vec::with_capacity(into.len() + from.len());
            let (mut i, mut j) = (0, 0);
            while i < into.len() || j < from.len() {
                let next = match (into.get(i), from.get(j)) {
                    (Some(&a), Some(&b)) if a == b => {
                        i += 1;
                        j += 1;
                        a
                    }
                    (Some(&a), Some(&b)) if a < b => {
                        i += 1;
                        a
                    }
                    (Some(_), Some(&b)) | (None, Some(&b)) => {
                        j += 1;
                        b
                    }
                    (Some(&a), None) => {
                        i += 1;
                        a
                    }
                    (None, None) => unreachable!(),
                };
                m.push(next);
            }
            *into = m;
        }
        fn walk(tape: &Tape, code: &[Instr], deps: &mut Vec<Vec<u32>>) {
            for ins in code {
                if let Instr::Block { k } = ins {
                    let b = &tape.blocks[*k as usize];
                    // Everything in a block depends on everything it reads.
                    let mut all = Vec::new();
                    for i in &b.body {
                        for s in sources_of(i, &tape.blocks) {
                            let from = std::mem::take(&mut deps[s as usize]);
                            merge(&mut all, &from);
                            deps[s as usize] = from;
                        }
                    }
                    for i in &b.body {
                        let d = dest(i);
                        if d != NONE {
                            deps[d as usize] = all.clone();
                        }
                    }
                    for &x in &b.tears {
                        deps[x as usize] = all.clone();
                    }
                    // Second pass: body values depend on the tears' dependencies.
                    walk(tape, &b.body, deps);
                    for i in &b.body {
                        let d = dest(i);
                        if d != NONE {
                            let mut v = std::mem::take(&mut deps[d as usize]);
                            merge(&mut v, &all);
                            deps[d as usize] = v;
                        }
                    }
                    continue;
                }
                let d = dest(ins);
                let mut acc = Vec::new();
                for s in sources_of(ins, &tape.blocks) {
                    merge(&mut acc, &deps[s as usize]);
                }
                deps[d as usize] = acc;
            }
        }
        walk(self, &self.code, &mut deps);
        let mut out = Vec::new();
        for (i, &d) in self.deriv_regs.iter().enumerate() {
            for &j in &deps[d as usize] {
                out.push((i, j as usize));
            }
        }
        out
    }
}

/// Mark the blocks whose body values (other than the tears) are read only
/// inside the body itself.
fn set_private(blocks: &mut [TapeBlock], programs: &[&[Instr]], direct: &[&[u32]]) {
    // Who reads each register: `None` for top-level code, `Some(k)` for the
    // body of block k, and a conflict (read by two) as top level.
    let mut reader: HashMap<u32, Option<usize>> = HashMap::new();
    let mut note = |r: u32, by: Option<usize>| {
        reader
            .entry(r)
            .and_modify(|old| {
                if *old != by {
                    *old = None;
                }
            })
            .or_insert(by);
    };
    for code in programs {
        for ins in code.iter() {
            for r in sources_of(ins, &[]) {
                note(r, None);
            }
        }
    }
    for regs in direct {
        for &r in regs.iter() {
            note(r, None);
        }
    }
    for (k, b) in blocks.iter().enumerate() {
        for ins in &b.body {
            for r in sources_of(ins, &[]) {
                note(r, Some(k));
            }
        }
    }
    for (k, b) in blocks.iter_mut().enumerate() {
        // A set: a block can have 10^4 tears and 10^5 instructions.
        let tears: std::collections::HashSet<u32> = b.tears.iter().copied().collect();
        b.private = b.body.iter().all(|ins| {
            let d = dest(ins);
            d == NONE || reader.get(&d).is_none_or(|by| *by == Some(k)) || tears.contains(&d)
        });
    }
}

/// `Some` when the block is exactly `r = s - Q(x)` (or `Q(x) - s`) for the
/// charge `Q` of a diode, its one tear `x` and a register `s` it does not write.
fn charge_inverse(b: &TapeBlock) -> Option<ChargeInverse> {
    let (&[x], &[res]) = (b.tears.as_slice(), b.residuals.as_slice()) else {
        return None;
    };
    let [Instr::Device { d: q, f, a }, Instr::Sub { d, a: l, b: r }] = b.body[..] else {
        return None;
    };
    let charge = f.part == crate::ir::DiodePart::Charge && f.order == 0;
    let target = match (l == q, r == q) {
        (false, true) => l,
        (true, false) => r,
        _ => return None,
    };
    (charge && a == x && d == res && target != x && target != q).then_some(ChargeInverse {
        diode: f.diode,
        target,
        memo: NONE,
    })
}

/// Mark the blocks whose Jacobian is constant: every path from a tear to a
/// residual goes through negations, sums and products (or quotients) with
/// registers no code writes (constants and parameters).
fn set_constant_jacobians(blocks: &mut [TapeBlock], programs: &[&[Instr]], states: &[u32]) {
    let mut written: std::collections::HashSet<u32> = states.iter().copied().collect();
    for ins in programs
        .iter()
        .flat_map(|c| c.iter())
        .chain(blocks.iter().flat_map(|b| b.body.iter()))
    {
        written.insert(dest(ins));
    }
    written.extend(blocks.iter().flat_map(|b| b.tears.iter().copied()));
    for b in blocks.iter_mut() {
        let mut varies: std::collections::HashSet<u32> = b.tears.iter().copied().collect();
        let mut constant = !b.tears.is_empty();
        for ins in &b.body {
            let v = |x: u32| varies.contains(&x);
            let coefficient = |x: u32| !written.contains(&x);
            // Whether the result moves with the tears, and whether its
            // derivative with respect to them is still a constant.
            let (moves, stays_affine) = match *ins {
                Instr::Neg { a, .. } => (v(a), true),
                Instr::Add { a, b, .. } | Instr::Sub { a, b, .. } => (v(a) || v(b), true),
                Instr::Mul { a, b, .. } => match (v(a), v(b)) {
                    (true, true) => (true, false),
                    (true, false) => (true, coefficient(b)),
                    (false, true) => (true, coefficient(a)),
                    (false, false) => (false, true),
                },
                Instr::Div { a, b, .. } => (v(a) || v(b), !v(b) && (!v(a) || coefficient(b))),
                Instr::Pow { a, b, .. } => (v(a) || v(b), !(v(a) || v(b))),
                Instr::Call { a, .. } | Instr::Device { a, .. } => (v(a), !v(a)),
                Instr::Src { .. } | Instr::Time { .. } => (false, true),
                Instr::Block { .. } => (true, false),
            };
            if !stays_affine {
                constant = false;
                break;
            }
            if moves {
                varies.insert(dest(ins));
            }
        }
        b.constant_jacobian = constant;
    }
}

/// Tears `x` of a block whose body computes `exp(x / vt)`.
fn junctions(b: &TapeBlock, vte_regs: &dyn Fn(u32) -> Option<u32>) -> Vec<(usize, u32)> {
    let mut out = Vec::new();
    // Maps, not scans: a block can hold 10^4 tears and junctions.
    let tear_index: HashMap<u32, usize> =
        b.tears.iter().enumerate().map(|(j, &x)| (x, j)).collect();
    let mut by_dest: HashMap<u32, &Instr> = HashMap::new();
    for i in &b.body {
        by_dest.entry(dest(i)).or_insert(i);
    }
    let mut found = std::collections::HashSet::new();
    for ins in &b.body {
        if let Instr::Device { f, a, .. } = *ins
            && let Some(&j) = tear_index.get(&a)
            && let Some(vt) = vte_regs(f.diode)
            && found.insert(j)
        {
            out.push((j, vt));
        }
        let Instr::Call {
            f: Func::Exp, a, ..
        } = *ins
        else {
            continue;
        };
        let Some(&&Instr::Div { a: num, b: den, .. }) = by_dest.get(&a) else {
            continue;
        };
        if let Some(&j) = tear_index.get(&num)
            && found.insert(j)
        {
            out.push((j, den));
        }
    }
    out
}

/// [`crate::ir::pnjlim`] where the saturation current is not known (tears
/// inside an `exp()`): the critical voltage taken as 12 thermal voltages.
fn pnjlim(new: f64, old: f64, vt: f64) -> f64 {
    crate::ir::pnjlim(new, old, vt, 12.0 * vt)
}

/// How a register depends on the states (see
/// [`Tape::jacobian_follows_junctions`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Dep {
    /// A parameter or constant.
    Const,
    /// A function of time alone.
    Time,
    /// Affine in the states, constant coefficients.
    Lin,
    /// The charge state of a diode's junction.
    Charge(u32),
    /// That junction's voltage `Q⁻¹(q)`.
    Volt(u32),
    /// Affine plus (`IdPos`) or minus (`IdNeg`) that junction's current.
    IdPos(u32),
    IdNeg(u32),
    /// Anything else that depends on the states.
    Bad,
}

impl Dep {
    fn timed(self) -> bool {
        matches!(self, Dep::Const | Dep::Time)
    }

    fn max_timed(self, other: Dep) -> Dep {
        if self == Dep::Const && other == Dep::Const {
            Dep::Const
        } else {
            Dep::Time
        }
    }

    /// As a term that enters affinely (a junction voltage becomes affine).
    fn affine(self) -> Dep {
        match self {
            Dep::Volt(_) => Dep::Lin,
            x => x,
        }
    }

    fn negate(self) -> Dep {
        match self {
            Dep::IdPos(d) => Dep::IdNeg(d),
            Dep::IdNeg(d) => Dep::IdPos(d),
            Dep::Charge(_) => Dep::Bad,
            x => x.affine(),
        }
    }

    fn sum(a: Dep, b: Dep) -> Dep {
        match (a.affine(), b.affine()) {
            (Dep::Bad | Dep::Charge(_), _) | (_, Dep::Bad | Dep::Charge(_)) => Dep::Bad,
            (x, y) if x.timed() && y.timed() => x.max_timed(y),
            (Dep::IdPos(_) | Dep::IdNeg(_), Dep::IdPos(_) | Dep::IdNeg(_)) => Dep::Bad,
            (id @ (Dep::IdPos(_) | Dep::IdNeg(_)), _)
            | (_, id @ (Dep::IdPos(_) | Dep::IdNeg(_))) => id,
            _ => Dep::Lin,
        }
    }

    /// A product: a state-dependent factor times a constant (a junction
    /// current only with its coefficient, `±1`, unchanged: never here).
    fn product(a: Dep, b: Dep) -> Dep {
        match (a, b) {
            (x, y) if x.timed() && y.timed() => x.max_timed(y),
            (Dep::Const, x) | (x, Dep::Const) => match x.affine() {
                Dep::Lin => Dep::Lin,
                _ => Dep::Bad,
            },
            _ => Dep::Bad,
        }
    }
}

/// The inversion memos of the junction charges that both `code` and
/// `out_code` invert (see [`Tape::memo_links`]).
fn memo_links(blocks: &[TapeBlock], code: &[Instr], out_code: &[Instr]) -> Vec<(u32, u32)> {
    let inversions = |code: &[Instr]| -> Vec<ChargeInverse> {
        code.iter()
            .filter_map(|i| match *i {
                Instr::Block { k } => blocks[k as usize].charge_inverse,
                _ => None,
            })
            .collect()
    };
    let in_f = inversions(code);
    inversions(out_code)
        .into_iter()
        .filter_map(|o| {
            let f = in_f
                .iter()
                .find(|f| f.target == o.target && f.diode == o.diode)?;
            (f.memo != o.memo).then_some((f.memo, o.memo))
        })
        .collect()
}

fn dest(ins: &Instr) -> u32 {
    match *ins {
        Instr::Neg { d, .. }
        | Instr::Add { d, .. }
        | Instr::Sub { d, .. }
        | Instr::Mul { d, .. }
        | Instr::Div { d, .. }
        | Instr::Pow { d, .. }
        | Instr::Call { d, .. }
        | Instr::Device { d, .. }
        | Instr::Src { d, .. }
        | Instr::Time { d } => d,
        Instr::Block { .. } => NONE,
    }
}

fn sources_of(ins: &Instr, _blocks: &[TapeBlock]) -> Vec<u32> {
    match *ins {
        Instr::Neg { a, .. } | Instr::Call { a, .. } | Instr::Device { a, .. } => vec![a],
        Instr::Add { a, b, .. }
        | Instr::Sub { a, b, .. }
        | Instr::Mul { a, b, .. }
        | Instr::Div { a, b, .. }
        | Instr::Pow { a, b, .. } => {
            vec![a, b]
        }
        _ => Vec::new(),
    }
}

/// Buffers of one Newton solve, pooled per thread so that evaluating `f`
/// allocates nothing once warm (blocks can nest, so it is a pool).
#[derive(Default)]
struct Work {
    jac: Vec<f64>,
    perm: Vec<usize>,
    step: Vec<f64>,
    x0: Vec<f64>,
    bar: Vec<f64>,
    tmp: Vec<f64>,
    /// The tears on entry (empty until filled).
    start: Vec<f64>,
    /// Saved tangents (empty until filled).
    saved: Vec<f64>,
    /// Residual right-hand side (empty until filled).
    res: Vec<f64>,
    /// Register-sized tangents.
    dr: Vec<f64>,
}

thread_local! {
    // Boxed so that taking and giving back moves a pointer, not ten vectors.
    #[allow(clippy::vec_box)]
    static WORK: std::cell::RefCell<Vec<Box<Work>>> = const { std::cell::RefCell::new(Vec::new()) };
}

impl Work {
    /// Buffers for an `n`-tear block and `regs` tangent registers.
    fn take(n: usize, regs: usize) -> Box<Work> {
        let mut w = WORK.with(|p| p.borrow_mut().pop()).unwrap_or_default();
        for v in [&mut w.step, &mut w.x0, &mut w.bar, &mut w.tmp] {
            v.clear();
            v.resize(n, 0.0);
        }
        w.perm.clear();
        w.perm.resize(n, 0);
        w.start.clear();
        w.saved.clear();
        w.res.clear();
        if w.dr.len() < regs {
            w.dr.resize(regs, 0.0);
        }
        w
    }

    /// The dense `n`×`n` Jacobian buffer, zeroed (only blocks that factor
    /// a Jacobian per call pay for it: a constant one is factored once).
    fn dense_jac(&mut self, n: usize) -> &mut Vec<f64> {
        self.jac.clear();
        self.jac.resize(n * n, 0.0);
        &mut self.jac
    }

    fn give(self: Box<Work>) {
        WORK.with(|p| p.borrow_mut().push(self));
    }
}

/// Which tears each residual of `b` depends on (sorted), followed through
/// the body as sets per register; `None` when a set grows past
/// [`PATTERN_MAX`] (dense enough for one column per run) or the body holds a
/// nested block.
fn tear_pattern(b: &TapeBlock) -> Option<Vec<Vec<u32>>> {
    let mut deps: HashMap<u32, Vec<u32>> = HashMap::new();
    for (j, &x) in b.tears.iter().enumerate() {
        deps.insert(x, vec![j as u32]);
    }
    for ins in &b.body {
        if matches!(ins, Instr::Block { .. }) {
            return None;
        }
        let mut set: Vec<u32> = Vec::new();
        for a in sources_of(ins, &[]) {
            if let Some(s) = deps.get(&a) {
                set.extend_from_slice(s);
            }
        }
        set.sort_unstable();
        set.dedup();
        if set.len() > PATTERN_MAX {
            return None;
        }
        let d = dest(ins);
        if set.is_empty() {
            deps.remove(&d);
        } else {
            deps.insert(d, set);
        }
    }
    Some(
        b.residuals
            .iter()
            .map(|r| deps.get(r).cloned().unwrap_or_default())
            .collect(),
    )
}

/// Dependency sets larger than this make [`tear_pattern`] give up.
const PATTERN_MAX: usize = 64;

/// Blocks with more tears than this factor a constant Jacobian as sparse.
const DENSE_TEARS: usize = 48;

/// Which tears each residual of a block depends on ([`tear_pattern`]) and
/// a colouring of the tears in which no residual sees two of one colour
/// (each tear's colour, and the tears of each colour).
#[derive(Clone, Debug)]
struct Pattern {
    rows: Vec<Vec<u32>>,
    colour: Vec<u32>,
    members: Vec<Vec<u32>>,
}

/// Solve with a sparse factorization when there is one, else with the
/// dense factors of [`lu_factor`] in the block's work buffers.
fn solve_factored(
    sparse: Option<&TripletLu>,
    jac: &[f64],
    perm: &[usize],
    b: &mut [f64],
    tmp: &mut [f64],
) {
    match sparse {
        Some(lu) => lu.solve_in_place(b, tmp),
        None => lu_solve(perm.len(), jac, perm, b, tmp),
    }
}
