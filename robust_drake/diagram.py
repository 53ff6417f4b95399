"""The closed-loop builder: plant + friction + encoder + observer + controller +
saturation + trajectory + loggers, from a small :class:`ClosedLoopConfig`.

::

    reference --x_d--> observer --v, v_error--> controller --u (held)--> [compensation] --> saturation --tau--+
       |                 ^ q                                                                                |
       +------x_d--------+---------------------------------------------> controller                       v
                         encoder <--state-- MultibodyPlant <--applied_generalized_force-- Adder(tau, effects...)
                                                  |--state--> friction / effect blocks --------------------^

The plant is continuous; the controller and observer are discrete at ``rate`` Hz and
their outputs are held between samples (zero-order hold). The integrator is a fixed-step
RK2 whose step divides the sample period (at most 0.4 ms), so every controller tick
lands on an integrator step (see BUILD_NOTES.md and the pydrake pitfalls notes).

A notebook user writes::

    from robust_drake.diagram import ClosedLoopConfig, simulate
    res = simulate(ClosedLoopConfig(robot="d2r2", controller="sp1", trajectory="cpt"))
    res.metrics["error_task"]
"""

from __future__ import annotations

import math
import numbers
import os
import time
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any, Callable

import numpy as np
from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput, Multiplexer, Saturation

from robust_drake.description import describe
from robust_drake.divergence import STATE_LIMIT, TRACKING_ERROR_LIMIT, is_diverged
from robust_drake.errors import RobustDrakeError
from robust_drake.loop_defaults import LOOP_DEFAULTS
from robust_drake.metrics import error_criteria, torque_statistics
from robust_drake.models import ArmSpec, JointLimits, ROBOTS, add_arm, get_arm, set_d2r2_theta
from robust_drake.registry import BuildContext, block_label, is_block_spec, make_block
from robust_drake.forces import add_force_blocks, sum_into_plant
from robust_drake.systems.friction import CompiledCoulombViscousFriction, FixedFrictionCompensation
from robust_drake.systems.sensors import CompiledQuantizingEncoder, quantize
from robust_drake.systems.sampled_reference import SampledReference
from robust_drake.trajectories import check_within_limits, make_reference

if TYPE_CHECKING:  # pragma: no cover
    import pandas as pd
    from matplotlib.figure import Figure

MAX_INTEGRATOR_STEP = 4e-4  # s; the plant is integrated with steps no longer than this
DIVERGENCE_LIMIT = STATE_LIMIT  # |q| [rad] or |v| [rad/s]; see robust_drake.divergence

#: Logged samples per logger of one run (one per controller tick): ~150 B each for the
#: 2-joint arm, so 2e6 samples (800 s at 2500 Hz) keep the logs near 300 MB.
MAX_LOG_SAMPLES = 2_000_000
#: fewest controller ticks a run may have (check_run_size): with fewer the metrics are NaN and
#: "not diverged" would say nothing
MIN_TICKS = 10
#: Fixed RK2 steps of one run (several per tick at low rates; ~ an hour of wall time).
MAX_INTEGRATOR_STEPS = 50_000_000


def check_run_size(duration: float, rate: float) -> None:
    """Refuse a run whose controller ticks (each logged, so: logged samples) exceed
    :data:`MAX_LOG_SAMPLES` or whose integrator steps exceed :data:`MAX_INTEGRATOR_STEPS`,
    before anything is allocated (``duration`` [s], ``rate`` [Hz])."""
    ticks = float(duration) * float(rate)
    if not ticks >= MIN_TICKS:
        raise RobustDrakeError(
            f"{duration:g} s at {rate:g} Hz is {ticks:.3g} controller tick(s): a run needs at least {MIN_TICKS} "
            "(its error criteria and divergence test come from the ticks); lengthen the duration or raise the rate")
    if ticks + 1 > MAX_LOG_SAMPLES:
        raise RobustDrakeError(
            f"{duration:g} s at {rate:g} Hz is {ticks:.3g} controller ticks, each logged: more "
            f"than the limit of {MAX_LOG_SAMPLES:.3g} logged samples per run "
            "(robust_drake.diagram.MAX_LOG_SAMPLES); lower the rate or the duration")
    period = 1.0 / float(rate)
    sub = max(1, math.ceil(period / MAX_INTEGRATOR_STEP - 1e-9))
    steps = ticks * sub
    if steps > MAX_INTEGRATOR_STEPS:
        raise RobustDrakeError(
            f"{duration:g} s at {rate:g} Hz needs {steps:.3g} integrator steps (at most "
            f"{MAX_INTEGRATOR_STEP * 1e3:g} ms each): more than the limit of "
            f"{MAX_INTEGRATOR_STEPS:.3g} (robust_drake.diagram.MAX_INTEGRATOR_STEPS); "
            "shorten the duration")

#: runs of at least this many controller ticks advance in PROGRESS_CHUNKS pieces (at whole
#: ticks) and log the share done with an estimate of the time left once PROGRESS_AFTER_S passed
PROGRESS_TICKS = 100_000
PROGRESS_CHUNKS = 20
PROGRESS_AFTER_S = 2.0


def _advance_with_progress(simulator, duration: float, period: float) -> None:
    """``simulator.AdvanceTo(duration)``; a long run (>= PROGRESS_TICKS ticks) goes in pieces that
    end on controller ticks and logs "simulating: 35 % (1260 of 3600 s), 40 s elapsed, about 74 s
    left" (INFO, logger robust_drake) when it has already taken PROGRESS_AFTER_S."""
    ticks = int(round(duration / period))
    if ticks < PROGRESS_TICKS:
        simulator.AdvanceTo(duration)
        return
    from robust_drake.log import get_logger

    log = get_logger()
    t0 = time.perf_counter()
    for k in range(1, PROGRESS_CHUNKS + 1):
        t_end = duration if k == PROGRESS_CHUNKS else (ticks * k // PROGRESS_CHUNKS) * period
        simulator.AdvanceTo(t_end)
        wall = time.perf_counter() - t0
        if wall >= PROGRESS_AFTER_S and k < PROGRESS_CHUNKS:
            left = wall * (duration - t_end) / t_end
            log.info("simulating: %.0f %% (%.4g of %.4g s), %.0f s elapsed, about %.0f s left",
                     100.0 * t_end / duration, t_end, duration, wall, left)


class _RobotDefault:
    """The marker of a field filled from the robot's description (:meth:`ClosedLoopConfig.resolved`)."""

    def __repr__(self) -> str:
        return "<from the robot's description>"


_DEFAULT = _RobotDefault()


@dataclass
class ClosedLoopConfig:
    """Everything that defines one closed loop (serialisable except ``effects`` callables).

    Defaults marked "robot" are filled in by :meth:`resolved` from the robot's description
    (:mod:`robust_drake.description`): the D2R2's values for the D2R2, none for arms without one.

    Parameters
    ----------
    robot : str
        Robot name (URDF shipped in ``robust_drake/robots``) or a URDF path (default ``"d2r2"``).
    load : str
        Load variant, ``"none"`` or ``"max"`` (JS section 9).
    controller : str, LeafSystem or callable
        Controller registry name (``"pd"``, ``"sp1"``, ``"sp2"``, ``"zc"``, ``"lgplus"``, ...), a
        pydrake LeafSystem instance (one loop per instance) or a factory ``f(ctx, **params) ->
        LeafSystem`` (``ctx`` a :class:`~robust_drake.registry.BuildContext`); ports as in
        BUILD_NOTES "Architecture contract", checked by
        :func:`robust_drake.registry.check_ports`; ``to_dict`` records a custom block as
        ``"custom:<name>"``.
    controller_params : dict
        Controller parameters (gains, epsilons, ...), by the controller's documented names.
    trajectory : str
        Reference: ``"cpt"`` (JS eq. 48), ``"circle"`` (JS section 10), ``"refmodel"``,
        ``"sine"``, ``"step"``, ``"line"``.
    trajectory_params : dict
        Reference parameters.
    rate : float
        Controller and observer sample rate [Hz]; default: the robot description's
        ``sample_rate`` (the D2R2: 2500, JS section 8; the Panda: 1000, Franka's control
        interface), 2500 for a robot whose description gives none.
    observer : str, LeafSystem or callable
        Velocity estimator (default ``"averaging"``, JS eqs. 64/66): a registry name, an instance
        or a factory, as for ``controller``.
    observer_params : dict
        Estimator parameters.
    plant_friction : dict or None
        ``{"coulomb": [N m], "viscous": [N m s/rad]}`` per joint for the plant-side friction
        block; None for a frictionless plant (default: robot).
    friction_compensation : bool
        Add the fixed compensation of JS eqs. 89-90 to the command.
    compensation_params : dict
        ``{"k_hat": [...]}`` for that compensation.
    encoder_resolution : float or None
        Quantum of the measured position [rad] (None: exact; default: robot, theta_m for the
        D2R2).
    torque_limit : list of float or None
        Saturation of the command [N m] per joint (None: none; default: robot, 31.2 N m on the
        D2R2).
    duration : float or None
        Simulated time [s] (None: the reference's).
    metrics_skip : float
        Ignore the first ``metrics_skip`` s in the error criteria [s].
    metrics_dt : float or None
        Summation grid of the |error_n| criteria [s] (JS eqs. 55, 58); None: every sample.
    true_theta : list of float or None
        D2R2 plant parameters of JS eq. 14 (the Monte Carlo "true" arm).
    initial_q : list of float or None
        Initial joint angles [rad] (None: the reference's start, at rest).
    effects : list
        Extra plant-side blocks: registry ``(name, {params})`` pairs or callables
        ``f(ctx) -> LeafSystem`` with input ``state`` (optionally ``tau``) and output
        ``generalized_force``.
    plant_setup : list
        Callables ``f(plant, plant_context)`` changing the plant's parameters before each run.
    feedforward : list
        Callables ``f(q_meas, v_hat) -> torques`` [N m] added to the controller's command within
        each tick (the controller must be a
        :class:`~robust_drake.systems.controllers.base.DiscreteController`).
    divergence_error : float or None
        Joint error [rad] beyond which a run stops as diverged (None: never).
    flexibility : FlexibilityConfig, dict or None
        Two-mass drives and structural modes (:mod:`robust_drake.systems.flexibility`);
        None: rigid arm.
    model : IdentifiedModel, str, dict or None
        The controller's model: an :class:`~robust_drake.identification.model.IdentifiedModel`, a
        repair's ``report.json`` (or its folder) / a model file, or a model's JSON dict. SP1,
        SP2, CI eq. 15 and BR Case A/B take theta0 and their uncertainty set from it (its
        confidence set); its friction and (q, v) effects are fed forward, its stateful effects
        compensated by their blocks (:meth:`IdentifiedModel.closed_loop_hooks`). Given
        ``controller_params`` theta0 / P / ellipsoid / rho win (the model then only compensates).
    plant_model : IdentifiedModel, str, dict or None
        The simulated arm is this identified model: its rigid body (base parameters realised as
        URDF inertias), friction (unless ``plant_friction`` is given) and every effect.
    compensation : list
        Block factories ``f(ctx) -> LeafSystem`` with input ``state`` (2n, fed [q_meas, v_hat])
        and output ``generalized_force`` (n): the force the block predicts on the plant is
        cancelled in the command (u - force) before saturation.
    """

    robot: str = LOOP_DEFAULTS["robot"]
    load: str = LOOP_DEFAULTS["load"]
    controller: str = LOOP_DEFAULTS["controller"]
    controller_params: dict = field(default_factory=dict)
    trajectory: str = LOOP_DEFAULTS["trajectory"]
    trajectory_params: dict = field(default_factory=dict)
    rate: Any = _DEFAULT
    observer: str = LOOP_DEFAULTS["observer"]
    observer_params: dict = field(default_factory=dict)
    plant_friction: Any = _DEFAULT
    friction_compensation: bool = LOOP_DEFAULTS["friction_compensation"]
    compensation_params: dict = field(default_factory=dict)
    encoder_resolution: Any = _DEFAULT
    torque_limit: Any = _DEFAULT
    duration: float | None = LOOP_DEFAULTS["duration"]
    metrics_skip: float = 0.0
    metrics_dt: float | None = 0.01
    true_theta: list | None = LOOP_DEFAULTS["true_theta"]
    initial_q: list | None = None
    effects: list = field(default_factory=list)
    plant_setup: list = field(default_factory=list)
    feedforward: list = field(default_factory=list)
    divergence_error: float | None = TRACKING_ERROR_LIMIT
    flexibility: Any = None  # FlexibilityConfig | dict | None (rigid); see robust_drake.systems.flexibility
    model: Any = None  # IdentifiedModel | report/model path | JSON dict: the controller's model
    plant_model: Any = None  # IdentifiedModel | path | dict: the simulated arm
    compensation: list = field(default_factory=list)

    def __post_init__(self):
        self.validate()
        from robust_drake.registry import canonical_or_same, canonical_robot

        self.robot = canonical_robot(self.robot)

        for kind in ("controller", "observer", "trajectory"):  # "SP1", "LG+" -> "sp1", "lgplus"
            setattr(self, kind, canonical_or_same(kind, getattr(self, kind)))

    def validate(self) -> None:
        """Check types and ranges of every field; raise RobustDrakeError naming the first
        bad one (called on construction, so a bad config never reaches the builder)."""
        _check_config(self)

    def resolved(self) -> "ClosedLoopConfig":
        """A copy with the robot-dependent defaults filled in and inputs checked."""
        c = ClosedLoopConfig(**{k: getattr(self, k) for k in self.__dataclass_fields__})
        c.model, c.plant_model = _identified(c.model, "model"), _identified(c.plant_model, "plant_model")
        if c.plant_model is not None and c.plant_friction is _DEFAULT:  # the identified arm's friction
            c.plant_friction = {"coulomb": np.asarray(c.plant_model.coulomb, float).tolist(),
                                "viscous": np.asarray(c.plant_model.viscous, float).tolist()}
        for name, value in describe(c.robot).closed_loop_defaults().items():
            if getattr(c, name) is _DEFAULT:
                setattr(c, name, value)
        if c.duration is not None:
            check_run_size(c.duration, c.rate)
        return c

    def to_dict(self) -> dict:
        d = {k: getattr(self, k) for k in self.__dataclass_fields__
             if k not in ("effects", "plant_setup", "feedforward", "compensation")}
        for k in ("model", "plant_model"):  # a path as given, a model as its JSON
            if d[k] is not None and not isinstance(d[k], (str, os.PathLike, dict)):
                d[k] = d[k].to_json()
            elif isinstance(d[k], os.PathLike):
                d[k] = os.fspath(d[k])
        d["controller"], d["observer"] = block_label(self.controller), block_label(self.observer)
        if self.flexibility is not None and hasattr(self.flexibility, "to_dict"):
            d["flexibility"] = self.flexibility.to_dict()
        d["effects"] = [e if isinstance(e, (list, tuple)) else getattr(e, "__name__", repr(e)) for e in self.effects]
        return {k: (None if v is _DEFAULT else v) for k, v in d.items()}

    @classmethod
    def from_dict(cls, d: dict) -> "ClosedLoopConfig":
        """A config from plain data (YAML / JSON): every field by name, ``effects`` as
        ``[name, {params}]`` pairs, ``plant_setup`` as ``"module:function"`` or
        ``["module:function", {params}]`` entries, ``model`` / ``plant_model`` as a path or a
        model's JSON dict; fields left out take their defaults (the robot description's)."""
        if not isinstance(d, dict):
            raise RobustDrakeError(f"a closed-loop description is a mapping of ClosedLoopConfig fields (got {type(d).__name__})")
        known = {f for f in cls.__dataclass_fields__}
        unknown = sorted(set(d) - known)
        if unknown:
            raise RobustDrakeError(f"unknown closed-loop field(s) {unknown}; known: {sorted(known)}")
        kw = {k: v for k, v in d.items() if not (v is None and k == "rate")}  # None elsewhere: "none"
        if "effects" in kw:
            bad = [e for e in kw["effects"] or [] if not isinstance(e, (list, tuple))]
            if bad:
                raise RobustDrakeError(f"effects entries must be [name, {{params}}] pairs (got {bad[0]!r}: a block "
                                       "factory is not written to a file)")
            kw["effects"] = [tuple(e) for e in kw["effects"] or []]
        if "plant_setup" in kw:
            kw["plant_setup"] = [e if callable(e) else plant_setup_callable(e) for e in kw["plant_setup"]]
        for k in ("controller_params", "trajectory_params", "observer_params", "compensation_params"):
            if kw.get(k) is None and k in kw:
                kw[k] = {}
        try:
            return cls(**kw)
        except TypeError as exc:
            raise RobustDrakeError(f"closed-loop description: {exc}") from None

    @classmethod
    def from_yaml(cls, path) -> "ClosedLoopConfig":
        """:meth:`from_dict` of a YAML file (a mapping of fields; a design file of ``robust-drake
        control`` keeps them under ``closed_loop``)."""
        import yaml

        try:
            with open(path) as fh:
                doc = yaml.safe_load(fh)
        except OSError as exc:
            raise RobustDrakeError(f"cannot read {path}: {exc.strerror or exc}") from None
        except yaml.YAMLError as exc:
            raise RobustDrakeError(f"{path} is not YAML: {str(exc).splitlines()[0]}") from None
        if isinstance(doc, dict) and isinstance(doc.get("closed_loop"), dict):
            doc = doc["closed_loop"]
        try:
            return cls.from_dict(doc)
        except RobustDrakeError as exc:
            raise RobustDrakeError(f"{path}: {exc}") from None

    def to_yaml(self, path=None) -> str:
        """The plain-data fields of the resolved config (robot defaults filled in, a model path
        replaced by the model's JSON) as YAML, which :meth:`from_yaml` reads back to the same
        loop (callables -- effects factories, plant_setup functions, feedforward -- are not
        written); written to ``path`` when given. Floats read back bit for bit."""
        import yaml

        text = yaml.safe_dump(_plain_data(self.resolved().to_dict()), sort_keys=False)
        if path is not None:
            with open(path, "w") as fh:
                fh.write(text)
        return text


def plant_setup_callable(entry):
    """``["module:function", {params}]`` -> ``f(plant, plant_context)`` (serialisable form of
    ClosedLoopConfig.plant_setup, e.g. Monte Carlo "true" parameters of a robot)."""
    import functools
    import importlib

    if isinstance(entry, str):
        target, params = entry, {}
    elif isinstance(entry, (list, tuple)) and len(entry) in (1, 2) and isinstance(entry[0], str):
        target, params = entry[0], (dict(entry[1]) if len(entry) == 2 else {})
    else:
        raise RobustDrakeError(
            f"plant_setup entries must be 'module:function' or ['module:function', {{params}}], "
            f"got {entry!r}")
    module_name, _, func_name = target.partition(":")
    try:
        func = getattr(importlib.import_module(module_name), func_name)
    except (ImportError, AttributeError) as exc:
        raise RobustDrakeError(f"plant_setup {target!r} not found: {exc}") from None
    return functools.partial(func, **params)


def _plain_data(x):
    """YAML-safe plain data: numpy -> Python, tuples -> lists."""
    if isinstance(x, dict):
        return {str(k): _plain_data(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain_data(v) for v in x]
    if isinstance(x, np.ndarray):
        return _plain_data(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    return x


def _identified(m, what: str):
    """``ClosedLoopConfig.model`` / ``plant_model`` as an IdentifiedModel (None stays None)."""
    if m is None:
        return None
    from robust_drake.identification.model import as_identified_model

    try:
        return as_identified_model(m)
    except RobustDrakeError as exc:
        raise RobustDrakeError(f"{what}: {exc}") from None


def _is_real(x) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, bool)


def _finite_positive(x) -> bool:
    return _is_real(x) and math.isfinite(float(x)) and float(x) > 0


def _finite_vector(x, what: str, positive: bool = False) -> None:
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        raise RobustDrakeError(f"{what} must be a number or a list of numbers (got {x!r})") from None
    if a.ndim > 1 or a.size == 0:
        raise RobustDrakeError(f"{what} must be a number or a flat list of numbers (got {x!r})")
    if not np.all(np.isfinite(a)):
        raise RobustDrakeError(f"{what} must be finite (got {x!r})")
    if positive and np.any(a <= 0):
        raise RobustDrakeError(f"{what} must be positive (got {x!r})")


def _check_config(c: "ClosedLoopConfig") -> None:
    """The checks of :meth:`ClosedLoopConfig.validate` (one place for every field)."""
    if not isinstance(c.robot, (str, os.PathLike)) or not str(c.robot):
        raise RobustDrakeError(f"robot must be a robot name or a URDF path (got {c.robot!r})")
    for name in ("load", "trajectory"):
        v = getattr(c, name)
        if not isinstance(v, str) or not v:
            raise RobustDrakeError(f"{name} must be a name (a non-empty string), got {v!r}")
    for name in ("controller", "observer"):  # a registry name, a LeafSystem or a factory f(ctx)
        if not is_block_spec(getattr(c, name)):
            raise RobustDrakeError(f"{name} must be a registry name, a pydrake LeafSystem or a factory "
                                   f"f(ctx) -> LeafSystem (got {getattr(c, name)!r})")
    for name in ("controller_params", "trajectory_params", "observer_params", "compensation_params"):
        v = getattr(c, name)
        if not isinstance(v, dict) or not all(isinstance(k, str) for k in v):
            raise RobustDrakeError(f"{name} must be a dict of name -> value (got {v!r})")
    if c.rate is not _DEFAULT and not _finite_positive(c.rate):
        raise RobustDrakeError(f"sample rate must be a positive finite number of Hz (got {c.rate!r})")
    if c.duration is not None and not _finite_positive(c.duration):
        raise RobustDrakeError(f"duration must be a positive finite number of seconds or None (got {c.duration!r})")
    if not (_is_real(c.metrics_skip) and math.isfinite(float(c.metrics_skip)) and c.metrics_skip >= 0):
        raise RobustDrakeError(f"metrics_skip must be a finite number of seconds >= 0 (got {c.metrics_skip!r})")
    if c.metrics_dt is not None and not _finite_positive(c.metrics_dt):
        raise RobustDrakeError(
            f"metrics_dt must be a positive finite resampling interval [s] or None (got {c.metrics_dt!r})")
    if not isinstance(c.friction_compensation, (bool, np.bool_)):
        raise RobustDrakeError(f"friction_compensation must be True or False (got {c.friction_compensation!r})")
    for name in ("initial_q", "true_theta"):
        v = getattr(c, name)
        if v is not None:
            _finite_vector(v, name)
    for name in ("torque_limit", "encoder_resolution"):
        v = getattr(c, name)
        if v is not _DEFAULT and v is not None:
            _finite_vector(v, name, positive=True)
    if c.plant_friction is not _DEFAULT and c.plant_friction is not None:
        pf = c.plant_friction
        if not isinstance(pf, dict) or set(pf) != {"coulomb", "viscous"}:
            raise RobustDrakeError(
                f"plant_friction must be None or {{'coulomb': [...], 'viscous': [...]}} (got {pf!r})")
        for k in ("coulomb", "viscous"):
            _finite_vector(pf[k], f"plant_friction[{k!r}]")
    for name in ("model", "plant_model"):
        m = getattr(c, name)
        if not (m is None or isinstance(m, (str, os.PathLike, dict)) or hasattr(m, "closed_loop_hooks")):
            raise RobustDrakeError(f"{name} must be an IdentifiedModel, a report.json / model file path or a "
                                   f"model's JSON dict (got {type(m).__name__})")
    for name in ("effects", "plant_setup", "feedforward", "compensation"):
        if not isinstance(getattr(c, name), (list, tuple)):
            raise RobustDrakeError(f"{name} must be a list (got {getattr(c, name)!r})")
    if c.divergence_error is not None and not _finite_positive(c.divergence_error):
        raise RobustDrakeError(f"divergence_error must be a positive number of rad or None (got {c.divergence_error!r})")


def _make_block(kind: str, name: str, ctx, params: dict):
    """``resolve(kind, name)(ctx, **params)``, with a wrong parameter name or value reported
    as a one-line user error naming the block."""
    return make_block(kind, name, ctx, params)  # names, LeafSystem instances, factories; ports checked


@dataclass
class SimulationResult:
    """Logs of one closed-loop run, sampled at the controller rate, and its metrics.

    ``repr(result)`` is one line (robot, controller, duration, metrics); :meth:`to_pandas` gives
    every logged signal as a DataFrame (units in ``df.attrs["units"]``), :meth:`plot` the
    tracking figure.

    Parameters
    ----------
    t : numpy.ndarray
        Sample times [s] (K,).
    q, v : numpy.ndarray
        True joint angles [rad] and velocities [rad/s] (K, n).
    q_d, qd_d, qdd_d : numpy.ndarray
        Reference position [rad], velocity [rad/s], acceleration [rad/s^2] (K, n).
    q_meas : numpy.ndarray
        Encoder output (quantised angle) [rad] (K, n).
    v_hat : numpy.ndarray or None
        The observer's velocity estimate held at the last tick [rad/s] (K, n).
    u : numpy.ndarray
        Controller output (held) [N m] (K, n).
    tau : numpy.ndarray
        Torque applied to the plant after compensation and saturation [N m] (K, n).
    metrics : dict
        The error criteria of JS eqs. 55, 56, 58, 59 (rad, m).
    torque_stats : dict
        RMS and peak torques [N m].
    sim_seconds, wall_seconds : float
        Simulated and wall-clock time [s].
    diverged : bool
        True when the run stopped as diverged (``divergence_reason`` says why).
    config : dict
        The resolved :class:`ClosedLoopConfig` as a dict.
    link_lengths : tuple or None
        Link lengths [m] of a planar 2-link arm (task-space metrics), else None.
    divergence_reason : str or None
        Why the run diverged, else None.
    """

    t: np.ndarray
    q: np.ndarray  # true joint angles [rad] (K, n)
    v: np.ndarray  # true joint velocities [rad/s]
    q_d: np.ndarray
    qd_d: np.ndarray
    qdd_d: np.ndarray
    q_meas: np.ndarray  # encoder output [rad]
    v_hat: np.ndarray | None  # observer estimate held at the last tick [rad/s]
    u: np.ndarray  # controller output (held) [N m]
    tau: np.ndarray  # torque applied to the plant after compensation and saturation [N m]
    metrics: dict
    torque_stats: dict
    sim_seconds: float
    wall_seconds: float
    diverged: bool
    config: dict
    link_lengths: tuple | None = None
    divergence_reason: str | None = None  # why ``diverged`` (robust_drake.divergence), else None

    def plot(self, title: str | None = None) -> "Figure":
        """The tracking figure of this run (:func:`robust_drake.plotting.tracking_figure`).

        Parameters
        ----------
        title : str, optional
            Figure title; None describes the run.

        Returns
        -------
        matplotlib.figure.Figure
            Joint errors [rad], task-space error [mm] (planar arms) and torques [N m] against
            t [s]; detached from pyplot (``fig.savefig(path)`` or show it in a notebook).
        """
        from robust_drake.plotting import tracking_figure

        return tracking_figure(self, title)

    def __repr__(self) -> str:
        c = self.config or {}
        m = self.metrics or {}
        keys = [k for k in ("error_task", "maxerr_task") if k in m and m[k] == m[k]]
        keys = keys or [k for k in m if k.startswith("maxerr")][:2]
        metrics = ", ".join(f"{k}={m[k]:.3g}" for k in keys)
        flag = f", DIVERGED: {self.divergence_reason}" if self.diverged else ""
        return (f"SimulationResult({c.get('controller', '?')} on {c.get('robot', '?')}, {c.get('trajectory', '?')}, "
                f"{self.sim_seconds:.3g} s at {c.get('rate', float('nan')):g} Hz, {len(self.t)} samples x "
                f"{self.q.shape[1] if np.ndim(self.q) == 2 else '?'} joints; {metrics}{flag})")

    #: the logged signals of :meth:`to_pandas`: attribute -> (column prefix, unit)
    PANDAS_COLUMNS = {"q": ("q", "rad"), "v": ("v", "rad/s"), "q_d": ("q_d", "rad"), "qd_d": ("qd_d", "rad/s"),
                      "qdd_d": ("qdd_d", "rad/s^2"), "q_meas": ("q_meas", "rad"), "v_hat": ("v_hat", "rad/s"),
                      "u": ("u", "N m"), "tau": ("tau", "N m")}

    def to_pandas(self) -> "pd.DataFrame":
        """The logs as a DataFrame indexed by ``t`` [s].

        Columns ``q1..qn`` [rad], ``v1..vn`` [rad/s], ``q_d1..``, ``qd_d1..``, ``qdd_d1..`` (the
        reference) [rad, rad/s, rad/s^2], ``q_meas1..`` (encoder) [rad], ``v_hat1..`` (observer,
        when it logs one) [rad/s], ``u1..`` and ``tau1..`` [N m], the tracking error ``e1..`` =
        q - q_d [rad] and, for a planar 2-link arm, ``e_task`` [m] (the end effector's distance
        from its desired point, JS eq. 58's integrand). Joint numbers from 1, as in the papers.
        ``df.attrs["units"]`` maps every column to its unit; ``df.attrs["config"]`` is the run's
        configuration.

        Returns
        -------
        pandas.DataFrame
            One row per controller tick.
        """
        import pandas as pd

        K, n = len(self.t), self.q.shape[1]
        cols, units = {}, {}
        for attr, (prefix, unit) in self.PANDAS_COLUMNS.items():
            value = getattr(self, attr)
            if value is None:
                continue
            a = np.asarray(value, float).reshape(K, n)
            for j in range(n):
                cols[f"{prefix}{j + 1}"] = a[:, j]
                units[f"{prefix}{j + 1}"] = unit
        e = np.asarray(self.q, float) - np.asarray(self.q_d, float)
        for j in range(n):
            cols[f"e{j + 1}"] = e[:, j]
            units[f"e{j + 1}"] = "rad"
        if self.link_lengths:
            from robust_drake.kinematics import planar_forward_kinematics

            cols["e_task"] = np.linalg.norm(planar_forward_kinematics(self.q, self.link_lengths)
                                            - planar_forward_kinematics(self.q_d, self.link_lengths), axis=1)
            units["e_task"] = "m"
        df = pd.DataFrame(cols, index=pd.Index(np.asarray(self.t, float), name="t"))
        df.attrs["units"] = {"t": "s", **units}
        df.attrs["config"] = dict(self.config or {})
        return df

    def to_dict(self, logs: bool = False) -> dict:
        out = dict(self.metrics)
        out.update(sim_seconds=self.sim_seconds, wall_seconds=self.wall_seconds, diverged=self.diverged,
                   divergence_reason=self.divergence_reason)
        out.update(self.torque_stats)
        if logs:
            for k in ("t", "q", "v", "q_d", "qd_d", "q_meas", "u", "tau"):
                out[k] = getattr(self, k).tolist()
        return out


def _debug_run(c, duration: float, step: float, wall: float) -> None:
    """One DEBUG line (``-v``) per run: what ran, how many ticks, the integrator step, the wall time."""
    from robust_drake.log import logger

    logger.debug("simulated %s on %s: %.4g s (%d ticks at %g Hz, RK2 step %.3g ms) in %.3g s wall",
                 block_label(c.controller), c.robot, duration, round(duration * c.rate), c.rate, 1e3 * step, wall)


def _warn_if_unsampled(block, spec, rate) -> None:
    """Warn when a controller declares no periodic event: its output is then recomputed at every
    integrator step (a continuous controller), not sampled at ``rate`` Hz as the loop says."""
    from pydrake.systems.framework import Diagram

    if isinstance(block, Diagram):
        return
    try:
        sampled = (block.GetUniquePeriodicDiscreteUpdateAttribute() is not None
                   or block.num_discrete_state_groups() > 0 or block.num_abstract_states() > 0)
    except Exception:  # noqa: BLE001 - only a hint
        return
    if not sampled:
        import warnings

        warnings.warn(f"controller {block_label(spec)} declares no periodic update, so it runs continuously (at "
                      f"every integrator step), not sampled at {float(rate):g} Hz with a held output; derive it "
                      "from rd.DiscreteController or declare DeclarePeriodicDiscreteUpdateEvent(1/rate, ...) "
                      "and a state output port", stacklevel=4)


def _arm_for(robot: str, n: int) -> ArmSpec:
    if robot in ROBOTS:
        return get_arm(robot)
    return ArmSpec(name=str(robot), urdf=str(robot), n=n, link_lengths=(), gravity=True, plane=None,
                   loads={"none": str(robot)})


def _vector(x, n, what):
    a = np.asarray(x, dtype=float)
    a = np.full(n, float(a)) if a.ndim == 0 else a
    if a.shape != (n,):
        raise RobustDrakeError(f"{what} must have {n} entries (got {x!r})")
    return a


class ClosedLoop:
    """A built closed-loop Diagram and what is needed to run it repeatedly.

    Built in the order of the signal flow (module docstring): plant (``models.add_arm``),
    reference, optional flexibility, encoder, observer, controller, command chain (fixed friction
    compensation, saturation), plant-side forces (``robust_drake.forces``), loggers.

    The reference source, the encoder and the plant friction are C++ blocks
    (:mod:`robust_drake.systems.sampled_reference`, :mod:`robust_drake.systems.sensors`,
    :mod:`robust_drake.systems.friction`), tested equal to their Python references (the reference at
    the ticks); a subclass may set ``reference_block`` / ``encoder_block`` / ``friction_block`` to
    other classes with the same signature and ports (benchmarks/bench_closed_loop.py runs the Python
    ones).  BUILD_NOTES "Speed of the 2500 Hz loop"."""

    reference_block = SampledReference  # (reference, period, duration): -> x_d, with tabulate(duration)
    encoder_block = CompiledQuantizingEncoder  # (n, theta_m): state -> q
    friction_block = CompiledCoulombViscousFriction  # (n, coulomb, viscous): state -> generalized_force

    def __init__(self, config: ClosedLoopConfig):
        self.config = config.resolved()
        c = self.config
        builder = DiagramBuilder()
        self.builder = builder
        self.plant, self.scene_graph = add_arm(builder, c.robot, c.load)
        n = self.plant.num_velocities()
        if self.plant.num_positions() != n:
            raise RobustDrakeError("only arms with one position per velocity (revolute/prismatic joints) are supported")
        self.n = n
        self.arm = _arm_for(c.robot, n)
        self.period = 1.0 / float(c.rate)
        self.build_context = BuildContext(robot=str(c.robot), arm=self.arm, load=c.load, n=n,
                                          period=self.period, config=c)
        self._model_hooks()
        x_d = self._add_reference()
        self.flexibility = None
        if c.flexibility is not None:  # drive / structural flexibility (None: rigid arm)
            from robust_drake.systems.flexibility import add_flexibility

            self.flexibility = add_flexibility(builder, self.plant, c.flexibility, n)
        q_meas = self._add_encoder()
        obs = self._add_observer(q_meas, x_d)
        u = self._add_controller(x_d, q_meas, obs)
        tau = self._add_command_chain(u, obs)
        self._add_plant_forces(tau)
        # the actuation input stays unconnected: MultibodyPlant reads it as zero (torque enters through
        # applied_generalized_force, see BUILD_NOTES "Simulation scheme"); a zero source cost ~0.5 us per tick
        self._add_logs(x_d, u, tau, obs)
        self.diagram = None

    def _model_hooks(self):
        """What ``config.plant_model`` (the simulated arm) and ``config.model`` (the controller's
        model) add to the loop (:meth:`IdentifiedModel.closed_loop_hooks`): plant effect blocks and
        setups, and the controller's model, feedforward and compensation blocks."""
        c = self.config
        self.model_plant_setup, self.model_effects, self.model_feedforward, self.model_compensation = [], [], [], []
        self.model_params, self.not_compensated = {}, {}
        for m, what in ((c.plant_model, "plant_model"), (c.model, "model")):
            if m is not None:
                _check_model_robot(m, c.robot, c.load, what)
        if c.plant_model is not None:
            hooks = c.plant_model.closed_loop_hooks(plant=True, controller=False)
            self.model_plant_setup, self.model_effects = hooks["plant_setup"], hooks["effects"]
        if c.model is not None and "model" not in c.controller_params:  # else the factory compensates its model
            hooks = c.model.closed_loop_hooks(controller=True)
            own = ("model", "theta0", "P", "ellipsoid", "rho", "regressor")
            if (isinstance(c.controller, str) and c.controller in MODEL_CONTROLLERS
                    and not any(k in c.controller_params for k in own)):
                self.model_params = {"model": c.model}  # the factory takes theta0, the set, ff and blocks
            else:
                self.model_feedforward, self.model_compensation = hooks["feedforward"], hooks["compensation"]
            self.not_compensated = hooks["not_compensated"]

    def _add_reference(self):
        """The reference source; returns its ``x_d`` port."""
        c, builder = self.config, self.builder
        try:
            self.reference = make_reference(self.arm, c.trajectory, **dict(c.trajectory_params))
        except RobustDrakeError as exc:
            if str(exc).startswith("unknown trajectory"):
                raise  # the name itself: the message has the nearest names
            raise RobustDrakeError(f"trajectory {c.trajectory!r} with parameters "
                                   f"{dict(c.trajectory_params)!r}: {exc}") from None
        except (TypeError, ValueError) as exc:
            msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            from robust_drake.registry import param_error

            raise RobustDrakeError(param_error("trajectory", c.trajectory, c.trajectory_params, msg) or
                                   f"trajectory {c.trajectory!r} with parameters {dict(c.trajectory_params)!r}: "
                                   f"{msg}") from None
        check_run_size(c.duration or self.reference.duration, c.rate)
        if self.reference.n != self.n:
            raise RobustDrakeError(f"trajectory {c.trajectory!r} has {self.reference.n} joints, robot has {self.n}")
        horizon = c.duration or self.reference.duration  # re-tabulated by simulate() for another duration
        self.joint_limits = JointLimits.from_plant(self.plant)  # a continuous plant does not enforce them
        check_within_limits(self.reference, self.joint_limits, horizon, self.period, c.trajectory)
        src = builder.AddSystem(self.reference_block(self.reference, self.period, horizon))
        self.reference_source = src
        src.set_name("reference")
        return src.get_output_port(0)

    def _add_encoder(self):
        """The quantising encoder on the plant (or the flexible drive's encoder side)."""
        builder, plant = self.builder, self.plant
        enc = builder.AddSystem(self.encoder_block(self.n, self.config.encoder_resolution))
        enc.set_name("encoder")
        builder.Connect(plant.get_state_output_port() if self.flexibility is None
                        else self.flexibility.encoder_state, enc.get_input_port(0))
        self.encoder = enc
        return enc.get_output_port(0)

    def _add_observer(self, q_meas, x_d):
        c, builder = self.config, self.builder
        obs = builder.AddSystem(_make_block("observer", c.observer, self.build_context, c.observer_params))
        obs.set_name("observer")
        self.observer = obs
        builder.Connect(q_meas, obs.GetInputPort("q"))
        builder.Connect(x_d, obs.GetInputPort("x_d"))
        if obs.HasInputPort("state"):
            builder.Connect(self.plant.get_state_output_port(), obs.GetInputPort("state"))
        return obs

    def _add_controller(self, x_d, q_meas, obs):
        """The controller (with its feedforward terms); returns its ``u`` port."""
        c, builder = self.config, self.builder
        ctrl = builder.AddSystem(_make_block("controller", c.controller, self.build_context,
                                             {**c.controller_params, **self.model_params}))
        ctrl.set_name("controller")
        self.controller = ctrl
        _warn_if_unsampled(ctrl, c.controller, c.rate)
        builder.Connect(x_d, ctrl.GetInputPort("x_d"))
        builder.Connect(q_meas, ctrl.GetInputPort("q"))
        builder.Connect(obs.GetOutputPort("v"), ctrl.GetInputPort("v"))
        builder.Connect(obs.GetOutputPort("v_error"), ctrl.GetInputPort("v_error"))
        for f in list(c.feedforward) + self.model_feedforward:
            if not hasattr(ctrl, "add_feedforward"):
                raise RobustDrakeError(f"controller {block_label(c.controller)!r} does not accept feedforward terms")
            ctrl.add_feedforward(f)
        return ctrl.GetOutputPort("u")

    def _add_command_chain(self, u, obs):
        """u -> [fixed friction compensation, JS eqs. 89-90] -> [saturation]; returns tau."""
        c, builder, n = self.config, self.builder, self.n
        self.compensation = None
        u_cmd = u
        if c.friction_compensation:
            params = dict(c.compensation_params)
            k_hat = describe(c.robot).friction_compensation_k_hat
            if not params and k_hat is not None:
                params = {"k_hat": list(k_hat)}
            if "k_hat" not in params:
                raise RobustDrakeError("friction_compensation needs compensation_params={'k_hat': [...]} for this robot")
            comp = builder.AddSystem(FixedFrictionCompensation(n, **params))
            comp.set_name("friction_compensation")
            builder.Connect(u, comp.GetInputPort("u"))
            v_src = obs.GetOutputPort("v_sampled") if obs.HasOutputPort("v_sampled") else obs.GetOutputPort("v")
            if v_src.size() != n:  # v_sampled = [v, v_error]: keep v
                from pydrake.systems.primitives import MatrixGain
                sel = builder.AddSystem(MatrixGain(np.eye(n, v_src.size())))
                sel.set_name("v_sampled_select")
                builder.Connect(v_src, sel.get_input_port(0))
                v_src = sel.get_output_port(0)
            builder.Connect(v_src, comp.GetInputPort("v"))
            u_cmd = comp.get_output_port(0)
            self.compensation = comp
        u_cmd = self._add_compensation(u_cmd, obs)
        tau = u_cmd
        if c.torque_limit is not None:
            lim = _vector(c.torque_limit, n, "torque_limit")
            if np.any(lim <= 0):
                raise RobustDrakeError("torque_limit must be positive")
            sat = builder.AddSystem(Saturation(-lim, lim))
            sat.set_name("saturation")
            builder.Connect(u_cmd, sat.get_input_port(0))
            tau = sat.get_output_port(0)
        self.tau_port = tau
        if obs.HasInputPort("tau"):
            builder.Connect(tau, obs.GetInputPort("tau"))
        return tau

    def _add_compensation(self, u, obs):
        """u - sum of the compensation blocks' forces (``config.compensation``, the controller
        model's stateful effects), each block fed [q_meas, v_hat]; returns the command port."""
        factories = list(self.config.compensation) + self.model_compensation + list(
            getattr(self.controller, "compensation", None) or [])
        self.compensation_blocks = []
        if not factories:
            return u
        from pydrake.systems.primitives import Adder, MatrixGain

        builder, n = self.builder, self.n
        mux = builder.AddSystem(Multiplexer([n, n]))
        mux.set_name("compensation_state")
        builder.Connect(self.encoder.get_output_port(0), mux.get_input_port(0))
        builder.Connect(obs.GetOutputPort("v"), mux.get_input_port(1))
        total = builder.AddSystem(Adder(len(factories), n))
        total.set_name("compensation_forces")
        for i, f in enumerate(factories):
            block = builder.AddSystem(f(self.build_context))
            block.set_name(f"compensation_{i}_{block.get_name() or type(block).__name__}")
            builder.Connect(mux.get_output_port(0), block.GetInputPort("state"))
            builder.Connect(block.GetOutputPort("generalized_force"), total.get_input_port(i))
            self.compensation_blocks.append(block)
        neg = builder.AddSystem(MatrixGain(-np.eye(n)))
        builder.Connect(total.get_output_port(0), neg.get_input_port(0))
        cmd = builder.AddSystem(Adder(2, n))
        cmd.set_name("compensated_command")
        builder.Connect(u, cmd.get_input_port(0))
        builder.Connect(neg.get_output_port(0), cmd.get_input_port(1))
        return cmd.get_output_port(0)

    def _add_plant_forces(self, tau):
        """tau (through the flexible drive if any) + plant friction + effect blocks, summed into
        the plant by the one force path (:mod:`robust_drake.forces`)."""
        c, builder, plant, n = self.config, self.builder, self.plant, self.n
        forces = [tau] if self.flexibility is None else self.flexibility.forces(builder, tau)
        self.effect_blocks = []
        if c.plant_friction is not None:
            fr = self.friction_block(n, c.plant_friction["coulomb"], c.plant_friction["viscous"])
            fr.set_name("plant_friction")
            self.effect_blocks.append(fr)
        for i, eff in enumerate(list(c.effects) + self.model_effects):
            if callable(eff):
                block = eff(self.build_context)
            else:
                name, params = (eff[0], eff[1]) if len(eff) > 1 else (eff[0], {})
                block = _make_block("plant_effect", name, self.build_context, params)
            block.set_name(f"effect_{i}_{block.get_name() or type(block).__name__}")
            self.effect_blocks.append(block)
        forces += add_force_blocks(builder, plant, self.effect_blocks, tau)
        sum_into_plant(builder, plant, forces)

    def _add_logs(self, x_d, u, tau, obs):
        """One logger at the sample rate on a Multiplexer of the plant state, x_d, u, tau (and the
        observer's ``v_sampled``): one publish per tick instead of one per signal (BUILD_NOTES
        "Speed of the 2500 Hz loop"); :meth:`_log_columns` splits its columns by signal."""
        builder = self.builder
        ports = {"state": self.plant.get_state_output_port(), "x_d": x_d, "u": u, "tau": tau}
        if obs.HasOutputPort("v_sampled"):
            ports["v_hat"] = obs.GetOutputPort("v_sampled")
        sizes = [p.size() for p in ports.values()]
        mux = builder.AddSystem(Multiplexer(sizes))
        mux.set_name("logged_signals")
        for i, p in enumerate(ports.values()):
            builder.Connect(p, mux.get_input_port(i))
        self._log = LogVectorOutput(mux.get_output_port(0), builder, self.period)
        self._log.set_name("logger")
        ends = np.cumsum([0] + sizes)
        self._log_slices = {k: slice(int(a), int(b)) for k, a, b in zip(ports, ends[:-1], ends[1:])}
        self.extra_logs = {}

    def _log_columns(self, context) -> tuple[np.ndarray, dict]:
        """(sample times, {signal: (K, size) array}) of the logger of :meth:`_add_logs`."""
        log = self._log.FindLog(context)
        data = log.data().T
        return log.sample_times(), {k: data[:, sl] for k, sl in self._log_slices.items()}

    def add_log(self, name: str, port) -> None:
        """Log another output port at the sample rate (before the first run)."""
        if self.diagram is not None:
            raise RobustDrakeError("add_log must be called before the first simulate()")
        self.extra_logs[name] = LogVectorOutput(port, self.builder, self.period)

    def _finish(self):
        if self.diagram is None:
            self.diagram = self.builder.Build()
            self.diagram.set_name(f"closed_loop_{self.config.robot}_{block_label(self.config.controller)}")

    def simulate(self, duration: float | None = None, initial_q=None) -> SimulationResult:
        """Run from rest at q_d(0) (or ``initial_q``) for ``duration`` s (default: the reference's)."""
        self._finish()
        c = self.config
        duration = duration if duration is not None else (c.duration or self.reference.duration)
        if not _finite_positive(duration):
            raise RobustDrakeError(f"duration must be a positive finite number of seconds (got {duration!r})")
        duration = float(duration)
        check_run_size(duration, c.rate)
        plant, n = self.plant, self.n
        context = self.diagram.CreateDefaultContext()
        plant_context = plant.GetMyMutableContextFromRoot(context)
        q_d0, qd_d0 = self.reference.initial_state()
        q_init = initial_q if initial_q is not None else c.initial_q
        if q_init is not None:
            _finite_vector(q_init, "initial_q")
        q0 = q_d0 if q_init is None else _vector(q_init, n, "initial_q")
        plant.SetPositions(plant_context, q0)
        plant.SetVelocities(plant_context, np.zeros(n))
        if c.true_theta is not None:
            if describe(c.robot).closed_form_regressor != "d2r2":
                raise RobustDrakeError("true_theta is defined for the D2R2 (JS eq. 14); use plant_setup for other robots")
            set_d2r2_theta(plant, plant_context, np.asarray(c.true_theta, dtype=float))
        for setup in list(self.model_plant_setup) + list(c.plant_setup):  # the identified arm, then the user's
            setup(plant, plant_context)
        if self.flexibility is not None:
            self.flexibility.initialize(context, q0)
        obs_ctx = self.observer.GetMyMutableContextFromRoot(context)
        if hasattr(self.observer, "set_initial"):
            q0_meas = q0 if c.encoder_resolution is None else quantize(q0, c.encoder_resolution)
            self.observer.set_initial(obs_ctx, q0_meas, q_d0, qd_d0)

        check_within_limits(self.reference, self.joint_limits, duration, self.period, c.trajectory)
        self.reference_source.tabulate(duration)
        simulator = Simulator(self.diagram, context)
        max_step = MAX_INTEGRATOR_STEP if self.flexibility is None else min(
            MAX_INTEGRATOR_STEP, self.flexibility.cfg.integrator_step())
        steps = max(1, math.ceil(self.period / max_step - 1e-9))
        ResetIntegratorFromFlags(simulator, "runge_kutta2", self.period / steps)
        wall0 = time.perf_counter()
        integrator_error = None
        try:
            simulator.Initialize()
            _advance_with_progress(simulator, duration, self.period)
        except RuntimeError as exc:  # e.g. the integrator gave up on a blown-up state
            text = str(exc).strip().splitlines()
            integrator_error = text[0] if text else type(exc).__name__
        wall = time.perf_counter() - wall0
        _debug_run(c, duration, self.period / steps, wall)

        t, logs = self._log_columns(context)
        X = logs["state"]
        XD = logs["x_d"]
        q, v = X[:, :n], X[:, n:]
        diverged, reason = is_diverged(t, q, v, XD[:, :n], error_limit=c.divergence_error)
        if integrator_error is not None:
            t_fail = context.get_time()
            reason = (f"simulation failed at t = {t_fail:.4g} s: {integrator_error}"
                      + (f"; {reason}" if reason else ""))
            diverged = True
        link_lengths = self.arm.link_lengths if len(self.arm.link_lengths) == 2 else None
        if diverged or len(t) < 2:
            metrics = {k: float("nan") for j in range(1, max(n, 2) + 1) for k in (f"error{j}", f"maxerr{j}")}
            metrics.update(error_task=float("nan"), maxerr_task=float("nan"))
        else:
            metrics = error_criteria(t, q, XD[:, :n], link_lengths, skip=c.metrics_skip, dt=c.metrics_dt)
        tau = logs["tau"]
        res = SimulationResult(
            t=t, q=q, v=v, q_d=XD[:, :n], qd_d=XD[:, n:2 * n], qdd_d=XD[:, 2 * n:],
            q_meas=q if c.encoder_resolution is None else quantize(q, c.encoder_resolution),
            v_hat=logs["v_hat"][:, :n] if "v_hat" in logs else None,
            u=logs["u"], tau=tau, metrics=metrics,
            torque_stats=torque_statistics(t, tau) if len(t) > 1 else {},
            sim_seconds=float(t[-1]) if len(t) else 0.0, wall_seconds=wall, diverged=diverged,
            config=c.to_dict(), link_lengths=link_lengths, divergence_reason=reason,
        )
        res.extra = {k: v.FindLog(context).data().T for k, v in self.extra_logs.items()}
        res.context = context
        return res


#: registry controllers that take ``model=`` (theta0 and the set from an identified model)
MODEL_CONTROLLERS = ("sp1", "sp2", "calafiore", "calafiore_nominal", "bascetta_a", "bascetta_b")


def _check_model_robot(model, robot, load, what: str) -> None:
    """An identified model fits the loop's arm when its base parameters are the arm's."""
    from robust_drake.regressor import InverseDynamicsRegressor

    names = InverseDynamicsRegressor.from_robot(robot, load).base_names
    if list(names) != list(model.base_names):
        raise RobustDrakeError(f"{what} was identified on {model.robot!r}: its {len(model.base_names)} base parameters "
                               f"are not those of the loop's robot {robot!r} ({len(names)})")


def build_closed_loop(config: ClosedLoopConfig) -> ClosedLoop:
    """Build (but do not run) the closed loop described by ``config``."""
    return ClosedLoop(config)


def simulate(config: ClosedLoopConfig, duration: float | None = None) -> SimulationResult:
    """Build and run one closed loop; see :class:`ClosedLoopConfig`."""
    return ClosedLoop(config).simulate(duration)
