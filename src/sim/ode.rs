//! The diffsol adapter: the compiled [`Tape`] as an ODE `dy/dt = f(t, y)`
//! with its Jacobian (forward-mode `J v`, assembled by column colouring on
//! the sparsity pattern the tape knows), for dense (nalgebra) and sparse
//! (faer) matrices.

use std::cell::{Cell, RefCell};
use std::rc::Rc;

use diffsol::{
    ConstantOp, FaerVec, Matrix, NalgebraVec, NonLinearOp, NonLinearOpJacobian, OdeEquations,
    OdeEquationsRef, Op, ParameterisedOp, UnitCallable, Vector, VectorCommon, VectorIndex,
};

use diffsol_la::matrix::sparsity::MatrixSparsity;

use super::SimError;
use crate::ir::VarId;
use crate::tape::{EvalError, TangentCache, Tape};
use std::collections::HashMap;

/// Vectors whose storage is one host slice.
pub trait HostVec: Vector<T = f64> {
    fn slice(&self) -> &[f64];
    fn slice_mut(&mut self) -> &mut [f64];
}

impl HostVec for NalgebraVec<f64> {
    fn slice(&self) -> &[f64] {
        self.inner().as_slice()
    }
    fn slice_mut(&mut self) -> &mut [f64] {
        self.inner_mut().as_mut_slice()
    }
}

impl HostVec for FaerVec<f64> {
    fn slice(&self) -> &[f64] {
        self.inner().col_as_slice(0)
    }
    fn slice_mut(&mut self) -> &mut [f64] {
        self.inner_mut().col_as_slice_mut(0)
    }
}

/// The Jacobian's columns grouped by colour (`numeric::colour_columns`:
/// columns that share no row), so that one `J v` per colour fills them all.
/// diffsol's own colouring clears an array of length `n` for every column,
/// quadratic on a ladder of 10^5 sections.
struct Colouring<M: Matrix> {
    /// Per colour: the columns seeded, the rows read from `J v`, and where
    /// those entries sit in the matrix's data.
    colours: Vec<[<M::V as Vector>::Index; 3]>,
    /// Each column's colour.
    colour: Vec<u32>,
    seed: RefCell<M::V>,
    column: RefCell<M::V>,
}

impl<M: Matrix<T = f64>> Colouring<M> {
    /// `nz`: the pattern's `(row, column)` entries, sorted.
    fn new(sp: &M::Sparsity, nz: &[(usize, usize)], ctx: M::C) -> Colouring<M> {
        let n = sp.ncols();
        let mut rows: Vec<Vec<u32>> = vec![Vec::new(); sp.nrows()];
        for &(i, j) in nz {
            rows[i].push(j as u32);
        }
        let (colour, n_colours) = crate::numeric::colour::colour_columns(n, &rows);
        let mut entries: Vec<Vec<(usize, usize)>> = vec![Vec::new(); n_colours as usize];
        for &(i, j) in nz {
            entries[colour[j] as usize].push((i, j));
        }
        let mut seeded: Vec<Vec<usize>> = vec![Vec::new(); n_colours as usize];
        for (j, &c) in colour.iter().enumerate() {
            seeded[c as usize].push(j);
        }
        let colours = entries
            .iter()
            .zip(seeded)
            .map(|(e, cols)| {
                let index = |v: Vec<usize>| <M::V as Vector>::Index::from_vec(v, ctx.clone());
                [
                    index(cols),
                    index(e.iter().map(|&(i, _)| i).collect()),
                    sp.get_index(e, ctx.clone()),
                ]
            })
            .collect();
        Colouring {
            colours,
            colour,
            seed: RefCell::new(M::V::zeros(n, ctx.clone())),
            column: RefCell::new(M::V::zeros(sp.nrows(), ctx)),
        }
    }

    /// Fill `y`'s entries of the colours `colours` from their compressed
    /// Jacobian `jac` (row-major, a column per colour; see
    /// [`Tape::jacobian_compressed`]).
    fn scatter(&self, jac: &[f64], colours: std::ops::Range<usize>, y: &mut M)
    where
        M::V: HostVec,
    {
        let m = colours.len();
        let mut column = self.column.borrow_mut();
        for (j, [_, rows, dst]) in self.colours[colours].iter().enumerate() {
            for (i, v) in column.slice_mut().iter_mut().enumerate() {
                *v = jac[i * m + j];
            }
            y.set_data_with_indices(dst, rows, &column);
        }
    }

    fn jacobian<F: NonLinearOpJacobian<M = M, V = M::V, T = f64, C = M::C>>(
        &self,
        op: &F,
        x: &M::V,
        t: f64,
        y: &mut M,
    ) {
        let (mut seed, mut column) = (self.seed.borrow_mut(), self.column.borrow_mut());
        for [cols, rows, dst] in &self.colours {
            seed.assign_at_indices(cols, 1.0);
            op.jac_mul_inplace(x, t, &seed, &mut column);
            y.set_data_with_indices(dst, rows, &column);
            seed.assign_at_indices(cols, 0.0);
        }
    }
}

/// The most tangent registers (registers × colours) of a Jacobian computed
/// in one multi-direction pass, 32 MiB.
const COMPRESSED_TANGENTS: usize = 1 << 22;

/// Counters of the evaluations the solver asked for.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct EvalCounts {
    pub rhs: usize,
    pub jac_mul: usize,
    pub jacobians: usize,
}

/// The circuit's ODE for diffsol.
pub struct CircuitOde<M: Matrix<T = f64>>
where
    M::V: HostVec,
{
    pub tape: Rc<Tape>,
    regs: RefCell<Vec<f64>>,
    dregs: RefCell<Vec<f64>>,
    /// The initial state, set before each (re)start.
    pub y0: RefCell<Vec<f64>>,
    sparsity: Option<M::Sparsity>,
    coloring: Option<Colouring<M>>,
    ctx: M::C,
    p: M::V,
    /// The first evaluation error, kept for the report (diffsol only sees NaN).
    pub error: RefCell<Option<EvalError>>,
    counts: Cell<EvalCounts>,
    /// The point of the last `J v` (the registers hold its solution while
    /// `tangents.valid`): the next column there reuses the solved blocks.
    jv_point: RefCell<(f64, Vec<f64>)>,
    tangents: RefCell<TangentCache>,
    /// Scratch of [`Tape::jacobian_columns`] (tangents in several directions).
    mregs: RefCell<Vec<f64>>,
    /// Registers of evaluations at output points: they keep their own warm
    /// starts (the previous output point's, the nearest) and leave the
    /// solver's alone.
    side_regs: RefCell<Vec<f64>>,
}

impl<M: Matrix<T = f64>> CircuitOde<M>
where
    M::V: HostVec,
{
    pub fn new(tape: Rc<Tape>, y0: Vec<f64>, sparse: bool) -> Result<CircuitOde<M>, SimError> {
        let ctx = M::C::default();
        let n = tape.states.len();
        let (sparsity, coloring) = if sparse {
            let mut nz = tape
                .jacobian_pattern()
                .map_err(|dense| SimError::DenseJacobian { dense })?;
            nz.extend((0..n).map(|i| (i, i)));
            nz.sort_unstable();
            nz.dedup();
            let sp = <M::Sparsity as MatrixSparsity<M>>::try_from_indices(n, n, nz.clone())
                .expect("the tape's pattern is in range");
            let col = Colouring::new(&sp, &nz, ctx.clone());
            (Some(sp), Some(col))
        } else {
            (None, None)
        };
        Ok(CircuitOde {
            regs: RefCell::new(tape.registers()),
            side_regs: RefCell::new(tape.registers()),
            // Made at the first `J v` (a sparse run may take none: its
            // Jacobian is coloured, through `mregs`).
            dregs: RefCell::new(Vec::new()),
            tape,
            y0: RefCell::new(y0),
            sparsity,
            coloring,
            p: M::V::zeros(0, ctx.clone()),
            ctx,
            error: RefCell::new(None),
            counts: Cell::new(EvalCounts::default()),
            jv_point: RefCell::new((f64::NAN, Vec::new())),
            tangents: RefCell::new(TangentCache::default()),
            mregs: RefCell::new(Vec::new()),
        })
    }

    pub fn counts(&self) -> EvalCounts {
        self.counts.get()
    }

    fn bump(&self, f: impl FnOnce(&mut EvalCounts)) {
        let mut c = self.counts.get();
        f(&mut c);
        self.counts.set(c);
    }

    fn fail(&self, e: EvalError) {
        let mut slot = self.error.borrow_mut();
        if slot.is_none() {
            *slot = Some(e);
        }
    }

    /// `f(t, y)` into `dy` outside the solver (initial conditions, checks).
    pub fn eval(&self, t: f64, y: &[f64], dy: &mut [f64]) -> Result<(), EvalError> {
        self.tangents.borrow_mut().valid = false;
        self.tape.rhs(&mut self.regs.borrow_mut(), t, y, dy)
    }

    /// The junction tears at the last [`CircuitOde::eval`] (see
    /// [`Tape::junction_voltages`]).
    pub fn junction_voltages(&self, out: &mut Vec<(f64, f64, f64)>) {
        self.tape.junction_voltages(&self.regs.borrow(), out)
    }

    /// Register `r` as the last [`CircuitOde::eval`] left it.
    pub fn reg_value(&self, r: crate::tape::Reg) -> f64 {
        self.regs.borrow()[r]
    }

    /// The outputs at `(t, y)`.
    pub fn outputs(&self, t: f64, y: &[f64], out: &mut [f64]) -> Result<(), EvalError> {
        self.tangents.borrow_mut().valid = false;
        self.tape.outputs(&mut self.regs.borrow_mut(), t, y, out)
    }

    /// The outputs at the point of the last evaluation of `f` on the
    /// solver's registers, at its time `t` (see [`Tape::outputs_after_rhs`]).
    pub fn outputs_after_rhs(&self, t: f64, out: &mut [f64]) -> Result<(), EvalError> {
        self.tangents.borrow_mut().valid = false;
        self.tape
            .outputs_after_rhs(&mut self.regs.borrow_mut(), t, out)
    }

    /// `∂out/∂y` of the outputs after an evaluation, in the directions of
    /// the [`CircuitOde::jacobian_columns`] on the solver's registers just
    /// made (`m` of them; see [`Tape::output_jacobian`]).
    pub fn output_jacobian(&self, t: f64, m: usize, jac: &mut [f64]) -> Result<(), EvalError> {
        let (mut regs, mut mregs) = (self.regs.borrow_mut(), self.mregs.borrow_mut());
        self.tape.output_jacobian(&mut regs, &mut mregs, m, t, jac)
    }

    /// Columns `cols` of the Jacobian at `(t, y)` in one tangent pass
    /// (row-major, `cols.len()` wide), and `f` there into `dy`, on the
    /// solver's registers or the output side's.
    pub fn jacobian_columns(
        &self,
        on: Regs,
        t: f64,
        y: &[f64],
        cols: &[usize],
        jac: &mut [f64],
        dy: &mut [f64],
    ) -> Result<(), EvalError> {
        let regs = match on {
            Regs::Solver => {
                self.tangents.borrow_mut().valid = false;
                &self.regs
            }
            Regs::Side => &self.side_regs,
        };
        let (mut regs, mut mregs) = (regs.borrow_mut(), self.mregs.borrow_mut());
        self.tape
            .jacobian_columns(&mut regs, &mut mregs, t, y, cols, jac, dy)
    }

    /// The Jacobian at `(t, y)` compressed by the colouring `colour` (see
    /// [`Tape::jacobian_compressed`]), and `f` there into `dy`, on the
    /// solver's registers.
    fn jacobian_compressed(
        &self,
        t: f64,
        y: &[f64],
        colour: &[u32],
        colours: std::ops::Range<usize>,
        jac: &mut [f64],
        dy: &mut [f64],
    ) -> Result<(), EvalError> {
        self.tangents.borrow_mut().valid = false;
        let (mut regs, mut mregs) = (self.regs.borrow_mut(), self.mregs.borrow_mut());
        self.tape
            .jacobian_compressed(&mut regs, &mut mregs, t, y, colour, colours, jac, dy)
    }

    /// Set switch `k`'s conductance (its state) in both register sets.
    pub fn set_switch(&self, k: usize, g: f64) {
        self.tape.set_switch(&mut self.regs.borrow_mut(), k, g);
        self.tape.set_switch(&mut self.side_regs.borrow_mut(), k, g);
        self.tangents.borrow_mut().valid = false;
    }

    /// Scale every independent source by `s` (source stepping; 1 restores).
    pub fn scale_sources(&self, s: f64) {
        self.tape.scale_sources(&mut self.regs.borrow_mut(), s);
        self.tape.scale_sources(&mut self.side_regs.borrow_mut(), s);
        self.tangents.borrow_mut().valid = false;
    }

    /// The factor on capacitance floors (see
    /// [`crate::ir::EquationSystem::add_floor_param`]; 1 restores).
    pub fn set_floor_factor(&self, s: f64) {
        if self.tape.floor_reg.is_none() {
            return;
        }
        self.tape.set_floor_factor(&mut self.regs.borrow_mut(), s);
        self.tape
            .set_floor_factor(&mut self.side_regs.borrow_mut(), s);
        self.tangents.borrow_mut().valid = false;
    }

    /// Every block's tears back at their first guesses (see
    /// [`crate::tape::Tape::reset_tears`]).
    pub fn reset_tears(&self) {
        self.tape.reset_tears(&mut self.regs.borrow_mut());
        self.tangents.borrow_mut().valid = false;
    }

    /// Every block's tears, in both register sets, at the values `value`
    /// gives their variables (those it gives none keep theirs).
    pub fn seed_tears(&self, value: impl Fn(VarId) -> Option<f64>) {
        for regs in [&self.regs, &self.side_regs] {
            let mut regs = regs.borrow_mut();
            for t in self.tape.blocks.iter().flat_map(|b| &b.tears) {
                if let Some(v) = self.tape.reg_var[t.idx()].and_then(&value) {
                    regs[t.idx()] = v;
                }
            }
        }
        self.tangents.borrow_mut().valid = false;
    }

    /// The value of every register that holds a variable, by its name,
    /// as the last evaluation left it.
    pub fn named_values(&self, sys: &crate::ir::EquationSystem) -> HashMap<String, f64> {
        let regs = self.regs.borrow();
        self.tape
            .reg_var
            .iter()
            .zip(regs.iter())
            .filter_map(|(v, &x)| v.map(|v| (sys.var_name(v).to_string(), x)))
            .collect()
    }

    /// The DC solve's GMIN step across the junctions (see
    /// [`crate::tape::Tape::set_gmin_step`]).
    pub fn set_gmin_step(&self, g: f64) {
        self.tape.set_gmin_step(g);
        self.tangents.borrow_mut().valid = false;
    }

    /// `f(t, y)` at an output point, on the output side's own registers.
    pub fn side_eval(&self, t: f64, y: &[f64], dy: &mut [f64]) -> Result<(), EvalError> {
        self.tape.rhs(&mut self.side_regs.borrow_mut(), t, y, dy)
    }

    /// `J v` inside the solver: consecutive calls at one point (the columns
    /// of a Jacobian) solve the blocks once.
    fn jv_kept(&self, t: f64, y: &[f64], v: &[f64], out: &mut [f64]) -> Result<(), EvalError> {
        let mut cache = self.tangents.borrow_mut();
        let mut point = self.jv_point.borrow_mut();
        if !(cache.valid && point.0 == t && point.1 == y) {
            cache.valid = false;
            point.0 = t;
            point.1.clear();
            point.1.extend_from_slice(y);
        }
        let mut dregs = self.dregs.borrow_mut();
        dregs.resize(self.tape.n_regs, 0.0);
        self.tape.jac_mul(
            &mut self.regs.borrow_mut(),
            &mut dregs,
            t,
            y,
            v,
            out,
            Some(&mut cache),
        )
    }

    /// One register of the solver's evaluations, as the last left it.
    pub fn register(&self, r: crate::tape::Reg) -> f64 {
        self.regs.borrow()[r]
    }

    /// One register of the output side's evaluations, as the last left it.
    pub fn side_register(&self, r: crate::tape::Reg) -> f64 {
        self.side_regs.borrow()[r]
    }

    /// The registers after the last evaluation (to find where a NaN came from).
    pub fn registers(&self) -> Vec<f64> {
        self.regs.borrow().clone()
    }
}

/// The register set of an evaluation outside the solver: the solver's own
/// (which then loses its cached tangents), or the output side's, which never
/// moves the solver's warm starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Regs {
    Solver,
    Side,
}

pub struct Rhs<'a, M: Matrix<T = f64>>
where
    M::V: HostVec,
{
    eqn: &'a CircuitOde<M>,
}

pub struct Init<'a, M: Matrix<T = f64>>
where
    M::V: HostVec,
{
    eqn: &'a CircuitOde<M>,
}

macro_rules! impl_op {
    ($name:ident) => {
        impl<M: Matrix<T = f64>> Op for $name<'_, M>
        where
            M::V: HostVec,
        {
            type M = M;
            type V = M::V;
            type T = f64;
            type C = M::C;
            fn nstates(&self) -> usize {
                self.eqn.tape.states.len()
            }
            fn nout(&self) -> usize {
                self.eqn.tape.states.len()
            }
            fn nparams(&self) -> usize {
                0
            }
            fn context(&self) -> &Self::C {
                &self.eqn.ctx
            }
        }
    };
}

impl_op!(Rhs);
impl_op!(Init);

impl<M: Matrix<T = f64>> NonLinearOp for Rhs<'_, M>
where
    M::V: HostVec,
{
    fn call_inplace(&self, x: &M::V, t: f64, y: &mut M::V) {
        self.eqn.bump(|c| c.rhs += 1);
        self.eqn.tangents.borrow_mut().valid = false;
        let r = self
            .eqn
            .tape
            .rhs(&mut self.eqn.regs.borrow_mut(), t, x.slice(), y.slice_mut());
        if let Err(e) = r {
            self.eqn.fail(e);
            y.slice_mut().iter_mut().for_each(|v| *v = f64::NAN);
        }
    }
}

impl<M: Matrix<T = f64>> NonLinearOpJacobian for Rhs<'_, M>
where
    M::V: HostVec,
{
    fn jac_mul_inplace(&self, x: &M::V, t: f64, v: &M::V, y: &mut M::V) {
        self.eqn.bump(|c| c.jac_mul += 1);
        let r = self.eqn.jv_kept(t, x.slice(), v.slice(), y.slice_mut());
        if let Err(e) = r {
            self.eqn.fail(e);
            y.slice_mut().iter_mut().for_each(|v| *v = f64::NAN);
        }
    }

    fn jacobian_inplace(&self, x: &M::V, t: f64, y: &mut M) {
        self.eqn.bump(|c| c.jacobians += 1);
        match self.eqn.coloring.as_ref() {
            // The colours in multi-direction tangent passes (each
            // instruction decoded once for all the colours of a pass), as
            // many a pass as their tangents fit in; a `J v` a colour where
            // not even two do.
            Some(col) if 2 * self.eqn.tape.n_regs <= COMPRESSED_TANGENTS => {
                let (n, m) = (self.eqn.tape.states.len(), col.colours.len());
                let chunk = (COMPRESSED_TANGENTS / self.eqn.tape.n_regs).clamp(1, m);
                let (mut jac, mut f) = (Vec::new(), vec![0.0; n]);
                for c0 in (0..m).step_by(chunk) {
                    let colours = c0..(c0 + chunk).min(m);
                    jac.clear();
                    jac.resize(n * colours.len(), 0.0);
                    let r = self.eqn.jacobian_compressed(
                        t,
                        x.slice(),
                        &col.colour,
                        colours.clone(),
                        &mut jac,
                        &mut f,
                    );
                    if let Err(e) = r {
                        self.eqn.fail(e);
                        jac.iter_mut().for_each(|v| *v = f64::NAN);
                    }
                    col.scatter(&jac, colours, y);
                }
            }
            Some(col) => col.jacobian(self, x, t, y),
            None => {
                // Dense: every column in one multi-direction tangent pass.
                let n = self.eqn.tape.states.len();
                let cols: Vec<usize> = (0..n).collect();
                let mut jac = vec![0.0; n * n];
                let mut f = vec![0.0; n];
                let r =
                    self.eqn
                        .jacobian_columns(Regs::Solver, t, x.slice(), &cols, &mut jac, &mut f);
                if let Err(e) = r {
                    self.eqn.fail(e);
                    jac.iter_mut().for_each(|v| *v = f64::NAN);
                }
                let mut col = M::V::zeros(n, self.eqn.ctx.clone());
                for j in 0..n {
                    for (i, c) in col.slice_mut().iter_mut().enumerate() {
                        *c = jac[i * n + j];
                    }
                    y.set_column(j, &col);
                }
            }
        }
    }

    fn jacobian_sparsity(&self) -> Option<M::Sparsity> {
        self.eqn.sparsity.clone()
    }
}

impl<M: Matrix<T = f64>> ConstantOp for Init<'_, M>
where
    M::V: HostVec,
{
    fn call_inplace(&self, _t: f64, y: &mut M::V) {
        y.slice_mut().copy_from_slice(&self.eqn.y0.borrow());
    }
}

impl<M: Matrix<T = f64>> Op for CircuitOde<M>
where
    M::V: HostVec,
{
    type M = M;
    type V = M::V;
    type T = f64;
    type C = M::C;
    fn nstates(&self) -> usize {
        self.tape.states.len()
    }
    fn nout(&self) -> usize {
        self.tape.states.len()
    }
    fn nparams(&self) -> usize {
        0
    }
    fn context(&self) -> &Self::C {
        &self.ctx
    }
}

impl<'a, M: Matrix<T = f64>> OdeEquationsRef<'a> for CircuitOde<M>
where
    M::V: HostVec,
{
    type Rhs = Rhs<'a, M>;
    type Init = Init<'a, M>;
    type Mass = ParameterisedOp<'a, UnitCallable<M>>;
    type Root = ParameterisedOp<'a, UnitCallable<M>>;
    type Out = ParameterisedOp<'a, UnitCallable<M>>;
    type Reset = ParameterisedOp<'a, UnitCallable<M>>;
}

impl<M: Matrix<T = f64>> OdeEquations for CircuitOde<M>
where
    M::V: HostVec,
{
    fn rhs(&self) -> Rhs<'_, M> {
        Rhs { eqn: self }
    }
    fn init(&self) -> Init<'_, M> {
        Init { eqn: self }
    }
    fn mass(&self) -> Option<<Self as OdeEquationsRef<'_>>::Mass> {
        None
    }
    fn out(&self) -> Option<<Self as OdeEquationsRef<'_>>::Out> {
        None
    }
    fn root(&self) -> Option<<Self as OdeEquationsRef<'_>>::Root> {
        None
    }
    fn set_params(&mut self, p: &Self::V) {
        self.p.copy_from(p);
    }
    fn get_params(&self, p: &mut Self::V) {
        p.copy_from(&self.p);
    }
}
