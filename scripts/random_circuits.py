#!/usr/bin/env python3
"""Random valid circuits through `kausal validate`.

Generates random connected circuits of R, C, L, V (DC/SIN/PULSE/EXP), I, E,
F, G, H, D (with a .model) and K, each with a `.tran`, built so that ngspice
can run them (every node has a resistive path to ground, inductors sit in
series with a resistor, controlled voltage sources drive their own node),
runs `kausal validate --format json` on each under a timeout, and reports
pass / fail / refused / ngspice-failed, the pass share among the circuits
whose reference ngspice ran, and for every failure its worst signal and a
likely class.

    scripts/random_circuits.py N [--seed S] [--out DIR] [--kausal PATH]
        [--timeout SECS] [--jobs 1]

Deterministic given the seed. Circuits, outputs and a summary (summary.json)
are written to --out (default /work/fuzz-out/random).
"""

import argparse
import json
import math
import os
import random
import re
import subprocess
import sys
import time


def eng(x):
    return f"{x:.4g}"


def lu(rng, lo, hi):
    """Log-uniform in [lo, hi]."""
    return math.exp(rng.uniform(math.log(lo), math.log(hi)))


class Gen:
    def __init__(self, rng):
        self.rng = rng
        self.lines = []
        self.count = {}
        self.nodes = ["0"]
        self.vsources = []
        self.inductors = []
        self.breakpoints = []
        self.kinds = set()
        self.has_diode_model = False
        self.coupled = set()

    def name(self, letter):
        k = self.count.get(letter, 0) + 1
        self.count[letter] = k
        return f"{letter}{k}"

    def new_node(self):
        n = f"n{len(self.nodes)}"
        self.nodes.append(n)
        return n

    def any_node(self, nonzero=False, but=None):
        cands = self.nodes[1:] if nonzero and len(self.nodes) > 1 else self.nodes
        return self.rng.choice([n for n in cands if n != but])

    def wave(self, amp, period, current=False):
        rng = self.rng
        kind = rng.choice(["DC", "SIN", "PULSE", "EXP"])
        self.kinds.add(kind)
        if kind == "DC":
            return f"DC {eng(rng.uniform(-1, 1) * amp)}"
        if kind == "SIN":
            off = rng.uniform(-0.3, 0.3) * amp
            f = 1 / period * rng.uniform(0.5, 5)
            td = rng.choice([0, 0, rng.uniform(0, 0.3) * self.tstop])
            theta = rng.choice([0, 0, rng.uniform(0, 3) / self.tstop])
            if td > 0:
                self.breakpoints.append(td)
            return f"SIN({eng(off)} {eng(amp)} {eng(f)} {eng(td)} {eng(theta)})"
        if kind == "PULSE":
            v1 = rng.uniform(-0.2, 0.2) * amp
            v2 = amp * rng.choice([1, -1])
            td = rng.uniform(0, 0.2) * self.tstop
            per = period * rng.uniform(0.3, 2)
            tr = per * lu(rng, 1e-4, 0.2)
            tf = per * lu(rng, 1e-4, 0.2)
            pw = per * rng.uniform(0.1, 0.5)
            t = td
            while t < self.tstop:
                self.breakpoints += [t, t + tr, t + tr + pw, t + tr + pw + tf]
                t += per
            return f"PULSE({eng(v1)} {eng(v2)} {eng(td)} {eng(tr)} {eng(tf)} {eng(pw)} {eng(per)})"
        # EXP
        v1 = rng.uniform(-0.2, 0.2) * amp
        v2 = amp * rng.choice([1, -1])
        td1 = rng.uniform(0, 0.2) * self.tstop
        tau1 = self.tstop * lu(rng, 1e-3, 0.3)
        td2 = td1 + rng.uniform(0.1, 0.6) * self.tstop
        tau2 = self.tstop * lu(rng, 1e-3, 0.3)
        self.breakpoints += [td1, td2]
        return f"EXP({eng(v1)} {eng(v2)} {eng(td1)} {eng(tau1)} {eng(td2)} {eng(tau2)})"

    def diode_model(self):
        if not self.has_diode_model:
            rng = self.rng
            self.has_diode_model = True
            is_ = lu(rng, 1e-16, 1e-9)
            n = rng.uniform(1, 2)
            rs = lu(rng, 0.1, 50)
            cjo = lu(rng, 1e-13, 1e-10)
            extra = ""
            if rng.random() < 0.3:
                extra += f" BV={eng(rng.uniform(3, 30))} IBV=1m"
            if rng.random() < 0.3:
                extra += f" TT={eng(lu(rng, 1e-10, 1e-7))}"
            self.lines.append(
                f".model DM D(IS={eng(is_)} N={eng(n)} RS={eng(rs)} CJO={eng(cjo)}{extra})"
            )

    def build(self):
        rng = self.rng
        self.tstop = lu(rng, 1e-6, 1e-2)
        period = self.tstop / rng.uniform(1, 10)
        r0 = lu(rng, 10, 1e4)
        tau = self.tstop * lu(rng, 0.02, 1)
        n_nodes = rng.randint(2, 7)
        elems = []
        # A resistive spanning tree: every node has a DC path to ground.
        for _ in range(n_nodes):
            a = self.any_node()
            b = self.new_node()
            self.lines.append(f"{self.name('R')} {b} {a} {eng(r0 * lu(rng, 0.1, 10))}")
        # At least one independent source.
        amp = lu(rng, 0.1, 20)
        vname = self.name("V")
        self.lines.append(f"{vname} {self.any_node(True)} 0 {self.wave(amp, period)}")
        self.vsources.append(vname)
        self.kinds.add("V")
        n_extra = rng.randint(2, 9)
        for _ in range(n_extra):
            kind = rng.choice("RCCLLVIEFGHDDK")
            self.kinds.add(kind)
            a, b = self.any_node(), self.any_node()
            while b == a:
                b = self.any_node()
            if kind == "R":
                self.lines.append(f"{self.name('R')} {a} {b} {eng(r0 * lu(rng, 0.1, 10))}")
            elif kind == "C":
                self.lines.append(f"{self.name('C')} {a} {b} {eng(tau / r0 * lu(rng, 0.1, 10))}")
            elif kind == "L":
                # In series with a resistor through a node of its own.
                m = self.new_node()
                ln = self.name("L")
                self.lines.append(f"{ln} {a} {m} {eng(tau * r0 * lu(rng, 0.01, 1))}")
                self.lines.append(f"{self.name('R')} {m} {b} {eng(r0 * lu(rng, 0.1, 10))}")
                self.inductors.append(ln)
            elif kind == "V":
                # Through a series resistor to a node of its own.
                m = self.new_node()
                vn = self.name("V")
                self.lines.append(f"{vn} {m} 0 {self.wave(lu(rng, 0.1, 20), period)}")
                self.lines.append(f"{self.name('R')} {m} {a} {eng(r0 * lu(rng, 0.1, 10))}")
                self.vsources.append(vn)
            elif kind == "I":
                self.lines.append(
                    f"{self.name('I')} {a} {b} {self.wave(lu(rng, 0.1, 20) / r0, period)}"
                )
            elif kind == "E":
                m = self.new_node()
                self.lines.append(f"{self.name('E')} {m} 0 {a} {b} {eng(rng.uniform(-3, 3))}")
                self.lines.append(f"{self.name('R')} {m} {self.any_node(but=m)} {eng(r0 * lu(rng, 0.1, 10))}")
            elif kind == "G":
                c, d = self.any_node(), self.any_node()
                self.lines.append(f"{self.name('G')} {a} {b} {c} {d} {eng(rng.uniform(-2, 2) / r0)}")
            elif kind == "F":
                self.lines.append(
                    f"{self.name('F')} {a} {b} {rng.choice(self.vsources)} {eng(rng.uniform(-2, 2))}"
                )
            elif kind == "H":
                m = self.new_node()
                self.lines.append(
                    f"{self.name('H')} {m} 0 {rng.choice(self.vsources)} {eng(rng.uniform(-2, 2) * r0)}"
                )
                self.lines.append(f"{self.name('R')} {m} {self.any_node(but=m)} {eng(r0 * lu(rng, 0.1, 10))}")
            elif kind == "D":
                self.diode_model()
                self.lines.append(f"{self.name('D')} {a} {b} DM")
            elif kind == "K":
                if len(self.inductors) < 2:
                    for _ in range(2 - len(self.inductors)):
                        p, q = self.any_node(), self.new_node()
                        ln = self.name("L")
                        self.lines.append(f"{ln} {p} {q} {eng(tau * r0 * lu(rng, 0.01, 1))}")
                        self.lines.append(f"{self.name('R')} {q} 0 {eng(r0 * lu(rng, 0.1, 10))}")
                        self.inductors.append(ln)
                l1, l2 = rng.sample(self.inductors, 2)
                pair = tuple(sorted((l1, l2)))
                if pair in self.coupled:
                    continue  # ngspice refuses a pair coupled twice
                self.coupled.add(pair)
                k = 1.0 if rng.random() < 0.25 else rng.uniform(0.1, 0.99)
                self.lines.append(f"{self.name('K')} {l1} {l2} {eng(k)}")
        rng.shuffle(self.lines)
        tstep = self.tstop / rng.choice([100, 200, 500, 1000])
        title = f"random circuit ({', '.join(sorted(self.kinds))}) T={eng(self.tstop)}"
        return "\n".join([title] + self.lines + [f".tran {eng(tstep)} {eng(self.tstop)}", ".end"]) + "\n"


def first_values(path, name, kausal):
    """The worst signal at t = 0 from kausal and from ngspice at the
    reference's tolerances: (kausal, ngspice), or None."""
    try:
        k = subprocess.run([kausal, "sim", "--probe", name, path], capture_output=True,
                           text=True, timeout=30)
        kv = float(k.stdout.splitlines()[1].split(",")[1])
        text = open(path).read().replace(
            "\n.end", f"\n.options reltol=1e-8 abstol=1e-15 vntol=1e-12 chgtol=1e-18\n.print tran {name}\n.end")
        tmp = path + ".dc.cir"
        with open(tmp, "w") as f:
            f.write(text)
        n = subprocess.run(["ngspice", "-b", tmp], capture_output=True, text=True, timeout=30)
        os.remove(tmp)
        for line in n.stdout.splitlines():
            w = line.split()
            if len(w) >= 3 and w[0] == "0":
                return kv, float(w[2])
    except (subprocess.TimeoutExpired, IndexError, ValueError, OSError):
        pass
    return None


def classify(report, stderr, gen, path=None, kausal=None):
    """The worst failing signal and a likely class."""
    tstop = gen.tstop
    tol = report.get("tol", 1e-3)
    bad = [s for s in report["signals"] if not s["pass"]]
    if not bad:
        return None, "other"
    worst = max(bad, key=lambda s: s["max_norm"] or 0)
    t = worst["worst_time"] or 0
    name = worst["name"]
    atol = 1e-12 if name.startswith("i(") else 1e-9
    big = 1e3 if name.startswith("i(") else 1e6
    dc = first_values(path, name, kausal) if path else None
    if worst["scale"] is not None and worst["scale"] > big:
        cls = "unstable circuit (exponential growth)"
    elif dc and abs(dc[0] - dc[1]) > tol * max(worst["scale"] or 0, 1e-300):
        cls = "another DC operating point"
    elif worst["max_abs"] is not None and worst["max_abs"] < 20 * atol:
        cls = "signal below atol"
    elif t <= 0.01 * tstop:
        cls = "first steps after t=0"
    elif any(abs(t - b) <= 2e-3 * tstop for b in gen.breakpoints):
        cls = "source corner"
    elif "K0409" in stderr:
        cls = "high-Q ringing"
    else:
        cls = "other"
    d = worst.get("ngspice_default_norm")
    if d is not None and d > tol:
        cls += " (ngspice default also off)"
    else:
        cls += " (ngspice default passes)"
    return worst, cls


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("n", type=int)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default="/work/fuzz-out/random")
    ap.add_argument("--kausal", default="kausal")
    ap.add_argument("--timeout", type=int, default=60)
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    env = dict(os.environ, KAUSAL_NGSPICE_TIMEOUT=str(max(5, args.timeout // 4)))
    results = []
    t_all = time.time()
    for i in range(args.n):
        rng = random.Random(args.seed * 1_000_003 + i)
        gen = Gen(rng)
        text = gen.build()
        path = os.path.join(args.out, f"c{i:04d}.cir")
        with open(path, "w") as f:
            f.write(text)
        t0 = time.time()
        try:
            p = subprocess.run(
                ["timeout", str(args.timeout), args.kausal, "validate", "--format", "json", path],
                capture_output=True, text=True, env=env,
            )
            rc, out, err = p.returncode, p.stdout, p.stderr
        except Exception as e:  # noqa: BLE001
            rc, out, err = -1, "", str(e)
        dt = time.time() - t0
        rec = {"i": i, "path": path, "rc": rc, "time": round(dt, 3)}
        report = None
        try:
            report = json.loads(out) if out.strip() else None
        except json.JSONDecodeError:
            report = None
        codes = sorted(set(re.findall(r"K\d{4}", err)))
        rec["codes"] = codes
        if rc == 124:
            rec["status"] = "timeout"
        elif rc not in (0, 1):
            rec["status"] = "crash"
            rec["stderr"] = err[-2000:]
        elif report is not None:
            rec["status"] = "pass" if report["pass"] else "fail"
            rec["ref_reltol"] = report["ref_reltol"]
            rec["ref_gear"] = report["ref_gear"]
            rec["tight"] = report["ref_reltol"] <= 1e-8 and not report["ref_gear"]
            if not report["pass"]:
                worst, cls = classify(report, err, gen, path, args.kausal)
                rec["class"] = cls
                if worst:
                    rec["worst"] = {k: worst[k] for k in ("name", "max_norm", "max_abs", "worst_time", "scale", "ngspice_default_norm")}
        elif "ngspice" in err and "kausal's simulation failed" not in err:
            rec["status"] = "ngspice-failed"
            rec["stderr"] = err[-600:]
            reasons = [
                ("did not finish", "ngspice timed out"),
                ("Timestep too small", "ngspice: timestep too small"),
                ("singular matrix", "ngspice: singular matrix"),
                ("duplicate K", "ngspice: duplicate K"),
            ]
            rec["class"] = next((c for k, c in reasons if k in err), "ngspice: other")
        elif "kausal's simulation failed" in err:
            rec["status"] = "kausal-sim-error"
            rec["stderr"] = err[-1500:]
            line = next((x for x in err.splitlines() if "×" in x), "")
            rec["class"] = "kausal sim error: " + line.split("failed:")[-1].strip()[:60]
        else:
            rec["status"] = "refused"
            rec["stderr"] = err[-1500:]
        results.append(rec)
        print(f"{i:4d} {rec['status']:16s} {dt:6.2f}s {rec.get('class', '')} {' '.join(codes)}", flush=True)
    el = time.time() - t_all
    by = {}
    for r in results:
        by[r["status"]] = by.get(r["status"], 0) + 1
    ran = [r for r in results if r["status"] in ("pass", "fail", "kausal-sim-error")]
    tight = [r for r in ran if r.get("tight", True)]
    passed = [r for r in ran if r["status"] == "pass"]
    passed_t = [r for r in tight if r["status"] == "pass"]
    classes = {}
    for r in results:
        if r["status"] == "fail":
            classes[r["class"]] = classes.get(r["class"], 0) + 1
        elif r["status"] == "kausal-sim-error":
            classes["kausal sim error"] = classes.get("kausal sim error", 0) + 1
    ngspice_failed = {}
    for r in results:
        if r["status"] == "ngspice-failed":
            ngspice_failed[r["class"]] = ngspice_failed.get(r["class"], 0) + 1
    stable = [r for r in ran if not r.get("class", "").startswith("unstable")]
    stable_pass = [r for r in stable if r["status"] == "pass"]
    summary = {
        "n": args.n, "seed": args.seed, "wall": round(el, 1), "status": by,
        "pass_share_reference_ran": f"{len(passed)}/{len(ran)}",
        "pass_share_tight_reference": f"{len(passed_t)}/{len(tight)}",
        "pass_share_excluding_unstable": f"{len(stable_pass)}/{len(stable)}",
        "failure_classes": classes,
        "ngspice_failed": ngspice_failed,
    }
    with open(os.path.join(args.out, "results.json"), "w") as f:
        json.dump(results, f, indent=1)
    with open(os.path.join(args.out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1)
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    sys.exit(main())
