"""Columns of a model and what it predicts: the shared base of selection, IV and repair.

``ColumnCache`` holds the parallel-filtered columns of one dataset (rigid body + Coulomb/viscous
friction + each effect's columns); ``predict_tau`` is the output-error prediction of the measured
torque (implicit for effects whose columns contain the torque); ``fit_model`` the final weighted
least-squares fit. Kept below ``selection.py`` and ``instruments.py`` so neither imports the other
in a cycle.
"""

from __future__ import annotations

import numpy as np

from robust_drake.identification.data import IdentData
from robust_drake.identification.least_squares import (
    LSResult, friction_columns, parallel_filter, rigid_body_columns, solve_ls,
)


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
    return f"{effect.kind}" + (f"[joint {j}]" if j is not None else "") + extra


class ColumnCache:
    """Parallel-filtered columns of one dataset: rigid body, friction, and each effect (memoised).

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
        Yrb, nrb = rigid_body_columns(regressor, data)
        Yfr, nfr = friction_columns(data)
        self.base = self._masked(parallel_filter(data, np.concatenate([Yrb, Yfr], axis=2)))
        self.base_names = nrb + nfr
        self.n_rigid = len(nrb)
        self._effects: dict = {}

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
        # keyed by the object and holding a reference to it (an id() key could be reused)
        key = (effect_label(effect), id(effect))
        if key not in self._effects:
            Y, names = effect.columns(self.source)  # the measured torque, not the zeroed one
            Y = np.asarray(Y, float)
            if Y.ndim == 2:
                Y = Y[:, :, None]
            self._effects[key] = (self._masked(parallel_filter(self.data, Y)), list(names), effect)
        return self._effects[key][:2]

    def model(self, effects) -> tuple[np.ndarray, list[str], list[slice]]:
        blocks, names, slices = [self.base], list(self.base_names), []
        start = self.base.shape[2]
        for e in effects:
            Y, nm = self.effect(e)
            blocks.append(Y)
            names += [f"{effect_label(e)}:{x}" for x in nm]
            slices.append(slice(start, start + Y.shape[2]))
            start += Y.shape[2]
        return np.concatenate(blocks, axis=2), names, slices


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


def predict_tau(cache: "ColumnCache", effects, theta, rows=None, iterations: int = 30) -> np.ndarray:
    """Output-error prediction of the measured torque (N, n).

    Equation error r = tau - Y theta is the right quantity to *fit* but not to *judge* a model
    whose columns contain tau itself: a torque_scale column -tau_j with coefficient -> -1 would
    shrink the equation error of joint j without predicting anything. So models are judged on
    tau - tau_hat with tau_hat the fixed point of tau_hat = Y_explicit theta + Phi(tau_hat) c
    (unfiltered Phi; a contraction for the admissible |c| < 1, see ``PLAUSIBLE``)."""
    Y, _, slices = cache.model(effects)
    rows = slice(None) if rows is None else rows
    imp, mask = implicit_mask(effects, slices, Y.shape[2])
    m = Y[rows][:, :, mask] @ theta[mask]
    if not imp:
        return m
    d = cache.data
    q, qd, qdd = d.q[rows], d.qd[rows], d.qdd[rows]
    tau_hat = m.copy()
    for _ in range(iterations):
        new = m + sum(e.evaluate_columns(q, qd, qdd, tau_hat) @ theta[sl] for e, sl in imp)
        if cache.keep is not None:
            new = new * cache.keep[rows]
        done = np.max(np.abs(new - tau_hat)) < 1e-10
        tau_hat = new
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
