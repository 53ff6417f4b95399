"""Regressor derivation and evaluation costs, measured side by side in one run.

Prints, per model: derivation time of the symbolic route (Drake ToSymbolic +
DecomposeLumpedParameters + compilation to numpy) and of the numeric route (vectorised
Newton-Euler + numeric base set); then per-sample evaluation cost of the base regressor:
compiled/vectorised numpy (both routes) vs per-sample ``pydrake.symbolic.Evaluate`` of the
lumped regressor, and Drake's ``CalcInverseDynamics`` per sample for scale.

Run: PYTHONPATH=. .venv/bin/python benchmarks/bench_regressor.py
(Timings on a shared machine vary; OpenBLAS threading on an oversubscribed machine makes small
QR factorisations 100x+ slower -- compare with OPENBLAS_NUM_THREADS=1.)
"""

import os
import time

import numpy as np

from robust_drake.models import ROBOTS, make_plant
from robust_drake.regressor import InverseDynamicsRegressor, drake_inverse_dynamics


def best_of(f, repeat=3):
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        f()
        best = min(best, time.perf_counter() - t)
    return best


def main():
    from pydrake.symbolic import Evaluate

    rng = np.random.default_rng(0)
    print(f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', '(default)')}")
    print("\nDerivation (s)")
    print(f"{'model':28s} {'n':>2s} {'p_std':>5s} {'p_base':>6s} {'symbolic':>9s} {'numeric':>8s}")
    regs = {}
    for robot, spec in ROBOTS.items():
        for load in spec.loads:
            plant = make_plant(robot, load)
            t_sym = np.nan
            if spec.n <= 2:
                t_sym = best_of(lambda: regs.__setitem__((robot, load, "s"), InverseDynamicsRegressor(plant, "symbolic")))
            t_num = best_of(lambda: regs.__setitem__((robot, load, "n"), InverseDynamicsRegressor(plant, "numeric")))
            r = regs[(robot, load, "n")]
            sym = f"{t_sym:9.3f}" if np.isfinite(t_sym) else "  skipped"
            print(f"{robot + '/' + load:28s} {spec.n:2d} {r.p_standard:5d} {r.p_base:6d} {sym} {t_num:8.3f}")
    print("  (symbolic skipped for n > 2 by design: pitfalls notes measured ~20x per added link)")

    print("\nEvaluation, microseconds per sample")
    print(f"{'model':28s} {'sym-compiled':>12s} {'numeric-NE':>10s} {'sym-Evaluate':>12s} {'Drake ID':>9s} {'Evaluate/compiled':>17s}")
    for robot, spec in ROBOTS.items():
        load = "none"
        n = spec.n
        N = 20000 if n <= 2 else 2000
        q, v, vd = rng.uniform(-3, 3, (N, n)), rng.normal(0, 2, (N, n)), rng.normal(0, 5, (N, n))
        rn = regs[(robot, load, "n")]
        t_num = best_of(lambda: rn.evaluate(q, v, vd)) / N * 1e6
        plant = rn.plant
        ctx = plant.CreateDefaultContext()
        Nd = 200
        t_id = best_of(lambda: drake_inverse_dynamics(plant, ctx, q[:Nd], v[:Nd], vd[:Nd]), 1) / Nd * 1e6
        t_cmp = t_ev = np.nan
        if (robot, load, "s") in regs:
            rs = regs[(robot, load, "s")]
            t_cmp = best_of(lambda: rs.evaluate(q, v, vd)) / N * 1e6
            W = rs._W_expr
            qv, vv, av = rs._sym_qva
            Ns = 100

            def per_sample():
                for k in range(Ns):
                    env = {**dict(zip(qv, q[k])), **dict(zip(vv, v[k])), **dict(zip(av, vd[k]))}
                    Evaluate(W, env) @ rs._A  # lumped regressor -> standard columns, as evaluate() does
            t_ev = best_of(per_sample, 1) / Ns * 1e6
        ratio = f"{t_ev / t_cmp:17.0f}" if np.isfinite(t_cmp) else f"{'-':>17s}"
        f = lambda x: f"{x:.2f}" if np.isfinite(x) else "-"
        print(f"{robot:28s} {f(t_cmp):>12s} {f(t_num):>10s} {f(t_ev):>12s} {f(t_id):>9s} {ratio}")
    print("  Drake ID is the torque for one sample (not a regressor), for scale.")


if __name__ == "__main__":
    main()
