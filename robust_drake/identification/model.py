"""The identified model: the one object that passes from identification to control.

A repair (``repair.run_repair``) ends in an :class:`IdentifiedModel`; it goes into a closed loop
through one door, :meth:`IdentifiedModel.closed_loop_hooks` (what ``ClosedLoopConfig(model=...,
plant_model=...)`` uses): the plant side (rigid body, friction, effect blocks and plant changes)
and the controller side (model, feedforward, compensation blocks). Nothing downstream parses
``report.json`` by key names any more.

Convention (the repair's, ``fitting.py``): the measured joint torque [N m] is

    tau = Y_b(q, qd, qdd) theta_b + fc sgn(qd) + fv qd + sum_k Phi_k(q, qd, qdd, tau) c_k

with ``Y_b`` the base-parameter regressor (``regressor.py``), ``fc``/``fv`` Coulomb [N m] and
viscous [N m s/rad] friction per joint and ``Phi_k c_k`` the chosen effects' columns
(``effects.py``). An effect block's generalized force on the plant is ``-(Phi_k c_k)``.
Joints are indexed from 0 in the URDF's order in Python (``effects[k].joint``, arrays) and the
model file; every text numbers them from 1 (README); ``joint_names`` are the URDF's names.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from robust_drake.errors import RobustDrakeError


@dataclass
class IdentifiedEffect:
    """One chosen effect: kind, joint (0-based, None = all joints), its physical parameters and
    its column coefficients (in the repair's sign convention above)."""

    kind: str
    joint: int | None
    parameters: dict
    coefficients: list[float]

    def effect(self, robot=None):
        """The :class:`effects.Effect` instance, shape parameters read back from ``parameters``."""
        from robust_drake.effects import EFFECTS, make_effect

        if self.kind not in EFFECTS:
            raise RobustDrakeError(f"unknown effect kind {self.kind!r} in the identified model")
        cls = EFFECTS[self.kind]
        shape = {k: self.parameters[k] for k in cls.default_shape if k in self.parameters and k != "robot"}
        if "robot" in cls.default_shape:
            shape["robot"] = robot
        return make_effect(self.kind, self.joint, **shape)


@dataclass
class IdentifiedModel:
    """Rigid-body base parameters + Coulomb/viscous friction + chosen effects of one arm: the
    product of identification (``rd.identify``, ``rd.repair(...).model``) that control takes
    (``ClosedLoopConfig(model=..., plant_model=...)``, ``rd.control``).

    Parameters
    ----------
    robot : str
        Robot name or URDF path the base parameters belong to.
    joint_names : list of str
        The URDF's moving joints, in velocity order (joints are numbered from 0).
    base_names : list of str
        Names of the base parameters (``InverseDynamicsRegressor.base_names``).
    base_values : numpy.ndarray
        (p,) identified base parameters [SI: kg m, kg m^2, ...].
    base_covariance : numpy.ndarray or None
        (p, p) covariance of the estimate (its confidence set: :meth:`confidence_set`).
    coulomb : numpy.ndarray
        (n,) Coulomb friction fc_j [N m].
    viscous : numpy.ndarray
        (n,) viscous friction fv_j [N m s/rad].
    effects : list of IdentifiedEffect
        The chosen effects (kind, joint, parameters, coefficients).
    estimator : str
        ``"least_squares"`` or ``"instrumental_variables"``.
    data : dict
        Summary of the fit data (samples, joints, dt, filter, covariance kind, ...).
    consistent : dict or None
        The repair's physically consistent fit of the same model (``identification.consistency``:
        per-link mass [kg], centre of mass [m], inertia about the link origin [kg m^2], reflected
        rotor inertias, friction and effect coefficients); None when not computed. What
        :meth:`to_urdf` exports.
    """

    robot: str
    joint_names: list[str]
    base_names: list[str]
    base_values: np.ndarray
    base_covariance: np.ndarray | None
    coulomb: np.ndarray  # fc_j [N m]
    viscous: np.ndarray  # fv_j [N m s/rad]
    effects: list[IdentifiedEffect] = field(default_factory=list)
    estimator: str = "least_squares"
    data: dict = field(default_factory=dict)  # summary of the fit data (samples, filter, ranges)
    #: the repair's physically consistent fit of the same model (``identification.consistency``):
    #: {"solver", "bodies": {link: {"mass", "com", "inertia_origin"}}, "extras": {"Ia_<joint>": ...},
    #: "base_values", "coulomb", "viscous", "effect_coefficients", "min_pseudo_inertia_eig"};
    #: None when it was not computed (``identification.export`` writes the URDF from it)
    consistent: dict | None = None

    @property
    def n(self) -> int:
        return len(self.coulomb)

    # ------------------------------------------------------------------ JSON
    def to_json(self) -> dict:
        cov = None if self.base_covariance is None else np.asarray(self.base_covariance, float).tolist()
        return {
            "robot": str(self.robot), "joint_names": list(self.joint_names),
            "base": {"names": list(self.base_names), "values": np.asarray(self.base_values, float).tolist(),
                     "covariance": cov},
            "friction": {"coulomb": np.asarray(self.coulomb, float).tolist(),
                         "viscous": np.asarray(self.viscous, float).tolist()},
            "effects": [{"kind": e.kind, "joint": e.joint, "parameters": dict(e.parameters),
                         "coefficients": [float(c) for c in e.coefficients]} for e in self.effects],
            "estimator": self.estimator, "data": dict(self.data),
            **({"consistent": self.consistent} if self.consistent is not None else {}),
            "version": MODEL_VERSION,
        }

    @classmethod
    def from_json(cls, d: dict) -> "IdentifiedModel":
        """The model of :meth:`to_json`'s dict; refuses (RobustDrakeError, one line naming the key)
        missing keys, null or non-numeric values, lengths that disagree with the joint count or the
        base-parameter names, and effects on joints the arm does not have."""
        _check_model_json(d)
        try:
            cov = d["base"].get("covariance")
            return cls(robot=d["robot"], joint_names=list(d["joint_names"]),
                       base_names=list(d["base"]["names"]), base_values=np.asarray(d["base"]["values"], float),
                       base_covariance=None if cov is None else np.asarray(
                           [[np.nan if x is None else x for x in row] for row in cov], float),
                       coulomb=np.asarray(d["friction"]["coulomb"], float),
                       viscous=np.asarray(d["friction"]["viscous"], float),
                       effects=[IdentifiedEffect(e["kind"], e["joint"], upgrade_parameters(e, d.get("version", 1)),
                                                 list(e["coefficients"])) for e in d.get("effects", [])],
                       estimator=d.get("estimator", "least_squares"), data=dict(d.get("data") or {}),
                       consistent=d.get("consistent"))
        except (KeyError, TypeError) as exc:
            raise RobustDrakeError(f"not an identified model (missing {exc})") from None

    @classmethod
    def from_report(cls, report: dict, stage: str = "final") -> "IdentifiedModel":
        """The model a repair report holds: ``report["model"]`` (``stage="final"``) or
        ``report["baseline_model"]`` (``stage="baseline"``)."""
        key = {"final": "model", "baseline": "baseline_model"}.get(stage)
        if key is None:
            raise RobustDrakeError(f"stage must be 'final' or 'baseline', got {stage!r}")
        if key not in report:
            raise RobustDrakeError(f"the repair report has no {key!r} (written by an older version): repair again")
        return cls.from_json(report[key])

    # ------------------------------------------------------------------ files
    @classmethod
    def load(cls, path) -> "IdentifiedModel":
        """The model in ``path``: a repair's ``report.json`` (its final ``model``), a folder holding
        one, or a model file written by :meth:`save`; the format is chosen by :data:`FORMATS`
        (first whose ``matches(path)`` is true), so another file format is one more entry there."""
        import pathlib

        p = pathlib.Path(path)
        if p.is_dir() and (p / "report.json").is_file():
            p = p / "report.json"
        if not p.is_file():
            raise RobustDrakeError(f"no identified model at {path}: give a report.json, its folder or a model file")
        for fmt in FORMATS.values():
            if fmt.matches(p):
                return fmt.load(p)
        raise RobustDrakeError(f"{path}: unknown model file format (known: {', '.join(FORMATS)})")

    def save(self, path, format: str | None = None) -> str:
        """Write the model to ``path`` in ``format`` (default: the first of :data:`FORMATS` whose
        ``matches`` accepts the name; ``.json``: this class's JSON with a format tag). Returns the path."""
        import pathlib

        p = pathlib.Path(path)
        fmt = FORMATS.get(format) if format else next((f for f in FORMATS.values() if f.matches(p, saving=True)), None)
        if fmt is None or fmt.save is None:
            raise RobustDrakeError(f"cannot save an identified model as {format or p.suffix!r} "
                                   f"(formats: {', '.join(k for k, f in FORMATS.items() if f.save)})")
        fmt.save(self, p)
        return str(p)

    # ------------------------------------------------------------------ parameters
    def theta(self) -> np.ndarray:
        """All coefficients in the repair's column order: base parameters, then (fc_j, fv_j) per
        joint, then each effect's coefficients (``identification.fitting.ColumnCache.model``)."""
        fr = np.column_stack([np.asarray(self.coulomb, float), np.asarray(self.viscous, float)]).ravel()
        return np.concatenate([np.asarray(self.base_values, float), fr]
                              + [np.asarray(e.coefficients, float) for e in self.effects])

    def confidence_set(self, alpha: float = 0.01):
        """The 1 - alpha confidence ellipsoid E(P, theta0) of the base parameters (CI eq. 10,
        ``uncertainty.confidence.confidence_ellipsoid``: chi2 / F quantile x the estimator's
        covariance) as an :class:`~robust_drake.uncertainty.ellipsoid.Ellipsoid` (SI units of
        the base parameters, in the order of ``base_names``)."""
        from robust_drake.uncertainty.confidence import confidence_ellipsoid
        from robust_drake.uncertainty.ellipsoid import Ellipsoid

        theta0, P = confidence_ellipsoid(self, alpha)
        return Ellipsoid(theta0, P)

    # ------------------------------------------------------------------ export (identification/export.py)
    def consistent_model(self) -> "IdentifiedModel":
        """This model with the physically consistent fit's values (``identification.export``)."""
        from robust_drake.identification.export import consistent_model

        return consistent_model(self)

    @classmethod
    def from_export(cls, path) -> "IdentifiedModel":
        """The model of a ``to_urdf`` export (the URDF or its ``.identified.yaml`` sidecar):
        robot = the exported URDF, its base parameters, friction and effects from the sidecar
        (``identification.export.read_export``)."""
        from robust_drake.identification.export import read_export

        return cls.from_json(read_export(path))

    def to_urdf(self, path) -> dict:
        """Write the URDF of the physically consistent identified arm and the effects a URDF cannot
        hold in a sidecar YAML (``identification.export.to_urdf``); returns the written paths."""
        from robust_drake.identification.export import to_urdf

        return to_urdf(self, path)

    # ------------------------------------------------------------------ torques
    def effect_terms(self) -> list:
        """``[(Effect, parameters), ...]`` for the diagram helpers in ``effects.py``."""
        return [(e.effect(self.robot), dict(e.parameters)) for e in self.effects]

    def predict(self, log, *, torque: str = "tau_meas", exclude_stuck: bool = False) -> "Prediction":
        """The torque [N m] this model gives for a log, computed exactly as the repair scores it:
        the log is read and filtered with the model's filter (``data["filter"]``: cut-off, order,
        position or logged velocities), the model's columns (rigid body, friction, every effect,
        time-dependent ones on the log's time stamps) pass through the torque's zero-phase
        low-pass (``least_squares.parallel_filter``) and torque-dependent effects are solved as a
        fixed point (``fitting.predict_tau``). ``exclude_stuck`` leaves the rows the fit leaves
        out for stiction (``data.friction_exclusion``) out of ``rms`` (the report's ``rms_fit``
        on the fit files; its ``rms_validate`` keeps every row).

        ``log``: a CSV path or a list of them (canonical or DFKI, ``torque`` chooses the DFKI
        column), an array (N, 1 + 2n) of columns ``t, q1..qn, tau1..taun``, or a pandas
        DataFrame with those columns (:func:`robust_drake.identification.logs.as_log_files`)."""
        from robust_drake.identification.data import friction_exclusion, load
        from robust_drake.identification.logs import as_log_files
        from robust_drake.identification.fitting import ColumnCache, predict_tau
        from robust_drake.identification.least_squares import load_regressor

        flt = dict((self.data or {}).get("filter") or {})
        reg = load_regressor(self.robot)
        if list(reg.base_names) != list(self.base_names):
            raise RobustDrakeError(f"the model's base parameters are not those of {self.robot!r}'s regressor")
        with as_log_files(log, self.n, "predict") as paths:
            given = flt.get("derivatives") == "given"
            data = load(paths, robot=self.robot, n_joints=self.n, torque=torque,
                        cutoff_hz=None if given else flt.get("cutoff_hz", 8.0), order=flt.get("order") or 4,
                        use_given_derivatives=given,
                        velocities="logged" if flt.get("velocities") == "logged velocities" else "positions",
                        joint_names=self.joint_names, quiet=True)
        effects = [e.effect(self.robot) for e in self.effects]
        cache = ColumnCache(data, reg)
        theta = self.theta()
        if len(cache.names(effects)) != len(theta):
            raise RobustDrakeError("the model's coefficients do not match its columns (corrupt model file)")
        tau_hat = predict_tau(cache, effects, theta)
        rows = None
        if exclude_stuck:
            ex = friction_exclusion(data)
            rows = None if ex is None else ~ex
        return Prediction(t=data.t, tau=data.tau, tau_hat=tau_hat, rows=rows, sources=list(data.sources))

    def predict_torque(self, q, qd, qdd, regressor=None, iterations: int = 30, t=None) -> np.ndarray:
        """Torque [N m] (N, n) the model gives at states (q, qd, qdd) (N, n) (convention above),
        unfiltered (for a log as the report scores it use :meth:`predict`); effects whose columns
        use the torque itself are solved as a fixed point; time-dependent effects need ``t`` [s]."""
        from robust_drake.identification.least_squares import load_regressor

        reg = regressor or load_regressor(self.robot)
        if getattr(reg, "base_names", None) is not None and (
                reg.n != self.n or list(reg.base_names) != list(self.base_names)):
            raise RobustDrakeError(
                f"the identified model does not belong to this robot: its {self.n} joints and {len(self.base_names)} "
                f"base parameters ({', '.join(self.base_names[:3])}, ...) against {reg.n} joints and "
                f"{len(reg.base_names)} ({', '.join(list(reg.base_names)[:3])}, ...) of {self.robot!r}: a model of "
                "another robot or URDF?")
        q, qd, qdd = (np.atleast_2d(np.asarray(a, float)) for a in (q, qd, qdd))
        tau = np.asarray(reg.evaluate(q, qd, qdd), float) @ self.base_values
        tau = tau + self.coulomb * np.sign(qd) + self.viscous * qd
        explicit = [(e.effect(self.robot), np.asarray(e.coefficients, float)) for e in self.effects]
        implicit = [(f, c) for f, c in explicit if f.needs_tau]
        for f, c in explicit:
            if getattr(f, "needs_time", False):
                if t is None:
                    raise RobustDrakeError(f"{f.kind} depends on time: give predict_torque(..., t=...) or use predict(log)")
                tau = tau + f.evaluate_columns(q, qd, qdd, t=t) @ c
            elif not f.needs_tau:
                tau = tau + f.evaluate_columns(q, qd, qdd) @ c
        out = tau
        for _ in range(iterations if implicit else 0):
            new = tau + sum(f.evaluate_columns(q, qd, qdd, out) @ c for f, c in implicit)
            done = np.max(np.abs(new - out)) < 1e-10
            out = new
            if done:
                break
        return out

    # ------------------------------------------------------------------ closed loop
    def _feedforward(self):
        """``f(q, v) -> torques`` [N m]: what the motors must add for the identified friction
        ``fc_j sgn(v_j) + fv_j v_j`` and the effects a controller can compute from (q, v) alone.
        Effects that need the torque, the acceleration or the log's clock, that change the plant
        itself or carry a state (fed forward as blocks: :meth:`closed_loop_hooks`) are left out
        (listed in ``f.skipped``, the reasons in ``f.reasons``)."""
        terms, skipped, reasons = [], [], {}
        for e in self.effects:
            eff = e.effect(self.robot)
            why = compensation_role(eff)
            if why != "feedforward":
                skipped.append(e.kind)
                reasons[e.kind] = why
                continue
            terms.append((eff, np.asarray(e.coefficients, float)))
        fc, fv = np.asarray(self.coulomb, float), np.asarray(self.viscous, float)

        def feedforward(q, v):
            tau = fc * np.sign(v) + fv * v
            for eff, coef in terms:
                tau = tau - eff.generalized_force(q, v, None, coef)
            return tau

        feedforward.skipped = skipped
        feedforward.reasons = reasons
        feedforward.terms = [eff.name for eff, _ in terms]
        return feedforward

    def closed_loop_hooks(self, *, plant: bool = False, controller: bool = True, sample_period=None,
                          rigid_body: bool = True) -> dict:
        """Fields of :class:`robust_drake.diagram.ClosedLoopConfig` that put the whole model into a
        closed loop (what ``ClosedLoopConfig(model=..., plant_model=...)`` uses): the one door from
        an identified model to a loop.

        * ``plant=True`` -- the simulated arm IS this model: ``plant_setup`` realises the
          identified base parameters as a rigid body (nearest one in the set when the centre is
          none, :func:`realise_base_parameters`) and applies the plant-modifying effects
          (rotor inertia, payload: ``Effect.apply_to_context``); ``plant_friction`` is the
          identified Coulomb/viscous friction; ``effects`` are every other effect's block
          (force, torque-dependent, time-dependent, the delay line and stateful ones such as
          presliding friction). Effects and setups are :func:`robust_drake.effects.effect_hooks`
          of :meth:`effect_terms`;
        * ``controller=True`` -- the controller's model: ``controller_params["model"]`` (SP1,
          SP2, CI eq. 15 and BR take theta0 and their set from it), ``feedforward`` (one term
          ``f(q, v) -> torques`` [N m]: the friction ``fc_j sgn(v_j) + fv_j v_j`` and the
          stateless (q, v) effects; ``f.terms`` names those effects, ``f.skipped`` the others and
          ``f.reasons`` why), ``compensation`` (stateful effects as their blocks, fed the measured
          q and estimated v, their force cancelled in the command) and ``not_compensated``
          ({kind: reason}).

        The delay line samples at ``sample_period`` (None: the loop's period); ``rigid_body=False``
        leaves the rigid-body setup out (a caller that sets the inertias itself, e.g. a plant drawn
        from the set: its setup first, then these)."""
        from robust_drake.effects import block_factory, effect_hooks

        out: dict = {}
        terms = self.effect_terms()
        if plant:
            hooks = effect_hooks(terms, sample_period)
            out["plant_friction"] = {"coulomb": np.asarray(self.coulomb, float).tolist(),
                                     "viscous": np.asarray(self.viscous, float).tolist()}
            out["plant_setup"] = ([self._rigid_body_setup()] if rigid_body else []) + hooks["plant_setup"]
            out["effects"] = hooks["effects"]
        if controller:
            ff = self._feedforward()
            comp = [block_factory(eff, prm, sample_period) for eff, prm in terms if compensation_role(eff) == "block"]
            out.update(controller_params={"model": self}, feedforward=[ff], compensation=comp,
                       not_compensated={k: r for k, r in ff.reasons.items() if r not in ("block",)})
        return out

    def _rigid_body_setup(self):
        """``setup(plant, context)`` writing the identified rigid body into a plant of ``robot``."""
        from robust_drake.uncertainty.plant_draws import plant_setup
        from robust_drake.regressor import InverseDynamicsRegressor

        reg = InverseDynamicsRegressor.from_robot(self.robot)
        if list(reg.base_names) != list(self.base_names):
            raise RobustDrakeError(f"the model's base parameters are not those of {self.robot!r}'s regressor")
        pi, info = realise_base_parameters(self, reg)
        setup = plant_setup(reg, pi)
        setup.info = info
        return setup


@dataclass
class Prediction:
    """:meth:`IdentifiedModel.predict` of one log: time ``t`` [s] (N,), the log's (filtered)
    torque ``tau`` and the model's ``tau_hat`` [N m] (N, n); ``rows`` (N, n) the equation rows
    scored (None: all)."""

    t: np.ndarray
    tau: np.ndarray
    tau_hat: np.ndarray
    rows: np.ndarray | None = None
    sources: list = field(default_factory=list)

    @property
    def residual(self) -> np.ndarray:
        return self.tau - self.tau_hat

    @property
    def rms(self) -> list[float]:
        """RMS residual [N m] per joint over the scored rows (the report's ``rms_*``)."""
        r2 = self.residual ** 2
        if self.rows is None:
            return np.sqrt(np.mean(r2, axis=0)).tolist()
        k = self.rows.astype(float)
        return np.sqrt(np.sum(r2 * k, axis=0) / np.maximum(k.sum(axis=0), 1.0)).tolist()


def compensation_role(eff) -> str:
    """How a controller compensates effect ``eff`` from (q_meas, v_hat): ``"feedforward"``
    (a function of (q, v)), ``"block"`` (a state of its own: its block, fed q and v), or the
    reason it is not compensated."""
    if eff.modifies_plant or eff.needs_qdd:
        return "changes M(q) (acceleration term): left to the controller's robust term"
    if getattr(eff, "needs_time", False):
        return "depends on the log's clock (a disturbance or a drift of that run): not fed forward"
    if eff.needs_tau:
        return "depends on the torque it would change (an algebraic loop): not fed forward"
    if type(eff).generalized_force is not _base_generalized_force():
        try:
            n = (eff.joint or 0) + 1
            eff.generalized_force(np.zeros(n), np.zeros(n), None, np.zeros(eff.num_coef(n)))
        except RobustDrakeError:
            return "block"
    return "feedforward"


def _base_generalized_force():
    from robust_drake.effects import Effect

    return Effect.generalized_force


def realise_base_parameters(model, reg, margin: float = 1e-4):
    """(pi, info): standard parameters of a rigid-body arm (URDF masses kept) whose base
    parameters are the model's: the closed-form nearest point or the SDP of
    ``uncertainty.plant_draws`` (certified); when the identified centre is no rigid body, the
    nearest physically valid point of its 99 % confidence set (``plant_draws.NearestPhysical``;
    ``info["projected"]`` and its Mahalanobis radius)."""
    from robust_drake.uncertainty.plant_draws import NearestPhysical, PhysicalBySdp, make_physical, standard_for_base

    theta = np.asarray(model.base_values, float)
    pi_nom = reg.standard_parameters()
    try:
        pi = make_physical(reg, standard_for_base(reg, theta, pi_nom))
    except RobustDrakeError:
        pi = None
    if pi is None:
        pi = PhysicalBySdp(reg, pi_nom, margin)(theta)
    if pi is not None:
        return pi, {"projected": False}
    if model.base_covariance is None:
        raise RobustDrakeError("the identified base parameters are no rigid-body arm with the URDF's masses, "
                               "and the model has no covariance to find the nearest one in its set")
    ell = model.confidence_set(0.01)
    pi = NearestPhysical(reg, pi_nom, ell.theta0, ell.P)(theta)
    if pi is None:
        raise RobustDrakeError("no rigid-body arm with the URDF's masses lies in the identified 99 % set")
    th = np.asarray(reg.K, float) @ pi
    return pi, {"projected": True, "radius": float(ell.radius(th))}


def as_identified_model(obj) -> IdentifiedModel:
    """An :class:`IdentifiedModel` from a model, a file or folder path (:meth:`IdentifiedModel.load`),
    a model's JSON dict or a repair report dict."""
    import os

    if isinstance(obj, IdentifiedModel):
        return obj
    if isinstance(obj, (str, os.PathLike)):
        return IdentifiedModel.load(obj)
    if isinstance(obj, dict):
        return IdentifiedModel.from_json(obj) if "base" in obj else IdentifiedModel.from_report(obj)
    if hasattr(obj, "model") and isinstance(getattr(obj, "model"), IdentifiedModel):  # a RepairResult
        return obj.model
    raise RobustDrakeError(f"model must be an IdentifiedModel, a report.json / model file path or a repair result "
                           f"(got {type(obj).__name__})")


def controller_set(model, reg, alpha: float = 0.01) -> tuple[np.ndarray, np.ndarray, dict]:
    """(theta0, P, uncertainty) a robust controller takes from an identified model: theta0 = its
    base parameters, E(P, theta0) its 1 - alpha confidence set (:meth:`IdentifiedModel.confidence_set`),
    checked against the loop's regressor ``reg`` (same base parameters); ``uncertainty`` is the
    JSON-able record (``rho`` = sqrt(lambda_max(P)) bounds ||theta - theta0||_2 over the set,
    ``rho_i`` = sqrt(P_ii) bounds |theta_i - theta0_i|)."""
    if list(reg.base_names) != list(model.base_names):
        raise RobustDrakeError(f"the model was identified on {model.robot!r}: its base parameters are not those of "
                               "the loop's robot")
    ell = model.confidence_set(alpha)
    P = ell.P
    unc = {"kind": "ellipsoid", "source": f"{1 - alpha:g} confidence set of the identified model ({model.estimator})",
           "parameters": list(model.base_names), "theta0": ell.theta0.tolist(), "P": P.tolist(), "alpha": float(alpha),
           "rho": float(np.sqrt(max(np.linalg.eigvalsh(P)[-1], 0.0))),
           "rho_i": np.sqrt(np.clip(np.diag(P), 0.0, None)).tolist(),
           "model": {"robot": str(model.robot), "estimator": model.estimator,
                     "samples": (model.data or {}).get("samples")}}
    return ell.theta0, P, unc


def attach_compensation(ctrl, model) -> None:
    """Give a controller built from ``model`` the model's compensation: its feedforward
    (friction and (q, v) effects, ``ctrl.add_feedforward``) and its stateful effects' blocks
    (``ctrl.compensation``, wired by the closed-loop builder); ``ctrl.not_compensated`` names the
    rest with the reason."""
    hooks = model.closed_loop_hooks(controller=True)
    for f in hooks["feedforward"]:
        ctrl.add_feedforward(f)
    ctrl.compensation = hooks["compensation"]
    ctrl.not_compensated = hooks["not_compensated"]


@dataclass
class ModelFormat:
    """One file format of identified models: ``matches(path, saving=False)``, ``load(path)`` and
    ``save(model, path)`` (None: read only)."""

    matches: object
    load: object
    save: object = None


MODEL_FILE_TAG = "robust_drake.identified_model"
#: version of the model dict (model files, report.json's "model"): 2 numbers the joints of the
#: configuration_dependent terms from 1 (``terms="s1,c1"``, coefficient ``sin(q1)``: the first
#: joint), as every label; version 1 (files before it, reports without a version) from 0, read
#: by :func:`upgrade_parameters`. ``effects[k].joint`` is the 0-based joint index in both.
MODEL_VERSION = 2

_V1_TERM = re.compile(r"^(?:j(\d+):)?(sin|cos)\(q(\d+)\)$|^(?:j(\d+):)?q(\d+)(\^2)?$")


def _v1_key(key: str) -> str:
    m = _V1_TERM.match(key)
    if not m:
        return key
    if m.group(2):
        pre = f"j{int(m.group(1)) + 1}:" if m.group(1) is not None else ""
        return f"{pre}{m.group(2)}(q{int(m.group(3)) + 1})"
    pre = f"j{int(m.group(4)) + 1}:" if m.group(4) is not None else ""
    return f"{pre}q{int(m.group(5)) + 1}{m.group(6) or ''}"


def upgrade_parameters(effect: dict, version) -> dict:
    """An effect's stored parameters in the current numbering (:data:`MODEL_VERSION`): from a
    version-1 dict, a configuration_dependent effect's term tokens (``"s0,c0"``) and coefficient
    names (``sin(q0)``, ``j0:cos(q1)``) renumbered from 1; everything else as stored."""
    params = dict(effect.get("parameters") or {})
    if effect.get("kind") != "configuration_dependent" or not isinstance(version, int) or version >= MODEL_VERSION:
        return params
    out = {}
    for k, v in params.items():
        if k == "terms" and isinstance(v, str):
            v = ",".join(f"{t.strip()[:1]}{int(t.strip()[1:]) + 1}" for t in v.split(",") if t.strip())
        out[_v1_key(k)] = v
    return out


def _json_matches(path, saving: bool = False) -> bool:
    return str(path).lower().endswith(".json")


def _json_load(path) -> IdentifiedModel:
    import json

    try:
        with open(path) as fh:
            doc = json.load(fh)
    except (OSError, ValueError) as exc:
        raise RobustDrakeError(f"cannot read {path}: {exc}") from None
    if not isinstance(doc, dict):
        raise RobustDrakeError(f"{path}: not a repair report or model file (a JSON object is needed)")
    if "base" in doc:
        return IdentifiedModel.from_json(doc)
    if "model" in doc:
        return IdentifiedModel.from_report(doc)
    raise RobustDrakeError(f"{path}: neither a repair report (key 'model') nor a model file (key 'base')")


def _json_save(model: IdentifiedModel, path) -> None:
    import json

    doc = {"format": MODEL_FILE_TAG, **_strict(model.to_json())}  # "version": MODEL_VERSION
    try:
        with open(path, "w") as fh:
            json.dump(doc, fh, indent=2, allow_nan=False)
    except OSError as exc:
        raise RobustDrakeError(f"cannot write {path}: {exc.strerror or exc}") from None


def _strict(obj):
    """Plain JSON values: numpy -> Python, NaN/inf -> None."""
    if isinstance(obj, dict):
        return {str(k): _strict(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, np.ndarray)):
        return [_strict(v) for v in (obj.tolist() if isinstance(obj, np.ndarray) else obj)]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


#: File formats of :meth:`IdentifiedModel.load` / :meth:`IdentifiedModel.save`, tried in order
#: (another format, e.g. URDF + sidecar YAML, is one more entry).
def _urdf_matches(path, saving: bool = False) -> bool:
    name = str(path).lower()
    return name.endswith(".urdf") or name.endswith(".identified.yaml")


def _urdf_load(path) -> IdentifiedModel:
    return IdentifiedModel.from_export(path)


def _urdf_save(model: IdentifiedModel, path) -> None:
    model.to_urdf(path)


FORMATS: dict[str, ModelFormat] = {"json": ModelFormat(_json_matches, _json_load, _json_save),
                                   "urdf": ModelFormat(_urdf_matches, _urdf_load, _urdf_save)}


def _check_model_json(d) -> None:
    """RobustDrakeError (one line naming the key) unless ``d`` is a well-formed model dict."""
    import math

    def fail(key, what):
        raise RobustDrakeError(f"not a valid identified model: {key} {what}")

    def numbers(key, value, length=None, allow_null=False):
        if not isinstance(value, (list, tuple)):
            fail(key, f"must be a list of numbers, got {type(value).__name__}")
        for i, x in enumerate(value):
            if x is None and allow_null:
                continue
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
                fail(key, f"must hold finite numbers; entry {i} is {x!r}")
        if length is not None and len(value) != length:
            fail(key, f"has {len(value)} values for {length} {'joints' if 'friction' in key else 'parameters'}")

    if not isinstance(d, dict):
        fail("", f"must be a dict (report.json's 'model'), got {type(d).__name__}")
    for key in ("robot", "joint_names", "base", "friction"):
        if key not in d:
            fail(key, "is missing")
    if not isinstance(d["robot"], str) or not d["robot"]:
        fail("robot", f"must be a robot name or URDF path, got {d['robot']!r}")
    names = d["joint_names"]
    if not isinstance(names, list) or not names or not all(isinstance(x, str) for x in names):
        fail("joint_names", f"must be a non-empty list of names, got {names!r}")
    n = len(names)
    base, fr = d["base"], d["friction"]
    if not isinstance(base, dict) or not isinstance(fr, dict):
        fail("base/friction", "must be dicts")
    bn = base.get("names")
    if not isinstance(bn, list) or not all(isinstance(x, str) for x in bn):
        fail("base.names", f"must be a list of names, got {bn!r}")
    numbers("base.values", base.get("values"), len(bn))
    cov = base.get("covariance")
    if cov is not None:
        if not isinstance(cov, list) or len(cov) != len(bn):
            fail("base.covariance", f"must be {len(bn)} x {len(bn)} or null")
        for row in cov:
            numbers("base.covariance", row, len(bn), allow_null=True)
    numbers("friction.coulomb", fr.get("coulomb"), n)
    numbers("friction.viscous", fr.get("viscous"), n)
    for k, e in enumerate(d.get("effects") or []):
        if not isinstance(e, dict) or not isinstance(e.get("kind"), str):
            fail(f"effects[{k}]", "must be a dict with a kind")
        j = e.get("joint")
        if j is not None and (isinstance(j, bool) or not isinstance(j, int) or not 0 <= j < n):
            fail(f"effects[{k}].joint", f"must be null or a 0-based joint index 0..{n - 1}, got {j!r}")
        numbers(f"effects[{k}].coefficients", e.get("coefficients"))
        if not isinstance(e.get("parameters", {}), dict):
            fail(f"effects[{k}].parameters", "must be a dict")


def joint_names_of(regressor, n: int) -> list[str]:
    """The URDF's names of the ``n`` moving joints in velocity order (``j0..`` if unknown)."""
    plant = getattr(regressor, "plant", None)
    names = []
    if plant is not None:
        try:
            from pydrake.multibody.tree import JointIndex

            joints = [plant.get_joint(JointIndex(i)) for i in range(plant.num_joints())]
            moving = sorted((j for j in joints if j.num_velocities() > 0), key=lambda j: j.velocity_start())
            names = [j.name() for j in moving]
        except Exception:  # noqa: BLE001 - a regressor without a Drake plant
            names = []
    return names if len(names) == n else [f"joint{i + 1}" for i in range(n)]
