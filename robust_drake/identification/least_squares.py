"""(Weighted) least squares on the Drake-derived base parameters plus friction and effect columns.

The model is linear in its parameters (Gautier & Khalil; JS eq. 15 for the closed form)::

    tau = Y(q, qd, qdd) theta + e,   Y = [Y_rb | Y_fric | Y_effect_1 | ...]   (N, n, p)

``Y_rb`` are the identifiable base-parameter columns of the URDF given with ``--robot``
(``robust_drake.regressor.InverseDynamicsRegressor``), ``Y_fric`` one Coulomb (sign qd_i) and one
viscous (qd_i) column per joint (the baseline), effect columns come from
``robust_drake.effects``.

Convention ("parallel filtering"): every column is passed through the same zero-phase filter as
the measured torque (``data.zero_phase_lowpass``), per file segment, so a discontinuous column
(sign qd) sees exactly the smoothing the filtered torque saw. Least squares stacks the joints
(row = one joint at one sample).

Weighted LS: rows of joint j are weighted by 1 / sigma_j, sigma_j estimated from the OLS residual
of that joint (two-step WLS). Standard errors: cov(theta) = (A^T W A)^-1 with W = diag(1/sigma_j^2)
(after weighting the residual has unit variance). The condition number is that of the regressor
with unit-norm columns (so units do not count); parameters whose direction lies in a numerically
null singular subspace are reported as unidentifiable (poor excitation).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from robust_drake.errors import DataError
from robust_drake.regressor import RANK_TOL  # noqa: F401  (the fits' rank cut, used by name from here)
from robust_drake.identification.data import DataWarning, IdentData, zero_phase_lowpass

#: condition number above which the excitation is called poor (warning)
COND_WARN = 1e4


def friction_columns(data: IdentData, out: np.ndarray | None = None) -> tuple[np.ndarray, list[str]]:
    """Baseline friction columns: Coulomb ``sign(qd_i)`` and viscous ``qd_i`` per joint (written
    into ``out`` (N, n, 2n) when given)."""
    N, n = data.qd.shape
    if out is None:
        Y = np.zeros((N, n, 2 * n))
    else:
        Y = out
        Y[...] = 0.0
    names = []
    for i in range(n):
        Y[:, i, 2 * i] = np.sign(data.qd[:, i])
        Y[:, i, 2 * i + 1] = data.qd[:, i]
        names += [f"fc{i + 1}", f"fv{i + 1}"]
    return Y, names


#: columns filtered per call in :func:`parallel_filter` (a block stays in cache: measured 0.40 s
#: instead of 0.71 s and 30 MB instead of 208 MB of temporaries for 20000 x 448 columns, the same bits)
FILTER_COLUMNS = 64
#: samples per call of the rigid-body regressor in :func:`rigid_body_columns` (its recursion's
#: temporaries grow with the samples: 450 MB for 20000 samples of serial7 at once, 125 MB in
#: blocks of 2048, as fast; every row is computed on its own, so the result is the same)
REGRESSOR_ROWS = 2048


def parallel_filter(data: IdentData, Y: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Apply the torque's zero-phase filter to regressor columns, segment by segment (each column
    is filtered on its own: done in blocks of ``FILTER_COLUMNS`` columns).  ``out`` (the shape of
    Y, may be Y itself: each block is read before it is written) receives the result; without it a
    new array is returned (Y itself when there is nothing to filter)."""
    cutoff = data.filter.cutoff_hz
    if cutoff is None or data.filter.derivatives == "given":
        if out is not None and out is not Y:
            out[...] = Y
            return out
        return Y
    out = np.empty(Y.shape) if out is None else out
    flat_in, flat_out = Y.reshape(Y.shape[0], -1), out.reshape(Y.shape[0], -1)
    for s in np.unique(data.segment):
        idx = np.nonzero(data.segment == s)[0]
        rows = slice(idx[0], idx[-1] + 1) if idx[-1] - idx[0] + 1 == len(idx) else idx
        dt = data.segment_period(s)
        for c in range(0, flat_in.shape[1], FILTER_COLUMNS):
            cols = slice(c, c + FILTER_COLUMNS)
            flat_out[rows, cols] = zero_phase_lowpass(flat_in[rows, cols], dt, cutoff, data.filter.order)
    return out


@dataclass
class LSResult:
    theta: np.ndarray
    names: list[str]
    se: np.ndarray  # standard errors (inf where unidentifiable)
    sigma: np.ndarray  # residual std per joint
    weights: np.ndarray  # row weight per joint (1 = OLS)
    cond: float
    rank: int
    unidentifiable: list[str]
    residual: np.ndarray  # (N, n) unweighted
    rms: np.ndarray  # (n,)
    N: int
    rss_weighted: float
    warnings: list[str] = field(default_factory=list)
    cov: np.ndarray | None = None  # covariance of theta (same scaling as ``se``)

    @property
    def p(self) -> int:
        return len(self.theta)

    def predict(self, Y: np.ndarray) -> np.ndarray:
        return Y @ self.theta

    def as_dict(self) -> dict:
        return {
            "parameters": {k: float(v) for k, v in zip(self.names, self.theta)},
            "standard_errors": {k: float(v) for k, v in zip(self.names, self.se)},
            "condition_number": float(self.cond), "rank": int(self.rank),
            "unidentifiable": list(self.unidentifiable),
            "rms": [float(x) for x in self.rms], "weights": [float(x) for x in self.weights],
        }


def _gram_eig(G: np.ndarray, tol: float):
    """Eigen-decomposition of the column-normalised Gram matrix G = A^T A.

    Singular values of the normalised A are sqrt(eigenvalues). Returns (scale, s, V, keep)."""
    d = np.sqrt(np.maximum(np.diag(G), 0.0))
    scale = np.where(d > 0, d, 1.0)
    Gs = G / np.outer(scale, scale)
    lam, V = np.linalg.eigh(Gs)
    lam, V = lam[::-1], V[:, ::-1]
    s = np.sqrt(np.maximum(lam, 0.0))
    keep = s >= tol * max(s[0], 1e-300)
    return scale, s, V, keep, d == 0


def identifiability(A: np.ndarray, names: list[str], tol: float = RANK_TOL, G: np.ndarray | None = None):
    """Condition number of the column-normalised regressor and unidentifiable parameters.

    ``A`` is the stacked (rows, p) regressor (or pass its Gram matrix ``G``).
    Returns ``(cond, rank, unidentifiable_names, scale)``.
    """
    G = A.T @ A if G is None else G
    scale, s, V, keep, zero = _gram_eig(G, tol)
    rank = int(keep.sum())
    cond = float(s[0] / s[-1]) if s.size and s[-1] > 0 else float("inf")
    bad = set(np.nonzero(zero)[0].tolist())
    for k in np.nonzero(~keep)[0]:
        v = np.abs(V[:, k])
        bad.update(np.nonzero(v > 0.2 * v.max())[0].tolist())
    return cond, rank, [names[i] for i in sorted(bad)], scale


def solve_gram(G: np.ndarray, g: np.ndarray, tol: float = RANK_TOL):
    """theta minimising ||A theta - b|| from G = A^T A, g = A^T b (truncated on null directions).

    Returns (theta, cov_unscaled = (A^T A)^+, keep mask, s, V, scale)."""
    scale, s, V, keep, _ = _gram_eig(G, tol)
    lam_inv = np.where(keep, 1.0 / np.where(keep, s, 1.0) ** 2, 0.0)
    Pinv = (V * lam_inv) @ V.T
    theta = Pinv @ (g / scale) / scale
    return theta, Pinv / np.outer(scale, scale), keep, s, V, scale


#: samples per block of :func:`solve_ls`'s normal equations
LS_ROWS = 4096


def solve_ls(Y: np.ndarray, tau: np.ndarray, names: list[str], weights=None,
             tol: float = RANK_TOL, warn: bool = True, rows=None) -> LSResult:
    """Least squares ``tau ~ Y theta`` (joints stacked), optional per-joint row weights.

    Solved through the normal equations of the column-normalised regressor (p x p; the data are
    touched once, so tens of thousands of samples cost milliseconds). Rank-deficient problems are
    solved in the minimum-norm sense on the identifiable subspace (truncated eigen-decomposition);
    the unidentifiable parameters are named and get ``se = inf``.

    ``rows`` (N, n) bool: the equation rows in use when others were weighted out by zeroing
    their columns and torque (``fitting.ColumnCache``, stiction); the residual RMS and the
    degrees of freedom count only those (None = all).
    """
    Y = np.asarray(Y, float)
    tau = np.asarray(tau, float)
    N, n, p = Y.shape
    if len(names) != p:
        raise ValueError(f"{p} columns but {len(names)} names")
    w = np.ones(n) if weights is None else np.asarray(weights, float)
    # normal equations by row blocks: the weighted copy of one block at a time, not of all
    # (N, n, p) (at 99.5k rows x 7 joints the joined weighted copy and einsum's were ~0.7 GB)
    G, g = np.zeros((p, p)), np.zeros(p)
    for r0 in range(0, N, LS_ROWS):
        Yw = (Y[r0:r0 + LS_ROWS] * w[None, :, None]).reshape(-1, p)
        G += Yw.T @ Yw
        g += Yw.T @ (tau[r0:r0 + LS_ROWS] * w[None, :]).reshape(-1)
    Yw = None  # the last block, before the residual's (N, n) arrays
    return solve_normal(G, g, lambda theta: tau - Y @ theta, names, w, N, tol, warn, rows)


def solve_normal(G: np.ndarray, g: np.ndarray, residual_of, names: list[str], w: np.ndarray, N: int,
                 tol: float = RANK_TOL, warn: bool = True, rows=None) -> LSResult:
    """:func:`solve_ls` from its normal equations G = Y^T W Y, g = Y^T W tau (W = diag(w_j^2)
    over joints) and ``residual_of(theta)`` = tau - Y theta (N, n), for callers that hold the
    Gram matrix already (``fitting.ColumnCache.gram``); ``rows`` as in :func:`solve_ls`.

    ``residual_of`` may instead be the float tau^T W tau: then no (N, n) residual is formed
    (``residual`` None, ``rms`` and ``sigma`` NaN) and the weighted residual sum of squares is
    :func:`rss_from_gram` (for the selection's many candidate fits, which read the coefficients)."""
    n = len(w)
    if not (np.all(np.isfinite(G)) and np.all(np.isfinite(g))):
        raise DataError("least squares: the regressor or the torque holds NaN or infinite values (clean the data; "
                        "nothing is dropped silently)")
    cond, rank, unident, _ = identifiability(None, names, tol, G=G)
    theta, cov0, keep, s, V, scale = solve_gram(G, g, tol)
    if callable(residual_of):
        resid = residual_of(theta)
        rss_w = float(np.sum((resid * w[None, :]) ** 2))
    else:
        resid, rss_w = None, rss_from_gram(G, g, float(residual_of), theta)
    used_count = N * n if rows is None else int(np.sum(rows))
    dof = max(used_count - rank, 1)
    cov = np.asarray(cov0, float) * rss_w / dof
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    for u in unident:
        se[names.index(u)] = np.inf
    msgs = []
    if cond > COND_WARN or unident:
        msgs.append(poor_excitation_text(cond, unident))
        if warn:
            warnings.warn(msgs[-1], DataWarning, stacklevel=3)
    if resid is None:
        rms = np.full(n, np.nan)
    else:
        used = np.ones((N, n)) if rows is None else np.asarray(rows, float)
        rms = np.sqrt(np.sum(resid**2 * used, axis=0) / np.maximum(used.sum(axis=0), 1.0))
    return LSResult(
        theta=theta, names=list(names), se=se, sigma=rms, weights=w, cond=cond, rank=rank,
        unidentifiable=unident, residual=resid, rms=rms, N=N, rss_weighted=rss_w, warnings=msgs, cov=cov,
    )


def rss_from_gram(G: np.ndarray, g: np.ndarray, tt: float, theta: np.ndarray) -> float:
    """||b - A theta||^2 = b^T b - 2 theta^T A^T b + theta^T A^T A theta from G = A^T A,
    g = A^T b, tt = b^T b (clipped at 0 against round-off)."""
    theta = np.asarray(theta, float)
    return max(float(tt - 2.0 * theta @ g + theta @ G @ theta), 0.0)


def poor_excitation_text(cond: float, unidentifiable: list[str]) -> str:
    """The one-line poor-excitation warning: the condition number and how many parameters are
    unidentifiable (their names, combinations with noise-level coefficients such as
    ``54448.4*Iyz_link4``, are listed in the fit's ``unidentifiable``, not in the message).
    Starts with :data:`POOR_EXCITATION` (the repair report keeps the first such warning only)."""
    k = len(unidentifiable)
    return (f"{POOR_EXCITATION}: condition number {cond:.3g} of the column-normalised regressor"
            + (f"; {k} unidentifiable parameter{'s' if k > 1 else ''} (listed under identifiability)" if k else ""))


#: first words of the poor-excitation warning
POOR_EXCITATION = "poor excitation"


def solve_wls(Y, tau, names, iterations: int = 2, tol: float = RANK_TOL, warn: bool = True,
              rows=None) -> LSResult:
    """Two-step weighted LS: OLS, then rows of joint j weighted by 1 / sigma_j (repeated);
    ``rows`` as in :func:`solve_ls`."""
    res = solve_ls(Y, tau, names, tol=tol, warn=warn, rows=rows)
    for _ in range(iterations):
        sigma = np.maximum(res.rms, 1e-9 * max(res.rms.max(), 1e-300))
        res = solve_ls(Y, tau, names, weights=1.0 / sigma, tol=tol, warn=False, rows=rows)
    return res


def rigid_body_columns(regressor, data: IdentData, out: np.ndarray | None = None) -> tuple[np.ndarray, list[str]]:
    """Drake-derived base-parameter columns ``(N, n, p_base)`` and their names, evaluated in blocks
    of ``REGRESSOR_ROWS`` samples written into ``out`` (N, n, p_base) when given (e.g. a slice of
    the ColumnCache's base block: no second full-size array), else into a new array."""
    names = list(regressor.base_names)
    shape = (data.N, data.n, len(names))
    Y = np.empty(shape) if out is None else out
    if Y.shape != shape:
        raise DataError(f"rigid_body_columns: out has shape {Y.shape}, expected {shape}")
    edges = np.linspace(0, data.N, max(1, data.N // REGRESSOR_ROWS) + 1).round().astype(int)
    for a, b in zip(edges[:-1], edges[1:]):  # blocks of >= REGRESSOR_ROWS rows (no short tail)
        rows = slice(int(a), int(b))
        block = np.asarray(regressor.evaluate(data.q[rows], data.qd[rows], data.qdd[rows]), float)
        if block.shape != (rows.stop - rows.start,) + shape[1:]:
            raise DataError(f"regressor returned shape {block.shape} for {rows.stop - rows.start} samples, "
                            f"expected ({rows.stop - rows.start}, {data.n}, {len(names)})")
        Y[rows] = block
    return Y, names


_UNDAMPED: dict = {}


def load_regressor(robot):
    """The Drake-derived base-parameter regressor of a robot name in ``models/`` or a URDF path.

    Identification fits one viscous level per joint (``fv_j``, :func:`friction_columns`), so a URDF's
    ``<dynamics damping=...>`` column ``b_<joint>`` (the same ``qd_j``) would duplicate it: the
    regressor is then derived from the plant with that damping set to 0 (``damping_dropped`` names
    the joints and the URDF's values; the fitted ``fv_j`` carries the damping, and the replay's plant
    has the URDF damping set to 0 too)."""
    import os

    from robust_drake.regressor import InverseDynamicsRegressor

    reg = InverseDynamicsRegressor.from_robot(robot)
    damped = [(name.split("_", 1)[1], float(reg.plant.GetJointByName(name.split("_", 1)[1]).default_damping_vector()[0]))
              for name, kind, _ in getattr(reg, "_extras", []) if kind == "b"]
    if not damped:
        reg.damping_dropped = []
        return reg
    from robust_drake.models import make_plant, resolve_urdf

    path = resolve_urdf(robot)
    key = (str(path), os.path.getmtime(path))
    if key not in _UNDAMPED:
        def undamped(plant):
            for name, _ in damped:
                joint = plant.GetJointByName(name)
                joint.set_default_damping_vector(np.zeros(joint.num_velocities()))

        plain = InverseDynamicsRegressor(make_plant(str(path), before_finalize=undamped), urdf=str(path))
        plain.damping_dropped = damped
        _UNDAMPED[key] = plain
    return _UNDAMPED[key]
