//! Equation building: snapshots of every netlist's equations, the IR
//! verifier, and seed example A in the loop formulation.

use kausal::build::{Kvl, Options};
use kausal::io::FsLoader;
use kausal::ir::{self, print};
use kausal::pipeline;

use crate::{goldens, netlists, stem};

#[test]
fn equations_of_every_netlist() {
    for path in netlists() {
        let (_, built) = match pipeline::equations(&path, &FsLoader, Options::default()) {
            Ok(x) => x,
            Err(f) => panic!(
                "{}: {:?}",
                path.display(),
                f.errors().map(|d| d.message.clone()).collect::<Vec<_>>()
            ),
        };
        assert_eq!(ir::verify(&built.system), vec![], "{}", path.display());
        let text = print::system(&built.system, 40);
        goldens("equations").bind(|| insta::assert_snapshot!(stem(&path), text));
    }
}

#[test]
fn every_formulation_verifies() {
    for path in netlists() {
        let el = pipeline::elaborate_file(&path, &FsLoader).ok().unwrap();
        // Every formulation, and the DC image's algebraic charges (no
        // charge is then a state).
        for kvl in [Kvl::Nodes, Kvl::Loops] {
            for (alias, algebraic_charges) in [(false, false), (true, false), (false, true)] {
                let opts = Options {
                    kvl,
                    alias,
                    algebraic_charges,
                };
                let built = kausal::build::build(&el.circuit, opts);
                assert_eq!(ir::verify(&built.system), vec![], "{}", path.display());
                assert_eq!(
                    built.system.eqs.len(),
                    built.system.n_unknowns(),
                    "{} {opts:?}: equations and unknowns differ",
                    path.display()
                );
                if algebraic_charges {
                    let sys = &built.system;
                    assert!(
                        sys.states()
                            .all(|s| sys.vars[s].kind != ir::VarKind::Charge),
                        "{}: a charge state with algebraic charges",
                        path.display()
                    );
                }
            }
        }
    }
}

#[test]
fn seed_a_in_loop_form_has_the_seeds_seven_equations() {
    let path = crate::root().join("netlists/seed_a_rc_rl.cir");
    let (_, built) = pipeline::equations(
        &path,
        &FsLoader,
        Options {
            kvl: Kvl::Loops,
            alias: true,
            ..Default::default()
        },
    )
    .ok()
    .unwrap();
    let sys = &built.system;
    let texts: Vec<String> = sys.eqs.ids().map(|e| print::equation(sys, e)).collect();
    // Seed 000: four component equations, one node, two loops.
    let expected = [
        "u_R1 = R1*i_R1",
        "i_C1 = C1*der(u_C1)",
        "u_R2 = R2*i_L1",
        "u_L1 = L1*der(i_L1)",
        "i_R1 = i_C1 + i_L1",
        "u_R1 = V1(t) - u_C1",
        "u_L1 = u_C1 - u_R2",
    ];
    assert_eq!(texts, expected);
    let unknowns: Vec<&str> = sys.unknowns().map(|v| sys.var_name(v)).collect();
    assert_eq!(unknowns.len(), 7);
    let states: Vec<&str> = sys.states().map(|v| sys.var_name(v)).collect();
    assert_eq!(states, ["u_C1", "i_L1"]);
    assert_eq!(sys.eliminated.len(), 3);
}
