//! The tape's instruction set: register operations, source reads and
//! block solves, with the derivative rules of the functions they call.

use crate::ir::{DeviceFn, Func};

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

/// No register: the destination of a [`Instr::Block`].
pub(super) const NONE: u32 = u32::MAX;

/// The registers an instruction reads (at most two), without allocating.
#[derive(Clone, Copy, Debug)]
pub struct Operands {
    regs: [u32; 2],
    n: usize,
}

impl IntoIterator for Operands {
    type Item = u32;
    type IntoIter = std::iter::Take<std::array::IntoIter<u32, 2>>;
    fn into_iter(self) -> Self::IntoIter {
        self.regs.into_iter().take(self.n)
    }
}

impl Instr {
    /// The register it writes; [`NONE`] for a block, whose writes are its
    /// body's.
    pub fn dest(&self) -> u32 {
        match *self {
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

    /// The registers it reads: the one accessor through which passes see
    /// operands, so that a pass need not match every opcode. Sources and
    /// time read none; a block's reads are its body's.
    pub fn operands(&self) -> Operands {
        let (regs, n) = match *self {
            Instr::Neg { a, .. } | Instr::Call { a, .. } | Instr::Device { a, .. } => ([a, 0], 1),
            Instr::Add { a, b, .. }
            | Instr::Sub { a, b, .. }
            | Instr::Mul { a, b, .. }
            | Instr::Div { a, b, .. }
            | Instr::Pow { a, b, .. } => ([a, b], 2),
            Instr::Src { .. } | Instr::Time { .. } | Instr::Block { .. } => ([0, 0], 0),
        };
        Operands { regs, n }
    }
}
