//! Elaboration: AST → [`Circuit`]. Evaluates `.param` expressions, expands
//! subcircuit instances with hierarchical names (`x1.r2`, node `x1.n2`),
//! resolves models and controlling sources, applies ngspice's source defaults.
//!
//! It knows the netlist AST and the circuit, nothing about equations.

mod behavioural;
mod bjt;
mod circuit;
mod element;
mod error;
mod jfet;
mod model;
mod mos;
mod switch;
pub(crate) mod thermal;
pub mod topology;

use std::collections::{HashMap, HashSet};

use rustc_hash::{FxHashMap, FxHashSet};

pub use circuit::*;
pub use error::ElabError;
pub use model::JUNCTION_CAPACITANCE_FLOOR;
pub(crate) use mos::MEYER_FLOOR;

use crate::diag::Span;
use crate::front::ast::{self, Stmt, Value};

/// Output points of a `.tran` above which it warns (K0295): a 10^8-row CSV
/// is several gigabytes, most likely a TSTEP meant as a step limit.
const MANY_OUTPUT_POINTS: f64 = 1e8;
/// Output points past which `.tran` is refused: 1e10 rows are half a
/// terabyte of CSV, and hours of interpolation before the first byte is read.
const TOO_MANY_OUTPUT_POINTS: f64 = 1e10;
/// A `.tran` TMAX that asks for more steps than this over the run is raised
/// to the run's length over this (a warning says so).
const MAX_TMAX_STEPS: f64 = 1e7;

/// Flatten a parsed netlist into a circuit. Errors and warnings are collected;
/// the circuit holds everything that elaborated.
pub fn elaborate(netlist: &ast::Netlist<'_>) -> (Circuit, Vec<ElabError>) {
    // Sized for a flat netlist (about as many nodes as elements): no rehash
    // while a big circuit fills them.
    let n = netlist.stmts.len();
    let mut e = Elab {
        circuit: Circuit {
            title: netlist.title.to_string(),
            title_span: netlist.title_span,
            elements: crate::ir::IdVec::with_capacity(n),
            nodes: crate::ir::IdVec::with_capacity(n),
            ..Circuit::default()
        },
        errors: Vec::new(),
        node_map: FxHashMap::with_capacity_and_hasher(n, Default::default()),
        elem_map: FxHashMap::with_capacity_and_hasher(n, Default::default()),
        key_buf: String::new(),
        pending: Vec::new(),
        model_cache: HashMap::new(),
        bjt_cache: HashMap::new(),
        jfet_seen: HashSet::new(),
        ports_seen: HashSet::new(),
        passive_models_seen: HashSet::new(),
        mos_cache: HashMap::new(),
        switch_seen: HashSet::new(),
        tstep: 1.0,
        tstop: 1.0,
        globals: FxHashSet::default(),
        n_flattened: 0,
        top_line: Span::default(),
        too_many: false,
        b_controls: Vec::new(),
    };
    e.circuit.nodes.push(Node {
        name: crate::ir::Name::new("0", Some(Span::default())),
        internal: false,
    });
    let mut top = Scope::default();
    e.collect(&netlist.stmts, &mut top);
    predefined_params(&netlist.stmts, &mut top);
    e.params(&netlist.stmts, &mut top);
    e.settings(&netlist.stmts, &top);
    let mut stack = Vec::new();
    e.walk(&netlist.stmts, &top, &mut stack);
    e.resolve_pending();
    e.drop_unused_nodes();
    e.outputs(&netlist.stmts, &top);
    e.dangling();
    (e.circuit, e.errors)
}

/// The parameters ngspice's PSpice mode defines ahead of the netlist's own
/// (`inpcompat.c`): `temp` (°C), `vt` (the thermal voltage at it) and
/// `gmin`. PSpice's libraries use them undefined (TI's TLC555 writes
/// `N={VTOHP/(VT*LOG(1+IO/IS))}`); a `.param` of the same name replaces
/// them. The temperature is a top-level `.options temp=` given as a
/// number, else ngspice's 27 °C.
fn predefined_params(stmts: &[Stmt<'_>], top: &mut Scope<'_, '_>) {
    let temp = stmts
        .iter()
        .filter_map(|s| match s {
            Stmt::Options(opts, _) => Some(opts),
            _ => None,
        })
        .flatten()
        .filter(|o| o.name.is("temp"))
        .find_map(|o| match &o.value {
            ast::OptValue::Value(Value::Num { value, .. }) => Some(*value),
            _ => None,
        })
        .filter(|t| (-273.15..=1000.0).contains(t))
        .unwrap_or(27.0);
    top.params.insert("temp".into(), temp);
    top.params
        .insert("vt".into(), (temp + 273.15) * PSPICE_VT_PER_KELVIN);
    top.params.insert("gmin".into(), 1e-12);
}

/// k/q in V/K as ngspice's PSpice mode writes it into `vt`.
const PSPICE_VT_PER_KELVIN: f64 = 8.6173303e-5;

/// Names visible while expanding one level of the hierarchy.
#[derive(Default)]
struct Scope<'s, 'a> {
    params: HashMap<String, f64>,
    subckts: HashMap<String, &'s ast::Subckt<'a>>,
    models: HashMap<String, &'s ast::Model<'a>>,
    funcs: HashMap<String, &'s ast::FuncDef<'a>>,
    parent: Option<&'s Scope<'s, 'a>>,
    /// Element-name prefix as written (`X1.`), empty at the top level.
    prefix: String,
    /// Formal port name → actual node.
    ports: HashMap<String, NodeId>,
    /// The `m=` of the instance this scope expands, with its span.
    m: Option<(f64, Span)>,
}

impl<'s, 'a> Scope<'s, 'a> {
    /// The product of the `m=` of every enclosing instance, and the span of
    /// the innermost one (`None` when no instance multiplies).
    fn multiplier(&self) -> (f64, Option<Span>) {
        let (outer, span) = self.parent.map_or((1.0, None), |p| p.multiplier());
        match self.m {
            Some((m, s)) => (m * outer, Some(s)),
            None => (outer, span),
        }
    }

    fn param(&self, name: &str) -> Option<f64> {
        self.params
            .get(name)
            .copied()
            .or_else(|| self.parent.and_then(|p| p.param(name)))
    }

    fn func(&self, name: &str) -> Option<&'s ast::FuncDef<'a>> {
        self.funcs
            .get(name)
            .copied()
            .or_else(|| self.parent.and_then(|p| p.func(name)))
    }

    fn subckt(&self, name: &str) -> Option<&'s ast::Subckt<'a>> {
        self.subckts
            .get(name)
            .copied()
            .or_else(|| self.parent.and_then(|p| p.subckt(name)))
    }

    fn model(&self, name: &str) -> Option<&'s ast::Model<'a>> {
        self.models
            .get(name)
            .copied()
            .or_else(|| self.parent.and_then(|p| p.model(name)))
    }
}

enum PendingRef {
    /// The `index`-th controlling source of an F, H (index 0) or B.
    Control {
        vsrc: String,
        index: usize,
    },
    Coupling {
        l1: String,
        l2: String,
    },
}

struct Pending {
    elem: ElemId,
    what: PendingRef,
    spans: [Span; 2],
}

struct Elab {
    circuit: Circuit,
    errors: Vec<ElabError>,
    node_map: FxHashMap<String, NodeId>,
    elem_map: FxHashMap<String, (ElemId, Span)>,
    /// Scratch for case-folded names.
    key_buf: String,
    pending: Vec<Pending>,
    model_cache: HashMap<(u32, u32, String), DiodeModel>,
    /// BJT models by definition and scope (`None`: refused, reported once).
    bjt_cache: HashMap<(u32, u32, String), Option<bjt::BjtModel>>,
    /// JFET model definitions already read (their warnings are given once).
    jfet_seen: HashSet<(u32, u32)>,
    /// Resistor, capacitor and inductor model definitions already read, as `jfet_seen`.
    passive_models_seen: HashSet<(u32, u32)>,
    /// MOS models read, as `bjt_cache`.
    mos_cache: HashMap<(u32, u32, String), Option<mos::MosModel>>,
    /// Switch model definitions already read (their warnings are given once).
    switch_seen: HashSet<(u32, u32)>,
    /// Subcircuit definitions whose repeated ports were reported, as `jfet_seen`.
    ports_seen: HashSet<(u32, u32)>,
    tstep: f64,
    tstop: f64,
    /// `.global` node names (case-folded): top-level nodes in every scope.
    globals: FxHashSet<String>,
    /// Element lines flattened so far (instances not counted), at most
    /// [`MAX_ELEMENTS`]: the count is checked before each one is built.
    n_flattened: usize,
    /// The name of the top-level line being flattened (an instance expands
    /// below it): where the element limit is reported.
    top_line: Span,
    /// Set once the limit is reached: nothing more is flattened.
    too_many: bool,
    /// The controlling sources of the B source being elaborated (keys),
    /// left by [`Elab::behavioural`] for [`Elab::element`].
    b_controls: Vec<String>,
}

impl Elab {
    /// Gather subcircuit and model definitions of one scope (through includes).
    fn collect<'s, 'a>(&mut self, stmts: &'s [Stmt<'a>], scope: &mut Scope<'s, 'a>) {
        for s in stmts {
            match s {
                Stmt::Subckt(sc) => {
                    scope.subckts.entry(sc.name.key()).or_insert(sc);
                }
                Stmt::Model(m) => {
                    scope.models.entry(m.name.key()).or_insert(m);
                }
                Stmt::Include { body, .. } => self.collect(body, scope),
                _ => {}
            }
        }
    }

    /// Evaluate `.param` lines of one scope in order (through includes). A
    /// parameter may use one defined later in the same scope.
    fn params<'s, 'a>(&mut self, stmts: &'s [Stmt<'a>], scope: &mut Scope<'s, 'a>) {
        let mut list = Vec::new();
        fn gather<'s, 'a>(
            stmts: &'s [Stmt<'a>],
            out: &mut Vec<&'s ast::Assign<'a>>,
            funcs: &mut HashMap<String, &'s ast::FuncDef<'a>>,
        ) {
            for s in stmts {
                match s {
                    Stmt::Param(a, _) => out.extend(a.iter()),
                    Stmt::Func(f) => {
                        funcs.insert(f.name.key(), f);
                    }
                    Stmt::Include { body, .. } => gather(body, out, funcs),
                    _ => {}
                }
            }
        }
        gather(stmts, &mut list, &mut scope.funcs);
        let mut left: Vec<&ast::Assign<'_>> = list;
        loop {
            let before = left.len();
            left.retain(|a| match try_value(&a.value, scope) {
                Ok(v) => {
                    scope.params.insert(a.name.key(), v);
                    false
                }
                Err(_) => true,
            });
            if left.is_empty() || left.len() == before {
                break;
            }
        }
        for a in left {
            // Report the real reason now that no more progress is possible.
            self.value(&a.value, scope);
        }
    }

    fn value(&mut self, v: &Value<'_>, scope: &Scope<'_, '_>) -> Option<f64> {
        match try_value(v, scope) {
            Ok(x) => Some(x),
            Err(e) => {
                self.errors.push(e);
                None
            }
        }
    }

    /// `.tran`, `.options`, `.global` of the top level (through includes).
    fn settings(&mut self, stmts: &[Stmt<'_>], scope: &Scope<'_, '_>) {
        for s in stmts {
            match s {
                Stmt::Tran(t) => self.tran(t, scope),
                Stmt::Options(opts, _) => {
                    for o in opts {
                        self.option(o, scope);
                    }
                }
                Stmt::Global(names, _) => {
                    self.globals.extend(
                        names
                            .iter()
                            .map(|n| n.key())
                            .filter(|k| k != "0" && k != "gnd"),
                    );
                }
                Stmt::Include { body, .. } => self.settings(body, scope),
                _ => {}
            }
        }
    }

    /// A `.tran` line: the circuit's transient analysis, and the TSTEP and
    /// TSTOP that source defaults refer to.
    fn tran(&mut self, t: &ast::Tran<'_>, scope: &Scope<'_, '_>) {
        let tstep = self.value(&t.tstep, scope);
        let tstop = self.value(&t.tstop, scope);
        let tstart = match &t.tstart {
            Some(v) => self.value(v, scope),
            None => Some(0.0),
        };
        let tmax = t.tmax.as_ref().and_then(|v| self.value(v, scope));
        let (Some(tstep), Some(tstop), Some(tstart)) = (tstep, tstop, tstart) else {
            return;
        };
        if !(tstep > 0.0 && tstop > tstart && tstart >= 0.0) {
            self.errors.push(ElabError::BadTran { span: t.span });
            return;
        }
        // Each point is a CSV row of ~24 bytes per column
        // (time and at least one vector).
        let points = (tstop - tstart) / tstep + 1.0;
        if points > TOO_MANY_OUTPUT_POINTS {
            self.errors.push(ElabError::TooManyOutputPoints {
                span: t.tstep.span(),
                points,
                limit: TOO_MANY_OUTPUT_POINTS,
            });
        } else if points > MANY_OUTPUT_POINTS {
            self.errors.push(ElabError::ManyOutputPoints {
                span: t.tstep.span(),
                points,
                gigabytes: points * 48.0 / 1e9,
            });
        }
        // TMAX caps the step (ngspice); zero or less means none.
        let tmax = tmax.filter(|&m| m > 0.0).map(|m| {
            // The run integrates from 0 whatever TSTART is.
            let least = tstop / MAX_TMAX_STEPS;
            if m < least {
                self.errors.push(ElabError::TinyTmax {
                    span: t.tmax.as_ref().map_or(t.span, |v| v.span()),
                    tmax: m,
                    max_steps: MAX_TMAX_STEPS,
                    capped: least,
                });
            }
            m.max(least)
        });
        self.tstep = tstep;
        self.tstop = tstop;
        self.circuit.tran = Some(Tran {
            tstep,
            tstop,
            tstart,
            tmax,
            uic: t.uic,
        });
    }

    /// One `.options` entry: a tolerance in its range, `method=`, or a
    /// warning that kausal ignores it.
    fn option(&mut self, o: &ast::OptionDef<'_>, scope: &Scope<'_, '_>) {
        let key = o.name.key();
        let num = match &o.value {
            ast::OptValue::Value(v) => self.value(v, scope),
            _ => None,
        };
        // Out-of-range tolerances would stall or void the
        // error control (reltol 0 with abstol 0 never ends).
        let range = match key.as_str() {
            "reltol" => Some((
                "a number in (0, 1)",
                num.is_some_and(|x| x > 0.0 && x < 1.0),
            )),
            "maxord" => Some(("1 to 6", num.is_some_and(|x| (1.0..=6.0).contains(&x)))),
            "abstol" | "vntol" | "chgtol" | "trtol" | "scale" => {
                Some(("above 0", num.is_some_and(|x| x > 0.0 && x.is_finite())))
            }
            "temp" | "tnom" => Some((
                "a temperature in °C from -273.15 to 1000",
                num.is_some_and(|x| (-273.15..=1000.0).contains(&x)),
            )),
            _ => None,
        };
        if let (Some((range, false)), Some(_), ast::OptValue::Value(v)) = (range, num, &o.value) {
            let value = match v {
                Value::Num { text, .. } | Value::Expr { text, .. } => text.to_string(),
                Value::Ident(n) => n.text.to_string(),
            };
            self.errors.push(ElabError::BadOption {
                span: v.span(),
                name: key.clone(),
                value,
                range,
            });
            return;
        }
        let opt = &mut self.circuit.options;
        let slot = match key.as_str() {
            "reltol" => Some(&mut opt.reltol),
            "abstol" => Some(&mut opt.abstol),
            "vntol" => Some(&mut opt.vntol),
            "chgtol" => Some(&mut opt.chgtol),
            "trtol" => Some(&mut opt.trtol),
            "maxord" => Some(&mut opt.maxord),
            "temp" => Some(&mut opt.temp),
            "tnom" => Some(&mut opt.tnom),
            "scale" => Some(&mut opt.scale),
            _ => None,
        };
        match (slot, &o.value) {
            (Some(slot), _) => *slot = num,
            (None, ast::OptValue::Word(w)) if key == "method" => {
                opt.method = Some(w.key());
            }
            _ => self.errors.push(ElabError::IgnoredOption {
                span: o.name.span,
                name: o.name.text.to_string(),
            }),
        }
    }

    fn node(&mut self, name: &ast::Name<'_>, scope: &Scope<'_, '_>) -> NodeId {
        if name.is("0") || name.is("gnd") {
            return GROUND;
        }
        // The case-folded name is built in a reused buffer: a lookup of a
        // known node allocates nothing.
        let mut key = std::mem::take(&mut self.key_buf);
        let id = self.node_keyed(name, scope, &mut key);
        self.key_buf = key;
        id
    }

    /// A port of the enclosing subcircuit, else the node of the hierarchical
    /// name (created on first use); `key` is scratch.
    fn node_keyed(
        &mut self,
        name: &ast::Name<'_>,
        scope: &Scope<'_, '_>,
        key: &mut String,
    ) -> NodeId {
        if !scope.ports.is_empty() {
            key.clear();
            key.push_str(name.text);
            key.make_ascii_lowercase();
            if let Some(&n) = scope.ports.get(key.as_str()) {
                return n;
            }
        }
        key.clear();
        if !scope.prefix.is_empty() && !self.globals.is_empty() {
            key.push_str(name.text);
            key.make_ascii_lowercase();
            if !self.globals.contains(key.as_str()) {
                key.clear();
            }
        }
        if key.is_empty() {
            key.push_str(&scope.prefix);
            key.push_str(name.text);
            key.make_ascii_lowercase();
        }
        if let Some(&n) = self.node_map.get(key.as_str()) {
            return n;
        }
        let id = self.circuit.nodes.push(Node {
            name: crate::ir::Name::new(key, Some(name.span)),
            internal: false,
        });
        self.node_map.insert(key.clone(), id);
        id
    }

    fn walk<'s, 'a>(
        &mut self,
        stmts: &'s [Stmt<'a>],
        scope: &Scope<'s, 'a>,
        stack: &mut Vec<String>,
    ) {
        for s in stmts {
            if self.too_many {
                return;
            }
            match s {
                Stmt::Element(el) => self.element(el, scope, stack),
                Stmt::Include { body, .. } => self.walk(body, scope, stack),
                _ => {}
            }
        }
        // A subcircuit's own `.ic` and `.nodeset` lines name its nodes: its
        // ports, and internal nodes of this instance (the top level's are
        // read with the outputs).
        if !scope.prefix.is_empty() {
            for s in stmts {
                let (ics, into_ic) = match s {
                    Stmt::Ic(ics, _) => (ics, true),
                    Stmt::Nodeset(ics, _) => (ics, false),
                    _ => continue,
                };
                let directive = if into_ic { ".ic" } else { ".nodeset" };
                let values = self.node_values(ics, scope, directive);
                match into_ic {
                    true => self.circuit.ics.extend(values),
                    false => self.circuit.nodesets.extend(values),
                }
            }
        }
    }

    /// The node `name` means in `scope` (a port, a global, or a node of
    /// this instance), if the circuit has it.
    fn scoped_node(&self, name: &str, scope: &Scope<'_, '_>) -> Option<NodeId> {
        let lower = name.to_ascii_lowercase();
        if lower == "0" || lower == "gnd" {
            return Some(GROUND);
        }
        if let Some(&n) = scope.ports.get(lower.as_str()) {
            return Some(n);
        }
        if scope.prefix.is_empty() || self.globals.contains(lower.as_str()) {
            return self.node_map.get(lower.as_str()).copied();
        }
        let key = format!("{}{lower}", scope.prefix).to_ascii_lowercase();
        self.node_map.get(key.as_str()).copied()
    }

    fn instance<'s, 'a>(
        &mut self,
        el: &'s ast::Element<'a>,
        name: &str,
        subckt: &ast::Name<'a>,
        params: &'s [ast::Assign<'a>],
        scope: &Scope<'s, 'a>,
        stack: &mut Vec<String>,
    ) {
        let key = subckt.key();
        let Some(def) = scope.subckt(&key) else {
            self.errors.push(ElabError::UndefinedSubckt {
                span: subckt.span,
                name: subckt.text.to_string(),
            });
            return;
        };
        if stack.len() >= MAX_HIERARCHY {
            self.errors.push(ElabError::DeepHierarchy {
                span: subckt.span,
                name: subckt.text.to_string(),
                limit: MAX_HIERARCHY,
            });
            return;
        }
        if stack.contains(&key) {
            let mut chain = stack.clone();
            chain.push(key.clone());
            self.errors.push(ElabError::RecursiveSubckt {
                span: subckt.span,
                name: subckt.text.to_string(),
                chain: chain.join(" → "),
            });
            return;
        }
        if def.ports.len() != el.nodes.len() {
            self.errors.push(ElabError::PortMismatch {
                span: el.name.span,
                instance: name.to_string(),
                name: def.name.text.to_string(),
                expected: def.ports.len(),
                found: el.nodes.len(),
                def: def.name.span,
            });
            return;
        }
        let mut inner = Scope {
            parent: Some(scope),
            prefix: format!("{name}."),
            ..Scope::default()
        };
        // A port named twice is the node of its first position, as ngspice
        // binds it; the node at a later position is not made here, so that
        // it exists only where something else uses it (ngspice's raw file
        // has no vector for it otherwise).
        let first_use = self.ports_seen.insert((def.span.file.0, def.span.start));
        for (port, n) in def.ports.iter().zip(&el.nodes) {
            let key = port.key();
            if inner.ports.contains_key(&key) {
                if first_use && let Some(first) = def.ports.iter().find(|p| p.key() == key) {
                    self.errors.push(ElabError::DuplicatePort {
                        span: port.span,
                        port: port.text.to_string(),
                        subckt: def.name.text.to_string(),
                        first: first.span,
                    });
                }
                continue;
            }
            let node = self.node(n, scope);
            inner.ports.insert(key, node);
        }
        // Defaults, evaluated where the subcircuit is used, then overrides.
        for d in &def.params {
            if let Some(v) = self.value(&d.value, scope) {
                inner.params.insert(d.name.key(), v);
            }
        }
        // `m=` is the instance multiplier unless the subcircuit declares a
        // parameter `m`, which it then sets (ngspice).
        let m_is_param = def.params.iter().any(|d| d.name.is("m"));
        for p in params {
            if p.name.is("m") && !m_is_param {
                // `m` instances in parallel: every R, C, L and D inside scaled.
                if let Some(m) = self.multiplier(p, name, scope) {
                    inner.m = Some((m, p.name.span));
                }
            } else if let Some(v) = self.value(&p.value, scope) {
                inner.params.insert(p.name.key(), v);
            }
        }
        self.collect(&def.body, &mut inner);
        self.params(&def.body, &mut inner);
        stack.push(key);
        self.walk(&def.body, &inner, stack);
        stack.pop();
    }

    fn resolve_pending(&mut self) {
        for p in std::mem::take(&mut self.pending) {
            let elem_name = self.circuit.elements[p.elem].name.to_string();
            match p.what {
                PendingRef::Control { vsrc, index } => {
                    // F and H sense a V source's current; a B source reads
                    // any element's (`i(R1)`, as ngspice allows), but a
                    // coupling's, which has none.
                    let any = matches!(
                        self.circuit.elements[p.elem].kind,
                        ElementKind::Behavioural { .. }
                    );
                    let found =
                        self.elem_map.get(&vsrc).map(|&(id, _)| id).filter(|&id| {
                            match self.circuit.elements[id].kind {
                                ElementKind::VSource { .. } => true,
                                ElementKind::Coupling { .. }
                                | ElementKind::DeviceBranch { .. }
                                | ElementKind::Intermediate { .. } => false,
                                _ => any,
                            }
                        });
                    match found {
                        Some(id) => {
                            if let Some(c) = self.circuit.elements[p.elem]
                                .kind
                                .controls_mut()
                                .get_mut(index)
                            {
                                *c = id
                            }
                        }
                        None => self.errors.push(ElabError::UnknownControl {
                            span: p.spans[0],
                            element: elem_name,
                            name: vsrc,
                        }),
                    }
                }
                PendingRef::Coupling { l1, l2 } => {
                    let mut ids = [ElemId(u32::MAX); 2];
                    let mut ok = true;
                    for (i, key) in [l1, l2].into_iter().enumerate() {
                        let found = self.elem_map.get(&key).map(|&(id, _)| id).filter(|&id| {
                            matches!(self.circuit.elements[id].kind, ElementKind::Inductor { .. })
                        });
                        match found {
                            Some(id) => ids[i] = id,
                            None => {
                                ok = false;
                                self.errors.push(ElabError::BadCoupling {
                                    span: p.spans[i],
                                    element: elem_name.clone(),
                                    name: key,
                                });
                            }
                        }
                    }
                    let value = |id: ElemId| match self.circuit.elements[id].kind {
                        ElementKind::Inductor { l, .. } => l,
                        _ => f64::NAN,
                    };
                    let (v1, v2) = if ok {
                        (value(ids[0]), value(ids[1]))
                    } else {
                        (0.0, 0.0)
                    };
                    if v1 * v2 < 0.0 {
                        ok = false;
                        let names: Vec<String> = ids
                            .iter()
                            .map(|&id| self.circuit.elements[id].name.to_string())
                            .collect();
                        self.errors.push(ElabError::CouplingSigns {
                            span: p.spans[if v1 < 0.0 { 0 } else { 1 }],
                            element: elem_name.clone(),
                            l1: names[0].clone(),
                            l2: names[1].clone(),
                            v1,
                            v2,
                        });
                    }
                    if ok
                        && let ElementKind::Coupling { l1, l2, .. } =
                            &mut self.circuit.elements[p.elem].kind
                    {
                        *l1 = ids[0];
                        *l2 = ids[1];
                    }
                }
            }
        }
        // Elements whose references failed are removed from the circuit so
        // that later stages never see a dangling id.
        let bad = |k: &ElementKind| match k {
            ElementKind::Cccs { ctrl, .. }
            | ElementKind::Ccvs { ctrl, .. }
            | ElementKind::Switch {
                ctrl: Some(ctrl), ..
            } => ctrl.0 == u32::MAX,
            ElementKind::Behavioural { controls, .. }
            | ElementKind::DeviceBranch { controls, .. }
            | ElementKind::Intermediate { controls, .. } => {
                controls.iter().any(|c| c.0 == u32::MAX)
            }
            ElementKind::Coupling { l1, l2, .. } => l1.0 == u32::MAX || l2.0 == u32::MAX,
            _ => false,
        };
        if self.circuit.elements.values().any(|e| bad(&e.kind)) {
            let mut remap = Vec::with_capacity(self.circuit.elements.len());
            let mut kept = crate::ir::IdVec::new();
            for (_, e) in self.circuit.elements.iter() {
                if bad(&e.kind) {
                    remap.push(None);
                } else {
                    remap.push(Some(kept.push(e.clone())));
                }
            }
            let fix = |id: &mut ElemId| *id = remap[id.0 as usize].unwrap_or(ElemId(u32::MAX));
            for e in kept.as_mut_slice() {
                match &mut e.kind {
                    ElementKind::Coupling { l1, l2, .. } => {
                        fix(l1);
                        fix(l2);
                    }
                    k => k.controls_mut().iter_mut().for_each(fix),
                }
            }
            self.circuit.elements = kept;
            for (_, (id, _)) in self.elem_map.iter_mut() {
                if let Some(Some(n)) = remap.get(id.0 as usize) {
                    *id = *n;
                }
            }
        }
    }

    /// The node values of an `.ic` or `.nodeset` line.
    fn node_values(
        &mut self,
        ics: &[(ast::OutVec<'_>, Value<'_>)],
        scope: &Scope<'_, '_>,
        directive: &'static str,
    ) -> Vec<NodeIc> {
        let mut out = Vec::new();
        for (v, val) in ics {
            let Some(value) = self.value(val, scope) else {
                continue;
            };
            if v.kind != 'v' || v.args.len() != 1 {
                self.errors.push(ElabError::UnknownNode {
                    span: v.span,
                    node: v.args.iter().map(|a| a.text).collect::<Vec<_>>().join(","),
                    directive,
                });
                continue;
            }
            match self.scoped_node(v.args[0].text, scope) {
                Some(node) => out.push(NodeIc {
                    node,
                    value,
                    span: v.span,
                }),
                None => self.errors.push(ElabError::UnknownNode {
                    span: v.args[0].span,
                    node: v.args[0].text.to_string(),
                    directive,
                }),
            }
        }
        out
    }

    /// `.ic`, `.nodeset` and `.print`/`.save`/`.probe` (top level, through
    /// includes).
    fn outputs(&mut self, stmts: &[Stmt<'_>], scope: &Scope<'_, '_>) {
        for s in stmts {
            match s {
                Stmt::Ic(ics, _) => {
                    let values = self.node_values(ics, scope, ".ic");
                    self.circuit.ics.extend(values);
                }
                Stmt::Nodeset(ics, _) => {
                    let values = self.node_values(ics, scope, ".nodeset");
                    self.circuit.nodesets.extend(values);
                }
                Stmt::Output {
                    directive,
                    vectors,
                    all,
                    ..
                } => {
                    // ngspice stores what `.save` names; `.print` only prints.
                    let save = ["save", "probe"]
                        .iter()
                        .any(|d| directive.text[1..].eq_ignore_ascii_case(d));
                    self.circuit.save_all |= save && *all;
                    for v in vectors {
                        let Some(o) = self.output(v) else {
                            continue;
                        };
                        let list = if save {
                            &mut self.circuit.outputs
                        } else {
                            &mut self.circuit.prints
                        };
                        if !list.contains(&o) {
                            list.push(o);
                        }
                    }
                }
                Stmt::Include { body, .. } => self.outputs(body, scope),
                _ => {}
            }
        }
    }

    fn output(&mut self, v: &ast::OutVec<'_>) -> Option<Output> {
        if v.kind == 'i' {
            let name = v.args[0].text;
            return match self.circuit.find_element(name) {
                Some(elem)
                    if v.args.len() == 1
                        && !matches!(
                            self.circuit.elements[elem].kind,
                            ElementKind::Coupling { .. }
                        ) =>
                {
                    Some(Output::Current { elem })
                }
                _ => {
                    self.errors.push(ElabError::UnknownCurrent {
                        span: v.span,
                        name: name.to_string(),
                    });
                    None
                }
            };
        }
        let mut nodes = [GROUND; 2];
        for (i, a) in v.args.iter().enumerate() {
            match self.circuit.find_node(a.text) {
                Some(n) => nodes[i] = n,
                None => {
                    self.errors.push(ElabError::UnknownNode {
                        span: a.span,
                        node: a.text.to_string(),
                        directive: "output",
                    });
                    return None;
                }
            }
        }
        Some(Output::Voltage {
            pos: nodes[0],
            neg: nodes[1],
        })
    }

    /// Leave out the nodes that no element connects and no expression reads:
    /// an instance's actual node bound to a port its subcircuit never uses
    /// (an IC's unconnected pin, `?` in eSim's netlists). ngspice makes a
    /// node only where an element line names it, so such a node is not in
    /// its circuit; kept, it would be floating. The other nodes keep their
    /// order.
    fn drop_unused_nodes(&mut self) {
        let mut used = vec![false; self.circuit.nodes.len()];
        used[GROUND.0 as usize] = true;
        for e in self.circuit.elements.values_mut() {
            for n in &e.nodes {
                used[n.0 as usize] = true;
            }
            for x in e.kind.exprs_mut() {
                for n in &x.nodes {
                    if let BNode::Pot(id) = n {
                        used[id.0 as usize] = true;
                    }
                }
            }
        }
        if used.iter().all(|&u| u) {
            return;
        }
        let mut new_id = vec![None; used.len()];
        let mut nodes = crate::ir::IdVec::with_capacity(used.len());
        for (id, node) in std::mem::take(&mut self.circuit.nodes).iter() {
            if used[id.0 as usize] {
                new_id[id.0 as usize] = Some(nodes.push(node.clone()));
            }
        }
        self.circuit.nodes = nodes;
        let map = |n: NodeId| new_id[n.0 as usize];
        for e in self.circuit.elements.values_mut() {
            for n in &mut e.nodes {
                *n = map(*n).expect("an element's node is used");
            }
            for x in e.kind.exprs_mut() {
                for n in &mut x.nodes {
                    if let BNode::Pot(id) = n {
                        *id = map(*id).expect("a node an expression reads is used");
                    }
                }
            }
        }
        // A subcircuit's `.ic` or `.nodeset` on such a node sets nothing.
        for ics in [&mut self.circuit.ics, &mut self.circuit.nodesets] {
            ics.retain_mut(|ic| match map(ic.node) {
                Some(n) => {
                    ic.node = n;
                    true
                }
                None => false,
            });
        }
        self.node_map.retain(|_, n| match map(*n) {
            Some(m) => {
                *n = m;
                true
            }
            None => false,
        });
    }

    /// Warn about nodes with one connection (skipped when errors removed
    /// elements, which would make the warning misleading).
    fn dangling(&mut self) {
        if self
            .errors
            .iter()
            .any(|e| e.severity() == crate::diag::Severity::Error)
        {
            return;
        }
        let mut count = vec![0u32; self.circuit.nodes.len()];
        for e in self.circuit.elements.values_mut() {
            for n in &e.nodes {
                count[n.0 as usize] += 1;
            }
            // A device terminal that only its own laws read (a MOSFET's gate
            // without gate capacitances) is a connection all the same.
            if matches!(
                e.kind,
                ElementKind::DeviceBranch { .. } | ElementKind::Intermediate { .. }
            ) {
                for x in e.kind.exprs_mut() {
                    for n in &x.nodes {
                        if let BNode::Pot(id) = n {
                            count[id.0 as usize] += 1;
                        }
                    }
                }
            }
        }
        for (id, node) in self.circuit.nodes.iter() {
            if id != GROUND && count[id.0 as usize] == 1 {
                self.errors.push(ElabError::DanglingNode {
                    span: node.span(),
                    node: node.name.to_string(),
                });
            }
        }
    }
}

/// The `.func` `name` visible in `scope` at `args` (`None`: there is none);
/// its arguments shadow the parameters it can also read. `depth` counts the
/// calls in progress, `calls` all calls of the expression: a function that
/// calls itself, or functions that each call the next twice 60 deep, are an
/// error, not an endless evaluation.
fn call_func(
    scope: &Scope<'_, '_>,
    name: &str,
    args: &[f64],
    chain: &std::cell::RefCell<Vec<String>>,
    calls: &std::cell::Cell<usize>,
) -> Option<Result<f64, crate::front::expr::EvalError>> {
    use crate::front::expr::EvalError;
    let f = scope.func(name)?;
    if args.len() != f.params.len() {
        return Some(Err(EvalError::Arity(name.to_string(), f.params.len())));
    }
    calls.set(calls.get() + 1);
    // The calls in progress: a name among them is a recursion; a chain
    // longer than MAX_CALL_DEPTH is refused before the stack runs out.
    {
        let chain = chain.borrow();
        if chain.iter().any(|c| c.eq_ignore_ascii_case(name)) {
            return Some(Err(EvalError::Recursive(name.to_string())));
        }
        if chain.len() >= MAX_CALL_DEPTH {
            return Some(Err(EvalError::TooDeep(name.to_string())));
        }
    }
    if calls.get() > 100_000 {
        return Some(Err(EvalError::TooManyCalls));
    }
    chain.borrow_mut().push(name.to_string());
    let bound = |p: &str| {
        f.params
            .iter()
            .position(|q| q.text.eq_ignore_ascii_case(p))
            .map(|k| args[k])
            .or_else(|| scope.param(p))
    };
    let inner = |n: &str, a: &[f64]| call_func(scope, n, a, chain, calls);
    let value = match &f.body {
        Value::Num { value, .. } => Ok(*value),
        Value::Ident(n) => bound(&n.key()).ok_or_else(|| EvalError::Undefined(n.text.to_string())),
        Value::Expr { expr, .. } => expr.eval_with(&bound, &inner),
    };
    chain.borrow_mut().pop();
    Some(value)
}

/// Subcircuit instances nested deeper than this are refused (flattening
/// recurses: unbounded, 2·10^4 levels overflow the stack).
const MAX_HIERARCHY: usize = 100;

/// A circuit with more elements than this once flattened is refused, when
/// flattening reaches it (before anything past it is built). Checking and
/// sorting take about 2 KB an element, so this bounds them near 4 GB; a
/// 20-level binary tree of instances is 10^6 elements in 1.3 KB of
/// netlist. The largest generated benchmark (an RC ladder of 1.7·10^5
/// sections) has 3.4·10^5.
pub(crate) const MAX_ELEMENTS: usize = 2_000_000;

/// `.func` calls nested deeper than this are refused (evaluation recurses).
const MAX_CALL_DEPTH: usize = 64;

fn try_value(v: &Value<'_>, scope: &Scope<'_, '_>) -> Result<f64, ElabError> {
    use crate::front::expr::EvalError;
    match v {
        Value::Num { value, .. } => Ok(*value),
        Value::Ident(n) => scope
            .param(&n.key())
            .ok_or_else(|| ElabError::UndefinedParam {
                span: n.span,
                name: n.text.to_string(),
            }),
        Value::Expr { expr, text, span } => {
            let calls = std::cell::Cell::new(0);
            let chain = std::cell::RefCell::new(Vec::new());
            let user = |name: &str, args: &[f64]| call_func(scope, name, args, &chain, &calls);
            expr.eval_with(&|name| scope.param(name), &user)
                .map_err(|e| {
                    let reason = match e {
                        EvalError::Undefined(name) => {
                            return ElabError::UndefinedParam { span: *span, name };
                        }
                        EvalError::Recursive(f) => format!("`.func {f}` calls itself"),
                        EvalError::TooDeep(f) => format!(
                            "`.func` calls are nested more than {MAX_CALL_DEPTH} deep (at `{f}`)"
                        ),
                        EvalError::TooManyCalls => {
                            "its functions call each other more than 10^5 times".into()
                        }
                        EvalError::UnknownFunction(f) => format!("unknown function `{f}`"),
                        EvalError::Arity(f, n) => format!("`{f}` takes {n} argument(s)"),
                        EvalError::NotFinite => "the result is not a finite number".into(),
                        EvalError::Probe(p) => format!(
                            "`{p}` is a node voltage or branch current, which only a B source's expression can read"
                        ),
                    };
                    ElabError::BadValue {
                        span: *span,
                        text: text.to_string(),
                        reason,
                    }
                })
        }
    }
}
