"""Full column rank of the uncertain regression matrix for every admissible uncertainty (CI section 3).

Calafiore & Indri (seeds/000, after eq. 4) assume that the stacked regressor ``A = D(delta)`` has full
column rank for any value of the uncertainty, and note that "this condition may be checked via a
sufficient LMI condition". With the affine LFR of eq. 18, ``D(delta) = D0 + L Delta R_D`` (Delta =
diag(delta_i I_{r_i}), |delta_i| <= 1, ``UncertaintyModel.lfr`` restricted to the m regressor columns),
write ``p = Delta R_D x``; channel block i obeys ``|p_i|^2 <= |R_i x|^2``. By the S-procedure, if scalars
``s_i >= 0`` and ``mu > 0`` make

    [[D0^T D0 - R_D^T S R_D - mu I,  D0^T L     ],
     [L^T D0,                        L^T L + S  ]]  >= 0,      S = diag(s_i I_{r_i}),

then ``|D(delta) x|^2 >= mu |x|^2`` for every x and every delta in the box, i.e.
``sigma_min(D(delta)) >= sqrt(mu)`` (full column rank, with a margin). The LMI is solved with Drake's
``MathematicalProgram`` (Clarabel) maximising mu; the certificate is then re-derived without the solver:
for the returned s the largest admissible mu is the smallest eigenvalue of the Schur complement
``D0^T D0 - R_D^T S R_D - D0^T L (L^T L + S)^-1 L^T D0``, accepted when it exceeds its rounding
tolerance (``analysis.tolerance.psd_tol`` times the conditioning of ``L^T L + S``).

The test is sufficient only (the scalings are scalar per block). A sampled check complements it: a
vertex or random delta whose ``D(delta)`` is rank deficient to rounding refutes the assumption.
Verdicts: "certified", "refuted", "undecided". The check is on the linearised model of CI section 5
(the same model the ellipsoid SDP uses).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from robust_drake.analysis.tolerance import certificate_tol, psd_tol
from robust_drake.errors import RobustDrakeError

#: above this many LFR channels the dense LMI is not attempted (the SDP grows as channels^2)
MAX_CHANNELS = 600


@dataclass
class FullRankResult:
    verdict: str                 # "certified" | "refuted" | "undecided" | "skipped"
    sigma_min_bound: float       # certified lower bound on sigma_min(D(delta)) over the box (0 if none)
    sigma_min_nominal: float     # sigma_min(D0)
    sigma_min_sampled: float     # smallest sigma_min(D(delta)) over the sampled deltas
    n_channels: int
    n_scalars: int
    draws: int
    solver_status: str
    reason: str = ""

    def to_dict(self) -> dict:
        return asdict(self)


def full_rank_lmi(D0, L, R, scalars, n_scalars: int | None = None):
    """Solve the S-procedure LMI (module docstring) for ``D(delta) = D0 + L diag(delta[scalars]) R``.

    Args:
        D0: (a, m) nominal matrix; L: (a, c); R: (c, m); scalars: (c,) scalar index of each channel.
    Returns:
        (s, mu_cert, status): per-scalar multipliers, the re-derived certified ``mu`` (may be <= 0:
        nothing certified) and the solver status.
    """
    from pydrake.solvers import ClarabelSolver, MathematicalProgram

    D0, L, R = (np.atleast_2d(np.asarray(a, float)) for a in (D0, L, R))
    scalars = np.asarray(scalars, int)
    a, m = D0.shape
    c = L.shape[1]
    if c == 0:
        return np.zeros(0), float(np.linalg.eigvalsh(D0.T @ D0)[0]), "no uncertainty"
    n_s = int(scalars.max()) + 1 if n_scalars is None else int(n_scalars)
    # scale so that ||D0|| = 1 (the LMI is homogeneous in (D0, L) and mu)
    scale = float(np.linalg.norm(D0, 2)) or 1.0
    D0s, Ls = D0 / scale, L / scale
    used = np.unique(scalars)
    prog = MathematicalProgram()
    s = prog.NewContinuousVariables(len(used), "s")
    mu = prog.NewContinuousVariables(1, "mu")[0]
    prog.AddBoundingBoxConstraint(0.0, 1e6, s)
    prog.AddBoundingBoxConstraint(-10.0, 10.0, mu)
    d = m + c
    F0 = np.zeros((d, d))
    F0[:m, :m] = D0s.T @ D0s
    F0[:m, m:] = D0s.T @ Ls
    F0[m:, :m] = Ls.T @ D0s
    F0[m:, m:] = Ls.T @ Ls
    Fs = []
    for u in used:
        ch = np.flatnonzero(scalars == u)
        Fi = np.zeros((d, d))
        Fi[:m, :m] = -R[ch].T @ R[ch]
        Fi[m + ch, m + ch] = 1.0
        Fs.append(Fi)
    Fmu = np.zeros((d, d))
    Fmu[:m, :m] = -np.eye(m)
    prog.AddLinearMatrixInequalityConstraint([F0, *Fs, Fmu], [*s, mu])
    prog.AddLinearCost(-mu)
    res = ClarabelSolver().Solve(prog)
    from robust_drake.log import debug_solve

    debug_solve("full-rank certificate SDP", res)
    status = str(res.get_solution_result()).split(".")[-1]
    s_val = np.clip(res.GetSolution(s), 0.0, None) if res.is_success() else np.zeros(len(used))
    svec = np.zeros(n_s)
    svec[used] = s_val
    return svec, schur_mu(D0, L, R, scalars, svec)[0], status


def schur_mu(D0, L, R, scalars, s) -> tuple[float, float]:
    """Largest mu for which the LMI holds at the multipliers ``s`` (solver-free) and its tolerance.

    ``mu(s) = lambda_min(D0^T D0 - R^T S R - D0^T L (L^T L + S)^-1 L^T D0)`` when ``L^T L + S > 0``;
    returns ``(mu, tol)`` with ``tol`` the rounding tolerance of that eigenvalue."""
    D0, L, R = (np.atleast_2d(np.asarray(a, float)) for a in (D0, L, R))
    Sd = np.asarray(s, float)[np.asarray(scalars, int)]
    Q = L.T @ L + np.diag(Sd)
    wq = np.linalg.eigvalsh(Q)
    if wq.size == 0:  # no uncertain regressor entry (only torque bounds): D(delta) = D0
        w = np.linalg.eigvalsh(D0.T @ D0)
        return float(w[0]), certificate_tol(1.0) * float(np.abs(w).max())
    if wq[0] <= psd_tol(wq):
        return -np.inf, 0.0
    G = D0.T @ D0 - (R.T * Sd) @ R - D0.T @ L @ np.linalg.solve(Q, L.T @ D0)
    w = np.linalg.eigvalsh(0.5 * (G + G.T))
    scale = max(float(np.linalg.norm(D0.T @ D0, 2)), float(np.abs(w).max()))
    tol = certificate_tol(wq[-1] / wq[0]) * scale
    return float(w[0]), tol


def check_full_rank(model, draws: int = 2000, seed: int = 0, max_channels: int = MAX_CHANNELS) -> FullRankResult:
    """CI's full-rank assumption on the stacked regressor of an ``UncertaintyModel`` (module docstring)."""
    from robust_drake.uncertainty.lfr import random_deltas

    m = model.n_params
    D0 = np.asarray(model.D0, float).reshape(-1, m)
    if D0.shape[0] < m:
        raise RobustDrakeError(f"{D0.shape[0]} regression rows cannot have full column rank {m}; "
                               "use more samples")
    # channels of the D part: rank of each scalar's D coefficient (tau scalars have none)
    ranks = [np.linalg.matrix_rank(model.coeffs[k, j, :, :m]) if np.any(model.coeffs[k, j, :, :m]) else 0
             for k in range(model.n_samples) for j in range(model.coeffs.shape[1])]
    n_channels = int(sum(ranks))
    sv0 = np.linalg.svd(D0, compute_uv=False)
    rng = np.random.default_rng(seed)
    deltas = random_deltas(model.n_scalars, draws, rng)
    smin = np.inf
    refuted = False
    for dlt in deltas:
        Dd = model.perturbed(dlt)[0]
        sv = np.linalg.svd(Dd, compute_uv=False)
        smin = min(smin, float(sv[-1]))
        if sv[-1] <= certificate_tol(max(Dd.shape)) * sv[0]:
            refuted = True
    common = dict(sigma_min_nominal=float(sv0[-1]), sigma_min_sampled=float(smin), n_channels=n_channels,
                  n_scalars=int(model.n_scalars), draws=int(draws))
    if refuted:
        return FullRankResult("refuted", 0.0, solver_status="not run",
                              reason="a sampled delta makes D(delta) rank deficient", **common)
    if n_channels > max_channels:
        return FullRankResult("skipped", 0.0, solver_status="not run",
                              reason=f"{n_channels} LFR channels > {max_channels}: dense LMI not attempted", **common)
    F = model.lfr()
    Lm, Rm = F.L, F.R[:, :m]
    keep = np.linalg.norm(Rm, axis=1) > 0          # tau channels do not enter D(delta)
    Lm, Rm, sc = Lm[:, keep], Rm[keep], F.scalars[keep]
    D0 = F.M0[:, :m]
    s, mu, status = full_rank_lmi(D0, Lm, Rm, sc, model.n_scalars)
    _, tol = schur_mu(D0, Lm, Rm, sc, s)
    if mu > tol:
        return FullRankResult("certified", float(np.sqrt(mu)), solver_status=status, **common)
    return FullRankResult("undecided", 0.0, solver_status=status,
                          reason="the sufficient LMI is infeasible and no sampled delta is rank deficient", **common)
