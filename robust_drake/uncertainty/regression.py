"""The uncertainty model of Calafiore & Indri (CI, seeds/000) section 5, for any regressor.

Measured samples ``(q, qd, qdd, tau)`` at K instants, and confidence bounds per signal
(``delta_max``): the "true" data are ``x = x_measured + delta_max * delta``, |delta| <= 1.
Linearising the regressor in the normalised uncertainties gives (CI section 5)

    D(delta) = D0 + sum_k sum_j delta_k^(j) D_k^(j),   tau(delta) = tau0 + sum_k sum_j delta_k^(j) tau_k^(j),

set in LFR form ``[D tau](delta) = [D0 tau0] + L Delta R`` (eq. 18) with one repeated block per
scalar of size rank([D_k^(j) tau_k^(j)]). Every scalar delta_k^(j) acts on the rows of sample k
only, so the model is stored per sample (``sample_lfrs``): the stacked LFR is never needed to
pose the SDP, and the normal equations (section 3.1)

    D(delta)^T D(delta) theta = D(delta)^T tau(delta)      <=>    sum_k D_k^T [D_k  tau_k] [theta; -1] = 0

are a sum over samples of small product LFRs (eq. 4), each depending on that sample's scalars
only. The derivatives are central finite differences of the regressor function, so any
regressor ``f(q, qd, qdd) -> (..., n, m)`` works; for a regressor linear in qdd (every rigid
body model) the qdd and tau parts are exact.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from robust_drake.errors import DataError, RobustDrakeError
from robust_drake.uncertainty.lfr import LFR, lfr_from_affine, lfr_product, lfr_sum

#: CI section 5, experimentally estimated confidence bounds (SI units).
CI_DELTA_MAX = {
    "tau": np.array([4.5744, 0.5459]),   # N m
    "q": np.array([0.0529, 0.0566]),     # rad
    "qd": np.array([0.0825, 0.0849]),    # rad/s
    "qdd": np.array([0.5892, 1.6478]),   # rad/s^2
}
#: The paper's reduced model: uncertainties on torques and accelerations only (N = 4 n_m).
CI_BOUNDS = {"tau": CI_DELTA_MAX["tau"], "qdd": CI_DELTA_MAX["qdd"]}

SIGNALS = ("tau", "q", "qd", "qdd")


@dataclass
class UncertaintyModel:
    """Per-sample linearised LFRs of ``[D tau](delta)`` (CI eq. 18) and of the normal equations.

    Attributes:
        D0: (K, n, m) regressor at the measured data.
        tau0: (K, n) measured torques.
        coeffs: (K, s, n, m+1) derivatives ``[D_k^(j) tau_k^(j)]`` per sample and scalar.
        scalar_names: the s per-sample scalars, e.g. ``["tau1", "tau2", "qdd1", "qdd2"]``.
        delta_max: (s,) bound of each scalar in SI units.
    """

    D0: np.ndarray
    tau0: np.ndarray
    coeffs: np.ndarray
    scalar_names: list
    delta_max: np.ndarray

    @property
    def n_samples(self) -> int:
        return self.D0.shape[0]

    @property
    def n_joints(self) -> int:
        return self.D0.shape[1]

    @property
    def n_params(self) -> int:
        return self.D0.shape[2]

    @property
    def n_scalars(self) -> int:
        return self.n_samples * len(self.scalar_names)

    def M0(self, k: int) -> np.ndarray:
        return np.hstack([self.D0[k], self.tau0[k][:, None]])

    def sample_lfr(self, k: int) -> LFR:
        """LFR of [D_k tau_k](delta_k) of sample k (n x (m+1)), local scalars 0..s-1."""
        return lfr_from_affine(self.M0(k), self.coeffs[k])

    def sample_normal_lfr(self, k: int) -> LFR:
        """LFR of sample k's normal-equation term D_k^T [D_k tau_k] (m x (m+1)), by eq. 4,
        dead channels removed (e.g. the tau scalars have no channel in D_k^T)."""
        Mk = self.sample_lfr(k)
        Dk = Mk.select(cols=slice(0, self.n_params))
        return lfr_product(Dk.transpose(), Mk).reduce()

    def sample_normal_lfrs(self) -> list:
        return [self.sample_normal_lfr(k) for k in range(self.n_samples)]

    # -------------------------------------------------------------- stacked forms (small K)
    def _globalise(self, F: LFR, k: int) -> LFR:
        s = len(self.scalar_names)
        groups = np.repeat(np.arange(self.n_samples), s)
        return LFR(F.M0, F.L, F.R, F.H, F.scalars + k * s, self.n_scalars, groups)

    def lfr(self) -> LFR:
        """Stacked LFR of [D tau](delta) (K n x (m+1)), CI eq. 18. Dense: for small K only."""
        K, n, m = self.D0.shape
        s = len(self.scalar_names)
        blocks = []
        for k in range(K):
            F = self.sample_lfr(k)
            L = np.zeros((K * n, F.n_channels))
            L[k * n:(k + 1) * n] = F.L
            M0 = np.zeros((K * n, m + 1))
            M0[k * n:(k + 1) * n] = F.M0
            blocks.append(self._globalise(LFR(M0, L, F.R, F.H, F.scalars, s), k))
        out = blocks[0]
        for b in blocks[1:]:
            out = lfr_sum(out, b)
        return out

    def normal_lfr(self) -> LFR:
        """LFR of [D^T D, D^T tau](delta) = sum_k D_k^T [D_k tau_k] (m x (m+1)), eq. 4 per sample."""
        out = None
        for k in range(self.n_samples):
            F = self._globalise(self.sample_normal_lfr(k), k)
            out = F if out is None else lfr_sum(out, F)
        return out

    # -------------------------------------------------------------- exact evaluation
    def perturbed(self, delta) -> tuple[np.ndarray, np.ndarray]:
        """(D(delta), tau(delta)) of the linearised model, delta (K, s) or (K*s,)."""
        d = np.asarray(delta, dtype=float).reshape(self.n_samples, len(self.scalar_names))
        M = np.concatenate([self.D0, self.tau0[..., None]], axis=2) + np.einsum("ks,ksij->kij", d, self.coeffs)
        return M[..., :-1].reshape(-1, self.n_params), M[..., -1].reshape(-1)

    def ls_solution(self, delta) -> np.ndarray:
        """theta(delta): the least-squares solution of the perturbed linearised equations."""
        D, tau = self.perturbed(delta)
        return np.linalg.lstsq(D, tau, rcond=None)[0]

    def ls_solutions(self, deltas) -> np.ndarray:
        """theta(delta) for many draws (count, K*s) -> (count, m), via the normal equations
        assembled per sample (cheap for thousands of samples)."""
        deltas = np.asarray(deltas, dtype=float)
        K, s = self.n_samples, len(self.scalar_names)
        M0 = np.concatenate([self.D0, self.tau0[..., None]], axis=2)         # (K, n, m+1)
        out = []
        for d in deltas.reshape(-1, K, s):
            M = M0 + np.einsum("ks,ksij->kij", d, self.coeffs)
            D, t = M[..., :-1], M[..., -1]
            G = np.einsum("kim,kin->mn", D, D)
            b = np.einsum("kim,ki->m", D, t)
            out.append(np.linalg.solve(G, b))
        return np.array(out)


def build_uncertainty_model(regressor, q, qd, qdd, tau, bounds=None, fd_step: float = 1e-4) -> UncertaintyModel:
    """Linearised uncertainty model of CI section 5 for any regressor.

    Args:
        regressor: ``f(q, qd, qdd) -> (..., n, m)`` with inputs (..., n).
        q, qd, qdd, tau: (K, n) measured samples (SI).
        bounds: dict signal -> (n,) delta_max, signals among "tau", "q", "qd", "qdd"; a
            missing signal or a zero bound has no uncertain scalar. Default: CI_BOUNDS
            (torques and accelerations, as in the paper).
        fd_step: central-difference step in normalised units (h = fd_step * delta_max).

    The scalars of sample k are ordered signal by signal (tau, q, qd, qdd), joint by joint,
    matching CI eq. 17 for the paper's choice (tau1, tau2, qdd1, qdd2).
    """
    q, qd, qdd, tau = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (q, qd, qdd, tau))
    K, n = q.shape
    for name, a in (("qd", qd), ("qdd", qdd), ("tau", tau)):
        if a.shape != (K, n):
            raise DataError(f"{name} has shape {a.shape}, expected {(K, n)} like q")
    if not all(np.isfinite(a).all() for a in (q, qd, qdd, tau)):
        raise DataError("samples contain NaN or inf")
    bounds = CI_BOUNDS if bounds is None else bounds
    for key in bounds:
        if key not in SIGNALS:
            raise RobustDrakeError(f"unknown signal {key!r} in bounds; use {SIGNALS}")
    D0 = np.asarray(regressor(q, qd, qdd), dtype=float)
    if D0.ndim != 3 or D0.shape[:2] != (K, n):
        raise RobustDrakeError(f"regressor returned shape {D0.shape}, expected (K, n, m) = ({K}, {n}, m)")
    m = D0.shape[2]
    names, dmax, cols = [], [], []
    signals = {"q": q, "qd": qd, "qdd": qdd}
    for sig in SIGNALS:
        if sig not in bounds or bounds[sig] is None:
            continue
        b = np.broadcast_to(np.asarray(bounds[sig], dtype=float), (n,))
        if np.any(b < 0):
            raise RobustDrakeError(f"bounds[{sig!r}] must be >= 0")
        for i in range(n):
            if b[i] == 0:
                continue
            C = np.zeros((K, n, m + 1))
            if sig == "tau":
                C[:, i, m] = b[i]
            else:
                h = fd_step * b[i]
                args_p = {k: v.copy() for k, v in signals.items()}
                args_m = {k: v.copy() for k, v in signals.items()}
                args_p[sig][:, i] += h
                args_m[sig][:, i] -= h
                Dp = np.asarray(regressor(args_p["q"], args_p["qd"], args_p["qdd"]))
                Dm = np.asarray(regressor(args_m["q"], args_m["qd"], args_m["qdd"]))
                C[:, :, :m] = (Dp - Dm) * (b[i] / (2 * h))
            names.append(f"{sig}{i + 1}")
            dmax.append(b[i])
            cols.append(C)
    if not cols:
        raise RobustDrakeError("no uncertain signal: give at least one nonzero bound")
    coeffs = np.stack(cols, axis=1)   # (K, s, n, m+1)
    return UncertaintyModel(D0, tau.copy(), coeffs, names, np.array(dmax))
