//! The start of a run: the DC operating point (damped Newton on `f = 0` in
//! DC mode, then source stepping), `.ic`/`uic` starts, and the diagnostics
//! that name what has no DC solution.
//!
//! The DC operating point is Newton on `f = 0` in DC mode: junction-charge
//! states take limited steps (ngspice's junction limiting, through `Q⁻¹`),
//! other steps are damped by the natural monotonicity test; if it fails, the
//! sources are ramped up from zero (`Tape::scale_sources`: a DC source's
//! value has a register of its own). Where all that fails, or Newton only
//! stalls near a point, the operating point is solved on the DC image
//! instead (see [`ic`]): there the node voltages are the unknowns of its
//! algebraic loops, where here they are reached through capacitor voltages
//! and junction charges, a formulation ill-conditioned where every
//! transistor is off (Xyce's `gm1`: first Newton steps of 10^2–10^5 V).

use super::*;

/// The start of a run.
pub(super) struct Start {
    pub(super) y: Vec<f64>,
    pub(super) warnings: Vec<crate::diag::Diagnostic>,
    /// The outputs at t = 0 when they are not those of `y`: the operating
    /// point with the `.ic` nodes held, before they are released.
    pub(super) row: Option<Vec<f64>>,
    /// The operating point's stages in the order tried (empty: held `.ic`
    /// nodes or `uic`), and the one whose point it is.
    pub(super) stages: Vec<DcStage>,
    pub(super) found: Option<DcStage>,
}

/// A stage of the operating point's search (see [`initial_state`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DcStage {
    /// Newton on the states alone, from ngspice's start.
    Newton,
    /// The DC image with its charges algebraic.
    AlgebraicImage,
    /// The DC image with its charges as states.
    ChargeImage,
    /// Newton on the states through continuation, GMIN and source stepping.
    Stepping,
    /// The same from every transistor conducting.
    TransistorsOn,
}

impl DcStage {
    /// The stage in words, as `kausal sim` reports it.
    pub fn describe(self) -> &'static str {
        match self {
            DcStage::Newton => "Newton",
            DcStage::AlgebraicImage => "the DC image",
            DcStage::ChargeImage => "the DC image with charge states",
            DcStage::Stepping => "continuation and stepping",
            DcStage::TransistorsOn => "stepping from the transistors on",
        }
    }
}

/// The element that owns each branch variable.
pub(super) fn element_of_vars(sorted: &Sorted) -> HashMap<VarId, crate::elab::ElemId> {
    let mut owner = HashMap::new();
    for (e, ev) in sorted.built.elem_vars.iter().enumerate() {
        if let Some(ev) = ev {
            let id = crate::elab::ElemId(e as u32);
            owner.insert(ev.u, id);
            owner.insert(ev.i, id);
        }
    }
    owner
}

/// The capacitor voltages just after t = 0 of a `uic` start where voltage
/// sources and capacitors share a node. ngspice starts a `uic` run from a
/// node vector of zeros (but the `.ic` nodes), the supplies' nodes too,
/// and each capacitor from its `ic=` or that vector; at its first time
/// point the sources have their values, and the charge they move through
/// the capacitors is conserved at every other node: a node between a
/// 0.1 pF capacitor to ground and one to a 3 V supply starts at 1.5 V,
/// where starting each capacitor at its own initial voltage would put it
/// at 3 V. Solved as that impulse: the network of the linear capacitors
/// and the independent voltage sources (nodal, the capacitances as
/// conductances, each capacitor's initial charge a current), where one of
/// its connected parts holds a source and two capacitors; elsewhere every
/// capacitor keeps its initial voltage, as it would here. A part where a
/// junction or gate charge or a controlled voltage source meets one of its
/// nodes (but ground) keeps kausal's start: they would share the impulse,
/// and the network does not hold them. Inductors pass no impulse.
fn uic_redistribution(
    c: &crate::elab::Circuit,
    initial: &dyn Fn(crate::elab::NodeId) -> f64,
) -> HashMap<crate::elab::ElemId, f64> {
    let n_nodes = c.nodes.len();
    let mut caps = Vec::new();
    let mut sources = Vec::new();
    for (id, el) in c.elements.iter() {
        match &el.kind {
            &ElementKind::Capacitor { c: cap, ic } if cap.is_finite() && cap != 0.0 => {
                let v0 = ic.unwrap_or_else(|| initial(el.nodes[0]) - initial(el.nodes[1]));
                caps.push((id, el.nodes[0].0 as usize, el.nodes[1].0 as usize, cap, v0));
            }
            ElementKind::VSource { wave } => {
                sources.push((
                    el.nodes[0].0 as usize,
                    el.nodes[1].0 as usize,
                    wave.eval(0.0, 0),
                ));
            }
            _ => {}
        }
    }
    // Nodes where something outside this network takes part in the
    // impulse: a device's charge or capacitance, a controlled voltage
    // source. A part holding one keeps kausal's start.
    let mut outside = vec![false; n_nodes];
    for el in c.elements.values() {
        let takes_part = match &el.kind {
            ElementKind::DeviceBranch { .. } | ElementKind::Diode { .. } => true,
            ElementKind::Vcvs { .. } | ElementKind::Ccvs { .. } => true,
            ElementKind::Behavioural { current, .. } => !current,
            _ => false,
        };
        if takes_part {
            for n in el.nodes.iter().take(2).filter(|n| n.0 != 0) {
                outside[n.0 as usize] = true;
            }
        }
    }
    let mut parts = crate::numeric::UnionFind::new(n_nodes);
    for &(_, a, b, ..) in &caps {
        parts.union(a, b);
    }
    for &(a, b, _) in &sources {
        parts.union(a, b);
    }
    let mut n_caps = vec![0usize; n_nodes];
    let mut has_source = vec![false; n_nodes];
    let mut has_outside = vec![false; n_nodes];
    for &(_, a, ..) in &caps {
        n_caps[parts.find(a)] += 1;
    }
    for &(a, ..) in &sources {
        has_source[parts.find(a)] = true;
    }
    for k in 0..n_nodes {
        if outside[k] {
            has_outside[parts.find(k)] = true;
        }
    }
    let live: Vec<bool> = (0..n_nodes)
        .map(|k| {
            let r = parts.find(k);
            has_source[r] && n_caps[r] >= 2 && !has_outside[r]
        })
        .collect();
    let mut out = HashMap::new();
    if !live.iter().any(|&l| l) {
        return out;
    }
    // Unknowns: the live nodes but ground, then one current per source.
    let mut index = vec![usize::MAX; n_nodes];
    let mut n = 0;
    for k in 1..n_nodes {
        if live[k] {
            index[k] = n;
            n += 1;
        }
    }
    let live_sources: Vec<_> = sources.iter().filter(|s| live[s.0]).collect();
    let order = n + live_sources.len();
    let at = |k: usize| (k != 0).then(|| index[k]);
    let mut entries = Vec::new();
    let mut rhs = vec![0.0; order];
    let scale = caps.iter().map(|c| c.3.abs()).fold(0.0, f64::max);
    for &(_, a, b, cap, v0) in caps.iter().filter(|c| live[c.1]) {
        let (ia, ib) = (at(a), at(b));
        if let Some(i) = ia {
            entries.push((i, i, cap));
            rhs[i] += cap * v0;
        }
        if let Some(j) = ib {
            entries.push((j, j, cap));
            rhs[j] -= cap * v0;
        }
        if let (Some(i), Some(j)) = (ia, ib) {
            entries.push((i, j, -cap));
            entries.push((j, i, -cap));
        }
    }
    // A part that floats (sources and capacitors, no ground) has no
    // potential of its own: a conductance 1e-12 of the largest
    // capacitance's to ground fixes one without moving any difference.
    for i in 0..n {
        entries.push((i, i, 1e-12 * scale));
    }
    for (k, &&(a, b, v)) in live_sources.iter().enumerate() {
        let row = n + k;
        if let Some(i) = at(a) {
            entries.push((i, row, 1.0));
            entries.push((row, i, 1.0));
        }
        if let Some(j) = at(b) {
            entries.push((j, row, -1.0));
            entries.push((row, j, -1.0));
        }
        rhs[row] = v;
    }
    let Some(lu) = crate::numeric::TripletLu::new(order, entries) else {
        return out;
    };
    let Some(x) = crate::numeric::Factored::Sparse(lu).solve(&rhs) else {
        return out;
    };
    let volt = |k: usize| at(k).map_or(0.0, |i| x[i]);
    for &(id, a, b, ..) in caps.iter().filter(|c| live[c.1]) {
        out.insert(id, volt(a) - volt(b));
    }
    out
}

/// The initial states: `uic` (element `ic=` and `.ic` values), the DC
/// operating point with the `.ic` nodes held (see [`ic`]), or the DC
/// operating point (capacitors open, inductors shorted: `f(0, y) = 0`).
pub(super) fn initial_state<M: Matrix<T = f64>>(
    sorted: &Sorted,
    ode: &CircuitOde<M>,
    t0: f64,
    atol: &[f64],
    outputs: &[Output],
    opts: &Options,
) -> Result<Start, SimError>
where
    M::V: HostVec,
{
    let c = &sorted.elaborated.circuit;
    let tape = &ode.tape;
    let n = tape.states.len();
    let uic = c.tran.as_ref().is_some_and(|t| t.uic);
    let mut warnings = Vec::new();
    // The operating point with `ics` held, on the DC image with charge
    // states; where that finds none, or cannot be mapped onto the circuit's
    // states (a junction charge that is no state of the image), on the
    // image with algebraic charges, which maps every charge by name (see
    // below).
    let held_point = |ics: &[crate::elab::NodeIc], directive: &str| {
        let on = |algebraic| {
            ic::held_operating_point(
                sorted,
                &tape.states,
                outputs,
                opts,
                ics,
                directive,
                algebraic,
            )
        };
        match on(false) {
            Err(e) if algebraic_image() => match on(true) {
                Ok(h) if !h.rough => Ok(h),
                _ => Err(e),
            },
            found => found,
        }
    };
    if !uic && !c.ics.is_empty() {
        match held_point(&c.ics, ".ic") {
            Ok(held) => {
                let sys = sorted.system();
                ode.seed_tears(|v| held.named.get(sys.var_name(v)).copied());
                return Ok(Start {
                    y: held.y,
                    warnings: held.warnings,
                    row: Some(held.row),
                    stages: Vec::new(),
                    found: None,
                });
            }
            Err(ic::Unheld::Sim(e)) => {
                return Err(ic::held_failure(c, &c.ics, ".ic", name_dc_failure(c, e)));
            }
            Err(ic::Unheld::Structure(why)) => warnings.push(ic::unheld_warning(c, &why)),
        }
    }
    let mut y = vec![0.0; n];
    if uic {
        // Element initial conditions, and `.ic` node voltages across
        // capacitors with a terminal on the `.ic` line; as in ngspice, a node
        // not on it starts at 0 V (a capacitor from a named node to an
        // unnamed one started at 0 V instead of the named node's value).
        let ic_node = |node: crate::elab::NodeId| -> f64 {
            c.ics
                .iter()
                .find(|i| i.node == node && node != GROUND)
                .map_or(0.0, |i| i.value)
        };
        let owner = element_of_vars(sorted);
        let redistributed = uic_redistribution(c, &ic_node);
        for (k, &s) in tape.states.iter().enumerate() {
            let Some(&e) = owner.get(&s) else {
                continue;
            };
            if let Some(&v) = redistributed.get(&e) {
                y[k] = v;
                continue;
            }
            let el = &c.elements[e];
            match el.kind {
                ElementKind::Capacitor { ic: Some(v), .. }
                | ElementKind::Inductor { ic: Some(v), .. } => y[k] = v,
                ElementKind::Capacitor { ic: None, .. }
                | ElementKind::DeviceBranch {
                    capacitance: Some(_),
                    ..
                } => {
                    let named = |node| node != GROUND && c.ics.iter().any(|i| i.node == node);
                    if named(el.nodes[0]) || named(el.nodes[1]) {
                        y[k] = ic_node(el.nodes[0]) - ic_node(el.nodes[1]);
                    }
                }
                _ => {}
            }
        }
        // A perfectly coupled group's fluxes from its inductors' IC= currents.
        let built = &sorted.built;
        for (g, vars) in built.reduced.iter().zip(&built.fluxes) {
            for (row, var) in g.flux.iter().zip(vars) {
                let Some(k) = tape.states.iter().position(|s| s == var) else {
                    continue;
                };
                y[k] = row
                    .iter()
                    .zip(&g.members)
                    .map(|(a, &e)| match c.elements[e].kind {
                        ElementKind::Inductor { ic: Some(i), .. } => a * i,
                        _ => 0.0,
                    })
                    .sum();
            }
        }
        return Ok(Start {
            y,
            warnings,
            row: None,
            stages: Vec::new(),
            found: None,
        });
    }
    // `.nodeset`: the operating point with those nodes held is the first
    // guess of the free one (ngspice holds them for its first iterations);
    // where it cannot be had, the guess is zero as without.
    let mut held_start = false;
    if !c.nodesets.is_empty()
        && let Ok(held) = held_point(&c.nodesets, ".nodeset")
    {
        y = held.y;
        warnings.extend(held.warnings);
        held_start = true;
    }
    let ptc = Continuation::of(c);
    let fets = fets(sorted, tape);
    let work = DcWork::from_now(tape, opts.dc_work.unwrap_or(DC_MAX_WORK), opts.dc_deadline);
    // Without `.nodeset`, Newton starts where ngspice's does: every diode at
    // its critical voltage. Where the circuit has several operating points
    // (a negative resistance that a diode clamps), that is the one ngspice
    // finds; where none is found from there, the solve starts again from 0 V.
    let diode_start = if held_start { None } else { diodes_on(c, tape) };
    let fets = &fets;
    let tried = std::cell::RefCell::new(Vec::new());
    let solve_with = |start: Vec<f64>, stage: DcStage| {
        tried.borrow_mut().push(stage);
        let work = DcWork {
            stepping: stage != DcStage::Newton,
            ..work
        };
        tape.in_mode(Mode::Dc, move || {
            dc_point::<M>(ode, t0, start, atol, ptc, fets, work)
        })
    };
    let solve = |start: Vec<f64>| solve_with(start, DcStage::Stepping);
    // The DC image (see [`ic`]): capacitors open, inductors shorted, with
    // what is left of the DC work limit, and at least a quarter of it, and
    // the wall-clock limit, at least a quarter of it: a failing operating
    // point ends within 1.25 times either.
    let image = |algebraic: bool| {
        tried.borrow_mut().push(if algebraic {
            DcStage::AlgebraicImage
        } else {
            DcStage::ChargeImage
        });
        let image_opts = Options {
            dc_work: Some(
                work.deadline
                    .saturating_sub(tape.work())
                    .max(work.limit / 4),
            ),
            dc_deadline: Some(work.wall.max(std::time::Instant::now() + DC_MAX_TIME / 4)),
            ..opts.clone()
        };
        ic::held_operating_point(
            sorted,
            &tape.states,
            outputs,
            &image_opts,
            &[],
            ".op",
            algebraic,
        )
    };
    // The circuit's loops start from the image's solution.
    let from_image = |h: ic::Held| {
        let sys = sorted.system();
        ode.reset_tears();
        ode.seed_tears(|v| h.named.get(sys.var_name(v)).copied());
        h.y
    };
    let start = |y, warnings, found| Start {
        y,
        warnings,
        row: None,
        stages: tried.borrow().clone(),
        found: Some(found),
    };
    let first = match diode_start.clone() {
        _ if image_only() => Err(SimError::DcFailed {
            reason: DcFailure::NotTried,
        }),
        Some(start) => solve_with(start, DcStage::Newton),
        None => solve_with(y.clone(), DcStage::Newton),
    };
    if let Ok(Found { y, rough: false }) = first {
        return Ok(start(y, warnings, DcStage::Newton));
    }
    // The first attempt is Newton alone. Where it finds no operating point
    // on the states, or only stalls near one, the image with algebraic
    // charges is solved next. Its unknowns are the node voltages and branch
    // currents of its algebraic loops alone, as ngspice's are, where Newton
    // on the states reaches them through capacitor voltages and junction
    // charges (a charge's rate is ill-conditioned where its junction is
    // off): a bipolar op-amp whose states' Newton, continuation, GMIN and
    // source stepping fail after seconds converges there by source stepping
    // in milliseconds.
    let algebraic = if held_start || !algebraic_image() {
        None
    } else {
        image(true).ok()
    };
    let algebraic = match algebraic {
        Some(h) if !h.rough => {
            return Ok(start(from_image(h), warnings, DcStage::AlgebraicImage));
        }
        other => other,
    };
    // Where the algebraic image fails (on Xyce's MOS decks its Jacobian is
    // singular: a node that only gate capacitances hold has nothing left at
    // DC once their charges are algebraic), the image with charge states,
    // the same problem with the charges' rates at zero, is tried next,
    // before continuation and stepping on the states: on gm1 and ab_integ
    // those spent 2.3 and 4.2 s failing where it takes 5 and 23 ms.
    let charged = (!held_start && algebraic_image() && algebraic.is_none()).then(|| image(false));
    let charged = match charged {
        Some(Ok(h)) if !h.rough => {
            return Ok(start(from_image(h), warnings, DcStage::ChargeImage));
        }
        other => other,
    };
    // Then Newton with continuation, GMIN and source stepping, from the
    // same start and (with diodes) from zero, the blocks from their first
    // guesses again, not where the failed solve left them.
    let r = match first {
        r if image_only() => r,
        _ => {
            ode.reset_tears();
            let again = match diode_start.clone() {
                Some(start) => solve(start),
                None => solve(y.clone()),
            };
            match again {
                Err(_) if diode_start.is_some() => {
                    ode.reset_tears();
                    solve(y)
                }
                r => r,
            }
        }
    };
    // Where no operating point is found from zero, the transistors are
    // started conducting, as ngspice starts them (each base-emitter
    // junction at its critical voltage, the others at 0 V), and the solve
    // is tried again from there.
    let r = match r {
        Err(e) if image_only() => Err(e),
        Err(e) => match transistors_on(sorted, &tape.states) {
            Some(start) => solve_with(start, DcStage::TransistorsOn).map_err(|_| e),
            None => Err(e),
        },
        ok => ok,
    };
    // The stage whose point `r` is.
    let r_stage = tried.borrow().last().copied().unwrap_or(DcStage::Newton);
    if let Ok(Found { y, rough: false }) = r {
        return Ok(start(y, warnings, r_stage));
    }
    // Then the image with charge states (the junction charges its own
    // states). Where Newton stalls near a point in all of them, the
    // states' point is kept, else the algebraic image's.
    let charged = charged.or_else(|| (!held_start).then(|| image(false)));
    if let Some(Ok(h)) = charged
        && !(h.rough && (r.is_ok() || algebraic.is_some()))
    {
        return Ok(start(from_image(h), warnings, DcStage::ChargeImage));
    }
    if r.is_err()
        && let Some(h) = algebraic
    {
        return Ok(start(from_image(h), warnings, DcStage::AlgebraicImage));
    }
    let weakest = |y: &[f64]| {
        tape.in_mode(Mode::Dc, || {
            ode.set_floor_factor(DC_FLOOR_FACTOR);
            let k = weakest_state(ode, t0, y, atol);
            ode.set_floor_factor(1.0);
            k
        })
    };
    let y = r
        .map_err(|e| name_state(sorted, &tape.states, name_dc_failure(c, e), &weakest))?
        .y;
    Ok(start(y, warnings, r_stage))
}

/// The states with every diode's junction at its critical voltage
/// `vte ln(vte / (√2 IS))` (ngspice's first iterate, MODEINITJCT) and every
/// other state at 0: each diode's charge from its law. `None` without a
/// diode whose charge is a state.
fn diodes_on(c: &Circuit, tape: &crate::tape::Tape) -> Option<Vec<f64>> {
    let mut y = vec![0.0; tape.states.len()];
    let mut any = false;
    for (k, ci) in tape.charge_states().into_iter().enumerate() {
        // Transistors' junctions come first in the device-function table;
        // the diodes' follow.
        let Some(ci) = ci.filter(|ci| ci.diode as usize >= c.junctions.len()) else {
            continue;
        };
        let p = &tape.diodes[ci.diode as usize];
        if !(p.is > 0.0 && p.vte > 0.0) {
            continue;
        }
        let q = p.charge(p.vcrit())[0];
        if q.is_finite() {
            y[k] = q;
            any = true;
        }
    }
    any.then_some(y)
}

/// The states with every BJT's base-emitter junction at its critical voltage
/// `vt ln(vt / (√2 IS))` (ngspice's first iterate) and every other junction
/// at 0 V: each junction charge from its law. `None` without transistors.
fn transistors_on(sorted: &Sorted, states: &[VarId]) -> Option<Vec<f64>> {
    let c = &sorted.elaborated.circuit;
    let sys = &sorted.built.system;
    let mut vals = vec![0.0; sys.vars.len()];
    let mut any = false;
    for (id, e) in c.elements.iter() {
        let Some(device) = e.name.strip_suffix(":be") else {
            continue;
        };
        if !matches!(e.kind, ElementKind::DeviceBranch { .. }) {
            continue;
        }
        let Some(p) = c.junctions.iter().find(|j| {
            j.name.len() == device.len() + 3
                && j.name.starts_with(device)
                && j.name.ends_with(".be")
                && j.is > 0.0
        }) else {
            continue;
        };
        let Some(ev) = sorted.built.elem_vars.get(id.0 as usize).copied().flatten() else {
            continue;
        };
        vals[ev.u.0 as usize] = p.vcrit();
        any = true;
    }
    if !any {
        return None;
    }
    // Each charge state from its law `q = Q(…)` at those voltages.
    let law: HashMap<VarId, crate::ir::ExprId> = sys
        .eqs
        .values()
        .filter_map(|eq| match sys.exprs.get(eq.lhs) {
            crate::ir::Expr::Var(v) if sys.vars[v].kind == crate::ir::VarKind::Charge => {
                Some((v, eq.rhs))
            }
            _ => None,
        })
        .collect();
    Some(
        states
            .iter()
            .map(|s| match law.get(s) {
                Some(&q) => crate::back::interp::eval(sys, &sys.exprs, q, &vals, 0.0),
                None => 0.0,
            })
            .collect(),
    )
}

/// Whether the DC solve may fall back on pseudo-transient continuation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Continuation {
    Allowed,
    /// Not where a node has no DC path to ground: the circuit has no unique
    /// operating point, and the DC solve says so rather than pick one.
    NoDcPath,
}

impl Continuation {
    pub(super) fn of(c: &Circuit) -> Continuation {
        match floating_islands(c).is_empty() {
            true => Continuation::Allowed,
            false => Continuation::NoDcPath,
        }
    }
}

/// For each node, a representative of the nodes that the elements `joins`
/// selects connect it to (union-find with path halving).
pub(super) fn node_components(c: &Circuit, joins: impl Fn(&ElementKind) -> bool) -> Vec<usize> {
    let mut sets = UnionFind::new(c.nodes.len());
    for e in c.elements.values() {
        if e.nodes.len() >= 2 && joins(&e.kind) {
            sets.union(e.nodes[0].0 as usize, e.nodes[1].0 as usize);
        }
    }
    sets.representatives()
}

/// The nodes with no DC path to ground (joined to the rest only through
/// capacitors and current sources), in islands, each with the elements that
/// touch it.
pub(super) fn floating_islands(c: &Circuit) -> Vec<(Vec<crate::elab::NodeId>, Vec<String>)> {
    let root = node_components(c, |k| {
        matches!(
            k,
            ElementKind::Resistor { .. }
                | ElementKind::Inductor { .. }
                | ElementKind::VSource { .. }
                | ElementKind::Diode { .. }
                | ElementKind::DeviceBranch {
                    controlled: false,
                    current: Some(_),
                    ..
                }
                | ElementKind::Vcvs { .. }
                | ElementKind::Ccvs { .. }
                | ElementKind::Behavioural { current: false, .. }
        )
    });
    let ground = root[GROUND.0 as usize];
    // Islands in order of their first node; each node's island by its root.
    let mut index: HashMap<usize, usize> = HashMap::new();
    let mut islands: Vec<(Vec<crate::elab::NodeId>, Vec<String>)> = Vec::new();
    for id in c.nodes.ids() {
        let r = root[id.0 as usize];
        if r == ground {
            continue;
        }
        let k = *index.entry(r).or_insert_with(|| {
            islands.push((Vec::new(), Vec::new()));
            islands.len() - 1
        });
        islands[k].0.push(id);
    }
    for e in c.elements.values() {
        let n = e.nodes.len().min(2);
        let mut of: Vec<usize> = e.nodes[..n]
            .iter()
            .filter_map(|x| index.get(&root[x.0 as usize]).copied())
            .collect();
        of.dedup();
        for k in of {
            islands[k].1.push(e.name.to_string());
        }
    }
    islands
}

/// A singular DC Jacobian explained by the nodes that have no DC path.
pub(super) fn name_dc_failure(c: &Circuit, e: SimError) -> SimError {
    match &e {
        SimError::DcSingular { .. } => {
            let islands = floating_islands(c);
            if islands.is_empty() {
                return e;
            }
            let islands = islands
                .into_iter()
                .take(3)
                .map(|(nodes, elems)| {
                    let names = nodes.iter().map(|&n| c.nodes[n].name.to_string()).collect();
                    (names, elems)
                })
                .collect();
            SimError::DcFailed {
                reason: DcFailure::NoDcPath { islands },
            }
        }
        _ => e,
    }
}

/// A MOSFET as the operating point's Newton limits it: the registers of its
/// frame's intermediates (`M1:vds`, the gate over the source end `M1:vg`,
/// the threshold `M1:von`, all in the device's polarity).
#[derive(Clone, Copy, Debug)]
pub(super) struct Fet {
    vds: tape::Reg,
    vg: tape::Reg,
    von: tape::Reg,
}

/// A MOSFET's voltages as ngspice limits them, at one evaluation.
#[derive(Clone, Copy, Debug, Default)]
struct FetVolts {
    vgs: f64,
    vgd: f64,
    vds: f64,
    von: f64,
}

impl Fet {
    /// Its voltages as the last evaluation left them.
    fn read<M: Matrix<T = f64>>(&self, ode: &CircuitOde<M>) -> FetVolts
    where
        M::V: HostVec,
    {
        let (vds, vg) = (ode.reg_value(self.vds), ode.reg_value(self.vg));
        // `vg` is over whichever end is the source: the drain when vds < 0.
        let (vgs, vgd) = if vds >= 0.0 {
            (vg, vg - vds)
        } else {
            (vg + vds, vg)
        };
        FetVolts {
            vgs,
            vgd,
            vds,
            von: ode.reg_value(self.von),
        }
    }
}

impl FetVolts {
    /// Whether ngspice's limiting leaves the step from `self` to `new` as it
    /// is: DEVfetlim on the gate over the source end (the drain in reverse),
    /// about the threshold, and DEVlimvds on the drain.
    fn allows(&self, new: &FetVolts) -> bool {
        use crate::ir::{fet_limit, vds_limit};
        if !(new.vgs.is_finite() && new.vds.is_finite()) {
            return false;
        }
        if self.vds >= 0.0 {
            fet_limit(new.vgs, self.vgs, self.von) == new.vgs
                && vds_limit(new.vds, self.vds) == new.vds
        } else {
            fet_limit(new.vgd, self.vgd, self.von) == new.vgd
                && vds_limit(-new.vds, -self.vds) == -new.vds
        }
    }
}

/// The MOSFETs of `sorted` whose frame `tape` computes in `f`.
pub(super) fn fets(sorted: &Sorted, tape: &Tape) -> Vec<Fet> {
    let sys = sorted.system();
    let by_name: HashMap<&str, VarId> = sys
        .vars
        .iter()
        .map(|(id, _)| (sys.var_name(id), id))
        .filter(|(n, _)| n.ends_with(":von") || n.ends_with(":vds") || n.ends_with(":vg"))
        .collect();
    if by_name.is_empty() {
        return Vec::new();
    }
    let reg = |device: &str, tag: &str| {
        by_name
            .get(format!("{device}:{tag}").as_str())
            .and_then(|&v| tape.reg_of(v))
    };
    let mos = crate::front::ast::ElementLetter::M;
    sorted
        .elaborated
        .circuit
        .elements
        .values()
        .filter(|e| matches!(e.kind, ElementKind::Intermediate { device, .. } if device == mos))
        .filter_map(|e| e.name.strip_suffix(":von"))
        .filter_map(|device| {
            Some(Fet {
                vds: reg(device, "vds")?,
                vg: reg(device, "vg")?,
                von: reg(device, "von")?,
            })
        })
        .collect()
}

/// The factor on capacitance floors while the operating point is solved:
/// MOSFET gate capacitances floored at [`crate::elab::MEYER_FLOOR`] of the
/// oxide's are raised to 1e-2 of it, which leaves the operating point as it
/// is and the Jacobian's rounding well away from cancelling junction
/// conductances (see [`crate::ir::EquationSystem::add_floor_param`]).
const DC_FLOOR_FACTOR: f64 = 1e-2 / crate::elab::MEYER_FLOOR;

/// The operating point's settings for as long as it lives (floors raised,
/// work limited): floors back at 1 and no limit when it drops, on every
/// return of the solve.
struct DcScope<'a, M: Matrix<T = f64>>(&'a CircuitOde<M>)
where
    M::V: HostVec;

impl<M: Matrix<T = f64>> Drop for DcScope<'_, M>
where
    M::V: HostVec,
{
    fn drop(&mut self) {
        self.0.set_floor_factor(1.0);
        self.0.tape.limit_work(u64::MAX);
    }
}

/// The operating point's whole work, in tape instructions, shared by every
/// start it is tried from: a circuit whose blocks cost much per evaluation
/// (a 700-equation block Newton in every `f`) ends its DC solve with a
/// diagnostic, not after minutes of GMIN and source stepping. Measured on
/// CircuitSim90's MOS decks, a DC solve runs about 1.2·10^8 instructions a
/// second (the sparse factorizations in between are not counted), so this
/// is about a minute and a half: the slowest operating point found in the
/// corpus (the 32-bit adder fadd32's) takes 9.5·10^9.
pub const DC_MAX_WORK: u64 = 12_000_000_000;

/// The operating point's wall-clock limit beside [`DC_MAX_WORK`]: an
/// instruction of junction functions costs far more than one of
/// arithmetic, and a bridge rectifier driven at 1.8e19 V (a fuzz finding)
/// ran 2.5·10^7 instructions a second, which would have made the work
/// limit eight minutes.
pub const DC_MAX_TIME: std::time::Duration = std::time::Duration::from_secs(90);

/// The operating point's work limit: `limit` instructions, spent when the
/// tape's count reaches `deadline`, or the time `wall`, whichever comes
/// first.
#[derive(Clone, Copy, Debug)]
pub(super) struct DcWork {
    pub deadline: u64,
    pub limit: u64,
    pub wall: std::time::Instant,
    /// Continuation, GMIN and source stepping after a failed Newton (else
    /// Newton alone).
    pub stepping: bool,
}

impl DcWork {
    /// From now: `limit` instructions, until `wall` (else [`DC_MAX_TIME`]
    /// from now).
    pub(super) fn from_now(tape: &Tape, limit: u64, wall: Option<std::time::Instant>) -> DcWork {
        DcWork {
            deadline: tape.work().saturating_add(limit),
            limit,
            wall: wall.unwrap_or_else(|| std::time::Instant::now() + DC_MAX_TIME),
            stepping: true,
        }
    }
}

/// DC operating point by damped Newton on f(t0, y) = 0 in DC mode, with the
/// states that `.ic` fixes held: the sparse LU of the coloured Jacobian above
/// `DENSE_STATES` states, else a dense solve. Junctions and MOSFETs take
/// limited steps (as ngspice limits them); when Newton still fails, the
/// sources are ramped up from zero (source stepping). Capacitance floors
/// are raised meanwhile ([`DC_FLOOR_FACTOR`]).
pub(super) fn dc_point<M: Matrix<T = f64>>(
    ode: &CircuitOde<M>,
    t0: f64,
    y: Vec<f64>,
    atol: &[f64],
    ptc: Continuation,
    fets: &[Fet],
    work: DcWork,
) -> Result<Found, SimError>
where
    M::V: HostVec,
{
    ode.set_floor_factor(DC_FLOOR_FACTOR);
    let _scope = DcScope(ode);
    use diffsol::{OdeEquations, Op};
    let n = y.len();
    let tape = &ode.tape;
    tape.limit_work(work.deadline);
    let out_of_work = || SimError::DcFailed {
        reason: DcFailure::WorkLimit {
            work: work.limit,
            state: None,
            at: None,
        },
    };
    let outs = std::cell::RefCell::new(vec![0.0; if n == 0 { tape.out_regs.len() } else { 0 }]);
    let resid = |y: &[f64], f: &mut Vec<f64>| -> Result<f64, SimError> {
        if tape.over_budget() {
            return Err(out_of_work());
        }
        if std::time::Instant::now() > work.wall {
            // Spent: every block and stage after this sees the budget gone.
            tape.limit_work(0);
            return Err(out_of_work());
        }
        ode.eval(t0, y, f)
            .map_err(|error| SimError::Eval { error })?;
        if n == 0 {
            // No states (the DC image with algebraic charges): its
            // algebraic loops, which only the outputs read, are the
            // operating point, solved here so that every stage below
            // (GMIN and source stepping) solves them from the last.
            ode.outputs(t0, y, &mut outs.borrow_mut())
                .map_err(|error| SimError::Eval { error })?;
        }
        Ok(f.iter().map(|x| x.abs()).fold(0.0, f64::max))
    };
    // The junction of each charge state (one pass over the tape, not a
    // search per state), and its voltage at the last iterate.
    let junction: Vec<Option<&crate::ir::DiodeParams>> = tape
        .charge_states()
        .into_iter()
        .map(|ci| ci.map(|ci| &tape.diodes[ci.diode as usize]))
        .collect();
    let mut volts: Vec<f64> = vec![0.0; n];
    let (mut before, mut after) = (Vec::new(), Vec::new());
    let mut trial = vec![0.0; n];
    let mut scratch = vec![0.0; n];
    // Circuits without a junction inside a block (an RC ladder) skip the
    // junction test and its evaluations.
    let junction_tears = tape.blocks.iter().any(|b| !b.junctions.is_empty());
    let (mut fets_before, mut fets_after) = (vec![FetVolts::default(); fets.len()], Vec::new());
    let mut limit = |y: &[f64], step: &mut [f64]| -> bool {
        // Junctions inside the blocks (a diode driven through its series
        // resistance by a node the states set) and MOSFETs: the step is
        // halved until no junction moves further than ngspice's limiting
        // lets it, from its voltage at `y`, and no MOSFET's gate or drain
        // further than ngspice's FET limiting does. A step that moves a
        // reverse-biased junction by 10^14 V (the first step from 0 V of a
        // zener driven by a current source, whose conductance there is GMIN)
        // would leave every later iterate beyond what the exponential can
        // represent; steps that turn every stage of a chain of 50 inverters
        // from off to far on at once overshoot their square laws, and
        // damping alone stalls. One factor for the whole step keeps Newton's
        // direction, which limiting each gate-voltage state on its own
        // (ngspice limits each device) would not.
        let mut shortened = false;
        before.clear();
        if (junction_tears || !fets.is_empty()) && resid(y, &mut scratch).is_ok() {
            ode.junction_voltages(&mut before);
            for (b, f) in fets_before.iter_mut().zip(fets) {
                *b = f.read(ode);
            }
        }
        if !before.is_empty() || !fets.is_empty() {
            let mut lambda = 1.0f64;
            for _ in 0..60 {
                for k in 0..n {
                    trial[k] = y[k] - lambda * step[k];
                }
                let within = resid(&trial, &mut scratch).is_ok_and(|r| r.is_finite()) && {
                    ode.junction_voltages(&mut after);
                    fets_after.clear();
                    fets_after.extend(fets.iter().map(|f| f.read(ode)));
                    after.len() == before.len()
                        && before
                            .iter()
                            .zip(&after)
                            .all(|(&(old, vt, bv), &(new, ..))| {
                                vt <= 0.0
                                    || crate::ir::junction_limit(new, old, vt, 12.0 * vt, bv) == new
                            })
                        && fets_before
                            .iter()
                            .zip(&fets_after)
                            .all(|(old, new)| old.allows(new))
                };
                if within {
                    break;
                }
                lambda *= 0.5;
            }
            if lambda < 1.0 {
                for s in step.iter_mut() {
                    *s *= lambda;
                }
                shortened = true;
            }
        }
        let mut limited = shortened;
        for k in 0..n {
            let Some(p) = junction[k] else { continue };
            let Some(old) = p.voltage_at_charge(y[k], volts[k]) else {
                continue;
            };
            volts[k] = old;
            let Some(new) = p.voltage_at_charge(y[k] - step[k], old) else {
                continue;
            };
            let v = p.limit(new, old);
            if v != new {
                step[k] = y[k] - p.charge(v)[0];
                limited = true;
            }
        }
        limited
    };
    let singular = || SimError::DcSingular {
        point: None,
        at: None,
    };
    let mut jacobian: Box<JacobianAt<'_>> = if n > DENSE_STATES {
        // The coloured sparse Jacobian.
        use diffsol::NonLinearOpJacobian;
        // Made at the first Jacobian: a Newton that starts at its solution
        // (a circuit at rest at t = 0) needs none, and on a 10^5-section
        // ladder the matrix and its pattern's copy were the run's peak.
        let mut jm: Option<M> = None;
        Box::new(move |y: &[f64], shift: f64| {
            if tape.over_budget() {
                return Err(out_of_work());
            }
            let jm = jm.get_or_insert_with(|| {
                let sparsity = ode.rhs().jacobian_sparsity();
                M::new_from_sparsity(n, n, sparsity, ode.context().clone())
            });
            let mut entries = sparse_jacobian(ode, t0, y, jm)?;
            if shift != 0.0 {
                entries.extend((0..n).map(|k| (k, k, -shift)));
            }
            TripletLu::new(n, entries)
                .map(Factored::Sparse)
                .ok_or_else(singular)
        })
    } else {
        let (mut cols, mut fy) = (vec![0.0; n * n], vec![0.0; n]);
        let all: Vec<usize> = (0..n).collect();
        Box::new(move |y: &[f64], shift: f64| {
            if tape.over_budget() {
                return Err(out_of_work());
            }
            ode.jacobian_columns(Regs::Solver, t0, y, &all, &mut cols, &mut fy)
                .map_err(|error| SimError::Eval { error })?;
            for k in 0..n {
                cols[k * n + k] -= shift;
            }
            match cols.iter().all(|v| v.is_finite()) {
                true => DenseLu::new(n, cols.clone())
                    .map(Factored::Dense)
                    .ok_or_else(singular),
                false => Err(singular()),
            }
        })
    };
    let solve = &mut *jacobian;
    let y0 = y.clone();
    let mut rough: Rough = None;
    let first = if direct_dc() {
        dc_newton(y.clone(), &resid, solve, &mut limit, atol, &mut rough)
    } else {
        Err(SimError::DcFailed {
            reason: DcFailure::NotTried,
        })
    };
    let Err(error) = first else {
        return first.map(Found::exact);
    };
    if !work.stepping {
        return match rough {
            Some((_, y)) => Ok(Found { y, rough: true }),
            None => Err(error),
        };
    }
    // Pseudo-transient continuation: the circuit itself, its sources held at
    // their values at t0, integrated towards its equilibrium. Not where a
    // node has no DC path: it has no operating point, and the integration
    // would only pick one of many.
    if ptc == Continuation::Allowed && n > 0 {
        // Its work is bounded in instructions run, PTC_WORK evaluations of f
        // at its start: a step whose blocks take long Newton solves at far
        // points gives up rather than run on.
        let before = tape.work();
        let mut scratch = vec![0.0; n];
        let _ = resid(&y0, &mut scratch);
        let per_eval = (tape.work() - before).max(1);
        tape.limit_work(
            tape.work()
                .saturating_add(PTC_WORK.saturating_mul(per_eval).min(PTC_MAX_WORK))
                .min(work.deadline),
        );
        let found = pseudo_transient(
            y0.clone(),
            &resid,
            solve,
            &mut limit,
            atol,
            &mut rough,
            tape,
        );
        tape.limit_work(work.deadline);
        if let Ok(found) = found {
            return Ok(Found::exact(found));
        }
    }
    // The blocks start the next solves from their first guesses, not from
    // where the integration left them.
    ode.reset_tears();
    // GMIN stepping (as SPICE steps it): a conductance across every junction
    // with GMIN, large enough that the circuit is nearly linear, stepped down
    // to none, each solution the start of the next; a failed stage is retried
    // with a smaller step down. Transistor circuits whose nodes only
    // junctions join (a 555's cut-off stages) converge this way.
    if tape.diodes.iter().any(|d| d.gmin > 0.0) {
        let stepped = (|| {
            let mut g = 1e-2f64;
            ode.set_gmin_step(g);
            let mut at = dc_newton(y.clone(), &resid, solve, &mut limit, atol, &mut None)?;
            let mut factor = 10.0f64;
            loop {
                let next = if g / factor < 1e-13 { 0.0 } else { g / factor };
                ode.set_gmin_step(next);
                // Only the last stage is the circuit itself.
                let stage_rough = if next == 0.0 { &mut rough } else { &mut None };
                match dc_newton(at.clone(), &resid, solve, &mut limit, atol, stage_rough) {
                    Ok(found) => {
                        at = found;
                        if next == 0.0 {
                            return Ok(at);
                        }
                        g = next;
                        factor = (factor * factor).min(10.0);
                    }
                    Err(_) if factor > 1.05 => factor = factor.sqrt(),
                    Err(e) => return Err(e),
                }
            }
        })();
        ode.set_gmin_step(0.0);
        if let Ok(found) = stepped {
            return Ok(Found::exact(found));
        }
    }
    // Source stepping: from all sources off (where y = 0 solves a circuit
    // without sources) up to their full values, each solution the start of
    // the next; a failed stage is retried with a quarter of the increment.
    let mut at = 0.0f64;
    let mut y = y;
    let mut inc = 0.1f64;
    ode.scale_sources(0.0);
    let result = (|| {
        y = dc_newton(y.clone(), &resid, solve, &mut limit, atol, &mut None)?;
        while at < 1.0 {
            let next = (at + inc).min(1.0);
            ode.scale_sources(next);
            let stage_rough = if next == 1.0 { &mut rough } else { &mut None };
            match dc_newton(y.clone(), &resid, solve, &mut limit, atol, stage_rough) {
                Ok(found) => {
                    y = found;
                    at = next;
                    inc = (inc * 2.0).min(0.25);
                }
                Err(_) if inc > 1e-4 => inc *= 0.25,
                Err(e) => return Err(e),
            }
        }
        Ok(y.clone())
    })();
    ode.scale_sources(1.0);
    if result.is_ok() {
        return result.map(Found::exact);
    }
    // A point where Newton stalled with its correction within ngspice's
    // convergence tolerances, where nothing converged further.
    if let Some((_, y)) = rough {
        return Ok(Found { y, rough: true });
    }
    if tape.over_budget() {
        // With where the direct attempt's residual was largest.
        let state = match &error {
            SimError::DcFailed {
                reason: DcFailure::Stalled { state, .. } | DcFailure::NoConvergence { state, .. },
            } => *state,
            _ => None,
        };
        return Err(SimError::DcFailed {
            reason: DcFailure::WorkLimit {
                work: work.limit,
                state,
                at: None,
            },
        });
    }
    // Report the direct attempt's failure, which names what went wrong at
    // the full sources.
    Err(error)
}

/// An operating point of [`dc_point`].
pub(super) struct Found {
    pub(super) y: Vec<f64>,
    /// Where Newton stalled within [`ROUGH`] and nothing converged
    /// further: accepted, but the DC image may find a solution.
    pub(super) rough: bool,
}

impl Found {
    fn exact(y: Vec<f64>) -> Found {
        Found { y, rough: false }
    }
}

/// Pseudo-transient continuation (Kelley and Keyes, "Convergence analysis of
/// pseudo-transient continuation", SIAM J. Numer. Anal. 35, 1998): backward
/// Euler steps of the circuit's own `y' = f(y)`, its sources held at their
/// values at t0, from `y` towards the equilibrium its transient reaches.
/// Accuracy along the way does not matter, only that each step's implicit
/// equation `f(x) − (x − y)/h = 0` is solved: by Newton on the matrix
/// `J − I/h` factored at the step's start (and once more if that stalls),
/// junction steps limited; the step grows fourfold after a quick solve and
/// twofold after a slower one, and a failed solve is retried at a quarter of
/// it. Once the step is long beside the rate at which the states still move,
/// [`dc_newton`] finishes from there.
///
/// This finds operating points that Newton, GMIN and source stepping miss
/// where the equilibrium is stable (a bipolar op-amp's bias network, whose
/// Newton iterates wander among the junctions' exponentials); it cannot find
/// an unstable one (an oscillator's), which the others may.
pub(super) fn pseudo_transient(
    mut y: Vec<f64>,
    resid: &Residual<'_>,
    jacobian: &mut JacobianAt<'_>,
    limit: &mut dyn FnMut(&[f64], &mut [f64]) -> bool,
    atol: &[f64],
    rough: &mut Rough,
    tape: &crate::tape::Tape,
) -> Result<Vec<f64>, SimError> {
    let n = y.len();
    // Sizes relative to each state's own scale: `|y| + 10^6 atol`.
    let scale = |k: usize, y: &[f64]| y[k].abs() + 1e6 * atol[k];
    // The root-mean-square rate of change of the states relative to their
    // scales (1/s): a maximum would let one reverse-biased junction's
    // femtocoulomb charge, moving at rounding level, stand for the circuit.
    let rate = |f: &[f64], y: &[f64]| {
        ((0..n).map(|k| (f[k] / scale(k, y)).powi(2)).sum::<f64>() / n as f64).sqrt()
    };
    let size = |d: &[f64], y: &[f64]| (0..n).map(|k| d[k].abs() / scale(k, y)).fold(0.0, f64::max);
    let mut f = vec![0.0; n];
    let mut x = vec![0.0; n];
    let mut g = vec![0.0; n];
    resid(&y, &mut f)?;
    let mut r = rate(&f, &y);
    let mut h = 1e-9f64;
    // The rate where Newton was last tried: it is tried again from a point
    // whose rate is ten times lower.
    let mut newton_rate = f64::INFINITY;
    // Evaluations of f in the steps' solves, against PTC_EVALS.
    let mut evals = 0usize;
    for _ in 0..PTC_STEPS {
        if (h * r < 1e-3 || h > 1e6) && r < 0.1 * newton_rate {
            newton_rate = r;
            if let Ok(found) = dc_newton(y.clone(), resid, jacobian, limit, atol, rough) {
                return Ok(found);
            }
        }
        if !(1e-18..=1e12).contains(&h) || evals > PTC_EVALS || tape.over_budget() {
            break;
        }
        // One backward-Euler step of length h, from y.
        x.copy_from_slice(&y);
        let mut solved = None;
        'refactor: for _ in 0..3 {
            let Ok(jac) = jacobian(&x, 1.0 / h) else {
                break;
            };
            let mut last = f64::INFINITY;
            for iteration in 1..=10 {
                evals += 1;
                if !resid(&x, &mut g).is_ok_and(|norm| norm.is_finite()) {
                    break 'refactor;
                }
                for k in 0..n {
                    g[k] -= (x[k] - y[k]) / h;
                }
                let Some(mut d) = jac.solve(&g) else {
                    break 'refactor;
                };
                limit(&x, &mut d);
                for k in 0..n {
                    x[k] -= d[k];
                }
                let moved = size(&d, &x);
                if moved <= 1e-3 {
                    solved = Some(iteration);
                    break 'refactor;
                }
                if moved > 0.5 * last {
                    // Not converging on this matrix: factor it anew here.
                    continue 'refactor;
                }
                last = moved;
            }
        }
        let Some(iterations) = solved else {
            h *= 0.25;
            continue;
        };
        if !resid(&x, &mut f).is_ok_and(|norm| norm.is_finite()) {
            h *= 0.25;
            continue;
        }
        // A step whose Newton ran off to a far point (its correction small
        // only beside states grown by 10^12) leaves the states moving at a
        // rate orders of magnitude above the one it started from: a
        // spurious solution of the step's equation, not the circuit settling.
        let next = rate(&f, &x);
        if !(next.is_finite() && (r == 0.0 || next <= RATE_JUMP * r)) {
            h *= 0.25;
            continue;
        }
        std::mem::swap(&mut y, &mut x);
        r = next;
        h *= match iterations {
            ..=3 => 4.0,
            4..=6 => 2.0,
            _ => 1.0,
        };
    }
    if r < newton_rate
        && let Ok(found) = dc_newton(y, resid, jacobian, limit, atol, rough)
    {
        return Ok(found);
    }
    // Where Newton stalled on rounding near the equilibrium the integration
    // reached, `rough` holds that point: GMIN and source stepping may still
    // converge fully (a stall can be a region boundary of a MOSFET's
    // equations, not rounding), and it is the answer where they do not.
    Err(SimError::DcFailed {
        reason: DcFailure::NotTried,
    })
}

/// The best point where a Newton iteration stalled with a correction below
/// [`ROUGH`] (its size, and the point).
pub(super) type Rough = Option<(f64, Vec<f64>)>;

/// A correction this small (relative to `|y| + 10^7 atol`, so below
/// 10^-6 V + 10^-4 |v| on node voltages: ngspice's VNTOL, and a tenth of its
/// RELTOL) is a solution where Newton stalls on rounding in `f` and nothing
/// converges further.
const ROUGH: f64 = 1e-4;

/// The most pseudo-transient steps, and evaluations of `f` in their solves,
/// before the DC solve moves on: a circuit whose blocks cost much per
/// evaluation (a bipolar IC's) ends its DC solve in tens of seconds at most.
const PTC_STEPS: usize = 3000;
/// The most a continuation step may raise the states' rate of change.
const RATE_JUMP: f64 = 1e3;
const PTC_EVALS: usize = 10_000;
/// The continuation's work, in evaluations of `f` at its start, and at most
/// this many tape instructions in all (about eight seconds, see
/// [`DC_MAX_WORK`]): a large circuit's failing continuation must not hold
/// up GMIN and source stepping.
const PTC_WORK: u64 = 100_000;
const PTC_MAX_WORK: u64 = 1_000_000_000;

/// `f` into its argument, returning its max-norm.
pub(super) type Residual<'a> = dyn Fn(&[f64], &mut Vec<f64>) -> Result<f64, SimError> + 'a;

/// Whether the DC solve tries Newton at the full sources first (tests can
/// send it straight to source stepping).
#[cfg(not(test))]
pub(super) fn direct_dc() -> bool {
    true
}

#[cfg(test)]
pub(super) fn direct_dc() -> bool {
    !tests::SOURCES_ONLY.with(|c| c.get())
}

/// Whether the operating point skips Newton on the states and goes
/// straight to the DC image (tests compare the two).
#[cfg(not(test))]
fn image_only() -> bool {
    false
}

#[cfg(test)]
fn image_only() -> bool {
    tests::IMAGE_ONLY.with(|c| c.get())
}

/// Whether the operating point tries the DC image with algebraic charges
/// (tests compare it with the image with charge states).
#[cfg(not(test))]
fn algebraic_image() -> bool {
    true
}

#[cfg(test)]
fn algebraic_image() -> bool {
    !tests::CHARGED_IMAGE.with(|c| c.get())
}

/// The factored DC Jacobian at a point.
/// Rows of held states are identity rows.
/// With a `shift` s it factors `J − s·I` (pseudo-transient continuation's
/// backward-Euler matrix for a pseudo-time step 1/s); Newton passes 0.
pub(super) type JacobianAt<'a> = dyn FnMut(&[f64], f64) -> Result<Factored, SimError> + 'a;

/// Damped Newton from `y` (Deuflhard's natural monotonicity test, which
/// compares corrections in the states' own units rather than residuals of
/// mixed units): `jacobian(y)` is factored once per iteration, `limit`
/// shortens junction steps (a limited step is taken whole, as SPICE takes
/// it). Converged when a correction is below 1e-10 relative and 1e-3 of
/// the integration's absolute tolerances, or `f` vanishes; or when no damped
/// step improves a correction already below 1e-7 of that scale with `f`
/// below 1e-12 (rounding).
pub(super) fn dc_newton(
    mut y: Vec<f64>,
    resid: &Residual<'_>,
    jacobian: &mut JacobianAt<'_>,
    limit: &mut dyn FnMut(&[f64], &mut [f64]) -> bool,
    atol: &[f64],
    rough: &mut Rough,
) -> Result<Vec<f64>, SimError> {
    let n = y.len();
    let mut f = vec![0.0; n];
    let mut norm = resid(&y, &mut f)?;
    if norm == 0.0 {
        return Ok(y);
    }
    let singular = |y: &[f64]| SimError::DcSingular {
        point: Some(std::rc::Rc::new(y.to_vec())),
        at: None,
    };
    // Corrections measured against |y| + 1e7 atol: 1e-10 of it converges.
    let scaled = |d: &[f64], y: &[f64]| newton::scaled_norm(d, |k| y[k].abs() + 1e7 * atol[k]);
    let mut trial = vec![0.0; n];
    let mut ft = vec![0.0; n];
    for _ in 0..200 {
        let jac = match jacobian(&y, 0.0) {
            Err(SimError::DcSingular { .. }) => return Err(singular(&y)),
            other => other?,
        };
        let mut step = jac.solve(&f).ok_or_else(|| singular(&y))?;
        let full = scaled(&step, &y);
        if full <= 1e-10 || norm <= 1e-15 {
            for k in 0..n {
                y[k] -= step[k];
            }
            return Ok(y);
        }
        if limit(&y, &mut step) {
            for k in 0..n {
                y[k] -= step[k];
            }
            norm = resid(&y, &mut f)?;
            continue;
        }
        let damping = newton::damp(full, |lambda| {
            for k in 0..n {
                trial[k] = y[k] - lambda * step[k];
            }
            // A trial point where the circuit cannot be evaluated (a loop
            // without solution that far out) is too far: halve the step.
            Ok::<_, SimError>(match resid(&trial, &mut ft) {
                Ok(nn) if nn.is_finite() => {
                    jac.solve(&ft).map_or(f64::INFINITY, |b| scaled(&b, &y))
                }
                _ => f64::INFINITY,
            })
        })?;
        if damping == Damping::Stalled {
            // No step along the correction is better: rounding, not the
            // circuit, sets the corrections now. When they are already within
            // 1e-7 of the integration's scale and f is at the level of
            // ngspice's ABSTOL (1 pA), this is the operating point; with a
            // larger f it is not, as a charge's correction reaches its
            // current amplified by 1/(C·RS) (source stepping goes on).
            if full <= 1e-9 || (full <= 1e-7 && norm <= 1e-12) {
                return Ok(y);
            }
            if full <= ROUGH && rough.as_ref().is_none_or(|(best, _)| full < *best) {
                *rough = Some((full, y.clone()));
            }
            return Err(SimError::DcFailed {
                reason: DcFailure::Stalled {
                    residual: norm,
                    state: largest(&f),
                    at: None,
                },
            });
        }
        std::mem::swap(&mut y, &mut trial);
        std::mem::swap(&mut f, &mut ft);
        norm = f.iter().map(|x| x.abs()).fold(0.0, f64::max);
    }
    Err(SimError::DcFailed {
        reason: DcFailure::NoConvergence {
            residual: norm,
            state: largest(&f),
            at: None,
        },
    })
}

/// Up to this many states a singular DC Jacobian's diagnostic finds the
/// state it depends least on by finite differences (one evaluation of `f`
/// per state); above, from the coloured sparse Jacobian.
const WEAKEST_STATES: usize = 500;

/// The state the DC Jacobian at `y` depends least on: the smallest of its
/// columns' largest entries in units of the tolerances. Evaluated once the
/// operating point has failed for good (the evaluations move the blocks'
/// warm starts).
fn weakest_state<M>(ode: &CircuitOde<M>, t0: f64, y: &[f64], atol: &[f64]) -> Option<usize>
where
    M: Matrix<T = f64>,
    M::V: HostVec,
{
    let n = y.len();
    if atol.len() != n {
        return None;
    }
    if n > WEAKEST_STATES {
        return weakest_column(ode, t0, y, atol);
    }
    let (mut f, mut ft, mut trial) = (vec![0.0; n], vec![0.0; n], y.to_vec());
    ode.eval(t0, y, &mut f).ok()?;
    let mut best: Option<(usize, f64)> = None;
    for k in 0..n {
        let h = 1e-7 * (y[k].abs() + 1e7 * atol[k]);
        if !(h > 0.0 && h.is_finite()) {
            // A state at 0 whose tolerance underflowed has no scale at all
            // (a transistor of area 1e-308): nothing depends on it less.
            return Some(k);
        }
        trial[k] = y[k] + h;
        let moved = ode.eval(t0, &trial, &mut ft);
        trial[k] = y[k];
        if moved.is_err() {
            // A direction the circuit's loops cannot be solved in says
            // nothing of the others.
            continue;
        }
        let col = (0..n)
            .map(|j| (ft[j] - f[j]).abs() / h * atol[k] / atol[j])
            .fold(0.0, f64::max);
        if col.is_finite() && best.is_none_or(|(_, b)| col < b) {
            best = Some((k, col));
        }
    }
    best.map(|(k, _)| k)
}

/// [`weakest_state`] from the Jacobian's nonzero entries (a circuit past
/// [`WEAKEST_STATES`], whose matrices are sparse: a 10^4-section line with
/// a singular operating point named nothing): a column with no entry at all
/// is the weakest.
fn weakest_column<M>(ode: &CircuitOde<M>, t0: f64, y: &[f64], atol: &[f64]) -> Option<usize>
where
    M: Matrix<T = f64>,
    M::V: HostVec,
{
    use diffsol::{NonLinearOpJacobian, OdeEquations, Op};
    let n = y.len();
    let sparsity = ode.rhs().jacobian_sparsity()?;
    let mut jm = M::new_from_sparsity(n, n, Some(sparsity), ode.context().clone());
    let entries = sparse_jacobian(ode, t0, y, &mut jm).ok()?;
    let mut col = vec![0.0f64; n];
    for (i, j, v) in entries {
        let w = (v * atol[j] / atol[i]).abs();
        if i < n && j < n && w.is_finite() {
            col[j] = col[j].max(w);
        }
    }
    (0..n).min_by(|&a, &b| col[a].total_cmp(&col[b]))
}

/// The coloured sparse Jacobian of `f` at `(t0, y)`, computed into `jm`
/// (a matrix of its pattern), as `(row, column, value)` entries.
fn sparse_jacobian<M>(
    ode: &CircuitOde<M>,
    t0: f64,
    y: &[f64],
    jm: &mut M,
) -> Result<Vec<(usize, usize, f64)>, SimError>
where
    M: Matrix<T = f64>,
    M::V: HostVec,
{
    use diffsol::{NonLinearOpJacobian, OdeEquations, Op, Vector};
    let yv = M::V::from_vec(y.to_vec(), ode.context().clone());
    ode.rhs().jacobian_inplace(&yv, t0, jm);
    if let Some(error) = ode.error.borrow_mut().take() {
        return Err(SimError::Eval { error });
    }
    let (at, vals) = jm.triplet_iter();
    Ok(at.zip(vals).map(|((i, j), v)| (i, j, v)).collect())
}

/// The index of the largest residual.
fn largest(f: &[f64]) -> Option<usize> {
    (0..f.len()).max_by(|&a, &b| f[a].abs().total_cmp(&f[b].abs()))
}

/// A failed Newton on the states with the element whose state has the
/// largest residual named (its branch, or the state's own name where no
/// element owns it).
fn name_state(
    sorted: &Sorted,
    states: &[VarId],
    e: SimError,
    weakest: &dyn Fn(&[f64]) -> Option<usize>,
) -> SimError {
    let name = |k: Option<usize>| {
        let s = *states.get(k?)?;
        let c = &sorted.elaborated.circuit;
        let var = &sorted.system().var_name(s);
        // A junction's charge `q_D1` is no branch variable: its element by
        // the name after the prefix.
        let by_name = || {
            let base = var.split_once('_')?.1;
            c.elements
                .values()
                .find(|e| e.name.eq_ignore_ascii_case(base))
                .map(|e| e.name.clone())
        };
        Some(match element_of_vars(sorted).get(&s) {
            Some(&el) => format!("`{}`", c.elements[el].name),
            None => match by_name() {
                Some(n) => format!("`{n}`"),
                None => format!("the state `{var}`"),
            },
        })
    };
    let reason = match e {
        SimError::DcSingular {
            point: Some(y),
            at: None,
        } => {
            let at = name(weakest(&y));
            return SimError::DcSingular { point: Some(y), at };
        }
        SimError::DcFailed { reason } => reason,
        other => return other,
    };
    let reason = match reason {
        DcFailure::Stalled {
            residual, state, ..
        } => DcFailure::Stalled {
            residual,
            state,
            at: name(state),
        },
        DcFailure::NoConvergence {
            residual, state, ..
        } => DcFailure::NoConvergence {
            residual,
            state,
            at: name(state),
        },
        DcFailure::WorkLimit { work, state, .. } => DcFailure::WorkLimit {
            work,
            state,
            at: name(state),
        },
        other => other,
    };
    SimError::DcFailed { reason }
}
