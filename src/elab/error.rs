//! Errors and warnings of elaboration (parameters, subcircuits, models, names).

use crate::diag::codes;
use crate::diag::{Diagnostic, Severity, Span, ToDiagnostic};

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ElabError {
    #[error("parameter `{name}` is not defined")]
    UndefinedParam { span: Span, name: String },
    #[error("cannot evaluate `{text}`: {reason}")]
    BadValue {
        span: Span,
        text: String,
        reason: String,
    },
    #[error("model `{name}` is not defined")]
    UndefinedModel { span: Span, name: String },
    #[error("model `{name}` has type `{found}`, but `{element}` needs a `{expected}` model")]
    WrongModelType {
        span: Span,
        name: String,
        found: String,
        expected: &'static str,
        element: String,
    },
    #[error("model `{model}` is {what}, which kausal does not model")]
    UnsupportedModel {
        span: Span,
        model: String,
        what: String,
        help: &'static str,
    },
    #[error("`{element}`: {why}")]
    BadDevice {
        span: Span,
        element: String,
        why: String,
    },
    #[error("`{name}` has both terminals on node `{node}`: it carries no current and is left out")]
    ShortedElement {
        span: Span,
        name: String,
        node: String,
    },
    #[error("subcircuit `{name}` is not defined")]
    UndefinedSubckt { span: Span, name: String },
    #[error("subcircuit `{name}` instantiates itself ({chain})")]
    RecursiveSubckt {
        span: Span,
        name: String,
        chain: String,
    },
    #[error("instantiating `{name}` nests subcircuits more than {limit} deep")]
    DeepHierarchy {
        span: Span,
        name: String,
        limit: usize,
    },
    /// Flattening reached `limit` elements; `span` is the top-level line
    /// being expanded then (the instance, or the element itself), `element`
    /// the hierarchical name of the element past the limit.
    #[error("the circuit expands to more than {limit} elements (`{element}` is past the limit)")]
    TooManyElements {
        span: Span,
        element: String,
        limit: usize,
    },
    #[error("`{instance}` connects {found} nodes, but subcircuit `{name}` has {expected} ports")]
    PortMismatch {
        span: Span,
        instance: String,
        name: String,
        expected: usize,
        found: usize,
        def: Span,
    },
    #[error(
        "port `{port}` is named twice in `.subckt {subckt}`: ngspice connects it to the first node, and so does kausal"
    )]
    DuplicatePort {
        span: Span,
        port: String,
        subckt: String,
        first: Span,
    },
    #[error(
        "`{element}` has a negative capacitance ({value:e} F): a mode through it can grow in time"
    )]
    NegativeCapacitance {
        span: Span,
        element: String,
        value: f64,
    },
    #[error("element `{name}` is defined twice")]
    DuplicateElement {
        span: Span,
        name: String,
        first: Span,
    },
    #[error("`{name}` has both terminals on node `{node}`")]
    SingleNode {
        span: Span,
        name: String,
        node: String,
    },
    #[error("`{element}` is controlled by `{name}`, which is not a voltage source of this circuit")]
    UnknownControl {
        span: Span,
        element: String,
        name: String,
    },
    #[error("`{element}` couples `{name}`, which is not an inductor of this circuit")]
    BadCoupling {
        span: Span,
        element: String,
        name: String,
    },
    #[error(
        "`{element}` couples `{l1}` ({v1} H) and `{l2}` ({v2} H), of opposite signs: k·√(L1·L2) is not real"
    )]
    CouplingSigns {
        span: Span,
        element: String,
        l1: String,
        l2: String,
        v1: f64,
        v2: f64,
    },
    #[error("coupling coefficient {k} of `{element}` is outside (0, 1]")]
    CouplingRange { span: Span, element: String, k: f64 },
    #[error("{kind} of `{element}` {problem}")]
    BadSourceArgs {
        span: Span,
        element: String,
        kind: &'static str,
        problem: String,
    },
    #[error("`{element}` has {what} {value}")]
    BadElementValue {
        span: Span,
        element: String,
        what: &'static str,
        value: f64,
    },
    #[error("node `{node}` in `{directive}` does not exist")]
    UnknownNode {
        span: Span,
        node: String,
        directive: &'static str,
    },
    #[error("`i({name})` names no voltage source, inductor or controlled source")]
    UnknownCurrent { span: Span, name: String },
    #[error("option `{name}` is {value}; it must be {range}")]
    BadOption {
        span: Span,
        name: String,
        /// As written.
        value: String,
        range: &'static str,
    },
    #[error("`.tran` needs 0 < TSTEP and TSTART < TSTOP")]
    BadTran { span: Span },
    #[error("unknown parameter `{name}` on model `{model}`")]
    UnknownModelParam {
        span: Span,
        name: String,
        model: String,
    },
    #[error("model parameter `{name}` is ignored by kausal")]
    IgnoredModelParam { span: Span, name: String },
    #[error("parameter `{name}` of `{element}` is ignored by kausal")]
    IgnoredElementParam {
        span: Span,
        name: String,
        element: String,
    },
    #[error(
        "`{element}` is inside a subcircuit instance with `m=`, which kausal applies to R, C, L and D only"
    )]
    UnscalableElement {
        span: Span,
        element: String,
        instance: Span,
    },
    #[error("option `{name}` is ignored by kausal")]
    IgnoredOption { span: Span, name: String },
    #[error("node `{node}` has only one connection")]
    DanglingNode { span: Span, node: String },
    #[error(
        "`.tran` asks for {points:.2e} output points (TSTOP/TSTEP): about {gigabytes:.0} GB of CSV"
    )]
    ManyOutputPoints {
        span: Span,
        points: f64,
        gigabytes: f64,
    },
    #[error(
        "`.tran` asks for {points:.1e} output points (TSTOP/TSTEP), more than kausal writes ({limit:.0e})"
    )]
    TooManyOutputPoints { span: Span, points: f64, limit: f64 },
    #[error(
        "TMAX {tmax:e} asks for more than {max_steps:.0e} steps over the run: kausal caps the step at {capped:e} instead"
    )]
    TinyTmax {
        span: Span,
        tmax: f64,
        max_steps: f64,
        capped: f64,
    },
    #[error(
        "model `{model}` has {tt} but no {cj}: kausal gives the junction a constant {cap} capacitance"
    )]
    TransitTimeWithoutCapacitance {
        span: Span,
        model: String,
        tt: &'static str,
        cj: &'static str,
        cap: &'static str,
    },
    #[error("`{name}` is a current source: ngspice takes PWL `{param}=` on voltage sources only")]
    PwlParamOnCurrent {
        span: Span,
        name: String,
        param: &'static str,
    },
}

impl ElabError {
    pub fn span(&self) -> Span {
        use ElabError::*;
        match self {
            UndefinedParam { span, .. }
            | BadValue { span, .. }
            | BadOption { span, .. }
            | UndefinedModel { span, .. }
            | WrongModelType { span, .. }
            | UnsupportedModel { span, .. }
            | BadDevice { span, .. }
            | ShortedElement { span, .. }
            | UndefinedSubckt { span, .. }
            | RecursiveSubckt { span, .. }
            | DeepHierarchy { span, .. }
            | TooManyElements { span, .. }
            | PortMismatch { span, .. }
            | DuplicatePort { span, .. }
            | NegativeCapacitance { span, .. }
            | DuplicateElement { span, .. }
            | SingleNode { span, .. }
            | UnknownControl { span, .. }
            | BadCoupling { span, .. }
            | CouplingRange { span, .. }
            | CouplingSigns { span, .. }
            | BadSourceArgs { span, .. }
            | BadElementValue { span, .. }
            | UnscalableElement { span, .. }
            | UnknownNode { span, .. }
            | UnknownCurrent { span, .. }
            | BadTran { span }
            | UnknownModelParam { span, .. }
            | IgnoredModelParam { span, .. }
            | IgnoredElementParam { span, .. }
            | IgnoredOption { span, .. }
            | DanglingNode { span, .. }
            | ManyOutputPoints { span, .. }
            | TooManyOutputPoints { span, .. }
            | TinyTmax { span, .. }
            | PwlParamOnCurrent { span, .. }
            | TransitTimeWithoutCapacitance { span, .. } => *span,
        }
    }

    pub fn severity(&self) -> Severity {
        use ElabError::*;
        match self {
            UnknownModelParam { .. }
            | IgnoredModelParam { .. }
            | IgnoredElementParam { .. }
            | IgnoredOption { .. }
            | DanglingNode { .. }
            | ManyOutputPoints { .. }
            | TinyTmax { .. }
            | PwlParamOnCurrent { .. }
            | TransitTimeWithoutCapacitance { .. }
            | DuplicatePort { .. }
            | NegativeCapacitance { .. }
            | ShortedElement { .. } => Severity::Warning,
            // An output vector naming nothing is left out, as ngspice leaves
            // it out (it warns and runs): Xyce's `v(*)`, `i(X1:L1)`.
            UnknownCurrent { .. } => Severity::Warning,
            UnknownNode { directive, .. } if *directive == "output" => Severity::Warning,
            _ => Severity::Error,
        }
    }
}

impl ToDiagnostic for ElabError {
    fn to_diagnostic(&self) -> Diagnostic {
        use ElabError::*;
        let (code, label, help): (codes::Code, &str, String) = match self {
            UndefinedParam { .. } => (codes::UNDEFINED_PARAM, "undefined", "define it with `.param NAME=VALUE` before use".into()),
            BadValue { .. } => (codes::BAD_VALUE, "here", "check the expression's functions and operands".into()),
            UndefinedModel { .. } => (codes::UNDEFINED_MODEL, "no such model", "add `.model NAME D(...)` or fix the name".into()),
            WrongModelType { expected, .. } => (codes::WRONG_MODEL_TYPE, "wrong model type", format!("this element needs a model of type `{expected}`")),
            UnsupportedModel { help, .. } => (codes::UNSUPPORTED_MODEL, "not modelled", (*help).into()),
            ShortedElement { .. } => (codes::SHORTED_ELEMENT, "both terminals here", "ngspice keeps it, and it changes nothing: remove it, or connect it where it was meant to be".into()),
            BadDevice { element, .. } => (codes::BAD_DEVICE, "here", device_usage(element).into()),
            UndefinedSubckt { .. } => (codes::UNDEFINED_SUBCKT, "no such subcircuit", "define it with `.subckt NAME ports ... .ends`".into()),
            RecursiveSubckt { .. } => (codes::RECURSIVE_SUBCKT, "recursive instance", "a subcircuit may not contain itself, directly or indirectly".into()),
            DeepHierarchy { .. } => (codes::DEEP_HIERARCHY, "too deep", "flatten some levels of the hierarchy".into()),
            TooManyElements { .. } => (codes::TOO_MANY_ELEMENTS, "expands past the limit here", "each instance copies its subcircuit, so a tree of instances grows exponentially with its depth; reduce its fan-out or depth".into()),
            PortMismatch { expected, .. } => (codes::PORT_MISMATCH, "wrong node count", format!("connect exactly {expected} nodes")),
            NegativeCapacitance { .. } => (codes::NEGATIVE_CAPACITANCE, "negative", "a macromodel's \"negative zero\" relies on the simulator to damp the mode it makes: ngspice's long steps do, and kausal's error control follows it as it grows (the smaller the resistance beside it, the faster); if the run stops in femtosecond steps, this is why".into()),
            DuplicatePort { .. } => (codes::DUPLICATE_PORT, "second time", "the node an instance connects here is left unconnected (it exists only where other elements use it); rename the port if both were meant".into()),
            DuplicateElement { .. } => (codes::DUPLICATE_ELEMENT, "second definition", "rename one of them".into()),
            SingleNode { .. } => (codes::SINGLE_NODE, "both terminals here", "an element must connect two different nodes".into()),
            UnknownControl { .. } => (codes::UNKNOWN_CONTROL, "not a V source", "F and H elements sense the current of a voltage source (add a 0 V source to measure it)".into()),
            BadCoupling { .. } => (codes::BAD_COUPLING, "not an inductor", "K couples two inductors: `K1 L1 L2 0.99`".into()),
            CouplingSigns { .. } => (codes::COUPLING_SIGNS, "this inductor", "an inductive system with a negative winding is not positive definite (ngspice says so too, then fails); give coupled inductors the same sign".into()),
            CouplingRange { .. } => (codes::COUPLING_RANGE, "out of range", "use 0 < k <= 1".into()),
            BadSourceArgs { .. } => (codes::BAD_SOURCE_ARGS, "here", "see the ngspice manual for the source function's arguments".into()),
            BadElementValue { .. } => (codes::BAD_ELEMENT_VALUE, "here", "use a nonzero, finite value".into()),
            UnscalableElement { .. } => (codes::UNSCALABLE_ELEMENT, "cannot be multiplied", "give the instance no `m=`, or write the parallel copies out".into()),
            UnknownNode { directive, .. } if *directive == "output" => (codes::UNKNOWN_NODE, "no such node", "the vector is left out, as ngspice leaves it out; check the node name".into()),
            UnknownNode { .. } => (codes::UNKNOWN_NODE, "no such node", "check the node name".into()),
            UnknownCurrent { .. } => (codes::UNKNOWN_CURRENT, "no such source", "the vector is left out, as ngspice leaves it out; ngspice names currents of V sources, e.g. `i(v1)`".into()),
            BadOption { .. } => (codes::BAD_OPTION, "out of range", "tolerances are positive and reltol below 1 (ngspice's defaults: reltol=1e-3 abstol=1e-12 vntol=1e-6 chgtol=1e-14 trtol=7); maxord is 1 to 6".into()),
            BadTran { .. } => (codes::BAD_TRAN, "here", "write `.tran TSTEP TSTOP [TSTART [TMAX]] [uic]`".into()),
            UnknownModelParam { .. } => (codes::UNKNOWN_MODEL_PARAM, "unknown", "it is not a parameter of ngspice's level-1 model of this type".into()),
            IgnoredModelParam { .. } => (codes::IGNORED_MODEL_PARAM, "ignored", "noise parameters and ngspice's safe-operating limits do not change a transient; a temperature coefficient kausal does not model changes it only away from the model's TNOM; ngspice's level 2 does not read UTRA either".into()),
            IgnoredElementParam { .. } => (codes::IGNORED_ELEMENT_PARAM, "ignored", "kausal does not model this instance parameter".into()),
            IgnoredOption { .. } => (codes::IGNORED_OPTION, "ignored", "kausal honours reltol, abstol, vntol, chgtol, trtol, method, maxord, temp and tnom".into()),
            DanglingNode { .. } => (codes::DANGLING_NODE, "dangling node", "a node with one connection carries no current".into()),
            PwlParamOnCurrent { .. } => (codes::PWL_PARAM_ON_CURRENT, "not in ngspice", "kausal runs it; for ngspice (and `kausal validate`) write the repeated points out".into()),
            TransitTimeWithoutCapacitance { .. } => (codes::TRANSIT_TIME_WITHOUT_CAPACITANCE, "transit time without capacitance", "a junction's charge is kausal's state for it, and diffusion charge alone (transit time × current) nearly vanishes in reverse bias: it could not fix the junction's voltage. ngspice has no such capacitance (`kausal validate` shows what it changes); give the zero-bias capacitance to choose it".into()),
            TinyTmax { .. } => (codes::TINY_TMAX, "TMAX", "TMAX is the longest step; a run of more steps than this would not end in reasonable time".into()),
            TooManyOutputPoints { .. } => (codes::TOO_MANY_OUTPUT_POINTS, "TSTEP", "TSTEP is the output spacing, not the solver's step: a larger TSTEP (or `--times` with a TSTEP that makes few points) keeps the output to what can be read".into()),
            ManyOutputPoints { .. } => (codes::MANY_OUTPUT_POINTS, "TSTEP", "TSTEP is the output spacing, not the solver's step (which follows the tolerance): a larger TSTEP, `--times`, or `.save` of fewer vectors makes the file smaller".into()),
        };
        let mut d = Diagnostic::error(code, self.to_string())
            .with_label(self.span(), label)
            .with_help(help);
        d.severity = self.severity();
        match self {
            DuplicateElement { first, .. } => d = d.with_label(*first, "first defined here"),
            PortMismatch { def, .. } => d = d.with_label(*def, "subcircuit defined here"),
            DuplicatePort { first, .. } => d = d.with_label(*first, "first named here"),
            UnscalableElement { instance, .. } => d = d.with_label(*instance, "the multiplier"),
            _ => {}
        }
        d
    }
}

/// How a device line is written, by the device's letter (the last path
/// segment's first character).
fn device_usage(element: &str) -> &'static str {
    let name = element.rsplit('.').next().unwrap_or(element);
    match name.chars().next().map(|c| c.to_ascii_uppercase()) {
        Some('M') => {
            "write `Mname drain gate source bulk model [L=…] [W=…] [AD=…] [AS=…] [PD=…] [PS=…] [NRD=…] [NRS=…] [m=…]`"
        }
        Some('J') => "write `Jname drain gate source model [area] [m=…]`",
        _ => "write `Qname collector base emitter [substrate] model [area] [m=…]`",
    }
}
