//! Every diagnostic code kausal emits, in one table: its stable id, the
//! constant the code names it by, and what it means. Ranges: K00xx input
//! files, K01xx parsing, K02xx elaboration, K03xx structure, K04xx
//! simulation, K05xx validation.

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
    EMPTY = "K0100", "Empty.";
    STRAY_CONTINUATION = "K0101", "Stray continuation.";
    UNTERMINATED = "K0102", "Unterminated.";
    UNEXPECTED = "K0103", "Unexpected.";
    UNKNOWN_ELEMENT = "K0104", "Unknown element.";
    UNSUPPORTED_ELEMENT = "K0105", "Unsupported element.";
    MISSING_NODE = "K0106", "Missing node.";
    MISSING_VALUE = "K0107", "Missing value.";
    BAD_NUMBER = "K0108", "Bad number.";
    BAD_EXPRESSION = "K0109", "Bad expression.";
    UNCLOSED_SUBCKT = "K0110", "Unclosed subckt.";
    STRAY_ENDS = "K0111", "Stray ends.";
    UNCLOSED_CONTROL = "K0112", "Unclosed control.";
    UNKNOWN_DIRECTIVE = "K0113", "Unknown directive.";
    UNSUPPORTED_DIRECTIVE = "K0114", "Unsupported directive.";
    UNSUPPORTED_SOURCE = "K0115", "Unsupported source.";
    INCLUDE_NOT_FOUND = "K0116", "Include not found.";
    INCLUDE_CYCLE = "K0117", "Include cycle.";
    EXPECTED = "K0118", "Expected.";
    LIB_SECTION_NOT_FOUND = "K0119", "Lib section not found.";
    UNCLOSED_LIB = "K0120", "Unclosed lib.";
    BEHAVIORAL_SOURCE = "K0121", "Behavioral source.";
    COMPLEX_EXPRESSION = "K0122", "Complex expression.";
    TOO_DEEP = "K0123", "Too deep.";
    FUNC_ARGS_WITHOUT_COMMA = "K0124", "Func args without comma.";
    SKIPPED_ANALYSIS = "K0190", "Skipped analysis.";
    SKIPPED_CONTROL = "K0191", "Skipped control.";
    IGNORED_DIRECTIVE = "K0192", "Ignored directive.";
    UNDEFINED_PARAM = "K0200", "Undefined param.";
    BAD_VALUE = "K0201", "Bad value.";
    UNDEFINED_MODEL = "K0202", "Undefined model.";
    WRONG_MODEL_TYPE = "K0203", "Wrong model type.";
    UNDEFINED_SUBCKT = "K0204", "Undefined subckt.";
    RECURSIVE_SUBCKT = "K0205", "Recursive subckt.";
    PORT_MISMATCH = "K0206", "Port mismatch.";
    DUPLICATE_ELEMENT = "K0207", "Duplicate element.";
    SINGLE_NODE = "K0208", "Single node.";
    UNKNOWN_CONTROL = "K0209", "Unknown control.";
    BAD_COUPLING = "K0210", "Bad coupling.";
    COUPLING_RANGE = "K0211", "Coupling range.";
    BAD_SOURCE_ARGS = "K0212", "Bad source args.";
    BAD_ELEMENT_VALUE = "K0213", "Bad element value.";
    UNKNOWN_NODE = "K0214", "Unknown node.";
    UNKNOWN_CURRENT = "K0215", "Unknown current.";
    BAD_TRAN = "K0216", "Bad tran.";
    UNSCALABLE_ELEMENT = "K0217", "Unscalable element.";
    BAD_OPTION = "K0218", "Bad option.";
    DEEP_HIERARCHY = "K0219", "Deep hierarchy.";
    UNKNOWN_MODEL_PARAM = "K0290", "Unknown model param.";
    IGNORED_MODEL_PARAM = "K0291", "Ignored model param.";
    IGNORED_ELEMENT_PARAM = "K0292", "Ignored element param.";
    IGNORED_OPTION = "K0293", "Ignored option.";
    DANGLING_NODE = "K0294", "Dangling node.";
    MANY_OUTPUT_POINTS = "K0295", "Many output points.";
    PWL_PARAM_ON_CURRENT = "K0296", "Pwl param on current.";
    TRANSIT_TIME_WITHOUT_CAPACITANCE = "K0297", "Transit time without capacitance.";
    STRUCTURALLY_SINGULAR = "K0300", "The equations are structurally singular.";
    ALGEBRAIC_LOOPS = "K0301", "Algebraic loops that could not be solved.";
    UNBALANCED = "K0302", "More equations than unknowns, or fewer.";
    INDEX_LIMIT = "K0303", "Index reduction did not finish.";
    NO_STATE_IN_CONSTRAINT = "K0304", "A constraint between states that index reduction cannot differentiate.";
    COUPLED_STATES = "K0310", "A capacitor loop or inductor cutset: index reduction removes a state.";
    CONFLICTING_TOPOLOGY = "K0311", "A voltage-source loop, current-source cutset or floating node.";
    PREFER_STATE_UNKNOWN = "K0320", "--prefer-state names no element.";
    PREFER_STATE_NOT_STORAGE = "K0321", "--prefer-state names an element without a state.";
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
    VALIDATE_FAILED = "K0500", "Validation against ngspice failed.";
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
