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

import itertools
import math

import numpy as np

from robust_drake.description import describe, packaged_description
from robust_drake.errors import RobustDrakeError
from robust_drake.systems.controllers.base import DiscreteController, diag_gain

# the D2R2's published design (JS appendix 12.2, section 8), from robots/d2r2.yaml
_D2R2_DESIGN = packaged_description("d2r2").controller_design
BETA0, BETA1, BETA2 = _D2R2_DESIGN.zc_beta
K_DEFAULT = _D2R2_DESIGN.K
LAMBDA_DEFAULT = _D2R2_DESIGN.Lambda
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


#: Up to this many uncertain parameters the box's 2^p vertices are enumerated (exact in theta);
#: above, the triangle-inequality bound (sound, looser).
MAX_VERTEX_PARAMETERS = 10
#: Gravity torque [N m] below which an arm counts as horizontal (eq. 25 has no gravity term).
GRAVITY_TOL = 1e-9


def zc_bounds_any_arm(robot, load: str = "none", rel_bound: float = 0.2, abs_bound: float = 0.0,
                      configs=None, samples: int = 400, seed: int = 0) -> dict:
    """beta0, beta1, beta2 of JS eqs. 21-23 for any URDF arm, over the box of base parameters
    |theta_k - theta0_k| <= b_k = rel_bound |theta0_k| + abs_bound (as SP1/SP2's set).

    From the Drake-derived Slotine-Li regressor: M(q) e_j = [Y(q, 0, 0, e_j) - Y(q, 0, 0, 0)] theta
    and C(q, e_j) e_i = [Y(q, e_j, e_i, 0) - Y(q, 0, 0, 0)] theta are linear in theta, so with
    M_k(q), C_jk(q) the coefficient matrices of theta_k, over the box (triangle inequality)

        lambda_min M >= lambda_min M(theta0) - sum_k b_k ||M_k||,   lambda_max M <= ... + sum_k b_k ||M_k||,
        ||C(q, q')|| <= ||q'|| sqrt(sum_j (||C_j(theta0)|| + sum_k b_k ||C_jk||)^2)

    (C(q, q') = sum_j q'_j C_j(q), Cauchy-Schwarz). With at most :data:`MAX_VERTEX_PARAMETERS`
    uncertain parameters the box vertices are enumerated instead (exact: lambda_min is concave,
    lambda_max and ||C_j|| convex in theta). Rigorous in theta; the sup/inf over q is
    sampled: ``configs`` (K x n) or ``samples`` uniform draws over [-pi, pi]^n (joint 1 of a
    serial arm does not change M or C). Raises :class:`RobustDrakeError` if the arm has gravity
    torques: eq. 25 has no gravity term and JS give no bound for one.
    """
    from robust_drake.regressor import InverseDynamicsRegressor

    reg = InverseDynamicsRegressor.from_robot(robot, load)
    n, th0 = reg.n, reg.base_parameters()
    b = rel_bound * np.abs(th0) + abs_bound
    Q = (np.random.default_rng(seed).uniform(-np.pi, np.pi, size=(samples, n)) if configs is None
         else np.asarray(configs, float).reshape(-1, n))
    Z = np.zeros_like(Q)
    G = reg.slotine_li(Q, Z, Z, Z)  # (K, n, p): gravity columns
    g_max = float(np.max(np.abs(G @ th0))) if len(Q) else 0.0
    if g_max > GRAVITY_TOL:
        raise RobustDrakeError(
            f"zc: robot {robot!r} has gravity torques up to {g_max:.3g} N m; the ZC law (JS eq. 25) has no "
            "gravity term and JS eqs. 21-23 give no bound for one, so ZC is defined for horizontal arms only "
            "(use sp1, sp2, calafiore or bascetta_a/b, which model gravity)")
    eye = np.eye(n)
    free = np.flatnonzero(b > 0)
    thetas = None
    if len(free) <= MAX_VERTEX_PARAMETERS:  # every vertex of the box
        signs = np.array(list(itertools.product((-1.0, 1.0), repeat=len(free))), dtype=float).reshape(2 ** len(free), len(free))
        thetas = np.tile(th0, (len(signs), 1))
        thetas[:, free] += signs * b[free]
    beta0, beta1, beta2 = np.inf, 0.0, 0.0
    for q, Gq in zip(Q, G):
        qq = np.tile(q, (n, 1))
        Mk = reg.slotine_li(qq, np.zeros((n, n)), np.zeros((n, n)), eye) - Gq  # (j, i, k): M[i, j] coefficient
        Mk = np.transpose(Mk, (2, 1, 0))  # (k, i, j)
        if thetas is not None:  # exact over the box: lambda_min concave, lambda_max convex in theta
            Ms = np.tensordot(thetas, Mk, axes=1)
            w = np.linalg.eigvalsh(0.5 * (Ms + np.transpose(Ms, (0, 2, 1))))
            beta0, beta1 = min(beta0, float(w[:, 0].min())), max(beta1, float(w[:, -1].max()))
        else:
            M0 = np.tensordot(th0, Mk, axes=1)
            dM = float(np.sum(b * np.linalg.norm(Mk, 2, axis=(1, 2))))
            w = np.linalg.eigvalsh(0.5 * (M0 + M0.T))
            beta0, beta1 = min(beta0, w[0] - dM), max(beta1, w[-1] + dM)
        qn = np.repeat(q[None, :], n * n, axis=0)
        Ej = np.repeat(eye, n, axis=0)  # (j, i) pairs: qd = e_j, v = e_i
        Ei = np.tile(eye, (n, 1))
        Ck = (reg.slotine_li(qn, Ej, Ei, np.zeros((n * n, n))) - Gq).reshape(n, n, n, -1)  # (j, i, row, k)
        Ck = np.transpose(Ck, (0, 3, 2, 1))  # (j, k, row, col=i)
        if thetas is not None:  # ||C_j(theta)|| is convex in theta: its max over the box is at a vertex
            cj = np.linalg.norm(np.einsum("jkrc,vk->vjrc", Ck, thetas), 2, axis=(2, 3)).max(axis=0)
        else:
            Cj0 = np.einsum("jkrc,k->jrc", Ck, th0)
            cj = np.linalg.norm(Cj0, 2, axis=(1, 2)) + np.einsum("k,jk->j", b, np.linalg.norm(Ck, 2, axis=(2, 3)))
        beta2 = max(beta2, float(np.sqrt(np.sum(cj ** 2))))
    if not beta0 > 0:
        raise RobustDrakeError(
            f"zc: over the box (rel_bound {rel_bound}, abs_bound {abs_bound}) the inertia bound beta0 = {beta0:.3g} "
            "is not positive (JS eq. 21 needs M(q) >= beta0 I > 0); use a smaller box")
    return {"beta0": float(beta0), "beta1": float(beta1), "beta2": float(beta2), "rel_bound": float(rel_bound),
            "abs_bound": float(abs_bound), "configs": int(len(Q)), "g_max": g_max,
            "parameters": list(reg.base_names), "theta0": th0.tolist(), "bounds": b.tolist()}


def zc_default_epsilon(ctx, beta1, beta2, K, samples: int = 200) -> float:
    """epsilon for arms without a published one: the robust gain rho^2 / (rho ||r|| + epsilon) of
    eq. 25 is at most rho^2 / epsilon; epsilon = rho_max^2 / min(K), rho_max = max of
    beta1 ||qdd_d|| + beta2 ||qd_d||^2 along the loop's reference (rho at zero error), caps it at
    min(K) (same rule as SP1's boundary layer; without it the imi_scara loop at 1 kHz blew up
    within 10 ms with the D2R2's epsilon = 25)."""
    from robust_drake.trajectories import make_reference

    cfg = ctx.config
    kmin = float(np.min(np.broadcast_to(np.asarray(K, float), (ctx.n,))))
    if cfg is None or not hasattr(cfg, "trajectory"):
        return EPSILON_CPT
    ref = make_reference(ctx.arm, cfg.trajectory, **dict(getattr(cfg, "trajectory_params", {}) or {}))
    duration = float(getattr(cfg, "duration", None) or ref.duration)
    _, qd, qdd = (np.asarray(x, float).reshape(-1, ctx.n) for x in ref(np.linspace(0.0, duration, samples)))
    rho = beta1 * np.linalg.norm(qdd, axis=1) + beta2 * np.linalg.norm(qd, axis=1) ** 2
    r = float(rho.max())
    return r * r / kmin if r > 0 else EPSILON_CPT


def make_zc(ctx, **params):
    """Registry factory ``zc``: the bounds and gains of the robot's description
    (``controller_design.zc_beta``, ``K``, ``Lambda``; the D2R2's are JS appendix 12.2 and section 8),
    table 1 epsilon = 25 by default (pass ``epsilon=45`` for the circle, section 10). Any other arm: beta0..2 from
    :func:`zc_bounds_any_arm` (params ``rel_bound``, ``abs_bound``; horizontal arms only), gains
    from :func:`robust_drake.systems.controllers.spong.default_gains`."""
    params = dict(params)
    box = {k: params.pop(k) for k in ("rel_bound", "abs_bound") if k in params}
    unc = None
    design = describe(ctx.robot).controller_design
    if design.zc_beta is not None:  # published bounds and gains in the robot's description
        _, b1, b2 = design.zc_beta
        params.setdefault("beta1", b1)
        params.setdefault("beta2", b2)
        for key, value in (("K", design.K), ("Lambda", design.Lambda)):
            if value is not None:
                params.setdefault(key, value)
    if design.zc_beta is None and not {"beta1", "beta2"} <= set(params):
        from robust_drake.systems.controllers.spong import default_gains

        unc = zc_bounds_any_arm(ctx.robot, ctx.load, **box)
        params.setdefault("beta1", unc["beta1"])
        params.setdefault("beta2", unc["beta2"])
        K0, L0 = default_gains(ctx)
        params.setdefault("K", K0)
        params.setdefault("Lambda", L0)
        if "epsilon" not in params:
            params["epsilon"] = zc_default_epsilon(ctx, params["beta1"], params["beta2"], params["K"])
            unc["epsilon_rule"] = {"epsilon": params["epsilon"]}
        unc = dict(unc, kind="box", source="URDF base parameters +- rel_bound |theta0_i| + abs_bound; "
                   "beta0..2 of JS eqs. 21-23 over it (sampled configurations)")
    elif box:
        raise RobustDrakeError(f"zc: rel_bound/abs_bound apply to arms without published bounds; {ctx.robot!r} "
                               "has beta0..2 in its description or params (the D2R2: JS appendix 12.2)")
    c = ZeniehCorlessController(ctx.n, ctx.period, **params)
    c.uncertainty = unc
    return c
