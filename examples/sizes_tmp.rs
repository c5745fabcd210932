fn main() {
    use std::mem::size_of;
    println!("Element {}", size_of::<kausal::elab::Element>());
    println!("ElementKind {}", size_of::<kausal::elab::ElementKind>());
    println!("Node {}", size_of::<kausal::elab::Node>());
    println!("Var {}", size_of::<kausal::ir::Var>());
    println!("Equation {}", size_of::<kausal::ir::Equation>());
    println!("Origin {}", size_of::<kausal::ir::Origin>());
    println!("OriginKind {}", size_of::<kausal::ir::OriginKind>());
    println!("Expr {}", size_of::<kausal::ir::Expr>());
    println!("ElemVars {}", size_of::<Option<kausal::build::ElemVars>>());
}
