"""Linear fractional representations (LFRs) with structured, repeated real scalars.

Calafiore & Indri (CI, seeds/000) section 3, eq. 3:

    M(Delta) = M0 + L Delta (I - H Delta)^-1 R,      Delta = diag(delta_{s(c)})_c,  |delta_i| <= 1.

Each LFR *channel* ``c`` (a column of ``L``, a row of ``R``) carries one normalised scalar
``delta[scalars[c]]``; a scalar that owns several channels is a repeated block
``delta_i I_{r_i}`` (the order of the channels does not matter: ``Delta`` is diagonal, so a
permutation of the channels is a similarity that leaves ``M(Delta)`` unchanged). This
representation makes products with shared scalars (eq. 4 with Delta_1 and Delta_2 carrying
the same deltas, as for ``D(delta)^T D(delta)`` in section 5) exact without bookkeeping.

All functions are pure and numpy-only. ``group`` labels (one per scalar, e.g. the sample
index of section 5) are carried along so that the SDP of :mod:`.ellipsoid` can exploit the
block structure of Delta.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from robust_drake.errors import RobustDrakeError


@dataclass
class LFR:
    """``M(Delta) = M0 + L Delta (I - H Delta)^-1 R`` (CI eq. 3).

    Attributes:
        M0: (a, b) nominal matrix.
        L: (a, n) left factor.
        R: (n, b) right factor.
        H: (n, n) feedback term (zero for affine dependence, eq. 18).
        scalars: (n,) int, the index of the normalised scalar on each channel.
        n_scalars: number of scalars (``delta`` has this length; some may own no channel).
        groups: (n_scalars,) int, a group label per scalar (the sample index in CI sec. 5).
    """

    M0: np.ndarray
    L: np.ndarray
    R: np.ndarray
    H: np.ndarray
    scalars: np.ndarray
    n_scalars: int
    groups: np.ndarray = field(default=None)

    def __post_init__(self):
        self.M0 = np.atleast_2d(np.asarray(self.M0, dtype=float))
        a, b = self.M0.shape
        n = len(self.scalars)
        self.L = np.asarray(self.L, dtype=float).reshape(a, n)
        self.R = np.asarray(self.R, dtype=float).reshape(n, b)
        self.H = np.asarray(self.H, dtype=float).reshape(n, n)
        self.scalars = np.asarray(self.scalars, dtype=int).reshape(n)
        if self.groups is None:
            self.groups = np.arange(self.n_scalars)
        self.groups = np.asarray(self.groups, dtype=int).reshape(self.n_scalars)
        if n and (self.scalars.min() < 0 or self.scalars.max() >= self.n_scalars):
            raise RobustDrakeError("LFR channel scalar index out of range")

    # ------------------------------------------------------------------ basics
    @property
    def shape(self):
        return self.M0.shape

    @property
    def n_channels(self) -> int:
        return len(self.scalars)

    def block_sizes(self) -> np.ndarray:
        """r_i: number of channels (repetitions) of each scalar."""
        return np.bincount(self.scalars, minlength=self.n_scalars)

    def channels_of(self, i: int) -> np.ndarray:
        return np.flatnonzero(self.scalars == i)

    def delta_matrix(self, delta) -> np.ndarray:
        """Delta = diag(delta_{s(c)}) for a vector of scalars ``delta`` (n_scalars,)."""
        delta = np.asarray(delta, dtype=float).reshape(self.n_scalars)
        return np.diag(delta[self.scalars])

    def is_structurally_well_posed(self) -> bool:
        """True when I - H Delta is invertible for EVERY diagonal Delta.

        Holds when the directed graph of H's nonzero pattern is acyclic (H Delta is then
        nilpotent, det(I - H Delta) = 1); true for all affine LFRs (H = 0) and for products of
        affine LFRs (eq. 4 gives a block upper-triangular H with zero diagonal blocks).
        """
        n = self.n_channels
        if n == 0 or not np.any(self.H):
            return True
        A = (np.abs(self.H) > 0).astype(float)
        # nilpotent pattern <=> A^n == 0; square repeatedly with renormalisation (0/1 pattern).
        P = A.copy()
        k = 1
        while k < n:
            P = ((P @ P) > 0).astype(float)
            k *= 2
        # P = pattern of A^(2^m) with 2^m >= n
        return not np.any(P)

    def well_posedness_margin(self, delta) -> float:
        """Smallest singular value of I - H Delta at ``delta`` (0 means ill-posed)."""
        n = self.n_channels
        if n == 0:
            return 1.0
        return float(np.linalg.svd(np.eye(n) - self.H @ self.delta_matrix(delta), compute_uv=False)[-1])

    def evaluate(self, delta) -> np.ndarray:
        """M(Delta) at the scalars ``delta`` (eq. 3); raises if I - H Delta is singular."""
        n = self.n_channels
        if n == 0:
            return self.M0.copy()
        Dm = self.delta_matrix(delta)
        if not np.any(self.H):
            return self.M0 + self.L @ (Dm @ self.R)
        I_HD = np.eye(n) - self.H @ Dm
        if np.linalg.cond(I_HD) > 1e12:
            raise RobustDrakeError("LFR is not well posed at this Delta: I - H Delta is singular")
        return self.M0 + self.L @ (Dm @ np.linalg.solve(I_HD, self.R))

    # ------------------------------------------------------------------ algebra
    def transpose(self) -> "LFR":
        """M(Delta)^T = M0^T + R^T Delta (I - H^T Delta)^-1 L^T (Delta diagonal, push-through)."""
        return LFR(self.M0.T, self.R.T, self.L.T, self.H.T, self.scalars, self.n_scalars, self.groups)

    def __add__(self, other: "LFR") -> "LFR":
        return lfr_sum(self, other)

    def __matmul__(self, other: "LFR") -> "LFR":
        return lfr_product(self, other)

    def select(self, rows=None, cols=None) -> "LFR":
        """Sub-matrix M(Delta)[rows, cols] (rows of M0/L, columns of M0/R)."""
        rows = slice(None) if rows is None else rows
        cols = slice(None) if cols is None else cols
        return LFR(self.M0[rows][:, cols], self.L[rows], self.R[:, cols], self.H, self.scalars,
                   self.n_scalars, self.groups)

    def left_multiply(self, A) -> "LFR":
        """A M(Delta) for a constant matrix A."""
        A = np.atleast_2d(A)
        return LFR(A @ self.M0, A @ self.L, self.R, self.H, self.scalars, self.n_scalars, self.groups)

    def right_multiply(self, B) -> "LFR":
        """M(Delta) B for a constant matrix B."""
        B = np.atleast_2d(B)
        return LFR(self.M0 @ B, self.L, self.R @ B, self.H, self.scalars, self.n_scalars, self.groups)

    def reduce(self, tol: float = 1e-12) -> "LFR":
        """Remove dead channels (exact): a channel whose output p_c reaches nothing
        (L[:, c] = 0 and H[:, c] = 0) or whose input q_c is identically zero
        (R[c, :] = 0 and H[c, :] = 0). Repeated until nothing changes."""
        out = self
        while True:
            scale = max(1.0, np.abs(out.L).max(initial=0), np.abs(out.R).max(initial=0))
            t = tol * scale
            dead_out = (np.abs(out.L).max(axis=0, initial=0) <= t) & (np.abs(out.H).max(axis=0, initial=0) <= t)
            dead_in = (np.abs(out.R).max(axis=1, initial=0) <= t) & (np.abs(out.H).max(axis=1, initial=0) <= t)
            keep = ~(dead_out | dead_in)
            if keep.all():
                return out
            out = LFR(out.M0, out.L[:, keep], out.R[keep], out.H[np.ix_(keep, keep)], out.scalars[keep],
                      out.n_scalars, out.groups)


def _check_scalars(a: LFR, b: LFR):
    if a.n_scalars != b.n_scalars or not np.array_equal(a.groups, b.groups):
        raise RobustDrakeError("LFRs must be defined on the same set of scalars (n_scalars, groups)")


def lfr_sum(a: LFR, b: LFR) -> LFR:
    """M1(Delta) + M2(Delta): stack the channels, Delta~ = diag(Delta1, Delta2), H block-diagonal."""
    _check_scalars(a, b)
    if a.shape != b.shape:
        raise RobustDrakeError(f"cannot add LFRs of shapes {a.shape} and {b.shape}")
    n1, n2 = a.n_channels, b.n_channels
    H = np.zeros((n1 + n2, n1 + n2))
    H[:n1, :n1] = a.H
    H[n1:, n1:] = b.H
    return LFR(a.M0 + b.M0, np.hstack([a.L, b.L]), np.vstack([a.R, b.R]), H,
               np.concatenate([a.scalars, b.scalars]), a.n_scalars, a.groups)


def lfr_product(a: LFR, b: LFR) -> LFR:
    """M1(Delta) M2(Delta) by the product rule, CI eq. 4:

        M = M1 M2,  L = [L1, M1 L2],  R = [R1 M2; R2],  H = [[H1, R1 L2], [0, H2]],
        Delta~ = diag(Delta1, Delta2).

    Shared scalars stay shared (the channel->scalar map is concatenated), so this is exact
    for D(delta)^T D(delta). Note H != 0 even when H1 = H2 = 0: the product of two affine
    LFRs is quadratic in delta, carried by the block R1 L2 (CI section 5 prints H^ = 0,
    which would drop the quadratic term; we keep it).
    """
    _check_scalars(a, b)
    if a.shape[1] != b.shape[0]:
        raise RobustDrakeError(f"cannot multiply LFRs of shapes {a.shape} and {b.shape}")
    n1, n2 = a.n_channels, b.n_channels
    H = np.zeros((n1 + n2, n1 + n2))
    H[:n1, :n1] = a.H
    H[:n1, n1:] = a.R @ b.L
    H[n1:, n1:] = b.H
    return LFR(a.M0 @ b.M0, np.hstack([a.L, a.M0 @ b.L]), np.vstack([a.R @ b.M0, b.R]), H,
               np.concatenate([a.scalars, b.scalars]), a.n_scalars, a.groups)


def lfr_from_affine(M0, coefficients, groups=None, tol: float = 1e-12) -> LFR:
    """LFR of an affine dependence M(delta) = M0 + sum_i delta_i M_i (CI eq. 18).

    Each coefficient matrix M_i (a, b) is factored by an SVD into r_i = rank(M_i) channels,
    M_i = L_i R_i with balanced factors (L_i = U sqrt(S), R_i = sqrt(S) V^T), so the
    repeated block of delta_i has size r_i. H = 0.

    Args:
        M0: (a, b).
        coefficients: (N, a, b) array or list of N matrices.
        groups: optional (N,) labels (e.g. sample index).
    """
    M0 = np.atleast_2d(np.asarray(M0, dtype=float))
    C = np.asarray(coefficients, dtype=float).reshape(-1, *M0.shape)
    N = C.shape[0]
    Ls, Rs, sc = [], [], []
    for i in range(N):
        Mi = C[i]
        if not np.any(Mi):
            continue
        U, S, Vt = np.linalg.svd(Mi, full_matrices=False)
        r = int(np.sum(S > tol * max(1.0, S[0])))
        sq = np.sqrt(S[:r])
        Ls.append(U[:, :r] * sq)
        Rs.append(sq[:, None] * Vt[:r])
        sc.extend([i] * r)
    a, b = M0.shape
    n = len(sc)
    L = np.hstack(Ls) if Ls else np.zeros((a, 0))
    R = np.vstack(Rs) if Rs else np.zeros((0, b))
    return LFR(M0, L, R, np.zeros((n, n)), np.array(sc, dtype=int), N, groups)


def random_deltas(n_scalars: int, count: int, rng, vertex_fraction: float = 0.5) -> np.ndarray:
    """(count, n_scalars) draws: a fraction at random vertices of the box, the rest uniform."""
    nv = int(round(vertex_fraction * count))
    V = rng.choice([-1.0, 1.0], size=(nv, n_scalars))
    U = rng.uniform(-1.0, 1.0, size=(count - nv, n_scalars))
    return np.vstack([V, U])
