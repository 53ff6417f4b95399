"""Information of an identification experiment about the base parameters, friction and effects.

The repair identifies (``identification/fitting.py``)::

    tau = A(q, qd, qdd) x,   A = [ Y_b(q, qd, qdd) | sgn(qd_j) | qd_j | Phi_e(q, qd, qdd, tau) ]

(base-parameter regressor of ``regressor.InverseDynamicsRegressor``, Coulomb and viscous
friction per joint, the columns of optional effects from ``effects/``).  With white
torque noise of standard deviation sigma [N m] on every sample, the Fisher information of x in a
log of samples k is ``F = sum_k A_k^T A_k / sigma^2`` and its inverse the Cramer-Rao covariance
of the (least-squares) estimate (Swevers et al. 1997 eq. 9 form; Gautier & Khalil 1992 use the
condition number of the stacked A).  A zero-phase low-pass (the repair's 8 Hz) applied to both
sides leaves F unchanged for a band-limited motion well below its cut-off: it removes noise
outside the band and no signal.

The design (:mod:`robust_drake.excitation.design`) needs d log det F / d(states), so this module
gives the columns together with their derivatives with respect to every state z = (q, qd, qdd)
(central differences on the stacked states: the regressor is a numpy recursion without
automatic derivatives).  Coulomb friction uses the smooth sign tanh(qd / v_eps) there (the
optimiser needs a differentiable objective; the columns of the fit use sgn).
"""

from __future__ import annotations

import numpy as np

from robust_drake.errors import RobustDrakeError

#: smooth-sign width [rad/s] of the Coulomb column in the design objective (the replay's width)
DESIGN_V_EPS = 0.05
#: central-difference step on the states [rad, rad/s, rad/s^2]: the regressor is polynomial in
#: qd, qdd and trigonometric in q, so the truncation error (h^2) is ~1e-10 of the columns
STATE_STEP = 1e-5


class InformationModel:
    """Columns A(q, qd, qdd) of the identification and the model torque, with state derivatives.

    Parameters
    ----------
    regressor : InverseDynamicsRegressor
        The arm's base-parameter regressor (``regressor.InverseDynamicsRegressor.from_robot``).
    effects : list of Effect
        Extra column blocks (``effects.make_effect(kind)``); kinds whose columns use the torque
        get the model torque below.
    coulomb, viscous : array (n,)
        Friction levels [N m], [N m s/rad] used in the model torque (the robot description's
        ``simulation.plant_friction``, zeros when it has none).
    theta : array (p_base,)
        Base parameters of the model torque (default: the URDF's).
    """

    def __init__(self, regressor, effects=(), coulomb=None, viscous=None, theta=None,
                 v_eps: float = DESIGN_V_EPS):
        self.reg = regressor
        self.n = n = regressor.n
        self.effects = list(effects)
        self.v_eps = float(v_eps)
        self.theta = np.asarray(regressor.base_parameters() if theta is None else theta, float)
        self.coulomb = np.zeros(n) if coulomb is None else np.asarray(coulomb, float)
        self.viscous = np.zeros(n) if viscous is None else np.asarray(viscous, float)
        self.names = (list(regressor.base_names) + [f"fc{j + 1}" for j in range(n)]
                      + [f"fv{j + 1}" for j in range(n)])
        for e in self.effects:
            self.names += [f"{e.name}:{c}" for c in e.column_names(n)]
        self.p_base = len(regressor.base_names)
        self.p = len(self.names)

    # ---------------------------------------------------------------- values
    def torque(self, q, qd, qdd, Y=None) -> np.ndarray:
        """Model torque (M, n) [N m]: Y_b theta + fc tanh(qd / v_eps) + fv qd (no effects)."""
        Y = self.reg.evaluate(q, qd, qdd) if Y is None else Y
        return Y @ self.theta + self.coulomb * np.tanh(qd / self.v_eps) + self.viscous * qd

    def columns(self, q, qd, qdd) -> np.ndarray:
        """A (M, n, p) at the states (each (M, n))."""
        return self._columns(q, qd, qdd)[0]

    def _columns(self, q, qd, qdd):
        q, qd, qdd = (np.atleast_2d(np.asarray(a, float)) for a in (q, qd, qdd))
        M, n = q.shape
        Y = self.reg.evaluate(q, qd, qdd)
        tau = self.torque(q, qd, qdd, Y)
        smooth = tau - self.coulomb * np.tanh(qd / self.v_eps)
        A = np.zeros((M, n, self.p))
        A[:, :, :self.p_base] = Y
        idx = np.arange(n)
        A[:, idx, self.p_base + idx] = np.tanh(qd / self.v_eps)
        A[:, idx, self.p_base + n + idx] = qd
        c = self.p_base + 2 * n
        for e in self.effects:
            cols = e.evaluate_columns(q, qd, qdd, tau)
            A[:, :, c:c + cols.shape[2]] = cols
            c += cols.shape[2]
        return A, smooth

    # ---------------------------------------------------------------- derivatives
    def with_derivatives(self, q, qd, qdd, h: float = STATE_STEP):
        """(A (M, n, p), tau (M, n), dA (3n, M, n, p), dtau (3n, M, n)): columns, the model torque
        without its Coulomb term (Y theta + fv qd: smooth; the Coulomb term switches by 2 fc
        within milliseconds at a reversal, between any knots, so the design bounds it by |fc|)
        and their derivatives with respect to the states z_s, s = r n + j for z = (q, qd,
        qdd)[r][:, j].  Forward differences, one batched regressor call for the 3n + 1 states:
        exact in qdd (the columns are linear in it), O(h) = 1e-5 relative in qd (quadratic) and q
        (measured: the optimiser's steps do not change below ~1e-4); central differences would
        double the cost, which is the design's whole cost."""
        q, qd, qdd = (np.atleast_2d(np.asarray(a, float)) for a in (q, qd, qdd))
        M, n = q.shape
        Z = np.stack([q, qd, qdd])  # (3, M, n)
        S = 3 * n
        batch = np.repeat(Z[None], S + 1, axis=0)  # (S+1, 3, M, n)
        for s in range(S):
            r, j = divmod(s, n)
            batch[1 + s, r, :, j] += h
        flat = batch.transpose(1, 0, 2, 3).reshape(3, -1, n)
        A_all, tau_all = self._columns(flat[0], flat[1], flat[2])
        A_all = A_all.reshape(S + 1, M, n, self.p)
        tau_all = tau_all.reshape(S + 1, M, n)
        dA = (A_all[1:] - A_all[0]) / h
        dtau = (tau_all[1:] - tau_all[0]) / h
        return A_all[0], tau_all[0], dA, dtau


def information(A: np.ndarray, sigma: float = 1.0) -> np.ndarray:
    """Fisher information F = sum_k A_k^T A_k / sigma^2 (p, p) of columns A (M, n, p)."""
    A2 = np.asarray(A, float).reshape(-1, A.shape[-1])
    return A2.T @ A2 / float(sigma) ** 2


def log_det(F: np.ndarray) -> float:
    """log det F (-inf when F is singular)."""
    sign, val = np.linalg.slogdet(F)
    return float(val) if sign > 0 else -np.inf


def condition_number(A: np.ndarray) -> float:
    """Condition number of the stacked columns, each scaled to unit norm (Gautier & Khalil 1992;
    the scaling makes it independent of the parameters' units, as ``regressor.rank_report``)."""
    A2 = np.asarray(A, float).reshape(-1, A.shape[-1])
    nrm = np.linalg.norm(A2, axis=0)
    s = np.linalg.svd(A2 / np.where(nrm > 0, nrm, 1.0), compute_uv=False)
    return float(s[0] / s[-1]) if s[-1] > 0 else float("inf")


def predicted_std(F: np.ndarray) -> np.ndarray:
    """Cramer-Rao standard deviation of every parameter, sqrt(diag F^-1) (inf if singular)."""
    try:
        C = np.linalg.inv(F)
    except np.linalg.LinAlgError:
        return np.full(F.shape[0], np.inf)
    d = np.diag(C)
    return np.where(d > 0, np.sqrt(np.abs(d)), np.inf)


def dependent_columns(A: np.ndarray, first: int, tol: float = 1e-8) -> list[int]:
    """Indices >= ``first`` of columns of A (M, n, p) that are (numerically) combinations of the
    columns before them (pivoting only among the later ones): effects inside the rigid-body span
    (a payload, the first joint's rotor inertia) that no motion can tell apart."""
    A2 = np.asarray(A, float).reshape(-1, A.shape[-1])
    A2 = A2 / np.where(np.linalg.norm(A2, axis=0) > 0, np.linalg.norm(A2, axis=0), 1.0)
    Q, _ = np.linalg.qr(A2[:, :first])
    out, basis = [], Q
    for c in range(first, A2.shape[1]):
        r = A2[:, c] - basis @ (basis.T @ A2[:, c])
        if np.linalg.norm(r) <= tol ** 0.5:
            out.append(c)
        else:
            basis = np.column_stack([basis, r / np.linalg.norm(r)])
    return out


def check_effect_kinds(kinds, n: int, robot=None) -> list:
    """Effect instances (all joints, default shape) for ``--for-effects``; a one-line error for a
    kind whose columns are not a function of the state and torque alone (time, torque rate)."""
    from robust_drake.effects import EFFECTS, TimeEffect, make_effect

    out = []
    for kind in kinds:
        kind = str(kind).strip()
        if kind not in EFFECTS:
            raise RobustDrakeError(f"unknown effect kind {kind!r} for --for-effects; known: {', '.join(EFFECTS)}")
        cls = EFFECTS[kind]
        if issubclass(cls, TimeEffect) or getattr(cls, "uses_taud", False) or kind == "presliding_friction":
            raise RobustDrakeError(f"effect {kind!r} depends on time, the torque's rate or the path's history, "
                                   "not on the instantaneous state; --for-effects takes kinds whose columns are "
                                   "functions of (q, qd, qdd, tau)")
        shape = {"robot": robot} if "robot" in cls.default_shape else {}
        out.append(make_effect(kind, None, **shape))
    return out
