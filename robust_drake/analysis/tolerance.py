"""Tolerances of numerical certificates: machine epsilon times a condition number.

A certificate ("this P solves eq. 18", "this Hamiltonian has an eigenvalue on the imaginary
axis", "this P is symmetric") compares a computed number with an exact statement. The computed
number is wrong by rounding, and by how much depends on the problem, not on the machine: a
backward-stable algorithm returns the exact answer of a problem perturbed by ~``p(n) eps`` relative
to its data, so the forward error is ``p(n) eps * cond`` with ``cond`` the problem's condition
number (Higham, *Accuracy and Stability of Numerical Algorithms*, 2nd ed., ch. 1). A fixed
threshold (``1e-8``) is therefore too tight on an ill-conditioned problem (a correct answer is
rejected: BR Lemma 4 at kappa = (120, 2.5), cond ~ 5e7, failed on one machine and passed on
another) and too loose on a well-conditioned one (a wrong answer passes).

The rule, used by every certificate in the package::

    tol = ROUND_C * eps * max(1, cond)        (relative to the size of the quantity checked)

* ``eps = 2.2e-16`` (float64 unit roundoff times 2, ``np.finfo(float).eps``).
* ``ROUND_C = 10``: the dimension factor ``p(n)`` of the backward error bounds for the matrices
  met here (n <= 16: QR / Schur / eigh / SVD of 2x2 .. 16x16) is taken as a constant. Measured on
  the BR grid (BUILD_NOTES "Certificate tolerances"): the worst forward error of the
  Hamiltonian-Schur Riccati solve is 0.14 eps cond, so 10 leaves a factor ~70, while a
  perturbation of 1e-6 relative is still ~1000x the tolerance at the worst conditioning met.

Condition numbers provided here (all small dense problems, computed exactly rather than estimated):

* :func:`eig_condition`: ``kappa(lambda) = ||x|| ||y|| / |y^H x|`` of each eigenvalue (Wilkinson):
  a computed eigenvalue is within ``eps ||M|| kappa(lambda)`` of an exact one.
* :func:`schur_are_condition`: the Riccati solution ``P = X2 X1^-1`` from the stable invariant
  subspace of a Hamiltonian H: the subspace is accurate to ``eps ||H|| / sep(T11, T22)``
  (Stewart 1973) and forming P amplifies that by ``cond(X1)``.
* :func:`symmetric_tol`, :func:`psd_tol`: a symmetric matrix computed by rounding is symmetric,
  and its eigenvalues are exact, to ``eps ||M||`` (cond = 1 for a symmetric eigenproblem).

Solver accuracies are not rounding: :data:`SDP_RTOL` is the agreement expected from an
interior-point SDP solve (Clarabel / SCS stop at relative gaps ~1e-8 on the objective, the
solution itself is accurate to about its square root).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

EPS = float(np.finfo(float).eps)
ROUND_C = 10.0
SDP_RTOL = 1e-5


def certificate_tol(cond: float = 1.0, c: float = ROUND_C) -> float:
    """Relative tolerance ``c * eps * max(1, cond)`` of a certificate whose problem has condition
    number ``cond`` (module docstring). ``cond`` = inf or nan gives inf (nothing certifiable)."""
    cond = float(cond)
    if not np.isfinite(cond):
        return float("inf")
    return c * EPS * max(1.0, cond)


def eig_condition(M) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues of M and their condition numbers ``||x|| ||y|| / |y^H x|`` (inf if defective)."""
    lam, yl, xr = scipy.linalg.eig(np.asarray(M, float), left=True, right=True)
    dots = np.abs(np.einsum("ij,ij->j", yl.conj(), xr))
    norms = np.linalg.norm(yl, axis=0) * np.linalg.norm(xr, axis=0)
    with np.errstate(divide="ignore"):
        kappa = np.where(dots > 0, norms / np.maximum(dots, 1e-300), np.inf)
    return lam, kappa


def on_imaginary_axis(M, c: float = ROUND_C) -> tuple[np.ndarray, np.ndarray]:
    """Mask of the eigenvalues of M whose real part is zero to rounding:
    ``|Re lambda| <= c eps kappa(lambda) ||M||_F``. Returns ``(mask, eigenvalues)``."""
    lam, kappa = eig_condition(M)
    scale = np.linalg.norm(M)
    tol = np.array([certificate_tol(k, c) for k in kappa]) * scale
    return np.abs(lam.real) <= tol, lam


def sep(T11, T22) -> float:
    """``sep(T11, T22) = sigma_min(I kron T11 - T22^T kron I)`` (Stewart): the smallest change
    that makes the two diagonal blocks of a Schur form share an eigenvalue."""
    n1, n2 = T11.shape[0], T22.shape[0]
    K = np.kron(np.eye(n2), T11) - np.kron(T22.T, np.eye(n1))
    return float(np.linalg.svd(K, compute_uv=False)[-1])


def schur_are_condition(T, Z, n: int) -> float:
    """Condition number of ``P = X2 X1^-1`` from an ordered Schur form ``H = Z T Z^T`` whose
    leading n columns of Z span the stable subspace: ``||T||_F / sep(T11, T22) * cond(X1)``."""
    s = sep(T[:n, :n], T[n:, n:])
    if s == 0.0:
        return float("inf")
    return float(np.linalg.norm(T) / s * np.linalg.cond(Z[:n, :n]))


def symmetric_tol(M, c: float = ROUND_C) -> float:
    """Absolute tolerance on ``|M - M^T|`` entries for a matrix that should be symmetric up to
    rounding: ``c eps max|M|``. A P read from JSON or assembled from symmetric terms is exactly
    or nearly exactly symmetric; anything beyond this is a different matrix."""
    return certificate_tol(1.0, c) * float(np.max(np.abs(M))) if np.size(M) else 0.0


def is_symmetric(M, c: float = ROUND_C) -> bool:
    M = np.asarray(M, float)
    return bool(M.shape[0] == M.shape[1] and np.all(np.abs(M - M.T) <= symmetric_tol(M, c)))


def psd_tol(eigenvalues, c: float = ROUND_C) -> float:
    """How negative the smallest computed eigenvalue of a PSD matrix may be from rounding alone:
    ``c eps max|lambda|`` (eigenvalues of a symmetric matrix are perfectly conditioned)."""
    w = np.asarray(eigenvalues, float)
    return certificate_tol(1.0, c) * float(np.max(np.abs(w))) if w.size else 0.0


def are_backward_error(A, G, Q, P, residual_norm: float) -> float:
    """Normwise backward error of a Riccati solution: ``||R(P)|| / (||Q|| + 2 ||A|| ||P|| +
    ||G|| ||P||^2)`` (Frobenius) for ``A^T P + P A + P G P + Q = R(P)``; a backward-stable solve
    leaves it at ``O(eps)`` regardless of conditioning, so it is compared with
    ``certificate_tol(1)`` times the residual-amplification ``cond``."""
    nP = np.linalg.norm(P)
    scale = np.linalg.norm(Q) + 2 * np.linalg.norm(A) * nP + np.linalg.norm(G) * nP**2
    return float(residual_norm / scale) if scale > 0 else float(residual_norm)
