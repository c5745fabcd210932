//! The flattened circuit: nodes, elements with numeric values, analysis
//! settings. Subcircuits are expanded, parameters evaluated, models resolved.

use crate::diag::Span;
use crate::front::ast::ElementLetter;
use crate::ir::{Cmp, DiodePart, Func, IdVec, Waveform};

crate::entity_id!(
    /// A circuit node; `n0` is ground.
    NodeId,
    "n"
);
crate::entity_id!(
    /// An element of the flattened circuit.
    ElemId,
    "el"
);

/// Ground, the reference node (`0` or `gnd` in the netlist).
pub const GROUND: NodeId = NodeId(0);

#[derive(Clone, Debug)]
pub struct Node {
    /// Lower-case, hierarchical for subcircuit-internal nodes (`x1.n2`),
    /// with where the node is first used ([`Node::span`]).
    pub name: crate::ir::Name,
    /// A device's internal node (`q1#c`, behind a terminal resistance):
    /// not among the default output vectors.
    pub internal: bool,
}

impl Node {
    /// Where the node is first used (its name entity holds it).
    pub fn span(&self) -> Span {
        self.name.span().unwrap_or_default()
    }
}

/// ngspice's level-1 diode parameters (defaults as in ngspice).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct DiodeModel {
    pub name: String,
    pub is: f64,
    pub n: f64,
    pub rs: f64,
    pub cjo: f64,
    pub vj: f64,
    pub m: f64,
    pub fc: f64,
    pub tt: f64,
    /// Reverse breakdown voltage (positive); `None` means no breakdown.
    pub bv: Option<f64>,
    pub ibv: f64,
    /// The saturation current's temperature law: activation energy (eV)
    /// and exponent; the temperature the parameters hold at (°C).
    pub eg: f64,
    pub xti: f64,
    pub tnom: Option<f64>,
}

impl Default for DiodeModel {
    fn default() -> Self {
        DiodeModel {
            name: String::new(),
            is: 1e-14,
            n: 1.0,
            rs: 0.0,
            cjo: 0.0,
            vj: 1.0,
            m: 0.5,
            fc: 0.5,
            tt: 0.0,
            bv: None,
            ibv: 1e-3,
            eg: 1.11,
            xti: 3.0,
            tnom: None,
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub enum ElementKind {
    Resistor {
        r: f64,
    },
    Capacitor {
        c: f64,
        ic: Option<f64>,
    },
    Inductor {
        l: f64,
        ic: Option<f64>,
    },
    /// Mutual coupling `k` between two inductors.
    Coupling {
        l1: ElemId,
        l2: ElemId,
        k: f64,
    },
    VSource {
        wave: Box<Waveform>,
    },
    ISource {
        wave: Box<Waveform>,
    },
    /// E: nodes are out+, out-, ctrl+, ctrl-.
    Vcvs {
        gain: f64,
    },
    /// G: nodes are out+, out-, ctrl+, ctrl-.
    Vccs {
        gm: f64,
    },
    /// F: current gain on the current of V source `ctrl`.
    Cccs {
        gain: f64,
        ctrl: ElemId,
    },
    /// H: transresistance on the current of V source `ctrl`.
    Ccvs {
        r: f64,
        ctrl: ElemId,
    },
    Diode {
        model: Box<DiodeModel>,
        area: f64,
    },
    /// B: `V=expr` (`current` false) or `I=expr`; `controls` are the V
    /// sources whose currents `expr` reads ([`BExpr::Current`]).
    Behavioural {
        current: bool,
        expr: Box<BExpr>,
        controls: Vec<ElemId>,
    },
    /// One branch of a transistor (`Q1:be`): its current `i = I + dq/dt`
    /// with `q = Q`, where `I` and `Q` read the branch voltages of
    /// `controls` ([`BNode::Volt`]) and the circuit's junction functions
    /// ([`BNode::Junction`]). Without `current`, a charge alone (a
    /// depletion capacitance); without `charge`, a current alone.
    DeviceBranch {
        /// The device's letter (`Q`).
        device: ElementLetter,
        /// A current set by other branches' voltages alone (a transistor's
        /// transport current), as a G source's; else the current depends on
        /// the branch's own voltage, as a diode's or a resistor's.
        controlled: bool,
        current: Option<Box<BExpr>>,
        charge: Option<Box<BExpr>>,
        /// A capacitance over the device's voltages (Meyer's gate
        /// capacitances): `i = C·du/dt`, the branch voltage `u` a state.
        capacitance: Option<Box<BExpr>>,
        controls: Vec<ElemId>,
    },
    /// S, W: a resistance of RON or ROFF as the switch's state says; the
    /// state is a run-time register the simulator sets when the control
    /// (S: the voltage from node 2 to node 3; W: the current of `ctrl`)
    /// crosses VT + VH upwards (on) or VT − VH downwards (off).
    Switch {
        sw: Box<SwitchModel>,
        /// W's controlling V source.
        ctrl: Option<ElemId>,
    },
    /// A device's named intermediate quantity (a MOSFET's threshold
    /// `M1:von`): one variable and its defining expression, read by the
    /// device's branches (and other intermediates) through
    /// [`BNode::Volt`]. No terminals: no branch, no current.
    Intermediate {
        device: ElementLetter,
        expr: Box<BExpr>,
        controls: Vec<ElemId>,
    },
}

/// A switch's model (ngspice's SW and CSW): the threshold and hysteresis
/// of its control (volts for S, amperes for W), its two resistances, and the
/// state it starts the operating point in (`on`; off by default).
#[derive(Clone, Debug, PartialEq)]
pub struct SwitchModel {
    pub vt: f64,
    pub vh: f64,
    pub ron: f64,
    pub roff: f64,
    pub initially_on: bool,
}

impl SwitchModel {
    /// The state after the control `x` from state `on`: on above VT + VH,
    /// off below VT − VH, unchanged in between.
    pub fn next(&self, on: bool, x: f64) -> bool {
        if x > self.vt + self.vh {
            true
        } else if x < self.vt - self.vh {
            false
        } else {
            on
        }
    }

    /// The control value at which state `on` changes.
    pub fn threshold(&self, on: bool) -> f64 {
        if on {
            self.vt - self.vh
        } else {
            self.vt + self.vh
        }
    }
}

/// A B source's expression with its names resolved: parameters and `.func`
/// calls are evaluated or inlined, node names are nodes. Nodes refer to
/// earlier nodes by index, so a subterm used twice (`min(x, y)` reads `x`
/// twice) is stored once; the root is the last.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct BExpr {
    pub nodes: Vec<BNode>,
    /// The comparisons whose value jumps where they flip (`v(a) > 1`, `u()`,
    /// `sgn()`): state events. Those inside `min`, `max`, `limit`, `pwl`
    /// select between equal values there and are left out.
    pub events: Vec<u32>,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BNode {
    Num(f64),
    Time,
    /// A node's potential (`v(a)`; `v(a, b)` is a difference of two).
    Pot(NodeId),
    /// The current of the element's `k`-th controlling V source (`i(v1)`).
    Current(u32),
    Neg(u32),
    Arith(Arith, u32, u32),
    Cmp(Cmp, u32, u32),
    /// The second where the first is not 0, else the third.
    Select(u32, u32, u32),
    Call(Func, u32),
    /// `ddt(x)`: the time derivative of its operand.
    Ddt(u32),
    /// The branch voltage of the element's `k`-th control (device branches).
    Volt(u32),
    /// A capacitance floor: the value times the system's floor factor
    /// (1 but while the operating point is solved, see
    /// `EquationSystem::add_floor_param`).
    Floor(f64),
    /// A junction function of [`Circuit::junctions`] (a device's junction
    /// current or depletion charge) of its operand.
    Junction {
        junction: u32,
        part: DiodePart,
        arg: u32,
    },
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Arith {
    Add,
    Sub,
    Mul,
    Div,
    Pow,
}

impl ElementKind {
    /// The expressions it holds: a B source's (or an intermediate's), a
    /// device branch's current, charge and capacitance.
    pub fn exprs_mut(&mut self) -> Vec<&mut BExpr> {
        match self {
            ElementKind::Behavioural { expr, .. } | ElementKind::Intermediate { expr, .. } => {
                vec![&mut **expr]
            }
            ElementKind::DeviceBranch {
                current,
                charge,
                capacitance,
                ..
            } => [current, charge, capacitance]
                .into_iter()
                .flatten()
                .map(|x| &mut **x)
                .collect(),
            _ => Vec::new(),
        }
    }

    /// The V sources whose currents it reads (F, H, B).
    pub fn controls_mut(&mut self) -> &mut [ElemId] {
        match self {
            ElementKind::Cccs { ctrl, .. } | ElementKind::Ccvs { ctrl, .. } => {
                std::slice::from_mut(ctrl)
            }
            ElementKind::Behavioural { controls, .. }
            | ElementKind::DeviceBranch { controls, .. }
            | ElementKind::Intermediate { controls, .. } => controls,
            ElementKind::Switch { ctrl: Some(c), .. } => std::slice::from_mut(c),
            _ => &mut [],
        }
    }

    /// Whether its branch voltage is what it fixes (V, E, H, B with `V=`).
    pub fn fixes_voltage(&self) -> bool {
        matches!(
            self,
            ElementKind::VSource { .. }
                | ElementKind::Vcvs { .. }
                | ElementKind::Ccvs { .. }
                | ElementKind::Behavioural { current: false, .. }
        )
    }

    /// The letter a netlist names this element with.
    pub fn letter(&self) -> ElementLetter {
        match self {
            ElementKind::Resistor { .. } => ElementLetter::R,
            ElementKind::Capacitor { .. } => ElementLetter::C,
            ElementKind::Inductor { .. } => ElementLetter::L,
            ElementKind::Coupling { .. } => ElementLetter::K,
            ElementKind::VSource { .. } => ElementLetter::V,
            ElementKind::ISource { .. } => ElementLetter::I,
            ElementKind::Vcvs { .. } => ElementLetter::E,
            ElementKind::Vccs { .. } => ElementLetter::G,
            ElementKind::Cccs { .. } => ElementLetter::F,
            ElementKind::Ccvs { .. } => ElementLetter::H,
            ElementKind::Diode { .. } => ElementLetter::D,
            ElementKind::Behavioural { .. } => ElementLetter::B,
            ElementKind::Switch { ctrl, .. } => {
                if ctrl.is_some() {
                    ElementLetter::W
                } else {
                    ElementLetter::S
                }
            }
            ElementKind::DeviceBranch { device, .. } | ElementKind::Intermediate { device, .. } => {
                *device
            }
        }
    }
}

#[derive(Clone, Debug)]
pub struct Element {
    /// Name as written, with the instance path in front (`X1.R2`).
    pub name: crate::ir::Name,
    pub kind: ElementKind,
    /// Terminals: two for most elements, four for E and G, none for K.
    pub nodes: Box<[NodeId]>,
}

impl Element {
    /// The element's line in the netlist (its name's entity holds it).
    pub fn span(&self) -> Span {
        self.name.span().unwrap_or_default()
    }

    /// The name ngspice gives this element's current vector: `v1`, or
    /// `v.x1.vmeas` inside a subcircuit.
    pub fn ngspice_name(&self) -> String {
        let lower = self.name.to_ascii_lowercase();
        match lower.rsplit_once('.') {
            Some((path, local)) => {
                let letter = local.chars().next().unwrap_or('?');
                format!("{letter}.{path}.{local}")
            }
            None => lower,
        }
    }
}

/// The `.tran` line.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Tran {
    pub tstep: f64,
    pub tstop: f64,
    pub tstart: f64,
    pub tmax: Option<f64>,
    pub uic: bool,
}

/// `.options` kausal understands; ngspice's meaning, ngspice's defaults when absent.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct SimOptions {
    pub reltol: Option<f64>,
    pub abstol: Option<f64>,
    pub vntol: Option<f64>,
    pub chgtol: Option<f64>,
    pub trtol: Option<f64>,
    /// `trap` or `gear`.
    pub method: Option<String>,
    pub maxord: Option<f64>,
    /// Circuit and nominal temperatures, °C (ngspice's defaults: 27).
    pub temp: Option<f64>,
    pub tnom: Option<f64>,
    /// ngspice's SCALE: MOSFETs' L, W, PD and PS given on their lines are
    /// multiplied by it, AD and AS by its square (defaults are not).
    pub scale: Option<f64>,
}

/// An initial condition from `.ic v(node)=value`.
#[derive(Clone, Debug)]
pub struct NodeIc {
    pub node: NodeId,
    pub value: f64,
    pub span: Span,
}

/// A requested output vector.
#[derive(Clone, Debug, PartialEq)]
pub enum Output {
    Voltage { pos: NodeId, neg: NodeId },
    Current { elem: ElemId },
}

#[derive(Clone, Debug, Default)]
pub struct Circuit {
    pub title: String,
    /// The netlist's title line (see [`crate::front::ast::Netlist::title_span`]).
    pub title_span: Span,
    /// `nodes[GROUND]` is ground.
    pub nodes: IdVec<NodeId, Node>,
    pub elements: IdVec<ElemId, Element>,
    pub tran: Option<Tran>,
    pub ics: Vec<NodeIc>,
    /// `.nodeset` guesses for the operating point.
    pub nodesets: Vec<NodeIc>,
    pub options: SimOptions,
    /// The vectors `.save` (and `.probe`) store: with none and no `.save
    /// all`, every node voltage and voltage source current is stored.
    pub outputs: Vec<Output>,
    /// `.save all`: the default vectors as well as `outputs`.
    pub save_all: bool,
    /// `.print` (and `.plot`) vectors: stored in addition to the default
    /// vectors when no `.save` selects.
    pub prints: Vec<Output>,
    /// The junction functions of transistors ([`BNode::Junction`]), with
    /// their area and thermal voltage applied.
    pub junctions: Vec<crate::ir::DiodeParams>,
}

impl Circuit {
    pub fn find_node(&self, name: &str) -> Option<NodeId> {
        let lower = name.to_ascii_lowercase();
        if lower == "0" || lower == "gnd" {
            return Some(GROUND);
        }
        self.nodes
            .iter()
            .find(|(_, n)| *n.name == *lower)
            .map(|(id, _)| id)
    }

    /// Find an element by its name (`X1.R2`) or ngspice's name (`r.x1.r2`).
    pub fn find_element(&self, name: &str) -> Option<ElemId> {
        self.elements
            .iter()
            .find(|(_, e)| {
                e.name.eq_ignore_ascii_case(name) || e.ngspice_name() == name.to_ascii_lowercase()
            })
            .map(|(id, _)| id)
    }

    /// The ngspice name of an output vector (`v(out)`, `i(v1)`).
    pub fn output_name(&self, out: &Output) -> String {
        match *out {
            Output::Voltage { pos, neg } if neg == GROUND => format!("v({})", self.nodes[pos].name),
            Output::Voltage { pos, neg } => {
                format!("v({},{})", self.nodes[pos].name, self.nodes[neg].name)
            }
            Output::Current { elem } => format!("i({})", self.elements[elem].ngspice_name()),
        }
    }
}
