"""Periodic, band-limited joint trajectories: a finite Fourier series per joint.

Swevers, Ganseman et al. 1997 (periodic excitation for maximum-likelihood identification) and
Gautier & Khalil 1992 write every joint as a finite Fourier series of one fundamental
``omega_f = 2 pi / T_p``::

    q_j(t) = c_j + sum_{k=1..K} [ a_jk sin(k omega_f t) + b_jk cos(k omega_f t) ]      [rad]

so the motion repeats every period ``T_p`` [s] and holds no frequency above ``K / T_p`` [Hz]
(band-limited: below the identification filter's cut-off it passes unchanged, see
:mod:`robust_drake.excitation.design`).  Velocity and acceleration are the exact derivatives.
Everything is linear in the coefficient vector ``x = [x_1, ..., x_n]``, ``x_j = [c_j, a_j1..a_jK,
b_j1..b_jK]`` (n (2K + 1) numbers): ``q(t) = B(t) x_j`` with the basis rows of :func:`basis`, so
position, velocity and acceleration limits on a grid and the rest conditions
q(0) = q_start, qd(0) = 0, qdd(0) = 0 are linear constraints.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from robust_drake.errors import RobustDrakeError


def basis(t, period: float, harmonics: int, derivative: int = 0) -> np.ndarray:
    """Rows (M, 2K + 1) such that d^r q_j / dt^r (t) = basis(t, ..., r) @ x_j.

    Columns [1, sin(k w t) (k = 1..K), cos(k w t) (k = 1..K)], w = 2 pi / period [rad/s];
    ``derivative`` r in {0, 1, 2}."""
    t = np.atleast_1d(np.asarray(t, float))
    K = int(harmonics)
    w = 2.0 * math.pi / float(period)
    kw = w * np.arange(1, K + 1)
    ph = np.multiply.outer(t, kw)
    s, c = np.sin(ph), np.cos(ph)
    out = np.zeros((t.size, 2 * K + 1))
    if derivative == 0:
        out[:, 0] = 1.0
        out[:, 1:K + 1], out[:, K + 1:] = s, c
    elif derivative == 1:
        out[:, 1:K + 1], out[:, K + 1:] = c * kw, -s * kw
    elif derivative == 2:
        out[:, 1:K + 1], out[:, K + 1:] = -s * kw ** 2, -c * kw ** 2
    else:
        raise RobustDrakeError(f"basis derivative must be 0, 1 or 2 (got {derivative})")
    return out


@dataclass
class FourierTrajectory:
    """The series above for n joints: ``coefficients`` (n, 2K + 1) [rad], ``period`` T_p [s].

    ``traj(t)`` returns (q, qd, qdd), each (n,) for a scalar t or (M, n) for an array (the
    :class:`robust_drake.trajectories.Reference` convention)."""

    coefficients: np.ndarray
    period: float

    @property
    def n(self) -> int:
        return self.coefficients.shape[0]

    @property
    def harmonics(self) -> int:
        return (self.coefficients.shape[1] - 1) // 2

    @property
    def max_frequency(self) -> float:
        """Highest frequency in the motion [Hz] (K / T_p)."""
        return self.harmonics / self.period

    def __call__(self, t):
        scalar = np.ndim(t) == 0
        out = tuple(basis(t, self.period, self.harmonics, r) @ self.coefficients.T for r in (0, 1, 2))
        return tuple(o[0] for o in out) if scalar else out

    @classmethod
    def from_vector(cls, x, n: int, period: float) -> "FourierTrajectory":
        x = np.asarray(x, float)
        if x.size % n or (x.size // n) % 2 != 1:
            raise RobustDrakeError(f"a Fourier coefficient vector for {n} joints has n (2K + 1) entries (got {x.size})")
        return cls(x.reshape(n, -1).copy(), float(period))

    def vector(self) -> np.ndarray:
        return self.coefficients.ravel().copy()

    def to_dict(self) -> dict:
        return {"period": float(self.period), "harmonics": int(self.harmonics),
                "coefficients": self.coefficients.tolist(),
                "layout": "per joint [c, a_1..a_K (sin), b_1..b_K (cos)] [rad]"}


def rest_constraints(n: int, period: float, harmonics: int, q_start) -> tuple[np.ndarray, np.ndarray]:
    """(A, b) with A x = b <=> q(0) = q_start, qd(0) = 0, qdd(0) = 0 on every joint (3n rows on
    the n (2K + 1) coefficients); by periodicity the motion is also at rest at q_start at every
    multiple of the period."""
    B = np.vstack([basis(0.0, period, harmonics, r) for r in (0, 1, 2)])  # (3, 2K+1)
    m = 2 * harmonics + 1
    A = np.zeros((3 * n, n * m))
    b = np.zeros(3 * n)
    q_start = np.asarray(q_start, float)
    for j in range(n):
        A[3 * j:3 * j + 3, j * m:(j + 1) * m] = B
        b[3 * j] = q_start[j]
    return A, b


def random_feasible(n: int, period: float, harmonics: int, q_start, half_width, rng) -> np.ndarray:
    """A starting point: random coefficients with 1/k decay, projected onto the rest conditions
    (least-norm change of the harmonics), then scaled about q_start so each joint stays within
    ``half_width`` [rad] of it (peak on a fine grid over one period)."""
    K, m = int(harmonics), 2 * int(harmonics) + 1
    k = np.arange(1, K + 1)
    x = np.zeros((n, m))
    x[:, 1:K + 1] = rng.standard_normal((n, K)) / k
    x[:, K + 1:] = rng.standard_normal((n, K)) / k
    B0 = np.vstack([basis(0.0, period, K, r) for r in (0, 1, 2)])[:, 1:]  # harmonics only
    for j in range(n):
        h = x[j, 1:]
        target = np.array([0.0, 0.0, 0.0])  # deviation q - q_start at t = 0, qd, qdd
        h = h - np.linalg.pinv(B0) @ (B0 @ h - target)
        x[j, 1:] = h
    tt = np.linspace(0.0, period, 40 * K + 1)
    dev = basis(tt, period, K, 0)[:, 1:] @ x[:, 1:].T
    peak = np.maximum(np.abs(dev).max(axis=0), 1e-12)
    x[:, 1:] *= (np.asarray(half_width, float) / peak)[:, None]
    # c_j from q(0) = q_start: c_j + sum_k b_jk = q_start_j
    x[:, 0] = np.asarray(q_start, float) - x[:, K + 1:].sum(axis=1)
    return x.ravel()
