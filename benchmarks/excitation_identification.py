"""Identification from a designed excitation against the default one (same duration, noise, filter).

For each arm: ``design_excitation`` (robust_drake.excitation), then ``simulate_experiment`` of the
true arm tracking it and tracking the default excitation (``logs_to_control.excitation_for``,
the same seed, duration, 250 Hz log, torque noise 2 % of the largest gravity torque, the
description's friction), both identified by the same repair (``logs_to_control.identify``'s
options: rigid body + friction, LS or IV by the Hausman rule).  Prints per arm: the median over the
base parameters of |theta_hat - theta_true| / sd0 (sd0 = the default excitation's predicted
standard deviation of that parameter: one unit for both runs), its ratio default / designed, and
the ratio of the repair's own confidence-set volume per parameter, (det Sigma_0 / det Sigma)^(1/2p).

    OPENBLAS_NUM_THREADS=1 python benchmarks/excitation_identification.py --robots puma560_3link \\
        --duration 6 --harmonics 4 --seeds 0 1 2
"""

from __future__ import annotations

import argparse

from robust_drake.excitation.evaluate import compare_identification


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--robots", nargs="+", default=["serial7", "puma560_3link", "panda"])
    ap.add_argument("--duration", type=float, default=6.0)
    ap.add_argument("--harmonics", type=int, default=None)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    a = ap.parse_args()
    for robot in a.robots:
        for seed in a.seeds:
            r = compare_identification(robot, a.duration, a.harmonics, seed)
            print({k: (round(v, 4) if isinstance(v, float) else v) for k, v in r.items()}, flush=True)


if __name__ == "__main__":
    main()
