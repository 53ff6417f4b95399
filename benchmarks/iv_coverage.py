"""Coverage of the repair's IV confidence sets on simulated 2-link arms (the truth: the URDF's base
parameters, which the simulation uses and the identification never sees).

Per seed: ``experiments.logs_to_control.identify`` (``simulate_experiment``: PD-tracked Fourier
excitation, 5 s at 250 Hz, torque noise 2 % of the largest gravity torque, encoder of ``--bits``
bits; then ``run_repair`` with its Hausman test choosing LS or IV). Over the seeds where the
repair chose instrumental variables, the share of 90 % and 99 % sets of
``uncertainty.confidence.confidence_ellipsoid`` that hold the truth, for the covariance the
model carries (the filter-aware sandwich, ``identification.instruments.iv_sandwich``) and for
the homoscedastic one it carried before (sigma^2 (Z^T Y)^-1 Z^T Z (Y^T Z)^-1 x N / N_eff with a
chi2 quantile), read from the same final fit.

    OPENBLAS_NUM_THREADS=1 python benchmarks/iv_coverage.py [--robot dfki_double_pendulum_c1]
        [--seeds 150] [--bits 14] [--coulomb FC]

About 0.5 s per seed (one core).
"""

from __future__ import annotations

import argparse
import math
import tempfile

import numpy as np
from scipy.stats import chi2


def main(argv=None) -> dict:
    from robust_drake.experiments import logs_to_control as L
    from robust_drake.identification import instruments as IV
    from robust_drake.synthetic import simulated
    from robust_drake.regressor import InverseDynamicsRegressor
    from robust_drake.uncertainty.confidence import confidence_ellipsoid, mahalanobis_radius

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robot", default="dfki_double_pendulum_c1")
    ap.add_argument("--seeds", type=int, default=150)
    ap.add_argument("--bits", type=int, default=14, help="encoder resolution [bits per turn]")
    ap.add_argument("--coulomb", type=float, default=None, help="the simulated arm's Coulomb level [N m]")
    a = ap.parse_args(argv)
    simulate, solve_iv = simulated.simulate_experiment, IV.solve_iv
    fits = []

    def simulate_with(*args, **kw):
        kw["encoder_resolution"] = 2 * math.pi / 2**a.bits
        if a.coulomb is not None:
            kw["coulomb"] = (a.coulomb, a.coulomb)
        return simulate(*args, **kw)

    def solve_iv_kept(*args, **kw):
        fits.append(solve_iv(*args, **kw))
        return fits[-1]

    simulated.simulate_experiment, IV.solve_iv = simulate_with, solve_iv_kept
    truth = InverseDynamicsRegressor.from_robot(a.robot).base_parameters()
    p = len(truth)
    hits = {(k, lev): 0 for k in ("sandwich", "homoscedastic") for lev in (0.9, 0.99)}
    n_iv = 0
    for seed in range(a.seeds):
        fits.clear()
        with tempfile.TemporaryDirectory() as tmp:
            m = L.identify(L.LogsToControlConfig(robot=a.robot, seed=seed), tmp)
        if m.estimator != "instrumental_variables":
            continue
        n_iv += 1
        d = truth - np.asarray(m.base_values, float)
        S0 = fits[-1].cov_homoscedastic[:p, :p]  # the final fit (friction levels >= 0)
        for lev in (0.9, 0.99):
            hits["sandwich", lev] += mahalanobis_radius(*confidence_ellipsoid(m, 1 - lev), truth) <= 1.0
            hits["homoscedastic", lev] += d @ np.linalg.solve(S0, d) <= chi2.ppf(lev, p)
    out = {"robot": a.robot, "bits": a.bits, "seeds": a.seeds, "iv_chosen": n_iv,
           "coverage": {f"{k} {lev:g}": round(float(v) / max(n_iv, 1), 3) for (k, lev), v in hits.items()}}
    print(out)
    return out


if __name__ == "__main__":
    main()
