//! Checks of the IR invariants, run after every pass in tests.

use super::entity::EntityId;
use super::expr::{Expr, ExprId};
use super::system::{EquationSystem, VarRole};

/// A broken IR invariant: always a kausal bug, never a user error.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum VerifyError {
    #[error("expression {user} uses {operand}, which does not precede it")]
    OperandOrder { user: ExprId, operand: ExprId },
    #[error("expression {expr} refers to an entity that does not exist")]
    Dangling { expr: ExprId },
    #[error("state {state} and derivative {der} do not point at each other")]
    StatePair {
        state: super::VarId,
        der: super::VarId,
    },
    #[error("equation {eq} refers to expression {expr}, which does not exist")]
    EquationExpr { eq: super::EqId, expr: ExprId },
    #[error("the stored variables of equation {eq} differ from its expressions'")]
    Incidence { eq: super::EqId },
    #[error("the stored unknown flag of variable {var} is stale")]
    UnknownFlag { var: super::VarId },
    #[error("{names} variable names for {vars} variables")]
    Names { names: usize, vars: usize },
}

/// Check every invariant of `sys`; returns all violations found.
pub fn verify(sys: &EquationSystem) -> Vec<VerifyError> {
    let mut errs = Vec::new();
    if sys.names.len() != sys.vars.len() {
        errs.push(VerifyError::Names {
            names: sys.names.len(),
            vars: sys.vars.len(),
        });
    }
    for (i, &e) in sys.exprs.nodes().iter().enumerate() {
        let user = ExprId::new(i);
        for op in e.operands().into_iter().flatten() {
            if op >= user {
                errs.push(VerifyError::OperandOrder { user, operand: op });
            }
        }
        let dangling = match e {
            Expr::Var(v) => v.index() >= sys.vars.len(),
            Expr::Param(p) => p.index() >= sys.params.len(),
            Expr::Source(s, _) => s.index() >= sys.sources.len(),
            _ => false,
        };
        if dangling {
            errs.push(VerifyError::Dangling { expr: user });
        }
    }
    for (id, v) in sys.vars.iter() {
        match v.role {
            VarRole::State { der } => {
                let ok = sys
                    .vars
                    .get(der)
                    .is_some_and(|d| d.role == VarRole::Derivative { of: id });
                if !ok {
                    errs.push(VerifyError::StatePair { state: id, der });
                }
            }
            VarRole::Derivative { of } => {
                let ok = sys
                    .vars
                    .get(of)
                    .is_some_and(|s| s.role == VarRole::State { der: id });
                if !ok {
                    errs.push(VerifyError::StatePair { state: of, der: id });
                }
            }
            VarRole::Unknown => {}
        }
    }
    for (id, v) in sys.vars.iter() {
        if sys.unknown_flags().get(id.index()) != Some(&v.is_unknown()) {
            errs.push(VerifyError::UnknownFlag { var: id });
        }
    }
    let (mut vars, mut stack) = (Vec::new(), Vec::new());
    for (id, eq) in sys.eqs.iter() {
        let mut exprs_ok = true;
        for expr in [eq.lhs, eq.rhs] {
            if expr.index() >= sys.exprs.len() {
                errs.push(VerifyError::EquationExpr { eq: id, expr });
                exprs_ok = false;
            }
        }
        if exprs_ok {
            sys.eq_vars(id, &mut vars, &mut stack);
            if sys.incidence(id) != vars.as_slice() {
                errs.push(VerifyError::Incidence { eq: id });
            }
        }
    }
    errs
}
