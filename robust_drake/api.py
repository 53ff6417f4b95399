"""The flat public API: ``import robust_drake as rd; rd.simulate(...)``.

Thin, documented entry points over the modules that do the work; the package's
``__init__`` loads this module (and pydrake behind it) only when one of these names is first
used (PEP 562 lazy attributes), so ``import robust_drake`` stays cheap and side-effect free.

Papers: CI = Calafiore & Indri, JS = Jaritz & Spong, BR = Bascetta & Rocco (text and equation
map in ``../shared/seeds``). Units are SI: rad, rad/s, m, N m, s, Hz.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any, Callable, Iterable, Mapping, Sequence

from robust_drake.errors import RobustDrakeError

if TYPE_CHECKING:  # pragma: no cover - for type checkers only
    import numpy as np
    import pandas as pd

    from robust_drake.diagram import ClosedLoop, ClosedLoopConfig, SimulationResult
    from robust_drake.identification.model import IdentifiedModel
    from robust_drake.model_repair.result import RepairResult
    from robust_drake.uncertainty.ellipsoid import EllipsoidResult
    from robust_drake.scenario import Scenario


def simulate(config: "ClosedLoopConfig | None" = None, duration: float | None = None,
             **fields: Any) -> "SimulationResult":
    """Build and run one closed loop: plant, friction, encoder, observer, controller, saturation.

    ``rd.simulate(controller="sp2", trajectory="circle", metrics_skip=1.0)`` is short for
    ``rd.simulate(rd.ClosedLoopConfig(controller="sp2", trajectory="circle", metrics_skip=1.0))``.
    The run's metrics are the error criteria of JS eqs. 55, 56, 58 and 59 (see
    :func:`error_criteria`).

    Parameters
    ----------
    config : ClosedLoopConfig, optional
        The loop to run. None builds one from ``fields`` (all defaults: SP1 on the unloaded
        D2R2 tracking the CPT of JS eq. 48 at 2500 Hz).
    duration : float, optional
        Simulated time [s]; None uses ``config.duration`` or else the reference's own length.
    **fields
        :class:`ClosedLoopConfig` fields, when ``config`` is None (an error otherwise).

    Returns
    -------
    SimulationResult
        Logs at the controller rate (``t`` [s], ``q``, ``q_d`` [rad], ``v`` [rad/s], ``u``,
        ``tau`` [N m], ...), ``metrics`` (dict of the JS criteria), ``diverged`` and
        ``divergence_reason``; ``to_dict()`` gives the JSON of ``robust-drake simulate``.

    Raises
    ------
    RobustDrakeError
        On a bad configuration (named field), or ``fields`` given together with ``config``.
    """
    from robust_drake.diagram import ClosedLoopConfig as _Config
    from robust_drake.diagram import simulate as _simulate

    if config is not None and fields:
        raise RobustDrakeError(f"simulate: give either a ClosedLoopConfig or fields, not both "
                               f"(got {sorted(fields)})")
    if config is None:
        # the duration is a field of the loop (SP1/SP2's sampled epsilon rule reads it), so the
        # keyword form and rd.simulate(ClosedLoopConfig(duration=...)) build the same loop
        config = _Config(**fields, **({} if duration is None else {"duration": duration}))
        duration = None
    return _simulate(config, duration)


def build_closed_loop(config: "ClosedLoopConfig") -> "ClosedLoop":
    """Build (but do not run) the closed-loop Drake diagram described by ``config``.

    Use it to run the same loop several times (``loop.simulate(duration)``) or to look inside:
    ``loop.diagram`` (the Drake ``Diagram``), ``loop.plant`` (``MultibodyPlant``),
    ``loop.controller``, ``loop.reference``.

    Parameters
    ----------
    config : ClosedLoopConfig
        The loop: robot, load, controller, trajectory, rate [Hz], observer, friction, ...

    Returns
    -------
    ClosedLoop
        The built loop; ``simulate(duration=None, initial_q=None)`` runs it from rest.
    """
    from robust_drake.diagram import build_closed_loop as _build

    return _build(config)


def make_plant(robot: str = "d2r2", load: str = "none", time_step: float = 0.0) -> Any:
    """A finalized, standalone Drake ``MultibodyPlant`` of a shipped robot or a URDF file.

    Parameters
    ----------
    robot : str
        Name of a URDF shipped in ``robust_drake/robots`` (``"d2r2"``, ``"imi_scara"``, ...) or
        a path to a URDF file.
    load : str
        Load variant: ``"none"`` or ``"max"`` (the D2R2's JS section 9 load).
    time_step : float
        0 for a continuous plant, else the discrete step [s].

    Returns
    -------
    pydrake.multibody.plant.MultibodyPlant
        Finalized, gravity along world -z (9.81 m/s^2), no SceneGraph.
    """
    from robust_drake.models import make_plant as _make_plant

    return _make_plant(robot, load, time_step)


def error_criteria(t: "np.ndarray", q: "np.ndarray", q_d: "np.ndarray",
                   link_lengths: Sequence[float] | None = None, skip: float = 0.0,
                   dt: float | None = 0.01) -> dict:
    """The six tracking-error criteria of Jaritz & Spong section 4.

    ``error{i}`` = |error_i| (JS eq. 55, the 2-norm of the joint error sampled every ``dt``),
    ``maxerr{i}`` (eq. 56, the peak joint error), ``error_task`` (eq. 58) and ``maxerr_task``
    (eq. 59) the same for the task-space distance of a planar 2-link arm.

    Note the grid: the paper sums its samples without saying at which interval; with ``dt`` =
    0.01 s the simulated |error_n| of the D2R2 CPT come out about twice the published values
    while the maxima agree (``robust-drake compare`` prints this note).

    Parameters
    ----------
    t : numpy.ndarray
        (K,) sample times [s].
    q : numpy.ndarray
        (K, n) joint angles [rad].
    q_d : numpy.ndarray
        (K, n) desired joint angles [rad].
    link_lengths : sequence of float, optional
        (l1, l2) [m] for the task-space criteria; None leaves them NaN.
    skip : float
        Ignore samples with ``t < t[0] + skip`` [s] (JS section 10 drops the circle's first 1 s).
    dt : float or None
        Resampling interval [s] of the sums of squares (default 0.01); None sums raw samples.

    Returns
    -------
    dict
        ``error1, maxerr1, ..., error_task, maxerr_task``: joint criteria in rad, task-space
        ones in m.
    """
    from robust_drake.metrics import error_criteria as _criteria

    return _criteria(t, q, q_d, link_lengths=link_lengths, skip=skip, dt=dt)


def identify(logs: Any, robot: str, *, validate: Any = None, torque: str = "tau_meas",
             cutoff_hz: float | None = None, velocities: str = "positions", estimator: str = "auto",
             progress: Callable[[str], None] | None = None) -> "IdentifiedModel":
    """Identify an arm's rigid body and friction from measured logs (no effect search).

    The URDF's base parameters (Drake-derived regressor) plus Coulomb and viscous friction per
    joint, linear in the parameters (CI eq. 2): weighted least squares, or instrumental variables
    where the Hausman test flags errors in the variables; friction levels >= 0; the estimator's
    covariance, from which :meth:`IdentifiedModel.confidence_set` gives the CI eq. 10 ellipsoid.

    Parameters
    ----------
    logs : str, sequence of str, numpy.ndarray or pandas.DataFrame
        Fit logs: CSV files (canonical ``t, q1..qn, tau1..taun`` or DFKI records), arrays
        (N, 1 + 2n) with columns ``t, q1..qn, tau1..taun`` [s, rad, N m] in that order, or
        DataFrames with those column names (or a list of them).
    robot : str
        Robot name (URDF shipped in ``robust_drake/robots``) or a URDF path.
    validate : optional
        Validation logs, as ``logs``; None holds out the last 25 % of every fit log.
    torque : str
        DFKI torque column, ``"tau_meas"`` or ``"tau_con"`` (ignored for canonical logs).
    cutoff_hz : float, optional
        Zero-phase low-pass cut-off for q and tau [Hz] (None: 8 Hz).
    velocities : str
        ``"positions"`` (differentiate the filtered positions) or ``"logged"`` (the logs' qd columns).
    estimator : str
        ``"auto"``, ``"least_squares"`` or ``"instrumental_variables"``.
    progress : callable, optional
        ``progress(message)`` for progress lines (None: the ``robust_drake`` logger).

    Returns
    -------
    IdentifiedModel
        Base parameters [SI] with covariance, friction ``coulomb`` [N m] / ``viscous``
        [N m s/rad], ``estimator``; ``data["rms_validate"]`` [N m] per joint.
    """
    from robust_drake.model_repair.identify import identify as _identify

    return _identify(logs, robot, validate=validate, torque=torque, cutoff_hz=cutoff_hz, velocities=velocities,
                     estimator=estimator, progress=progress)


def control(model: Any, controller: str = "ci", **options: Any) -> dict:
    """Design a robust controller from an identified model and check it over its confidence set.

    The controller (``"ci"``: Calafiore & Indri eq. 15 on the 1 - alpha ellipsoid; ``"sp1"``,
    ``"sp2"``: Spong's JS eqs. 18 / SP2 with rho from that ellipsoid) is designed from the model's
    base parameters (theta0) and its confidence set; plants drawn across the set (half on its
    boundary, each a physically valid arm) with the identified friction and effects are tracked,
    each run's largest error per joint after the transient compared with that plant's ultimate
    bound (CI: ``experiments.ultimate_bound``; SP1/SP2: JS eq. 20 with rho epsilon).

    Parameters
    ----------
    model : IdentifiedModel, str or RepairResult
        The model, a repair's ``report.json`` (or its folder) or a model file.
    controller : str
        ``"ci"``, ``"sp1"`` or ``"sp2"``.
    **options
        :class:`robust_drake.experiments.control.ControlConfig` fields: ``alpha`` (0.01),
        ``draws`` (8), ``track_duration`` [s] (2), ``transient`` [s] (1), ``rate`` [Hz] (the
        robot's), ``seed``, ``design`` (path of the design YAML to write, None: none).

    Returns
    -------
    dict
        ``guaranteed``, ``verdict``, ``bound`` / ``max_error`` [rad], ``draws`` (per draw:
        ``bound_per_joint``, ``max_error_per_joint``, ...), ``design`` (controller, gains,
        theta0, set, epsilon, rate), ``nominal`` (the design's own run) and ``design_file``.
    """
    from robust_drake.experiments.control import ControlConfig, run_control

    return run_control(model, ControlConfig(controller=controller, **options))


def repair(fit: Any, robot: str, *, validate: Any = None,
           out: str | os.PathLike | None = None, torque: str = "tau_meas",
           cutoff_hz: float | None = None, effects: Sequence[str] | None = None,
           min_gain: float | None = None, max_effects: int = 4, consistent: bool = True,
           instruments: bool = True, nominal: bool = True, replay: bool = True,
           plots: bool = True, sigma_rel: float | None = None, level: float | None = None,
           overwrite: bool = False,
           progress: Callable[[str], None] | None = None) -> "RepairResult":
    """Identify a model from measured data, find and add the missing effects, report before/after.

    The loop of ``robust-drake repair``: filter and differentiate the records, fit the baseline
    (the URDF's base parameters from Drake plus Coulomb and viscous friction, linear in the
    parameters as CI eq. 2), analyse the residual, add effects from the library by forward
    selection on held-out error, test the estimator (least squares vs instrumental variables),
    compare with the URDF's parameters and replay the motion through the Drake plant.

    Parameters
    ----------
    fit : str, sequence of str, numpy.ndarray or pandas.DataFrame
        Fit data: CSV files (canonical ``t, q1..qn, tau1..taun`` or DFKI records), arrays
        (N, 1 + 2n) with columns ``t, q1..qn, tau1..taun`` [s, rad, N m] in that order, or
        DataFrames with those column names (or a list of them).
    robot : str
        Robot name (URDF shipped in ``robust_drake/robots``) or a URDF path.
    validate : optional
        Validation data, as ``fit``; None holds out the last 25 % of every fit file.
    out : str or path, optional
        Folder for ``report.md``, ``report.json`` and the PNG plots; None writes nothing.
    torque : str
        DFKI torque column, ``"tau_meas"`` or ``"tau_con"`` (ignored for canonical CSVs).
    cutoff_hz : float, optional
        Zero-phase low-pass cut-off for q and tau [Hz]; None uses the default (8 Hz).
    effects : sequence of str or str, optional
        Candidate effect kinds to consider, a list or one comma-separated string as the command
        line's ``--effects`` (None: the whole library; an empty string is refused).
    min_gain : float, optional
        Minimum relative held-out error reduction to accept an effect (None: 0.05).
    max_effects : int
        At most this many effects are added.
    consistent : bool
        Also compute the physically consistent (pseudo-inertia LMI) estimate.
    instruments : bool
        Run the errors-in-variables test (least squares vs instrumental variables).
    nominal : bool
        Compare with the URDF's parameters (payload, rotor inertia, torque scale).
    replay : bool
        Replay the measured motion through the Drake plant before and after.
    plots : bool
        Write the residual and replay plots into ``out``.
    sigma_rel : float, optional
        Relative trust in the URDF's base parameters for that comparison (None: 0.05).
    level : float, optional
        Confidence level of every decision from the data (effects, guards, setup change; None: 0.95).
    overwrite : bool
        Replace an earlier report in ``out`` (False refuses, like the CLI without ``--force``).
    progress : callable, optional
        ``progress(message)`` for progress lines; None logs them to the ``robust_drake``
        logger at INFO level.

    Returns
    -------
    RepairResult
        A read-only mapping over the report (``report.json``: ``res["baseline"]`` and
        ``res["final"]`` RMS torque residuals [N m] per joint, ``res["effects"]`` added,
        ``res["verdict"]``, ``res["warnings"]``, ...) with ``.report`` (the dict), ``.model`` and
        ``.baseline_model`` (:class:`IdentifiedModel`), ``.plot()`` and ``.to_markdown()``.
    """
    from robust_drake.errors import OptionError
    from robust_drake.log import progress_callback
    from robust_drake.model_repair.pipeline import RepairOptions
    given = {"cutoff_hz": cutoff_hz, "min_gain": min_gain, "sigma_rel": sigma_rel, "level": level}
    try:  # the command line's validation (RepairOptions.validate, pipeline.run_repair): one set of rules
        opts = RepairOptions(robot=robot, torque=torque, kinds=effects, max_effects=max_effects, consistent=consistent,
                             replay=replay, plots=plots, nominal=nominal, instruments=instruments,
                             **{k: v for k, v in given.items() if v is not None})  # None: RepairOptions' default
        return _repair_logs(fit, validate, opts, out, progress_callback(progress), overwrite)
    except OptionError as exc:
        if exc.option == "kinds":  # the API's keyword for RepairOptions.kinds
            raise OptionError("effects", exc.text) from None
        raise


def _repair_logs(fit, validate, opts, out, progress, overwrite) -> "RepairResult":
    """``run_repair`` on logs given as files, arrays or DataFrames (``identification.logs``)."""
    from robust_drake.identification.logs import as_log_files
    from robust_drake.model_repair.pipeline import run_repair
    from robust_drake.model_repair.result import RepairResult

    with as_log_files(fit, None, "repair") as fits:
        if validate is None:
            rep = run_repair(fits, opts, validate_paths=None, out_dir=out, progress=progress, overwrite=overwrite)
        else:
            with as_log_files(validate, None, "repair (validate)") as vals:
                rep = run_repair(fits, opts, validate_paths=vals, out_dir=out, progress=progress, overwrite=overwrite)
    return RepairResult(rep, None if out is None else str(out))


def ellipsoid(data: Mapping[str, "np.ndarray"] | None = None, *, samples: int = 5,
              bounds: Mapping[str, Sequence[float]] | None = None, solver: str = "clarabel",
              backend: str = "drake", formulation: str = "chordal", draws: int = 1000,
              seed: int = 0) -> "EllipsoidResult":
    """Minimal-trace confidence ellipsoid of the IMI SCARA parameters (CI sections 3-5).

    Builds the per-sample uncertainty model of the linear-in-parameters regressor (CI eqs. 2
    and 12-13, bounded errors on tau and qdd), solves the SDP of CI section 3.1 (through Drake's
    ``MathematicalProgram`` by default) and certifies the result by sampling Delta.

    Parameters
    ----------
    data : mapping, optional
        Measured samples: ``q`` [rad], ``qd`` [rad/s], ``qdd`` [rad/s^2], ``tau`` [N m], each
        (n_m, 2). None simulates the paper's identification experiment with ``samples`` points.
    samples : int
        Number of simulated samples n_m when ``data`` is None (paper: 5).
    bounds : mapping, optional
        Error bounds delta_max, e.g. ``{"tau": [4.5744, 0.5459], "qdd": [0.5892, 1.6478]}``
        [N m, rad/s^2] (None: the paper's section 5 values).
    solver : str
        ``"clarabel"``, ``"scs"`` or ``"csdp"``.
    backend : str
        ``"drake"`` (MathematicalProgram), ``"cvxpy"`` or ``"direct"`` (Clarabel's own API).
    formulation : str
        ``"chordal"`` SDP, ``"full"`` dense SDP, ``"energy"`` closed-form bound, or ``"auto"``.
    draws : int
        Delta draws for the sampling certificate (>= 1: every ellipsoid is certified).
    seed : int
        Random seed of the simulated experiment and the certificate.

    Returns
    -------
    EllipsoidResult
        ``ellipsoid`` (``theta0``, ``P``: E = {theta : (theta - theta0)^T P^-1 (theta - theta0)
        <= 1}), ``trace`` (of P), ``status``, ``certificate``, solve times [s].
    """
    import numpy as np

    from robust_drake.experiments.calafiore import run_ellipsoid_experiment

    for name, value, low in (("samples", samples, 1), ("draws", draws, 1), ("seed", seed, 0)):
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < low:
            raise RobustDrakeError(f"ellipsoid: {name} must be a whole number >= {low}, got {value!r}")
    for name, value in (("solver", solver), ("backend", backend), ("formulation", formulation)):
        if not isinstance(value, str):
            raise RobustDrakeError(f"ellipsoid: {name} must be a name (str), got {value!r}")
    if data is not None:
        if not isinstance(data, Mapping):
            raise RobustDrakeError(f"ellipsoid: data must be a mapping of arrays (q, qd, qdd, tau), got {type(data).__name__}")
        missing = [k for k in ("q", "qd", "qdd", "tau") if k not in data]
        if missing:
            raise RobustDrakeError(f"ellipsoid: data lacks {missing} (need q, qd, qdd, tau)")
        data = {k: np.asarray(data[k], float) for k in ("q", "qd", "qdd", "tau")} | {"theta_true": None}
    if bounds is not None:
        bounds = {k: np.asarray(v, float) for k, v in bounds.items()}
    out = run_ellipsoid_experiment(samples, solver, seed, backend, formulation, draws,
                                   bounds=bounds, data=data)
    return out["_result"]


def run_batch(scenarios: Iterable["Scenario | dict"], *, out: str | os.PathLike | None = None,
              workers: int | None = None, force: bool = False, progress: bool = True) -> "pd.DataFrame":
    """Run many closed loops in parallel and return one table row per run.

    Parameters
    ----------
    scenarios : iterable of Scenario or dict
        The runs; a dict holds :class:`robust_drake.scenario.Scenario` fields (``controller``,
        ``trajectory``, ``load``, ``rate`` [Hz], ``duration`` [s], ...). Duplicates run once.
    out : str or path, optional
        Parquet results file, written as rows finish and resumed on a rerun (None: memory only).
    workers : int, optional
        Local worker processes (None: the core count; 1 runs in this process).
    force : bool
        Overwrite ``out`` even if it holds the results of another batch.
    progress : bool
        Show a progress bar on stderr.

    Returns
    -------
    pandas.DataFrame
        One row per scenario: its fields, ``status`` (ok / diverged / failed), the JS error
        criteria (rad, m) and torque statistics (N m). More options:
        :func:`robust_drake.batch.run_batch`.
    """
    from robust_drake.batch import run_batch as _run_batch

    return _run_batch(scenarios, out=out, workers=workers, force=force, progress=progress)


def run_montecarlo(robot: str = "d2r2", controllers: Sequence[str] = ("sp1", "sp2"),
                   draws: int = 200, *, seed: int = 0, corners: bool = False,
                   ellipsoid: "str | tuple[np.ndarray, np.ndarray] | None" = None,
                   boundary_fraction: float = 0.5, trajectory: str = "cpt",
                   duration: float | None = None, friction_compensation: bool = False,
                   out: str | os.PathLike | None = None, workers: int | None = None,
                   progress: bool = True) -> "pd.DataFrame":
    """Monte Carlo robustness: every controller on drawn "true" plant parameters.

    ``robot="d2r2"`` draws the load increments of JS eq. 93 uniformly over their box (plus its
    8 corners with ``corners``); ``robot="imi_scara"`` draws physically realisable points inside
    and on the boundary of a CI confidence ellipsoid.

    Parameters
    ----------
    robot : str
        ``"d2r2"`` or ``"imi_scara"``.
    controllers : sequence of str
        Controller names (registry), e.g. ``("sp1", "sp2")``.
    draws : int
        Number of parameter draws.
    seed : int
        Random seed of the draws.
    corners : bool
        D2R2: also run the 8 corners of the eq. 93 box.
    ellipsoid : str or (theta0, P), optional
        IMI SCARA: a JSON file with keys ``theta0`` and ``P``, or the pair itself.
    boundary_fraction : float
        IMI SCARA: share of the draws on the ellipsoid's boundary (0..1).
    trajectory : str
        Reference trajectory name (default ``"cpt"``, JS eq. 48).
    duration : float, optional
        Simulated time of every run [s] (None: the trajectory's).
    friction_compensation : bool
        Add the fixed friction compensation of JS eqs. 89-90.
    out : str or path, optional
        Parquet results file (resumable); None keeps results in memory.
    workers : int, optional
        Local worker processes (None: the core count).
    progress : bool
        Show a progress bar on stderr.

    Returns
    -------
    pandas.DataFrame
        One row per (controller, draw) with the JS error criteria; summarise with
        :func:`robust_drake.montecarlo.percentile_table`.
    """
    import numpy as np

    from robust_drake import montecarlo as mc
    from robust_drake.description import describe

    if describe(robot).load_intervals:  # a payload box in the robot's description (D2R2: JS eq. 93)
        if ellipsoid is not None:
            raise RobustDrakeError(f"run_montecarlo: ellipsoid is for robot imi_scara; {robot} draws from the "
                                   "load_intervals of its description (the D2R2: JS eq. 93)")
        thetas, deltas = mc.draw_d2r2(draws, seed=seed, corners=corners)
        tags = [{"dm2": float(d[0]), "dlc2": float(d[1]), "dI2": float(d[2])} for d in deltas]
    elif describe(robot).closed_form_regressor == "imi_scara":  # CI section 5 parameters
        if ellipsoid is None:
            raise RobustDrakeError("run_montecarlo: robot imi_scara needs ellipsoid (file or (theta0, P))")
        theta0, P = (mc.load_ellipsoid(ellipsoid) if isinstance(ellipsoid, (str, os.PathLike))
                     else (np.asarray(ellipsoid[0], float), np.asarray(ellipsoid[1], float)))
        thetas, radii, _ = mc.draw_imi(theta0, P, draws, seed=seed, boundary_fraction=boundary_fraction)
        tags = [{"radius": float(r)} for r in radii]
    else:
        raise RobustDrakeError(f"run_montecarlo: robot must be d2r2 or imi_scara, not {robot!r}")
    base = dict(trajectory=trajectory, duration=duration, friction_compensation=friction_compensation,
                seed=seed)
    scenarios = mc.montecarlo_scenarios(robot, list(controllers), thetas, base=base, tags=tags)
    return mc.run_montecarlo(scenarios, out=out, workers=workers, progress=progress)


def list_robots() -> "list[dict]":
    """The shipped robots (``robust-drake list robots``).

    Returns
    -------
    list of dict
        One per robot: ``name``, ``joints``, ``loads``, ``sample_rate`` [Hz] (None: the 2500 Hz
        default), ``torque_limits`` [N m], ``gravity``, ``plane`` and a one-line ``summary``.
    """
    from robust_drake.registry import list_robots as _list

    return _list()


def list_controllers() -> "list[dict]":
    """The controllers ``ClosedLoopConfig(controller=...)`` accepts (``robust-drake list controllers``).

    Names are accepted in any case and by their paper names (``"SP1"``, ``"LG+"``).

    Returns
    -------
    list of dict
        One per controller: ``name``, ``paper_name``, ``summary``, ``paper`` (equations) and
        ``parameters`` (``[{"name", "unit", "description"}]``, the keys of ``controller_params``).
    """
    from robust_drake.registry import catalog

    return catalog()["controllers"]


def list_trajectories() -> "list[dict]":
    """The references ``ClosedLoopConfig(trajectory=...)`` accepts (``robust-drake list trajectories``).

    Returns
    -------
    list of dict
        One per trajectory: ``name``, ``paper_name``, ``summary`` and ``parameters``
        (``[{"name", "unit", "description"}]``, the keys of ``trajectory_params``).
    """
    from robust_drake.registry import catalog

    return catalog()["trajectories"]


def list_observers() -> "list[dict]":
    """The velocity estimators ``ClosedLoopConfig(observer=...)`` accepts (``robust-drake list observers``).

    Returns
    -------
    list of dict
        One per observer: ``name``, ``summary`` and ``parameters`` (the keys of ``observer_params``).
    """
    from robust_drake.registry import catalog

    return catalog()["observers"]


def default_gains(ctx: Any) -> "tuple":
    """The K [N m s/rad] and Lambda [1/s] gains the PD, SP1 and SP2 of a loop use by default.

    JS section 8's diag(30, 10) and diag(50, 20) on the D2R2; on any other arm Lambda = 20 I and
    K = 20 [1/s] diag(M(0)), so each joint's sliding variable r = e_dot + Lambda e decays at about
    20 1/s under K alone. For a custom controller's factory: ``K, Lam = rd.default_gains(ctx)``.

    Parameters
    ----------
    ctx : BuildContext
        What a factory is called with (``ctx.robot``, ``ctx.load``, ``ctx.n``, ``ctx.period``).

    Returns
    -------
    tuple
        ``(K, Lambda)``, one entry per joint each.
    """
    from robust_drake.systems.controllers.spong import default_gains as _gains

    return _gains(ctx)
def excite(robot: str | None = None, *, config: "Any" = None, progress: Callable | None = None,
           **options: Any) -> "Any":
    """Design an identification experiment: a periodic, band-limited Fourier motion that
    maximises log det of the information of the base parameters plus friction (D-optimal,
    Swevers et al. 1997; Gautier & Khalil 1992's condition number is reported), within the
    joint position, velocity, acceleration and torque limits and free of collisions where the
    URDF has collision geometry, at rest at the start pose at both ends
    (:mod:`robust_drake.excitation.design`).

    ``rd.excite("panda", duration=10)`` is short for
    ``rd.excite(config=rd.ExcitationConfig(robot="panda", duration=10))``.

    Parameters
    ----------
    robot : str
        Robot name or URDF path (when ``config`` is not given).
    config : ExcitationConfig, optional
        The whole design: duration [s], period [s], harmonics, max_frequency [Hz], start pose
        [rad], velocity / acceleration / torque limits, ``effects`` (kinds added to the
        information, e.g. ``("position_dependent", "stribeck")``), min_distance [m], rate [Hz].
    progress : callable, optional
        ``progress(message)`` at each stage (default: the ``robust_drake`` logger).
    **options
        :class:`~robust_drake.excitation.design.ExcitationConfig` fields.

    Returns
    -------
    ExcitationResult
        ``trajectory`` (callable t -> (q, qd, qdd)), samples ``t, q, qd, qdd, tau`` at the
        robot's rate, ``report`` (log_det, condition_number, predicted_std vs the default
        excitation, margins); ``to_csv(path)`` writes ``t, q1.., qd1.., qdd1..`` (what
        ``simulate --trajectory FILE.csv`` tracks), ``plot(dir)``, ``figure()``.

    Raises
    ------
    RobustDrakeError
        On a bad configuration or when no motion satisfies the limits.
    """
    from robust_drake.excitation.design import ExcitationConfig as _Config
    from robust_drake.excitation.design import design_excitation

    if config is not None and (robot is not None or options):
        raise RobustDrakeError("excite: give either a config or robot and options, not both")
    if config is None:
        if robot is None:
            raise RobustDrakeError("excite: give the robot (a name or a URDF path)")
        config = _Config(robot=robot, **options)
    return design_excitation(config, progress=progress)


def simulate_experiment(robot: str, effects: Any = (), *, duration: float = 10.0, reference: Any = None,
                        seed: int = 0, out_csv: str | None = None, **options: Any) -> "Any":
    """Rehearse an identification experiment in simulation: the arm (URDF + the description's
    friction) with hidden ``effects`` tracks ``reference`` (e.g. ``rd.excite(...).trajectory``,
    or by default the built-in Fourier excitation about the middle of the joint ranges) under a
    PD loop, with torque noise and encoder rounding; returns the log ``t, q1..qn, tau1..taun``
    [s, rad, N m] as a DataFrame and writes it to ``out_csv`` when given (what ``rd.repair``
    reads).

    Parameters
    ----------
    robot : str
        Robot name or URDF path.
    effects : list of (kind, joint, parameters)
        Effects the simulated arm has and the URDF does not (kinds of the effect library, joints
        0-based as in the library's constructors), e.g. ``[("position_dependent", 1,
        {"amplitude": 0.06, "harmonic": 4})]``.
    duration : float
        Length of the log [s].
    reference : callable, optional
        ``f(t) -> (q, qd, qdd)`` to track instead of the default excitation.
    seed : int
        Seed of the noise (and of the default excitation's phases).
    out_csv : str, optional
        Where to write the log.
    **options
        ``synthetic.simulated.simulate_experiment`` keywords (``rate_hz``, ``coulomb``,
        ``viscous``, ``torque_noise_std`` [N m], ``encoder_resolution`` [rad], ...).
    """
    from robust_drake.experiments.logs_to_control import excitation_for
    from robust_drake.synthetic.simulated import simulate_experiment as _simulate

    excitation = excitation_for(robot)
    if reference is not None:
        if not callable(reference):
            raise RobustDrakeError("simulate_experiment: reference must be a callable t -> (q, qd, qdd), "
                                   "e.g. rd.excite(...).trajectory")
        excitation["reference"] = reference
    return _simulate(robot=robot, effects=effects, duration=duration, seed=seed, excitation=excitation,
                     out_csv=out_csv, **options)
