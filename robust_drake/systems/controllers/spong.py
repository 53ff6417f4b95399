"""Spong's robust passivity-based controllers SP1 and SP2, and the PD baseline.

Jaritz & Spong (JS) section 3.1, after Spong (1992):

- error terms (eq. 11): q~ = q - q_d, r = q~' + Lambda q~, v = qd_d - Lambda q~, a = v';
- nominal law (eqs. 9-10): tau_0 = Y(q, q', v, a) theta_0 - K r;
- robust law (eq. 12): tau = Y (theta_0 + u) - K r with
  SP1 (eq. 18): u = -rho Y^T r / ||Y^T r|| outside the boundary layer ||Y^T r|| > epsilon,
  -(rho / epsilon) Y^T r inside; SP2 (eq. SP2): the same per component, rho_i, epsilon_i.

The PD baseline is the same law without model terms, tau = -K r = -K q~' - K Lambda q~,
with the same K and Lambda (what SP1/SP2 must beat).

D2R2 numbers (appendix 12.1): theta_0 = table 11, rho = 0.1062 (SP1; the Euclidean norm of
theta_0 - theta_unloaded; eq. 17 prints the sum without squares), rho_i = table 10 (SP2),
K = diag(30, 10), Lambda = diag(50, 20) (section 8), epsilon from table 1 (SP1: 1, SP2: 0.5).
"""

from __future__ import annotations

import math

import numpy as np

from robust_drake.errors import RobustDrakeError
from robust_drake.systems.controllers.base import DiscreteController, diag_gain

# JS appendix 12.1 / table 10 / table 1 / section 8
D2R2_RHO_SP1 = 0.1062
D2R2_RHO_SP2 = (0.053, 0.075, 0.053)
D2R2_K = (30.0, 10.0)
D2R2_LAMBDA = (50.0, 20.0)
EPSILON_SP1 = 1.0
EPSILON_SP2 = 0.5


# --------------------------------------------------------------------------- pure math
def spong_error_terms(q_d, qd_d, qdd_d, q, v_error, Lambda):
    """JS eq. 11: returns (q_tilde, r, v, a) with a = qdd_d - Lambda q~'.

    ``v_error`` is the (estimated) velocity error q~' = q' - qd_d.
    """
    q_tilde = np.asarray(q) - np.asarray(q_d)
    qt_dot = np.asarray(v_error)
    r = qt_dot + Lambda * q_tilde
    v = np.asarray(qd_d) - Lambda * q_tilde
    a = np.asarray(qdd_d) - Lambda * qt_dot
    return q_tilde, r, v, a


def sp1_robust_input(xi, rho: float, epsilon: float) -> list:
    """JS eq. 18: u = -rho xi/||xi|| if ||xi|| > epsilon else -(rho/epsilon) xi, xi = Y^T r.

    Scalar Python math on purpose: it runs at every 2500 Hz tick on 3-vectors.
    """
    norm = math.sqrt(sum(x * x for x in xi))
    g = rho / norm if norm > epsilon else rho / epsilon
    return [-g * x for x in xi]


def sp2_robust_input(xi, rho, epsilon) -> list:
    """JS eq. (SP2): componentwise u_i = -rho_i sgn(xi_i) outside |xi_i| <= epsilon_i, linear inside."""
    out = []
    for x, r, e in zip(xi, rho, epsilon):
        out.append(-r * math.copysign(1.0, x) if abs(x) > e else -(r / e) * x)
    return out


def spong_torque(Y, theta0, u, K, r) -> np.ndarray:
    """JS eq. 12: tau = Y (theta_0 + u) - K r (u = 0 gives the nominal law, eq. 10)."""
    return Y @ (np.asarray(theta0) + u) - K * r


# --------------------------------------------------------------------------- systems
class PDController(DiscreteController):
    """PD baseline with Spong's gains: tau = -K (q~' + Lambda q~)."""

    def __init__(self, n, period, K, Lambda):
        super().__init__(n, period, name="PDController")
        self.K = diag_gain(K, n, "K")
        self.Lambda = diag_gain(Lambda, n, "Lambda")
        self._K, self._Lam = self.K.tolist(), self.Lambda.tolist()

    def compute(self, t, q_d, qd_d, qdd_d, q, v, v_error):
        K, Lam = self._K, self._Lam
        return [-K[j] * (v_error[j] + Lam[j] * (q[j] - q_d[j])) for j in range(self.n)]


class _SpongController(DiscreteController):
    def __init__(self, n, period, regressor, theta0, K, Lambda, name):
        super().__init__(n, period, name=name)
        self.regressor = regressor
        self.theta0 = np.asarray(theta0, dtype=float)
        self.K = diag_gain(K, n, "K")
        self.Lambda = diag_gain(Lambda, n, "Lambda")
        self._Lam, self._K, self._theta0 = self.Lambda.tolist(), self.K.tolist(), self.theta0.tolist()

    def robust_input(self, xi):  # pragma: no cover - abstract
        raise NotImplementedError

    def compute(self, t, q_d, qd_d, qdd_d, q, v, v_error):
        # eqs. 11 and 12 in scalar Python (same math as spong_error_terms / spong_torque)
        n, Lam, K, th = self.n, self._Lam, self._K, self._theta0
        q, v, q_d, qd_d, qdd_d, v_error = q.tolist(), v.tolist(), q_d.tolist(), qd_d.tolist(), qdd_d.tolist(), v_error.tolist()
        r, vref, a = [0.0] * n, [0.0] * n, [0.0] * n
        for j in range(n):
            qt = q[j] - q_d[j]
            qtd = v_error[j]
            r[j] = qtd + Lam[j] * qt
            vref[j] = qd_d[j] - Lam[j] * qt
            a[j] = qdd_d[j] - Lam[j] * qtd
        Y = self.regressor(q, v, vref, a)
        p = len(th)
        xi = [sum(Y[i][k] * r[i] for i in range(n)) for k in range(p)]
        u = self.robust_input(xi)
        return [sum(Y[i][k] * (th[k] + u[k]) for k in range(p)) - K[i] * r[i] for i in range(n)]


class SpongSP1Controller(_SpongController):
    """SP1 (JS eqs. 9-12, 18): a single uncertainty bound rho and boundary layer epsilon."""

    def __init__(self, n, period, regressor, theta0, rho, epsilon, K, Lambda):
        super().__init__(n, period, regressor, theta0, K, Lambda, "SpongSP1Controller")
        if rho < 0 or epsilon <= 0:
            raise RobustDrakeError(f"SP1 needs rho >= 0 and epsilon > 0 (got {rho}, {epsilon})")
        self.rho = float(rho)
        self.epsilon = float(epsilon)

    def robust_input(self, xi):
        return sp1_robust_input(xi, self.rho, self.epsilon)


class SpongSP2Controller(_SpongController):
    """SP2 (JS eqs. 9-12, SP2): per-parameter bounds rho_i and boundary layers epsilon_i."""

    def __init__(self, n, period, regressor, theta0, rho, epsilon, K, Lambda):
        super().__init__(n, period, regressor, theta0, K, Lambda, "SpongSP2Controller")
        p = self.theta0.shape[0]
        self.rho = np.broadcast_to(np.asarray(rho, dtype=float), (p,)).tolist()
        self.epsilon = np.broadcast_to(np.asarray(epsilon, dtype=float), (p,)).tolist()
        if min(self.rho) < 0 or min(self.epsilon) <= 0:
            raise RobustDrakeError("SP2 needs rho_i >= 0 and epsilon_i > 0")

    def robust_input(self, xi):
        return sp2_robust_input(xi, self.rho, self.epsilon)


# --------------------------------------------------------------------------- factories
def d2r2_regressor_single(q, qd, v, a) -> list:
    """JS eq. 15 for one sample in scalar math, as nested lists (the per-tick path; the
    vectorised implementation is :func:`robust_drake.regressor.d2r2_regressor`)."""
    c2 = math.cos(q[1])
    s2 = math.sin(q[1])
    a1, a2 = a[0], a[1]
    y13 = c2 * (2.0 * a1 + a2) - s2 * (qd[0] * v[1] + qd[1] * (v[0] + v[1]))
    y23 = c2 * a1 + s2 * qd[0] * v[0]
    return [[a1, a1 + a2, y13], [0.0, a1 + a2, y23]]


def _slotine_li_regressor(ctx, params):
    """The regressor Y(q, qd, v, a) for the robot in ``ctx`` (only the D2R2's eq. 15 is built in)."""
    if "regressor" in params:
        return params.pop("regressor")
    if ctx.robot.startswith("d2r2"):
        return d2r2_regressor_single
    raise RobustDrakeError(
        f"SP1/SP2 need a Slotine-Li regressor Y(q, qd, v, a); one is built in for d2r2 only. "
        f"Pass controller_params={{'regressor': f, 'theta0': ..., 'rho': ...}} for {ctx.robot!r}."
    )


def _defaults(params, **d):
    out = dict(d)
    out.update(params)
    return out


def make_pd(ctx, K=D2R2_K, Lambda=D2R2_LAMBDA):
    return PDController(ctx.n, ctx.period, K, Lambda)


def make_sp1(ctx, **params):
    from robust_drake.models import D2R2_THETA0

    reg = _slotine_li_regressor(ctx, params)
    p = _defaults(params, theta0=D2R2_THETA0, rho=D2R2_RHO_SP1, epsilon=EPSILON_SP1, K=D2R2_K, Lambda=D2R2_LAMBDA)
    return SpongSP1Controller(ctx.n, ctx.period, reg, **p)


def make_sp2(ctx, **params):
    from robust_drake.models import D2R2_THETA0

    reg = _slotine_li_regressor(ctx, params)
    p = _defaults(params, theta0=D2R2_THETA0, rho=D2R2_RHO_SP2, epsilon=EPSILON_SP2, K=D2R2_K, Lambda=D2R2_LAMBDA)
    return SpongSP2Controller(ctx.n, ctx.period, reg, **p)
