//! Argument types shared by several subcommands: output formats, the build
//! options, the command line's own value enums (converted into the library's
//! types, which know nothing of clap) and the parsers of tolerances.

use clap::ValueEnum;
use kausal::build;

/// Output format of `equations` and `validate`.
#[derive(Clone, Copy, Debug, ValueEnum, PartialEq, Eq)]
pub enum Format {
    Text,
    Json,
}

/// How Kirchhoff's voltage law is written: [`build::Kvl`] on the command line.
#[derive(Clone, Copy, Debug, ValueEnum, PartialEq, Eq)]
pub enum Kvl {
    /// Node potentials and one branch equation per element.
    Nodes,
    /// KVL on the fundamental loops of a spanning tree (no node potentials).
    Loops,
}

impl From<Kvl> for build::Kvl {
    fn from(kvl: Kvl) -> Self {
        match kvl {
            Kvl::Nodes => build::Kvl::Nodes,
            Kvl::Loops => build::Kvl::Loops,
        }
    }
}

/// The target language of generated source: [`kausal::back::codegen::Lang`]
/// on the command line.
#[derive(Clone, Copy, Debug, ValueEnum, PartialEq, Eq)]
pub enum Lang {
    Rust,
    C,
}

impl From<Lang> for kausal::back::codegen::Lang {
    fn from(lang: Lang) -> Self {
        use kausal::back::codegen::Lang as L;
        match lang {
            Lang::Rust => L::Rust,
            Lang::C => L::C,
        }
    }
}

/// The integration method: [`kausal::sim::Method`] on the command line. The
/// variants' docs are the help text of `--method` and `--solvers`.
#[derive(Clone, Copy, Debug, ValueEnum, PartialEq, Eq)]
pub enum Method {
    /// Variable-order BDF (stiff; the default). Its orders above 2 are not
    /// A-stable: on an undamped oscillator (an LC tank) at a loose --rtol
    /// (1e-2) the amplitude can grow; tr-bdf2 cannot.
    Bdf,
    /// TR-BDF2, an L-stable SDIRK (stiff).
    TrBdf2,
    /// ESDIRK34 (stiff, 4th order).
    Esdirk34,
    /// Tsitouras 5(4), explicit (non-stiff circuits only).
    Tsit5,
    /// TR-BDF2 for circuits (kausal's own, small circuits): every output
    /// point is a step, and each state's error is measured against its
    /// largest magnitude so far, as circuit simulators measure it; fastest
    /// on switching circuits (rectifiers).
    Circuit,
    /// `circuit` with one BDF2 stage per step after the first (ngspice's
    /// gear of order 2) where TR-BDF2 has two: half the work of a step
    /// bound by TMAX or the output spacing; about as much as `circuit`
    /// where the error test sets the steps (its error constant is 5.5
    /// times TR-BDF2's).
    Gear2,
    /// Forward Euler at a fixed --step (seed 004; no error control).
    Euler,
    /// Runge–Kutta 2 (the midpoint rule) at a fixed --step (seed 004).
    Rk2,
    /// Runge–Kutta 4 at a fixed --step (seed 004). Before the run kausal
    /// states the longest stable step on the circuit.
    Rk4,
}

impl From<Method> for kausal::sim::Method {
    fn from(method: Method) -> Self {
        use kausal::sim::Method as M;
        match method {
            Method::Bdf => M::Bdf,
            Method::TrBdf2 => M::TrBdf2,
            Method::Esdirk34 => M::Esdirk34,
            Method::Tsit5 => M::Tsit5,
            Method::Circuit => M::Circuit,
            Method::Gear2 => M::Gear2,
            Method::Euler => M::Euler,
            Method::Rk2 => M::Rk2,
            Method::Rk4 => M::Rk4,
        }
    }
}

/// The build options of `equations`, `sort` and `sim`.
#[derive(clap::Args)]
pub struct BuildArgs {
    /// How Kirchhoff's voltage law is written.
    #[arg(long, value_enum, default_value_t = Kvl::Nodes)]
    kvl: Kvl,
    /// Eliminate alias equations (`x = y`, `x = -y`, `x = known`).
    #[arg(long)]
    alias: bool,
}

impl BuildArgs {
    pub fn options(&self) -> build::Options {
        build::Options {
            kvl: self.kvl.into(),
            alias: self.alias,
            algebraic_charges: false,
        }
    }
}

/// A relative tolerance: a number in (0, 1).
pub fn relative_tolerance(s: &str) -> Result<f64, String> {
    let x: f64 = s.trim().parse().map_err(|e| format!("`{s}`: {e}"))?;
    if x > 0.0 && x < 1.0 {
        Ok(x)
    } else {
        Err(format!("{s} is not in (0, 1): e.g. 1e-6"))
    }
}

/// An absolute tolerance or bound: a finite number above 0, in SPICE's
/// notation as well (`1u`, `20n`, `1e-6`).
pub fn positive(s: &str) -> Result<f64, String> {
    let x = kausal::front::expr::parse_number(s.trim())
        .ok_or_else(|| format!("`{s}` is not a number (write it as 1e-6, 1u or 0.000001)"))?;
    if x > 0.0 && x.is_finite() {
        Ok(x)
    } else {
        Err(format!("{s} is not a finite number above 0"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `--tmax 1u` reads as a netlist would; zero, negatives and words are
    /// refused.
    #[test]
    fn positive_numbers_take_spice_suffixes() {
        assert_eq!(positive("1u"), Ok(1e-6));
        assert_eq!(positive("20n"), Ok(20e-9));
        assert_eq!(positive(" 1e-6 "), Ok(1e-6));
        assert_eq!(positive("0.5"), Ok(0.5));
        for bad in ["0", "-1u", "abc", "", "1u2"] {
            assert!(positive(bad).is_err(), "{bad:?} was accepted");
        }
    }

    /// Every library value has its command-line twin under the same name: a
    /// variant added to the library fails to compile here until it is added
    /// to the command line.
    #[test]
    fn value_enums_mirror_the_library() {
        use kausal::back::codegen::Lang as L;
        use kausal::sim::Method as M;
        let kvl = |k: build::Kvl| match k {
            build::Kvl::Nodes => Kvl::Nodes,
            build::Kvl::Loops => Kvl::Loops,
        };
        let lang = |l: L| match l {
            L::Rust => Lang::Rust,
            L::C => Lang::C,
        };
        let method = |m: M| match m {
            M::Bdf => Method::Bdf,
            M::TrBdf2 => Method::TrBdf2,
            M::Esdirk34 => Method::Esdirk34,
            M::Tsit5 => Method::Tsit5,
            M::Circuit => Method::Circuit,
            M::Gear2 => Method::Gear2,
            M::Euler => Method::Euler,
            M::Rk2 => Method::Rk2,
            M::Rk4 => Method::Rk4,
        };
        for &k in Kvl::value_variants() {
            assert_eq!(kvl(k.into()), k);
        }
        for &l in Lang::value_variants() {
            assert_eq!(lang(l.into()), l);
        }
        for &m in Method::value_variants() {
            assert_eq!(method(m.into()), m);
        }
    }
}
