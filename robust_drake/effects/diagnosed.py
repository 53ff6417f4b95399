"""Kinds for structure outside the original library (issue 13). They are offered to the selection
only where a residual diagnostic (diagnostics.py) found their structure: their ``candidates``
return nothing unless given ``diagnostics=[rows of diagnostics.diagnose]``. Time-dependent ones
(a periodic disturbance, a friction drift) read the log's clock; the dead zone acts on the command.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
from pydrake.systems.framework import LeafSystem

from robust_drake.effects.base import Effect, V_EPS, _joint_values, _limit_by, check_bounds, smooth_sign
from robust_drake.errors import RobustDrakeError


class TimeEffect(Effect):
    """Base of kinds whose columns depend on time t [s] (the log's clock: time since the run's
    t = 0, which is also the simulator's context time in the block)."""

    needs_time: ClassVar[bool] = True

    def _features_t(self, j, t, q, qd, tau):
        raise NotImplementedError

    def evaluate_columns(self, q, qd=None, qdd=None, tau=None, taud=None, t=None) -> np.ndarray:
        if t is None:
            raise RobustDrakeError(f"{self.kind} columns need the time stamps t")
        q = np.atleast_2d(np.asarray(q, dtype=float))
        N, n = q.shape
        t = np.broadcast_to(np.asarray(t, dtype=float).ravel(), (N,))
        cols = np.zeros((N, n, self.num_coef(n)))
        m = len(self.coef_names)
        for i, j in enumerate(self.joints(n)):
            cols[:, j, i * m:(i + 1) * m] = self._features_t(j, t, q, None if qd is None else np.atleast_2d(qd), tau)
        return cols

    def columns(self, data):
        cols = self.evaluate_columns(data.q, data.qd, None, data.tau, None, t=data.t)
        return cols, self.column_names(np.asarray(data.q).shape[1])

    def generalized_force(self, q, qd, tau, coef, t=0.0):
        """Block output for one state at time t [s]: -(columns @ coef), shape (n,)."""
        cols = self.evaluate_columns(np.atleast_2d(q), np.atleast_2d(qd), None, None, None, t=[t])
        return -(cols[0] @ np.asarray(coef, dtype=float))

    def block(self, n, parameters, **kw):
        return TimeEffectBlock(self, n, self.coef_from_parameters(parameters, n))


class TimeEffectBlock(LeafSystem):
    """Stateless block of a :class:`TimeEffect`: ``generalized_force = -(columns(state, t) @ coef)``
    with t the context time [s]."""

    def __init__(self, effect: TimeEffect, n: int, coef):
        super().__init__()
        self.effect, self.n = effect, n
        self.coef = np.asarray(coef, dtype=float).copy()
        self.set_name(f"effect_{effect.kind}_{'all' if effect.joint is None else effect.joint + 1}")
        self._state = self.DeclareVectorInputPort("state", 2 * n)
        self.DeclareVectorOutputPort("generalized_force", n, self._calc)

    def _calc(self, context, output):
        x = self._state.Eval(context)
        output.SetFromVector(self.effect.generalized_force(x[:self.n], x[self.n:], None, self.coef,
                                                           t=context.get_time()))


class PeriodicDisturbanceEffect(TimeEffect):
    """A torque periodic in *time* acting on joint j: a DISTURBANCE of the environment (a pump, a
    vibrating base, a neighbouring machine), not a property of the arm -- it does not depend on
    the state and is reported as a disturbance (``is_disturbance``).

    The plant receives f_e = A sin(2 pi f t + phi); columns [sin(2 pi f t), cos(2 pi f t)] with
    coefficients (a, b) = -A (cos phi, sin phi) (sign convention of this module: columns @ coef
    = -f_e). The frequency f [Hz] is a fixed shape parameter taken from the residual's spectrum
    (``diagnostics.periodic_peaks``, refined by a 1-D least-squares search), so the rest is linear.
    The phase is referenced to each log's t = 0: it predicts another log only if the disturbance
    keeps its phase relative to the logs' clocks (a synchronous source); otherwise use it on the
    fit data to clean the residual and report it, not to predict.
    Admissible: 2 / T_file <= f <= the analysis band's cut-off (below, it is a drift; above, the
    filter removed it); amplitude >= 0 by construction."""

    kind = "periodic_disturbance"
    coef_names = ("sin", "cos")
    default_shape = {"frequency": 1.0}
    is_disturbance = True
    bounds = {"frequency": (1e-12, math.inf)}

    def admissible(self, parameters, context=None):
        """frequency in the analysis band (2 / T_file, f_c): below it a drift, above it filtered
        out; amplitude <= the largest torque the joint carried."""
        parameters = {**self.shape, **parameters}
        why = check_bounds(parameters, self.bounds) or _limit_by(self, parameters, "amplitude", context,
                                                                 "tau_max", "max |tau|")
        if why or context is None or context.band_hz is None:
            return why
        lo, hi = context.band_hz
        return check_bounds(parameters, {"frequency": (lo, hi)})

    def _features_t(self, j, t, q, qd, tau):
        ph = 2.0 * math.pi * float(self.shape["frequency"]) * t
        return np.column_stack([np.sin(ph), np.cos(ph)])

    def _parameters_one(self, c):
        a, b = float(c[0]), float(c[1])
        return {"sin": a, "cos": b, "amplitude": math.hypot(a, b), "phase": math.atan2(-b, -a)}

    def _coef_one(self, p):
        if "amplitude" in p:
            A, phi = float(p["amplitude"]), float(p.get("phase", 0.0))
            return [-A * math.cos(phi), -A * math.sin(phi)]
        return [float(p["sin"]), float(p["cos"])]

    @classmethod
    def candidates(cls, n_joints, diagnostics=None, **context):
        return [cls(joint=d["joint"], frequency=round(float(d["frequency_hz"]), 5))
                for d in diagnostics or [] if d.get("test") == "periodic"]


class DeadZone(Effect):
    """Driver dead-zone on joint j: commanded torque below the threshold d [N m] in magnitude does
    not reach the joint; the joint receives tau - c clip(tau, -d, d) (c = 1: all of it is lost).

    Columns: clip(tau_j, -d, d) (the torque the motor spends without effect), coefficient
    ``share`` c (dimensionless); d is a fixed shape parameter per candidate, from the dead-band
    diagnostic (``diagnostics.dead_band``, candidates at 0.9, 1 and 1.1 times its estimate).
    Block input ``tau``: generalized_force = -c clip(tau_j, -d, d). Admissible: 0.5 <= c <= 1.5
    (``admissible``). Predicting the commanded torque from the motion needs the inverse
    dead-zone (:meth:`commanded_torque`), not a fixed-point iteration (the map has slope c ~ 1
    inside the band)."""

    kind = "dead_zone"
    own_joint_tau = True  # _features reads tau[:, j]
    coef_names = ("share",)
    needs_tau = True
    default_shape = {"threshold": 0.1}
    limits = {"share": (0.5, 1.5)}
    #: c ~ 1 for a dead-zone (the torque below d is lost); d > 0
    bounds = {"share": limits["share"], "threshold": (1e-12, math.inf)}

    def _features(self, j, q, qd, qdd, tau, taud):
        d = float(self.shape["threshold"])
        return np.clip(tau[:, j], -d, d)[:, None]

    def commanded_torque(self, m, coef):
        """Pure inverse of tau = m + c clip(tau, -d, d) for the joint's needed torque m [N m]:
        tau = m / (1 - c) where |m| <= (1 - c) d, else m + c d sign(m)."""
        m = np.asarray(m, dtype=float)
        c, d = float(np.ravel(coef)[0]), float(self.shape["threshold"])
        inside = np.abs(m) <= (1.0 - c) * d
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(inside, m / max(1.0 - c, 1e-12), m + c * d * np.sign(m))

    @classmethod
    def candidates(cls, n_joints, diagnostics=None, **context):
        return [cls(joint=d["joint"], threshold=round(float(d["threshold"]) * k, 6))
                for d in diagnostics or [] if d.get("test") == "dead_band" for k in (0.9, 1.0, 1.1)]


class FrictionDrift(TimeEffect):
    """Friction that changes slowly over a run (warming up): viscous and Coulomb coefficients
    linear in time, b(t) = b_0 + r_b t, F_c(t) = F_c0 + r_c t, with b_0, F_c0 the baseline's.

    Columns [t qd_j, t tanh(qd_j / v_eps)] with t the run's time [s]; coefficients
    ``viscous_rate`` r_b [N m s/rad per s] and ``coulomb_rate`` r_c [N m/s]. Either sign is
    physical (warming thins the lubricant: r_b < 0; a seal or a brake heating up: r_b > 0);
    admissible when the coefficients stay non-negative over the run given the baseline's
    (``admissible`` with ``baseline`` and ``duration``). Offered where ``diagnostics.friction_drift``
    fired."""

    kind = "friction_drift"
    coef_names = ("viscous_rate", "coulomb_rate")
    default_shape = {"v_eps": V_EPS}

    def admissible(self, parameters, context=None):
        """Viscous and Coulomb levels non-negative at the end of the run: b_0 + r_b T >= 0,
        F_c0 + r_c T >= 0 (b_0, F_c0 the same fit's, T ``context.duration``)."""
        if context is None or context.viscous is None or context.duration is None:
            return ""
        n = len(context.viscous)
        for key, rate in (("viscous", "viscous_rate"), ("coulomb", "coulomb_rate")):
            base = _joint_values(self, getattr(context, key), n)
            end = base + np.atleast_1d(np.asarray(parameters[rate], float)) * context.duration
            if np.any(end < 0):
                return f"{key} coefficient {np.round(end, 4).tolist()} < 0 at the end of the run"
        return ""

    def _features_t(self, j, t, q, qd, tau):
        v = qd[:, j]
        return np.column_stack([t * v, t * smooth_sign(v, self.shape["v_eps"])])

    @classmethod
    def candidates(cls, n_joints, diagnostics=None, **context):
        js = sorted({d["joint"] for d in diagnostics or [] if d.get("test") == "drift"})
        return [cls(joint=j) for j in js]
