"""How much better a designed excitation identifies than the default one, on a simulated arm.

:func:`compare_identification`: the true arm (its URDF, the description's friction or the
generator's defaults, torque noise 2 % of the largest gravity torque: the repo's simulated
experiments, ``experiments.logs_to_control``) runs ``synthetic.simulated.simulate_experiment``
twice with the same duration, seed, 250 Hz log, noise and 8 Hz filter: tracking the designed
motion and tracking the default excitation (``logs_to_control.excitation_for``).  Both logs are
identified by the same repair (rigid body + friction, LS or IV by the Hausman rule, as
``logs_to_control.identify``).  Errors are |theta_hat - theta_true| per base parameter, in units
of the default excitation's predicted standard deviation of that parameter (one unit for both
runs, so parameters of every size count alike); the median over the parameters is compared.
"""

from __future__ import annotations

import os
import tempfile
import time

import numpy as np


def identify_csv(robot, path):
    from robust_drake.identification.model import IdentifiedModel
    from robust_drake.model_repair.pipeline import RepairOptions, run_repair

    opts = RepairOptions(robot=robot, max_effects=0, kinds=[], replay=False, plots=False, instruments=True,
                         nominal=False, consistent=False, never_worse_tol=float("inf"))
    rep = run_repair([path], opts, progress=lambda *_: None)
    return IdentifiedModel.from_report(rep, "final")


def compare_identification(robot, duration, harmonics=None, seed=0, out_dir=None, design=None) -> dict:
    """The comparison for one arm and seed (module docstring): ``median_error_default`` /
    ``median_error_designed`` and their ``error_ratio``, the repair's own confidence-set volume
    ratio per parameter (det Sigma_0 / det Sigma)^(1/2p), the design's predicted median std ratio.
    ``design``: an :class:`ExcitationResult` to use (default: designed here)."""
    from robust_drake.excitation.design import ExcitationConfig, design_excitation
    from robust_drake.experiments.logs_to_control import excitation_for, torque_noise_std, true_friction
    from robust_drake.synthetic.simulated import simulate_experiment
    from robust_drake.regressor import InverseDynamicsRegressor

    out_dir = out_dir or tempfile.mkdtemp(prefix=f"excite_{robot}_")
    t0 = time.perf_counter()
    res = design or design_excitation(ExcitationConfig(robot=robot, duration=duration, harmonics=harmonics,
                                                       seed=seed), progress=lambda *_: None)
    t_design = time.perf_counter() - t0
    exc = excitation_for(robot)
    n = len(exc["amplitude"])
    coulomb, viscous = true_friction(robot, n)
    sigma = torque_noise_std(robot, 0.02)
    truth = InverseDynamicsRegressor.from_robot(robot).base_parameters()
    p = len(truth)
    sd0 = np.asarray(res.report["default"]["predicted_std"][:p])
    out = {"robot": robot, "seed": seed, "duration": duration, "harmonics": res.trajectory.harmonics,
           "design_seconds": t_design}
    models = {}
    for name, excitation in (("default", dict(exc)), ("designed", {**exc, "reference": res.trajectory})):
        path = os.path.join(out_dir, f"{name}.csv")
        simulate_experiment(robot=robot, duration=duration, seed=seed, out_csv=path, torque_noise_std=sigma,
                            excitation=excitation, coulomb=coulomb, viscous=viscous)
        m = identify_csv(robot, path)
        models[name] = m
        err = np.abs(np.asarray(m.base_values) - truth) / sd0
        out[f"median_error_{name}"] = float(np.median(err))
        out[f"estimator_{name}"] = m.estimator
    out["error_ratio"] = out["median_error_default"] / out["median_error_designed"]
    C0, C1 = models["default"].base_covariance, models["designed"].base_covariance
    if C0 is not None and C1 is not None:
        l0, l1 = np.linalg.slogdet(C0)[1], np.linalg.slogdet(C1)[1]
        out["volume_ratio_per_parameter"] = float(np.exp((l0 - l1) / (2 * p)))
    out["predicted_median_std_ratio"] = res.report["median_std_ratio"]
    return out
