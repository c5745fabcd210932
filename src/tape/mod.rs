//! The in-process evaluator: a schedule compiled into a flat register
//! program over an `f64` slice. No tree walking and no hashing when it runs:
//! one `match` per instruction. Assignments alias registers (`x := y` costs
//! nothing), common subexpressions share one register (the expression arena
//! is hash-consed), and algebraic blocks are solved by damped Newton on their
//! tearing variables with an analytic Jacobian from forward-mode tangents.
//!
//! Only what the scene needs is computed during integration: the state
//! derivatives, with the blocks they need. Requested outputs are computed by
//! a second program, at output points only, from the states; a third, the
//! tail, computes them after an evaluation of `f` from its registers (only
//! the steps `f` does not need), for an integrator whose output points are
//! its steps' ends.

use std::collections::HashMap;

use crate::analysis::{Assignment, Schedule, Solved, Step};
use crate::ir::{DiodeParams, EquationSystem, Expr, ExprId, Func, VarId, Waveform};
use crate::numeric::colour::{colour_columns, members};
use crate::numeric::dense::{lu_factor, lu_solve};
use crate::numeric::newton::{self, Damping};
use crate::numeric::{DenseLu, Factored, SparsePattern, TripletLu};

mod analyze;
pub use analyze::{DensePattern, PATTERN_LIMIT};
mod block;
mod compile;
mod eval;
mod instr;
mod tangent;

pub use compile::compile;
pub use instr::{Instr, NO_MODE, Reg};
pub use tangent::TangentCache;

use analyze::*;
use block::*;
use instr::*;

/// An algebraic loop: guess the tearing registers, run `body`, drive the
/// residual registers to zero.
#[derive(Clone, Debug)]
pub struct TapeBlock {
    /// 1-based index in the schedule (for messages).
    pub index: usize,
    pub tears: Vec<Reg>,
    /// A one-tear block's magnitude of its tear below which Newton's
    /// corrections are measured absolutely (see [`tear_floor`]). 1 in a block
    /// of many tears: its damping weighs every tear's correction in one norm,
    /// and a current weighed against a nanoampere there made the loop of
    /// eSim's IR2130 (level shifters of B sources into MOSFETs) diverge.
    pub floor: f64,
    pub residuals: Vec<Reg>,
    pub body: Vec<Instr>,
    pub linear: bool,
    /// The circuit elements of the block, for messages.
    pub elements: Vec<String>,
    /// Tears that enter an `exp(x/vt)` (junction voltages), with the register
    /// of `vt`: their Newton steps are limited as ngspice limits junctions.
    /// With each, the breakdown voltage of its diode (infinite: none), whose
    /// reverse steps are limited too.
    pub junctions: Vec<(usize, Reg, f64)>,
    /// Registers the body reads or writes, each once: the tangents a
    /// Jacobian column clears before it runs.
    pub touched: Vec<Reg>,
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

/// The magnitude of a tear of `kind` below which its Newton corrections are
/// measured absolutely: corrections are sized against `floor + |x|`. A volt
/// (and a volt per second) for every unknown but a branch current, whose
/// floor is a nanoampere. Against `1 + |x|`, Newton on a nanoampere tear
/// stopped where its correction was small beside a volt, not beside the
/// tear, and a current through 100 MΩ carried that onto its node: in Xyce's
/// `teststep1` (an op-amp macromodel's bias network, TMAX 1 ns) the
/// integrator's Newton then failed 51,763 times in its first 107,890 steps
/// (6,302 in 25,282 after), and a failure with a fresh Jacobian cuts the
/// step to 0.3 of itself: the run took 5.4 times span/TMAX steps.
pub fn tear_floor(kind: crate::ir::VarKind) -> f64 {
    match kind {
        crate::ir::VarKind::BranchCurrent => 1e-9,
        _ => 1.0,
    }
}

/// A junction-charge block: find `x` with `Q_diode(x) = r[target]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChargeInverse {
    pub diode: u32,
    pub target: Reg,
    /// Four registers: the last voltage the inversion evaluated the junction
    /// at, and its charge, `Q′` and `Q″` there (NaN: none yet). The next
    /// inversion starts from it and takes its first step without evaluating
    /// the junction.
    pub memo: Reg,
}

impl TapeBlock {
    /// Affine in its tears with no junction among them: the full Newton
    /// step solves it, up to rounding.
    pub(crate) fn affine(&self) -> bool {
        self.linear && self.junctions.is_empty()
    }

    /// A block of `body` solving `residuals` for `tears`, before the
    /// compiler's analyses fill in its junctions, touched registers and
    /// solution method.
    pub fn new(
        index: usize,
        (tears, residuals): (Vec<Reg>, Vec<Reg>),
        body: Vec<Instr>,
        linear: bool,
        elements: Vec<String>,
    ) -> TapeBlock {
        TapeBlock {
            index,
            floor: 1.0,
            tears,
            residuals,
            body,
            linear,
            elements,
            junctions: Vec::new(),
            touched: Vec::new(),
            private: false,
            constant_jacobian: false,
            lu: std::cell::OnceCell::new(),
            pattern: std::cell::OnceCell::new(),
            charge_inverse: None,
        }
    }

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

/// `t = …`, or what a time that is no number means: an integrator's first
/// step from derivatives that overflow (a source of 1e308 V) has a NaN size.
fn at_time(t: f64) -> String {
    if t.is_nan() {
        "the first step, whose time is no number (the derivatives at the start overflow)".into()
    } else {
        format!("t = {t:e}")
    }
}

/// Why an evaluation failed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum EvalError {
    #[error(
        "Newton did not converge in algebraic loop {block} through {} (residual {residual:.3e} at {})",
        crate::back::listing::shortened(elements, crate::back::listing::ELEMENTS_SHOWN),
        at_time(*t)
    )]
    NoConvergence {
        block: usize,
        elements: Vec<String>,
        residual: f64,
        t: f64,
    },
    #[error(
        "singular Jacobian in algebraic loop {block} through {} at {}",
        crate::back::listing::shortened(elements, crate::back::listing::ELEMENTS_SHOWN),
        at_time(*t)
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
    pub state_regs: Vec<Reg>,
    /// The state variables, in the same order.
    pub states: Vec<VarId>,
    /// Register of each state's derivative (the ODE's `f`).
    pub deriv_regs: Vec<Reg>,
    /// Initial register contents (parameters and constants).
    pub init: Vec<f64>,
    pub code: Vec<Instr>,
    pub blocks: Vec<TapeBlock>,
    /// The registers `code` and `tail_code` read and nothing in them writes
    /// (states, parameters, constants): a tangent pass clears only these,
    /// as every other register's tangent is written before it is read.
    pub tangent_inputs: Vec<Reg>,
    /// Computes the outputs from the states, on its own registers.
    pub out_code: Vec<Instr>,
    /// The states `out_code` reads: (index in `y`, register).
    pub out_inputs: Vec<(usize, Reg)>,
    pub out_regs: Vec<Reg>,
    /// Computes the outputs after an evaluation of `f`, from `code`'s
    /// registers: only what `f` does not compute (see
    /// [`Tape::outputs_after_rhs`]).
    pub tail_code: Vec<Instr>,
    pub tail_regs: Vec<Reg>,
    /// `(from, to)`: the inversion memo of a junction charge in `code` and
    /// of the same charge in `out_code`. An output point after a step
    /// starts each inversion where the step's last evaluation ended (a
    /// Halley step or none), not where the last output point did.
    memo_links: Vec<(Reg, Reg)>,
    pub sources: Vec<Waveform>,
    pub diodes: Vec<DiodeParams>,
    /// Where the schedule's assignments are evaluated.
    pub coverage: Coverage,
    /// For each register, the assignment (variable) whose value it holds,
    /// when it holds one: to name the source of a NaN.
    pub reg_var: Vec<Option<VarId>>,
    /// The register of each variable `code` computes (`NONE` for the
    /// others): what the operating point's Newton reads of a device after
    /// an evaluation (see [`Tape::reg_of`]).
    var_regs: Vec<Reg>,
    /// The mode evaluations run in (see [`Tape::in_mode`]).
    mode: std::cell::Cell<Mode>,
    /// Every independent source's value is multiplied by this (1 but while
    /// the DC solve ramps the sources up): waveforms as they are evaluated,
    /// DC values in their registers (see [`Tape::scale_sources`]).
    pub source_scale: std::cell::Cell<f64>,
    /// Where the integrator's run stops (a source corner, or the end): at
    /// and past it a source's derivatives are the left-sided ones, so that
    /// the step that lands on a corner sees the slope before it (see
    /// [`Tape::set_slope_end`]).
    slope_end: std::cell::Cell<f64>,
    /// Where the integrator's run started (a source corner): at and before
    /// it a source's derivatives are the right-sided ones, whatever rounding
    /// put the corner on either side of it (see [`Tape::set_slope_start`]).
    slope_start: std::cell::Cell<f64>,
    /// A conductance added across every junction that has GMIN (0 but
    /// while the DC solve steps it down, see [`Tape::set_gmin_step`]).
    pub gmin_step: std::cell::Cell<f64>,
    /// The registers of DC sources' values, and the values.
    pub source_params: Vec<(Reg, f64)>,
    /// Each switch's conductance register (in element order; `NONE` where
    /// no code reads it).
    pub switch_regs: Vec<Reg>,
    /// The register of the capacitance floors' factor, where code reads it
    /// (see [`crate::ir::EquationSystem::add_floor_param`]).
    pub floor_reg: Option<Reg>,
    /// The comparisons written in B sources, each a state event: its value
    /// held through a step (see [`HeldCmp`]).
    pub modes: Vec<HeldCmp>,
    /// Each source's last `(t, value)` (unscaled, order 0): the Newton
    /// iterations of an implicit stage evaluate `f` at one time again and
    /// again, and a transcendental source (SIN) is then computed once.
    source_memo: Vec<std::cell::Cell<(f64, f64)>>,
    /// Instructions run so far (evaluations and tangent runs), and the
    /// count past which a block's Newton gives up (`u64::MAX` but while
    /// the DC solve's continuation bounds its work: see [`Tape::limit_work`]).
    work: std::cell::Cell<u64>,
    work_limit: std::cell::Cell<u64>,
}

/// A comparison a user wrote (`v(a) > 1`, `u(x)`): while `held` is a value
/// (0 or 1) every evaluation reads it, so a step sees no jump; the event
/// search reads `control`, the difference of the operands at the last
/// evaluation, and flips `held` where the comparison's own value differs.
/// NaN `held`: evaluated as it falls (a method that locates no events, the
/// operating point's Newton).
#[derive(Clone, Debug)]
pub struct HeldCmp {
    pub op: crate::ir::Cmp,
    /// The B source it is written in.
    pub element: String,
    /// The comparison as the listing prints it.
    pub text: String,
    pub held: std::cell::Cell<f64>,
    pub control: std::cell::Cell<f64>,
}

impl HeldCmp {
    /// The value the comparison takes with the operands' difference `x`.
    pub fn value(&self, x: f64) -> f64 {
        self.op.apply(x, 0.0)
    }
}

/// How many of the schedule's assignments the tape evaluates where.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Coverage {
    /// In `f`, at every evaluation.
    pub in_f: usize,
    /// Only at output points.
    pub at_outputs: usize,
    /// Never (nothing asked for them).
    pub unused: usize,
}

/// What the sources mean to an evaluation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Mode {
    /// Sources as functions of time.
    #[default]
    Transient,
    /// The operating point: sources' time derivatives read as zero, so
    /// capacitors are open and inductors shorted whatever the sources do.
    Dc,
}

impl Tape {
    /// The junction tears of every block as the registers `regs` hold them:
    /// `(voltage, vt, breakdown voltage)` each (see [`TapeBlock::junctions`]).
    pub fn junction_voltages(&self, regs: &[f64], out: &mut Vec<(f64, f64, f64)>) {
        out.clear();
        for b in &self.blocks {
            for &(j, vt, bv) in &b.junctions {
                out.push((regs[b.tears[j]], regs[vt].abs(), bv));
            }
        }
    }
}

impl Tape {
    /// The register that holds `v` after an evaluation of `f`, if `f`
    /// computes it.
    pub fn reg_of(&self, v: VarId) -> Option<Reg> {
        self.var_regs
            .get(v.0 as usize)
            .copied()
            .filter(|&r| r != instr::NONE)
    }

    /// Run `f` with evaluations in `mode`, then return to the mode before.
    pub fn in_mode<R>(&self, mode: Mode, f: impl FnOnce() -> R) -> R {
        let before = self.mode.replace(mode);
        let result = f();
        self.mode.set(before);
        result
    }
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
