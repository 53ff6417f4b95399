"""Robust tracking controller ZC of Zenieh & Corless, as used by Jaritz & Spong (section 3.2).

The law does not use the linear parametrisation, only the bounds (JS eqs. 21-23)

    lambda_min M(q) >= beta0,   lambda_max M(q) <= beta1,   ||C(q, q')|| <= beta2 ||q'||,

and is (JS eq. 25, with r, v, q~ as in eq. 11 and a = v')

    tau = -K r - rho^2 r / (||rho r|| + epsilon),   rho = beta1 ||v'|| + beta2 ||v|| ||q'||.

The paper's D2R2 values (appendix 12.2): beta0 = 0.0276 (not used by the law), beta1 = 1.3254,
beta2 = 0.2571; K = diag(30, 10), Lambda = diag(50, 20); epsilon = 25 on the CPT (table 1), 45 on
the circle (section 10). :func:`zc_bounds` recomputes the betas from the parameter intervals
(eqs. 21-23, 28) so a test can check the published numbers.
"""

from __future__ import annotations

import math

import numpy as np

from robust_drake.errors import RobustDrakeError
from robust_drake.systems.controllers.base import DiscreteController, diag_gain

BETA0 = 0.0276
BETA1 = 1.3254
BETA2 = 0.2571
K_DEFAULT = (30.0, 10.0)
LAMBDA_DEFAULT = (50.0, 20.0)
EPSILON_CPT = 25.0
EPSILON_CIRCLE = 45.0


def zc_torque(q_d, qd_d, qdd_d, q, v, v_error, K=K_DEFAULT, Lambda=LAMBDA_DEFAULT,
              beta1=BETA1, beta2=BETA2, epsilon=EPSILON_CPT):
    """JS eq. 25 for any number of joints (diagonal K and Lambda given as sequences).

    ``v`` is the (estimated) joint velocity q', ``v_error`` the estimate of d/dt (q - q_d).
    Returns the list of joint torques.
    """
    n = len(q)
    r = [0.0] * n
    vref = [0.0] * n
    a = [0.0] * n
    for i in range(n):
        qt = q[i] - q_d[i]
        r[i] = v_error[i] + Lambda[i] * qt  # eq. 11
        vref[i] = qd_d[i] - Lambda[i] * qt
        a[i] = qdd_d[i] - Lambda[i] * v_error[i]  # v' = q''_d - Lambda q~'
    na = math.sqrt(sum(x * x for x in a))
    nv = math.sqrt(sum(x * x for x in vref))
    nq = math.sqrt(sum(x * x for x in v))
    nr = math.sqrt(sum(x * x for x in r))
    rho = beta1 * na + beta2 * nv * nq
    gain = rho * rho / (rho * nr + epsilon)
    return [-K[i] * r[i] - gain * r[i] for i in range(n)]


def zc_bounds(theta_unloaded, theta_loaded, n_grid: int = 721):
    """beta0, beta1, beta2 of JS eqs. 21-23 and 28 for the D2R2 over the parameter box.

    ``M(q)`` is linear in theta = (th1, th2, th3) (eq. 14): ``d11 = th1 + th2 + 2 th3 c2``,
    ``d12 = th2 + th3 c2``, ``d22 = th2``. As in appendix 12.2 the bounds are taken over the
    unloaded and the maximum-loaded arm (and so over every arm on the segment between them:
    lambda_min is concave and lambda_max convex in M); q2 is gridded. (Over the whole box of
    parameter intervals beta0 would drop to 0.004: a corner with th2 at its minimum and th3 at
    its maximum is not a physical arm.) For eq. 28, ``C v`` has
    ``y_i = q'^T L_i v`` with ``L_1 = h [[0, 1], [1, 1]]``, ``L_2 = h [[-1, 0], [0, 0]]`` and
    ``|h| <= th3``, so ``beta2 = max th3 * sqrt(phi^2 + 1)`` (phi = golden ratio, the spectral
    norm of [[0, 1], [1, 1]]).
    """
    lo = np.asarray(theta_unloaded, float)
    hi = np.asarray(theta_loaded, float)
    if lo.shape != (3,) or hi.shape != (3,):
        raise RobustDrakeError("zc_bounds needs the 3 D2R2 parameters of JS eq. 14 for each arm")
    c2 = np.cos(np.linspace(0.0, 2 * np.pi, n_grid))
    lmin, lmax = np.inf, -np.inf
    for vert in (lo, hi):
        t1, t2, t3 = vert
        d11 = t1 + t2 + 2 * t3 * c2
        d12 = t2 + t3 * c2
        d22 = np.full_like(c2, t2)
        tr = d11 + d22
        disc = np.sqrt(((d11 - d22) / 2) ** 2 + d12 ** 2)
        lmin = min(lmin, float(np.min(tr / 2 - disc)))
        lmax = max(lmax, float(np.max(tr / 2 + disc)))
    phi = (1 + math.sqrt(5)) / 2
    h_max = float(max(abs(lo[2]), abs(hi[2])))
    beta2 = h_max * math.sqrt(phi ** 2 + 1.0)
    return lmin, lmax, beta2


def zc_guarantee(K=K_DEFAULT, Lambda=LAMBDA_DEFAULT, beta0=BETA0, beta1=BETA1, epsilon=EPSILON_CPT):
    """What the ZC design guarantees (JS eqs. 24, 26, 27): the largest convergence rate
    ``alpha_max = min(lambda_min Lambda, lambda_min K / beta1)`` and, at that rate, the smallest
    tolerance ``s = sqrt(epsilon beta1 / (lambda_min K beta0)) / alpha`` that eq. 27 allows.

    For the paper's numbers (epsilon = 25): alpha_max = 7.5 1/s and s = 1.45, a very loose
    guarantee, which is the conservatism the paper blames for ZC's larger errors (section 9).
    """
    kmin = min(K)
    alpha = min(min(Lambda), kmin / beta1)
    s = math.sqrt(epsilon * beta1 / (kmin * beta0)) / alpha
    return {"alpha_max": alpha, "s": s}


class ZeniehCorlessController(DiscreteController):
    """ZC (JS eq. 25) as a discrete controller at the sample rate (held torque)."""

    def __init__(self, n, period, K=K_DEFAULT, Lambda=LAMBDA_DEFAULT, beta1=BETA1,
                 beta2=BETA2, epsilon=EPSILON_CPT):
        super().__init__(n, period, name="ZeniehCorlessController")
        self.K = tuple(float(k) for k in diag_gain(K, n, "K"))
        self.Lambda = tuple(float(x) for x in diag_gain(Lambda, n, "Lambda"))
        if epsilon <= 0 or beta1 <= 0 or beta2 < 0:
            raise RobustDrakeError(
                f"ZC needs epsilon > 0, beta1 > 0, beta2 >= 0 (JS eqs. 22-27); got "
                f"epsilon={epsilon}, beta1={beta1}, beta2={beta2}")
        self.beta1 = float(beta1)
        self.beta2 = float(beta2)
        self.epsilon = float(epsilon)

    def compute(self, t, q_d, qd_d, qdd_d, q, v, v_error):
        return zc_torque(q_d, qd_d, qdd_d, q, v, v_error, self.K, self.Lambda,
                         self.beta1, self.beta2, self.epsilon)


def make_zc(ctx, **params):
    """Registry factory ``zc``: JS appendix 12.2 bounds, table 1 epsilon = 25 by default
    (pass ``epsilon=45`` for the circle, section 10)."""
    return ZeniehCorlessController(ctx.n, ctx.period, **params)
