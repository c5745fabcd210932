//! The tape's instruction set: register operations, source reads and
//! block solves, with the derivative rules of the functions they call.

use crate::ir::{Cmp, DeviceFn, Func};

/// A register of the tape: an index into the `f64` register file that
/// every program of one tape shares.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Reg(pub u32);

impl Reg {
    /// Its index in the register file.
    #[inline]
    pub fn idx(self) -> usize {
        self.0 as usize
    }

    /// The register `k` places after it (a block of registers).
    pub fn offset(self, k: u32) -> Reg {
        Reg(self.0 + k)
    }
}

impl<T> std::ops::Index<Reg> for [T] {
    type Output = T;
    #[inline]
    fn index(&self, r: Reg) -> &T {
        &self[r.idx()]
    }
}

impl<T> std::ops::IndexMut<Reg> for [T] {
    #[inline]
    fn index_mut(&mut self, r: Reg) -> &mut T {
        &mut self[r.idx()]
    }
}

impl<T> std::ops::Index<Reg> for Vec<T> {
    type Output = T;
    #[inline]
    fn index(&self, r: Reg) -> &T {
        &self[r.idx()]
    }
}

impl<T> std::ops::IndexMut<Reg> for Vec<T> {
    #[inline]
    fn index_mut(&mut self, r: Reg) -> &mut T {
        &mut self[r.idx()]
    }
}

/// One instruction: `dst = op(a, b)`; operands are registers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Instr {
    Neg {
        d: Reg,
        a: Reg,
    },
    /// A device function (diode current or charge, or a derivative).
    Device {
        d: Reg,
        f: DeviceFn,
        a: Reg,
    },
    Add {
        d: Reg,
        a: Reg,
        b: Reg,
    },
    Sub {
        d: Reg,
        a: Reg,
        b: Reg,
    },
    Mul {
        d: Reg,
        a: Reg,
        b: Reg,
    },
    Div {
        d: Reg,
        a: Reg,
        b: Reg,
    },
    Pow {
        d: Reg,
        a: Reg,
        b: Reg,
    },
    Call {
        d: Reg,
        f: Func,
        a: Reg,
    },
    /// 1 where `a op b` holds, else 0; with a held mode `m` (not
    /// [`NO_MODE`]), the value the mode holds (see [`HeldCmp`]).
    Cmp {
        d: Reg,
        op: Cmp,
        a: Reg,
        b: Reg,
        m: u32,
    },
    /// `a` where `c` is not 0, else `b`.
    Select {
        d: Reg,
        c: Reg,
        a: Reg,
        b: Reg,
    },
    /// The `order`-th time derivative of source `s`.
    Src {
        d: Reg,
        s: u32,
        order: u8,
    },
    Time {
        d: Reg,
    },
    /// d/dt of time: 1, but 0 in [`super::Mode::Dc`] (see [`crate::ir::Expr::TimeRate`]).
    TimeRate {
        d: Reg,
    },
    /// Solve block `k` (see [`TapeBlock`]).
    Block {
        k: u32,
    },
}

/// No register: the destination of a [`Instr::Block`].
pub(super) const NONE: Reg = Reg(u32::MAX);

/// A comparison with no held mode: evaluated as it falls.
pub const NO_MODE: u32 = u32::MAX;

/// The registers an instruction reads (at most three), without allocating.
#[derive(Clone, Copy, Debug)]
pub struct Operands {
    regs: [Reg; 3],
    n: usize,
}

impl IntoIterator for Operands {
    type Item = Reg;
    type IntoIter = std::iter::Take<std::array::IntoIter<Reg, 3>>;
    fn into_iter(self) -> Self::IntoIter {
        self.regs.into_iter().take(self.n)
    }
}

impl Instr {
    /// The register it writes; [`NONE`] for a block, whose writes are its
    /// body's.
    pub fn dest(&self) -> Reg {
        match *self {
            Instr::Neg { d, .. }
            | Instr::Add { d, .. }
            | Instr::Sub { d, .. }
            | Instr::Mul { d, .. }
            | Instr::Div { d, .. }
            | Instr::Pow { d, .. }
            | Instr::Call { d, .. }
            | Instr::Cmp { d, .. }
            | Instr::Select { d, .. }
            | Instr::Device { d, .. }
            | Instr::Src { d, .. }
            | Instr::Time { d }
            | Instr::TimeRate { d } => d,
            Instr::Block { .. } => NONE,
        }
    }

    /// The registers it reads: the one accessor through which passes see
    /// operands, so that a pass need not match every opcode. Sources and
    /// time read none; a block's reads are its body's.
    pub fn operands(&self) -> Operands {
        let (regs, n) = match *self {
            Instr::Neg { a, .. } | Instr::Call { a, .. } | Instr::Device { a, .. } => {
                ([a, NONE, NONE], 1)
            }
            Instr::Add { a, b, .. }
            | Instr::Sub { a, b, .. }
            | Instr::Mul { a, b, .. }
            | Instr::Div { a, b, .. }
            | Instr::Pow { a, b, .. }
            | Instr::Cmp { a, b, .. } => ([a, b, NONE], 2),
            Instr::Select { c, a, b, .. } => ([c, a, b], 3),
            Instr::Src { .. }
            | Instr::Time { .. }
            | Instr::TimeRate { .. }
            | Instr::Block { .. } => ([NONE, NONE, NONE], 0),
        };
        Operands { regs, n }
    }
}
