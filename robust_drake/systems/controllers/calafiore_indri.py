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

Any other URDF arm (n joints): D is the Drake-derived Slotine-Li regressor on the base parameters
(:meth:`robust_drake.regressor.InverseDynamicsRegressor.slotine_li_single`, gravity included;
eq. 6's D(q, qd, v, a) theta = M a + C v + g), theta0 the URDF's base parameters unless given, and
the ellipsoid E(P, theta0) (eq. 10) on the base parameters comes from ``P``, an identified
``ellipsoid`` (JSON path or :class:`~robust_drake.uncertainty.ellipsoid.Ellipsoid`, same base
parameterisation), or, by default, the smallest axis-aligned ellipsoid containing the box
|theta_i - theta0_i| <= b_i of SP1/SP2 (``rel_bound``, ``abs_bound``): P = k diag(b^2), k the
number of b_i > 0 (every box vertex lies on its boundary). See :func:`ellipsoid_design`.
"""

from __future__ import annotations

import math

import numpy as np

from robust_drake.analysis.tolerance import psd_tol
from robust_drake.description import describe, packaged_description
from robust_drake.errors import RobustDrakeError
from robust_drake.systems.controllers.base import DiscreteController, diag_gain

#: Gains used for the CI section 5.2 study (the paper does not print its K, Lambda), and the
#: IMI SCARA's l1: from robots/imi_scara.yaml.
_IMI = packaged_description("imi_scara")
IMI_K = _IMI.controller_design.K
IMI_LAMBDA = _IMI.controller_design.Lambda
IMI_L1 = _IMI.link_lengths[0]


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

    def __init__(self, n, period, regressor, theta0, K, Lambda, E=None, P=None, epsilon=1.0, robust=True,
                 list_inputs=True):
        super().__init__(n, period, name="CalafioreIndriController" if robust else "CalafioreIndriNominal")
        self.regressor = regressor
        self.list_inputs = bool(list_inputs)  # scalar-math regressors take lists; Drake's takes arrays
        self.uncertainty = None  # the ellipsoid (JSON-able), set by the factories
        self.rho = None  # max ||theta~||_2 over the ellipsoid = sqrt(lambda_max(P))
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
        if self.list_inputs:
            q, v, vref, a = q.tolist(), v.tolist(), vref.tolist(), a.tolist()
        D = np.asarray(self.regressor(q, v, vref, a), dtype=float)
        return calafiore_torque(D, self.theta0, self.E, self.K, r, self.epsilon, self.robust)


def ellipsoid_from_box(theta0, rel_bound: float, abs_bound: float = 0.0) -> np.ndarray:
    """P of the smallest axis-aligned ellipsoid {theta0 + E z, ||z|| <= 1} (CI eq. 10) containing
    the box |theta_i - theta0_i| <= b_i = rel_bound |theta0_i| + abs_bound: P = k diag(b^2),
    k = #{b_i > 0} (each vertex has sum_i (theta~_i / b_i)^2 / k = 1)."""
    if not (np.isfinite(rel_bound) and rel_bound >= 0 and np.isfinite(abs_bound) and abs_bound >= 0):
        raise RobustDrakeError(f"rel_bound and abs_bound must be finite and >= 0 (got {rel_bound}, {abs_bound})")
    b = rel_bound * np.abs(np.asarray(theta0, dtype=float)) + abs_bound
    return max(int(np.count_nonzero(b > 0)), 1) * np.diag(b ** 2)


def ellipsoid_epsilon(D_samples, E, K) -> float:
    """Boundary layer for arms without a published one: inside the layer eq. 15 adds the gain
    D P D^T / epsilon on r (P = E E^T); epsilon = max_k ||D_k E||_2^2 / min(K) over the reference
    samples D_k = D(q_d, qd_d, qd_d, qdd_d) caps it at min(K) (with P = rho^2 I this is
    rho times SP1's rule in :func:`robust_drake.systems.controllers.spong.default_epsilon`)."""
    DE = np.asarray(D_samples, dtype=float) @ np.asarray(E, dtype=float)
    g = float(np.linalg.norm(DE, ord=2, axis=(1, 2)).max()) ** 2 if DE.size else 0.0
    return g / float(np.min(K)) if g > 0 else 1.0


def ellipsoid_design(ctx, p: dict):
    """(regressor, theta0, E, uncertainty) for an n-joint URDF arm (pops the keys it uses from p):
    Drake's Slotine-Li regressor on the base parameters, theta0 (param or the URDF's), and the
    ellipsoid from ``P``, ``ellipsoid`` (JSON path / Ellipsoid) or the box of ``rel_bound`` (default
    0.2) / ``abs_bound`` (see the module docstring)."""
    from robust_drake.regressor import InverseDynamicsRegressor
    from robust_drake.systems.controllers.spong import DEFAULT_REL_BOUND

    reg = InverseDynamicsRegressor.from_robot(ctx.robot, ctx.load)
    if reg.n != ctx.n:
        raise RobustDrakeError(f"regressor of {ctx.robot!r} has {reg.n} joints, the loop has {ctx.n}")
    box = {k: float(p.pop(k)) for k in ("rel_bound", "abs_bound") if k in p}
    ell = p.pop("ellipsoid", None)
    model, alpha, extra = p.pop("model", None), float(p.pop("alpha", 0.01)), {}
    if model is not None:  # an identified model: theta0 and E(P, theta0) = its confidence set
        from robust_drake.identification.model import as_identified_model, controller_set

        if ell is not None or "theta0" in p or "P" in p:
            raise RobustDrakeError("calafiore: give either 'model' or 'ellipsoid' / 'theta0' / 'P', not both")
        p["_model"] = as_identified_model(model)
        theta0, P, extra = controller_set(p["_model"], reg, alpha)
        source = extra.pop("source")
        extra = {k: extra[k] for k in ("alpha", "model")}
    elif ell is not None:
        from robust_drake.uncertainty.ellipsoid import Ellipsoid

        ell = ell if isinstance(ell, Ellipsoid) else Ellipsoid.load(ell)
        theta0, P, source = ell.theta0, ell.P, "identified confidence ellipsoid (CI eq. 10)"
        if "theta0" in p or "P" in p:
            raise RobustDrakeError("calafiore: give either 'ellipsoid' or 'theta0'/'P', not both")
    else:
        theta0 = np.asarray(p.pop("theta0", reg.base_parameters()), dtype=float)
        if "P" in p:
            P, source = np.asarray(p.pop("P"), dtype=float), "user P"
        else:
            rel = box.get("rel_bound", DEFAULT_REL_BOUND)
            P = ellipsoid_from_box(theta0, rel, box.get("abs_bound", 0.0))
            source = "smallest axis-aligned ellipsoid containing the box +- rel_bound |theta0_i| + abs_bound"
            box = {"rel_bound": rel, "abs_bound": box.get("abs_bound", 0.0)}
    m = reg.p_base
    if theta0.shape != (m,) or P.shape != (m, m):
        raise RobustDrakeError(
            f"calafiore on {ctx.robot!r}: theta0 must have the {m} base parameters "
            f"(InverseDynamicsRegressor.base_names) and P be {m}x{m}; got {theta0.shape} and {P.shape}")
    E = sqrtm_psd(P)
    unc = {"kind": "ellipsoid", "source": source, "parameters": list(reg.base_names),
           "theta0": theta0.tolist(), "P": P.tolist(), **box, **extra,
           "rho": float(np.sqrt(max(np.linalg.eigvalsh(0.5 * (P + P.T))[-1], 0.0)))}
    return reg, theta0, E, unc


def _make_any_arm(ctx, robust, p):
    from robust_drake.systems.controllers.spong import default_gains

    reg, theta0, E, unc = ellipsoid_design(ctx, p)
    model = p.pop("_model", None)
    K0, L0 = default_gains(ctx)
    p.setdefault("K", K0)
    p.setdefault("Lambda", L0)
    if not robust:
        E = np.zeros_like(E)
    if "epsilon" not in p:
        D = _reference_regressors(ctx, reg)
        Kv = np.broadcast_to(np.asarray(p["K"], dtype=float), (ctx.n,))
        p["epsilon"] = ellipsoid_epsilon(D, E, Kv) if robust else 1.0
        unc["epsilon_rule"] = {"epsilon": p["epsilon"], "samples": int(len(D))}
    try:
        c = CalafioreIndriController(ctx.n, ctx.period, reg.slotine_li_single, theta0, E=E, robust=robust,
                                     list_inputs=False, **p)
    except (TypeError, ValueError) as exc:
        raise RobustDrakeError(f"calafiore: {exc}") from None
    c.uncertainty = unc
    c.rho = unc["rho"] if robust else None
    if model is not None:  # its friction and effects fed forward, stateful ones as blocks
        from robust_drake.identification.model import attach_compensation

        attach_compensation(c, model)
    return _fused(c)


def _reference_regressors(ctx, reg, samples: int = 200) -> np.ndarray:
    """D(q_d, qd_d, qd_d, qdd_d) at ``samples`` instants of the loop's reference (K, n, m);
    empty if the loop has no reference."""
    from robust_drake.trajectories import make_reference

    cfg = ctx.config
    if cfg is None or not hasattr(cfg, "trajectory"):
        return np.zeros((0, ctx.n, reg.p_base))
    ref = make_reference(ctx.arm, cfg.trajectory, **dict(getattr(cfg, "trajectory_params", {}) or {}))
    duration = float(getattr(cfg, "duration", None) or ref.duration)
    q, qd, qdd = (np.asarray(x, float).reshape(-1, ctx.n) for x in ref(np.linspace(0.0, duration, samples)))
    return reg.evaluate(q, qd, qdd)


def _make(ctx, robust, params):
    p = dict(params)
    reg = p.pop("regressor", None)
    if reg is None:
        if describe(ctx.robot).closed_form_regressor != "imi_scara" or "model" in p:  # CI section 5 model
            return _make_any_arm(ctx, robust, p)
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
    c = CalafioreIndriController(ctx.n, ctx.period, reg, robust=robust, **p)
    if "theta0" in params or describe(ctx.robot).closed_form_regressor == "imi_scara":
        c.uncertainty = {"kind": "ellipsoid", "source": "CI section 5.1" if "P" not in params else "user P",
                         "theta0": np.asarray(p["theta0"], float).tolist()}
        c.rho = float(np.linalg.norm(c.E, 2)) if robust else None
    return _fused(c)


def _fused(c):
    """The closed loop's block: the four contract ports gathered by one C++ Multiplexer, so the
    per-tick update reads one port (spong.FusedInputController; same torque, tests/test_compiled_blocks.py)."""
    from robust_drake.systems.controllers.spong import FusedInputController

    return FusedInputController(c)


def make_calafiore(ctx, **params):
    """Registry factory: robust law (eqs. 6-8, 15); defaults: published theta0, P (CI sec. 5.1).
    ``model`` (an identified model or a report / model path): theta0 and P from its ``alpha``
    (0.01) confidence set, and its compensation (friction, effects)."""
    return _make(ctx, True, params)


def make_calafiore_nominal(ctx, **params):
    """Registry factory: nominal law (eq. 6) only."""
    return _make(ctx, False, params)
