"""Case A of Bascetta & Rocco (BR) section II-B: the classical Lyapunov design.

Error e = (q_d - q, qd_d - qd) in R^{2n}, eq. 6: ``e' = A e + B (eta - w)`` with

    A = [[0, I], [-K_P, -K_D]],   B = [0; I],

P > 0 solves the Lyapunov equation ``A^T P + P A = -Q`` (solved with Drake's
``RealContinuousLyapunovEquation``), and the robust term uses ``z = B^T P e`` (eq. 8).
The paper leaves Q free; we use Q = I_{2n} unless told otherwise (BUILD_NOTES).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from robust_drake.errors import RobustDrakeError


def error_matrices(K_P, K_D):
    """``(A, B)`` of BR eq. 6 for diagonal (or vector) gains."""
    kp = np.atleast_1d(np.diag(K_P) if np.ndim(K_P) == 2 else K_P).astype(float)
    kd = np.atleast_1d(np.diag(K_D) if np.ndim(K_D) == 2 else K_D).astype(float)
    if kp.shape != kd.shape:
        raise RobustDrakeError(f"K_P and K_D sizes differ: {kp.shape} vs {kd.shape}")
    if np.any(kp <= 0) or np.any(kd <= 0):
        raise RobustDrakeError("K_P and K_D must be positive definite (BR eq. 5)")
    n = len(kp)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-np.diag(kp), -np.diag(kd)]])
    B = np.vstack([np.zeros((n, n)), np.eye(n)])
    return A, B


@dataclass
class LyapunovDesign:
    A: np.ndarray
    B: np.ndarray
    Q: np.ndarray
    P: np.ndarray
    BtP: np.ndarray  # z = BtP @ e
    residual: float  # ||A^T P + P A + Q||_F
    K_norm: float  # ||diag(K_P, K_D)||_2, enters beta_1 of eq. 13


def lyapunov_design(K_P, K_D, Q=None) -> LyapunovDesign:
    """Case A: P of ``A^T P + P A = -Q`` with Drake's ``RealContinuousLyapunovEquation``."""
    from pydrake.math import RealContinuousLyapunovEquation

    A, B = error_matrices(K_P, K_D)
    n2 = A.shape[0]
    Q = np.eye(n2) if Q is None else np.asarray(Q, float)
    if Q.shape != (n2, n2) or np.min(np.linalg.eigvalsh(0.5 * (Q + Q.T))) <= 0:
        raise RobustDrakeError(f"Q must be symmetric positive definite {n2}x{n2}")
    P = RealContinuousLyapunovEquation(A, Q)
    P = 0.5 * (P + P.T)
    res = float(np.linalg.norm(A.T @ P + P @ A + Q))
    kp = -np.diag(A[n2 // 2:, : n2 // 2])
    kd = -np.diag(A[n2 // 2:, n2 // 2:])
    K_norm = float(max(np.max(kp), np.max(kd)))
    return LyapunovDesign(A, B, Q, P, B.T @ P, res, K_norm)
