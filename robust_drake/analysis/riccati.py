"""The Riccati equation of Bascetta & Rocco (BR) section IV, solved two independent ways.

BR eq. 17 (plus sign: a bounded-real / H-infinity type equation, not an LQR one):

    (A0 + I)^T P0 + P0 (A0 + I) + gamma^2 P0 B B^T P0 + A0^T B B^T A0 = 0,
    A0 = [[0, 1], [-kappa01, -kappa02]],   B = [0; 1].

It is an instance of the bounded-real equation

    A^T P + P A + gamma^2 P B B^T P + C^T C = 0                               (*)

with A = A0 + I (Hurwitz under BR eq. 16, Lemma 1) and C = B^T A0. Its stabilising solution
(A + gamma^2 B B^T P Hurwitz) exists iff ||C (sI - A)^{-1} B||_inf < 1/gamma (bounded-real lemma),
so the largest admissible gamma is 1/||t||_inf (BR Lemma 2, 5).

* :func:`bounded_real_are_hamiltonian`: stable invariant subspace of the Hamiltonian
  ``[[A, gamma^2 B B^T], [-C^T C, -A^T]]`` by an ordered real Schur form (scipy).
* :func:`bounded_real_are_sdp`: the stabilising solution is the *smallest* symmetric P satisfying
  the Riccati inequality ``(*) <= 0``; by a Schur complement that inequality is the LMI
  ``[[A^T P + P A + C^T C, P B], [B^T P, -I / gamma^2]] <= 0``, and minimising ``trace(P)`` over it
  with Drake's ``MathematicalProgram`` (Clarabel by default) returns the same P.

Drake's ``ContinuousAlgebraicRiccatiEquation(A, B, Q, R)`` needs R > 0 (the minus sign) and is
deliberately not used here.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from robust_drake.analysis.norms import hinf_norm_hamiltonian, solve_program, sym_basis, sym_from_vec
from robust_drake.analysis.tolerance import (are_backward_error, certificate_tol, on_imaginary_axis,
                                            schur_are_condition)
from robust_drake.errors import RobustDrakeError, SolverError

B2 = np.array([[0.0], [1.0]])


def A0_matrix(kappa01: float, kappa02: float) -> np.ndarray:
    """``A0 = [[0, 1], [-kappa01, -kappa02]]`` (BR, before eq. 17)."""
    return np.array([[0.0, 1.0], [-float(kappa01), -float(kappa02)]])


def conditions16(kappa01: float, kappa02: float) -> bool:
    """BR eq. 16: ``kappa02 > 2`` and ``kappa01 > kappa02 - 1`` (equivalent to A0 + I Hurwitz)."""
    return bool(kappa02 > 2.0 and kappa01 > kappa02 - 1.0)


def eq17_data(kappa01: float, kappa02: float):
    """``(A, B, C)`` of the bounded-real form (*) of eq. 17: A = A0 + I, C = B^T A0."""
    A0 = A0_matrix(kappa01, kappa02)
    return A0 + np.eye(2), B2.copy(), B2.T @ A0


def are_residual(A, B, C, gamma, P) -> float:
    """Frobenius norm of the left-hand side of (*) at P."""
    R = A.T @ P + P @ A + gamma**2 * P @ B @ B.T @ P + C.T @ C
    return float(np.linalg.norm(R))


def bounded_real_are_hamiltonian(A, B, C, gamma: float, with_cond: bool = False):
    """Stabilising solution of (*) from the stable invariant subspace of its Hamiltonian.

    Raises :class:`SolverError` when the Hamiltonian has imaginary-axis eigenvalues
    (``||C (sI - A)^{-1} B||_inf >= 1/gamma``: no stabilising solution). "On the axis" is decided
    to rounding, ``|Re lambda| <= 10 eps kappa(lambda) ||H||`` (``analysis.tolerance``).
    With ``with_cond`` returns ``(P, cond)``, ``cond`` the condition number of the Schur solve
    (``tolerance.schur_are_condition``): P is accurate to ``certificate_tol(cond)`` relative.
    """
    A = np.atleast_2d(np.asarray(A, float))
    B = np.asarray(B, float).reshape(A.shape[0], -1)
    C = np.asarray(C, float).reshape(-1, A.shape[0])
    n = A.shape[0]
    H = np.block([[A, gamma**2 * B @ B.T], [-C.T @ C, -A.T]])
    on_axis, _ = on_imaginary_axis(H)
    if np.any(on_axis):
        raise SolverError(
            f"no stabilising Riccati solution for gamma = {gamma:.6g}: the Hamiltonian has "
            "eigenvalues on the imaginary axis (||t||_inf >= 1/gamma); lower gamma"
        )
    T, Z, sdim = scipy.linalg.schur(H, output="real", sort="lhp")
    if sdim != n:
        raise SolverError(f"Hamiltonian stable subspace has dimension {sdim}, expected {n}")
    X1, X2 = Z[:n, :n], Z[n:, :n]
    P = np.linalg.solve(X1.T, X2.T).T  # X2 X1^{-1}
    P = 0.5 * (P + P.T)
    if with_cond:
        return P, schur_are_condition(T, Z, n)
    return P


def are_certificate(A, B, C, gamma, P, cond: float) -> dict:
    """Residual certificate of (*) at P, as a forward-error estimate.

    The residual R(P) is turned into the Newton correction X of P, ``Acl^T X + X Acl = -R(P)``
    with ``Acl = A + gamma^2 B B^T P`` (the first-order error of P), and ``||X|| / ||P||`` is
    compared with ``certificate_tol(cond)``, the accuracy the solve can have (``cond`` from
    :func:`bounded_real_are_hamiltonian`). P must also be stabilising (Acl Hurwitz). The normwise
    backward error ``||R|| / (||C^T C|| + 2 ||A|| ||P|| + gamma^2 ||B B^T|| ||P||^2)`` is reported
    too; alone it misses errors along directions where the equation is flat (P scaled by 1 + e)."""
    A = np.atleast_2d(np.asarray(A, float))
    B = np.asarray(B, float).reshape(A.shape[0], -1)
    C = np.asarray(C, float).reshape(-1, A.shape[0])
    P = np.asarray(P, float)
    G = gamma**2 * B @ B.T
    R = A.T @ P + P @ A + P @ G @ P + C.T @ C
    Acl = A + G @ P
    stabilising = bool(np.max(np.linalg.eigvals(Acl).real) < 0)
    X = scipy.linalg.solve_continuous_lyapunov(Acl.T, -R)
    step = float(np.linalg.norm(X) / np.linalg.norm(P))
    tol = certificate_tol(cond)
    return {"newton_step_rel": step, "backward_error": are_backward_error(A, G, C.T @ C, P, float(np.linalg.norm(R))),
            "tol": tol, "stabilising": stabilising, "ok": bool(stabilising and step <= tol)}


def bounded_real_are_sdp(A, B, C, gamma: float, solver: str = "clarabel") -> np.ndarray:
    """Stabilising (minimal) solution of (*) as the SDP ``min trace(P)`` s.t. the Riccati LMI.

    Posed with numeric coefficients on Drake's ``MathematicalProgram``:
    ``-[[A^T P + P A + C^T C, P B], [B^T P, -I/gamma^2]] >= 0``.
    """
    from pydrake.solvers import MathematicalProgram

    A = np.atleast_2d(np.asarray(A, float))
    B = np.asarray(B, float).reshape(A.shape[0], -1)
    C = np.asarray(C, float).reshape(-1, A.shape[0])
    n, m = A.shape[0], B.shape[1]
    N = n + m
    prog = MathematicalProgram()
    pv = prog.NewContinuousVariables(n * (n + 1) // 2, "P")
    F0 = np.zeros((N, N))
    F0[:n, :n] = -C.T @ C
    F0[n:, n:] = np.eye(m) / gamma**2
    F = [F0]
    cost = []
    for E in sym_basis(n):
        Fi = np.zeros((N, N))
        Fi[:n, :n] = -(A.T @ E + E @ A)
        Fi[:n, n:] = -E @ B
        Fi[n:, :n] = -B.T @ E
        F.append(Fi)
        cost.append(np.trace(E))
    prog.AddLinearMatrixInequalityConstraint(F, pv)
    prog.AddLinearCost(np.array(cost), pv)
    result = solve_program(prog, solver)
    return sym_from_vec(result.GetSolution(pv), n)


def solve_eq17(kappa01: float, kappa02: float, gamma: float, method: str = "hamiltonian",
               solver: str = "clarabel") -> np.ndarray:
    """P0 of BR eq. 17 by ``method`` = ``"hamiltonian"`` or ``"sdp"``."""
    if not conditions16(kappa01, kappa02):
        raise RobustDrakeError(
            f"(kappa01, kappa02) = ({kappa01:g}, {kappa02:g}) violates BR eq. 16 "
            "(kappa02 > 2, kappa01 > kappa02 - 1): A0 + I is not Hurwitz"
        )
    A, B, C = eq17_data(kappa01, kappa02)
    if method == "hamiltonian":
        return bounded_real_are_hamiltonian(A, B, C, gamma)
    if method == "sdp":
        return bounded_real_are_sdp(A, B, C, gamma, solver=solver)
    raise RobustDrakeError(f"unknown Riccati method {method!r}; use 'hamiltonian' or 'sdp'")


def t_norm(kappa01: float, kappa02: float, rtol: float = 1e-10, n_sweep: int = 400) -> float:
    """``||t(s)||_inf`` with ``t(s) = B^T A0 [sI - (A0 + I)]^{-1} B`` (BR Lemma 2)."""
    A, B, C = eq17_data(kappa01, kappa02)
    return hinf_norm_hamiltonian(A, B, C, rtol=rtol, n_sweep=n_sweep).norm


def gamma_max(kappa01: float, kappa02: float, rtol: float = 1e-10, n_sweep: int = 400) -> float:
    """Largest admissible gamma: ``1 / ||t||_inf`` (BR Lemma 5)."""
    return 1.0 / t_norm(kappa01, kappa02, rtol, n_sweep)


def common_gains(K_P, K_D):
    """Scalar (omega_n^2, 2 zeta omega_n) when all joints share the error dynamics (BR section IV)."""
    kp = np.atleast_1d(np.diag(K_P) if np.ndim(K_P) == 2 else K_P).astype(float)
    kd = np.atleast_1d(np.diag(K_D) if np.ndim(K_D) == 2 else K_D).astype(float)
    if not (np.allclose(kp, kp[0]) and np.allclose(kd, kd[0])):
        raise RobustDrakeError(
            "BR section IV assumes all joints share the same error dynamics: K_P = omega_n^2 I, "
            f"K_D = 2 zeta omega_n I; got K_P = {kp.tolist()}, K_D = {kd.tolist()}"
        )
    if kp[0] <= 0 or kd[0] <= 0:
        raise RobustDrakeError("K_P and K_D must be positive")
    return float(kp[0]), float(kd[0]), len(kp)


def kappas(kp: float, kd: float, delta: float):
    """``kappa01 = kp / delta^2``, ``kappa02 = kd / delta`` (BR, before eq. 16)."""
    return kp / delta**2, kd / delta


def delta_for_gamma(kp: float, kd: float, gamma_needed: float, iters: int = 40) -> float:
    """Largest delta in (0, kd/2) with ``gamma_max(kappa(delta)) >= gamma_needed`` (bisection).

    gamma_max decreases with delta (larger delta = larger guaranteed decay rate but a harder
    H-infinity condition). Raises if even delta -> 0 is not enough.
    """
    lo, hi = 1e-3 * kd / 2.0, kd / 2.0 * (1 - 1e-9)
    if gamma_max(*kappas(kp, kd, lo)) < gamma_needed:
        raise RobustDrakeError(
            f"no delta makes gamma_max >= {gamma_needed:.4g} for K_P = {kp:g}, K_D = {kd:g} "
            f"(gamma_max -> {gamma_max(*kappas(kp, kd, lo)):.4g} as delta -> 0): the bound alpha on "
            "||I - M^-1 M_hat|| is too large for BR's Riccati design (improve M_hat or raise the damping)"
        )
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        ok = conditions16(*kappas(kp, kd, mid)) and gamma_max(*kappas(kp, kd, mid), 1e-7, 60) >= gamma_needed
        lo, hi = (mid, hi) if ok else (lo, mid)
    return lo


@dataclass
class RiccatiDesign:
    """Result of :func:`design_riccati` (BR section IV)."""

    kp: float
    kd: float
    n: int
    delta: float
    kappa01: float
    kappa02: float
    gamma: float
    gamma_max: float
    t_norm: float
    P0: np.ndarray
    residual: float
    Pi: np.ndarray  # delta * Bb P0 Bb, Bb = diag(delta, 1) (Lemma 4)
    P: np.ndarray  # (2n x 2n) in the original e = (q~, q~dot) ordering
    BtP: np.ndarray  # (n x 2n): z = BtP @ e
    notes: list = field(default_factory=list)
    certificate: dict = field(default_factory=dict)  # are_certificate of P0

    def to_dict(self):
        return {
            "kp": self.kp, "kd": self.kd, "delta": self.delta, "kappa01": self.kappa01,
            "kappa02": self.kappa02, "gamma": self.gamma, "gamma_max": self.gamma_max,
            "t_norm": self.t_norm, "P0": self.P0.tolist(), "residual": self.residual,
            "residual_certificate": self.certificate,
            "Pi": self.Pi.tolist(), "P0_eigs": np.linalg.eigvalsh(self.P0).tolist(),
        }


def block_P_in_e_order(Pi: np.ndarray, n: int) -> np.ndarray:
    """``P = bdiag(Pi, ..., Pi)`` in epsilon = (q~1, q~dot1, q~2, ...) order, mapped back to
    e = (q~1..q~n, q~dot1..q~dotn): entries P[i, i] = Pi[0, 0], P[i, n+i] = Pi[0, 1], ..."""
    P = np.zeros((2 * n, 2 * n))
    for i in range(n):
        idx = [i, n + i]
        P[np.ix_(idx, idx)] = Pi
    return P


def design_riccati(K_P, K_D, alpha: float | None = None, delta: float | None = None,
                   gamma: float | None = None, margin: float = 1.1) -> RiccatiDesign:
    """Case B design (BR section IV): delta, kappas, gamma, P0 (eq. 17), Pi and P (Lemma 4).

    Choices (documented in BUILD_NOTES, "Bascetta & Rocco"):
    * gamma: the quadratic-stability argument needs ``||Delta|| <= gamma <= 1/||t||_inf``; by
      default ``gamma = alpha`` (the smallest admissible value, the best-conditioned P0), or 0.5 if
      alpha is not given.
    * delta: by default the largest delta in (0, K_D/2) with ``gamma_max >= margin * gamma``
      (largest certified decay rate with a margin against the Riccati singularity).
    """
    kp, kd, n = common_gains(K_P, K_D)
    notes = []
    if gamma is None:
        gamma = float(alpha) if alpha is not None else 0.5
    if alpha is not None and gamma < alpha:
        raise RobustDrakeError(f"gamma = {gamma:.4g} < alpha = {alpha:.4g}: BR section IV needs ||Delta|| <= gamma")
    if delta is None:
        delta = delta_for_gamma(kp, kd, margin * gamma)
        notes.append(f"delta chosen as the largest value with gamma_max >= {margin} gamma")
    k01, k02 = kappas(kp, kd, delta)
    if not conditions16(k01, k02):
        raise RobustDrakeError(
            f"delta = {delta:.4g} gives (kappa01, kappa02) = ({k01:.4g}, {k02:.4g}), violating BR eq. 16; "
            f"choose delta < K_D/2 = {kd / 2:.4g}"
        )
    tn = t_norm(k01, k02)
    gmax = 1.0 / tn
    if gamma >= gmax:
        raise RobustDrakeError(
            f"gamma = {gamma:.4g} >= gamma_max = 1/||t||_inf = {gmax:.4g} for delta = {delta:.4g}: "
            "no stabilising solution of eq. 17; lower delta or gamma"
        )
    A, B, C = eq17_data(k01, k02)
    P0, cond = bounded_real_are_hamiltonian(A, B, C, gamma, with_cond=True)
    res = are_residual(A, B, C, gamma, P0)
    cert = are_certificate(A, B, C, gamma, P0, cond)
    if not cert["ok"]:
        raise SolverError(f"eq. 17 solve is not accurate: Newton step {cert['newton_step_rel']:.3g} of ||P0|| > "
                          f"tolerance {cert['tol']:.3g} (condition number {cond:.3g})")
    Bb = np.diag([delta, 1.0])
    Pi = delta * Bb @ P0 @ Bb
    P = block_P_in_e_order(Pi, n)
    Bfull = np.vstack([np.zeros((n, n)), np.eye(n)])
    return RiccatiDesign(kp, kd, n, float(delta), k01, k02, float(gamma), gmax, tn, P0, res, Pi, P,
                         Bfull.T @ P, notes, cert)
