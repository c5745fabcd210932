//! `.ic` without `uic`: the operating point with every `.ic` node held at
//! its value, as ngspice computes it (a 1e10 S Norton source loaded at the
//! node), from which the transient starts with the nodes released.
//!
//! It is solved on the circuit's DC image: capacitors open (0 A sources,
//! whose branch voltages are the capacitors' voltages), inductors shorted
//! (0 V sources carrying the inductors' currents), couplings dropped (they
//! carry nothing at DC), and an ideal voltage source on each `.ic` node. A
//! capacitor's `ic=` is not used, as ngspice does not use it without `uic`.

use crate::diag::codes;
use std::rc::Rc;

use diffsol::{FaerSparseMat, Matrix, NalgebraMat};

use super::dc::Continuation;
use super::ode::{CircuitOde, HostVec};
use super::{DENSE_STATES, Options, SimError, atols, dc_point, output_ref};
use crate::diag::Diagnostic;
use crate::elab::{Circuit, ElemId, Element, ElementKind, GROUND, NodeIc, Output};
use crate::ir::{IdVec, VarId, VarKind, Waveform};
use crate::pipeline::{Elaborated, SortOptions, Sorted};
use crate::tape;

/// The held operating point.
pub(super) struct Held {
    /// K0408 for each `.ic` that could not be held.
    pub warnings: Vec<Diagnostic>,
    /// The circuit's states there (one per state of the sorted system).
    pub y: Vec<f64>,
    /// The outputs there: the `.ic` nodes at their values, as ngspice
    /// reports its operating point at t = 0.
    pub row: Vec<f64>,
    /// Every variable the image's tape holds, by name, at the operating
    /// point: the first guesses of the circuit's own algebraic loops.
    pub named: std::collections::HashMap<String, f64>,
    /// Whether its Newton only stalled near the point (see
    /// [`super::dc::Found`]).
    pub rough: bool,
}

/// Why the `.ic` nodes could not be held.
pub(super) enum Unheld {
    /// The DC image has no solution structure (an `.ic` on a node that a
    /// voltage source or an inductor ties to another fixed potential): the
    /// message of its first error.
    Structure(String),
    /// The held operating point was set up but not found.
    Sim(SimError),
}

/// Which `.ic` nodes can be held: not those that voltage sources, inductors
/// (shorts at DC) and controlled voltage sources tie to ground or to a node
/// held before (the node would have two potentials; ngspice's finite
/// conductance gives way to the source there too).
fn holdable(c: &Circuit, ics: &[NodeIc]) -> Vec<bool> {
    let root = super::node_components(c, |k| {
        matches!(
            k,
            ElementKind::VSource { .. }
                | ElementKind::Inductor { .. }
                | ElementKind::Vcvs { .. }
                | ElementKind::Ccvs { .. }
                | ElementKind::Behavioural { current: false, .. }
        )
    });
    let mut fixed = vec![false; c.nodes.len()];
    fixed[root[GROUND.0 as usize]] = true;
    ics.iter()
        .map(|ic| !std::mem::replace(&mut fixed[root[ic.node.0 as usize]], true))
        .collect()
}

/// The DC image of `c` (see the module documentation), holding the `.ic`
/// nodes marked in `hold`, and, for each element of `c`, its element in the
/// image (`None` for couplings).
fn dc_image(
    c: &Circuit,
    ics: &[NodeIc],
    directive: &str,
    hold: &[bool],
) -> (Circuit, Vec<Option<ElemId>>) {
    let zero = || Box::new(Waveform::Dc { value: 0.0 });
    let mut elements = IdVec::with_capacity(c.elements.len() + ics.len());
    let mut map = Vec::with_capacity(c.elements.len());
    for e in c.elements.values() {
        let kind = match &e.kind {
            ElementKind::Coupling { .. } => {
                map.push(None);
                continue;
            }
            ElementKind::Capacitor { .. } => ElementKind::ISource { wave: zero() },
            // A capacitance branch is open in DC: its current alone.
            ElementKind::DeviceBranch {
                device,
                controlled,
                current,
                charge,
                capacitance: Some(_),
                controls,
            } => ElementKind::DeviceBranch {
                device: *device,
                controlled: *controlled,
                current: current.clone(),
                charge: charge.clone(),
                capacitance: None,
                controls: controls.clone(),
            },
            ElementKind::Inductor { .. } => ElementKind::VSource { wave: zero() },
            k => k.clone(),
        };
        map.push(Some(elements.push(Element {
            name: e.name.clone(),
            kind,
            nodes: e.nodes.clone(),
        })));
    }
    for e in elements.values_mut() {
        // A controlling element is a voltage source, never a coupling.
        for ctrl in e.kind.controls_mut() {
            if let Some(to) = map[ctrl.0 as usize] {
                *ctrl = to;
            }
        }
    }
    for ic in ics.iter().zip(hold).filter(|h| *h.1).map(|h| h.0) {
        elements.push(Element {
            name: crate::ir::Name::new(
                &format!("{directive} v({})", c.nodes[ic.node].name),
                Some(ic.span),
            ),
            kind: ElementKind::VSource {
                wave: Box::new(Waveform::Dc { value: ic.value }),
            },
            nodes: Box::new([ic.node, GROUND]),
        });
    }
    let image = Circuit {
        title: c.title.clone(),
        nodes: c.nodes.clone(),
        elements,
        tran: c.tran.clone(),
        ics: Vec::new(),
        nodesets: Vec::new(),
        options: c.options.clone(),
        // The transistors' junction functions, which their branches call.
        junctions: c.junctions.clone(),
        ..Default::default()
    };
    (image, map)
}

/// A failed operating point with the nodes of `held` held at their values:
/// its diagnostic points at their lines (the values are part of the
/// problem, and a wild one, `.ic v(g)=6.69e31`, is its likeliest cause).
/// Errors that are not the operating point's own pass unchanged.
pub(super) fn held_failure(c: &Circuit, held: &[NodeIc], directive: &str, e: SimError) -> SimError {
    if !matches!(e, SimError::DcFailed { .. } | SimError::DcSingular { .. }) {
        return e;
    }
    SimError::HeldDcFailed {
        directive: directive.to_string(),
        held: held
            .iter()
            .map(|ic| {
                let name = &c.nodes[ic.node].name;
                let v = ic.value;
                let v = if v == 0.0 || (1e-3..1e6).contains(&v.abs()) {
                    format!("{v}")
                } else {
                    format!("{v:e}")
                };
                (ic.span, format!("v({name}) = {v} V"))
            })
            .collect(),
        cause: Box::new(e),
    }
}

/// The operating point of `sorted`'s circuit with the nodes of `ics` held
/// (its `.ic` or `.nodeset` values, as `directive` names them): the values
/// of `states` (the states of the sorted system, in order) and of
/// `outputs` there.
pub(super) fn held_operating_point(
    sorted: &Sorted,
    states: &[VarId],
    outputs: &[Output],
    opts: &Options,
    ics: &[NodeIc],
    directive: &str,
    algebraic: bool,
) -> Result<Held, Unheld> {
    let c = &sorted.elaborated.circuit;
    let hold = holdable(c, ics);
    let warnings = ics
        .iter()
        .zip(&hold)
        .filter(|h| !*h.1)
        .map(|(ic, _)| {
            let name = &c.nodes[ic.node].name;
            Diagnostic::warning(
                codes::IC_NOT_HELD,
                format!(
                    "`{directive} v({name})` cannot be held in the DC operating point: a voltage source or inductor ties `{name}` to ground or to another {directive} node"
                ),
            )
            .with_label(ic.span, "the node takes the value the circuit gives it")
            .with_help("remove this `.ic`, or put it on a node that no voltage source fixes")
        })
        .collect();
    let (image, map) = dc_image(c, ics, directive, &hold);
    let el = Elaborated {
        sources: sorted.elaborated.sources.clone(),
        circuit: image,
        warnings: Vec::new(),
    };
    let built = crate::build::build(
        &el.circuit,
        crate::build::Options {
            algebraic_charges: algebraic,
            ..Default::default()
        },
    );
    let dc = crate::pipeline::sort_built(el, built, &SortOptions::default()).map_err(|f| {
        Unheld::Structure(
            f.errors()
                .next()
                .map_or_else(|| "it cannot be sorted".into(), |d| d.message.clone()),
        )
    })?;
    let sys = dc.system();
    let dc_states: Vec<VarId> = sys.states().collect();
    // What each of the circuit's states is in the image: a capacitor's
    // voltage across its open terminals, an inductor's current through its
    // short, a junction's charge the image's own state of that name.
    let owner = super::element_of_vars(sorted);
    let image_elem = |e: ElemId| map[e.0 as usize].expect("a two-terminal element");
    let unmapped = |v: VarId| {
        Unheld::Structure(format!(
            "kausal cannot map the state `{}` onto the operating point",
            sorted.system().var_name(v)
        ))
    };
    enum Read {
        Output(usize),
        State(usize),
    }
    let image_state: std::collections::HashMap<&str, usize> = dc_states
        .iter()
        .enumerate()
        .map(|(k, &d)| (sys.var_name(d), k))
        .collect();
    // With algebraic charges, each charge is a variable of the image.
    let image_charge: std::collections::HashMap<&str, VarId> = dc
        .built
        .charges
        .values()
        .map(|&q| (sys.var_name(q), q))
        .collect();
    let mut refs = Vec::new();
    let mut from = Vec::with_capacity(states.len());
    for &s in states {
        let var = &sorted.system().vars[s];
        if var.kind == VarKind::Charge && algebraic {
            let q = *image_charge
                .get(sorted.system().var_name(s))
                .ok_or_else(|| unmapped(s))?;
            from.push(Read::Output(refs.len()));
            refs.push(tape::OutputRef::Var(q));
            continue;
        }
        if var.kind == VarKind::Charge {
            let k = *image_state
                .get(sorted.system().var_name(s))
                .ok_or_else(|| unmapped(s))?;
            from.push(Read::State(k));
            continue;
        }
        let e = *owner.get(&s).ok_or_else(|| unmapped(s))?;
        let el = &c.elements[e];
        let out = match el.kind {
            ElementKind::Capacitor { .. }
            | ElementKind::DeviceBranch {
                capacitance: Some(_),
                ..
            } => Output::Voltage {
                pos: el.nodes[0],
                neg: el.nodes[1],
            },
            ElementKind::Inductor { .. } => Output::Current {
                elem: image_elem(e),
            },
            _ => return Err(unmapped(s)),
        };
        from.push(Read::Output(refs.len()));
        refs.push(output_ref(&dc.built, &out));
    }
    let first_output = refs.len();
    for o in outputs {
        let o = match *o {
            Output::Current { elem } => Output::Current {
                elem: image_elem(elem),
            },
            ref v => v.clone(),
        };
        refs.push(output_ref(&dc.built, &o));
    }
    let tape = Rc::new(tape::compile(sys, &dc.schedule, &refs));
    let atol = atols(sys, &dc_states, opts, &dc.elaborated.circuit);
    let ptc = Continuation::of(&dc.elaborated.circuit);
    let fets = super::dc::fets(&dc, &tape);
    let ImagePoint {
        y,
        values,
        named,
        rough,
    } = if dc_states.len() > DENSE_STATES {
        solve::<FaerSparseMat<f64>>(sys, tape, &atol, true, ptc, &fets, opts)
    } else {
        solve::<NalgebraMat<f64>>(sys, tape, &atol, false, ptc, &fets, opts)
    }
    .map_err(Unheld::Sim)?;
    let y = from
        .iter()
        .map(|f| match *f {
            Read::Output(k) => values[k],
            Read::State(k) => y[k],
        })
        .collect();
    Ok(Held {
        warnings,
        y,
        row: values[first_output..].to_vec(),
        named,
        rough,
    })
}

/// The image's operating point.
struct ImagePoint {
    /// Its states (junction charges).
    y: Vec<f64>,
    /// The tape's outputs there.
    values: Vec<f64>,
    /// Every variable its tape holds there, by name.
    named: std::collections::HashMap<String, f64>,
    /// Whether its Newton only stalled near it.
    rough: bool,
}

/// The image's operating point (see [`ImagePoint`]).
fn solve<M: Matrix<T = f64>>(
    sys: &crate::ir::EquationSystem,
    tape: Rc<tape::Tape>,
    atol: &[f64],
    sparse: bool,
    ptc: Continuation,
    fets: &[super::dc::Fet],
    opts: &Options,
) -> Result<ImagePoint, SimError>
where
    M::V: HostVec,
{
    let n = tape.states.len();
    let ode = CircuitOde::<M>::new(tape.clone(), vec![0.0; n], sparse)?;
    tape.in_mode(tape::Mode::Dc, || {
        let y = dc_point::<M>(
            &ode,
            0.0,
            vec![0.0; n],
            atol,
            ptc,
            fets,
            super::dc::DcWork::from_now(
                &ode.tape,
                opts.dc_work.unwrap_or(super::dc::DC_MAX_WORK),
                opts.dc_deadline,
            ),
        )?;
        let (y, rough) = (y.y, y.rough);
        let mut out = vec![0.0; tape.out_regs.len()];
        ode.outputs(0.0, &y, &mut out)
            .map_err(|error| SimError::Eval { error })?;
        Ok(ImagePoint {
            named: ode.named_values(sys),
            y,
            values: out,
            rough,
        })
    })
}

/// K0408: the `.ic` nodes could not be held, and why.
pub(super) fn unheld_warning(c: &Circuit, why: &str) -> Diagnostic {
    let names: Vec<String> = c
        .ics
        .iter()
        .map(|i| format!("`v({})`", c.nodes[i.node].name))
        .collect();
    let mut d = Diagnostic::warning(
        codes::IC_NOT_HELD,
        format!(
            "{} cannot be held in the DC operating point ({why})",
            names.join(", ")
        ),
    );
    if let Some(first) = c.ics.first() {
        d = d.with_label(first.span, "the nodes take their DC values instead");
    }
    d.with_help("remove the conflicting `.ic`, or give capacitors `ic=` and use `.tran ... uic`")
}
