"""H-infinity norm of a stable LTI system ``G(s) = C (sI - A)^{-1} B + D``, two independent ways.

1. :func:`hinf_norm_hamiltonian`: a frequency sweep gives a lower bound, then bisection on
   the Hamiltonian test (Boyd, Balakrishnan & Kabamba 1989): for ``gamma > sigma_max(D)``,
   ``||G||_inf < gamma`` iff the Hamiltonian

       H(gamma) = [[A + B R^-1 D^T C,            B R^-1 B^T            ],
                   [-C^T (I + D R^-1 D^T) C,   -(A + B R^-1 D^T C)^T   ]],   R = gamma^2 I - D^T D

   has no eigenvalue on the imaginary axis.
2. :func:`hinf_norm_lmi`: the bounded-real (KYP) lemma as an SDP posed with Drake's
   ``MathematicalProgram``: minimise ``g`` subject to

       [[A^T X + X A,  X B,   C^T],
        [B^T X,       -g I,   D^T],   <= 0,
        [C,            D,    -g I]]

   whose optimum is ``||G||_inf``.

Used by Lemma 2 of Bascetta & Rocco (BR) for ``t(s) = B^T A0 [sI - (A0 + I)]^{-1} B``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from robust_drake.analysis.tolerance import certificate_tol, on_imaginary_axis
from robust_drake.errors import RobustDrakeError, SolverError


def _as_ss(A, B, C, D=None):
    A = np.atleast_2d(np.asarray(A, dtype=float))
    B = np.asarray(B, dtype=float).reshape(A.shape[0], -1)
    C = np.asarray(C, dtype=float).reshape(-1, A.shape[0])
    if D is None:
        D = np.zeros((C.shape[0], B.shape[1]))
    D = np.asarray(D, dtype=float).reshape(C.shape[0], B.shape[1])
    return A, B, C, D


def _require_hurwitz(A):
    lam = np.linalg.eigvals(A)
    if np.max(lam.real) >= 0.0:
        raise RobustDrakeError(
            f"H-infinity norm needs a Hurwitz A; max Re(eig(A)) = {np.max(lam.real):.6g} >= 0 "
            "(the norm is infinite or undefined)"
        )
    return lam


def frequency_response_gain(A, B, C, D, omega):
    """``sigma_max(G(j omega))`` for each frequency in ``omega`` (rad/s)."""
    A, B, C, D = _as_ss(A, B, C, D)
    n = A.shape[0]
    out = np.empty(len(omega))
    for k, w in enumerate(omega):
        G = C @ np.linalg.solve(1j * w * np.eye(n) - A, B) + D
        out[k] = np.linalg.svd(G, compute_uv=False)[0]
    return out


def hamiltonian_has_imaginary_eigs(A, B, C, D, gamma):
    """True if ``H(gamma)`` (module docstring) has an eigenvalue on the imaginary axis, i.e. if
    ``sigma_max(G(j w)) >= gamma`` somewhere.

    Decided to rounding (``analysis.tolerance``): candidates are the eigenvalues with
    ``|Re lambda| <= 10 eps kappa(lambda) ||H||``; near the peak the two crossing eigenvalues
    form a Jordan pair (kappa -> inf), so a candidate is confirmed by evaluating the gain at its
    frequency and at the midpoints between candidate frequencies (the gain exceeds gamma between
    two crossings): confirmed if ``sigma_max >= gamma (1 - certificate_tol(cond(j w I - A)))``.
    """
    A, B, C, D = _as_ss(A, B, C, D)
    m = B.shape[1]
    p = C.shape[0]
    R = gamma**2 * np.eye(m) - D.T @ D
    Ri = np.linalg.inv(R)
    Ah = A + B @ Ri @ D.T @ C
    H = np.block(
        [
            [Ah, B @ Ri @ B.T],
            [-C.T @ (np.eye(p) + D @ Ri @ D.T) @ C, -Ah.T],
        ]
    )
    on_axis, lam = on_imaginary_axis(H)
    if not np.any(on_axis):
        return False, lam
    w = np.unique(np.abs(lam[on_axis].imag))
    w = np.concatenate([w, 0.5 * (w[1:] + w[:-1])])
    n = A.shape[0]
    for wk, g in zip(w, frequency_response_gain(A, B, C, D, w)):
        if g >= gamma * (1.0 - certificate_tol(np.linalg.cond(1j * wk * np.eye(n) - A))):
            return True, lam
    return False, lam


@dataclass
class HinfResult:
    norm: float
    omega_peak: float  # frequency of the peak found by the sweep (rad/s)
    lower: float  # final bisection bracket
    upper: float
    iterations: int


def hinf_norm_hamiltonian(A, B, C, D=None, rtol=1e-10, n_sweep=400):
    """``||G||_inf`` by a log frequency sweep refined by Hamiltonian bisection.

    The sweep (``n_sweep`` points over four decades either side of the spectrum of A, plus
    omega = 0) gives a lower bound ``lb`` attained at ``omega_peak``; the upper bound is found by
    doubling until ``H(gamma)`` has no imaginary-axis eigenvalue, then bisection to ``rtol``.
    """
    A, B, C, D = _as_ss(A, B, C, D)
    lam = _require_hurwitz(A)
    wmag = np.abs(lam)
    lo_w = max(np.min(wmag), 1e-6) * 1e-4
    hi_w = max(np.max(wmag), 1e-6) * 1e4
    omega = np.concatenate([[0.0], np.logspace(np.log10(lo_w), np.log10(hi_w), n_sweep), np.abs(lam.imag)])
    gains = frequency_response_gain(A, B, C, D, omega)
    k = int(np.argmax(gains))
    lb = max(float(gains[k]), float(np.linalg.svd(D, compute_uv=False)[0]) if D.size else 0.0)
    if lb == 0.0:
        return HinfResult(0.0, float(omega[k]), 0.0, 0.0, 0)
    ub = lb * 1.001
    it = 0
    while hamiltonian_has_imaginary_eigs(A, B, C, D, ub)[0]:
        ub *= 2.0
        it += 1
        if it > 200:
            raise SolverError("Hamiltonian bisection did not find an upper bound for the H-infinity norm")
    while (ub - lb) > rtol * ub:
        mid = 0.5 * (lb + ub)
        if hamiltonian_has_imaginary_eigs(A, B, C, D, mid)[0]:
            lb = mid
        else:
            ub = mid
        it += 1
    return HinfResult(0.5 * (lb + ub), float(omega[k]), lb, ub, it)


def sym_basis(n):
    """Basis of the symmetric n x n matrices (upper-triangle order), for numeric LMIs."""
    basis = []
    for i in range(n):
        for j in range(i, n):
            E = np.zeros((n, n))
            E[i, j] = E[j, i] = 1.0
            basis.append(E)
    return basis


def sym_from_vec(x, n):
    X = np.zeros((n, n))
    k = 0
    for i in range(n):
        for j in range(i, n):
            X[i, j] = X[j, i] = x[k]
            k += 1
    return X


def solve_program(prog, solver="clarabel"):
    """Solve with a bundled Drake solver by name (``clarabel``, ``scs``, ``csdp``); raise on failure."""
    from pydrake.solvers import ClarabelSolver, CsdpSolver, ScsSolver, SolverOptions

    solvers = {"clarabel": ClarabelSolver, "scs": ScsSolver, "csdp": CsdpSolver}
    if solver not in solvers:
        raise RobustDrakeError(f"unknown SDP solver {solver!r}; choose one of {sorted(solvers)}")
    s = solvers[solver]()
    if not (s.available() and s.enabled()):
        raise SolverError(f"solver {solver} is not available in this Drake build")
    opts = SolverOptions()
    if solver == "csdp":
        from pydrake.solvers import RemoveFreeVariableMethod

        opts.SetOption(CsdpSolver().solver_id(), "drake::RemoveFreeVariableMethod",
                       int(RemoveFreeVariableMethod.kTwoSlackVariables))
    result = s.Solve(prog, None, opts)
    from robust_drake.log import debug_solve

    debug_solve("norm-bound SDP", result)
    if not result.is_success():
        raise SolverError(f"{solver} failed: {result.get_solution_result()}")
    return result


def hinf_norm_lmi(A, B, C, D=None, solver="clarabel"):
    """``||G||_inf`` from the bounded-real (KYP) LMI of the module docstring, via ``MathematicalProgram``.

    Returns ``(norm, X)``. The LMI is written with numeric coefficient matrices
    (``AddLinearMatrixInequalityConstraint(F, vars)``: ``F0 + sum x_i F_i >= 0``).
    """
    from pydrake.solvers import MathematicalProgram

    A, B, C, D = _as_ss(A, B, C, D)
    _require_hurwitz(A)
    n, m, p = A.shape[0], B.shape[1], C.shape[0]
    N = n + m + p
    prog = MathematicalProgram()
    xv = prog.NewContinuousVariables(n * (n + 1) // 2, "X")
    g = prog.NewContinuousVariables(1, "g")
    # -[[A^T X + X A, X B, C^T], [B^T X, -g I, D^T], [C, D, -g I]] >= 0
    F0 = np.zeros((N, N))
    F0[n + m:, :n] = -C
    F0[:n, n + m:] = -C.T
    F0[n + m:, n:n + m] = -D
    F0[n:n + m, n + m:] = -D.T
    F = [F0]
    for E in sym_basis(n):
        Fi = np.zeros((N, N))
        Fi[:n, :n] = -(A.T @ E + E @ A)
        Fi[:n, n:n + m] = -E @ B
        Fi[n:n + m, :n] = -B.T @ E
        F.append(Fi)
    Fg = np.zeros((N, N))
    Fg[n:, n:] = np.eye(m + p)
    F.append(Fg)
    prog.AddLinearMatrixInequalityConstraint(F, np.concatenate([xv, g]))
    prog.AddLinearCost(np.array([1.0]), g)
    result = solve_program(prog, solver)
    X = sym_from_vec(result.GetSolution(xv), n)
    return float(result.GetSolution(g)[0]), X
