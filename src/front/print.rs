//! Print an AST back as netlist text. `parse(print(ast))` gives the same AST
//! (modulo spans); the round-trip test relies on it.

use std::fmt::Write;

use super::ast::*;

pub fn netlist(n: &Netlist<'_>) -> String {
    let mut out = String::new();
    out.push_str(n.title);
    out.push('\n');
    stmts(&n.stmts, &mut out);
    out.push_str(".end\n");
    out
}

fn value(v: &Value<'_>) -> String {
    match v {
        Value::Num { text, .. } => text.to_string(),
        Value::Expr { text, .. } => format!("{{{text}}}"),
        Value::Ident(n) => n.text.to_string(),
    }
}

fn assigns(a: &[Assign<'_>], out: &mut String) {
    for x in a {
        let _ = write!(out, " {}={}", x.name.text, value(&x.value));
    }
}

fn out_vec(v: &OutVec<'_>) -> String {
    let args: Vec<&str> = v.args.iter().map(|a| a.text).collect();
    format!("{}({})", v.kind, args.join(","))
}

fn stmts(list: &[Stmt<'_>], out: &mut String) {
    for s in list {
        stmt(s, out);
    }
}

fn stmt(s: &Stmt<'_>, out: &mut String) {
    match s {
        Stmt::Element(e) => element(e, out),
        Stmt::Model(m) => {
            let _ = write!(out, ".model {} {}(", m.name.text, m.kind.text);
            let mut inner = String::new();
            assigns(&m.params, &mut inner);
            out.push_str(inner.trim_start());
            out.push_str(")\n");
        }
        Stmt::Subckt(sc) => {
            let _ = write!(out, ".subckt {}", sc.name.text);
            for p in &sc.ports {
                let _ = write!(out, " {}", p.text);
            }
            if !sc.params.is_empty() {
                out.push_str(" params:");
                assigns(&sc.params, out);
            }
            out.push('\n');
            stmts(&sc.body, out);
            let _ = writeln!(out, ".ends {}", sc.name.text);
        }
        Stmt::Param(a, _) => {
            out.push_str(".param");
            assigns(a, out);
            out.push('\n');
        }
        Stmt::Func(f) => {
            let params: Vec<&str> = f.params.iter().map(|p| p.text).collect();
            let _ = writeln!(
                out,
                ".func {}({}) {}",
                f.name.text,
                params.join(" "),
                value(&f.body)
            );
        }
        Stmt::Global(names, _) => {
            out.push_str(".global");
            for n in names {
                let _ = write!(out, " {}", n.text);
            }
            out.push('\n');
        }
        Stmt::Ic(ics, _) | Stmt::Nodeset(ics, _) => {
            out.push_str(if matches!(s, Stmt::Ic(..)) {
                ".ic"
            } else {
                ".nodeset"
            });
            for (v, val) in ics {
                let _ = write!(out, " {}={}", out_vec(v), value(val));
            }
            out.push('\n');
        }
        Stmt::Tran(t) => {
            let _ = write!(out, ".tran {} {}", value(&t.tstep), value(&t.tstop));
            if let Some(v) = &t.tstart {
                let _ = write!(out, " {}", value(v));
            }
            if let Some(v) = &t.tmax {
                let _ = write!(out, " {}", value(v));
            }
            if t.uic {
                out.push_str(" uic");
            }
            out.push('\n');
        }
        Stmt::Options(opts, _) => {
            out.push_str(".options");
            for o in opts {
                match &o.value {
                    OptValue::Flag => {
                        let _ = write!(out, " {}", o.name.text);
                    }
                    OptValue::Value(v) => {
                        let _ = write!(out, " {}={}", o.name.text, value(v));
                    }
                    OptValue::Word(w) => {
                        let _ = write!(out, " {}={}", o.name.text, w.text);
                    }
                }
            }
            out.push('\n');
        }
        Stmt::Output {
            directive,
            analysis,
            vectors,
            all,
            ..
        } => {
            out.push_str(directive.text);
            if let Some(a) = analysis {
                let _ = write!(out, " {}", a.text);
            }
            if *all {
                out.push_str(" all");
            }
            for v in vectors {
                let _ = write!(out, " {}", out_vec(v));
            }
            out.push('\n');
        }
        Stmt::Include {
            path,
            section: None,
            ..
        } => {
            let _ = writeln!(out, ".include \"{path}\"");
        }
        Stmt::Include {
            path,
            section: Some(section),
            ..
        } => {
            let _ = writeln!(out, ".lib \"{path}\" {section}");
        }
    }
}

fn element(e: &Element<'_>, out: &mut String) {
    out.push_str(e.name.text);
    for n in &e.nodes {
        let _ = write!(out, " {}", n.text);
    }
    match &e.body {
        ElementBody::Passive {
            value: v,
            model,
            params,
        } => {
            let _ = write!(out, " {}", value(v));
            if let Some(m) = model {
                let _ = write!(out, " {}", m.text);
            }
            assigns(params, out);
        }
        ElementBody::Coupling { l1, l2, k } => {
            let _ = write!(out, " {} {} {}", l1.text, l2.text, value(k));
        }
        ElementBody::Source { dc, tran, ac } => {
            if let Some(d) = dc {
                let _ = write!(out, " DC {}", value(d));
            }
            if !ac.is_empty() {
                out.push_str(" AC");
                for a in ac {
                    let _ = write!(out, " {}", value(a));
                }
            }
            if let Some(t) = tran {
                let args: Vec<String> = t.args.iter().map(value).collect();
                let _ = write!(out, " {}({})", t.kind.name(), args.join(" "));
                if let Some(r) = &t.repeat {
                    let _ = write!(out, " r={}", value(r));
                }
                if let Some(d) = &t.delay {
                    let _ = write!(out, " td={}", value(d));
                }
            }
        }
        ElementBody::VoltageControlled { gain } => {
            let _ = write!(out, " {}", value(gain));
        }
        ElementBody::CurrentControlled { vsrc, gain } => {
            let _ = write!(out, " {} {}", vsrc.text, value(gain));
        }
        ElementBody::Diode {
            model,
            area,
            params,
        } => {
            let _ = write!(out, " {}", model.text);
            if let Some(a) = area {
                let _ = write!(out, " {}", value(a));
            }
            assigns(params, out);
        }
        ElementBody::Behavioural { current, text, .. } => {
            let key = match (e.letter, current) {
                (ElementLetter::E | ElementLetter::F | ElementLetter::G | ElementLetter::H, _) => {
                    "VALUE"
                }
                (_, true) => "I",
                (_, false) => "V",
            };
            let _ = write!(out, " {key}={{{text}}}");
        }
        ElementBody::Device { words, params } => {
            for w in words {
                let _ = write!(out, " {}", value(w));
            }
            assigns(params, out);
        }
        ElementBody::Instance { subckt, params } => {
            let _ = write!(out, " {}", subckt.text);
            assigns(params, out);
        }
    }
    out.push('\n');
}
