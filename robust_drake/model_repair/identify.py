"""Plain identification: logs -> an :class:`~robust_drake.identification.model.IdentifiedModel`.

Rigid body (the URDF's base parameters, Drake-derived regressor) + Coulomb and viscous friction,
linear in the parameters (CI eq. 2), weighted least squares with the per-joint weights of the
repair's first step, or instrumental variables where the Hausman test flags errors in the
variables (``identification.instruments``); friction levels >= 0; the estimator's covariance
(least squares: homoscedastic, IV: the filter-aware sandwich), from which
:meth:`IdentifiedModel.confidence_set` builds the confidence ellipsoid. No effect search, no
URDF comparison, no replay: the stages of the repair this needs and nothing else
(``stages.load_inputs``, ``fit_baseline``, ``choose_estimator``, ``final_model``), so the model
is the one the repair with no effects would give.
"""

from __future__ import annotations

import os

from robust_drake.errors import RobustDrakeError

ESTIMATORS = ("auto", "least_squares", "instrumental_variables")


def identify(logs, robot, *, validate=None, torque: str = "tau_meas", cutoff_hz: float | None = None,
             velocities: str = "positions", estimator: str = "auto", progress=None):
    """Identify rigid body + friction from ``logs`` (module docstring); returns the model.

    ``logs`` / ``validate``: CSV paths, arrays (N, 1 + 2n) with columns ``t, q1..qn, tau1..taun``
    or pandas DataFrames (:func:`robust_drake.identification.logs.as_log_files`); without
    ``validate`` the last 25 % of every fit file is held out for ``model.data["rms_validate"]``.
    ``estimator``: "auto" (IV when the Hausman test is significant at 1 %), "least_squares" or
    "instrumental_variables"."""
    from robust_drake.identification.data import DEFAULT_CUTOFF_HZ
    from robust_drake.identification.logs import as_log_files
    from robust_drake.log import progress_callback
    from robust_drake.model_repair.pipeline import RepairOptions

    if estimator not in ESTIMATORS:
        raise RobustDrakeError(f"estimator must be one of {', '.join(ESTIMATORS)} (got {estimator!r})")
    if not isinstance(robot, (str, os.PathLike)) or not str(robot):
        raise RobustDrakeError(f"robot must be a robot name or a URDF path (got {robot!r})")
    log = progress_callback(progress)
    opts = RepairOptions(robot=str(robot), torque=torque, cutoff_hz=DEFAULT_CUTOFF_HZ if cutoff_hz is None else cutoff_hz,
                         velocities=velocities, kinds=[], max_effects=0, consistent=False, replay=False, plots=False,
                         nominal=False, instruments=estimator != "least_squares")
    with as_log_files(logs, None, "identify") as fits:
        if validate is None:
            return _identify_files(fits, None, opts, estimator, log)
        with as_log_files(validate, None, "identify (validate)") as vals:
            return _identify_files(fits, vals, opts, estimator, log)


def _identify_files(fits, vals, opts, estimator: str, log):
    import numpy as np

    from robust_drake.identification import input_checks as IC
    from robust_drake.model_repair import stages as S
    from robust_drake.model_repair.pipeline import _check_robot_urdf

    IC.check_distinct_files(fits, vals)
    _check_robot_urdf(opts.robot)
    inp = S.load_inputs(fits, vals, opts, log)
    base = S.fit_baseline(inp, opts, log)
    est = S.choose_estimator(inp, base, opts, log)
    if estimator == "instrumental_variables":
        if est.icache is None:
            raise RobustDrakeError("instrumental variables need filtered positions (a cut-off and computed "
                                   "derivatives)")
        est.method = est.report["method"] = "instrumental_variables"
    sel = S.Selection(candidates=[], steps=[], ranking=[], chosen=[], weights=base.weights, step_label={})
    fin = S.final_model(inp, est, sel, opts)
    _, model = S.identified_models(inp, base, est, sel, fin)
    model.data.update(torque=opts.torque, rms_fit=inp.cf.rms(fin.fit.residual).tolist(),
                      rms_validate=np.sqrt(np.mean(np.asarray(fin.val_residual) ** 2, axis=0)).tolist(),
                      warnings=list(dict.fromkeys(inp.warnings)), identified_by="identify")
    log(f"identified {opts.robot}: {model.estimator}, validation RMS {np.round(model.data['rms_validate'], 4)} N m")
    return model
