"""Friction kinds beyond the baseline Coulomb + viscous law: Stribeck, smooth (arctan) Coulomb,
direction-dependent Coulomb, load-dependent friction and presliding (Dahl) friction with its
stateful block. Every sign is the smooth sign ``tanh(qd / v_eps)`` of :mod:`.base`.
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.systems.framework import LeafSystem

from robust_drake.effects.base import Effect, V_EPS, _limit_by, smooth_sign
from robust_drake.errors import RobustDrakeError


class Stribeck(Effect):
    """Stribeck friction excess: ``(F_s - F_c) exp(-(qd/v_s)^2) sign(qd)`` (Gaussian shape).

    Coefficient ``stribeck_torque`` = F_s - F_c [N m] (breakaway minus Coulomb level), shape
    ``stribeck_velocity`` v_s [rad/s]."""

    kind = "stribeck"
    coef_names = ("stribeck_torque",)
    #: a breakaway excess lives at low speed, mostly next to reversals, where a short stick and the
    #: filter's spread of the Coulomb step can imitate it (stages.validated_gain_guard)
    velocity_shape = True
    #: F_s >= F_c: the breakaway level is above the Coulomb level (a level *below* it at low
    #: speed is not Stribeck friction)
    bounds = {"stribeck_torque": (0.0, math.inf)}
    default_shape = {"stribeck_velocity": 0.1, "v_eps": V_EPS}
    shape_grid = [{"stribeck_velocity": v} for v in (0.05, 0.1, 0.2, 0.4)]

    def _features(self, j, q, qd, qdd, tau, taud):
        v = qd[:, j]
        vs = self.shape["stribeck_velocity"]
        return (np.exp(-(v / vs) ** 2) * smooth_sign(v, self.shape["v_eps"]))[:, None]


class SmoothCoulomb(Effect):
    """Coulomb friction with a gradual transition: ``F_c tanh(qd/v_0)`` or
    ``F_c (2/pi) atan(qd/v_0)``. Fitted next to the baseline's sharp sign(qd) column, the
    coefficient is the share of the Coulomb level that switches gradually."""

    kind = "smooth_coulomb"
    coef_names = ("coulomb",)
    #: a gradual switch is told from sign(qd) only near zero speed, where short sticks and the
    #: filter's spread of the Coulomb step look the same (stages.validated_gain_guard)
    velocity_shape = True
    #: the gradually switching share of the Coulomb level is a friction level: >= 0
    bounds = {"coulomb": (0.0, math.inf)}
    default_shape = {"transition_velocity": 0.3, "form": "tanh"}
    shape_grid = [{"transition_velocity": v} for v in (0.1, 0.3, 1.0)]

    def _features(self, j, q, qd, qdd, tau, taud):
        v = qd[:, j] / self.shape["transition_velocity"]
        if self.shape["form"] == "atan":
            return (2.0 / math.pi * np.arctan(v))[:, None]
        if self.shape["form"] != "tanh":
            raise RobustDrakeError("smooth_coulomb form must be 'tanh' or 'atan'")
        return np.tanh(v)[:, None]


class AsymmetricCoulomb(Effect):
    """Direction-dependent Coulomb level: ``F_c+ `` for qd > 0, ``F_c-`` for qd < 0.

    With the baseline's symmetric ``F_c sign(qd)`` this adds ``a |sign(qd)|`` where the
    coefficient ``asymmetry`` a = (F_c+ - F_c-)/2 [N m]. Unlike a torque offset it vanishes at
    rest, so only data with slow phases / reversals separate the two."""

    kind = "asymmetric_coulomb"
    coef_names = ("asymmetry",)
    default_shape = {"v_eps": 0.02}
    shape_grid = [{"v_eps": 0.02}]

    def _features(self, j, q, qd, qdd, tau, taud):
        return np.abs(smooth_sign(qd[:, j], self.shape["v_eps"]))[:, None]

    def admissible(self, parameters, context=None):
        """Both directional levels F_c +- a non-negative: |a| <= F_c (the same fit's)."""
        return _limit_by(self, parameters, "asymmetry", context, "coulomb", "the Coulomb level")


class LoadDependentFriction(Effect):
    """Friction growing with the transmitted load (gear friction): ``mu |tau| sign(qd)``.
    Coefficient ``load_coefficient`` mu (dimensionless). Block input ``tau`` = commanded torque."""

    kind = "load_dependent_friction"
    own_joint_tau = True  # _features reads tau[:, j]
    coef_names = ("load_coefficient",)
    #: friction grows with the transmitted load (mu >= 0); mu > 1 would make the gear lose more
    #: than it transmits
    bounds = {"load_coefficient": (0.0, 1.0)}
    needs_tau = True
    default_shape = {"v_eps": V_EPS}
    shape_grid = [{}]

    def _features(self, j, q, qd, qdd, tau, taud):
        return (np.abs(tau[:, j]) * smooth_sign(qd[:, j], self.shape["v_eps"]))[:, None]


class PreslidingFriction(Effect):
    """Presliding (Dahl) friction: a friction component that builds up over a small displacement
    after every velocity reversal instead of switching at once.

    Dahl's model in the displacement domain (Dahl 1968; the rate-independent limit of LuGre,
    Canudas de Wit et al. 1995 eq. 1 with sigma_1 = 0): with ``x0`` =
    ``presliding_displacement`` [rad] (the displacement over which the friction state settles)
    ::

        dz/dt = (qd - |qd| z) / x0 ,      z in [-1, 1],      torque = F_d z

    so z -> sign(qd) after a motion of a few x0 in one direction and lags behind sign(qd) for
    ~x0 after a reversal (a hysteresis loop in the friction-vs-position plane; a rate-independent
    friction lag, not a time delay). Coefficient ``presliding_torque`` F_d [N m]: fitted next to
    the baseline's sharp ``F_c sign(qd)``, F_d > 0 means part of the Coulomb level is reached
    only gradually after a reversal (presliding compliance of gear teeth / bearings, backlash
    being taken up). Dahl's model has F_d >= 0; the selection rejects a negative fit (a
    breakaway that decays after a reversal is the ``stribeck`` kind), see
    :attr:`bounds`.

    Columns: z integrated along each file's filtered positions (exact solution for a piecewise
    monotone sample path: z_{k+1} = s + (z_k - s) exp(-|dq|/x0), s = sign(dq)), starting at
    z = 0. ``x0`` is a fixed shape parameter per candidate, so the columns are linear in F_d.
    Block: :class:`PreslidingFrictionBlock` (continuous state z per joint, output -F_d z).
    """

    kind = "presliding_friction"
    coef_names = ("presliding_torque",)
    #: Dahl's model has F_d >= 0 (a level higher just after a reversal that decays is a
    #: breakaway: the ``stribeck`` kind); x0 > 0
    bounds = {"presliding_torque": (0.0, math.inf), "presliding_displacement": (1e-12, math.inf)}
    default_shape = {"presliding_displacement": 0.01}
    shape_grid = [{"presliding_displacement": x} for x in (0.003, 0.01, 0.03)]

    def _features(self, j, q, qd, qdd, tau, taud):
        return presliding_state(q[:, j], self.shape["presliding_displacement"])[:, None]

    def columns(self, data):
        q = np.asarray(data.q, dtype=float)
        N, n = q.shape
        seg = getattr(data, "segment", None)
        seg = np.zeros(N, dtype=int) if seg is None else np.asarray(seg)
        cols = np.zeros((N, n, self.num_coef(n)))
        for s in np.unique(seg):
            m = seg == s
            cols[m] = self.evaluate_columns(q[m])
        return cols, self.column_names(n)

    def generalized_force(self, q, qd, tau, coef):
        raise RobustDrakeError("presliding_friction has internal state: use its block "
                               "(PreslidingFrictionBlock) or columns on a trajectory")

    def block(self, n, parameters, **kw):
        return PreslidingFrictionBlock(self, n, self.coef_from_parameters(parameters, n))


def presliding_state(q, x0, z0=0.0):
    """Dahl state z along a sampled position path q (N,), exact per monotone step (pure)."""
    q = np.asarray(q, dtype=float)
    z = np.empty(len(q))
    zk = float(z0)
    if len(q):
        z[0] = zk
    dq = np.diff(q)
    s = np.sign(dq)
    a = np.exp(-np.abs(dq) / float(x0))
    for k in range(len(dq)):
        zk = s[k] + (zk - s[k]) * a[k]
        z[k + 1] = zk
    return z


class PreslidingFrictionBlock(LeafSystem):
    """Continuous-state Dahl friction (see :class:`PreslidingFriction`): state z (n; joints the
    effect does not act on stay at 0), input ``state`` (2n), output ``generalized_force`` =
    -F_d z (depends on the block's own state only: no direct feedthrough)."""

    def __init__(self, effect: "PreslidingFriction", n: int, coef):
        super().__init__()
        self.effect, self.n = effect, n
        self.x0 = float(effect.shape["presliding_displacement"])
        self.Fd = np.zeros(n)
        js = effect.joints(n)
        self.Fd[js] = np.asarray(coef, dtype=float).reshape(-1)  # one F_d per acting joint
        self.active = np.zeros(n)
        self.active[js] = 1.0
        self.set_name(f"effect_presliding_friction_{'all' if effect.joint is None else effect.joint + 1}")
        self._state = self.DeclareVectorInputPort("state", 2 * n)
        self.DeclareContinuousState(n)
        self.DeclareVectorOutputPort("generalized_force", n, self._calc,
                                     prerequisites_of_calc={self.xc_ticket()})

    def DoCalcTimeDerivatives(self, context, derivatives):
        z = context.get_continuous_state_vector().CopyToVector()
        qd = self._state.Eval(context)[self.n:]
        derivatives.get_mutable_vector().SetFromVector(self.active * (qd - np.abs(qd) * z) / self.x0)

    def _calc(self, context, output):
        z = context.get_continuous_state_vector().CopyToVector()
        output.SetFromVector(-self.Fd * z)
