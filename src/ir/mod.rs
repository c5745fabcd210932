//! The equation IR: typed ids, interned symbols, a deduplicating expression
//! arena and the acausal [`EquationSystem`].
//!
//! The IR knows nothing of netlist syntax, graph algorithms or simulation; the only
//! thing it takes from the rest of the crate is [`crate::diag::Span`], so that
//! each equation can say which netlist line it came from.

pub mod derive;
mod device;
mod entity;
mod expr;
mod names;
pub mod print;
mod system;
mod verify;

pub use device::{
    DeviceFn, DiodeParams, DiodePart, VT_27C, fet_limit, junction_limit, pnjlim, thermal_voltage,
    vds_limit,
};
pub use entity::{EntityId, IdVec};
pub use expr::{Cmp, Expr, ExprArena, ExprId, Func, Slope, bits, select};
pub use names::NameTable;
pub use system::{
    EqId, Equation, EquationSystem, KvlLoop, Name, Origin, OriginKind, Param, ParamId, SourceFn,
    SourceId, Var, VarId, VarKind, VarRole, Waveform, joined,
};
pub use verify::{VerifyError, verify};
