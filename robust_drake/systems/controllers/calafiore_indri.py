"""Calafiore & Indri's ellipsoid-based robust controller (CI, seeds/000, section 4).

Nominal law (eq. 6) with the error terms of eq. 7 (a = v' = qdd_d - Lambda e'):

    tau_0 = D(q, qd, v, a) theta0 - K r,     v = qd_d - Lambda e,  r = e' + Lambda e,  e = q - q_d,

robust law (eq. 8) ``tau = tau_0 + D(q, qd, v, a) u`` with u from eq. 15,

    w = (D E)^T r,     u = -E w / ||w||  if ||w|| > epsilon,   u = -E w / epsilon  otherwise,

where E^T E = P describes the confidence ellipsoid E(P, theta0) (eq. 10). With P = rho^2 I
(E = rho I) eq. 15 is Spong's single-bound law (JS eq. 18): u = -rho^2 Y^T r / ||rho Y^T r||.

``D(q, qd, v, a)`` is the Slotine-Li form of the regressor: M(q) a + C(q, qd) v + friction, so that
D(q, qd, qd, qdd) is the identification regressor (for the IMI SCARA, CI section 5). Friction
columns: Coulomb on sgn(qd) (the velocity estimate), viscous on v (the difference
sigma_v (qd - v) = sigma_v r only adds damping for sigma_v > 0).
"""

from __future__ import annotations

import math

import numpy as np

from robust_drake.analysis.tolerance import psd_tol
from robust_drake.errors import RobustDrakeError
from robust_drake.systems.controllers.base import DiscreteController, diag_gain

#: Gains used for the CI section 5.2 study (the paper does not print its K, Lambda).
IMI_K = (20.0, 2.0)
IMI_LAMBDA = (10.0, 10.0)
IMI_L1 = 0.359


def imi_scara_control_regressor(q, qd, v, a, l1: float = IMI_L1) -> list:
    """D(q, qd, v, a) of CI eq. 6 for the IMI SCARA (2 x 8 nested lists, scalar math).

    M(q) a + C(q, qd) v with C = [[-h qd2, -h (qd1 + qd2)], [h qd1, 0]],
    h = l1 (s2 theta2 + c2 theta3) (Christoffel symbols of the section 5 model), plus
    [sgn(qd1), v1] and [sgn(qd2), v2] for the friction of eq. 16.
    """
    c2 = math.cos(q[1])
    s2 = math.sin(q[1])
    a1, a2 = a[0], a[1]
    cv1 = qd[1] * v[0] + (qd[0] + qd[1]) * v[1]          # -(C v)_1 / h
    return [
        [a1, l1 * (c2 * (2 * a1 + a2) - s2 * cv1), l1 * (-s2 * (2 * a1 + a2) - c2 * cv1), a1 + a2,
         math.copysign(1.0, qd[0]) if qd[0] != 0 else 0.0, v[0], 0.0, 0.0],
        [0.0, l1 * (c2 * a1 + s2 * qd[0] * v[0]), l1 * (-s2 * a1 + c2 * qd[0] * v[0]), a1 + a2, 0.0, 0.0,
         math.copysign(1.0, qd[1]) if qd[1] != 0 else 0.0, v[1]],
    ]


# --------------------------------------------------------------------------- pure math
def calafiore_error_terms(q_d, qd_d, qdd_d, q, v_error, Lambda):
    """CI eq. 7: (e, r, v, a) with e' estimated by ``v_error``."""
    e = np.asarray(q, dtype=float) - np.asarray(q_d, dtype=float)
    ed = np.asarray(v_error, dtype=float)
    Lam = np.asarray(Lambda, dtype=float)
    return e, ed + Lam * e, np.asarray(qd_d) - Lam * e, np.asarray(qdd_d) - Lam * ed


def ellipsoid_robust_input(D, E, r, epsilon: float) -> np.ndarray:
    """CI eq. 15: u = -E w / max(||w||, epsilon), w = (D E)^T r."""
    D = np.asarray(D, dtype=float)
    E = np.asarray(E, dtype=float)
    w = (D @ E).T @ np.asarray(r, dtype=float)
    nw = float(np.linalg.norm(w))
    return -(E @ w) / max(nw, epsilon)


def calafiore_torque(D, theta0, E, K, r, epsilon, robust: bool = True) -> np.ndarray:
    """CI eqs. 6 and 8: tau = D theta0 - K r + D u (u = 0 for the nominal law)."""
    D = np.asarray(D, dtype=float)
    tau = D @ np.asarray(theta0, dtype=float) - np.asarray(K) * np.asarray(r)
    if robust:
        tau = tau + D @ ellipsoid_robust_input(D, E, r, epsilon)
    return tau


def sqrtm_psd(P) -> np.ndarray:
    """Symmetric E = P^(1/2) (CI section 5.2), so that E^T E = P."""
    P = np.asarray(P, dtype=float)
    w, V = np.linalg.eigh(0.5 * (P + P.T))
    if not np.all(np.isfinite(w)) or w[0] < -psd_tol(w):  # rounding, relative to ||P|| (analysis.tolerance)
        raise RobustDrakeError(f"P must be positive semidefinite (smallest eigenvalue {w[0]:.3g})")
    return (V * np.sqrt(np.clip(w, 0.0, None))) @ V.T


# --------------------------------------------------------------------------- system
class CalafioreIndriController(DiscreteController):
    """CI eqs. 6-8 with eq. 15, on the controller port convention (x_d, q, v, v_error -> u).

    Args:
        regressor: D(q, qd, v, a) -> n x m (nested lists or array).
        theta0: (m,) central estimate. E: (m, m) with E^T E = P (or pass P). epsilon > 0.
        robust: False gives the nominal law (eq. 6) alone.
    """

    def __init__(self, n, period, regressor, theta0, K, Lambda, E=None, P=None, epsilon=1.0, robust=True):
        super().__init__(n, period, name="CalafioreIndriController" if robust else "CalafioreIndriNominal")
        self.regressor = regressor
        self.theta0 = np.asarray(theta0, dtype=float)
        m = self.theta0.size
        if E is None:
            if P is None:
                raise RobustDrakeError("give the ellipsoid as E (E^T E = P) or P")
            E = sqrtm_psd(P)
        self.E = np.asarray(E, dtype=float)
        if self.E.shape != (m, m):
            raise RobustDrakeError(f"E must be {m}x{m}, got {self.E.shape}")
        if not epsilon > 0:
            raise RobustDrakeError(f"epsilon must be positive (got {epsilon})")
        self.epsilon = float(epsilon)
        self.robust = bool(robust)
        self.K = diag_gain(K, n, "K")
        self.Lambda = diag_gain(Lambda, n, "Lambda")

    def compute(self, t, q_d, qd_d, qdd_d, q, v, v_error):
        _, r, vref, a = calafiore_error_terms(q_d, qd_d, qdd_d, q, v_error, self.Lambda)
        D = np.asarray(self.regressor(q.tolist(), v.tolist(), vref.tolist(), a.tolist()), dtype=float)
        return calafiore_torque(D, self.theta0, self.E, self.K, r, self.epsilon, self.robust)


def _make(ctx, robust, params):
    p = dict(params)
    reg = p.pop("regressor", None)
    if reg is None:
        if ctx.robot != "imi_scara":
            raise RobustDrakeError(
                f"calafiore needs controller_params={{'regressor': D(q, qd, v, a), 'theta0': ..., 'P': ...}} "
                f"for robot {ctx.robot!r} (built in for imi_scara only)")
        reg = imi_scara_control_regressor
    if "theta0" not in p:
        from robust_drake.regressor import IMI_P, IMI_THETA0

        p.setdefault("theta0", IMI_THETA0)
        if "E" not in p:
            p.setdefault("P", IMI_P)
    p.setdefault("K", IMI_K)
    p.setdefault("Lambda", IMI_LAMBDA)
    if not robust:
        p.pop("E", None)
        p.pop("P", None)
        p["E"] = np.zeros((len(p["theta0"]), len(p["theta0"])))
    return CalafioreIndriController(ctx.n, ctx.period, reg, robust=robust, **p)


def make_calafiore(ctx, **params):
    """Registry factory: robust law (eqs. 6-8, 15); defaults: published theta0, P (CI sec. 5.1)."""
    return _make(ctx, True, params)


def make_calafiore_nominal(ctx, **params):
    """Registry factory: nominal law (eq. 6) only."""
    return _make(ctx, False, params)
