//! The netlist AST: statements as written, borrowing the source text, with spans.
//! Names keep their spelling; comparisons are case-insensitive.

use super::expr::PExpr;
use crate::diag::Span;

/// A name as written (node, element, model, parameter).
#[derive(Clone, Copy, Debug)]
pub struct Name<'a> {
    pub text: &'a str,
    pub span: Span,
}

impl Name<'_> {
    /// The case-folded key used for lookups.
    pub fn key(&self) -> String {
        self.text.to_ascii_lowercase()
    }

    pub fn is(&self, s: &str) -> bool {
        self.text.eq_ignore_ascii_case(s)
    }
}

/// A numeric value: a literal, a `{…}` expression or a bare parameter name.
#[derive(Clone, Debug)]
pub enum Value<'a> {
    Num {
        value: f64,
        text: &'a str,
        span: Span,
    },
    Expr {
        expr: Box<PExpr>,
        text: &'a str,
        span: Span,
    },
    Ident(Name<'a>),
}

impl Value<'_> {
    pub fn span(&self) -> Span {
        match self {
            Value::Num { span, .. } | Value::Expr { span, .. } => *span,
            Value::Ident(n) => n.span,
        }
    }
}

/// `name=value`
#[derive(Clone, Debug)]
pub struct Assign<'a> {
    pub name: Name<'a>,
    pub value: Value<'a>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TranFnKind {
    Pulse,
    Sin,
    Exp,
    Pwl,
    /// SPICE3's single-frequency FM source, `SFFM(VO VA FC MDI FS)`.
    Sffm,
}

impl TranFnKind {
    pub fn name(self) -> &'static str {
        match self {
            TranFnKind::Pulse => "PULSE",
            TranFnKind::Sin => "SIN",
            TranFnKind::Exp => "EXP",
            TranFnKind::Pwl => "PWL",
            TranFnKind::Sffm => "SFFM",
        }
    }
}

/// A transient source function such as `PULSE(0 1 1n)`.
#[derive(Clone, Debug)]
pub struct TranFn<'a> {
    pub kind: TranFnKind,
    pub args: Vec<Value<'a>>,
    /// PWL's `r=` (the time point the sequence repeats from) and `td=`
    /// (its delay), written after the parenthesis.
    pub repeat: Option<Value<'a>>,
    pub delay: Option<Value<'a>>,
    pub span: Span,
}

/// What follows an element's nodes, by element letter.
#[derive(Clone, Debug)]
pub enum ElementBody<'a> {
    /// R, C, L: a value plus `name=value` extras (`ic=`, `m=`, ...); a
    /// resistor's or capacitor's model after its value (`R1 a b 1k RMOD`;
    /// one in place of the value is the value's identifier until
    /// elaboration).
    Passive {
        value: Value<'a>,
        model: Option<Name<'a>>,
        params: Vec<Assign<'a>>,
    },
    /// K: coupling of two inductors.
    Coupling {
        l1: Name<'a>,
        l2: Name<'a>,
        k: Value<'a>,
    },
    /// V, I.
    Source {
        dc: Option<Value<'a>>,
        tran: Option<TranFn<'a>>,
        /// `AC mag [phase]`: kept for printing, ignored by transient analysis.
        ac: Vec<Value<'a>>,
    },
    /// E, G: four nodes (out+, out-, ctrl+, ctrl-) and a gain.
    VoltageControlled { gain: Value<'a> },
    /// F, H: two nodes, a controlling V source, a gain.
    CurrentControlled { vsrc: Name<'a>, gain: Value<'a> },
    /// D: a model name and an optional area factor.
    Diode {
        model: Name<'a>,
        area: Option<Value<'a>>,
        params: Vec<Assign<'a>>,
    },
    /// B: `V=expr` or `I=expr` over node voltages, branch currents, `time`
    /// and parameters.
    Behavioural {
        /// `I=` (a current source), else `V=`.
        current: bool,
        expr: Box<PExpr>,
        /// The expression as written (continuation lines joined).
        text: String,
        span: Span,
    },
    /// Q, J, M, S and W: after the terminals, the bare words (Q's `[substrate] model
    /// [area]`, told apart by which word names a model; J's `model [area]`),
    /// then `name=value`s.
    Device {
        words: Vec<Value<'a>>,
        params: Vec<Assign<'a>>,
    },
    /// X: a subcircuit instance.
    Instance {
        subckt: Name<'a>,
        params: Vec<Assign<'a>>,
    },
}

#[derive(Clone, Debug)]
pub struct Element<'a> {
    pub name: Name<'a>,
    /// The first letter of the name, which says what the element is.
    pub letter: ElementLetter,
    pub nodes: Vec<Name<'a>>,
    pub body: ElementBody<'a>,
    pub span: Span,
}

/// The elements kausal reads, by the first letter of their name (in either
/// case). Every place that tells elements apart by letter uses this.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ElementLetter {
    /// Resistor.
    R,
    /// Capacitor.
    C,
    /// Inductor.
    L,
    /// Coupling of two inductors.
    K,
    /// Independent voltage source.
    V,
    /// Independent current source.
    I,
    /// Voltage-controlled voltage source.
    E,
    /// Voltage-controlled current source.
    G,
    /// Current-controlled current source.
    F,
    /// Current-controlled voltage source.
    H,
    /// Diode.
    D,
    /// Behavioural voltage or current source.
    B,
    /// Bipolar transistor.
    Q,
    /// Junction field-effect transistor.
    J,
    /// MOSFET.
    M,
    /// Voltage-controlled switch.
    S,
    /// Current-controlled switch.
    W,
    /// Subcircuit instance.
    X,
}

impl ElementLetter {
    /// The element kind of a name's first character, in either case; `None`
    /// for a letter kausal does not read (see [`unsupported_kind`]).
    pub fn from_char(c: char) -> Option<ElementLetter> {
        use ElementLetter::*;
        Some(match c.to_ascii_uppercase() {
            'R' => R,
            'C' => C,
            'L' => L,
            'K' => K,
            'V' => V,
            'I' => I,
            'E' => E,
            'G' => G,
            'F' => F,
            'H' => H,
            'D' => D,
            'B' => B,
            'Q' => Q,
            'J' => J,
            'M' => M,
            'S' => S,
            'W' => W,
            'X' => X,
            _ => return None,
        })
    }

    /// The letter, upper-case.
    pub fn as_char(self) -> char {
        use ElementLetter::*;
        match self {
            R => 'R',
            C => 'C',
            L => 'L',
            K => 'K',
            V => 'V',
            I => 'I',
            E => 'E',
            G => 'G',
            F => 'F',
            H => 'H',
            D => 'D',
            B => 'B',
            Q => 'Q',
            J => 'J',
            M => 'M',
            S => 'S',
            W => 'W',
            X => 'X',
        }
    }

    /// How many nodes follow the name: four for the voltage-controlled
    /// sources and M, three for Q (a fourth, the substrate, is one of its
    /// words) and J, none for K, two for the others; `None` for X, whose nodes end where
    /// its subcircuit's name stands.
    pub fn n_nodes(self) -> Option<usize> {
        use ElementLetter::*;
        match self {
            R | C | L | V | I | F | H | D | B | W => Some(2),
            E | G | S => Some(4),
            Q | J => Some(3),
            M => Some(4),
            K => Some(0),
            X => None,
        }
    }
}

/// What an element letter that kausal does not read stands for in SPICE
/// (`Q`: a bipolar transistor), for the error; `None` for a letter SPICE
/// does not know either. `letter` is upper-case.
pub fn unsupported_kind(letter: char) -> Option<&'static str> {
    Some(match letter {
        'T' | 'O' | 'U' | 'Y' => "transmission line",
        'Z' => "MESFET",
        'N' => "OSDI device",
        'P' => "coupled transmission line",
        'A' => "XSPICE code model",
        _ => return None,
    })
}

#[derive(Clone, Debug)]
pub struct Model<'a> {
    pub name: Name<'a>,
    pub kind: Name<'a>,
    pub params: Vec<Assign<'a>>,
    /// PSpice's `AKO:ORIG` ("a kind of"): ORIG's parameters, then this
    /// card's (a later value wins). The parser merges them into `params`
    /// and clears this once ORIG is found.
    pub ako: Option<Name<'a>>,
    pub span: Span,
}

#[derive(Clone, Debug)]
pub struct Subckt<'a> {
    pub name: Name<'a>,
    pub ports: Vec<Name<'a>>,
    /// Parameters with defaults (`params: a=1`).
    pub params: Vec<Assign<'a>>,
    pub body: Vec<Stmt<'a>>,
    pub span: Span,
}

/// A vector such as `v(a)`, `v(a,b)` or `i(v1)`.
#[derive(Clone, Debug)]
pub struct OutVec<'a> {
    /// `v` or `i`, lower-case.
    pub kind: char,
    pub args: Vec<Name<'a>>,
    pub span: Span,
}

#[derive(Clone, Debug)]
pub struct Tran<'a> {
    pub tstep: Value<'a>,
    pub tstop: Value<'a>,
    pub tstart: Option<Value<'a>>,
    pub tmax: Option<Value<'a>>,
    pub uic: bool,
    pub span: Span,
}

#[derive(Clone, Debug)]
pub enum OptValue<'a> {
    Flag,
    Value(Value<'a>),
    Word(Name<'a>),
}

#[derive(Clone, Debug)]
pub struct OptionDef<'a> {
    pub name: Name<'a>,
    pub value: OptValue<'a>,
}

#[derive(Clone, Debug)]
pub enum Stmt<'a> {
    Element(Element<'a>),
    Model(Model<'a>),
    Subckt(Box<Subckt<'a>>),
    Param(Vec<Assign<'a>>, Span),
    /// `.ic v(node)=value ...`
    Ic(Vec<(OutVec<'a>, Value<'a>)>, Span),
    /// `.nodeset v(n)=x ...`: initial guesses for the operating point.
    Nodeset(Vec<(OutVec<'a>, Value<'a>)>, Span),
    /// `.global node ...`: these names mean the top-level node inside every
    /// subcircuit too.
    Global(Vec<Name<'a>>, Span),
    /// `.func name(arg ...) {expression}`.
    Func(Box<FuncDef<'a>>),
    Tran(Box<Tran<'a>>),
    Options(Vec<OptionDef<'a>>, Span),
    /// `.print`, `.save`, `.probe`: the directive name and its vectors.
    Output {
        directive: Name<'a>,
        analysis: Option<Name<'a>>,
        vectors: Vec<OutVec<'a>>,
        /// The keyword `all` (every node voltage and source current).
        all: bool,
        span: Span,
    },
    /// `.include "path"`, with the included file's statements; or
    /// `.lib "path" SECTION`, with the statements of that section of the file.
    Include {
        path: &'a str,
        section: Option<&'a str>,
        span: Span,
        body: Vec<Stmt<'a>>,
    },
}

/// A user function: `.func name(a, b) {a*b}` (commas optional to kausal).
#[derive(Clone, Debug)]
pub struct FuncDef<'a> {
    pub name: Name<'a>,
    pub params: Vec<Name<'a>>,
    pub body: Value<'a>,
    pub span: Span,
}

/// A parsed netlist file tree.
#[derive(Clone, Debug, Default)]
pub struct Netlist<'a> {
    pub title: &'a str,
    /// The title line: where a diagnostic about the netlist as a whole
    /// points.
    pub title_span: Span,
    pub stmts: Vec<Stmt<'a>>,
}
