"""Certificates for Lemmas 1-5 of Bascetta & Rocco (BR) section IV.

Each ``lemmaK(...)`` returns a small dataclass with ``ok`` and the numbers that decide it, so a
test (or a user) can see *why* a design is admissible or not. The multi-joint objects are the
reordered system of BR section IV:

    calA = bdiag(A, ..., A),  A = [[0, 1], [-delta^2 kappa01, -delta kappa02]],
    calB = (calB_1^T ... calB_n^T)^T,  calB_i = [0_{2,i-1}  B  0_{2,n-i}],  B = [0; 1],
    calC = calB^T calA.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import scipy.linalg

from robust_drake.analysis.norms import hinf_norm_hamiltonian, hinf_norm_lmi
from robust_drake.analysis.riccati import (
    B2,
    A0_matrix,
    are_certificate,
    are_residual,
    bounded_real_are_hamiltonian,
    conditions16,
    eq17_data,
)
from robust_drake.analysis.tolerance import SDP_RTOL, certificate_tol, eig_condition
from robust_drake.errors import RobustDrakeError, SolverError


def joint_A(kappa01, kappa02, delta):
    """Per-joint error matrix A with omega_n^2 = delta^2 kappa01, 2 zeta omega_n = delta kappa02."""
    return np.array([[0.0, 1.0], [-delta**2 * kappa01, -delta * kappa02]])


def big_system(kappa01, kappa02, delta, n):
    """``(calA, calB, calC)`` of BR section IV for n joints (epsilon ordering)."""
    A = joint_A(kappa01, kappa02, delta)
    calA = scipy.linalg.block_diag(*([A] * n))
    calB = np.zeros((2 * n, n))
    for i in range(n):
        calB[2 * i:2 * i + 2, i:i + 1] = B2
    return calA, calB, calB.T @ calA


@dataclass
class Certificate:
    lemma: int
    ok: bool
    numbers: dict

    def to_dict(self):
        return asdict(self)


def lemma1(kappa01, kappa02, delta=1.0, n=2) -> Certificate:
    """Lemma 1: calA + delta I Hurwitz for all delta iff (16). Returns max Re(eig) for the given
    delta and for A0 + I (the delta-free statement: eig(A + delta I) = delta eig(A0 + I))."""
    calA, _, _ = big_system(kappa01, kappa02, delta, n)
    Ad = calA + delta * np.eye(2 * n)
    lam, kappa = eig_condition(Ad)
    lam0 = np.linalg.eigvals(A0_matrix(kappa01, kappa02) + np.eye(2))
    ok = bool(np.max(lam.real) < 0 and np.max(lam0.real) < 0)
    return Certificate(1, ok, {
        "max_real_eig": float(np.max(lam.real)),
        "max_real_eig_A0_plus_I": float(np.max(lam0.real)),
        "conditions16": conditions16(kappa01, kappa02),
        "scaling_error": float(np.max(np.abs(np.sort_complex(lam) - np.sort_complex(np.tile(delta * lam0, n))))),
        # eigenvalues are accurate to eps kappa(lambda) ||Ad|| (both sides: factor 2)
        "scaling_tol": 2 * certificate_tol(float(np.max(kappa))) * float(np.linalg.norm(Ad)),
    })


def lemma2(kappa01, kappa02, delta=1.0, n=2, solver="clarabel", rtol=SDP_RTOL) -> Certificate:
    """Lemma 2: ||T_delta||_inf = ||t||_inf, t(s) = B^T A0 [sI - (A0 + I)]^{-1} B.

    ||t||_inf two ways (Hamiltonian bisection, KYP LMI) and ||T_delta||_inf of the n-joint MIMO
    system ``T_delta(s) = -calB^T calA [sI - (calA + delta I)]^{-1} calB`` by the Hamiltonian.
    Fails (ok False, norms inf) when A0 + I is not Hurwitz.
    """
    if not lemma1(kappa01, kappa02, delta, n).ok:
        return Certificate(2, False, {"t_norm_hamiltonian": float("inf"), "t_norm_lmi": float("inf"),
                                      "T_delta_norm": float("inf"), "reason": "A0 + I not Hurwitz"})
    A, B, C = eq17_data(kappa01, kappa02)
    th = hinf_norm_hamiltonian(A, B, C)
    try:
        tl, _ = hinf_norm_lmi(A, B, C, solver=solver)
    except SolverError as exc:  # pragma: no cover - reported, not hidden
        tl = float("nan")
    calA, calB, calC = big_system(kappa01, kappa02, delta, n)
    Ad = calA + delta * np.eye(2 * n)
    Th = hinf_norm_hamiltonian(Ad, calB, -calC)
    # Both norms are bisection results (relative bracket width 1e-10 each) of a quantity whose
    # rounding sensitivity is cond(j w_peak I - Ad) (the resolvent at the peak).
    w = Th.omega_peak
    cond_peak = np.linalg.cond(1j * w * np.eye(2 * n) - Ad)
    tol_T = 2 * (Th.upper - Th.lower) / Th.upper + 2 * (th.upper - th.lower) / th.upper + certificate_tol(cond_peak)
    ok = bool(abs(th.norm - tl) <= rtol * th.norm and abs(th.norm - Th.norm) <= tol_T * th.norm)
    return Certificate(2, ok, {
        "t_norm_hamiltonian": th.norm, "t_norm_lmi": tl, "T_delta_norm": Th.norm,
        "T_vs_t_rel_diff": abs(th.norm - Th.norm) / th.norm, "T_vs_t_tol": tol_T,
        "omega_peak_t": th.omega_peak, "omega_peak_T": Th.omega_peak,
        "gamma_max": 1.0 / th.norm,
    })


def lemma3(kappa01, kappa02, delta=1.0, n=2) -> Certificate:
    """Lemma 3: (calA + delta I, calC) observable iff kappa01 != 0.

    PBH test: ``min over eigenvalues lambda of sigma_min([lambda I - Ad; calC])``, scaled by
    ``||Ad|| + ||calC||`` (the Kalman observability matrix is too ill-conditioned to rank).
    Rank decision to rounding: a computed eigenvalue is off by ``eps kappa(lambda) ||Ad||``, which
    moves sigma_min by as much, so the pair is observable when the scaled sigma_min exceeds
    ``certificate_tol(max kappa(lambda))`` (``analysis.tolerance``)."""
    calA, _, calC = big_system(kappa01, kappa02, delta, n)
    Ad = calA + delta * np.eye(2 * n)
    scale = np.linalg.norm(Ad, 2) + np.linalg.norm(calC, 2)
    worst = np.inf
    lams, kappa = eig_condition(Ad)
    for lam in lams:
        M = np.vstack([lam * np.eye(2 * n) - Ad, calC])
        worst = min(worst, np.linalg.svd(M, compute_uv=False)[-1])
    rel = float(worst / scale)
    tol = certificate_tol(float(np.max(kappa)))
    return Certificate(3, bool(rel > tol), {"pbh_sigma_min_rel": rel, "tol": tol})


def lemma4(kappa01, kappa02, delta, gamma, n=2) -> Certificate:
    """Lemma 4: the stabilising solution of eq. 18 (solved directly, 2n x 2n) equals
    ``bdiag(Pi, ..., Pi)``, ``Pi = delta Bb P0 Bb``, Bb = diag(delta, 1), P0 from eq. 17."""
    calA, calB, calC = big_system(kappa01, kappa02, delta, n)
    Ad = calA + delta * np.eye(2 * n)
    try:
        Pfull, cond_full = bounded_real_are_hamiltonian(Ad, calB, calC, gamma, with_cond=True)
        A, B, C = eq17_data(kappa01, kappa02)
        P0, cond0 = bounded_real_are_hamiltonian(A, B, C, gamma, with_cond=True)
    except SolverError as exc:
        return Certificate(4, False, {"reason": str(exc)})
    Bb = np.diag([delta, 1.0])
    Pi = delta * Bb @ P0 @ Bb
    Pblock = scipy.linalg.block_diag(*([Pi] * n))
    return lemma4_compare(Ad, calB, calC, gamma, Pfull, cond_full, Pblock, cond0 * np.linalg.cond(Bb) ** 2,
                          conditions16(kappa01, kappa02), Pi)


def lemma4_compare(Ad, calB, calC, gamma, Pfull, cond_full, Pblock, cond_block, ok16, Pi=None) -> Certificate:
    """The decision of :func:`lemma4` for given matrices (so a test can hand it a wrong P).

    ``Pfull`` and ``Pblock`` are two computed solutions of eq. 18, accurate to
    ``certificate_tol(cond_full)`` and ``certificate_tol(cond_block)`` relative (condition numbers
    of the Hamiltonian-Schur solves, ``tolerance.schur_are_condition``); they agree when their
    relative difference is within the sum. Pblock must also pass the residual certificate of
    eq. 18 (``riccati.are_certificate``: Newton step from the residual), and the stabilising solution must be PSD (Lemma 5, needs eq. 16)."""
    err = float(np.linalg.norm(Pfull - Pblock) / np.linalg.norm(Pfull))
    tol = certificate_tol(cond_full) + certificate_tol(cond_block)
    res = are_certificate(Ad, calB, calC, gamma, Pblock, max(cond_full, cond_block))
    min_eig = float(np.min(np.linalg.eigvalsh(Pfull)))
    # The block identity is algebraic; the lemma is about the PSD stabilising solution, which needs (16).
    ok = bool(err <= tol and res["ok"] and ok16 and min_eig >= -certificate_tol() * np.linalg.norm(Pfull, 2))
    return Certificate(4, ok, {
        "rel_diff": err, "tol": tol, "cond_full": float(cond_full), "cond_block": float(cond_block),
        "eq18_newton_step_rel": res["newton_step_rel"], "eq18_backward_error": res["backward_error"],
        "eq18_tol": res["tol"], "min_eig_P": min_eig,
        "conditions16": bool(ok16), "Pi": (Pi if Pi is not None else Pblock[:2, :2]).tolist()})


def lemma5(kappa01, kappa02, gamma) -> Certificate:
    """Lemma 5: if ||t||_inf <= 1/gamma the stabilising P0 of eq. 17 exists, is PSD (PD when
    observable) and eig(P0) > 1. Returns the eigenvalues, ||t||_inf * gamma and the closed-loop
    spectral abscissa of ``A0 + I + gamma^2 B B^T P0`` (negative = stabilising)."""
    if not conditions16(kappa01, kappa02):
        return Certificate(5, False, {"reason": "A0 + I not Hurwitz (eq. 16 fails)"})
    A, B, C = eq17_data(kappa01, kappa02)
    tn = hinf_norm_hamiltonian(A, B, C).norm
    try:
        P0, cond = bounded_real_are_hamiltonian(A, B, C, gamma, with_cond=True)
    except SolverError as exc:
        return Certificate(5, False, {"t_norm_times_gamma": tn * gamma, "reason": str(exc)})
    eig = np.linalg.eigvalsh(P0)
    cl = np.max(np.linalg.eigvals(A + gamma**2 * B @ B.T @ P0).real)
    res = are_certificate(A, B, C, gamma, P0, cond)
    ok = bool(tn * gamma <= 1.0 and eig[0] > 1.0 and cl < 0 and res["ok"])
    return Certificate(5, ok, {"eig_P0": eig.tolist(), "t_norm_times_gamma": tn * gamma,
                               "closed_loop_abscissa": float(cl),
                               "residual": are_residual(A, B, C, gamma, P0),
                               "newton_step_rel": res["newton_step_rel"], "backward_error": res["backward_error"],
                               "residual_tol": res["tol"]})


def check_all(kappa01, kappa02, delta, gamma, n=2, solver="clarabel") -> dict:
    """All five certificates as a dict ``{"lemma1": {...}, ...}``."""
    certs = [lemma1(kappa01, kappa02, delta, n), lemma2(kappa01, kappa02, delta, n, solver=solver),
             lemma3(kappa01, kappa02, delta, n), lemma4(kappa01, kappa02, delta, gamma, n),
             lemma5(kappa01, kappa02, gamma)]
    return {f"lemma{c.lemma}": c.to_dict() for c in certs}
