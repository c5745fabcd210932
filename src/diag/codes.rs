//! Every diagnostic code kausal emits, in one table: its stable id, the
//! constant the code names it by, and what it means. Ranges: K00xx input
//! files, K01xx parsing, K02xx elaboration, K03xx structure, K04xx
//! simulation, K05xx validation, K06xx bond graphs.

use std::fmt;

/// A stable diagnostic code (`K0102`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Code {
    /// The id users see and search for.
    pub id: &'static str,
    /// What the code means, in a few words.
    pub meaning: &'static str,
}

impl fmt::Display for Code {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.id)
    }
}

impl PartialEq<&str> for Code {
    fn eq(&self, other: &&str) -> bool {
        self.id == *other
    }
}

macro_rules! codes {
    ($($name:ident = $id:literal, $meaning:literal;)*) => {
        $(
            #[doc = $meaning]
            pub const $name: Code = Code { id: $id, meaning: $meaning };
        )*
        /// Every code, in the order of the table.
        pub const ALL: &[Code] = &[$($name),*];
    };
}

codes! {
    READ_FAILED = "K0001", "A netlist or include file could not be read.";
    NOT_A_FILE = "K0002", "A netlist or include path names a directory, FIFO or device, not a file.";
    FILE_TOO_LARGE = "K0003", "A netlist or include file is larger than kausal reads.";
    NOT_UTF8 = "K0004", "A statement holds bytes that are not UTF-8 text.";
    EMPTY = "K0100", "The netlist is empty.";
    STRAY_CONTINUATION = "K0101", "`+` continuation line with nothing to continue.";
    UNTERMINATED = "K0102", "Unterminated expression: missing `…`.";
    UNEXPECTED = "K0103", "Unexpected ….";
    UNKNOWN_ELEMENT = "K0104", "Unknown element type `…`.";
    UNSUPPORTED_ELEMENT = "K0105", "… (`…`) elements are not supported by kausal.";
    MISSING_NODE = "K0106", "Element `…` needs … nodes, found ….";
    MISSING_VALUE = "K0107", "Missing … for `…`.";
    BAD_NUMBER = "K0108", "`…` is not a number.";
    BAD_EXPRESSION = "K0109", "Cannot parse expression `…`.";
    UNCLOSED_SUBCKT = "K0110", "`.subckt …` has no matching `.ends`.";
    STRAY_ENDS = "K0111", "`.ends` without a `.subckt`.";
    UNCLOSED_CONTROL = "K0112", "`.control` block has no matching `.endc`.";
    UNKNOWN_DIRECTIVE = "K0113", "Unknown directive `…`.";
    UNSUPPORTED_DIRECTIVE = "K0114", "`…` is not supported by kausal.";
    UNSUPPORTED_SOURCE = "K0115", "Source function `…` is not supported by kausal.";
    INCLUDE_NOT_FOUND = "K0116", "Cannot read include file `…`: ….";
    INCLUDE_CYCLE = "K0117", "`…` includes itself.";
    EXPECTED = "K0118", "Expected ….";
    LIB_SECTION_NOT_FOUND = "K0119", "`…` has no library section `…`.";
    UNCLOSED_LIB = "K0120", "Library section `.lib …` has no matching `.endl`.";
    BEHAVIORAL_SOURCE = "K0121", "`…` is a behavioural source (`…`), which kausal does not support.";
    COMPLEX_EXPRESSION = "K0122", "Expression too complex: ….";
    TOO_DEEP = "K0123", "… nested more than … deep.";
    FUNC_ARGS_WITHOUT_COMMA = "K0124", "`.func …`'s arguments are not separated by commas.";
    SKIPPED_ANALYSIS = "K0190", "`…` is skipped: kausal runs transient analysis only.";
    SKIPPED_CONTROL = "K0191", "`.control` block skipped: kausal does not run ngspice scripts.";
    IGNORED_DIRECTIVE = "K0192", "`.…` is ignored by kausal.";
    IGNORED_OUTPUT = "K0193", "An output item kausal does not write (`vdb(…)`, `@r1[i]`, an expression) is left out.";
    STRAY_MODEL_VALUE = "K0194", "A value with no parameter name in a `.model` card is ignored.";
    UNDEFINED_PARAM = "K0200", "Parameter `…` is not defined.";
    BAD_VALUE = "K0201", "Cannot evaluate `…`: ….";
    UNDEFINED_MODEL = "K0202", "Model `…` is not defined.";
    WRONG_MODEL_TYPE = "K0203", "Model `…` has type `…`, but `…` needs a `…` model.";
    UNDEFINED_SUBCKT = "K0204", "Subcircuit `…` is not defined.";
    RECURSIVE_SUBCKT = "K0205", "Subcircuit `…` instantiates itself (…).";
    PORT_MISMATCH = "K0206", "`…` connects … nodes, but subcircuit `…` has … ports.";
    DUPLICATE_ELEMENT = "K0207", "Element `…` is defined twice.";
    SINGLE_NODE = "K0208", "`…` has both terminals on node `…`.";
    UNKNOWN_CONTROL = "K0209", "`…` is controlled by `…`, which is not a voltage source of this circuit.";
    BAD_COUPLING = "K0210", "`…` couples `…`, which is not an inductor of this circuit.";
    COUPLING_RANGE = "K0211", "Coupling coefficient … of `…` is outside (0, 1].";
    BAD_SOURCE_ARGS = "K0212", "… of `…` ….";
    BAD_ELEMENT_VALUE = "K0213", "`…` has … ….";
    UNKNOWN_NODE = "K0214", "Node `…` in `…` does not exist.";
    UNKNOWN_CURRENT = "K0215", "`i(…)` names no voltage source, inductor or controlled source.";
    BAD_TRAN = "K0216", "`.tran` needs 0 < TSTEP and TSTART < TSTOP.";
    UNSCALABLE_ELEMENT = "K0217", "`…` is inside a subcircuit instance with `m=`, which kausal applies to R, C, L and D only.";
    BAD_OPTION = "K0218", "Option `…` is …; it must be ….";
    DEEP_HIERARCHY = "K0219", "Instantiating `…` nests subcircuits more than … deep.";
    TOO_MANY_ELEMENTS = "K0220", "The circuit has more than … elements once its subcircuits are expanded.";
    COUPLING_SIGNS = "K0221", "`…` couples `…` and `…`, of opposite signs.";
    TOO_MANY_OUTPUT_POINTS = "K0222", "`.tran` asks for … output points, more than kausal writes (…).";
    UNSUPPORTED_MODEL = "K0223", "Model `…` is …, which kausal does not model.";
    BAD_DEVICE = "K0224", "`…`: ….";
    NEGATIVE_CAPACITANCE = "K0287", "`…` has a negative capacitance: a mode through it can grow in time.";
    DUPLICATE_PORT = "K0288", "Port `…` is named twice in `.subckt …`: ngspice connects it to the first node.";
    SHORTED_ELEMENT = "K0289", "`…` has both terminals on node `…`: it carries no current and is left out.";
    UNKNOWN_MODEL_PARAM = "K0290", "Unknown parameter `…` on model `…`.";
    IGNORED_MODEL_PARAM = "K0291", "Model parameter `…` is ignored by kausal.";
    IGNORED_ELEMENT_PARAM = "K0292", "Parameter `…` of `…` is ignored by kausal.";
    IGNORED_OPTION = "K0293", "Option `…` is ignored by kausal.";
    DANGLING_NODE = "K0294", "Node `…` has only one connection.";
    MANY_OUTPUT_POINTS = "K0295", "`.tran` asks for … output points (TSTOP/TSTEP): about … GB of CSV.";
    PWL_PARAM_ON_CURRENT = "K0296", "`…` is a current source: ngspice takes PWL `…=` on voltage sources only.";
    TRANSIT_TIME_WITHOUT_CAPACITANCE = "K0297", "Model `…` has … but no …: kausal gives the junction a constant … capacitance.";
    TINY_TMAX = "K0298", "`.tran`'s TMAX asks for more steps than kausal takes: the step cap is raised.";
    STRUCTURALLY_SINGULAR = "K0300", "The equations are structurally singular.";
    ALGEBRAIC_LOOPS = "K0301", "Algebraic loops that could not be solved.";
    UNBALANCED = "K0302", "More equations than unknowns, or fewer.";
    INDEX_LIMIT = "K0303", "Index reduction did not finish.";
    NO_STATE_IN_CONSTRAINT = "K0304", "A constraint between states that index reduction cannot differentiate.";
    COUPLED_STATES = "K0310", "A capacitor loop or inductor cutset: index reduction removes a state.";
    CONFLICTING_TOPOLOGY = "K0311", "A voltage-source loop, current-source cutset or floating node.";
    FORCED_JUNCTION = "K0312", "A diode without series resistance whose voltage voltage sources fix.";
    PREFER_STATE_UNKNOWN = "K0320", "--prefer-state names no element.";
    PREFER_STATE_NOT_STORAGE = "K0321", "--prefer-state names an element without a state.";
    PERFECT_COUPLING = "K0330", "Coupled inductors with a singular inductance matrix: fluxes are the states.";
    INDEFINITE_COUPLING = "K0331", "Coupled inductors whose inductance matrix is indefinite: a negative magnetic energy.";
    NO_TRAN = "K0400", "The netlist has no .tran line.";
    UNKNOWN_PROBE = "K0401", "An output vector names no node or element.";
    EVAL_FAILED = "K0402", "An algebraic loop has no solution at some time.";
    NON_FINITE = "K0403", "A value became infinite or NaN.";
    STEP_UNDERFLOW = "K0404", "The step size fell below the run's minimum.";
    SOLVER_FAILED = "K0405", "The integrator failed.";
    DC_FAILED = "K0406", "No DC operating point.";
    WRITE_FAILED = "K0407", "An output file could not be written.";
    IC_NOT_HELD = "K0408", "An .ic or .nodeset value cannot be held.";
    RINGING = "K0409", "A lightly damped mode keeps the steps short.";
    BDF_ON_LIGHT_DAMPING = "K0410", "BDF at a loose tolerance on a lightly damped mode.";
    BAD_TOLERANCE = "K0411", "A tolerance out of range.";
    BDF_STALLED = "K0412", "BDF's steps stalled at a stability limit; ESDIRK34 took over.";
    NO_PROGRESS = "K0413", "The run stopped making progress within its step budget.";
    FIXED_STEP_BOUND = "K0414", "A fixed-step method's stability bound, and where the step stands.";
    BLEW_UP = "K0415", "A fixed-step run blew up: its step is past the stability bound.";
    FIXED_STEP = "K0416", "A step length given to a method that has none, or missing where needed.";
    SWITCH_METHOD = "K0417", "Switch events are located by the adaptive diffsol methods only.";
    CHATTER = "K0418", "A B source's comparison chatters at its threshold (a sliding mode).";
    DENSE_JACOBIAN = "K0419", "The Jacobian is too dense to integrate.";
    VALIDATE_FAILED = "K0500", "Validation against ngspice failed.";
    CAUSAL_CONFLICT = "K0600", "A causal conflict in the bond graph: a junction or source whose causality cannot be met.";
    VIEWS_DISAGREE = "K0601", "The bond graph's causality and the equations' sorting disagree (`kausal bondgraph --check`).";
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_are_unique_and_ordered() {
        for pair in ALL.windows(2) {
            assert!(
                pair[0].id < pair[1].id,
                "{} before {}",
                pair[0].id,
                pair[1].id
            );
        }
        for c in ALL {
            assert!(c.id.len() == 5 && c.id.starts_with('K'), "{}", c.id);
            assert!(c.id[1..].bytes().all(|b| b.is_ascii_digit()), "{}", c.id);
        }
    }
}
