//! Compiling a [`Schedule`] into a [`Tape`]: registers for variables,
//! parameters and constants, instructions in the schedule's order, blocks
//! for algebraic loops, and the outputs' own program.

use std::collections::HashMap;

use super::*;

pub(super) struct Compiler<'a> {
    sys: &'a EquationSystem,
    n_regs: u32,
    init: Vec<f64>,
    /// The register of each expression emitted so far, by expression
    /// index ([`NONE`]: not yet).
    memo: Vec<Reg>,
    var_reg: Vec<Reg>,
    param_reg: Vec<Reg>,
    /// Constant registers (constants, parameters, reciprocals) by value.
    consts: HashMap<u64, Reg>,
    reg_var: Vec<Option<VarId>>,
    blocks: Vec<TapeBlock>,
    /// The comparisons written in B sources (index in the system's
    /// `events`), and the mode each got in `code`: the output program's copy
    /// of a comparison reads the same mode; one that `code` never evaluates
    /// changes no state and gets none.
    events: HashMap<ExprId, usize>,
    mode_of: HashMap<ExprId, u32>,
    modes: Vec<HeldCmp>,
    /// Whether `code` (not the output program) is being compiled.
    in_code: bool,
    /// Scratch of [`Compiler::hoist`], by register: moves with the tears.
    /// All false between calls.
    variant: Vec<bool>,
}

impl Compiler<'_> {
    fn reg(&mut self, value: f64) -> Reg {
        let r = Reg(self.n_regs);
        self.n_regs += 1;
        self.init.push(value);
        self.reg_var.push(None);
        r
    }

    /// The register of output `o`, its code appended to `out`.
    fn output(&mut self, o: OutputRef, out: &mut Vec<Instr>) -> Reg {
        match o {
            OutputRef::Expr(e) => self.emit(e, out),
            OutputRef::Diff(a, b) => {
                let (ra, rb) = (self.emit(a, out), self.emit(b, out));
                let d = self.reg(0.0);
                out.push(Instr::Sub { d, a: ra, b: rb });
                d
            }
            OutputRef::Var(v) => self.var(v, out),
        }
    }

    /// A program of the steps of `sched` that `steps` flags, then
    /// `outputs`, and the outputs' registers.
    fn outputs(
        &mut self,
        sched: &Schedule,
        steps: &[bool],
        outputs: &[OutputRef],
    ) -> (Vec<Instr>, Vec<Reg>) {
        let mut code = Vec::new();
        for (step, _) in sched.steps.iter().zip(steps).filter(|(_, f)| **f) {
            self.step(step, &mut code);
        }
        let regs = outputs.iter().map(|&o| self.output(o, &mut code)).collect();
        (code, regs)
    }

    /// Mark the junction-charge blocks, each with its four memo registers.
    fn set_charge_inverses(&mut self) {
        for k in 0..self.blocks.len() {
            self.blocks[k].charge_inverse = charge_inverse(&self.blocks[k]).map(|ci| {
                let memo = self.reg(f64::NAN);
                for _ in 1..4 {
                    self.reg(f64::NAN);
                }
                ChargeInverse { memo, ..ci }
            });
        }
    }

    /// A register of its own for variable `v`, holding its value (a state,
    /// a tear).
    fn var_reg_new(&mut self, v: VarId) -> Reg {
        let r = self.reg(0.0);
        self.var_reg[v.0 as usize] = r;
        self.reg_var[r] = Some(v);
        r
    }

    /// The register of a constant value, one per distinct value: a ladder
    /// of 10^5 equal resistors reads one `1/R`, which stays in cache.
    fn const_reg(&mut self, v: f64) -> Reg {
        if let Some(&r) = self.consts.get(&v.to_bits()) {
            return r;
        }
        let r = self.reg(v);
        self.consts.insert(v.to_bits(), r);
        r
    }

    /// The value of a constant or parameter expression (not of a
    /// parameter the simulator sets).
    fn constant(&self, e: ExprId) -> Option<f64> {
        match self.sys.exprs.get(e) {
            Expr::Const(b) => Some(f64::from_bits(b)),
            // Sources' and switches' values change at run time.
            Expr::Param(p) => {
                let p = &self.sys.params[p];
                (!p.source && !p.switch && !p.floor).then_some(p.value)
            }
            _ => None,
        }
    }

    /// The register of `e`, its code appended to `out` (each node once).
    fn emit(&mut self, e: ExprId, out: &mut Vec<Instr>) -> Reg {
        self.emit_at(e, out, 0)
    }

    /// Whether `e` already has its register.
    fn emitted(&self, e: ExprId) -> bool {
        self.memo[e.0 as usize] != NONE
            || match self.sys.exprs.get(e) {
                Expr::Var(v) => self.var_reg[v.0 as usize] != NONE,
                Expr::Param(p) => self.param_reg[p.0 as usize] != NONE,
                _ => false,
            }
    }

    /// [`Compiler::emit`] at recursion depth `depth`. Past 128 levels (the
    /// loop formulation's node potentials are tree-path sums 10^5 deep,
    /// which would overflow the stack) the operands are emitted bottom-up with
    /// an explicit stack, each then found memoized.
    fn emit_at(&mut self, e: ExprId, out: &mut Vec<Instr>, depth: usize) -> Reg {
        let r = self.memo[e.0 as usize];
        if r != NONE {
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
                let x = &self.sys.exprs;
                let children = match x.get(n) {
                    Expr::Var(v) if self.var_reg[v.0 as usize] == NONE => {
                        [self.sys.vars[v].alias, None, None]
                    }
                    Expr::Var(_)
                    | Expr::Const(_)
                    | Expr::Param(_)
                    | Expr::Time
                    | Expr::TimeRate
                    | Expr::Source(..) => [None, None, None],
                    op => op.operands(),
                };
                stack.extend(children.into_iter().rev().flatten().map(|c| (c, false)));
            }
        }
        let depth = depth + 1;
        let x = &self.sys.exprs;
        let r = match x.get(e) {
            Expr::Const(b) => {
                let r = self.const_reg(f64::from_bits(b));
                self.memo[e.0 as usize] = r;
                return r;
            }
            Expr::Param(p) => {
                let k = p.0 as usize;
                if self.param_reg[k] == NONE {
                    let param = &self.sys.params[p];
                    // A source's value gets a register of its own (source
                    // stepping scales it), as do a switch's conductance and
                    // the floor factor; other parameters share constants.
                    self.param_reg[k] = if param.source || param.switch || param.floor {
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
            Expr::TimeRate => {
                let d = self.reg(1.0);
                out.push(Instr::TimeRate { d });
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
            Expr::Select(c, a, b) => {
                let rc = self.emit_at(c, out, depth);
                let (ra, rb) = (self.emit_at(a, out, depth), self.emit_at(b, out, depth));
                let d = self.reg(0.0);
                out.push(Instr::Select {
                    d,
                    c: rc,
                    a: ra,
                    b: rb,
                });
                d
            }
            Expr::Add(a, b)
            | Expr::Sub(a, b)
            | Expr::Mul(a, b)
            | Expr::Div(a, b)
            | Expr::Pow(a, b)
            | Expr::Cmp(_, a, b) => {
                let (ra, rb) = (self.emit_at(a, out, depth), self.emit_at(b, out, depth));
                let d = self.reg(0.0);
                out.push(match x.get(e) {
                    Expr::Add(..) => Instr::Add { d, a: ra, b: rb },
                    Expr::Sub(..) => Instr::Sub { d, a: ra, b: rb },
                    Expr::Mul(..) => Instr::Mul { d, a: ra, b: rb },
                    Expr::Div(..) => Instr::Div { d, a: ra, b: rb },
                    Expr::Cmp(op, ..) => Instr::Cmp {
                        d,
                        op,
                        a: ra,
                        b: rb,
                        m: self.mode(e, op),
                    },
                    _ => Instr::Pow { d, a: ra, b: rb },
                });
                d
            }
        };
        self.memo[e.0 as usize] = r;
        r
    }

    /// The held mode of comparison `e` (see [`HeldCmp`]), or [`NO_MODE`].
    fn mode(&mut self, e: ExprId, op: crate::ir::Cmp) -> u32 {
        if let Some(&m) = self.mode_of.get(&e) {
            return m;
        }
        let Some(&k) = self.events.get(&e).filter(|_| self.in_code) else {
            return NO_MODE;
        };
        let m = self.modes.len() as u32;
        self.modes.push(HeldCmp {
            op,
            element: self.sys.events[k].1.to_string(),
            text: crate::ir::print::expr(self.sys, e),
            held: std::cell::Cell::new(f64::NAN),
            control: std::cell::Cell::new(f64::NAN),
        });
        self.mode_of.insert(e, m);
        m
    }

    /// Find a block's junction tears; diode thermal voltages get registers.
    /// A nested block (compiled before its enclosing one) contributes its
    /// own registers: a Jacobian column must clear those tangents too.
    fn set_touched(&mut self, k: usize) {
        let mut touched: Vec<Reg> = Vec::new();
        for ins in &self.blocks[k].body {
            match *ins {
                Instr::Block { k: inner } => {
                    touched.extend_from_slice(&self.blocks[inner as usize].touched)
                }
                _ => touched.extend(ins.operands().into_iter().chain([ins.dest()])),
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
                let p = &self.sys.diodes[d as usize];
                let (vte, bv) = (p.vte, p.bv.unwrap_or(f64::INFINITY));
                e.insert((self.reg(vte), bv));
            }
        }
        let j = junctions(&self.blocks[k], &|d| regs.get(&d).copied());
        self.blocks[k].junctions = j;
    }

    /// The register of variable `v` (an alias is emitted on first use).
    fn var(&mut self, v: VarId, out: &mut Vec<Instr>) -> Reg {
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

    /// Move the instructions of a block's `body` that do not depend on its
    /// tears to `out`, ahead of the block, keeping their order: they are
    /// evaluated once per run of the program, not in every Newton iteration
    /// and every Jacobian column (a MOSFET's junction currents and charges
    /// and its Meyer capacitances depend on the states alone, where the loop
    /// of its gate capacitances is torn). A nested block stays, with
    /// everything that reads what it writes.
    fn hoist(&mut self, tears: &[Reg], body: Vec<Instr>, out: &mut Vec<Instr>) -> Vec<Instr> {
        if self.variant.len() < self.n_regs as usize {
            self.variant.resize(self.n_regs as usize, false);
        }
        let set = |variant: &mut Vec<bool>, x: Reg, marked: &mut Vec<Reg>| {
            if x != NONE && !variant[x.idx()] {
                variant[x.idx()] = true;
                marked.push(x);
            }
        };
        let mut marked = Vec::new();
        for &x in tears {
            set(&mut self.variant, x, &mut marked);
        }
        let mut kept = Vec::with_capacity(body.len());
        for ins in body {
            let moves = match ins {
                Instr::Block { k } => {
                    for &x in &self.blocks[k as usize].touched {
                        set(&mut self.variant, x, &mut marked);
                    }
                    true
                }
                _ => ins.operands().into_iter().any(|x| self.variant[x.idx()]),
            };
            if moves {
                set(&mut self.variant, ins.dest(), &mut marked);
                kept.push(ins);
            } else {
                out.push(ins);
            }
        }
        for x in marked {
            self.variant[x.idx()] = false;
        }
        kept
    }

    /// Add a block of `body` solving `residuals` for `tears`, with its
    /// junction tears and touched registers, and its solve to `out`, its
    /// instructions that do not depend on the tears ahead of it; the block,
    /// for the caller to set its tear's floor.
    fn push_block(
        &mut self,
        index: usize,
        (tears, residuals): (Vec<Reg>, Vec<Reg>),
        body: Vec<Instr>,
        linear: bool,
        elements: Vec<String>,
        out: &mut Vec<Instr>,
    ) -> &mut TapeBlock {
        let body = self.hoist(&tears, body, out);
        let k = self.blocks.len();
        self.blocks.push(TapeBlock::new(
            index,
            (tears, residuals),
            body,
            linear,
            elements,
        ));
        self.set_junctions(k);
        self.set_touched(k);
        out.push(Instr::Block { k: k as u32 });
        &mut self.blocks[k]
    }

    fn assign(&mut self, a: &Assignment, out: &mut Vec<Instr>) {
        match a.solved {
            Solved::Explicit(e) => {
                let r = self.emit(e, out);
                self.var_reg[a.var.0 as usize] = r;
                if self.reg_var[r].is_none() {
                    self.reg_var[r] = Some(a.var);
                }
            }
            Solved::Implicit(f) => {
                // A one-equation block: guess the unknown, zero the residual.
                let t = self.reg(0.0);
                self.var_reg[a.var.0 as usize] = t;
                self.reg_var[t] = Some(a.var);
                let mut body = Vec::new();
                let r = self.emit(f, &mut body);
                let elements = self.sys.eqs[a.eq]
                    .origin
                    .elements()
                    .into_iter()
                    .map(String::from)
                    .collect();
                let floor = super::tear_floor(self.sys.vars[a.var].kind);
                self.push_block(0, (vec![t], vec![r]), body, false, elements, out)
                    .floor = floor;
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
                let tears: Vec<Reg> = unknowns.iter().map(|&v| self.var_reg_new(v)).collect();
                let floor = match unknowns[..] {
                    [v] => super::tear_floor(self.sys.vars[v].kind),
                    _ => 1.0,
                };
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
                self.push_block(
                    b.index,
                    (tears, residuals),
                    body,
                    b.linear,
                    b.elements.clone(),
                    out,
                )
                .floor = floor;
            }
        }
    }
}

/// The registers `programs` (with the bodies of the blocks they solve, and
/// theirs) read but never write; a block's tears count as written.
fn tangent_inputs(programs: &[&[Instr]], blocks: &[TapeBlock], n_regs: usize) -> Vec<Reg> {
    let mut written = vec![false; n_regs];
    let mut read = vec![false; n_regs];
    let mut stack: Vec<&[Instr]> = programs.to_vec();
    while let Some(prog) = stack.pop() {
        for ins in prog {
            if let Instr::Block { k } = *ins {
                let b = &blocks[k as usize];
                for &x in &b.tears {
                    written[x.idx()] = true;
                }
                stack.push(&b.body);
                continue;
            }
            for x in ins.operands() {
                read[x.idx()] = true;
            }
            written[ins.dest().idx()] = true;
        }
    }
    (0..n_regs)
        .filter(|&x| read[x] && !written[x])
        .map(|x| Reg(x as u32))
        .collect()
}

/// The variables each step computes and the ones it reads, flat (a
/// ladder of 10^5 sections has half a million steps: two vectors each would
/// be a million allocations).
struct StepVars {
    writes: Vec<VarId>,
    reads: Vec<VarId>,
    /// Step `k` writes `writes[w[k]..w[k + 1]]` and reads `reads[r[k]..r[k + 1]]`.
    w: Vec<usize>,
    r: Vec<usize>,
}

impl StepVars {
    fn of(sys: &EquationSystem, steps: &[Step]) -> StepVars {
        let mut sv = StepVars {
            writes: Vec::with_capacity(steps.len()),
            reads: Vec::with_capacity(2 * steps.len()),
            w: Vec::with_capacity(steps.len() + 1),
            r: Vec::with_capacity(steps.len() + 1),
        };
        sv.w.push(0);
        sv.r.push(0);
        let (mut vars, mut stack) = (Vec::new(), Vec::new());
        for step in steps {
            let assigns: &mut dyn Iterator<Item = &Assignment> = match step {
                Step::Assign(a) => &mut std::iter::once(a),
                Step::Block(b) => &mut b.inner.iter().chain(&b.residuals),
            };
            let w0 = sv.writes.len();
            let r0 = sv.reads.len();
            for a in assigns {
                sv.writes.push(a.var);
                sys.eq_vars(a.eq, &mut vars, &mut stack);
                sv.reads.extend_from_slice(&vars);
            }
            // What the step writes itself is not a read. A block can write
            // 10^5 variables: look them up in a set, not a scan; a step of a
            // few (nearly every one) scans.
            let writes = &sv.writes[w0..];
            let set: Option<std::collections::HashSet<VarId>> =
                (writes.len() > 16).then(|| writes.iter().copied().collect());
            let mut k = r0;
            for i in r0..sv.reads.len() {
                let v = sv.reads[i];
                if !set
                    .as_ref()
                    .map_or_else(|| writes.contains(&v), |s| s.contains(&v))
                {
                    sv.reads[k] = v;
                    k += 1;
                }
            }
            sv.reads.truncate(k);
            sv.w.push(sv.writes.len());
            sv.r.push(sv.reads.len());
        }
        sv
    }

    /// Which steps compute something `needed` marks, walking the schedule
    /// backwards; what those steps read is marked needed on the way.
    fn needed(&self, needed: &mut [bool]) -> Vec<bool> {
        let n = self.w.len() - 1;
        let mut steps = vec![false; n];
        for k in (0..n).rev() {
            let writes = &self.writes[self.w[k]..self.w[k + 1]];
            if writes.iter().any(|w| needed[w.0 as usize]) {
                steps[k] = true;
                for r in &self.reads[self.r[k]..self.r[k + 1]] {
                    needed[r.0 as usize] = true;
                }
            }
        }
        steps
    }
}

/// The variables the outputs read: one pass over their expression DAG,
/// through aliases (the loop formulation's node potentials share their tree
/// paths, so a pass per output would be quadratic).
fn output_vars(sys: &EquationSystem, outputs: &[OutputRef]) -> Vec<bool> {
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
    out_needed
}

/// `tail` behind the bodies of the private blocks of `code` whose values it
/// reads: a private block's solve leaves its body at the last trial point
/// (nothing in `f` reads it), so the tail brings each up to date first, in
/// `code`'s order, as a block's settling would.
fn settled_tail(
    blocks: &[TapeBlock],
    code: &[Instr],
    tail: Vec<Instr>,
    regs: &[Reg],
) -> Vec<Instr> {
    let mut read: std::collections::HashSet<Reg> = regs.iter().copied().collect();
    let mut stack: Vec<&[Instr]> = vec![&tail];
    while let Some(prog) = stack.pop() {
        for ins in prog {
            match *ins {
                Instr::Block { k } => stack.push(&blocks[k as usize].body),
                _ => read.extend(ins.operands()),
            }
        }
    }
    let mut settled = Vec::new();
    for ins in code {
        if let Instr::Block { k } = *ins {
            let b = &blocks[k as usize];
            if b.private && b.body.iter().any(|i| read.contains(&i.dest())) {
                settled.extend_from_slice(&b.body);
            }
        }
    }
    settled.extend(tail);
    settled
}

/// The states the output program reads, as `(index in y, register)`.
fn states_read(
    blocks: &[TapeBlock],
    out_code: &[Instr],
    out_regs: &[Reg],
    state_regs: &[Reg],
) -> Vec<(usize, Reg)> {
    let read: std::collections::HashSet<Reg> = out_code
        .iter()
        .flat_map(|i| match i {
            Instr::Block { k } => blocks[*k as usize]
                .body
                .iter()
                .flat_map(|b| b.operands())
                .collect::<Vec<_>>(),
            other => other.operands().into_iter().collect(),
        })
        .chain(out_regs.iter().copied())
        .collect();
    state_regs
        .iter()
        .enumerate()
        .filter(|(_, r)| read.contains(r))
        .map(|(k, &r)| (k, r))
        .collect()
}

/// Compile `sched` of `sys`. `outputs` are evaluated at output points only.
pub fn compile(sys: &EquationSystem, sched: &Schedule, outputs: &[OutputRef]) -> Tape {
    let states: Vec<VarId> = sys.states().collect();
    let mut c = Compiler {
        sys,
        n_regs: 0,
        init: Vec::new(),
        memo: vec![NONE; sys.exprs.len()],
        var_reg: vec![NONE; sys.vars.len()],
        param_reg: vec![NONE; sys.params.len()],
        consts: HashMap::new(),
        reg_var: Vec::new(),
        blocks: Vec::new(),
        events: sys
            .events
            .iter()
            .enumerate()
            .map(|(k, &(e, _))| (e, k))
            .collect(),
        mode_of: HashMap::new(),
        modes: Vec::new(),
        in_code: true,
        variant: Vec::new(),
    };
    let state_regs: Vec<Reg> = states.iter().map(|&s| c.var_reg_new(s)).collect();
    // Which steps the derivatives need: walk the schedule backwards.
    let ders: Vec<VarId> = states
        .iter()
        .map(|&s| match sys.vars[s].role {
            crate::ir::VarRole::State { der } => der,
            _ => unreachable!("states have derivatives"),
        })
        .collect();
    let info = StepVars::of(sys, &sched.steps);
    let mut needed = vec![false; sys.vars.len()];
    for &d in &ders {
        needed[d.0 as usize] = true;
    }
    let in_f = info.needed(&mut needed);
    // Every step the outputs need, in f or not: the output program is
    // independent of `code`, so output points cost only what they read.
    let for_out = info.needed(&mut output_vars(sys, outputs));
    drop(info);
    let at_out: Vec<bool> = for_out.iter().zip(&in_f).map(|(o, f)| *o && !f).collect();
    let mut code = Vec::new();
    for (k, step) in sched.steps.iter().enumerate() {
        if in_f[k] {
            c.step(step, &mut code);
        }
    }
    let deriv_regs: Vec<Reg> = ders.iter().map(|d| c.var_reg[d.0 as usize]).collect();
    let var_regs = c.var_reg.clone();
    // The outputs after an evaluation of `f`: what `code` computed is read
    // from its registers, only the output-only steps are computed.
    c.in_code = false;
    let tail_blocks = c.blocks.len();
    let (tail_code, tail_regs) = c.outputs(sched, &at_out, outputs);
    let tail_blocks = tail_blocks..c.blocks.len();
    // The output program gets its own registers for everything computed.
    for (r, e) in c.memo.iter_mut().zip(sys.exprs.nodes()) {
        if !matches!(e, Expr::Const(_)) {
            *r = NONE;
        }
    }
    for v in sys.vars.ids() {
        if !sys.vars[v].is_state() {
            c.var_reg[v.0 as usize] = NONE;
        }
    }
    let (out_code, out_regs) = c.outputs(sched, &for_out, outputs);
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
    let out_inputs = states_read(&c.blocks, &out_code, &out_regs, &state_regs);
    set_private(
        &mut c.blocks,
        &[&code, &out_code],
        &[&deriv_regs, &out_regs],
    );
    // The tail's own blocks settle their bodies: its outputs read them
    // (the analysis above sees only `code` and the output program).
    for b in &mut c.blocks[tail_blocks] {
        b.private = false;
    }
    let tail_code = settled_tail(&c.blocks, &code, tail_code, &tail_regs);
    // Switch conductances change between runs of the code: never constants.
    let switch_regs: Vec<Reg> = sys
        .params
        .iter()
        .zip(&c.param_reg)
        .filter(|((_, p), _)| p.switch)
        .map(|(_, &r)| r)
        .collect();
    // The floor factor changes between the operating point and the run.
    let floor_reg: Option<Reg> = sys
        .params
        .iter()
        .zip(&c.param_reg)
        .find(|((_, p), r)| p.floor && **r != NONE)
        .map(|(_, &r)| r);
    let varying: Vec<Reg> = state_regs
        .iter()
        .chain(switch_regs.iter().filter(|&&r| r != NONE))
        .chain(&floor_reg)
        .copied()
        .collect();
    set_constant_jacobians(
        &mut c.blocks,
        &[&code, &out_code, &tail_code],
        &varying,
        c.n_regs as usize,
    );
    c.set_charge_inverses();
    let memo_links = memo_links(&c.blocks, &code, &out_code);
    let n_in_f = count(&in_f);
    let n_at_outputs = count(&at_out);
    let source_params: Vec<(Reg, f64)> = sys
        .params
        .iter()
        .zip(&c.param_reg)
        .filter(|((_, p), r)| p.source && **r != NONE)
        .map(|((_, p), &r)| (r, p.value))
        .collect();
    let tangent_inputs = tangent_inputs(&[&code, &tail_code], &c.blocks, c.n_regs as usize);
    Tape {
        n_regs: c.n_regs as usize,
        tangent_inputs,
        state_regs,
        states,
        deriv_regs,
        init: c.init,
        code,
        blocks: c.blocks,
        out_code,
        out_inputs,
        out_regs,
        tail_code,
        tail_regs,
        memo_links,
        sources: sys.sources.values().map(|s| s.wave.clone()).collect(),
        diodes: sys.diodes.clone(),
        coverage: Coverage {
            in_f: n_in_f,
            at_outputs: n_at_outputs,
            unused: sys.eqs.len() - n_in_f - n_at_outputs,
        },
        reg_var: c.reg_var,
        var_regs,
        mode: std::cell::Cell::new(Mode::Transient),
        source_scale: std::cell::Cell::new(1.0),
        slope_end: std::cell::Cell::new(f64::INFINITY),
        slope_start: std::cell::Cell::new(f64::NEG_INFINITY),
        gmin_step: std::cell::Cell::new(0.0),
        source_params,
        switch_regs,
        floor_reg,
        modes: c.modes,
        source_memo: vec![std::cell::Cell::new((f64::NAN, 0.0)); sys.sources.len()],
        work: std::cell::Cell::new(0),
        work_limit: std::cell::Cell::new(u64::MAX),
    }
}
