//! Output vectors: `v(node)`, `i(element)` and the `.print`/`.save` lists
//! resolved to the tape's registers.

use super::*;

/// The output a probe names.
pub(super) fn resolve_probe(c: &Circuit, probe: &str) -> Result<Output, SimError> {
    let p = probe.trim().to_ascii_lowercase();
    let bad = || SimError::UnknownProbe(probe.to_string());
    let inner = |prefix: &str| -> Option<&str> { p.strip_prefix(prefix)?.strip_suffix(')') };
    if let Some(args) = inner("v(") {
        let nodes: Vec<&str> = args.split(',').map(str::trim).collect();
        let ids: Vec<_> = nodes
            .iter()
            .map(|n| c.find_node(n))
            .collect::<Option<_>>()
            .ok_or_else(bad)?;
        return match ids.as_slice() {
            [a] => Ok(Output::Voltage {
                pos: *a,
                neg: GROUND,
            }),
            [a, b] => Ok(Output::Voltage { pos: *a, neg: *b }),
            _ => Err(bad()),
        };
    }
    if let Some(name) = inner("i(") {
        let e = c.find_element(name.trim()).ok_or_else(bad)?;
        if matches!(
            c.elements[e].kind,
            ElementKind::Coupling { .. } | ElementKind::Intermediate { .. }
        ) {
            return Err(bad());
        }
        return Ok(Output::Current { elem: e });
    }
    Err(bad())
}

/// What computes an output in the equations `b`.
pub(super) fn output_ref(b: &Built, out: &Output) -> OutputRef {
    match *out {
        Output::Voltage { pos, neg } if neg == GROUND => {
            OutputRef::Expr(b.node_pot[pos.0 as usize])
        }
        Output::Voltage { pos, neg } => {
            OutputRef::Diff(b.node_pot[pos.0 as usize], b.node_pot[neg.0 as usize])
        }
        Output::Current { elem } => OutputRef::Var(
            b.elem_vars[elem.0 as usize]
                .expect("two-terminal element")
                .i,
        ),
    }
}

/// The outputs of a run, as ngspice stores them: `--probe`s if given, else
/// the `.save` vectors if any, else every node voltage and every voltage
/// source's current (ngspice's default vectors) followed by the `.print`
/// vectors that are not among them. The probe or `.save` item `all` adds
/// the default vectors.
pub fn output_list(c: &Circuit, probes: &[String]) -> Result<Vec<Output>, SimError> {
    let mut list = Vec::new();
    let add = |list: &mut Vec<Output>, o: Output| {
        if !list.contains(&o) {
            list.push(o);
        }
    };
    if !probes.is_empty() {
        if probes.iter().any(|p| p.trim().eq_ignore_ascii_case("all")) {
            list = default_vectors(c);
        }
        for p in probes
            .iter()
            .filter(|p| !p.trim().eq_ignore_ascii_case("all"))
        {
            add(&mut list, resolve_probe(c, p)?);
        }
        return Ok(list);
    }
    if c.save_all || c.outputs.is_empty() {
        list = default_vectors(c);
    }
    let extra = if c.save_all || !c.outputs.is_empty() {
        &c.outputs
    } else {
        &c.prints
    };
    for o in extra {
        add(&mut list, o.clone());
    }
    Ok(list)
}

/// Every node voltage and every voltage source's current.
fn default_vectors(c: &Circuit) -> Vec<Output> {
    let mut v: Vec<Output> = c
        .nodes
        .ids()
        .filter(|&n| n != GROUND && !c.nodes[n].internal)
        .map(|n| Output::Voltage {
            pos: n,
            neg: GROUND,
        })
        .collect();
    v.extend(
        c.elements
            .iter()
            .filter(|(_, e)| matches!(e.kind, ElementKind::VSource { .. }))
            .map(|(id, _)| Output::Current { elem: id }),
    );
    v
}

/// [`output_list`] with each output's name and what computes it.
pub fn outputs(sorted: &Sorted, probes: &[String]) -> Result<Vec<(String, OutputRef)>, SimError> {
    let c = &sorted.elaborated.circuit;
    Ok(output_list(c, probes)?
        .iter()
        .map(|o| (c.output_name(o), output_ref(&sorted.built, o)))
        .collect())
}
