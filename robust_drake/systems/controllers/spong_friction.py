"""SP1 / SP2 with the Coulomb friction inside the robust law (Jaritz & Spong section 7.2).

The D2R2 parameter vector is extended with the Coulomb levels (JS eq. 91)

    theta = (m1 lc1^2 + m2 l1^2 + I1,  m2 lc2^2 + I2,  m2 l1 lc2,  k1,  k2)

and the regressor of eq. 15 with the columns ``diag(sgn q')`` (eq. 92):

    Y = [[a1, a1 + a2, y13, sgn q'1, 0], [0, a1 + a2, y23, 0, sgn q'2]]

so ``tau = Y (theta_0 + u) - K r`` (eq. 12) both compensates the nominal Coulomb friction
``k_hat sgn(q')`` and is robust to ``|k - k_hat| <= rho_k``. ``q'`` is the velocity estimate
(``v`` port). Use it *instead of* the fixed compensation of eqs. 89-90 (the builder's
``friction_compensation`` must stay off, or the friction is compensated twice).

Choices (not printed in the paper, recorded in BUILD_NOTES.md): nominal ``k_hat = (1, 2)`` N m
as in section 9; friction bounds ``rho_k = (0.5, 1.0)`` N m (half the nominal values); SP1's
single bound is the Euclidean norm ``sqrt(0.1062^2 + 0.5^2 + 1.0^2)`` (as the 0.1062 of
appendix 12.1 is the norm over the rigid-body parameters) and SP2's per-component bounds are
table 10 extended with rho_k; epsilon as in table 1 (SP1: 1, SP2: 0.5 for every component).
"""

from __future__ import annotations

import math

import numpy as np

from robust_drake.description import packaged_description
from robust_drake.errors import RobustDrakeError
from robust_drake.systems.controllers.base import DiscreteController
from robust_drake.systems.controllers.spong import (
    D2R2_K,
    D2R2_LAMBDA,
    D2R2_RHO_SP1,
    D2R2_RHO_SP2,
    EPSILON_SP1,
    EPSILON_SP2,
    SpongSP1Controller,
    SpongSP2Controller,
    d2r2_regressor_single,
)

K_HAT = packaged_description("d2r2").friction_compensation_k_hat  # JS section 9, k1_hat, k2_hat [N m]
RHO_K = tuple(0.5 * k for k in K_HAT)  # our choice: |k - k_hat| <= k_hat / 2


def _sgn(x: float) -> float:
    return 1.0 if x > 0 else (-1.0 if x < 0 else 0.0)


def d2r2_friction_regressor(q, qd, v, a) -> np.ndarray:
    """JS eq. 92: the eq. 15 regressor with the Coulomb columns ``diag(sgn q')`` (2 x 5)."""
    Y = np.zeros((2, 5))
    Y[:, :3] = d2r2_regressor_single(q, qd, v, a)
    Y[0, 3] = _sgn(qd[0])
    Y[1, 4] = _sgn(qd[1])
    return Y


def extended_bounds(rho_rigid_sp1=D2R2_RHO_SP1, rho_rigid_sp2=D2R2_RHO_SP2, rho_k=RHO_K):
    """(rho for SP1, rho vector for SP2) over the 5 parameters of eq. 91."""
    rho1 = math.sqrt(rho_rigid_sp1 ** 2 + sum(r * r for r in rho_k))
    rho2 = tuple(rho_rigid_sp2) + tuple(rho_k)
    return rho1, rho2


def _theta0_ext(k_hat):
    from robust_drake.models import D2R2_THETA0

    return tuple(D2R2_THETA0) + tuple(k_hat)


def _check(ctx, name):
    from robust_drake.description import describe

    if describe(ctx.robot).closed_form_regressor != "d2r2":
        raise RobustDrakeError(f"{name} is built for the D2R2 regressor of JS eq. 92; got robot {ctx.robot!r}")
    if getattr(ctx.config, "friction_compensation", False):
        raise RobustDrakeError(
            f"{name} already compensates Coulomb friction inside the robust law (JS eqs. 91-92); "
            f"set friction_compensation=False or the friction is compensated twice")


def _make_robust_friction(ctx, name, cls, which, epsilon, label, k_hat, rho_k, params):
    _check(ctx, name)
    rho = extended_bounds(rho_k=rho_k)[which]
    p = dict(theta0=_theta0_ext(k_hat), rho=rho, epsilon=epsilon, K=D2R2_K, Lambda=D2R2_LAMBDA)
    p.update(params)
    c = cls(ctx.n, ctx.period, d2r2_friction_regressor, scalar_fast_path=True, **p)
    c.uncertainty = {"kind": "box", "source": "JS appendix 12.1 extended with Coulomb levels (eq. 91)",
                     "theta0": list(p["theta0"]), "bounds": list(D2R2_RHO_SP2) + list(rho_k)}
    c.set_name(label)
    return c


def make_sp1_robust_friction(ctx, k_hat=K_HAT, rho_k=RHO_K, **params):
    """Registry factory ``sp1_robust_friction``."""
    return _make_robust_friction(ctx, "sp1_robust_friction", SpongSP1Controller, 0, EPSILON_SP1,
                                 "SP1RobustFriction", k_hat, rho_k, params)


def make_sp2_robust_friction(ctx, k_hat=K_HAT, rho_k=RHO_K, **params):
    """Registry factory ``sp2_robust_friction``."""
    return _make_robust_friction(ctx, "sp2_robust_friction", SpongSP2Controller, 1, EPSILON_SP2,
                                 "SP2RobustFriction", k_hat, rho_k, params)


# ---------------------------------------------------------------------------------------------
# ZC and LG with the friction inside the robust law (JS section 7.2, last paragraph: "when the
# friction terms were incorporated into the other algorithms, ZC and LG, the performance was, in
# fact, much worse"). The paper does not print these laws; ours add to the unchanged ZC / LG law
# a friction group built as eqs. 91-92 build it for SP1:
#
#     tau = tau_ZC or LG + Y_F (k_hat + u_F),   Y_F = diag(sgn q'),
#     u_F = -rho_F Y_F^T r / ||Y_F^T r||  if ||Y_F^T r|| > eps_F,  else  -(rho_F / eps_F) Y_F^T r,
#
# the SP1-type saturation LG already uses for its inertia and Coriolis groups (eqs. 38-39), with
# rho_F = ||rho_k|| bounding |k - k_hat| and eps_F = 1 (SP1's table-1 value for the same
# saturation). With F_C sgn(q') the true friction, r^T (Y_F (k_hat + u_F) - F_C sgn q') <= eps_F rho_F / 4
# for any |k - k_hat| <= rho_F, so the friction adds a term of the usual boundary-layer size to
# the ultimate bound, and each law keeps its own guarantee for the rigid-body part.
# ---------------------------------------------------------------------------------------------
EPSILON_F = 1.0


def friction_robust_term(q_d, q, v, v_error, Lambda, k_hat=K_HAT, rho_k=RHO_K, eps_F=EPSILON_F):
    """``Y_F (k_hat + u_F)`` above (N m per joint); ``v`` the estimated q', ``v_error`` the estimated q~'."""
    n = len(q)
    sg = [_sgn(v[i]) for i in range(n)]
    xi = [sg[i] * (v_error[i] + Lambda[i] * (q[i] - q_d[i])) for i in range(n)]   # Y_F^T r, r eq. 11
    rho = math.sqrt(sum(x * x for x in rho_k))
    nrm = math.sqrt(sum(x * x for x in xi))
    u = [-rho * x / nrm for x in xi] if nrm > eps_F else [-(rho / eps_F) * x for x in xi]
    return [sg[i] * (k_hat[i] + u[i]) for i in range(n)]


class RobustFrictionWrapper(DiscreteController):
    """A rigid ZC / LG controller (``inner``, used only through its pure ``compute``) plus
    :func:`friction_robust_term`; the builder's fixed compensation must stay off."""

    def __init__(self, inner, name, k_hat=K_HAT, rho_k=RHO_K, eps_F=EPSILON_F):
        super().__init__(inner.n, inner.period, name=name)
        if eps_F <= 0 or min(rho_k) < 0 or min(k_hat) < 0:
            raise RobustDrakeError(f"friction term needs eps_F > 0, rho_k >= 0, k_hat >= 0 (got {eps_F}, {rho_k}, {k_hat})")
        self.inner = inner
        self.Lambda = tuple(float(x) for x in inner.Lambda)
        self.k_hat, self.rho_k, self.eps_F = tuple(map(float, k_hat)), tuple(map(float, rho_k)), float(eps_F)

    def compute(self, t, q_d, qd_d, qdd_d, q, v, v_error):
        tau = self.inner.compute(t, q_d, qd_d, qdd_d, q, v, v_error)
        f = friction_robust_term(q_d, q, v, v_error, self.Lambda, self.k_hat, self.rho_k, self.eps_F)
        return [a + b for a, b in zip(tau, f)]


def _wrap(ctx, name, module, factory, k_hat, rho_k, eps_F, params):
    import importlib

    _check(ctx, name)
    inner = getattr(importlib.import_module(f"robust_drake.systems.controllers.{module}"), factory)(ctx, **params)
    return RobustFrictionWrapper(inner, name, k_hat, rho_k, eps_F)


def make_zc_robust_friction(ctx, k_hat=K_HAT, rho_k=RHO_K, eps_F=EPSILON_F, **params):
    """Registry factory ``zc_robust_friction``: ZC (JS eq. 25) + the friction group above."""
    return _wrap(ctx, "zc_robust_friction", "zenieh_corless", "make_zc", k_hat, rho_k, eps_F, params)


def make_lg_robust_friction(ctx, k_hat=K_HAT, rho_k=RHO_K, eps_F=EPSILON_F, **params):
    """Registry factory ``lg_robust_friction``: LG (JS eq. 36, nominal at the unloaded arm) + friction group."""
    return _wrap(ctx, "lg_robust_friction", "liu_goldenberg", "make_lg", k_hat, rho_k, eps_F, params)


def make_lgplus_robust_friction(ctx, k_hat=K_HAT, rho_k=RHO_K, eps_F=EPSILON_F, **params):
    """Registry factory ``lgplus_robust_friction``: LG+ + friction group."""
    return _wrap(ctx, "lgplus_robust_friction", "liu_goldenberg", "make_lgplus", k_hat, rho_k, eps_F, params)
