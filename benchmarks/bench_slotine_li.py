"""Cost of one Slotine-Li regressor evaluation Y(q, qd, v, a) (the SP1/SP2 per-tick path).

Prints microseconds per single-sample evaluation (best of several timing loops) for the D2R2's
closed form (JS eq. 15, scalar math) and the Drake-derived regressor
(``InverseDynamicsRegressor.slotine_li_single``) on the D2R2, the Siciliano arm and the 7-axis
``serial7``; and per-sample cost of the vectorised ``slotine_li`` on 1000 samples.  Print only,
not a test.

Run: OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python benchmarks/bench_slotine_li.py
"""

import os
import time

import numpy as np

from robust_drake.regressor import InverseDynamicsRegressor
from robust_drake.systems.controllers.spong import d2r2_regressor_single


def per_call_us(f, calls=300, repeat=5):
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        for _ in range(calls):
            f()
        best = min(best, (time.perf_counter() - t) / calls)
    return best * 1e6


def main():
    rng = np.random.default_rng(0)
    print(f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', '(default)')}")
    print(f"{'model':18s} {'route':28s} {'n':>2s} {'p_base':>6s} {'us/sample':>10s} {'vectorised us/sample (1000)':>28s}")
    q, qd, v, a = (x.tolist() for x in rng.normal(size=(4, 2)))
    print(f"{'d2r2':18s} {'closed form JS eq. 15':28s} {2:2d} {3:6d} "
          f"{per_call_us(lambda: d2r2_regressor_single(q, qd, v, a), calls=3000):10.1f} {'':>28s}")
    for robot, method in (("d2r2", "symbolic"), ("d2r2", "numeric"), ("siciliano_2link", "symbolic"),
                          ("siciliano_2link", "numeric"), ("serial7", "numeric")):
        reg = InverseDynamicsRegressor.from_robot(robot, method=method)
        n = reg.n
        q, qd, v, a = rng.normal(size=(4, n))
        single = per_call_us(lambda: reg.slotine_li_single(q, qd, v, a))
        Q, QD, V, A = rng.normal(size=(4, 1000, n))
        vec = per_call_us(lambda: reg.slotine_li(Q, QD, V, A), calls=3) / 1000
        print(f"{robot:18s} {'Drake-derived (' + reg.method + ')':28s} {n:2d} {reg.p_base:6d} {single:10.1f} {vec:28.2f}")


if __name__ == "__main__":
    main()
