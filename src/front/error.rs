//! Errors and warnings of the front end (loading, lexing, parsing).

use super::load::{FileKind, LoadError, mib};
use crate::diag::codes;
use crate::diag::{Diagnostic, Severity, Span, ToDiagnostic};

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ParseError {
    #[error("the netlist is empty")]
    Empty { span: Span },
    #[error("`+` continuation line with nothing to continue")]
    StrayContinuation { span: Span },
    #[error("unterminated expression: missing `{close}`")]
    Unterminated { span: Span, close: char },
    #[error("unexpected {what}")]
    Unexpected { span: Span, what: String },
    #[error("unknown element type `{letter}`")]
    UnknownElement { span: Span, letter: char },
    #[error("{kind} (`{letter}`) elements are not supported by kausal")]
    UnsupportedElement {
        span: Span,
        letter: char,
        kind: &'static str,
    },
    #[error("element `{name}` needs {expected} nodes, found {found}")]
    MissingNode {
        span: Span,
        name: String,
        expected: usize,
        found: usize,
    },
    #[error("missing {what} for `{name}`")]
    MissingValue {
        span: Span,
        name: String,
        what: &'static str,
    },
    #[error("`{text}` is not a number")]
    BadNumber { span: Span, text: String },
    #[error("cannot parse expression `{text}`")]
    BadExpression { span: Span, text: String },
    #[error("expression too complex: {why}")]
    ComplexExpression { span: Span, why: String },
    #[error("`.subckt {name}` has no matching `.ends`")]
    UnclosedSubckt { span: Span, name: String },
    #[error("`.ends` without a `.subckt`")]
    StrayEnds { span: Span },
    #[error("`.control` block has no matching `.endc`")]
    UnclosedControl { span: Span },
    #[error("unknown directive `{name}`")]
    UnknownDirective { span: Span, name: String },
    #[error("model `{name}` is not defined")]
    AkoUndefined { span: Span, name: String },
    #[error("model `{orig}` has type `{orig_kind}`, but `{name}` needs a `{kind}` model")]
    AkoType {
        span: Span,
        name: String,
        kind: String,
        orig: String,
        orig_kind: String,
    },
    #[error("`{name}` is not supported by kausal")]
    UnsupportedDirective { span: Span, name: String },
    #[error("source function `{name}` is not supported by kausal")]
    UnsupportedSource { span: Span, name: String },
    #[error("`{name}` is a behavioural source (`{form}`), which kausal does not support")]
    BehavioralSource {
        span: Span,
        name: String,
        form: String,
    },
    #[error("cannot read include file `{path}`: {reason}")]
    IncludeNotFound {
        span: Span,
        path: String,
        reason: String,
    },
    #[error("cannot include `{path}`: it is {kind}, not a file")]
    IncludeNotAFile {
        span: Span,
        path: String,
        kind: FileKind,
    },
    #[error("cannot include `{path}`: it is larger than {}", mib(*limit))]
    IncludeTooLarge {
        span: Span,
        path: String,
        limit: u64,
    },
    #[error("byte 0x{byte:02X} is not UTF-8 text")]
    NotUtf8 { span: Span, byte: u8 },
    #[error("`{path}` includes itself")]
    IncludeCycle { span: Span, path: String },
    #[error("{what} nested more than {limit} deep")]
    TooDeep {
        span: Span,
        what: &'static str,
        limit: usize,
    },
    #[error("`{path}` has no library section `{section}`")]
    LibSectionNotFound {
        span: Span,
        path: String,
        section: String,
    },
    #[error("library section `.lib {section}` has no matching `.endl`")]
    UnclosedLib { span: Span, section: String },
    #[error("expected {expected}")]
    Expected { span: Span, expected: String },
    #[error("`{name}` is skipped: kausal runs transient analysis only")]
    SkippedAnalysis { span: Span, name: String },
    #[error("`.control` block skipped: kausal does not run ngspice scripts")]
    SkippedControl { span: Span },
    #[error("`.{name}` is ignored by kausal")]
    IgnoredDirective { span: Span, name: String },
    #[error("`{item}` on `.{directive}` is not a vector kausal writes: it is left out")]
    IgnoredOutput {
        span: Span,
        directive: String,
        item: String,
    },
    #[error("`.func {name}`'s arguments are not separated by commas")]
    FuncArgsWithoutComma { span: Span, name: String },
    #[error("`{text}` in the parameters of model `{model}` names no parameter and is ignored")]
    StrayModelValue {
        span: Span,
        text: String,
        model: String,
    },
}

impl ParseError {
    pub fn span(&self) -> Span {
        use ParseError::*;
        match self {
            Empty { span }
            | StrayContinuation { span }
            | Unterminated { span, .. }
            | Unexpected { span, .. }
            | UnknownElement { span, .. }
            | UnsupportedElement { span, .. }
            | MissingNode { span, .. }
            | MissingValue { span, .. }
            | BadNumber { span, .. }
            | BadExpression { span, .. }
            | ComplexExpression { span, .. }
            | UnclosedSubckt { span, .. }
            | StrayEnds { span }
            | UnclosedControl { span }
            | UnknownDirective { span, .. }
            | AkoUndefined { span, .. }
            | AkoType { span, .. }
            | UnsupportedDirective { span, .. }
            | UnsupportedSource { span, .. }
            | BehavioralSource { span, .. }
            | IncludeNotFound { span, .. }
            | IncludeNotAFile { span, .. }
            | IncludeTooLarge { span, .. }
            | NotUtf8 { span, .. }
            | IncludeCycle { span, .. }
            | TooDeep { span, .. }
            | LibSectionNotFound { span, .. }
            | UnclosedLib { span, .. }
            | Expected { span, .. }
            | SkippedAnalysis { span, .. }
            | SkippedControl { span }
            | IgnoredDirective { span, .. }
            | IgnoredOutput { span, .. }
            | FuncArgsWithoutComma { span, .. }
            | StrayModelValue { span, .. } => *span,
        }
    }

    pub fn severity(&self) -> Severity {
        match self {
            ParseError::SkippedAnalysis { .. }
            | ParseError::SkippedControl { .. }
            | ParseError::IgnoredDirective { .. }
            | ParseError::IgnoredOutput { .. }
            | ParseError::FuncArgsWithoutComma { .. }
            | ParseError::StrayModelValue { .. } => Severity::Warning,
            _ => Severity::Error,
        }
    }

    fn code_and_help(&self) -> (codes::Code, &'static str, String) {
        use ParseError::*;
        match self {
            Empty { .. } => (codes::EMPTY, "", "a netlist is a title line followed by elements".into()),
            StrayContinuation { .. } => (codes::STRAY_CONTINUATION, "continuation", "a `+` line continues the line above it; put it after an element or directive".into()),
            Unterminated { close, .. } => (codes::UNTERMINATED, "opened here", format!("close the expression with `{close}`")),
            Unexpected { .. } => (codes::UNEXPECTED, "unexpected", "remove it or check the element's syntax in the ngspice manual".into()),
            UnknownElement { .. } => (codes::UNKNOWN_ELEMENT, "unknown element", "element names start with R, C, L, K, V, I, E, F, G, H, D or X".into()),
            UnsupportedElement { .. } => (codes::UNSUPPORTED_ELEMENT, "not supported", "kausal supports R, C, L, K, V, I, E, F, G, H, D, B, Q, J, M, S, W and X elements".into()),
            MissingNode { expected, .. } => (codes::MISSING_NODE, "missing node", format!("write {expected} node names after the element name")),
            MissingValue { .. } => (codes::MISSING_VALUE, "value missing", "add the value after the nodes, e.g. `R1 a b 1k`".into()),
            BadNumber { text, .. } => (codes::BAD_NUMBER, "bad number", match crate::front::expr::parse_rkm(text) {
                // RKM notation, which ngspice reads only in its LTspice
                // compatibility mode (otherwise it ignores what follows
                // the scale letter).
                Some(v) => format!("`{text}` is RKM notation for {v}; ngspice reads it so only in its LTspice compatibility mode, and otherwise ignores what follows the scale letter: write `{v}`"),
                None => "numbers look like `10`, `1.5e-3`, `4.7k`, `10uF` or `3meg`".into(),
            }),
            TooDeep { .. } => (codes::TOO_DEEP, "too deep", "flatten the nesting: subcircuits can instantiate each other without being defined inside each other".into()),
            FuncArgsWithoutComma { .. } => (codes::FUNC_ARGS_WITHOUT_COMMA, "no comma", "kausal reads them; ngspice needs `f(x, y)`".into()),
            ComplexExpression { .. } => (codes::COMPLEX_EXPRESSION, "here", "split it with `.param`s or `.func`s".into()),
            BadExpression { .. } => (codes::BAD_EXPRESSION, "bad expression", "expressions use numbers, parameters, + - * / ** and functions like sqrt()".into()),
            UnclosedSubckt { .. } => (codes::UNCLOSED_SUBCKT, "opened here", "end the subcircuit with `.ends`".into()),
            StrayEnds { .. } => (codes::STRAY_ENDS, "no open subcircuit", "remove it, or add the `.subckt` line it closes".into()),
            UnclosedControl { .. } => (codes::UNCLOSED_CONTROL, "opened here", "end the block with `.endc`".into()),
            AkoUndefined { .. } => (codes::UNDEFINED_MODEL, "`AKO:` names it", "define it with `.model` in the same subcircuit or at the top level (as ngspice's PSpice compatibility mode looks it up)".into()),
            AkoType { orig_kind, .. } => (codes::WRONG_MODEL_TYPE, "`AKO:` names it", format!("a model made from another keeps its type: write `{orig_kind}`, or name a model of the type you need")),
            UnknownDirective { .. } => (codes::UNKNOWN_DIRECTIVE, "unknown directive", "check the spelling against the ngspice manual".into()),
            UnsupportedDirective { .. } => (codes::UNSUPPORTED_DIRECTIVE, "not supported", "remove it. kausal reads these directives: param, subckt, model, include, lib, global, func, ic, tran, options, print, save, probe".into()),
            UnsupportedSource { .. } => (codes::UNSUPPORTED_SOURCE, "not supported", "use DC, PULSE, SIN, PWL or EXP".into()),
            BehavioralSource { .. } => (codes::BEHAVIORAL_SOURCE, "not supported", "write it as an expression, `E1 out 0 VALUE={...}` or a B source `B1 out 0 V={...}` (POLY is read too), or linear: `E1 out 0 in 0 GAIN`".into()),
            IncludeNotFound { .. } => (codes::INCLUDE_NOT_FOUND, "included here", "include paths are relative to the including file".into()),
            IncludeNotAFile { .. } => (codes::NOT_A_FILE, "included here", "`.include` and `.lib` read regular files only".into()),
            IncludeTooLarge { limit, .. } => (codes::FILE_TOO_LARGE, "included here", format!("kausal reads netlist files of up to {}", mib(*limit))),
            NotUtf8 { .. } => (codes::NOT_UTF8, "not UTF-8", "save the file as UTF-8 (or ASCII); other bytes are accepted in comments only".into()),
            IncludeCycle { .. } => (codes::INCLUDE_CYCLE, "included again here", "remove the circular `.include` or `.lib`".into()),
            LibSectionNotFound { .. } => (codes::LIB_SECTION_NOT_FOUND, "no such section", "sections are opened by `.lib NAME` and closed by `.endl` in the library file".into()),
            UnclosedLib { .. } => (codes::UNCLOSED_LIB, "opened here", "close the section with `.endl`".into()),
            Expected { .. } => (codes::EXPECTED, "here", "see the ngspice manual for the statement's syntax".into()),
            SkippedAnalysis { .. } => (codes::SKIPPED_ANALYSIS, "skipped", "only `.tran` analyses are run".into()),
            StrayModelValue { .. } => (codes::STRAY_MODEL_VALUE, "no parameter", "ngspice ignores it too (a decimal comma, `M=0,2`, reads as `M=0` and a stray `2`); write `M=0.2` if that was meant".into()),
            IgnoredOutput { .. } => (codes::IGNORED_OUTPUT, "left out", "kausal writes node voltages `v(node)`, `v(node1,node2)` and currents `i(source)`; ngspice also skips what it cannot print".into()),
            SkippedControl { .. } => (codes::SKIPPED_CONTROL, "skipped", "use `.tran`, `.print` and `.options` instead of a control script".into()),
            IgnoredDirective { name, .. } => (codes::IGNORED_DIRECTIVE, "ignored", match name.as_str() {
                "temp" => "kausal's devices are at 27 °C (ngspice's default): at another .temp ngspice's diodes conduct differently".into(),
                _ => "it does not affect the transient run as kausal performs it".into(),
            }),
        }
    }
}

impl ParseError {
    /// `.include` or `.lib` of `path` (written at `span`) whose loader failed.
    pub fn include_failed(span: Span, path: String, error: LoadError) -> ParseError {
        match error {
            LoadError::Io(e) => ParseError::IncludeNotFound {
                span,
                path,
                reason: e.to_string(),
            },
            LoadError::NotAFile { kind } => ParseError::IncludeNotAFile { span, path, kind },
            LoadError::TooLarge { limit } => ParseError::IncludeTooLarge { span, path, limit },
        }
    }
}

/// The netlist file named on the command line could not be read; it has no
/// span (an include's failure is a [`ParseError`] at its `.include` line).
#[derive(Debug, thiserror::Error)]
#[error("cannot read `{path}`: {error}")]
pub struct ReadError {
    pub path: String,
    pub error: LoadError,
}

impl ToDiagnostic for ReadError {
    fn to_diagnostic(&self) -> Diagnostic {
        let (code, help) = match &self.error {
            LoadError::Io(_) => (codes::READ_FAILED, "check the path".to_string()),
            LoadError::NotAFile { .. } => (
                codes::NOT_A_FILE,
                "give the path of a netlist file".to_string(),
            ),
            LoadError::TooLarge { limit } => (
                codes::FILE_TOO_LARGE,
                format!("kausal reads netlist files of up to {}", mib(*limit)),
            ),
        };
        Diagnostic::error(code, self.to_string()).with_help(help)
    }
}

impl ToDiagnostic for ParseError {
    fn to_diagnostic(&self) -> Diagnostic {
        let (code, label, help) = self.code_and_help();
        let mut d = Diagnostic::error(code, self.to_string()).with_label(self.span(), label);
        d.severity = self.severity();
        if !help.is_empty() {
            d = d.with_help(help);
        }
        d
    }
}
