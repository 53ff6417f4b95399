"""Columns of a model and what it predicts: the shared base of selection, IV and repair.

``ColumnCache`` holds the parallel-filtered columns of one dataset (rigid body + Coulomb/viscous
friction + each effect's columns); ``predict_tau`` is the output-error prediction of the measured
torque (implicit for effects whose columns contain the torque); ``fit_model`` the final weighted
least-squares fit. Kept below ``selection.py`` and ``instruments.py`` so neither imports the other
in a cycle.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict

import numpy as np

from robust_drake.identification.data import IdentData
from robust_drake.identification.least_squares import (
    LSResult, friction_columns, parallel_filter, rigid_body_columns, solve_ls, solve_normal,
)


#: bytes of filtered effect columns a ColumnCache keeps (least recently used first out; evicted
#: columns are rebuilt on demand, their Gram products stay memoised). 163 serial7 candidates hold
#: ~220 MB at 20k samples (all kept, as before) and ~1.1 GB at 100k (then each is rebuilt at most
#: once per selection step instead of all being held at once).
EFFECT_MEMO_BYTES = 320 * 2**20

#: equation rows (samples x joints) per block of :meth:`ColumnCache.qr_r`'s incremental QR.
QR_ROWS = 16384


def effect_label(effect) -> str:
    if isinstance(getattr(effect, "name", None), str):
        return effect.name
    j = getattr(effect, "joint", None)
    extra = ""
    for attr in ("label",):
        if hasattr(effect, attr) and isinstance(getattr(effect, attr), str):
            return getattr(effect, attr)
    shape = getattr(effect, "shape", None)
    if shape:
        extra = "(" + ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in shape.items()) + ")"
    return f"{effect.kind}" + (f"[{j + 1}]" if j is not None else "") + extra  # joints from 1, as Effect.name


def row_runs(rows, N: int) -> list[slice] | None:
    """``rows`` (None, a slice, or a boolean mask of length N) as a list of contiguous slices,
    so blocks of the (N, n, p) columns are read as views instead of fancy-indexed copies.
    None for anything else (an index array): the caller indexes directly."""
    if rows is None:
        return [slice(0, N)]
    if isinstance(rows, slice):
        return [slice(*rows.indices(N))]
    rows = np.asarray(rows)
    if rows.dtype != bool or rows.shape != (N,):
        return None
    edges = np.diff(np.concatenate([[0], rows.view(np.int8), [0]]))
    return [slice(a, b) for a, b in zip(np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0])]


class ColumnCache:
    """Parallel-filtered columns of one dataset: rigid body, friction, and each effect (memoised).

    The columns are kept as blocks (``base`` and one block per effect); :meth:`model` joins them
    for a solver, :meth:`explicit_prediction` and :meth:`gram` work block by block without
    building the joined (N, n, p) array, and :meth:`gram` memoises the per-block products, so
    the baseline columns' Gram matrix is computed once and shared by every candidate effect.

    ``exclude`` (N, n) bool: rows of joint j's equation left out of every fit and held-out score
    (stiction, :func:`~robust_drake.identification.data.friction_exclusion`). They are weighted
    out by zeroing both the columns and the torque there: ``data`` is the dataset with those
    torques set to 0 (``source`` the dataset as given), so every consumer of ``model()`` and
    ``data.tau`` (least squares, IV, held-out folds, consistent fit) ignores them and their
    residual is 0. ``rows`` is the complementary mask; :meth:`rms` counts only those rows."""

    def __init__(self, data: IdentData, regressor, exclude=None):
        self.source = data
        self.exclude = None if exclude is None or not np.any(exclude) else np.asarray(exclude, bool)
        self.keep = None if self.exclude is None else (~self.exclude).astype(float)
        self.data = data if self.keep is None else data.with_tau(data.tau * self.keep)
        # one (N, n, p) array built in place: regressor rows in blocks, friction, then the filter
        # column block by column block and the mask (peak = this array plus blocks; the joined
        # copies of the rigid, friction, filtered and masked columns held 4x it at once)
        p_rb, n = len(regressor.base_names), data.n
        base = np.empty((data.N, n, p_rb + 2 * n))
        _, nrb = rigid_body_columns(regressor, data, out=base[:, :, :p_rb])
        _, nfr = friction_columns(data, out=base[:, :, p_rb:])
        parallel_filter(data, base, out=base)
        if self.keep is not None:
            base *= self.keep[:, :, None]
        self.base = base
        self.base_names = nrb + nfr
        self.n_rigid = len(nrb)
        self._effects: OrderedDict = OrderedDict()  # key -> (columns, names, effect), LRU order
        self._held: dict = {}  # key -> effect: the ids in memo keys stay unique after an eviction
        self._effect_bytes = 0
        self.memo_bytes = EFFECT_MEMO_BYTES
        self._grams: dict = {}
        self._lefts: dict = {}
        #: memo key -> the joints where that block's columns are not all zero (None = all; a
        #: single-joint effect's (N, n, k) block is zero on the other joints: its Gram products
        #: are read on its joint only, :func:`_wsum`)
        self._joints: dict = {"base": None}
        self._last_prediction: tuple = (None, None)

    def _key(self, effect):
        # keyed by the object and holding a reference to it (an id() key could be reused)
        return (effect_label(effect), id(effect))

    @property
    def rows(self) -> np.ndarray | None:
        """(N, n) bool: the equation rows in use (None = all)."""
        return None if self.exclude is None else ~self.exclude

    def _masked(self, Y: np.ndarray) -> np.ndarray:
        return Y if self.keep is None else Y * self.keep[:, :, None]

    def rms(self, residual) -> np.ndarray:
        """RMS per joint of a residual (N, n) over the rows in use."""
        r2 = np.asarray(residual, float) ** 2
        if self.keep is None:
            return np.sqrt(np.mean(r2, axis=0))
        return np.sqrt(np.sum(r2 * self.keep, axis=0) / np.maximum(self.keep.sum(axis=0), 1.0))

    def effect(self, effect) -> tuple[np.ndarray, list[str]]:
        """The effect's filtered (and masked) columns (N, n, k) and names, memoised up to
        ``memo_bytes`` (least recently used evicted; rebuilt identically when asked again)."""
        key = self._key(effect)
        hit = self._effects.get(key)
        if hit is not None:
            self._effects.move_to_end(key)
            return hit[:2]
        Y, names = effect.columns(self.source)  # the measured torque, not the zeroed one
        Y = np.array(Y, dtype=float, order="C")  # our own copy (an effect may hold its array)
        if Y.ndim == 2:
            Y = Y[:, :, None]
        joints = nonzero_joints(Y)
        if joints is None:
            parallel_filter(self.data, Y, out=Y)  # in place: no filtered and masked copies at once
        elif joints:  # a single-joint effect: the zero-phase filter maps the zero joints to exact zeros
            Y[:, list(joints), :] = parallel_filter(self.data, np.ascontiguousarray(Y[:, list(joints), :]))
        if self.keep is not None:
            Y *= self.keep[:, :, None]
        self._effects[key] = (Y, list(names), effect)
        self._held[key] = effect
        self._joints[key] = joints if self.keep is None else nonzero_joints(Y)
        self._effect_bytes += Y.nbytes
        while self._effect_bytes > self.memo_bytes and len(self._effects) > 1:
            old = next(iter(self._effects))
            if old == key:
                break
            self._effect_bytes -= self._effects.pop(old)[0].nbytes
        return Y, list(names)

    def blocks(self, effects) -> tuple[list[np.ndarray], list, list[slice]]:
        """The column blocks [base, effect 1, ...], their memo keys and their column slices."""
        blocks, keys, slices = [self.base], ["base"], []
        start = self.base.shape[2]
        for e in effects:
            Y, _ = self.effect(e)
            blocks.append(Y)
            keys.append(self._key(e))
            slices.append(slice(start, start + Y.shape[2]))
            start += Y.shape[2]
        return blocks, keys, slices

    def release(self, keep=()) -> None:
        """Forget the columns of every effect but ``keep`` and all memoised products (after the
        selection and the nominal comparison: 163 candidates of serial7 hold ~220 MB at 20k samples)."""
        kept = {self._key(e) for e in keep}
        self._effects = OrderedDict((k, v) for k, v in self._effects.items() if k in kept)
        self._held = {k: v for k, v in getattr(self, "_held", {}).items() if k in kept}
        self._effect_bytes = sum(v[0].nbytes for v in self._effects.values())
        self._grams.clear()
        self._lefts.clear()
        self._joints = {k: v for k, v in getattr(self, "_joints", {}).items() if k == "base" or k in kept}
        self._last_prediction = (None, None)

    def excluding(self, extra: np.ndarray) -> "ColumnCache":
        """A cache of the same columns that also leaves out the rows ``extra`` (N, n) bool of each
        joint's equation (a copy of the baseline block, masked; effect columns and Gram products
        are rebuilt on demand, never shared with this cache)."""
        new = object.__new__(ColumnCache)
        new.__dict__.update(self.__dict__)
        exclude = np.asarray(extra, bool) if self.exclude is None else (self.exclude | np.asarray(extra, bool))
        new.exclude = exclude if exclude.any() else None
        new.keep = None if new.exclude is None else (~new.exclude).astype(float)
        new.data = self.source if new.keep is None else self.source.with_tau(self.source.tau * new.keep)
        new.base = self.base.copy() if new.keep is None else self.base * new.keep[:, :, None]
        new._effects, new._held, new._effect_bytes = OrderedDict(), {}, 0
        new._grams, new._lefts, new._joints = {}, {}, {"base": None}
        new._last_prediction = (None, None)
        return new

    def names(self, effects) -> list[str]:
        names = list(self.base_names)
        for e in effects:
            names += [f"{effect_label(e)}:{x}" for x in self.effect(e)[1]]
        return names

    def model(self, effects) -> tuple[np.ndarray, list[str], list[slice]]:
        """The joined columns (N, n, p); without effects a read-only view of ``base`` (no copy)."""
        blocks, _, slices = self.blocks(effects)
        if not effects:
            Y = self.base.view()
            Y.flags.writeable = False
            return Y, self.names(effects), slices
        return np.concatenate(blocks, axis=2), self.names(effects), slices

    def tau_sq(self, weights) -> float:
        """tau^T W tau = sum_j w_j^2 sum_rows tau_j^2 over the rows in use (memoised per weights)."""
        w2 = np.asarray(weights, float) ** 2
        key = ("tt", w2.tobytes())
        if key not in self._grams:
            self._grams[key] = float(np.sum(self.data.tau**2 @ w2))
        return self._grams[key]

    def fit_ls(self, effects, weights=None, parts=None, warn: bool = True, residual: bool = True) -> LSResult:
        """``solve_ls(*self.model(effects)[:2] ...)`` (weighted least squares, equation-error
        residual) from the memoised block Gram matrices of :meth:`gram`: ``parts`` is a list of
        boolean row masks that partition the rows (e.g. the cross-validation folds, whose
        products the held-out score reuses); default all rows. ``residual`` False: no (N, n)
        residual is formed (``residual`` None, ``rms`` NaN; ``rss_weighted`` from the Gram
        matrix): the selection's candidate fits, which read the coefficients."""
        w = np.ones(self.data.n) if weights is None else np.asarray(weights, float)
        parts = [np.ones(self.data.N, bool)] if parts is None else parts
        if not np.array_equal(np.sum(parts, axis=0), np.ones(self.data.N)):
            raise ValueError("parts must partition the rows")
        Gs, gs = self.gram(effects, w, parts)
        resid = (lambda th: self.data.tau - self.explicit_prediction(effects, th)) if residual else self.tau_sq(w)
        return solve_normal(sum(Gs), sum(gs), resid, self.names(effects), w, self.data.N, warn=warn, rows=self.rows)

    def explicit_prediction(self, effects, theta, mask=None, rows=None, joints=None) -> np.ndarray:
        """sum over blocks of Y_block[rows] @ theta_block (N_rows, n), skipping the columns where
        ``mask`` (p,) is False: ``Y[rows][:, :, mask] @ theta[mask]`` without the joined copy.
        ``joints`` (a list; None = all): only those joints' columns are computed, the others are 0.
        The last all-rows prediction is remembered (the selection's fit residual and its output
        error ask for the same one)."""
        blocks, keys, slices = self.blocks(effects)
        theta = np.asarray(theta, float)
        p = slices[-1].stop if slices else self.base.shape[2]
        mask = np.ones(p, bool) if mask is None else np.asarray(mask, bool)
        if joints is not None:
            return self._joint_prediction(blocks, slices, theta, mask, rows, list(joints))
        memo = (tuple(keys), mask.tobytes(), theta.tobytes()) if rows is None else None
        if memo is not None and self._last_prediction[0] == memo:
            return self._last_prediction[1].copy()
        spans = [slice(0, self.base.shape[2])] + slices
        parts = [(Y, sl) for Y, sl in zip(blocks, spans) if mask[sl].any()]
        runs = row_runs(rows, self.data.N)
        if runs is None or not parts:
            n_rows = len(self.data.tau[slice(None) if rows is None else rows])
            return sum((Y[rows][:, :, mask[sl]] @ theta[sl][mask[sl]] for Y, sl in parts),
                       np.zeros((n_rows, self.data.n)))
        out = np.zeros((sum(r.stop - r.start for r in runs), self.data.n))
        at = 0
        for r in runs:
            k = r.stop - r.start
            for Y, sl in parts:
                m = mask[sl]
                Yr = Y[r] if m.all() else Y[r][:, :, m]
                out[at:at + k] += (Yr.reshape(-1, Yr.shape[2]) @ theta[sl][m]).reshape(k, -1)
            at += k
        if memo is not None:
            self._last_prediction = (memo, out.copy())
        return out

    def _joint_prediction(self, blocks, slices, theta, mask, rows, joints) -> np.ndarray:
        """:meth:`explicit_prediction` on ``joints`` only (N_rows, n), the other joints 0."""
        spans = [slice(0, self.base.shape[2])] + slices
        rows = slice(None) if rows is None else rows
        n_rows = len(self.data.tau[rows])
        out = np.zeros((n_rows, self.data.n))
        for Y, sl in zip(blocks, spans):
            m = mask[sl]
            if not m.any():
                continue
            for j in joints:
                out[:, j] += Y[rows, j, :][:, m] @ theta[sl][m]
        return out

    def joint_gram(self, effects, masks):
        """Per joint and row mask, the unweighted products of joint j's equations:
        ``G[m, j] = sum_{rows in mask m} Y[r, j, :]^T Y[r, j, :]`` (p, p), ``g[m, j] = sum Y^T tau_j``
        (p,), ``tt[m, j] = sum tau_j^2``, memoised per block pair like :meth:`gram` (a
        single-joint block's products on its joint only). The squared output error of joint j
        on mask m of an explicit model theta is tt - 2 theta^T g + theta^T G theta
        (``selection.heldout_sse``)."""
        yb, keys, slices = self.blocks(effects)
        spans = [slice(0, self.base.shape[2])] + slices
        p, n = spans[-1].stop, self.data.n
        runs = [row_runs(mk, self.data.N) for mk in masks]
        digest = hashlib.blake2b(np.packbits(np.asarray(masks, bool)).tobytes(), digest_size=16).digest()
        ctx = (len(masks), digest)
        G, g = np.zeros((len(masks), n, p, p)), np.zeros((len(masks), n, p))
        tkey = ("Jt",) + ctx
        if tkey not in self._grams:
            self._grams[tkey] = np.array([[sum(float(self.data.tau[r, j] @ self.data.tau[r, j]) for r in rr)
                                           for j in range(n)] for rr in runs])
        tau = self.data.tau[:, :, None]
        for a, (Ya, ka, sa) in enumerate(zip(yb, keys, spans)):
            ja = _joints_of(self, ka)
            key = ("Jg", ka) + ctx
            if key not in self._grams:
                self._grams[key] = _joint_sums(Ya, tau, runs, ja)[..., 0]
            g[:, :, sa] = self._grams[key]
            for Yb, kb, sb in zip(yb[a:], keys[a:], spans[a:]):
                key = ("JG", ka, kb) + ctx
                if key not in self._grams:
                    self._grams[key] = _joint_sums(Ya, Yb, runs, _common_joints(ja, _joints_of(self, kb)))
                G[:, :, sa, sb] = self._grams[key]
                if sb != sa:
                    G[:, :, sb, sa] = np.swapaxes(self._grams[key], 2, 3)
        return G, g, self._grams[tkey]

    def qr_r(self, effects, weights, left: "ColumnCache | None" = None, block_rows: int = QR_ROWS) -> np.ndarray:
        """R (p+1, p+1) of the QR factorisation of [A | b], A = W Y (``self.model(effects)`` with
        joint weights W, equations stacked), b = W tau; with ``left`` (instrument columns Z on the
        same rows) of [P_Z A | b], (the two-stage IV regressor). ||A x - b||^2 = ||R[:p, :p] x - R[:p, p]||^2 + R[p, p]^2, so
        R^T R = [A | b]^T [A | b] as from ``np.linalg.qr(np.column_stack([A, b]), mode="r")``.
        ``left``: P_Z is the orthogonal projection on the span of W Z (as
        ``Zw @ lstsq(Zw, A)``).

        Built by row blocks (incremental Householder QR: R = qr([R; next block])) from the column
        blocks, never the joined (N n, p) arrays (the joined copy, the weighted copy, [A | b] and
        QR's own copy held ~4x the columns: ~1.3 GB at 99.5k rows x 7 joints). With ``left`` the
        QR runs on [W Z | A | b] and P_Z A's factor is read off it: with R = [[Rzz, Rza, Rzb],
        [0, Raa, Rab], [0, 0, rbb]], Q_z^T A = Rza, Q_z^T b = Rzb and the part of b orthogonal to
        W Z has norm sqrt(||Rab||^2 + rbb^2), so [P_Z A | b] has the factor of
        [[Rza, Rzb], [0, sqrt(||Rab||^2 + rbb^2)]]."""
        w = np.asarray(weights, float)
        yb, _, _ = self.blocks(effects)
        zb = [] if left is None else left.blocks(effects)[0]
        cols = sum(Y.shape[2] for Y in zb) + sum(Y.shape[2] for Y in yb) + 1
        R = np.zeros((0, cols))
        N = self.data.N
        step = max(1, int(block_rows) // max(self.data.n, 1))
        for r0 in range(0, N, step):
            r = slice(r0, min(N, r0 + step))
            M = np.concatenate([Y[r] for Y in zb] + [Y[r] for Y in yb] + [self.data.tau[r][:, :, None]], axis=2)
            M *= w[None, :, None]
            R = np.linalg.qr(np.vstack([R, M.reshape(-1, cols)]), mode="r")
        if left is None:
            return R
        pz = cols - 1 - sum(Y.shape[2] for Y in yb)
        Rza, Rzb = R[:pz, pz:-1], R[:pz, -1]
        tail = float(np.sqrt(np.sum(R[pz:, -1] ** 2)))  # ||Rab||^2 + rbb^2
        small = np.zeros((pz + 1, cols - pz))
        small[:pz, :-1], small[:pz, -1], small[pz, -1] = Rza, Rzb, tail
        return np.linalg.qr(small, mode="r")

    def gram(self, effects, weights, masks, left: "ColumnCache | None" = None):
        """Per-mask normal equations of the weighted model: for every boolean row mask M,
        ``G_M = sum_{rows in M} Z^T W Y`` (p, p) and ``g_M = sum Z^T W tau`` (p,), with
        W = diag(w_j^2) over joints, Y = ``self.model(effects)`` and Z = ``left.model(effects)``
        (instrument columns on the same rows; default Z = Y).

        Assembled from memoised block products (Z_a^T W Y_b per pair of blocks, Z_a^T W tau per
        block), so across the candidates of a selection step only the new effect's products are
        computed; the memo is keyed by the blocks, the weights and the masks."""
        w2 = np.asarray(weights, float) ** 2
        zc = self if left is None else left
        yb, ykeys, slices = self.blocks(effects)
        zb, zkeys, _ = zc.blocks(effects)
        spans = [slice(0, self.base.shape[2])] + slices
        p = spans[-1].stop
        runs = [row_runs(m, self.data.N) for m in masks]
        self._lefts[id(zc)] = zc  # held, so its id cannot be reused by another cache
        digest = hashlib.blake2b(np.packbits(np.asarray(masks, bool)).tobytes(), digest_size=16).digest()
        ctx = (id(zc), w2.tobytes(), len(masks), digest)
        Gs = [np.empty((p, p)) for _ in masks]
        gs = [np.empty(p) for _ in masks]
        for a, (Za, ka, sa) in enumerate(zip(zb, zkeys, spans)):
            key = ("g", ka) + ctx
            if key not in self._grams:
                self._grams[key] = [_wsum(Za, self.data.tau[:, :, None], w2, r, _joints_of(zc, ka))[:, 0]
                                    for r in runs]
            for g, val in zip(gs, self._grams[key]):
                g[sa] = val
            for Yb, kb, sb in zip(yb, ykeys, spans):
                key = ("G", ka, kb) + ctx
                if key not in self._grams:
                    tkey = ("G", kb, ka) + ctx
                    if left is None and tkey in self._grams:
                        self._grams[key] = [v.T for v in self._grams[tkey]]
                    else:
                        on = _common_joints(_joints_of(zc, ka), _joints_of(self, kb))
                        self._grams[key] = [_wsum(Za, Yb, w2, r, on) for r in runs]
                for G, val in zip(Gs, self._grams[key]):
                    G[sa, sb] = val
        return Gs, gs


def nonzero_joints(Y: np.ndarray) -> tuple | None:
    """The joints j where the block Y (N, n, k) has a nonzero column entry, or None when that
    is every joint (a single-joint effect: one joint)."""
    nz = np.flatnonzero(np.any(Y != 0, axis=(0, 2)))
    return None if len(nz) == Y.shape[1] else tuple(int(j) for j in nz)


def _joints_of(cache, key):
    """The nonzero joints of ``cache``'s block ``key`` (None = all or not known: a cache built
    without :meth:`ColumnCache.effect`'s bookkeeping)."""
    return getattr(cache, "_joints", {}).get(key)


def _common_joints(a, b):
    """Joints where two blocks are both nonzero (None = all joints)."""
    if a is None:
        return b
    if b is None:
        return a
    return tuple(j for j in a if j in b)


def _joint_sums(A: np.ndarray, B: np.ndarray, runs: list, joints=None) -> np.ndarray:
    """(masks, n, a, b): per row mask (its runs) and joint j, sum_rows A[r, j, :]^T B[r, j, :]
    (zeros on the joints outside ``joints``, None = all)."""
    n = A.shape[1]
    out = np.zeros((len(runs), n, A.shape[2], B.shape[2]))
    for m, rr in enumerate(runs):
        for j in range(n) if joints is None else joints:
            for r in rr:
                out[m, j] += A[r, j, :].T @ B[r, j, :]
    return out


def _wsum(A: np.ndarray, B: np.ndarray, w2: np.ndarray, runs: list[slice], joints=None) -> np.ndarray:
    """sum_j w2_j sum_{rows in runs} A[rows, j, :]^T B[rows, j, :]: per run one product of the
    stacked (rows * n, p) views, the joint weights applied to a copy of the narrower block.
    ``joints`` (None = all): the joints where A or B can be nonzero (the others add exact
    zeros): then per run and joint one product of the (rows, k) views of that joint (a
    single-joint effect's products cost 1/n of the stacked ones; equal up to round-off)."""
    out = np.zeros((A.shape[2], B.shape[2]))
    if joints is not None:
        for r in runs:
            for j in joints:
                out += w2[j] * (A[r, j, :].T @ B[r, j, :])
        return out
    for r in runs:
        a, b = A[r].reshape(-1, A.shape[2]), B[r].reshape(-1, B.shape[2])
        wr = np.tile(w2, r.stop - r.start)[:, None]
        out += (a * wr).T @ b if a.shape[1] <= b.shape[1] else a.T @ (b * wr)
    return out


def implicit_mask(effects, slices, p: int) -> tuple[list, np.ndarray]:
    """Effects whose columns use the measured torque (torque_scale, load-dependent friction):
    their prediction is implicit, tau_hat = m + Phi(tau_hat) c. Returns ([(effect, slice)], mask
    of the explicit columns)."""
    imp = [(e, sl) for e, sl in zip(effects, slices)
           if getattr(e, "needs_tau", False) and not getattr(e, "uses_taud", False)]
    mask = np.ones(p, bool)
    for _, sl in imp:
        mask[sl] = False
    return imp, mask


def _generic_columns(effect) -> bool:
    """True when ``effect.evaluate_columns`` is the base class's (``Effect.evaluate_columns``:
    joint j's features ``_features(j, ...)`` in its own column group, zeros elsewhere)."""
    owner = next((c for c in type(effect).__mro__ if "evaluate_columns" in vars(c)), None)
    return owner is not None and owner.__name__ == "Effect" and hasattr(effect, "_features")


def implicit_term(effect, q, qd, qdd, tau, coef) -> np.ndarray:
    """``effect.evaluate_columns(q, qd, qdd, tau) @ coef`` (N, n), the implicit prediction's
    term, without the (N, n, k) column array when the columns are the generic per-joint ones
    (joint j's features only in row j): out[:, j] = _features(j) @ coef_j. The zeros of the
    other joints' groups add exact zeros, so the values are those of the joined product (one
    coefficient per group: bit for bit)."""
    if not _generic_columns(effect) or getattr(effect, "uses_taud", False):
        return effect.evaluate_columns(q, qd, qdd, tau) @ coef
    q = np.atleast_2d(np.asarray(q, dtype=float))
    N, n = q.shape
    coef = np.asarray(coef, float)
    m = len(effect.coef_names)
    out = np.zeros((N, n))
    shared = effect.shared and effect.joint is None
    for i, j in enumerate(effect.joints(n)):
        f = np.asarray(effect._features(j, q, qd, qdd, tau, None), float).reshape(N, m)
        c = coef if shared else coef[i * m:(i + 1) * m]
        out[:, j] = f[:, 0] * c[0] if m == 1 else f @ c
    return out


def predict_tau(cache: "ColumnCache", effects, theta, rows=None, iterations: int = 30,
                joints=None) -> np.ndarray:
    """Output-error prediction of the measured torque (N, n).

    Equation error r = tau - Y theta is the right quantity to *fit* but not to *judge* a model
    whose columns contain tau itself: a torque_scale column -tau_j with coefficient -> -1 would
    shrink the equation error of joint j without predicting anything. So models are judged on
    tau - tau_hat with tau_hat the fixed point of tau_hat = Y_explicit theta + Phi(tau_hat) c
    (unfiltered Phi; a contraction for the admissible |c| < 1, see ``PLAUSIBLE``).

    ``joints`` (a list; None = all): only those joints' columns are predictions (the others are
    not); exact when every implicit effect reads its own joint's torque only
    (``Effect.own_joint_tau``): the caller checks (``selection.heldout_sse``)."""
    _, _, slices = cache.blocks(effects)
    p = slices[-1].stop if slices else cache.base.shape[2]
    imp, mask = implicit_mask(effects, slices, p)
    m = cache.explicit_prediction(effects, theta, mask, rows, joints)
    rows = slice(None) if rows is None else rows
    if not imp:
        return m
    d = cache.data
    q, qd, qdd = d.q[rows], d.qd[rows], d.qdd[rows]
    cols = slice(None) if joints is None else list(joints)  # the columns iterated
    keep = None if cache.keep is None else cache.keep[rows][:, cols]
    tau_hat = m.copy()
    for _ in range(iterations):
        new = m[:, cols] + sum(implicit_term(e, q, qd, qdd, tau_hat, theta[sl])[:, cols] for e, sl in imp)
        if keep is not None:
            new *= keep
        done = np.max(np.abs(new - tau_hat[:, cols]), initial=0.0) < 1e-10
        tau_hat[:, cols] = new
        if done:
            break
    return tau_hat


def fit_model(cache: ColumnCache, effects, weights=None) -> tuple[LSResult, list[slice]]:
    """Final LS fit of baseline + effects on all fit data with fixed per-joint ``weights``
    (the selection's baseline weights; None = OLS). ``residual``/``rms`` are output errors."""
    Y, names, slices = cache.model(effects)
    res = solve_ls(Y, cache.data.tau, names, weights=weights, rows=cache.rows)
    res.residual = cache.data.tau - predict_tau(cache, effects, res.theta)
    res.rms = cache.rms(res.residual)
    return res, slices


def predict(cache: ColumnCache, effects, fit: LSResult) -> np.ndarray:
    return predict_tau(cache, effects, fit.theta)
