//! ngspice's MOS level 2, the Grove–Frohman model (its mos2load.c and
//! mos2temp.c at the nominal temperature), as the device's named
//! intermediates in the frame of the source of the moment (`mos.rs`).
//!
//! The threshold is `vbin + γs·√(φ − vbs)` with `vbin = vbi + f·(φ − vbs)`
//! (the narrow-width factor `f = DELTA·π·εSi/(4·Cox·W)`, `η = 1 + f`) and
//! the body factor `γs` shortened by the source and drain depletion
//! regions (XJ, with NSUB's depletion width). Above it the current is
//! `β·ufact/clfact · ((vgs − vbin − η·v/2)·v − γs·(√(φ − vbs + v)³ −
//! √(φ − vbs)³)/1.5)` at `v = min(vds, vdsat)`, where `ufact` is the
//! mobility degradation `(vc/(vgs − von))^UEXP` past the critical field
//! (UCRIT), `clfact` the channel-length modulation (LAMBDA, or from NSUB's
//! depletion width, with VMAX from the velocity-saturated pinch-off
//! region; punch-through limits it), and `vdsat` Grove–Frohman's or, with
//! VMAX, Baum's: the smallest positive root `x` of a quartic that ngspice
//! solves in closed form (Ferrari's resolvent cubic by Cardano's or the
//! trigonometric formula, then two quadratics), `vdsat = x² − (φ − vbs)`.
//! That solve is written out here as ngspice computes it, its choices as
//! `Cmp`/`Select`: no iteration. Below `von` with NFS the current at `von`
//! falls off as `exp((vgs − von)/(n·vt))`, `n` from the fast surface states
//! and the body factor's slope (the derivatives of √(φ − vbs) and of `γs`,
//! written out as ngspice has them); without NFS it is zero below `vbin`.
//!
//! Where ngspice's arithmetic breaks down the choice here is the nearest
//! defined one, named where it is made: a quartic whose factors have no
//! real coefficients keeps Grove–Frohman's `vdsat` (ngspice's NaN would
//! propagate), and weak inversion with `vdsat ≤ 0` (not reached with
//! ngspice's own formulas) carries no current where ngspice reuses the
//! last device's. The narrow-width factor is per device, without `m`
//! (ngspice since 2025; ngspice-39 also divides it by `m`).

use super::{Channel, Def, Device, EPS_SI, Frame, sqrt_phi_over};
use crate::elab::bjt::Ex;
use crate::elab::{Arith, BNode};
use crate::ir::{Cmp, Func};

/// ngspice's acceptance of a root of the velocity-saturation quartic:
/// the polynomial's magnitude there at most this.
const QUARTIC_TOL: f64 = 1e-6;
/// No accepted root of the velocity-saturation quartic (a root is
/// √(vdsat + φ − vbs), volts^½: far below this).
const NO_ROOT: f64 = 1e30;
/// ngspice's `vds` below which the channel carries nothing.
const VDS_MIN: f64 = 1e-10;
/// ngspice's punch-through width without NSUB (m).
const XWB_DEFAULT: f64 = 0.25e-6;

/// Arithmetic on [`Ex`], for writing equations as equations.
trait Ops {
    fn add(&mut self, a: u32, b: u32) -> u32;
    fn sub(&mut self, a: u32, b: u32) -> u32;
    fn mul(&mut self, a: u32, b: u32) -> u32;
    fn div(&mut self, a: u32, b: u32) -> u32;
    fn call(&mut self, f: Func, a: u32) -> u32;
    fn cmp(&mut self, op: Cmp, a: u32, b: u32) -> u32;
    /// `a` where `c` is not 0, else `b`.
    fn sel(&mut self, c: u32, a: u32, b: u32) -> u32;
    fn min(&mut self, a: u32, b: u32) -> u32 {
        let c = self.cmp(Cmp::Lt, a, b);
        self.sel(c, a, b)
    }
    fn max(&mut self, a: u32, b: u32) -> u32 {
        let c = self.cmp(Cmp::Gt, a, b);
        self.sel(c, a, b)
    }
    fn cube(&mut self, a: u32) -> u32 {
        let t = self.mul(a, a);
        self.mul(t, a)
    }
}

impl Ops for Ex {
    fn add(&mut self, a: u32, b: u32) -> u32 {
        self.arith(Arith::Add, a, b)
    }
    fn sub(&mut self, a: u32, b: u32) -> u32 {
        self.arith(Arith::Sub, a, b)
    }
    fn mul(&mut self, a: u32, b: u32) -> u32 {
        self.arith(Arith::Mul, a, b)
    }
    fn div(&mut self, a: u32, b: u32) -> u32 {
        self.arith(Arith::Div, a, b)
    }
    fn call(&mut self, f: Func, a: u32) -> u32 {
        self.push(BNode::Call(f, a))
    }
    fn cmp(&mut self, op: Cmp, a: u32, b: u32) -> u32 {
        self.push(BNode::Cmp(op, a, b))
    }
    fn sel(&mut self, c: u32, a: u32, b: u32) -> u32 {
        self.push(BNode::Select(c, a, b))
    }
}

/// A value that is a constant of the device or one of its intermediates.
#[derive(Clone, Copy)]
enum Val {
    Num(f64),
    Var(crate::elab::ElemId),
}

impl Val {
    fn at(self, x: &mut Ex) -> u32 {
        match self {
            Val::Num(v) => x.num(v),
            Val::Var(id) => x.volt(id),
        }
    }
}

impl Device<'_> {
    /// The level-2 drain current (see the module documentation).
    pub(super) fn level2(&self, def: &mut Def<'_>, f: &Frame) -> Channel {
        let md = self.md;
        let dv = self.dv;
        let (leff, weff) = (self.leff, self.weff);
        let phi = dv.phi;
        let sphi3 = phi * phi.sqrt();
        let nfs = md.nfs != 0.0;
        let vmax = md.vmax > 0.0;
        // The narrow-width factor and η.
        let factor = md.delta * std::f64::consts::PI * EPS_SI / (4.0 * dv.cox * weff);
        let eta = 1.0 + factor;
        // The short-channel body factor: XJ with a depletion width (NSUB).
        let short = md.xj > 0.0 && dv.xd > 0.0;
        let vb = |x: &mut Ex| x.volt(f.vb);
        // φ − vbs.
        let phi_vb = |x: &mut Ex| {
            let p = x.num(phi);
            let v = vb(x);
            x.sub(p, v)
        };

        // √(φ − vbs) and, at the drain, √(φ − vbs + vds) (continued above
        // zero as ngspice does).
        let mut x = Ex::default();
        let v = vb(&mut x);
        sqrt_phi_over(&mut x, phi, v);
        let sarg = def("sarg", x);
        let barg = short.then(|| {
            let mut x = Ex::default();
            let (v, d) = (vb(&mut x), x.volt(f.vd));
            let v = x.sub(v, d);
            sqrt_phi_over(&mut x, phi, v);
            def("barg", x)
        });
        // vbin = vbi + f·(φ − vbs).
        let vbin = if factor == 0.0 {
            Val::Num(dv.vbi)
        } else {
            let mut x = Ex::default();
            let t = phi_vb(&mut x);
            let k = x.num(factor);
            let t = x.mul(k, t);
            let vbi = x.num(dv.vbi);
            x.add(vbi, t);
            Val::Var(def("vbin", x))
        };
        // The short channel: `args`, `argd` = √(1 + 2·xd·√(·)/XJ) at the
        // source and the drain, and `γs = γ·(1 − XJ/2L·(args − 1) −
        // XJ/2L·(argd − 1))`.
        let arg_sd = barg.map(|barg| {
            let mut arg = |tag: &str, of| {
                let mut x = Ex::default();
                let s = x.volt(of);
                let k = x.num(2.0 * dv.xd / md.xj);
                let t = x.mul(k, s);
                let one = x.num(1.0);
                let t = x.add(one, t);
                x.call(Func::Sqrt, t);
                def(tag, x)
            };
            (arg("args", sarg), arg("argd", barg))
        });
        let gamasd = match arg_sd {
            Some((args, argd)) => {
                let mut x = Ex::default();
                let one = x.num(1.0);
                let k = x.num(0.5 * md.xj / leff);
                let a = x.volt(args);
                let t = x.sub(a, one);
                let ss = x.mul(k, t);
                let a = x.volt(argd);
                let t = x.sub(a, one);
                let sd = x.mul(k, t);
                let t = x.sub(one, ss);
                let t = x.sub(t, sd);
                let g = x.num(dv.gamma);
                x.mul(g, t);
                Val::Var(def("gamasd", x))
            }
            None => Val::Num(dv.gamma),
        };
        // The threshold `vbin + γs·√(φ − vbs)`; with NFS, von is above it
        // by `n·vt`.
        let threshold = |x: &mut Ex| {
            let b = vbin.at(x);
            let g = gamasd.at(x);
            let s = x.volt(sarg);
            let t = x.mul(g, s);
            x.add(b, t)
        };
        let xn = nfs.then(|| {
            // n = 1 + q·NFS/Cox + cdonco, cdonco = −(γs·∂s + ∂γs·s) + f,
            // with s = √(φ − vbs) and ∂ the slope in vbs.
            let mut x = Ex::default();
            let slope = |x: &mut Ex, of, at: u32| {
                let s = x.volt(of);
                let zero = x.num(0.0);
                let rev = x.cmp(Cmp::Le, at, zero);
                let h = x.num(-0.5);
                let r = x.div(h, s);
                let k = x.num(-0.5 / sphi3);
                let s2 = x.mul(s, s);
                let fw = x.mul(k, s2);
                x.sel(rev, r, fw)
            };
            let v = vb(&mut x);
            let dsrgdb = slope(&mut x, sarg, v);
            let g = gamasd.at(&mut x);
            let mut t = x.mul(g, dsrgdb);
            if let (Some(barg), Some((args, argd))) = (barg, arg_sd) {
                let v = vb(&mut x);
                let d = x.volt(f.vd);
                let v = x.sub(v, d);
                let dbrgdb = slope(&mut x, barg, v);
                let a = x.volt(args);
                let s = x.div(dsrgdb, a);
                let a = x.volt(argd);
                let d = x.div(dbrgdb, a);
                let t2 = x.add(s, d);
                let k = x.num(-dv.gamma * 0.5 * dv.xd / leff);
                let dgddvb = x.mul(k, t2);
                let s = x.volt(sarg);
                let t2 = x.mul(dgddvb, s);
                t = x.add(t, t2);
            }
            let k = x.num(1.0 + CHARGE_NFS * md.nfs / dv.cox + factor);
            x.sub(k, t);
            def("xn", x)
        });
        let mut x = Ex::default();
        threshold(&mut x);
        let von = match xn {
            Some(xn) => {
                let vth = def("vth", x);
                let mut x = Ex::default();
                let t = x.volt(vth);
                let n = x.volt(xn);
                let k = x.num(self.vt);
                let n = x.mul(k, n);
                x.add(t, n);
                def("von", x)
            }
            None => def("von", x),
        };
        // Mobility degradation past the critical field: `(vc/(vgs −
        // von))^UEXP` where vgs − von > vc = UCRIT·εSi/Cox, else 1.
        let ufact = (md.uexp != 0.0).then(|| {
            let mut x = Ex::default();
            let (g, o) = (x.volt(f.vg), x.volt(von));
            let vgst = x.sub(g, o);
            let vc = x.num(md.ucrit * 100.0 * EPS_SI / dv.cox);
            let past = x.cmp(Cmp::Gt, vgst, vc);
            let one = x.num(1.0);
            let r = x.div(vc, vgst);
            let e = x.num(md.uexp);
            let u = x.arith(Arith::Pow, r, e);
            x.sel(past, u, one);
            def("ufact", x)
        });
        let ufact_at = |x: &mut Ex| match ufact {
            Some(u) => x.volt(u),
            None => x.num(1.0),
        };
        // The gate voltage the strong-inversion formulas read: vgs, at
        // least von with NFS.
        let vgsx_id = if nfs {
            let mut x = Ex::default();
            let g = x.volt(f.vg);
            let o = x.volt(von);
            x.max(g, o);
            def("vgsx", x)
        } else {
            f.vg
        };
        let vgsx = |x: &mut Ex| x.volt(vgsx_id);
        // (vgsx − vbin)/η.
        let over = |x: &mut Ex| {
            let g = vgsx(x);
            let b = vbin.at(x);
            let t = x.sub(g, b);
            let k = x.num(1.0 / eta);
            x.mul(t, k)
        };
        // γd = γs/η.
        let gammad_v = match gamasd {
            Val::Num(g) => Val::Num(g / eta),
            Val::Var(_) => {
                let mut x = Ex::default();
                let g = gamasd.at(&mut x);
                let k = x.num(1.0 / eta);
                x.mul(g, k);
                Val::Var(def("gammad", x))
            }
        };
        let gammad = |x: &mut Ex| gammad_v.at(x);
        // v1 = (vgsx − vbin)/η + φ − vbs.
        let body_effect = !matches!(gamasd, Val::Num(g) if g <= 0.0);
        let v1 = (body_effect || vmax).then(|| {
            let mut x = Ex::default();
            let u = over(&mut x);
            let p = phi_vb(&mut x);
            x.add(u, p);
            def("v1", x)
        });
        // Grove–Frohman's vdsat: `u + γd²·(1 − √(1 + 4·v1/γd²))/2` with u =
        // (vgsx − vbin)/η, zero where v1 is not positive; `u` itself
        // without a body effect; at least 0.
        let mut x = Ex::default();
        {
            let zero = x.num(0.0);
            let plain = |x: &mut Ex| {
                let u = over(x);
                x.max(u, zero)
            };
            let body = |x: &mut Ex| {
                let argv = x.volt(v1.expect("v1 with a body effect"));
                let gd = gammad(x);
                let gd2 = x.mul(gd, gd);
                let a = x.max(argv, zero);
                let four = x.num(4.0);
                let t = x.mul(four, a);
                let t = x.div(t, gd2);
                let one = x.num(1.0);
                let t = x.add(one, t);
                let r = x.call(Func::Sqrt, t);
                let t = x.sub(one, r);
                let t = x.mul(gd2, t);
                let half = x.num(0.5);
                let t = x.mul(t, half);
                let u = over(x);
                let v = x.add(u, t);
                let v = x.max(v, zero);
                let none = x.cmp(Cmp::Le, argv, zero);
                x.sel(none, zero, v)
            };
            match gamasd {
                Val::Num(g) if g > 0.0 => {
                    body(&mut x);
                }
                Val::Num(_) => {
                    plain(&mut x);
                }
                Val::Var(_) => {
                    let with = body(&mut x);
                    let plain = plain(&mut x);
                    let gd = gammad(&mut x);
                    let pos = x.cmp(Cmp::Gt, gd, zero);
                    x.sel(pos, with, plain);
                }
            }
        }
        let gf = def(if vmax || !nfs { "vdsgf" } else { "vdsat" }, x);
        // The velocity-saturated drain, from Baum's quartic.
        let ueff = |x: &mut Ex| {
            let u = ufact_at(x);
            let k = x.num(dv.u0 * 1e-4);
            x.mul(k, u)
        };
        let vdsat = if vmax {
            self.baum(
                def,
                &BaumIn {
                    sarg,
                    gf,
                    v1: v1.expect("v1 with VMAX"),
                    phi_vb: &phi_vb,
                    gammad: &gammad,
                    ueff: &ueff,
                },
            )
        } else {
            gf
        };
        // Without NFS the device is cut off at vgs ≤ vbin, where ngspice's
        // vdsat is 0 (Meyer's capacitances read it).
        let vdsat = if nfs {
            vdsat
        } else {
            let mut x = Ex::default();
            let g = x.volt(f.vg);
            let b = vbin.at(&mut x);
            let off = x.cmp(Cmp::Le, g, b);
            let zero = x.num(0.0);
            let v = x.volt(vdsat);
            x.sel(off, zero, v);
            def("vdsat", x)
        };
        // Channel-length modulation: the fraction `dl` of the channel lost,
        // LAMBDA·vds, or from the depletion width: `xd/L·√(a + √(1 + a²))`
        // with a = (vds − vdsat)/4, or with VMAX `xd'/L·(√(xl² + (vds −
        // vdsat)⁺) − xl)`, xd' = xd/√NEFF, xl = VMAX·xd'/(2·µeff).
        let sqrt_pb = dv.pb.sqrt();
        let xwb = if dv.nsub {
            dv.xd * sqrt_pb
        } else {
            XWB_DEFAULT
        };
        let xld = leff - dv.xd * sqrt_pb;
        let from_depletion = dv.nsub && md.lambda <= 0.0;
        let clfact = if !from_depletion && md.lambda == 0.0 {
            // Punch-through limits even the unmodulated channel.
            Val::Num(if leff < xwb {
                xwb / (1.0 + (-xld) / xwb) / leff
            } else {
                1.0
            })
        } else {
            let dl = from_depletion.then(|| {
                let mut x = Ex::default();
                let d = x.volt(f.vd);
                if !vmax {
                    let s = x.volt(vdsat);
                    let t = x.sub(d, s);
                    let q = x.num(0.25);
                    let a = x.mul(t, q);
                    let a2 = x.mul(a, a);
                    let one = x.num(1.0);
                    let t = x.add(one, a2);
                    let t = x.call(Func::Sqrt, t);
                    let t = x.add(a, t);
                    let t = x.call(Func::Sqrt, t);
                    let k = x.num(dv.xd / leff);
                    x.mul(k, t);
                } else {
                    let xdv = dv.xd / md.neff.sqrt();
                    let s = x.volt(vdsat);
                    let t = x.sub(d, s);
                    let zero = x.num(0.0);
                    let t = x.max(t, zero);
                    let u = ueff(&mut x);
                    let k = x.num(md.vmax * xdv / 2.0);
                    let xlv = x.div(k, u);
                    let x2 = x.mul(xlv, xlv);
                    let t = x.add(x2, t);
                    let t = x.call(Func::Sqrt, t);
                    let t = x.sub(t, xlv);
                    let k = x.num(xdv / leff);
                    x.mul(k, t);
                }
                def("dl", x)
            });
            let mut x = Ex::default();
            let dl = match dl {
                Some(dl) => x.volt(dl),
                None => {
                    let d = x.volt(f.vd);
                    let l = x.num(md.lambda);
                    x.mul(l, d)
                }
            };
            let one = x.num(1.0);
            let plain = x.sub(one, dl);
            let l = x.num(leff);
            let xleff = x.mul(l, plain);
            let w = x.num(xwb);
            let punch = x.cmp(Cmp::Lt, xleff, w);
            let deltal = x.mul(dl, l);
            let xl = x.num(xld);
            let t = x.sub(deltal, xl);
            let t = x.div(t, w);
            let t = x.add(one, t);
            let k = x.num(xwb / leff);
            let limited = x.div(k, t);
            x.sel(punch, limited, plain);
            Val::Var(def("clfact", x))
        };
        // The drain current at `vdsx = min(vds, vdsat)`, with the bulk
        // charge's root there, `bx = √(φ − vbs + vdsx)`.
        let mut x = Ex::default();
        {
            let d = x.volt(f.vd);
            let s = x.volt(vdsat);
            x.min(d, s);
        }
        let vdsx = def("vdsx", x);
        let mut x = Ex::default();
        {
            let b = vb(&mut x);
            let v = x.volt(vdsx);
            let at = x.sub(b, v);
            sqrt_phi_over(&mut x, phi, at);
        }
        let bx = def("bx", x);
        let mut x = Ex::default();
        {
            let d = x.volt(f.vd);
            let v = x.volt(vdsx);
            let bx = x.volt(bx);
            let bx3 = x.cube(bx);
            let s = x.volt(sarg);
            let s3 = x.cube(s);
            let body = x.sub(bx3, s3);
            let g = gamasd.at(&mut x);
            let k = x.num(1.0 / 1.5);
            let t = x.mul(g, k);
            let body = x.mul(t, body);
            let gx = vgsx(&mut x);
            let bi = vbin.at(&mut x);
            let t = x.sub(gx, bi);
            let k = x.num(0.5 * eta);
            let h = x.mul(k, v);
            let t = x.sub(t, h);
            let t = x.mul(t, v);
            let core = x.sub(t, body);
            let beta = x.num(self.beta);
            let u = ufact_at(&mut x);
            let bu = x.mul(beta, u);
            let cl = clfact.at(&mut x);
            let b1 = x.div(bu, cl);
            let mut id = x.mul(b1, core);
            let zero = x.num(0.0);
            let g = x.volt(f.vg);
            if let Some(xn) = xn {
                // Weak inversion: the current at von, falling off below it.
                let o = x.volt(von);
                let t = x.sub(g, o);
                let t = x.min(t, zero);
                let n = x.volt(xn);
                let k = x.num(self.vt);
                let n = x.mul(k, n);
                let t = x.div(t, n);
                let e = x.call(Func::Exp, t);
                id = x.mul(id, e);
                let below = x.cmp(Cmp::Le, g, o);
                let s = x.volt(vdsat);
                let none = x.cmp(Cmp::Le, s, zero);
                let off = x.sel(below, none, zero);
                id = x.sel(off, zero, id);
            } else {
                let bi = vbin.at(&mut x);
                let off = x.cmp(Cmp::Le, g, bi);
                id = x.sel(off, zero, id);
            }
            let m = x.num(VDS_MIN);
            let off = x.cmp(Cmp::Le, d, m);
            x.sel(off, zero, id);
        }
        let id = def("id", x);
        Channel { id, von, vdsat }
    }

    /// Baum's velocity-saturated `vdsat` as ngspice computes it: the
    /// quartic `x⁴ + a1·x³ + b1·x² + c1·x + d1` in `x = √(vdsat + φ −
    /// vbs)` (a1 = 4γd/3, b1 = −2(v1 + xv), c1 = −2γd·xv, d1 = 2·v1·(φ −
    /// vbs + xv) − (φ − vbs)² − 4/3·γd·√(φ − vbs)³, v1 = (vgsx − vbin)/η +
    /// φ − vbs, xv = VMAX·L/µeff), factored by a root `y3` of its resolvent
    /// cubic into two quadratics `x² + (a1/2 ± a3)·x + (y3/2 ± b3)`; the
    /// smallest positive root whose residual is at most [`QUARTIC_TOL`],
    /// else Grove–Frohman's `vdsat`.
    fn baum(&self, def: &mut Def<'_>, b: &BaumIn<'_>) -> crate::elab::ElemId {
        let vl = self.md.vmax * self.leff;
        let v1 = b.v1;
        // xv = VMAX·L/µeff.
        let mut x = Ex::default();
        {
            let u = (b.ueff)(&mut x);
            let k = x.num(vl);
            x.div(k, u);
        }
        let xv = def("xv", x);
        let a1 = |x: &mut Ex| {
            let g = (b.gammad)(x);
            let k = x.num(1.0 / 0.75);
            x.mul(g, k)
        };
        let mut x = Ex::default();
        {
            let v = x.volt(v1);
            let xv = x.volt(xv);
            let t = x.add(v, xv);
            let k = x.num(-2.0);
            x.mul(k, t);
        }
        let b1 = def("b1", x);
        let c1 = |x: &mut Ex| {
            let g = (b.gammad)(x);
            let xv = x.volt(xv);
            let t = x.mul(g, xv);
            let k = x.num(-2.0);
            x.mul(k, t)
        };
        let mut x = Ex::default();
        {
            let v = x.volt(v1);
            let v2 = (b.phi_vb)(&mut x);
            let xv = x.volt(xv);
            let t = x.add(v2, xv);
            let t = x.mul(v, t);
            let two = x.num(2.0);
            let t = x.mul(two, t);
            let v22 = x.mul(v2, v2);
            let t = x.sub(t, v22);
            let g = (b.gammad)(&mut x);
            let s = x.volt(b.sarg);
            let s3 = x.cube(s);
            let k = x.num(4.0 / 3.0);
            let gs = x.mul(g, s3);
            let gs = x.mul(k, gs);
            x.sub(t, gs);
        }
        let d1 = def("d1", x);
        // The resolvent cubic y³ + a·y² + b·y + c (a = −b1, b = a1·c1 −
        // 4·d1, c = −d1·(a1² − 4·b1) − c1²), reduced: y = z − a/3, z³ +
        // r·z + s, and p = s²/4 + r³/27.
        let bb = |x: &mut Ex| {
            let a = a1(x);
            let c = c1(x);
            let t = x.mul(a, c);
            let four = x.num(4.0);
            let d = x.volt(d1);
            let t2 = x.mul(four, d);
            x.sub(t, t2)
        };
        let mut x = Ex::default();
        {
            let t = bb(&mut x);
            let b = x.volt(b1);
            let b2 = x.mul(b, b);
            let k = x.num(1.0 / 3.0);
            let t2 = x.mul(b2, k);
            x.sub(t, t2);
        }
        let qr = def("qr", x);
        let mut x = Ex::default();
        {
            // 2a³/27 − a·b/3 + c with a = −b1.
            let b = x.volt(b1);
            let b3 = x.cube(b);
            let k = x.num(-2.0 / 27.0);
            let t = x.mul(k, b3);
            let bv = bb(&mut x);
            let t2 = x.mul(b, bv);
            let k = x.num(1.0 / 3.0);
            let t2 = x.mul(t2, k);
            let t = x.add(t, t2);
            let a = a1(&mut x);
            let a2 = x.mul(a, a);
            let four = x.num(4.0);
            let t3 = x.mul(four, b);
            let t3 = x.sub(a2, t3);
            let d = x.volt(d1);
            let t3 = x.mul(d, t3);
            let t = x.sub(t, t3);
            let c = c1(&mut x);
            let c2 = x.mul(c, c);
            x.sub(t, c2);
        }
        let qs = def("qs", x);
        let mut x = Ex::default();
        {
            let s = x.volt(qs);
            let s2 = x.mul(s, s);
            let k = x.num(0.25);
            let t = x.mul(s2, k);
            let r = x.volt(qr);
            let r3 = x.cube(r);
            let k = x.num(1.0 / 27.0);
            let t2 = x.mul(r3, k);
            x.add(t, t2);
        }
        let qp = def("qp", x);
        // The root ngspice takes: by the cosine where p < 0, 2·ρ·cos(ϑ/3)
        // with ρ = (s²/4 + |p|)^(1/6) and ϑ = atan(−2√|p|/s) (atan, not
        // atan2), else Cardano's sum of the cube roots of |−s/2 ± √|p||;
        // minus a/3 = −b1/3.
        let mut x = Ex::default();
        {
            let third = x.num(1.0 / 3.0);
            let zero = x.num(0.0);
            let s = x.volt(qs);
            let p = x.volt(qp);
            let p0 = x.call(Func::Abs, p);
            let p2 = x.call(Func::Sqrt, p0);
            let b = x.volt(b1);
            let a_3 = x.mul(b, third);
            let s2 = x.mul(s, s);
            let k = x.num(0.25);
            let t = x.mul(s2, k);
            let t = x.add(t, p0);
            let t = x.call(Func::Sqrt, t);
            let t = x.call(Func::Ln, t);
            let t = x.mul(t, third);
            let ro = x.call(Func::Exp, t);
            let m2 = x.num(-2.0);
            let t = x.mul(m2, p2);
            let t = x.div(t, s);
            let fi = x.call(Func::Atan, t);
            let t = x.mul(fi, third);
            let t = x.call(Func::Cos, t);
            let two = x.num(2.0);
            let t = x.mul(two, t);
            let t = x.mul(t, ro);
            let trig = x.add(t, a_3);
            let half = x.num(0.5);
            let hs = x.mul(s, half);
            let ms = x.sub(zero, hs);
            let cbrt = |x: &mut Ex, v: u32| {
                let t = x.call(Func::Abs, v);
                let t = x.call(Func::Ln, t);
                let t = x.mul(t, third);
                x.call(Func::Exp, t)
            };
            let t = x.add(ms, p2);
            let p3 = cbrt(&mut x, t);
            let t = x.sub(ms, p2);
            let p4 = cbrt(&mut x, t);
            let t = x.add(p3, p4);
            let card = x.add(t, a_3);
            let neg = x.cmp(Cmp::Lt, p, zero);
            x.sel(neg, trig, card);
        }
        let y3 = def("y3", x);
        // a3 = √(a1²/4 − b1 + y3), b3 = √(y3²/4 − d1); −1 where the root's
        // argument is negative (ngspice's NaN: no root is taken then).
        let mut root = |tag: &str, sq: &dyn Fn(&mut Ex) -> u32| {
            let mut x = Ex::default();
            let t = sq(&mut x);
            let zero = x.num(0.0);
            let real = x.cmp(Cmp::Ge, t, zero);
            let r = x.call(Func::Sqrt, t);
            let none = x.num(-1.0);
            x.sel(real, r, none);
            def(tag, x)
        };
        let a3 = root("a3", &|x: &mut Ex| {
            let a = a1(x);
            let a2 = x.mul(a, a);
            let q = x.num(0.25);
            let t = x.mul(a2, q);
            let b = x.volt(b1);
            let t = x.sub(t, b);
            let y = x.volt(y3);
            x.add(t, y)
        });
        let b3 = root("b3", &|x: &mut Ex| {
            let y = x.volt(y3);
            let y2 = x.mul(y, y);
            let q = x.num(0.25);
            let t = x.mul(y2, q);
            let d = x.volt(d1);
            x.sub(t, d)
        });
        // Each quadratic's roots `−a4/2 ± √(a4²/4 − b4)`, a4 = a1/2 ± a3,
        // b4 = y3/2 ± b3, and its smaller accepted one ([`NO_ROOT`] for
        // none).
        let mut best = Vec::new();
        for (k, (s1, s2)) in [(1.0, 1.0), (-1.0, 1.0), (1.0, -1.0), (-1.0, -1.0)]
            .into_iter()
            .enumerate()
        {
            let a4 = |x: &mut Ex| {
                let a = a1(x);
                let half = x.num(0.5);
                let ah = x.mul(a, half);
                let a3v = x.volt(a3);
                let k1 = x.num(s1);
                let t = x.mul(k1, a3v);
                x.add(ah, t)
            };
            let mut x = Ex::default();
            {
                let a = a4(&mut x);
                let a2 = x.mul(a, a);
                let q = x.num(0.25);
                let t = x.mul(a2, q);
                let y = x.volt(y3);
                let half = x.num(0.5);
                let yh = x.mul(y, half);
                let b3v = x.volt(b3);
                let k2 = x.num(s2);
                let t2 = x.mul(k2, b3v);
                let b4 = x.add(yh, t2);
                x.sub(t, b4);
            }
            let q = def(&format!("q{}", k + 1), x);
            let mut pair = Vec::new();
            for (side, sign) in [("lo", -1.0), ("hi", 1.0)] {
                let mut x = Ex::default();
                {
                    let qv = x.volt(q);
                    let zero = x.num(0.0);
                    let real = x.cmp(Cmp::Ge, qv, zero);
                    let qp = x.max(qv, zero);
                    let sq = x.call(Func::Sqrt, qp);
                    let k = x.num(sign);
                    let sq = x.mul(k, sq);
                    let a = a4(&mut x);
                    let half = x.num(-0.5);
                    let h = x.mul(a, half);
                    let r = x.add(h, sq);
                    let none = x.num(-1.0);
                    x.sel(real, r, none);
                }
                pair.push(def(&format!("x{}{side}", k + 1), x));
            }
            let mut x = Ex::default();
            {
                let zero = x.num(0.0);
                let accepted = |x: &mut Ex, r: u32| {
                    // r⁴ + a1·r³ + b1·r² + c1·r + d1, by Horner.
                    let a = a1(x);
                    let t = x.add(r, a);
                    let t = x.mul(t, r);
                    let b = x.volt(b1);
                    let t = x.add(t, b);
                    let t = x.mul(t, r);
                    let c = c1(x);
                    let t = x.add(t, c);
                    let t = x.mul(t, r);
                    let d = x.volt(d1);
                    let poly = x.add(t, d);
                    let mag = x.call(Func::Abs, poly);
                    let tol = x.num(QUARTIC_TOL);
                    let near = x.cmp(Cmp::Le, mag, tol);
                    let pos = x.cmp(Cmp::Gt, r, zero);
                    x.sel(pos, near, zero)
                };
                let (lo, hi) = (x.volt(pair[0]), x.volt(pair[1]));
                let ok_lo = accepted(&mut x, lo);
                let ok_hi = accepted(&mut x, hi);
                let none = x.num(NO_ROOT);
                let t = x.sel(ok_hi, hi, none);
                x.sel(ok_lo, lo, t);
            }
            best.push(def(&format!("x{}", k + 1), x));
        }
        // The smallest, where a3 and b3 are real; vdsat = x² − (φ − vbs),
        // else Grove–Frohman's.
        let mut x = Ex::default();
        {
            let v: Vec<u32> = best.iter().map(|&r| x.volt(r)).collect();
            let m12 = x.min(v[0], v[1]);
            let m34 = x.min(v[2], v[3]);
            let m = x.min(m12, m34);
            let none = x.num(NO_ROOT);
            let zero = x.num(0.0);
            let a = x.volt(a3);
            let ok_a = x.cmp(Cmp::Ge, a, zero);
            let b = x.volt(b3);
            let ok_b = x.cmp(Cmp::Ge, b, zero);
            let t = x.sel(ok_b, m, none);
            x.sel(ok_a, t, none);
        }
        let xs = def("xs", x);
        let mut x = Ex::default();
        {
            let r = x.volt(xs);
            let none = x.num(NO_ROOT);
            let found = x.cmp(Cmp::Lt, r, none);
            let r2 = x.mul(r, r);
            let p = (b.phi_vb)(&mut x);
            let v = x.sub(r2, p);
            let gf = x.volt(b.gf);
            x.sel(found, v, gf);
        }
        def(if self.md.nfs != 0.0 { "vdsat" } else { "vdsvm" }, x)
    }
}

/// What Baum's `vdsat` reads from the rest of the level-2 channel.
struct BaumIn<'a> {
    sarg: crate::elab::ElemId,
    /// Grove–Frohman's vdsat, the fallback.
    gf: crate::elab::ElemId,
    /// (vgsx − vbin)/η + φ − vbs.
    v1: crate::elab::ElemId,
    /// φ − vbs.
    phi_vb: &'a dyn Fn(&mut Ex) -> u32,
    /// γs/η.
    gammad: &'a dyn Fn(&mut Ex) -> u32,
    /// The effective mobility (m²/V·s).
    ueff: &'a dyn Fn(&mut Ex) -> u32,
}

/// q·1e4 (cm² → m²), the fast surface states' charge per cm⁻².
const CHARGE_NFS: f64 = super::CHARGE * 1e4;
