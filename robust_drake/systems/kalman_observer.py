"""Steady-state Kalman velocity filter of Jaritz & Spong, section 6.1 (after Belanger [3]).

Per joint, the continuous model of JS eqs. 68-73

    x' = A x + Gamma w,   q = C x + e,   A = [[0, 1], [0, 0]],  C = [1, 0],  Gamma = [0, 1]^T

(``w`` a surrogate for the joint acceleration with covariance ``c``, ``e`` the quantisation error
with variance ``R = theta_m^2 / 3``, eq. 70) is discretised with a zero-order hold (Matlab
``c2d`` in the paper; here :func:`scipy.signal.cont2discrete`) and the steady-state gain is the
one of Matlab ``dlqe``: the noise enters the discrete model as ``Gamma_d w_k`` with
``E[w_k^2] = c`` (so ``Q_d = c Gamma_d Gamma_d^T``), the prior covariance ``P`` solves the
discrete algebraic Riccati equation (:func:`scipy.linalg.solve_discrete_are`), and
``M = P C^T (C P C^T + R)^-1`` is the measurement-update gain. The estimator is the *current*
form (Matlab ``destim`` with the current estimate): at tick k

    x_k|k   = x_k|k-1 + M (q_k - C x_k|k-1)          -> output
    x_k+1|k = A_d x_k|k                               -> stored

so the controller at tick k sees an estimate that already uses ``q_k``. The same filter runs on
``q~ = q - q^d`` for the velocity-error output ("for the velocity error estimation the same
filter design was used", section 6.1). With the paper's ``c ~ 1000`` at 2500 Hz.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg
import scipy.signal

from robust_drake.errors import RobustDrakeError
from robust_drake.systems.estimators import THETA_M


def kalman_velocity_design(T: float, c: float = 1000.0, theta_m: float = THETA_M):
    """Discretise JS eqs. 68-73 (ZOH) and solve for the steady-state Kalman gain.

    Returns a dict with ``Ad`` (2x2), ``Gd`` (2x1), ``Qd``, ``R`` (eq. 70), ``P`` (prior
    covariance, DARE solution), ``M`` (2x1 measurement-update gain, Matlab ``dlqe``), ``L``
    (``Ad M``, the predictor gain, as Drake's ``DiscreteTimeSteadyStateKalmanFilter``) and the
    closed-loop poles of the predictor ``eig(Ad - L C)``.
    """
    if T <= 0 or c <= 0 or theta_m <= 0:
        raise RobustDrakeError(f"Kalman design needs T > 0, c > 0, theta_m > 0 (got {T}, {c}, {theta_m})")
    A = np.array([[0.0, 1.0], [0.0, 0.0]])  # eq. 71
    C = np.array([[1.0, 0.0]])  # eq. 72
    Gamma = np.array([[0.0], [1.0]])  # eq. 73
    Ad, Gd, _, _, _ = scipy.signal.cont2discrete((A, Gamma, C, np.zeros((1, 1))), T, method="zoh")
    Qd = c * (Gd @ Gd.T)
    R = np.array([[theta_m ** 2 / 3.0]])  # eq. 70
    P = scipy.linalg.solve_discrete_are(Ad.T, C.T, Qd, R)
    M = P @ C.T @ np.linalg.inv(C @ P @ C.T + R)
    L = Ad @ M
    poles = np.linalg.eigvals(Ad - L @ C)
    return {"Ad": Ad, "Gd": Gd, "Qd": Qd, "R": R, "P": P, "M": M, "L": L, "C": C, "poles": poles}


class KalmanVelocityLaw:
    """Per-step current-form Kalman filter on ``n`` independent channels (pure math).

    State (2 per channel): the prior ``x_k|k-1 = (position, velocity)``. ``step(x, y)``
    returns ``(position_est, velocity_est, x_next)`` for the measurement vector ``y``.
    """

    def __init__(self, T: float, c: float = 1000.0, theta_m: float = THETA_M):
        d = kalman_velocity_design(T, c, theta_m)
        self.design = d
        self.a01 = float(d["Ad"][0, 1])
        self.m0 = float(d["M"][0, 0])
        self.m1 = float(d["M"][1, 0])

    def step(self, x, y):
        """x: list/array (2 * channels) prior [p0, v0, p1, v1, ...]; y: measurements."""
        m0, m1, a01 = self.m0, self.m1, self.a01
        p_out = []
        v_out = []
        x_next = []
        for i, yi in enumerate(y):
            p = x[2 * i]
            v = x[2 * i + 1]
            innov = yi - p
            pc = p + m0 * innov
            vc = v + m1 * innov
            p_out.append(pc)
            v_out.append(vc)
            x_next.append(pc + a01 * vc)
            x_next.append(vc)
        return p_out, v_out, x_next


def run_kalman(q, q_d, T, c=1000.0, theta_m=THETA_M):
    """Run the filter over sampled signals (K, n); returns ``(v, v_error)`` (tests, notebooks).

    The filter starts at rest at the first sample (prior position = first measurement)."""
    q = np.atleast_2d(np.asarray(q, float))
    q_d = np.atleast_2d(np.asarray(q_d, float))
    qt = q - q_d
    law = KalmanVelocityLaw(T, c, theta_m)
    n = q.shape[1]
    xq = [0.0] * (2 * n)
    xe = [0.0] * (2 * n)
    for i in range(n):
        xq[2 * i] = q[0, i]
        xe[2 * i] = qt[0, i]
    V = np.empty_like(q)
    E = np.empty_like(q)
    for k in range(q.shape[0]):
        _, V[k], xq = law.step(xq, q[k])
        _, E[k], xe = law.step(xe, qt[k])
    return V, E


def kalman_bandwidth_hz(T: float, c: float = 1000.0, theta_m: float = THETA_M) -> float:
    """-3 dB bandwidth of the velocity estimate (magnitude of the transfer q -> v_hat divided
    by the ideal differentiator), found on a log frequency grid up to Nyquist."""
    d = kalman_velocity_design(T, c, theta_m)
    Ad, M, C = d["Ad"], d["M"], d["C"]
    I2 = np.eye(2)
    freqs = np.logspace(-1, math.log10(0.5 / T), 400)
    ratio = []
    for f in freqs:
        z = np.exp(1j * 2 * np.pi * f * T)
        # x_k+1|k = Ad (I - M C) x_k|k-1 + Ad M y_k ; v_k = [0 1]((I - M C) x_k|k-1 + M y_k)
        F = Ad @ (I2 - M @ C)
        G = Ad @ M
        X = np.linalg.solve(z * I2 - F, G)  # prior per unit y
        v = (np.array([[0.0, 1.0]]) @ ((I2 - M @ C) @ X + M))[0, 0]
        ratio.append(abs(v) / (2 * np.pi * f))
    ratio = np.asarray(ratio)
    below = np.nonzero(ratio < 1 / math.sqrt(2))[0]
    return float(freqs[below[0]]) if len(below) else float(freqs[-1])


# ---------------------------------------------------------------------------------------------
# LeafSystem on the observer port convention
# ---------------------------------------------------------------------------------------------
from robust_drake.systems.observers import DiscreteObserver  # noqa: E402


class KalmanVelocityObserver(DiscreteObserver):
    """Steady-state Kalman filter of JS section 6.1 on q (-> v) and on q~ (-> v_error).

    History: the priors of the q filters (2n) then of the q~ filters (2n), per joint
    (position, velocity)."""

    def __init__(self, n, period, c=1000.0, theta_m=THETA_M):
        self.law = KalmanVelocityLaw(period, c, theta_m)
        self.c = float(c)
        super().__init__(n, period, history_size=4 * n, name="KalmanVelocityObserver")

    def _run(self, h, q, q_d):
        n = self.n
        hl = h.tolist() if hasattr(h, "tolist") else list(h)
        qt = [q[i] - q_d[i] for i in range(n)]
        _, v, xq = self.law.step(hl[:2 * n], q)
        _, ve, xe = self.law.step(hl[2 * n:], qt)
        return v, ve, xq + xe

    def estimate(self, h, q, q_d, qd_d, t):
        v, ve, _ = self._run(h, q, q_d)
        return v, ve

    def advance(self, h, q, q_d, qd_d, v, v_error, t):
        return self._run(h, q, q_d)[2]

    def initial_history(self, q0, q_d0, qd_d0):
        n = self.n
        h = np.zeros(4 * n)
        h[0:2 * n:2] = q0
        h[2 * n::2] = q0 - q_d0
        h[2 * n + 1::2] = -qd_d0
        return h


def make_kalman(ctx, c=1000.0, theta_m=None, python=False):
    """Registry factory ``kalman``; ``theta_m`` defaults to the loop's encoder resolution
    (the D2R2 interpulse angle when the encoder is exact).  A linear filter: run as a Drake
    LinearSystem (:mod:`robust_drake.systems.linear_observer`) unless ``python=True``."""
    from robust_drake.systems.linear_observer import compiled

    if theta_m is None:
        theta_m = getattr(ctx.config, "encoder_resolution", None) or THETA_M
    return compiled(KalmanVelocityObserver(ctx.n, ctx.period, c=c, theta_m=theta_m), python)
