"""Effect library and experiment generator costs, measured side by side in one run.

Prints: CPU seconds per simulated second of the hidden-effect generator (DFKI C.1, 250 Hz
recording, RK3 at accuracy 1e-5) with no extra effect and with each plant-side kind, and the
time to build each kind's regressor columns for 3000 samples of 2 joints.
Run: OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_effects.py
"""

import os
import time
from types import SimpleNamespace

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from robust_drake.effects import EFFECTS, all_candidates  # noqa: E402
from robust_drake.synthetic.simulated import HIDDEN_CASES, simulate_experiment  # noqa: E402

ROBOT = "dfki_double_pendulum_c1"
DURATION = 6.0


def cpu(f):
    t = time.process_time()
    f()
    return time.process_time() - t


def main():
    print(f"generator: CPU s per simulated s ({DURATION} s runs, {ROBOT})")
    base = cpu(lambda: simulate_experiment(ROBOT, [], duration=DURATION, seed=0)) / DURATION
    print(f"  {'(baseline only)':28s} {base:6.3f}   ratio 1.00")
    for kind, case in HIDDEN_CASES.items():
        params = dict(case["parameters"])
        if kind == "payload":
            params["robot"] = ROBOT
        c = cpu(lambda: simulate_experiment(ROBOT, [(kind, case["joint"], params)], duration=DURATION,
                                            seed=0)) / DURATION
        print(f"  {kind:28s} {c:6.3f}   ratio {c / base:4.2f}")
    rng = np.random.default_rng(0)
    N = 3000
    data = SimpleNamespace(t=np.arange(N) * 0.004, q=rng.uniform(-2, 2, (N, 2)), qd=rng.normal(0, 1, (N, 2)),
                           qdd=rng.normal(0, 5, (N, 2)), tau=rng.normal(0, 1, (N, 2)), robot=ROBOT)
    print(f"columns for {N} samples x 2 joints (all candidates of a kind), ms")
    for kind in EFFECTS:
        cands = all_candidates(2, kinds=[kind], robot=ROBOT)
        t = time.perf_counter()
        for e in cands:
            e.columns(data)
        print(f"  {kind:28s} {len(cands):3d} candidates {1e3 * (time.perf_counter() - t):8.1f}")


if __name__ == "__main__":
    main()
