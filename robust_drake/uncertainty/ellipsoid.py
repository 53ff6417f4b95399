"""Confidence ellipsoid for the least-squares solutions of uncertain linear equations.

El Ghaoui & Calafiore (CDC 1999), as used by Calafiore & Indri (CI, seeds/000) sections 3-5:
find ``E(P, theta0) = {theta : (theta - theta0)^T P^-1 (theta - theta0) <= 1}`` of minimal
trace(P) containing every solution of the normal equations

    A(Delta) x = b(Delta),   [A b](Delta) = [A0 b0] + L Delta (I - H Delta)^-1 [R_A R_b]   (CI eqs. 2-4)

for every Delta = diag(delta_i I_{r_i}), |delta_i| <= 1.

Derivation used here (S-procedure with D-G scalings). With p = Delta q,
q = R_A x - R_b t + H p and the homogenising variable t, x is a solution iff
xi = (x, t, p) satisfies ``C xi := A0 x - b0 t + L p = 0`` (t = 1) and p_i = delta_i q_i.
For every block, S_i = S_i^T >= 0 and G_i = -G_i^T give
``phi_i = q_i^T S_i q_i - p_i^T S_i p_i + 2 q_i^T G_i p_i >= 0`` (real repeated scalars). Then

    t^2 - (x - theta0 t)^T P^-1 (x - theta0 t) - sum_i phi_i >= 0    on ker C

implies containment; with a Schur complement this is an LMI in (P, theta0, S, G).

Two formulations, the same mathematics:

* ``"full"``: restrict to ker C with an orthonormal null-space basis N (one dense LMI of size
  dim(ker C) + m). Its size grows with the number of LFR channels (59 at the paper's 5
  samples, ~10 n_m + 9 in general); dense, for small problems and cross-checks.
* ``"chordal"`` (default): Finsler's lemma with a multiplier Y acting on the head
  h = (x, t) only, ``Omega + Y C + C^T Y^T >= 0``. Because each sample's uncertainties enter
  only that sample's channels, Omega + YC + C^TY^T has an arrow pattern (head h coupled to
  every sample's channels, samples not coupled to each other). An arrow pattern is chordal,
  so the big LMI is equivalent (Agler / Grone et al.) to one small LMI per clique
  {h, p_g} plus one for {h, P}, linked by splitting matrices U_g of the head block
  (sum U = 0). The head-only multiplier loses nothing when the per-sample quadratic blocks
  are definite (the optimal Lagrange multiplier of the coupling equality is linear in h);
  the benchmark measures the two formulations side by side (BUILD_NOTES "Calafiore & Indri").

  Why not constraint generation over samples: dropping a sample's LMI is the same problem with
  that sample's deltas fixed at 0 (its U_g >= -H_g >= 0, so the rest stays feasible): a
  relaxation. Every sample's uncertainty moves the LS solutions, so every clique is binding:
  at 20 IMI samples, dropping 1 / 5 / 10 random samples' LMIs lowers the optimal trace to 0.93 /
  0.64 / 0.29 of the full one (``bench_ellipsoid.py --relax 20:19,15,10``). An active set would
  grow to all samples before it could stop.

Scaling: theta is scaled by the column norms of D and the torques by the size of the LS
estimate before the SDP, and mapped back after; trace(P) becomes a weighted trace, the same
optimum. Solvers: Drake's bundled Clarabel, SCS, CSDP through ``MathematicalProgram``, or
cvxpy (Clarabel/SCS) for cross-checks. Every solve is certified by sampling (``certify``).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from robust_drake.analysis.tolerance import SDP_RTOL, certificate_tol, is_symmetric
from robust_drake.errors import RobustDrakeError, SolverError
from robust_drake.uncertainty.lfr import LFR, random_deltas
from robust_drake.uncertainty.regression import UncertaintyModel

SOLVERS = ("clarabel", "scs", "csdp")
FORMULATIONS = ("chordal", "full", "energy", "auto")
AUTO_ENERGY_ABOVE = 200     # "auto": chordal SDP up to this many samples (~25 s), closed-form bound above


# ============================================================================ data types
@dataclass
class Ellipsoid:
    """E(P, theta0) (CI notation; E^T E = P)."""

    theta0: np.ndarray
    P: np.ndarray

    def __post_init__(self):
        self.theta0 = np.asarray(self.theta0, dtype=float).reshape(-1)
        self.P = np.asarray(self.P, dtype=float)
        m = self.theta0.size
        if self.P.shape != (m, m):
            raise RobustDrakeError(f"P must be {m}x{m} for theta0 of length {m}, got {self.P.shape}")
        if not np.all(np.isfinite(self.P)) or not np.all(np.isfinite(self.theta0)):
            raise RobustDrakeError("theta0 and P must be finite")
        if not is_symmetric(self.P):  # to rounding, relative to the size of P (analysis.tolerance)
            raise RobustDrakeError("P must be symmetric")
        self.P = 0.5 * (self.P + self.P.T)

    @property
    def E(self) -> np.ndarray:
        """Symmetric square root E = P^(1/2) (CI section 5.2), E^T E = P."""
        w, V = np.linalg.eigh(self.P)
        return (V * np.sqrt(np.clip(w, 0, None))) @ V.T

    def radius(self, theta) -> np.ndarray:
        """sqrt((theta - theta0)^T P^-1 (theta - theta0)); <= 1 inside. theta (..., m)."""
        d = np.asarray(theta, dtype=float) - self.theta0
        w, V = np.linalg.eigh(self.P)
        if w[0] <= 0:
            raise RobustDrakeError("P is not positive definite")
        z = (d @ V) / np.sqrt(w)
        return np.sqrt(np.sum(z * z, axis=-1))

    def boundary_points(self, count: int, rng) -> np.ndarray:
        """Random points theta0 + E z with ||z|| = 1 (CI eq. 10 on the boundary)."""
        z = rng.normal(size=(count, self.theta0.size))
        z /= np.linalg.norm(z, axis=1, keepdims=True)
        return self.theta0 + z @ self.E.T

    def to_dict(self) -> dict:
        return {"theta0": self.theta0.tolist(), "P": self.P.tolist()}

    def save(self, path) -> None:
        """JSON with keys ``theta0`` and ``P``."""
        try:
            with open(path, "w") as f:
                json.dump(self.to_dict(), f, indent=2)
        except OSError as exc:
            raise RobustDrakeError(f"cannot write ellipsoid to {path}: {exc.strerror or exc}") from None

    @classmethod
    def load(cls, path) -> "Ellipsoid":
        try:
            with open(path) as f:
                d = json.load(f)
            return cls(np.array(d["theta0"]), np.array(d["P"]))
        except (OSError, KeyError, ValueError, TypeError) as exc:
            raise RobustDrakeError(f"cannot read ellipsoid from {path}: {exc} (need JSON keys 'theta0', 'P')") from exc


@dataclass
class EllipsoidResult:
    ellipsoid: Ellipsoid
    trace: float
    solver: str
    formulation: str
    status: str
    setup_seconds: float
    solve_seconds: float
    lmi_sizes: list
    n_variables: int
    min_lmi_eig: float
    eigenvalues: np.ndarray
    certificate: dict = field(default_factory=dict)

    @property
    def theta0(self):
        return self.ellipsoid.theta0

    @property
    def P(self):
        return self.ellipsoid.P


@dataclass
class SDPData:
    """min cost.x  s.t.  svec(F_l(x)) = f0_l + B_l x in PSD (upper triangle, row-major), x[nonneg] >= 0."""

    nv: int
    cost: np.ndarray
    lmis: list            # (d, f0 (ns,), B (ns, nv) csr)
    nonneg: np.ndarray
    P_idx: np.ndarray     # (m, m) variable index of P entries
    x_idx: np.ndarray     # (m,)


# ============================================================================ scaling
@dataclass
class _Scaling:
    c: np.ndarray       # theta = gamma * c * theta_tilde
    gamma: float


def _scaled_model(model: UncertaintyModel) -> tuple[UncertaintyModel, _Scaling]:
    m = model.n_params
    c = 1.0 / np.maximum(np.sqrt(np.mean(model.D0 ** 2, axis=(0, 1))), 1e-12)
    D = (model.D0 * c).reshape(-1, m)
    th = np.linalg.lstsq(D, model.tau0.reshape(-1), rcond=None)[0]
    gamma = float(max(np.sqrt(np.mean(th ** 2)), 1e-12))
    coeffs = model.coeffs.copy()
    coeffs[..., :m] *= c
    coeffs[..., m] /= gamma
    scaled = UncertaintyModel(model.D0 * c, model.tau0 / gamma, coeffs, model.scalar_names,
                              model.delta_max)
    return scaled, _Scaling(c, gamma)


# ============================================================================ SDP assembly
class _Vars:
    def __init__(self):
        self.n = 0

    def new(self, k):
        idx = np.arange(self.n, self.n + k)
        self.n += k
        return idx


def _sym_basis(r):
    """List of (a, b) for the symmetric basis of S^r."""
    return [(a, b) for a in range(r) for b in range(a, r)]


class _LMIBuilder:
    """Collects svec(F(x)) = f0 + B x for one d x d LMI from dense per-variable matrices."""

    def __init__(self, d):
        self.d = d
        self.iu, self.ju = np.triu_indices(d)
        self.f0 = np.zeros(len(self.iu))
        self.rows, self.cols, self.vals = [], [], []

    def const(self, F):
        self.f0 += F[self.iu, self.ju]

    def add(self, var_idx, mats):
        """mats (k, d, d) symmetric, var_idx (k,)."""
        mats = np.asarray(mats)
        V = mats[:, self.iu, self.ju]             # (k, ns)
        k, e = np.nonzero(V)
        self.rows.append(e)
        self.cols.append(np.asarray(var_idx)[k])
        self.vals.append(V[k, e])

    def add_sparse(self, i, j, var, val):
        """Entry (i, j) and (j, i) += val * x[var]."""
        i, j = np.minimum(i, j), np.maximum(i, j)
        pos = np.asarray(i) * self.d - (np.asarray(i) * (np.asarray(i) - 1)) // 2 + (np.asarray(j) - np.asarray(i))
        self.rows.append(np.atleast_1d(pos))
        self.cols.append(np.atleast_1d(var))
        self.vals.append(np.atleast_1d(val).astype(float))

    def finish(self, nv):
        if self.rows:
            r, c, v = (np.concatenate(a) for a in (self.rows, self.cols, self.vals))
        else:
            r = c = np.zeros(0, int)
            v = np.zeros(0)
        B = sp.csr_matrix((v, (r, c)), shape=(len(self.iu), nv))
        B.sum_duplicates()
        return (self.d, self.f0, B)


def _block_phi_mats(Q, Pm, chans):
    """Matrices of phi_i = q^T S q - p^T S p + 2 q^T G p w.r.t. the S_i and G_i basis
    (q = Q z, p = Pm z), returned as (nS + nG, dz, dz) and the counts (nS, nG)."""
    r = len(chans)
    Qc, Pc = Q[chans], Pm[chans]
    mats = []
    for a, b in _sym_basis(r):
        if a == b:
            M = np.outer(Qc[a], Qc[a]) - np.outer(Pc[a], Pc[a])
        else:
            M = (np.outer(Qc[a], Qc[b]) + np.outer(Qc[b], Qc[a])
                 - np.outer(Pc[a], Pc[b]) - np.outer(Pc[b], Pc[a]))
        mats.append(M)
    nS = len(mats)
    for a in range(r):
        for b in range(a + 1, r):
            # 2 q^T K p, K = e_a e_b^T - e_b e_a^T  ->  2 (q_a p_b - q_b p_a), symmetrised
            M = (np.outer(Qc[a], Pc[b]) + np.outer(Pc[b], Qc[a])
                 - np.outer(Qc[b], Pc[a]) - np.outer(Pc[a], Qc[b]))
            mats.append(M)
    return np.array(mats).reshape(-1, Q.shape[1], Q.shape[1]), nS, len(mats) - nS


def _add_scaling_vars(V, F: LFR, Q, Pm, nonneg_list, lmis_small):
    """Variables S_i, G_i of every block of LFR F; returns (var_idx, phi mats) and records
    S_i >= 0 constraints."""
    idx_all, mats_all = [], []
    for i in np.unique(F.scalars):
        chans = np.flatnonzero(F.scalars == i)
        mats, nS, nG = _block_phi_mats(Q, Pm, chans)
        idx = V.new(nS + nG)
        idx_all.append(idx)
        mats_all.append(mats)
        r = len(chans)
        if r == 1:
            nonneg_list.append(idx[:1])
        else:
            lmis_small.append((r, idx[:nS]))
    if not idx_all:
        return np.zeros(0, int), np.zeros((0, Q.shape[1], Q.shape[1]))
    return np.concatenate(idx_all), np.concatenate(mats_all)


def _small_psd_lmis(lmis_small, nv):
    out = []
    for r, idx in lmis_small:
        b = _LMIBuilder(r)
        for k, (a, c) in enumerate(_sym_basis(r)):
            b.add_sparse(a, c, idx[k], 1.0)      # svec entry (a, c) of S_i is the variable itself
        out.append(b.finish(nv))
    return out


def _head_P_lmi(V_n, m, P_idx, x_idx, extra):
    """Clique {h, P}: [[W + e_t e_t^T + ..., T^T], [T, P]], T = [I_m, -theta0]; `extra(builder)`
    adds the head-block terms (size 2m+1: h = (x, t) first, then P)."""
    d = 2 * m + 1
    b = _LMIBuilder(d)
    F0 = np.zeros((d, d))
    F0[m, m] = 1.0                                   # t^2
    F0[m + 1:, :m] = np.eye(m)                        # T = [I, -theta0]
    F0[:m, m + 1:] = np.eye(m)
    b.const(F0)
    for a in range(m):
        b.add_sparse(m + 1 + a, m, x_idx[a], -1.0)    # -theta0 in T's t column
        for c in range(a, m):
            b.add_sparse(m + 1 + a, m + 1 + c, P_idx[a, c], 1.0)
    extra(b)
    return b


def _Y_terms(b, Y_idx, Ch):
    """Adds Z + Z^T, Z = Y C_h, to the head block of builder b: Y (m+1, m), C_h (m, m+1)."""
    m1, m = Y_idx.shape
    a, j, c = np.meshgrid(np.arange(m1), np.arange(m1), np.arange(m), indexing="ij")
    a, j, c = a.ravel(), j.ravel(), c.ravel()
    v = Ch[c, j] * np.where(a == j, 2.0, 1.0)
    nz = v != 0
    b.add_sparse(a[nz], j[nz], Y_idx[a[nz], c[nz]], v[nz])


def _normal_parts(model: UncertaintyModel, samples_per_clique: int):
    """Per clique LFR (local scalars) of its share of the normal equations [A b](delta)."""
    F = model.sample_normal_lfrs()
    m = model.n_params
    A0b0 = sum(f.M0 for f in F)
    cliques = []
    for s in range(0, len(F), samples_per_clique):
        grp = F[s:s + samples_per_clique]
        L = np.hstack([f.L for f in grp])
        R = np.vstack([f.R for f in grp])
        H = scipy.linalg.block_diag(*[f.H for f in grp]) if grp else np.zeros((0, 0))
        off, sc = 0, []
        for f in grp:
            sc.append(f.scalars + off)
            off += f.n_scalars
        cliques.append(LFR(np.zeros((m, m + 1)), L, R, H, np.concatenate(sc), off))
    return A0b0, cliques


def _finish(V, m, lmis, cost_w, nonneg_list, P_idx, x_idx):
    cost = np.zeros(V.n)
    for a in range(m):
        cost[P_idx[a, a]] = cost_w[a]
    nonneg = np.concatenate(nonneg_list) if nonneg_list else np.zeros(0, int)
    return SDPData(V.n, cost, lmis, nonneg, P_idx, x_idx)


def _new_P(V, m):
    P_idx = np.zeros((m, m), int)
    idx = V.new(m * (m + 1) // 2)
    k = 0
    for a in range(m):
        for c in range(a, m):
            P_idx[a, c] = P_idx[c, a] = idx[k]
            k += 1
    return P_idx


def build_chordal_sdp(model: UncertaintyModel, cost_w, samples_per_clique: int = 1) -> SDPData:
    """Arrow/chordal formulation (module docstring): one LMI of size m+1+n_g per clique of
    samples, one of size 2m+1 for the ellipsoid, S_i >= 0 blocks."""
    m = model.n_params
    A0b0, cliques = _normal_parts(model, samples_per_clique)
    J = np.diag(np.r_[np.ones(m), -1.0])
    Ch = A0b0 @ J                                     # C_h h = A0 x - b0 t
    V = _Vars()
    P_idx = _new_P(V, m)
    x_idx = V.new(m)
    Y_idx = V.new((m + 1) * m).reshape(m + 1, m)
    nonneg_list, lmis_small, lmis = [], [], []
    m1 = m + 1
    hu, hv = np.triu_indices(m1)
    U_all = []
    for F in cliques:
        n = F.n_channels
        d = m1 + n
        Q = np.hstack([F.R @ J, F.H])
        Pm = np.hstack([np.zeros((n, m1)), np.eye(n)])
        b = _LMIBuilder(d)
        idx, mats = _add_scaling_vars(V, F, Q, Pm, nonneg_list, lmis_small)
        if len(idx):
            b.add(idx, -mats)
        U = V.new(len(hu))
        U_all.append(U)
        b.add_sparse(hu, hv, U, np.ones(len(hu)))
        # Y c_g with c_g = L_g (m, n): entry (a, m1 + j) += sum_c Y[a, c] L[c, j]
        for a in range(m1):
            for c in range(m):
                row = F.L[c]
                nz = np.flatnonzero(row)
                if nz.size:
                    b.add_sparse(np.full(nz.size, a), m1 + nz, np.full(nz.size, Y_idx[a, c]), row[nz])
        lmis.append(b)

    def extra(bh):
        # W_0 = -sum_g U_g, plus Y C_h + C_h^T Y^T on the head block
        for U in U_all:
            bh.add_sparse(hu, hv, U, -np.ones(len(hu)))
        _Y_terms(bh, Y_idx, Ch)

    head = _head_P_lmi(V.n, m, P_idx, x_idx, extra)
    nv = V.n
    out = [head.finish(nv)] + [b.finish(nv) for b in lmis] + _small_psd_lmis(lmis_small, nv)
    return _finish(V, m, out, cost_w, nonneg_list, P_idx, x_idx)


def build_full_sdp(model: UncertaintyModel, cost_w) -> SDPData:
    """Dense null-space formulation: one LMI of size dim(ker C) + m."""
    m = model.n_params
    A0b0, cliques = _normal_parts(model, model.n_samples)
    F = cliques[0]
    n = F.n_channels
    J = np.diag(np.r_[np.ones(m), -1.0])
    m1 = m + 1
    C = np.hstack([A0b0 @ J, F.L])
    N = scipy.linalg.null_space(C)                  # (m1 + n, k), orthonormal
    k = N.shape[1]
    Q = np.hstack([F.R @ J, F.H]) @ N
    Pm = np.hstack([np.zeros((n, m1)), np.eye(n)]) @ N
    V = _Vars()
    P_idx = _new_P(V, m)
    x_idx = V.new(m)
    nonneg_list, lmis_small = [], []
    d = k + m
    b = _LMIBuilder(d)
    F0 = np.zeros((d, d))
    et = N[m]                                        # t = e_t^T N zeta
    F0[:k, :k] = np.outer(et, et)
    Nx = N[:m]
    F0[k:, :k] = Nx
    F0[:k, k:] = Nx.T
    b.const(F0)
    # -theta0 N_t in the (P rows, zeta cols) block
    for a in range(m):
        nz = np.flatnonzero(et)
        b.add_sparse(np.full(nz.size, k + a), nz, np.full(nz.size, x_idx[a]), -et[nz])
        for c in range(a, m):
            b.add_sparse(k + a, k + c, P_idx[a, c], 1.0)
    idx, mats = _add_scaling_vars(V, F, Q, Pm, nonneg_list, lmis_small)
    big = np.zeros((len(idx), d, d))
    big[:, :k, :k] = -mats
    b.add(idx, big)
    nv = V.n
    out = [b.finish(nv)] + _small_psd_lmis(lmis_small, nv)
    return _finish(V, m, out, cost_w, nonneg_list, P_idx, x_idx)


# ============================================================================ backends
def _solve_drake(data: SDPData, solver: str, tol: float | None = None, lmi_mode: str = "lmi",
                 solver_options: dict | None = None):
    from pydrake.solvers import (ClarabelSolver, CsdpSolver, MathematicalProgram, RemoveFreeVariableMethod,
                                 ScsSolver, SolverOptions)

    prog = MathematicalProgram()
    x = prog.NewContinuousVariables(data.nv, "x")
    prog.AddLinearCost(data.cost, 0.0, x)
    if lmi_mode == "lmi":
        for d, f0, B in data.lmis:
            Bc = B.tocsc()
            used = np.flatnonzero(np.diff(Bc.indptr))
            iu, ju = np.triu_indices(d)
            F = np.zeros((len(used) + 1, d, d))
            F[0, iu, ju] = f0
            Bu = Bc[:, used].toarray().T
            F[1:, iu, ju] = Bu
            F[1:, ju, iu] = Bu
            F[0, ju, iu] = f0
            prog.AddLinearMatrixInequalityConstraint(list(F), x[used])
        return _drake_run(prog, x, data, solver, tol, solver_options)
    rows_A, rhs, Xvars = [], [], []
    offset = data.nv
    blocks = []
    for d, f0, B in data.lmis:
        X = prog.NewSymmetricContinuousVariables(d)
        prog.AddPositiveSemidefiniteConstraint(X)
        iu, ju = np.triu_indices(d)
        Xv = X[iu, ju]
        Xvars.append(Xv)
        ns = len(iu)
        # X_upper - B x = f0
        blocks.append((offset, ns, B))
        offset += ns
        rhs.append(f0)
    total = offset
    # one sparse equality for everything: [ -B_l ... I ] [x; X] = f0
    rows, cols, vals = [], [], []
    r0 = 0
    for (off, ns, B), f0 in zip(blocks, rhs):
        Bc = B.tocoo()
        rows.append(Bc.row + r0)
        cols.append(Bc.col)
        vals.append(-Bc.data)
        rows.append(np.arange(ns) + r0)
        cols.append(np.arange(ns) + off)
        vals.append(np.ones(ns))
        r0 += ns
    A = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(r0, total))
    allvars = np.concatenate([x] + Xvars)
    prog.AddLinearEqualityConstraint(A, np.concatenate(rhs), allvars)
    return _drake_run(prog, x, data, solver, tol, solver_options)


def _drake_run(prog, x, data, solver, tol, solver_options=None):
    from pydrake.solvers import ClarabelSolver, CsdpSolver, RemoveFreeVariableMethod, ScsSolver, SolverOptions

    if data.nonneg.size:
        prog.AddBoundingBoxConstraint(0.0, np.inf, x[data.nonneg])
    opts = SolverOptions()
    if solver == "clarabel":
        s = ClarabelSolver()
        if tol:
            for key in ("tol_gap_abs", "tol_gap_rel", "tol_feas"):
                opts.SetOption(s.id(), key, tol)
    elif solver == "scs":
        s = ScsSolver()
        opts.SetOption(s.id(), "eps_abs", tol or 1e-7)
        opts.SetOption(s.id(), "eps_rel", tol or 1e-7)
        opts.SetOption(s.id(), "max_iters", 200000)
    elif solver == "csdp":
        s = CsdpSolver()
        opts.SetOption(s.id(), "drake::RemoveFreeVariableMethod", int(RemoveFreeVariableMethod.kTwoSlackVariables))
    else:
        raise RobustDrakeError(f"unknown solver {solver!r}; use one of {SOLVERS}")
    for key, val in (solver_options or {}).items():
        opts.SetOption(s.id(), key, val)
    if not s.available() or not s.enabled():
        raise SolverError(f"solver {solver} is not available in this Drake build")
    t0 = time.perf_counter()
    res = s.Solve(prog, None, opts)
    solve_s = time.perf_counter() - t0
    from robust_drake.log import debug_solve

    debug_solve("confidence-ellipsoid SDP (CI section 5)", res, solve_s)
    status = str(res.get_solution_result()).split(".")[-1]
    if not res.is_success():
        raise SolverError(f"{solver} failed on the ellipsoid SDP: {status}")
    return res.GetSolution(x), status, solve_s


def _solve_cvxpy(data: SDPData, solver: str):
    from robust_drake.extras import import_extra

    cp = import_extra("cvxpy", "cvxpy", "the cvxpy backend")

    x = cp.Variable(data.nv)
    cons = []
    for d, f0, B in data.lmis:
        iu, ju = np.triu_indices(d)
        ns = len(iu)
        # svec -> full symmetric vec (column-major)
        r = np.r_[iu * d + ju, ju * d + iu]
        c = np.r_[np.arange(ns), np.arange(ns)]
        keep = np.r_[np.ones(ns, bool), iu != ju]
        S = sp.csr_matrix((np.ones(keep.sum()), (r[keep], c[keep])), shape=(d * d, ns))
        vec = S @ f0 + (S @ B) @ x
        M = cp.reshape(vec, (d, d), order="F")
        cons.append(0.5 * (M + M.T) >> 0)
    if data.nonneg.size:
        cons.append(x[data.nonneg] >= 0)
    prob = cp.Problem(cp.Minimize(data.cost @ x), cons)
    name = {"clarabel": cp.CLARABEL, "scs": cp.SCS}.get(solver)
    if name is None:
        raise RobustDrakeError(f"cvxpy backend supports clarabel and scs, not {solver!r}")
    t0 = time.perf_counter()
    kw = {"eps": 1e-7, "max_iters": 200000} if solver == "scs" else {}
    try:
        prob.solve(solver=name, **kw)
    except cp.error.SolverError as exc:
        raise SolverError(f"cvxpy/{solver} failed on the ellipsoid SDP: {str(exc).splitlines()[0]}") from None
    solve_s = time.perf_counter() - t0
    if prob.status not in ("optimal",):
        raise SolverError(f"cvxpy/{solver} status {prob.status} on the ellipsoid SDP")
    return np.asarray(x.value), prob.status, solve_s


def _solve_clarabel_direct(data: SDPData, tol: float | None = None):
    """The same conic program handed straight to the pip ``clarabel`` package (no modelling
    layer): s = b - A x in {R+^k, PSD triangles}; svec column-major upper, off-diagonals * sqrt 2."""
    from robust_drake.extras import import_extra

    clarabel = import_extra("clarabel", "cvxpy", "the 'direct' backend (pip clarabel)")

    A_blocks, b_blocks, cones = [], [], []
    if data.nonneg.size:
        k = data.nonneg.size
        A_blocks.append(sp.csr_matrix((-np.ones(k), (np.arange(k), data.nonneg)), shape=(k, data.nv)))
        b_blocks.append(np.zeros(k))
        cones.append(clarabel.NonnegativeConeT(k))
    for d, f0, B in data.lmis:
        iu, ju = np.triu_indices(d)
        pos = {(i, j): n for n, (i, j) in enumerate(zip(iu, ju))}
        perm = np.array([pos[(i, j)] for j in range(d) for i in range(j + 1)])
        scale = np.array([1.0 if i == j else np.sqrt(2.0) for j in range(d) for i in range(j + 1)])
        Bp = sp.diags(scale) @ B[perm]
        A_blocks.append(-Bp)
        b_blocks.append(scale * f0[perm])
        cones.append(clarabel.PSDTriangleConeT(d))
    A = sp.vstack(A_blocks).tocsc()
    b = np.concatenate(b_blocks)
    settings = clarabel.DefaultSettings()
    settings.verbose = bool(int(__import__("os").environ.get("RD_VERBOSE", "0")))
    settings.direct_solve_method = __import__("os").environ.get("RD_CLARABEL_METHOD", "faer")
    if tol:
        settings.tol_gap_abs = settings.tol_gap_rel = settings.tol_feas = tol
    Pq = sp.csc_matrix((data.nv, data.nv))
    t0 = time.perf_counter()
    solver = clarabel.DefaultSolver(Pq, data.cost, A, b, cones, settings)
    sol = solver.solve()
    solve_s = time.perf_counter() - t0
    status = str(sol.status)
    if status not in ("Solved", "AlmostSolved"):
        raise SolverError(f"clarabel (direct) failed on the ellipsoid SDP: {status}")
    return np.asarray(sol.x), status, solve_s


def _min_eigs(data: SDPData, xs):
    worst = np.inf
    for d, f0, B in data.lmis:
        v = f0 + B @ xs
        M = np.zeros((d, d))
        iu, ju = np.triu_indices(d)
        M[iu, ju] = v
        M[ju, iu] = v
        w = np.linalg.eigvalsh(M)
        worst = min(worst, w[0] / max(1.0, np.abs(w).max()))
    return float(worst)



# ============================================================================ closed-form bound
def _abs_sum(K):
    w, V = np.linalg.eigh(K)
    return np.einsum("jab,jb,jcb->ac", V, np.abs(w), V)

def _scalar_multiplier_bound(model: UncertaintyModel, theta0, A0, iters: int = 4, grid=None):
    """S-procedure on the scalar energy identity with one fixed multiplier per uncertain scalar
    (step 4 of ``energy_bound``). Returns (centre, P) or (None, None)."""
    grid = np.exp(np.linspace(-5, 3, 17)) if grid is None else grid
    K, s, n, m1 = model.coeffs.shape; m = m1 - 1
    D0 = model.D0
    res0 = model.tau0 - np.einsum("kim,m->ki", D0, theta0)
    C = model.coeffs[..., :m]; w = model.coeffs[..., m] - np.einsum("ksim,m->ksi", C, theta0)
    g = (np.einsum("kim,ksi->ksm", D0, w) + np.einsum("ksim,ki->ksm", C, res0)).reshape(-1, m)
    quad = np.einsum("ksim,kti->kstm", C, w)
    iu, ju = np.triu_indices(s, 1)
    gx = (quad + quad.transpose(0, 2, 1, 3))[:, iu, ju].reshape(-1, m)
    gd = quad[:, np.arange(s), np.arange(s)].reshape(-1, m)
    r0 = np.einsum("kim,ki->m", D0, res0)             # round-off of the LS residual condition
    N = np.einsum("ksim,kin->ksmn", C, D0); N = (N + np.swapaxes(N, 2, 3)).reshape(-1, m, m)
    def hk(G, Nm=None):           # symmetric (m+1)x(m+1) forms in h = (e, t)
        Kh = np.zeros((G.shape[0], m1, m1))
        if Nm is not None: Kh[:, :m, :m] = Nm
        Kh[:, :m, m] = -G / 2; Kh[:, m, :m] = -G / 2
        keep = np.any(Kh != 0, axis=(1, 2))
        return Kh[keep]
    Klin = hk(g, N); Kx = hk(gx); Kd = hk(gd); K0 = hk(r0[None])
    B = np.zeros((m1, m1)); B[:m, :m] = A0
    wA, VA = np.linalg.eigh(A0)
    L = (VA / np.sqrt(wA)) @ VA.T; c0 = np.zeros(m)
    best = (np.inf, None, None)
    for it in range(iters):
        for sc in grid:
            T = np.zeros((m1, m1)); T[:m, :m] = L; T[:m, m] = c0 * sc; T[m, m] = sc   # h = T h~, t = sc v
            Kt = [T.T @ Kk @ T for Kk in (Klin, Kx, Kd, K0)]
            X = _abs_sum(Kt[0]) + _abs_sum(Kt[1]) + 0.5 * _abs_sum(Kt[2]) - 0.5 * Kt[2].sum(0) + _abs_sum(Kt[3])
            Z = T.T @ B @ T - X
            Zuu, zuv, zvv = Z[:m, :m], Z[:m, m], Z[m, m]
            wz = np.linalg.eigvalsh(Zuu)
            if wz[0] <= 1e-12 * max(1.0, wz[-1]):
                continue
            v = 1.0 / sc
            Zi = np.linalg.inv(Zuu)
            uc = -Zi @ zuv * v
            rad = uc @ Zuu @ uc - zvv * v * v
            if rad <= 0:
                continue
            P = L @ (rad * Zi) @ L.T
            tr = np.trace(P)
            if tr < best[0]:
                best = (tr, theta0 + c0 + L @ uc, 0.5 * (P + P.T))
        if best[1] is None:
            break
        # re-centre and re-normalise on the best ellipsoid so far
        c0 = best[1] - theta0
        wp, Vp = np.linalg.eigh(best[2]); L = (Vp * np.sqrt(wp)) @ Vp.T
    return best[1], best[2]


def _energy_generators(model: UncertaintyModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 2 of :func:`energy_bound`: nominal LS estimate theta0, A0 = sum D0^T D0 and the
    zonotope generators (rows of G) of r(delta)."""
    K, s, n, m1 = model.coeffs.shape
    m = m1 - 1
    D0, tau0 = model.D0, model.tau0
    A0 = np.einsum("kim,kin->mn", D0, D0)
    b0 = np.einsum("kim,ki->m", D0, tau0)
    try:
        theta0 = np.linalg.solve(A0, b0)
    except np.linalg.LinAlgError as exc:
        raise SolverError("energy bound: the nominal regressor D0 has no full column rank") from exc
    res0 = tau0 - np.einsum("kim,m->ki", D0, theta0)           # (K, n)
    C = model.coeffs[..., :m]                                    # (K, s, n, m)
    w = model.coeffs[..., m] - np.einsum("ksim,m->ksi", C, theta0)
    lin = np.einsum("kim,ksi->ksm", D0, w) + np.einsum("ksim,ki->ksm", C, res0)
    quad = np.einsum("ksim,kti->kstm", C, w)                     # coefficient of delta_s delta_t
    iu, ju = np.triu_indices(s, 1)
    cross = (quad + quad.transpose(0, 2, 1, 3))[:, iu, ju]
    sq = quad[:, np.arange(s), np.arange(s)]
    centre = 0.5 * sq.sum(axis=(0, 1)) + (b0 - A0 @ theta0)     # second term: round-off of sum D0^T res0
    G = np.concatenate([lin.reshape(-1, m), cross.reshape(-1, m), 0.5 * sq.reshape(-1, m), centre[None]])
    return theta0, A0, G[np.any(G != 0, axis=1)]


def _energy_amin(model: UncertaintyModel, A0: np.ndarray) -> tuple[np.ndarray, float]:
    """Step 1 of :func:`energy_bound`: A_min^-1/2 and alpha = ||sum |M_j|||; SolverError when
    A(delta) is not provably invertible."""
    m = A0.shape[0]
    C, D0 = model.coeffs[..., :m], model.D0
    wA, VA = np.linalg.eigh(A0)
    if wA[0] <= 0:
        raise SolverError("energy bound: D0^T D0 is singular")
    A0mh = (VA / np.sqrt(wA)) @ VA.T
    A0h = (VA * np.sqrt(wA)) @ VA.T
    N = np.einsum("ksim,kin->ksmn", C, D0)
    Mj = A0mh @ (N + np.swapaxes(N, 2, 3)).reshape(-1, m, m) @ A0mh
    wj, Vj = np.linalg.eigh(Mj)
    absM = np.einsum("jab,jb,jcb->ac", Vj, np.abs(wj), Vj)
    Bn = np.eye(m) - 0.5 * (absM + absM.T)
    wb = np.linalg.eigvalsh(Bn)
    alpha = float(1.0 - wb[0])
    if wb[0] <= 1e-9:
        raise SolverError(f"energy bound: A(delta) is not provably invertible (||sum |M_j||| = {alpha:.3f} >= 1); "
                          "use formulation='chordal'")
    Amin = A0h @ Bn @ A0h
    wm, Vm = np.linalg.eigh(0.5 * (Amin + Amin.T))
    return (Vm / np.sqrt(wm)) @ Vm.T, alpha


def _energy_outer(Gn: np.ndarray, Amh: np.ndarray, lambda_iters: int) -> tuple[np.ndarray, float, str]:
    """Steps 2-3 of :func:`energy_bound` on the normalised generators Gn = G A_min^-1/2: the
    smaller-trace of the ball and Thales outer ellipsoids over a few lambda re-weightings."""
    m = Amh.shape[0]
    lam = np.linalg.norm(Gn, axis=1)
    lam = lam / lam.sum()
    best, best_tr, best_kind = None, np.inf, ""
    trA = np.trace(Amh @ Amh)
    for _ in range(max(1, lambda_iters)):
        Qt = (Gn.T / lam) @ Gn
        wq, Vq = np.linalg.eigh(0.5 * (Qt + Qt.T))
        rho2 = float(wq[-1])
        T1, T2 = np.trace(Amh @ Qt @ Amh) / 4.0, trA * rho2 / 4.0
        l1 = np.sqrt(T1) / (np.sqrt(T1) + np.sqrt(T2))
        for kind, Cw in (("ball", rho2 * np.eye(m)),
                         ("thales", (Qt / 4.0) / l1 + (rho2 / 4.0) * np.eye(m) / (1.0 - l1))):
            P = Amh @ Cw @ Amh
            if np.trace(P) < best_tr:
                best, best_tr, best_kind = P, float(np.trace(P)), kind
        lam = np.abs(Gn @ Vq[:, -1]) + 1e-3 * np.linalg.norm(Gn, axis=1)
        lam = lam / lam.sum()
    return best, best_tr, best_kind


def energy_bound(model: UncertaintyModel, lambda_iters: int = 8) -> tuple[np.ndarray, np.ndarray, dict]:
    """Sound closed-form outer ellipsoid of the LS solutions (formulation ``"energy"``; no SDP).

    Notation of the module docstring, per sample k: D_k(delta) = D0_k + sum_i delta_i C_ki,
    tau_k(delta) = tau0_k + sum_i delta_i c_ki (the linearised model, exact in delta). With the
    nominal LS estimate theta0 and e = theta - theta0, the normal equations (CI section 3.1) read

        A(delta) e = r(delta),  A = sum_k D_k^T D_k,  r = sum_k D_k^T (tau_k - D_k theta0),

    r quadratic in each sample's own scalars. Sound steps, all O(#scalars) (eigendecompositions of small matrices):

    1. ``A(delta) >= A_min := A0^1/2 (I - sum_j |M_j|) A0^1/2`` with M_j = A0^-1/2 N_j A0^-1/2,
       N_j = C_j^T D0 + D0^T C_j (the linear part; E^T E >= 0 is dropped; |M| is the matrix
       absolute value, |M_j| >= +-M_j: a fixed-multiplier matrix-cube bound). Raises if
       I - sum |M_j| is not positive definite (A(delta) not provably invertible).
    2. r(delta) lies in the zonotope Z with generators D0^T w_i + C_i^T res0 (linear terms),
       sym(C_i^T w_j) for delta_i delta_j (i < j), and half of C_i^T w_i (delta_i^2 in [0, 1],
       whose other half is the centre); w_i = c_i - C_i theta0. Z is inside the ellipsoid
       sum_j g_j g_j^T / lambda_j for any lambda on the simplex (Minkowski sum of segments).
    3. Energy: e^T A_min e <= e^T A(delta) e = e^T r. With w = A_min^1/2 e and z~ = A_min^-1/2 r,
       ||w||^2 <= w^T z~  <=>  ||w - z~/2|| <= ||z~||/2 (Thales), so
       w in Z~/2 (+) B(rho/2) with rho^2 = lambda_max of Z~'s bounding ellipsoid, or simply
       ||w|| <= rho. Both outer ellipsoids are formed; the smaller trace is returned.

    4. Keeping the correlation of each scalar's effect on A and on r: with h = (e, t) the energy
       identity is 0 = e^T A0 e + sum_j delta_j h^T K_j h + ||E e||^2 + (delta_i delta_j and
       delta_i^2 terms of r), K_j = [[N_j, -g_j/2], [-g_j^T/2, 0]]. Bounding delta_j h^T K_j h >=
       -h^T |T^T K_j T| h in coordinates h = T h~ (one fixed multiplier per uncertain scalar, a
       restriction of the S-procedure; delta^2 h^T K h >= -(|K| - K)/2) gives one quadratic
       inequality in e, i.e. an ellipsoid when its e-block is positive definite. T is
       re-centred and re-normalised on the best ellipsoid so far, the t-scale searched on a grid.

    lambda is re-weighted towards the worst direction for a few rounds (any lambda is sound).
    The smallest-trace candidate of steps 3-4 is returned.
    Returns (centre, P, info). The first-order part is as tight as the SDP on the IMI data; the
    loss is the worst-case A over the whole box (||sum |M_j||| ~ 0.5 there): measured
    2.2-4x the chordal SDP's trace (BUILD_NOTES "Calafiore & Indri").
    """
    theta0, A0, G = _energy_generators(model)
    Amh, alpha = _energy_amin(model, A0)                          # step 1: A_min^-1/2
    best, best_tr, best_kind = _energy_outer(G @ Amh, Amh, lambda_iters)  # steps 2-3
    centre = theta0
    c4, P4 = _scalar_multiplier_bound(model, theta0, A0)
    if P4 is not None and np.trace(P4) < best_tr:
        centre, best, best_kind = c4, P4, "multiplier"
    info = {"alpha": alpha, "n_generators": int(G.shape[0]), "shape": best_kind}
    return centre, 0.5 * (best + best.T), info


def _solve_energy(model: UncertaintyModel, certify_draws: int, seed: int) -> EllipsoidResult:
    t0 = time.perf_counter()
    theta0, P, info = energy_bound(model)
    solve_s = time.perf_counter() - t0
    eig = np.linalg.eigvalsh(P)
    if eig[0] <= 0:
        raise SolverError(f"energy bound: P is not positive definite (smallest eigenvalue {eig[0]:.3g})")
    res = EllipsoidResult(Ellipsoid(theta0, P), float(np.trace(P)), "closed-form", "energy",
                          f"bound ({info['shape']}, alpha={info['alpha']:.3f})", 0.0, solve_s, [], 0, 0.0, eig)
    if certify_draws:
        res.certificate = certify(model, res.ellipsoid, certify_draws, seed)
        if res.certificate["inside"] < res.certificate["tested"]:
            raise SolverError(f"energy bound: certificate failed ({res.certificate}); this is a bug")
    return res


# ============================================================================ public API
def check_identifiable(model: UncertaintyModel) -> None:
    """Refuse data whose nominal regressor D0 (all samples stacked) has no full column rank: the
    least-squares solutions then form an unbounded set and no ellipsoid contains them. Rank decided
    to rounding: ``sigma_min <= certificate_tol(max(shape)) sigma_max`` (``analysis.tolerance``)."""
    m = model.n_params
    D = np.asarray(model.D0, float).reshape(-1, m)
    s = np.linalg.svd(D, compute_uv=False) if D.size else np.zeros(0)
    if D.shape[0] < m or s.size < m or s[-1] <= certificate_tol(max(D.shape)) * s[0]:
        rank = int(np.sum(s > certificate_tol(max(D.shape)) * s[0])) if s.size and s[0] > 0 else 0
        n = model.D0.shape[1] if np.ndim(model.D0) == 3 else 1
        raise RobustDrakeError(
            f"the nominal regressor of the {model.n_samples} samples has rank {rank} < {m} parameters: the "
            f"least-squares solutions are unbounded and no ellipsoid contains them; use at least "
            f"{-(-m // n)} samples of exciting motion")


def solve_ellipsoid(model: UncertaintyModel, solver: str = "clarabel", formulation: str = "chordal",
                    backend: str = "drake", samples_per_clique: int = 1, certify_draws: int = 1000,
                    seed: int = 0, tol: float | None = None,
                    solver_options: dict | None = None) -> EllipsoidResult:
    """Minimal-trace confidence ellipsoid of the LS solutions (CI section 3.1, El Ghaoui & Calafiore).

    Args:
        model: per-sample linearised uncertainty model (``build_uncertainty_model``).
        solver: "clarabel" | "scs" | "csdp" (Drake); "clarabel" | "scs" with backend "cvxpy".
        formulation: "chordal" (SDP, default; 100 samples ~10 s, 1000 samples ~4 min), "full"
            (dense SDP, small n_m), "energy" (sound closed form ``energy_bound``, ~5 s at
            1000 samples, 2.2-4x the chordal trace), or "auto" (chordal up to
            ``AUTO_ENERGY_ABOVE`` samples, energy above).
        solver_options: extra Drake ``SolverOptions`` entries (name -> value) for the solver.
        samples_per_clique: samples merged per clique in the chordal formulation.
        certify_draws: Delta draws for the certificate (0 = skip); half box vertices.

    Raises SolverError when the solver fails or the certificate finds a LS solution outside.
    """
    check_identifiable(model)
    if formulation == "auto":
        formulation = "energy" if model.n_samples > AUTO_ENERGY_ABOVE else "chordal"
    if formulation == "energy":
        return _solve_energy(model, certify_draws, seed)
    t0 = time.perf_counter()
    scaled, scl = _scaled_model(model)
    m = model.n_params
    cost_w = (scl.gamma * scl.c) ** 2                # trace(P) = sum_j (gamma c_j)^2 P~_jj
    cost_w = cost_w / cost_w.max()
    if formulation == "chordal":
        data = build_chordal_sdp(scaled, cost_w, samples_per_clique)
    elif formulation == "full":
        data = build_full_sdp(scaled, cost_w)
    else:
        raise RobustDrakeError(f"unknown formulation {formulation!r}; use one of {FORMULATIONS}")
    if backend == "drake":
        xs, status, solve_s = _solve_drake(data, solver, tol, solver_options=solver_options)
    elif backend == "cvxpy":
        xs, status, solve_s = _solve_cvxpy(data, solver)
    elif backend == "direct":
        if solver != "clarabel":
            raise RobustDrakeError("backend 'direct' is the pip clarabel package: use solver='clarabel'")
        xs, status, solve_s = _solve_clarabel_direct(data, tol)
    else:
        raise RobustDrakeError(f"unknown backend {backend!r}")
    total = time.perf_counter() - t0
    Pt = xs[data.P_idx]
    th_t = xs[data.x_idx]
    S = scl.gamma * scl.c
    P = S[:, None] * Pt * S[None, :]
    theta0 = S * th_t
    eig = np.linalg.eigvalsh(P)
    min_eig = _min_eigs(data, xs)
    if eig[0] <= 0:
        raise SolverError(f"{solver}: P is not positive definite (smallest eigenvalue {eig[0]:.3g})")
    res = EllipsoidResult(Ellipsoid(theta0, P), float(np.trace(P)), solver if backend == "drake" else f"{backend}-{solver}",
                          formulation, status, total - solve_s, solve_s, [d for d, _, _ in data.lmis], data.nv,
                          min_eig, eig)
    if min_eig < -1e-4:
        raise SolverError(f"{solver}: solution violates an LMI (normalised eigenvalue {min_eig:.2e}); inaccurate solve")
    if certify_draws:
        res.certificate = certify(model, res.ellipsoid, certify_draws, seed)
        if res.certificate["inside"] < res.certificate["tested"]:
            raise SolverError(
                f"{solver}: certificate failed, {res.certificate['tested'] - res.certificate['inside']} of "
                f"{res.certificate['tested']} LS solutions outside the ellipsoid (max radius "
                f"{res.certificate['max_radius']:.6f}); the solve is not accurate enough")
    return res


def certify(model: UncertaintyModel, ell: Ellipsoid, draws: int = 1000, seed: int = 0,
            tol: float | None = None) -> dict:
    """Sample Delta in the box (half at random vertices), compute the exact LS solution of the
    perturbed linearised equations, and count how many lie in E(P, theta0) (radius <= 1 + tol).
    ``max_radius`` < 1 measures how tight the ellipsoid is along the sampled solutions.

    Default ``tol``: the SDP's own accuracy (``tolerance.SDP_RTOL``; the ellipsoid is an
    interior-point solution, feasible to the solver's tolerance) plus rounding of the radius,
    ``certificate_tol(cond(P))`` (``analysis.tolerance``)."""
    if int(draws) < 1:
        raise RobustDrakeError(f"certificate draws must be >= 1 (got {draws})")
    if tol is None:
        tol = SDP_RTOL + certificate_tol(np.linalg.cond(ell.P))
    rng = np.random.default_rng(seed)
    deltas = random_deltas(model.n_scalars, draws, rng)
    th = model.ls_solutions(deltas)
    r = ell.radius(th)
    return {"tested": int(draws), "inside": int(np.sum(r <= 1.0 + tol)), "max_radius": float(r.max()),
            "mean_radius": float(r.mean()), "tol": float(tol)}


def result_to_dict(res: EllipsoidResult) -> dict:
    return {
        "theta0": res.theta0.tolist(),
        "P": res.P.tolist(),
        "trace": res.trace,
        "solver": res.solver,
        "formulation": res.formulation,
        "status": res.status,
        "setup_seconds": res.setup_seconds,
        "solve_seconds": res.solve_seconds,
        "lmi_sizes_max": int(max(res.lmi_sizes, default=0)),
        "n_lmis": len(res.lmi_sizes),
        "n_variables": res.n_variables,
        "min_lmi_eig": res.min_lmi_eig,
        "eigenvalues": res.eigenvalues.tolist(),
        "containment": res.certificate,
    }
