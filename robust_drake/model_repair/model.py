"""The identified model: the one object that passes from identification to control.

A repair (``repair.run_repair``) ends in an :class:`IdentifiedModel`; a controller gets its
feedforward from :meth:`IdentifiedModel.feedforward`, a plant its effect blocks from
:meth:`IdentifiedModel.add_effect_blocks` / :meth:`IdentifiedModel.closed_loop_effects`. Nothing
downstream parses ``report.json`` by key names any more.

Convention (the repair's, ``fitting.py``): the measured joint torque [N m] is

    tau = Y_b(q, qd, qdd) theta_b + fc sgn(qd) + fv qd + sum_k Phi_k(q, qd, qdd, tau) c_k

with ``Y_b`` the base-parameter regressor (``regressor.py``), ``fc``/``fv`` Coulomb [N m] and
viscous [N m s/rad] friction per joint and ``Phi_k c_k`` the chosen effects' columns
(``effects.py``). An effect block's generalized force on the plant is ``-(Phi_k c_k)``.
Joints are indexed from 0 in the URDF's order; ``joint_names`` are the URDF's names.
"""

from __future__ import annotations

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
        from robust_drake.model_repair.effects import EFFECTS, make_effect

        if self.kind not in EFFECTS:
            raise RobustDrakeError(f"unknown effect kind {self.kind!r} in the identified model")
        cls = EFFECTS[self.kind]
        shape = {k: self.parameters[k] for k in cls.default_shape if k in self.parameters and k != "robot"}
        if "robot" in cls.default_shape:
            shape["robot"] = robot
        return make_effect(self.kind, self.joint, **shape)


@dataclass
class IdentifiedModel:
    """Rigid-body base parameters + Coulomb/viscous friction + chosen effects of one arm."""

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
                       effects=[IdentifiedEffect(e["kind"], e["joint"], dict(e["parameters"]),
                                                 list(e["coefficients"])) for e in d.get("effects", [])],
                       estimator=d.get("estimator", "least_squares"), data=dict(d.get("data") or {}))
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

    # ------------------------------------------------------------------ torques
    def effect_terms(self) -> list:
        """``[(Effect, parameters), ...]`` for the diagram helpers in ``effects.py``."""
        return [(e.effect(self.robot), dict(e.parameters)) for e in self.effects]

    def predict_torque(self, q, qd, qdd, regressor=None, iterations: int = 30) -> np.ndarray:
        """Torque [N m] (N, n) the model gives at states (q, qd, qdd) (N, n) (convention above);
        effects whose columns use the torque itself are solved as a fixed point."""
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
            if not f.needs_tau:
                tau = tau + f.evaluate_columns(q, qd, qdd) @ c
        out = tau
        for _ in range(iterations if implicit else 0):
            new = tau + sum(f.evaluate_columns(q, qd, qdd, out) @ c for f, c in implicit)
            done = np.max(np.abs(new - out)) < 1e-10
            out = new
            if done:
                break
        return out

    def feedforward(self):
        """``f(q, v) -> torques`` [N m]: what the motors must add for the identified friction
        ``fc_j sgn(v_j) + fv_j v_j`` and the effects a controller can compute from (q, v) alone.
        Effects that need the torque or the acceleration, or that change the plant itself, are
        left out (listed in ``f.skipped``)."""
        terms, skipped = [], []
        for e in self.effects:
            eff = e.effect(self.robot)
            if eff.needs_tau or eff.needs_qdd or eff.modifies_plant:
                skipped.append(e.kind)
                continue
            terms.append((eff, np.asarray(e.coefficients, float)))
        fc, fv = np.asarray(self.coulomb, float), np.asarray(self.viscous, float)

        def feedforward(q, v):
            tau = fc * np.sign(v) + fv * v
            for eff, coef in terms:
                tau = tau - eff.generalized_force(q, v, None, coef)
            return tau

        feedforward.skipped = skipped
        feedforward.terms = [eff.name for eff, _ in terms]
        return feedforward

    # ------------------------------------------------------------------ plant side
    def add_effect_blocks(self, builder, plant, tau_port, sample_period=None):
        """Sum ``tau_port`` and the force-type effect blocks into the plant's applied
        generalized force (``effects.add_effect_blocks``); returns the added blocks."""
        from robust_drake.model_repair.effects import add_effect_blocks

        return add_effect_blocks(builder, plant, tau_port, self.effect_terms(), sample_period=sample_period)

    def closed_loop_effects(self, sample_period: float = 1e-3) -> list:
        """Block factories ``f(ctx) -> LeafSystem`` for ``ClosedLoopConfig.effects`` (force-type
        effects only; plant-modifying ones go through ``effects.load_plant``)."""
        facts = []
        for eff, params in self.effect_terms():
            if eff.modifies_plant:
                continue
            facts.append(lambda ctx, eff=eff, params=params: eff.block(ctx.n, params, sample_period=sample_period))
        return facts


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
            fail(f"effects[{k}].joint", f"must be null or a joint 0..{n - 1}, got {j!r}")
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
    return names if len(names) == n else [f"j{i}" for i in range(n)]
