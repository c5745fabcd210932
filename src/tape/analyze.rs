//! Abstract interpretations of the compiled tape: which blocks are private,
//! charge inversions or affine, how registers depend on the states, and the
//! Jacobian's sparsity.

use std::collections::HashMap;
use std::rc::Rc;

use super::*;

/// Mark the blocks whose body values (other than the tears) are read only
/// inside the body itself.
pub(super) fn set_private(blocks: &mut [TapeBlock], programs: &[&[Instr]], direct: &[&[Reg]]) {
    // Who reads each register, by register: unseen, top-level code, or the
    // body of block k; read by two counts as top level.
    const UNSEEN: u32 = u32::MAX;
    const TOP: u32 = u32::MAX - 1;
    let mut reader: Vec<u32> = Vec::new();
    let mut note = |r: Reg, by: u32| {
        if r == NONE {
            return;
        }
        let i = r.idx();
        if i >= reader.len() {
            reader.resize(i + 1, UNSEEN);
        }
        reader[i] = match reader[i] {
            UNSEEN => by,
            old if old == by => old,
            _ => TOP,
        };
    };
    for code in programs {
        for ins in code.iter() {
            for r in ins.operands() {
                note(r, TOP);
            }
        }
    }
    for regs in direct {
        for &r in regs.iter() {
            note(r, TOP);
        }
    }
    for (k, b) in blocks.iter().enumerate() {
        for ins in &b.body {
            for r in ins.operands() {
                note(r, k as u32);
            }
        }
    }
    for (k, b) in blocks.iter_mut().enumerate() {
        // A set: a block can have 10^4 tears and 10^5 instructions.
        let tears: std::collections::HashSet<Reg> = b.tears.iter().copied().collect();
        b.private = b.body.iter().all(|ins| {
            let d = ins.dest();
            d == NONE
                || reader
                    .get(d.idx())
                    .is_none_or(|&by| by == UNSEEN || by == k as u32)
                || tears.contains(&d)
        });
    }
}

/// `Some` when the block is exactly `r = s - Q(x)` (or `Q(x) - s`) for the
/// charge `Q` of a diode, its one tear `x` and a register `s` it does not write.
pub(super) fn charge_inverse(b: &TapeBlock) -> Option<ChargeInverse> {
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
pub(super) fn set_constant_jacobians(
    blocks: &mut [TapeBlock],
    programs: &[&[Instr]],
    states: &[Reg],
    n_regs: usize,
) {
    if blocks.is_empty() {
        return;
    }
    // A flag by register, not a hashed set (every instruction but a block's
    // call writes one).
    let mut written = vec![false; n_regs];
    let dests = programs
        .iter()
        .flat_map(|c| c.iter())
        .chain(blocks.iter().flat_map(|b| b.body.iter()))
        .map(|ins| ins.dest())
        .chain(states.iter().copied())
        .chain(blocks.iter().flat_map(|b| b.tears.iter().copied()));
    for r in dests.filter(|&r| r != NONE) {
        written[r.idx()] = true;
    }
    let written = |x: Reg| written[x.idx()];
    for b in blocks.iter_mut() {
        let mut varies: std::collections::HashSet<Reg> = b.tears.iter().copied().collect();
        let mut constant = !b.tears.is_empty();
        for ins in &b.body {
            let v = |x: Reg| varies.contains(&x);
            let coefficient = |x: Reg| !written(x);
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
                // Piecewise: a comparison or a choice that moves with the
                // tears can change the Jacobian.
                Instr::Cmp { a, b, .. } => (v(a) || v(b), !(v(a) || v(b))),
                Instr::Select { c, a, b, .. } => {
                    let moves = v(c) || v(a) || v(b);
                    (moves, !moves)
                }
                Instr::Src { .. } | Instr::Time { .. } | Instr::TimeRate { .. } => (false, true),
                Instr::Block { .. } => (true, false),
            };
            if !stays_affine {
                constant = false;
                break;
            }
            if moves {
                varies.insert(ins.dest());
            }
        }
        b.constant_jacobian = constant;
    }
}

/// Tears `x` of a block whose body computes `exp(x / vt)` (a diode's
/// current: its `vt` register and breakdown voltage from `diode`).
pub(super) fn junctions(
    b: &TapeBlock,
    diode: &dyn Fn(u32) -> Option<(Reg, f64)>,
) -> Vec<(usize, Reg, f64)> {
    let mut out = Vec::new();
    // Maps, not scans: a block can hold 10^4 tears and junctions.
    let tear_index: HashMap<Reg, usize> =
        b.tears.iter().enumerate().map(|(j, &x)| (x, j)).collect();
    let mut by_dest: HashMap<Reg, &Instr> = HashMap::new();
    for i in &b.body {
        by_dest.entry(i.dest()).or_insert(i);
    }
    let mut found = std::collections::HashSet::new();
    for ins in &b.body {
        if let Instr::Device { f, a, .. } = *ins
            && let Some(&j) = tear_index.get(&a)
            && let Some((vt, bv)) = diode(f.diode)
            && found.insert(j)
        {
            out.push((j, vt, bv));
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
            out.push((j, den, f64::INFINITY));
        }
    }
    out
}

/// How a register depends on the states (see
/// [`Tape::jacobian_follows_junctions`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Dep {
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
pub(super) fn memo_links(
    blocks: &[TapeBlock],
    code: &[Instr],
    out_code: &[Instr],
) -> Vec<(Reg, Reg)> {
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

impl Tape {
    /// Each state register's index among the states.
    fn state_slots(&self) -> HashMap<Reg, usize> {
        self.state_regs
            .iter()
            .enumerate()
            .map(|(k, &s)| (s, k))
            .collect()
    }

    /// For each state, the junction-charge inversion whose charge it is
    /// (the block that finds the junction voltage from it), if any.
    pub fn charge_states(&self) -> Vec<Option<ChargeInverse>> {
        let mut of = vec![None; self.states.len()];
        if self.blocks.is_empty() {
            return of;
        }
        let slot = self.state_slots();
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

    /// For each state, the zero-bias depletion capacitance of the junction
    /// whose charge it is, if any: the sum of `CJO` over the charge
    /// functions of the one-tear block that finds the junction's voltage
    /// from that state and no other (a diode's inversion, a BJT junction's
    /// depletion and diffusion charge). `None` for every other state, and
    /// where no depletion capacitance is given.
    pub fn charge_capacitances(&self) -> Vec<Option<f64>> {
        let mut of = vec![None; self.states.len()];
        if self.blocks.is_empty() {
            return of;
        }
        let slot = self.state_slots();
        for ins in &self.code {
            let Instr::Block { k } = *ins else { continue };
            let b = &self.blocks[k as usize];
            if b.tears.len() != 1 {
                continue;
            }
            let (mut cap, mut state, mut one) = (0.0, None, true);
            for i in &b.body {
                if let Instr::Device { f, .. } = *i
                    && f.part == crate::ir::DiodePart::Charge
                    && f.order == 0
                {
                    cap += self.diodes[f.diode as usize].cjo;
                }
                for r in i.operands() {
                    if let Some(&s) = slot.get(&r) {
                        one &= state.is_none_or(|t| t == s);
                        state = Some(s);
                    }
                }
            }
            if let Some(s) = state
                && one
                && cap > 0.0
                && of[s].is_none()
            {
                of[s] = Some(cap);
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
        let (mut dep, charges) = self.state_deps();
        self.classify(&self.code, &mut dep);
        self.deriv_regs
            .iter()
            .enumerate()
            .all(|(k, &d)| match dep[d] {
                Dep::Const | Dep::Time | Dep::Lin | Dep::Volt(_) => true,
                Dep::IdNeg(diode) => charges[k].is_some_and(|ci| ci.diode == diode),
                Dep::Charge(_) | Dep::IdPos(_) | Dep::Bad => false,
            })
    }

    /// Whether the outputs after an evaluation ([`Tape::outputs_after_rhs`])
    /// depend on the states as [`Tape::jacobian_follows_junctions`] proves
    /// `f` does, without a junction's current: affine in the states and the
    /// junction voltages (a charge's column of their Jacobian is then a
    /// constant over `Q′`, followed as `f`'s is).
    pub fn outputs_follow_junctions(&self) -> bool {
        let (mut dep, _) = self.state_deps();
        self.classify(&self.code, &mut dep);
        self.classify(&self.tail_code, &mut dep);
        self.tail_regs
            .iter()
            .all(|&r| matches!(dep[r], Dep::Const | Dep::Time | Dep::Lin | Dep::Volt(_)))
    }

    /// Every register constant but the states: a junction charge its
    /// diode's charge, any other state affine; and each state's charge
    /// inversion, if it is a junction charge.
    fn state_deps(&self) -> (Vec<Dep>, Vec<Option<ChargeInverse>>) {
        let mut dep = vec![Dep::Const; self.n_regs];
        let charges = self.charge_states();
        for (k, &s) in self.state_regs.iter().enumerate() {
            dep[s] = match charges[k] {
                Some(ci) => Dep::Charge(ci.diode),
                None => Dep::Lin,
            };
        }
        (dep, charges)
    }

    /// How each register of `code` depends on the states (see
    /// [`Tape::jacobian_follows_junctions`]).
    pub(super) fn classify(&self, code: &[Instr], dep: &mut [Dep]) {
        for ins in code {
            let (d, v) = match *ins {
                Instr::Neg { d, a } => (d, dep[a].negate()),
                Instr::Add { d, a, b } => (d, Dep::sum(dep[a], dep[b])),
                Instr::Sub { d, a, b } => (d, Dep::sum(dep[a], dep[b].negate())),
                Instr::Mul { d, a, b } => (d, Dep::product(dep[a], dep[b])),
                Instr::Div { d, a, b } => match (dep[a], dep[b]) {
                    (x, Dep::Const) => (d, Dep::product(x, Dep::Const)),
                    (x, y) if x.timed() && y.timed() => (d, Dep::Time),
                    _ => (d, Dep::Bad),
                },
                Instr::Pow { d, a, b } => match dep[a].timed() && dep[b].timed() {
                    true => (d, dep[a].max_timed(dep[b])),
                    false => (d, Dep::Bad),
                },
                Instr::Call { d, a, .. } => (d, if dep[a].timed() { dep[a] } else { Dep::Bad }),
                Instr::Cmp { d, a, b, .. } => match dep[a].timed() && dep[b].timed() {
                    true => (d, dep[a].max_timed(dep[b])),
                    false => (d, Dep::Bad),
                },
                Instr::Select { d, c, a, b } => {
                    match dep[c].timed() && dep[a].timed() && dep[b].timed() {
                        true => (d, dep[a].max_timed(dep[b]).max_timed(dep[c])),
                        false => (d, Dep::Bad),
                    }
                }
                Instr::Device { d, f, a } => match dep[a] {
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
                Instr::Src { d, .. } | Instr::Time { d } | Instr::TimeRate { d } => (d, Dep::Time),
                Instr::Block { k } => {
                    self.classify_block(&self.blocks[k as usize], dep);
                    continue;
                }
            };
            dep[d] = v;
        }
    }

    pub(super) fn classify_block(&self, b: &TapeBlock, dep: &mut [Dep]) {
        if let Some(ci) = b.charge_inverse {
            let v = match dep[ci.target] {
                Dep::Charge(diode) if diode == ci.diode => Dep::Volt(diode),
                x if x.timed() => x,
                _ => Dep::Bad,
            };
            // What the body computes besides the voltage is `Q(v)`: nothing
            // the analysis can follow if `f` reads it.
            self.classify_tears(b, dep, Dep::Bad);
            for &x in &b.tears {
                dep[x] = v;
            }
            return;
        }
        // Independent of the states; else affine with constant coefficients.
        let linear = |dep: &[Dep]| {
            b.residuals
                .iter()
                .all(|&r| matches!(dep[r], Dep::Const | Dep::Time | Dep::Lin | Dep::Volt(_)))
        };
        self.classify_tears(b, dep, Dep::Time);
        if b.residuals.iter().all(|&r| dep[r].timed()) {
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
    pub(super) fn classify_tears(&self, b: &TapeBlock, dep: &mut [Dep], tear: Dep) {
        for &x in &b.tears {
            dep[x] = tear;
        }
        self.classify(&b.body, dep);
    }

    /// The sparsity of `∂f/∂y`: for each derivative, the states it depends
    /// on; [`DensePattern`] past [`PATTERN_LIMIT`] entries (in the pattern,
    /// or made while it is computed), before they take gigabytes.
    pub fn jacobian_pattern(&self) -> Result<Vec<(usize, usize)>, DensePattern> {
        self.jacobian_pattern_within(PATTERN_LIMIT)
    }

    /// [`Tape::jacobian_pattern`] with at most `limit` entries.
    pub fn jacobian_pattern_within(
        &self,
        limit: usize,
    ) -> Result<Vec<(usize, usize)>, DensePattern> {
        // Dependencies propagate through the program as sorted state lists,
        // shared where a register depends on what one other does (a copy, a
        // scaling, every value of a block): only unions are new lists.
        let empty: Rc<[u32]> = Rc::from(Vec::new());
        let mut deps: Vec<Rc<[u32]>> = vec![empty.clone(); self.n_regs];
        for (k, &s) in self.state_regs.iter().enumerate() {
            deps[s] = Rc::from(vec![k as u32]);
        }
        let mut walk = PatternWalk {
            tape: self,
            deps,
            empty,
            made: 0,
            limit,
            widest: None,
        };
        walk.walk(&self.code)?;
        let entries: usize = self.deriv_regs.iter().map(|&d| walk.deps[d].len()).sum();
        if entries > limit {
            return Err(walk.dense(entries));
        }
        let mut out = Vec::with_capacity(entries);
        for (i, &d) in self.deriv_regs.iter().enumerate() {
            for &j in walk.deps[d].iter() {
                out.push((i, j as usize));
            }
        }
        Ok(out)
    }
}

/// The most entries [`Tape::jacobian_pattern`] makes, in the pattern or in
/// the dependency lists it computes it from: 2·10^7, a dense Jacobian of
/// about 4,500 states, whose every factorization takes 3·10^10 operations.
pub const PATTERN_LIMIT: usize = 20_000_000;

/// The Jacobian is too dense to integrate: the states coupled, the entries
/// found before the count stopped, and the block that couples the most.
#[derive(Clone, Debug, PartialEq)]
pub struct DensePattern {
    pub states: usize,
    /// The entries counted when the limit was passed, and the limit.
    pub entries: usize,
    pub limit: usize,
    /// The block whose body reads the most states: its number, elements and
    /// how many states it reads.
    pub block: Option<(usize, Vec<String>, usize)>,
}

/// [`Tape::jacobian_pattern`]'s walk over the program.
struct PatternWalk<'t> {
    tape: &'t Tape,
    deps: Vec<Rc<[u32]>>,
    empty: Rc<[u32]>,
    /// Entries of the lists made so far, and the most it may make.
    made: usize,
    limit: usize,
    /// The block that read the most states so far, and how many.
    widest: Option<(usize, usize)>,
}

impl PatternWalk<'_> {
    fn dense(&self, entries: usize) -> DensePattern {
        DensePattern {
            states: self.tape.states.len(),
            entries,
            limit: self.limit,
            block: self.widest.map(|(k, n)| {
                let b = &self.tape.blocks[k];
                (b.index, b.elements.clone(), n)
            }),
        }
    }

    /// The union of two sorted lists, shared when one holds the other.
    fn union(&mut self, a: &Rc<[u32]>, b: &Rc<[u32]>) -> Result<Rc<[u32]>, DensePattern> {
        if b.is_empty() || Rc::ptr_eq(a, b) {
            return Ok(a.clone());
        }
        if a.is_empty() {
            return Ok(b.clone());
        }
        let mut m = Vec::with_capacity(a.len() + b.len());
        let (mut i, mut j) = (0, 0);
        while i < a.len() && j < b.len() {
            match a[i].cmp(&b[j]) {
                std::cmp::Ordering::Equal => {
                    m.push(a[i]);
                    i += 1;
                    j += 1;
                }
                std::cmp::Ordering::Less => {
                    m.push(a[i]);
                    i += 1;
                }
                std::cmp::Ordering::Greater => {
                    m.push(b[j]);
                    j += 1;
                }
            }
        }
        m.extend_from_slice(&a[i..]);
        m.extend_from_slice(&b[j..]);
        if m.len() == a.len() {
            return Ok(a.clone());
        }
        if m.len() == b.len() {
            return Ok(b.clone());
        }
        self.made += m.len();
        if self.made > self.limit {
            return Err(self.dense(self.made));
        }
        Ok(Rc::from(m))
    }

    fn walk(&mut self, code: &[Instr]) -> Result<(), DensePattern> {
        for ins in code {
            if let Instr::Block { k } = ins {
                let b = &self.tape.blocks[*k as usize];
                // Everything in a block depends on everything it reads.
                let mut all = self.empty.clone();
                for i in &b.body {
                    for s in i.operands() {
                        let from = self.deps[s].clone();
                        all = self.union(&all, &from)?;
                    }
                }
                if self.widest.is_none_or(|(_, n)| all.len() > n) {
                    self.widest = Some((*k as usize, all.len()));
                }
                for i in &b.body {
                    let d = i.dest();
                    if d != NONE {
                        self.deps[d] = all.clone();
                    }
                }
                for &x in &b.tears {
                    self.deps[x] = all.clone();
                }
                // Second pass: body values depend on the tears' dependencies.
                self.walk(&b.body)?;
                for i in &b.body {
                    let d = i.dest();
                    if d != NONE {
                        let v = self.deps[d].clone();
                        self.deps[d] = self.union(&v, &all)?;
                    }
                }
                continue;
            }
            let d = ins.dest();
            let mut acc = self.empty.clone();
            for s in ins.operands() {
                let from = self.deps[s].clone();
                acc = self.union(&acc, &from)?;
            }
            self.deps[d] = acc;
        }
        Ok(())
    }
}
