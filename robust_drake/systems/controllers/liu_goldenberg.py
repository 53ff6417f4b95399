"""Robust controller LG of Liu & Goldenberg and its variant LG+ (Jaritz & Spong section 3.3).

The inertia and Coriolis terms are parametrised separately (JS eqs. 30-31, 40-43 for the D2R2):

    M(q) a = Y_M(a) theta_M(q),    Y_M(a) = [[a1, a2, 0], [0, a1, a2]],  theta_M = (d11, d12, d22)
    C(q, q') v = Y_C(q', v) theta_C(q),  Y_C = [q'2 v1 + (q'1 + q'2) v2, -q'1 v1]^T,  theta_C = h

with d_ij from eq. 3 and h = -m2 l1 lc2 sin q2 (eq. 5). In the parameters of eq. 14
(th1, th2, th3): d11 = th1 + th2 + 2 th3 cos q2, d12 = th2 + th3 cos q2, d22 = th2, h = -th3 sin q2.
The law (eqs. 34-39) is

    tau = Y_M(a) (theta_M0(q) + u_M) + Y_C(q', v) (theta_C0(q) + u_C) - K r

with u_M (eq. 38) and u_C (eq. 39) the SP1-type saturations of Y_M^T r (bound rho_M, layer
epsilon_M) and Y_C^T r (rho_C, epsilon_C). Bounds (eqs. 44-46): the nominal parameters are
``theta_nom`` and every parameter lies within ``theta_nom +- width`` (LG+) or in
``[theta_nom, theta_nom + width]`` (LG, nominal at the unloaded arm); in both cases

    rho_M = sqrt(Dd11^2 + Dd12^2 + Dd22^2),  Dd11 = w1 + w2 + 2 w3 |cos q2|,
    Dd12 = w2 + w3 |cos q2|,  Dd22 = w2,    rho_C = Dh = w3 |sin q2|.

- LG (Liu & Goldenberg [7]): theta_nom = unloaded arm (table 8), width = loaded - unloaded
  (tables 9 - 8).
- LG+ (JS): theta_nom = centre (table 11), width = half the interval (table 10); appendix 12.3
  prints Dd11 = 0.1281 + 0.1065 |c2|, Dd12 = 0.07502 + 0.05327 |c2|, Dd22 = 0.07502, which
  these formulas reproduce, and Dh = 0.050327 |sin q2|, where the formula gives
  w3 = 0.053 (we use 0.053: the printed value would not bound the interval of table 10).

epsilon (table 1): eps_M = 1.5, eps_C = 1 on the CPT; eps_M = 20, eps_C = 2.5 on the circle
(section 10). K = diag(30, 10), Lambda = diag(50, 20).
"""

from __future__ import annotations

import math

from robust_drake.description import packaged_description
from robust_drake.errors import RobustDrakeError
from robust_drake.systems.controllers.base import DiscreteController, diag_gain

K_DEFAULT = packaged_description("d2r2").controller_design.K  # JS section 8 (robots/d2r2.yaml)
LAMBDA_DEFAULT = packaged_description("d2r2").controller_design.Lambda
EPSILON_M_CPT, EPSILON_C_CPT = 1.5, 1.0
EPSILON_M_CIRCLE, EPSILON_C_CIRCLE = 20.0, 2.5


def lg_bounds(q2: float, width) -> tuple[float, float, tuple[float, float, float]]:
    """(rho_M, rho_C, (Dd11, Dd12, Dd22)) of JS eqs. 44-46 at joint angle ``q2``."""
    w1, w2, w3 = width
    ac = abs(math.cos(q2))
    dd11 = w1 + w2 + 2.0 * w3 * ac
    dd12 = w2 + w3 * ac
    dd22 = w2
    return math.sqrt(dd11 * dd11 + dd12 * dd12 + dd22 * dd22), w3 * abs(math.sin(q2)), (dd11, dd12, dd22)


def theta_M(q2: float, theta) -> tuple[float, float, float]:
    """JS eq. 41 in the parameters of eq. 14."""
    c2 = math.cos(q2)
    return theta[0] + theta[1] + 2.0 * theta[2] * c2, theta[1] + theta[2] * c2, theta[1]


def theta_C(q2: float, theta) -> float:
    """JS eq. 43: theta_C = h = -th3 sin q2 (eq. 5)."""
    return -theta[2] * math.sin(q2)


def _sat_vector(xi, rho, eps):
    """SP1-type saturation (JS eqs. 38-39) for a vector xi."""
    nrm = math.sqrt(sum(x * x for x in xi))
    if nrm > eps:
        return [-rho * x / nrm for x in xi]
    return [-(rho / eps) * x for x in xi]


def lg_torque(q_d, qd_d, qdd_d, q, v, v_error, theta_nom, width, K=K_DEFAULT,
              Lambda=LAMBDA_DEFAULT, eps_M=EPSILON_M_CPT, eps_C=EPSILON_C_CPT):
    """JS eq. 36 for the 2-joint D2R2 (scalar math). ``v`` is the estimated q', ``v_error`` the
    estimated q~'. Returns ``[tau1, tau2]``."""
    qt1 = q[0] - q_d[0]
    qt2 = q[1] - q_d[1]
    r1 = v_error[0] + Lambda[0] * qt1  # eq. 11
    r2 = v_error[1] + Lambda[1] * qt2
    vr1 = qd_d[0] - Lambda[0] * qt1
    vr2 = qd_d[1] - Lambda[1] * qt2
    a1 = qdd_d[0] - Lambda[0] * v_error[0]
    a2 = qdd_d[1] - Lambda[1] * v_error[1]
    qd1, qd2 = v[0], v[1]
    q2 = q[1]
    tM = theta_M(q2, theta_nom)
    tC = theta_C(q2, theta_nom)
    rho_M, rho_C, _ = lg_bounds(q2, width)
    # Y_M^T r and Y_C^T r (eqs. 40, 42)
    xiM = (a1 * r1, a2 * r1 + a1 * r2, a2 * r2)
    yc1 = qd2 * vr1 + (qd1 + qd2) * vr2
    yc2 = -qd1 * vr1
    xiC = yc1 * r1 + yc2 * r2
    uM = _sat_vector(xiM, rho_M, eps_M)  # eq. 38
    uC = _sat_vector((xiC,), rho_C, eps_C)[0]  # eq. 39
    p1, p2, p3 = tM[0] + uM[0], tM[1] + uM[1], tM[2] + uM[2]
    pc = tC + uC
    return [a1 * p1 + a2 * p2 + yc1 * pc - K[0] * r1,
            a1 * p2 + a2 * p3 + yc2 * pc - K[1] * r2]


class LiuGoldenbergController(DiscreteController):
    """LG / LG+ (JS eq. 36) as a discrete controller at the sample rate (held torque)."""

    def __init__(self, n, period, theta_nom, width, K=K_DEFAULT, Lambda=LAMBDA_DEFAULT,
                 eps_M=EPSILON_M_CPT, eps_C=EPSILON_C_CPT, name="LiuGoldenbergController"):
        if n != 2:
            raise RobustDrakeError(
                f"LG/LG+ is available for 2-link planar horizontal arms only (JS eqs. 40-43); this arm has n = {n}. "
                "Missing for n joints: the split M(q) a = Y_M(a) theta_M(q), C(q, q') v = Y_C(q', v) theta_C(q) with "
                "the bounds rho_M(q), rho_C(q) of eqs. 32-33, and a gravity term (eq. 36 has none); "
                "use sp1, sp2 or calafiore, whose bounds come from the URDF")
        super().__init__(n, period, name=name)
        self.theta_nom = tuple(float(x) for x in theta_nom)
        self.width = tuple(float(x) for x in width)
        if len(self.theta_nom) != 3 or len(self.width) != 3 or min(self.width) < 0:
            raise RobustDrakeError("LG needs 3 nominal parameters and 3 nonnegative widths (JS eq. 14)")
        if eps_M <= 0 or eps_C <= 0:
            raise RobustDrakeError(f"LG needs eps_M > 0 and eps_C > 0, got {eps_M}, {eps_C}")
        self.K = tuple(float(k) for k in diag_gain(K, n, "K"))
        self.Lambda = tuple(float(x) for x in diag_gain(Lambda, n, "Lambda"))
        self.eps_M = float(eps_M)
        self.eps_C = float(eps_C)

    def compute(self, t, q_d, qd_d, qdd_d, q, v, v_error):
        return lg_torque(q_d, qd_d, qdd_d, q, v, v_error, self.theta_nom, self.width,
                         self.K, self.Lambda, self.eps_M, self.eps_C)


def _paper_thetas(ctx):
    """The unloaded and loaded parameter sets of the robot's description (D2R2: JS tables 8, 9)."""
    from robust_drake.description import describe

    sets = describe(ctx.robot).parameter_sets
    return sets["unloaded"], sets["loaded"]


def _require_d2r2(ctx, name):
    from robust_drake.description import describe

    if not {"unloaded", "loaded"} <= set(describe(ctx.robot).parameter_sets):
        if ctx.n != 2:
            LiuGoldenbergController(ctx.n, ctx.period, (0.0,) * 3, (0.0,) * 3)  # raises the n-joint message
        raise RobustDrakeError(
            f"{name} has the D2R2 bounds of JS appendix 12.3 built in; robot {ctx.robot!r} needs "
            "controller_params theta_nom=(th1, th2, th3), width=(w1, w2, w3) in JS eq. 14's parameters, which "
            "exist only for a horizontal 2-link arm whose link-2 centre of mass lies on the link axis "
            "(d12 = th2 + th3 cos q2); use sp1, sp2 or calafiore for other arms")


def make_lg(ctx, **params):
    """Registry factory ``lg``: Liu & Goldenberg's original choice, nominal = unloaded arm."""
    if "theta_nom" not in params or "width" not in params:
        _require_d2r2(ctx, "LG")
        lo, hi = _paper_thetas(ctx)
        params.setdefault("theta_nom", tuple(lo))
        params.setdefault("width", tuple(h - l for h, l in zip(hi, lo)))
    return LiuGoldenbergController(ctx.n, ctx.period, name="LG", **params)


def make_lgplus(ctx, **params):
    """Registry factory ``lgplus``: JS's LG+, nominal at the centre of the interval."""
    if "theta_nom" not in params or "width" not in params:
        _require_d2r2(ctx, "LG+")
        lo, hi = _paper_thetas(ctx)
        params.setdefault("theta_nom", tuple((h + l) / 2 for h, l in zip(hi, lo)))
        params.setdefault("width", tuple((h - l) / 2 for h, l in zip(hi, lo)))
    return LiuGoldenbergController(ctx.n, ctx.period, name="LG+", **params)
