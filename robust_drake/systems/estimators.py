"""Finite-difference velocity estimators of Jaritz & Spong, section 6.

Three estimators from encoder positions ``q_k`` (quantised) and the reference ``q_k^d``:

- ``euler``: the Euler difference, JS eq. 60, ``v_k = (q_k - q_{k-1}) / T``;
- ``filtered``: the filtered derivative, JS eqs. 61-63, ``v_k = nu v_{k-1} + g (q_k - q_{k-1}) / T``;
- ``averaging67``: the recursive average of JS eq. 67, ``v_k = (sum_{i=1}^{n-1} v_{k-i} + (q_k - q_{k-1}) / T) / n``;
- ``averaging65``: JS eq. 64 for v and eq. 65 for the velocity error, the plain n-sample secant
  on q~ = q - q^d, ``e'_k = ((q_k - q_{k-n}) - (q^d_k - q^d_{k-n})) / (n T)`` (the filter the
  paper tried first and found "was not working sufficiently", replaced by eq. 66).

Each also estimates the derivative of the tracking error ``q~ = q - q^d`` by running the
*same* filter on ``q~`` (JS eq. 63: "the desired velocity for the velocity error is calculated
using the same filter to avoid a phase shift"), which is the ``v_error`` output of the observer
port convention (BUILD_NOTES, "Port conventions").

Two readings of the printed equations, both recorded in BUILD_NOTES.md:

- eq. 61 as printed has DC gain ``1 / (1 - nu)`` (a ramp ``q = w t`` gives ``v -> w / (1 - nu)``).
  By default we use the unit-gain form ``g = 1 - nu`` (``normalize=True``); the literal form is
  ``normalize=False``.
- eq. 67 as printed (``(1/n) sum v_{k-i} + Euler``) has DC gain ``n``; the text calls it an
  *average* of the last estimates with the newest Euler difference and says it performs about
  like eq. 64, so we read the ``1/n`` as applying to the whole sum (unit DC gain).

The per-step laws are pure functions of a small history vector (``*_step``), so tests can run
them on known signals without a simulator (:func:`run_estimator`); the LeafSystems are thin
wrappers on the lead's :class:`robust_drake.systems.observers.DiscreteObserver`.
"""

from __future__ import annotations

import numpy as np

from robust_drake.description import packaged_description
from robust_drake.errors import RobustDrakeError

#: D2R2 encoder interpulse angle, JS eq. 70: 2 pi / (counts per revolution) rad (robots/d2r2.yaml).
THETA_M = packaged_description("d2r2").encoder_resolution


# ---------------------------------------------------------------------------------------------
# pure per-step laws. History layout (1-D float array h, n joints):
#   h[0:n] = q_{k-1}, h[n:2n] = q~_{k-1}, then law-specific memory of past outputs.
# step(h, q, qt, T, ...) -> (v, v_error, h_new)   (h is not modified)
# ---------------------------------------------------------------------------------------------


def euler_history_size(n: int) -> int:
    return 2 * n


def euler_step(h, q, qt, T):
    """JS eq. 60 on q and on q~ (eq. 63 with nu = 0)."""
    n = len(q)
    q = np.asarray(q, float)
    qt = np.asarray(qt, float)
    v = (q - h[:n]) / T
    ve = (qt - h[n:2 * n]) / T
    return v, ve, np.concatenate([q, qt])


def filtered_history_size(n: int) -> int:
    return 4 * n


def filtered_step(h, q, qt, T, nu=0.5, normalize=True):
    """JS eqs. 61 (v) and 62/63 (v_error): first-order filtered derivative, pole at ``z = nu``.

    ``normalize=True`` multiplies the difference by ``1 - nu`` so the DC gain is one; the
    literal eq. 61 (``normalize=False``) has DC gain ``1 / (1 - nu)``.
    """
    n = len(q)
    q = np.asarray(q, float)
    qt = np.asarray(qt, float)
    g = (1.0 - nu) if normalize else 1.0
    v = nu * h[2 * n:3 * n] + g * (q - h[:n]) / T
    ve = nu * h[3 * n:4 * n] + g * (qt - h[n:2 * n]) / T
    return v, ve, np.concatenate([q, qt, v, ve])


def averaging67_history_size(n: int, window: int = 3) -> int:
    return 2 * n + 2 * n * (window - 1)


def averaging67_step(h, q, qt, T, window=3):
    """JS eq. 67 (v) and the same recursion on q~ (the form of eq. 66), unit-DC-gain reading.

    ``v_k = (v_{k-1} + ... + v_{k-n+1} + (q_k - q_{k-1}) / T) / n`` with ``n = window``.
    History after the two last positions: ``window - 1`` past v's then ``window - 1`` past
    v_error's, newest first.
    """
    n = len(q)
    m = window - 1
    q = np.asarray(q, float)
    qt = np.asarray(qt, float)
    pv = h[2 * n:2 * n + m * n].reshape(m, n)
    pe = h[2 * n + m * n:].reshape(m, n)
    v = (pv.sum(axis=0) + (q - h[:n]) / T) / window
    ve = (pe.sum(axis=0) + (qt - h[n:2 * n]) / T) / window
    pv_new = np.vstack([v[None, :], pv[:-1]]) if m > 0 else pv
    pe_new = np.vstack([ve[None, :], pe[:-1]]) if m > 0 else pe
    return v, ve, np.concatenate([q, qt, pv_new.ravel(), pe_new.ravel()])


def initial_history(kind: str, q0, qt0, **params) -> np.ndarray:
    """History for a loop that starts at rest at ``q0`` (past outputs zero)."""
    q0 = np.asarray(q0, float)
    qt0 = np.asarray(qt0, float)
    n = len(q0)
    size = {"euler": euler_history_size(n), "filtered": filtered_history_size(n),
            "averaging67": averaging67_history_size(n, params.get("window", 3)),
            "averaging65": averaging65_history_size(n, params.get("window", 3))}[kind]
    h = np.zeros(size)
    if kind == "averaging65":
        N = params.get("window", 3)
        return np.concatenate([np.tile(q0, N), np.tile(qt0, N)])
    h[:n] = q0
    h[n:2 * n] = qt0
    return h


def averaging65_history_size(n: int, window: int = 3) -> int:
    return 2 * n * window


def averaging65_step(h, q, qt, T, window=3):
    """JS eq. 64 (v) and eq. 65 (v_error): ``(x_k - x_{k-N}) / (N T)`` for x = q and x = q~.

    A secant over N samples: exact for a signal linear in t, and for any quadratic it returns the
    derivative at the window's midpoint ``t_k - N T / 2`` (a delay of N/2 samples).
    History: ``window`` past q's then ``window`` past q~'s, newest first.
    """
    n = len(q)
    N = int(window)
    q = np.asarray(q, float)
    qt = np.asarray(qt, float)
    pq = h[:N * n].reshape(N, n)
    pe = h[N * n:].reshape(N, n)
    v = (q - pq[-1]) / (N * T)
    ve = (qt - pe[-1]) / (N * T)
    return v, ve, np.concatenate([np.vstack([q[None], pq[:-1]]).ravel(), np.vstack([qt[None], pe[:-1]]).ravel()])


STEP_LAWS = {"euler": euler_step, "filtered": filtered_step, "averaging67": averaging67_step,
             "averaging65": averaging65_step}


def run_estimator(kind: str, q, q_d, T, **params):
    """Run one of the finite-difference laws over sampled signals (tests, notebooks).

    ``q``, ``q_d``: arrays (K, n) sampled every ``T``. Returns ``(v, v_error)``, each (K, n);
    the first sample is estimated from a history at rest at ``q[0]``.
    """
    if kind not in STEP_LAWS:
        raise RobustDrakeError(f"unknown estimator {kind!r}; known: {sorted(STEP_LAWS)}")
    q = np.atleast_2d(np.asarray(q, float))
    q_d = np.atleast_2d(np.asarray(q_d, float))
    qt = q - q_d
    step = STEP_LAWS[kind]
    h = initial_history(kind, q[0], qt[0], **params)
    V = np.empty_like(q)
    E = np.empty_like(q)
    for k in range(q.shape[0]):
        V[k], E[k], h = step(h, q[k], qt[k], T, **params)
    return V, E


def quantize(q, theta_m=THETA_M):
    """Encoder quantisation: round down to a multiple of the interpulse angle ``theta_m``."""
    return np.floor(np.asarray(q, float) / theta_m) * theta_m


def estimator_quality(v_hat, v_true, a_true, T, skip=0):
    """Bias, gain, lag and noise of a velocity estimate against the exact derivative.

    The error ``e = v_hat - v_true`` is fitted (least squares, samples from ``skip`` on) by
    ``bias + (gain - 1) v_true - lag a_true``: for a smooth signal, a filter with DC gain ``g``
    and group delay ``tau`` gives ``v_hat(t) ~ g v_true(t - tau) ~ g v_true - tau a_true``.
    Returns ``bias`` (rad/s), ``gain``, ``lag`` (s), ``lag_samples`` and ``noise_rms`` (rad/s, RMS
    of the fit residual: quantisation noise passed by the estimator).
    """
    v_hat = np.asarray(v_hat, float).ravel()[skip:]
    v_true = np.asarray(v_true, float).ravel()[skip:]
    a_true = np.asarray(a_true, float).ravel()[skip:]
    e = v_hat - v_true
    X = np.column_stack([np.ones_like(v_true), v_true, -a_true])
    coef, *_ = np.linalg.lstsq(X, e, rcond=None)
    res = e - X @ coef
    return {"bias": float(coef[0]), "gain": float(1.0 + coef[1]), "lag": float(coef[2]),
            "lag_samples": float(coef[2] / T), "noise_rms": float(np.sqrt(np.mean(res * res)))}


# ---------------------------------------------------------------------------------------------
# LeafSystems on the observer port convention (q, x_d -> v, v_error)
# ---------------------------------------------------------------------------------------------
from robust_drake.systems.linear_observer import compiled  # noqa: E402
from robust_drake.systems.observers import DiscreteObserver  # noqa: E402


class _FiniteDifferenceObserver(DiscreteObserver):
    kind = ""

    def __init__(self, n, period, history_size, name, **params):
        self.params = params
        super().__init__(n, period, history_size=history_size, name=name)

    def estimate(self, h, q, q_d, qd_d, t):
        v, ve, _ = STEP_LAWS[self.kind](h, q, q - q_d, self.period, **self.params)
        return v, ve

    def advance(self, h, q, q_d, qd_d, v, v_error, t):
        return STEP_LAWS[self.kind](h, q, q - q_d, self.period, **self.params)[2]

    def initial_history(self, q0, q_d0, qd_d0):
        """At rest at q0 before t = 0: the past error slope is -qd_d0 (q~' = q' - qd_d)."""
        T = self.period
        n = self.n
        if self.kind == "averaging65":
            N = self.params.get("window", 3)
            past = [q0 - q_d0 + (i + 1) * T * qd_d0 for i in range(N)]   # q~_{k-1-i}, newest first
            return np.concatenate([np.tile(q0, N), np.concatenate(past)])
        h = initial_history(self.kind, q0, q0 - q_d0 + T * qd_d0, **self.params)
        if self.kind == "filtered":
            h[3 * n:4 * n] = -qd_d0
        elif self.kind == "averaging67":
            m = self.params.get("window", 3) - 1
            h[2 * n + m * n:] = np.tile(-qd_d0, m)
        return h


class EulerVelocityObserver(_FiniteDifferenceObserver):
    """JS eq. 60 (v) and the same difference on q~ (v_error)."""

    kind = "euler"

    def __init__(self, n, period):
        super().__init__(n, period, euler_history_size(n), "EulerVelocityObserver")


class FilteredDerivativeObserver(_FiniteDifferenceObserver):
    """JS eqs. 61-63: filtered derivative with pole ``nu`` (unit DC gain by default)."""

    kind = "filtered"

    def __init__(self, n, period, nu=0.5, normalize=True):
        if not 0.0 <= nu < 1.0:
            raise RobustDrakeError(f"filtered derivative needs 0 <= nu < 1 (a stable pole), got {nu}")
        super().__init__(n, period, filtered_history_size(n), "FilteredDerivativeObserver",
                         nu=float(nu), normalize=bool(normalize))


class Averaging67Observer(_FiniteDifferenceObserver):
    """JS eq. 67 (v) with the eq. 66 recursion on q~ (v_error), window ``window`` (paper: 3)."""

    kind = "averaging67"

    def __init__(self, n, period, window=3):
        if int(window) < 1:
            raise RobustDrakeError(f"averaging window must be >= 1, got {window}")
        super().__init__(n, period, averaging67_history_size(n, int(window)), "Averaging67Observer",
                         window=int(window))


class Averaging65Observer(_FiniteDifferenceObserver):
    """JS eq. 64 (v) and eq. 65 (v_error), window ``window`` (paper: 3)."""

    kind = "averaging65"

    def __init__(self, n, period, window=3):
        if int(window) < 1:
            raise RobustDrakeError(f"averaging window must be >= 1, got {window}")
        super().__init__(n, period, averaging65_history_size(n, int(window)), "Averaging65Observer",
                         window=int(window))


# Registry factories: the law runs as a Drake LinearSystem (systems.linear_observer, tested equal
# to the Python block); ``python=True`` gives the Python block itself.
def make_averaging65(ctx, window=3, python=False):
    return compiled(Averaging65Observer(ctx.n, ctx.period, window=window), python)


def make_euler(ctx, python=False):
    return compiled(EulerVelocityObserver(ctx.n, ctx.period), python)


def make_filtered(ctx, nu=0.5, normalize=True, python=False):
    return compiled(FilteredDerivativeObserver(ctx.n, ctx.period, nu=nu, normalize=normalize), python)


def make_averaging67(ctx, window=3, python=False):
    return compiled(Averaging67Observer(ctx.n, ctx.period, window=window), python)
