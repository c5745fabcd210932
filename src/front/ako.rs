//! PSpice's "a kind of" models, `.model QHI AKO:QBASE NPN(BF=300)`: QBASE's
//! parameters, then the card's own (a later value wins). Resolved on the AST
//! before elaboration, as ngspice's PSpice compatibility mode rewrites the
//! card: the model named is looked up among the models of the same
//! subcircuit body, then the top level (through includes, never inside
//! another subcircuit), and must have the same type.

use std::collections::HashMap;

use super::ast::{Assign, Model, Name, Stmt};
use super::error::ParseError;

/// Models by lower-case name: their type and their parameters.
type Models<'a> = HashMap<String, (Name<'a>, Vec<Assign<'a>>)>;

/// Merge every `AKO:` model of `stmts` (the top level) and its subcircuits.
pub(super) fn resolve(stmts: &mut [Stmt<'_>], errors: &mut Vec<ParseError>) {
    block(stmts, &[], errors);
}

/// One block (the top level or a subcircuit body) with the blocks that
/// enclose it, innermost first.
fn block<'a>(stmts: &mut [Stmt<'a>], outer: &[&Models<'a>], errors: &mut Vec<ParseError>) {
    let mut here = Models::new();
    gather(stmts, &mut here);
    merge(stmts, &mut here, outer, errors);
    let mut chain = vec![&here];
    chain.extend_from_slice(outer);
    subckts(stmts, &chain, errors);
}

/// The block's models that name no other (through includes).
fn gather<'a>(stmts: &[Stmt<'a>], out: &mut Models<'a>) {
    for s in stmts {
        match s {
            Stmt::Model(m) if m.ako.is_none() => {
                out.entry(m.name.key())
                    .or_insert_with(|| (m.kind, m.params.clone()));
            }
            Stmt::Include { body, .. } => gather(body, out),
            _ => {}
        }
    }
}

/// Resolve the block's `AKO:` models in their order, each then known to the
/// ones after it.
fn merge<'a>(
    stmts: &mut [Stmt<'a>],
    here: &mut Models<'a>,
    outer: &[&Models<'a>],
    errors: &mut Vec<ParseError>,
) {
    for s in stmts {
        match s {
            Stmt::Model(m) if m.ako.is_some() => {
                if let Some(err) = one(m, here, outer) {
                    errors.push(err);
                    continue;
                }
                here.entry(m.name.key())
                    .or_insert_with(|| (m.kind, m.params.clone()));
            }
            Stmt::Include { body, .. } => merge(body, here, outer, errors),
            _ => {}
        }
    }
}

/// Merge one model's parameters after those of the model it names.
fn one<'a>(m: &mut Model<'a>, here: &Models<'a>, outer: &[&Models<'a>]) -> Option<ParseError> {
    let orig = m.ako?;
    let key = orig.key();
    let Some((kind, params)) = std::iter::once(here)
        .chain(outer.iter().copied())
        .find_map(|ms| ms.get(&key))
    else {
        return Some(ParseError::AkoUndefined {
            span: orig.span,
            name: orig.text.to_string(),
        });
    };
    if !kind.is(m.kind.text) {
        return Some(ParseError::AkoType {
            span: orig.span,
            name: m.name.text.to_string(),
            kind: m.kind.text.to_string(),
            orig: orig.text.to_string(),
            orig_kind: kind.text.to_string(),
        });
    }
    let own = std::mem::take(&mut m.params);
    m.params = params.iter().cloned().chain(own).collect();
    m.ako = None;
    None
}

/// The subcircuits defined in a block (through includes), each a block
/// inside `chain`.
fn subckts<'a>(stmts: &mut [Stmt<'a>], chain: &[&Models<'a>], errors: &mut Vec<ParseError>) {
    for s in stmts {
        match s {
            Stmt::Subckt(sc) => block(&mut sc.body, chain, errors),
            Stmt::Include { body, .. } => subckts(body, chain, errors),
            _ => {}
        }
    }
}
