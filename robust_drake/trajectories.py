"""Reference trajectories: pure functions of time plus one Drake source system.

Every reference is a :class:`Reference`: ``ref(t) -> (q_d, qd_d, qdd_d)``, with ``t`` a
scalar (each output of shape (n,)) or an array of shape (K,) (outputs (K, n)).
Units: s, rad, rad/s, rad/s^2, m.

- :func:`cubic_cpt` -- JS eq. 48, 0 -> 90 deg -> 0 in two 1 s cubic segments;
- :func:`circle_task_space` -- JS eqs. 50-51 through inverse kinematics;
- :func:`second_order_step` -- JS eq. 47 (critically damped reference model) and the
  filtered steps of CI section 5.2;
- :func:`sinusoid` -- JS eq. 49;
- :func:`trapezoidal_line` -- a Cartesian straight line with a trapezoidal velocity
  profile (BR section V, figs. 1-2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from pydrake.systems.framework import BasicVector, LeafSystem

from robust_drake.errors import RobustDrakeError
from robust_drake.kinematics import (
    planar_forward_kinematics,
    planar_inverse_kinematics,
    planar_jacobian,
    planar_jacobian_dot,
)


# --------------------------------------------------------------------------- pure functions
def cubic_segment(t, t0, T, q0, q1):
    """Cubic with zero end velocities from q0 at t0 to q1 at t0+T (JS eq. 48).

    q = q0 + (q1 - q0)(3 s^2 - 2 s^3), s = (t - t0)/T clipped to [0, 1].
    """
    t = np.asarray(t, dtype=float)
    s = np.clip((t - t0) / T, 0.0, 1.0)
    inside = ((t - t0) >= 0.0) & ((t - t0) <= T)
    dq = np.asarray(q1, dtype=float) - np.asarray(q0, dtype=float)
    h = 3 * s**2 - 2 * s**3
    hd = np.where(inside, (6 * s - 6 * s**2) / T, 0.0)
    hdd = np.where(inside, (6 - 12 * s) / T**2, 0.0)
    q = np.asarray(q0) + np.multiply.outer(h, dq)
    qd = np.multiply.outer(hd, dq)
    qdd = np.multiply.outer(hdd, dq)
    return q, qd, qdd


def cubic_cpt(t, amplitude=(math.pi / 2, math.pi / 2), segment=1.0):
    """JS eq. 48: each joint 0 -> amplitude in ``segment`` s, then back to 0 in ``segment`` s."""
    t = np.asarray(t, dtype=float)
    amp = np.asarray(amplitude, dtype=float)
    zero = np.zeros_like(amp)
    q_a, qd_a, qdd_a = cubic_segment(t, 0.0, segment, zero, amp)
    q_b, qd_b, qdd_b = cubic_segment(t, segment, segment, amp, zero)
    first = (t < segment)[..., None]
    return (np.where(first, q_a, q_b), np.where(first, qd_a, qd_b), np.where(first, qdd_a, qdd_b))


def second_order_step(t, amplitude, omega=10.0, zeta=1.0, t0=0.0):
    """Step of height ``amplitude`` at ``t0`` through omega^2/(s^2 + 2 zeta omega s + omega^2).

    JS eq. 47 with zeta = 1 (critically damped reference model); CI section 5.2's
    "step function smoothed by a second order filter". Closed form for all zeta > 0.
    """
    t = np.asarray(t, dtype=float)
    amp = np.asarray(amplitude, dtype=float)
    tau = np.maximum(t - t0, 0.0)
    w, z = float(omega), float(zeta)
    if w <= 0 or z <= 0:
        raise RobustDrakeError(f"second-order step needs omega > 0 and zeta > 0 (got {w}, {z})")
    if abs(z - 1.0) < 1e-9:
        e = np.exp(-w * tau)
        y = 1.0 - (1.0 + w * tau) * e
        yd = w * w * tau * e
        ydd = w * w * (1.0 - w * tau) * e
    elif z < 1.0:
        wd = w * math.sqrt(1.0 - z * z)
        k = z / math.sqrt(1.0 - z * z)
        e = np.exp(-z * w * tau)
        c, s = np.cos(wd * tau), np.sin(wd * tau)
        y = 1.0 - e * (c + k * s)
        yd = (w / math.sqrt(1.0 - z * z)) * e * s
        ydd = w * w * e * (c - k * s)
    else:
        root = math.sqrt(z * z - 1.0)
        p1, p2 = -w * (z - root), -w * (z + root)
        e1, e2 = np.exp(p1 * tau), np.exp(p2 * tau)
        y = 1.0 + (p2 * e1 - p1 * e2) / (p1 - p2)
        yd = p1 * p2 * (e1 - e2) / (p1 - p2)
        ydd = p1 * p2 * (p1 * e1 - p2 * e2) / (p1 - p2)
    return np.multiply.outer(y, amp), np.multiply.outer(yd, amp), np.multiply.outer(ydd, amp)


def sinusoid(t, amplitude, omega):
    """JS eq. 49: q_d = a sin(omega t), per joint."""
    t = np.asarray(t, dtype=float)
    a = np.asarray(amplitude, dtype=float)
    w = np.broadcast_to(np.asarray(omega, dtype=float), a.shape)
    ph = np.multiply.outer(t, w)
    return a * np.sin(ph), a * w * np.cos(ph), -a * w * w * np.sin(ph)


def task_space_to_joint(p, pd, pdd, link_lengths, elbow="up"):
    """Joint reference from a Cartesian one: q = IK(p), qd = J^-1 pd, qdd = J^-1 (pdd - Jd qd)."""
    q = planar_inverse_kinematics(p, link_lengths, elbow)
    J = planar_jacobian(q, link_lengths)
    det = J[..., 0, 0] * J[..., 1, 1] - J[..., 0, 1] * J[..., 1, 0]
    if np.any(np.abs(det) < 1e-6):
        raise RobustDrakeError("the Cartesian path passes through a kinematic singularity (det J ~ 0)")
    qd = np.linalg.solve(J, np.asarray(pd)[..., None])[..., 0]
    Jd = planar_jacobian_dot(q, qd, link_lengths)
    rhs = np.asarray(pdd) - np.einsum("...ij,...j->...i", Jd, qd)
    qdd = np.linalg.solve(J, rhs[..., None])[..., 0]
    return q, qd, qdd


def circle_task_space(t, link_lengths, center=(0.4, 0.0), radius=0.1, omega=6.0, elbow="up"):
    """JS eqs. 50-51: x_d = a + r cos(omega t), y_d = b + r sin(omega t), mapped to joints."""
    t = np.asarray(t, dtype=float)
    a, b = center
    ph = omega * t
    p = np.stack([a + radius * np.cos(ph), b + radius * np.sin(ph)], axis=-1)
    pd = np.stack([-radius * omega * np.sin(ph), radius * omega * np.cos(ph)], axis=-1)
    pdd = np.stack([-radius * omega**2 * np.cos(ph), -radius * omega**2 * np.sin(ph)], axis=-1)
    return task_space_to_joint(p, pd, pdd, link_lengths, elbow)


def trapezoidal_profile(t, T, Ta):
    """Arc-length fraction s(t) in [0, 1] with trapezoidal velocity: accel Ta, cruise, decel Ta."""
    if not (0 < Ta <= T / 2):
        raise RobustDrakeError(f"trapezoidal profile needs 0 < accel time <= T/2 (T={T}, Ta={Ta})")
    t = np.clip(np.asarray(t, dtype=float), 0.0, T)
    vmax = 1.0 / (T - Ta)
    acc = vmax / Ta
    s = np.where(t < Ta, 0.5 * acc * t**2,
                 np.where(t <= T - Ta, vmax * (t - Ta / 2), 1.0 - 0.5 * acc * (T - t) ** 2))
    sd = np.where(t < Ta, acc * t, np.where(t <= T - Ta, vmax, acc * (T - t)))
    sdd = np.where(t < Ta, acc, np.where(t <= T - Ta, 0.0, -acc))
    return s, sd, sdd


def trapezoidal_line(t, link_lengths, start, end, T, Ta, t0=0.0, elbow="up"):
    """Straight Cartesian line start -> end in T s with trapezoidal velocity (BR section V)."""
    s, sd, sdd = trapezoidal_profile(np.asarray(t, dtype=float) - t0, T, Ta)
    p0, p1 = np.asarray(start, float), np.asarray(end, float)
    d = p1 - p0
    p = p0 + np.multiply.outer(s, d)
    pd = np.multiply.outer(sd, d)
    pdd = np.multiply.outer(sdd, d)
    return task_space_to_joint(p, pd, pdd, link_lengths, elbow)


# --------------------------------------------------------------------------- Reference
@dataclass
class Reference:
    """A joint-space reference ``q_d(t)`` with its first two derivatives.

    ``func(t)`` returns ``(q, qd, qdd)``; ``duration`` is the default simulation length [s];
    ``name`` and ``params`` describe it for logs and JSON.
    """

    func: Callable
    n: int
    duration: float
    name: str = "reference"
    params: dict = field(default_factory=dict)

    def __call__(self, t):
        return self.func(t)

    def initial_state(self) -> tuple[np.ndarray, np.ndarray]:
        q, qd, _ = self.func(0.0)
        return np.asarray(q, float).reshape(self.n), np.asarray(qd, float).reshape(self.n)


class ReferenceTrajectory(LeafSystem):
    """Source system with output ``x_d`` = [q_d, qd_d, qdd_d] (3n) from a :class:`Reference`.

    With ``period`` and ``duration`` given, the reference is tabulated once (vectorised) at
    the sample instants k*period, and the output at a sample instant is a table look-up;
    at any other time it is computed exactly. This keeps numpy work out of the 2500 Hz path.
    """

    def __init__(self, reference: Reference, period: float | None = None, duration: float | None = None):
        super().__init__()
        self.reference = reference
        n = reference.n
        self._n = n
        self._period = period
        self._table = None
        if period is not None and duration is not None:
            self.tabulate(duration)
        self.DeclareVectorOutputPort("x_d", 3 * n, self._calc)

    def tabulate(self, duration: float) -> None:
        """(Re)build the look-up table for samples 0..ceil(duration/period)."""
        if self._period is None:
            return
        k = np.arange(int(math.ceil(duration / self._period)) + 2)
        q, qd, qdd = self.reference(k * self._period)
        self._table = np.ascontiguousarray(np.hstack([q, qd, qdd]))

    def _calc(self, context, output):
        t = context.get_time()
        table = self._table
        if table is not None:
            x = t / self._period
            k = int(round(x))
            if abs(x - k) < 1e-6 and k < table.shape[0]:
                output.SetFromVector(table[k])
                return
        q, qd, qdd = self.reference(t)
        out = output.get_mutable_value()
        n = self._n
        out[:n] = q
        out[n:2 * n] = qd
        out[2 * n:] = qdd


# --------------------------------------------------------------------------- factories
def _two_joints(arm, what):
    if arm.n != 2:
        raise RobustDrakeError(f"the {what} reference is defined for 2-joint planar arms; {arm.name} has {arm.n}")


def _vec(x, n):
    a = np.asarray(x, dtype=float)
    return np.full(n, float(a)) if a.ndim == 0 else a


def make_cpt(arm, amplitude_deg=90.0, segment=1.0):
    """JS eq. 48 CPT: 0 -> ``amplitude_deg`` -> 0 on every joint, two ``segment``-s cubics."""
    amp = np.deg2rad(_vec(amplitude_deg, arm.n))
    return Reference(lambda t: cubic_cpt(t, amp, segment), arm.n, 2.0 * segment, "cpt",
                     {"amplitude_deg": amplitude_deg, "segment": segment})


def make_circle(arm, center=(0.4, 0.0), radius=0.1, omega=6.0, duration=7.0, elbow="up"):
    """JS eqs. 50-51 circle (section 10: r = 0.1 m at (0.4, 0) m, 6 rad/s, 7 s)."""
    _two_joints(arm, "circle")
    if radius <= 0:
        raise RobustDrakeError("circle radius must be positive")
    L = arm.link_lengths
    grid = np.linspace(0.0, 2 * math.pi / omega, 721)
    circle_task_space(grid, L, center, radius, omega, elbow)  # raises if unreachable or singular
    return Reference(lambda t: circle_task_space(t, L, center, radius, omega, elbow), 2, duration,
                     "circle", {"center": list(center), "radius": radius, "omega": omega})


def make_refmodel(arm, amplitude_deg=90.0, omega=3.5, duration=3.0):
    """JS eq. 47: critically damped second-order reference model driven by a 0 -> 90 deg step."""
    amp = np.deg2rad(_vec(amplitude_deg, arm.n))
    return Reference(lambda t: second_order_step(t, amp, omega, 1.0), arm.n, duration, "refmodel",
                     {"amplitude_deg": amplitude_deg, "omega": omega})


def make_step(arm, amplitude=0.5, omega=10.0, zeta=1.0, t0=0.0, duration=3.0, offset=0.0):
    """A step of ``amplitude`` rad per joint smoothed by a second-order filter (CI section 5.2)."""
    amp = _vec(amplitude, arm.n)
    off = _vec(offset, arm.n)

    def f(t):
        q, qd, qdd = second_order_step(t, amp, omega, zeta, t0)
        return q + off, qd, qdd

    return Reference(f, arm.n, duration, "step",
                     {"amplitude": amp.tolist(), "omega": omega, "zeta": zeta, "t0": t0})


def make_sine(arm, amplitude=0.5, omega=math.pi, duration=4.0):
    """JS eq. 49: q_d = a sin(omega t) on every joint."""
    amp = _vec(amplitude, arm.n)
    return Reference(lambda t: sinusoid(t, amp, omega), arm.n, duration, "sine",
                     {"amplitude": amp.tolist(), "omega": omega})


def make_line(arm, start=None, end=None, T=2.0, Ta=0.5, hold=0.5, elbow="up"):
    """Cartesian straight line with a trapezoidal velocity profile, then ``hold`` s at rest.

    Defaults: from 60 % to 30 %... of the reach: start = (0.55 L, 0.25 L), end = (0.25 L, 0.7 L),
    with L = l1 + l2 (for the Siciliano arm, (1.1, 0.5) m -> (0.5, 1.4) m).
    """
    _two_joints(arm, "line")
    L = sum(arm.link_lengths)
    start = (0.55 * L, 0.25 * L) if start is None else start
    end = (0.25 * L, 0.7 * L) if end is None else end
    Ls = arm.link_lengths
    grid = np.linspace(0.0, T, 401)
    trapezoidal_line(grid, Ls, start, end, T, Ta, 0.0, elbow)
    return Reference(lambda t: trapezoidal_line(t, Ls, start, end, T, Ta, 0.0, elbow), 2, T + hold,
                     "line", {"start": list(start), "end": list(end), "T": T, "Ta": Ta})


def make_reference(arm, name: str, **params) -> Reference:
    """Build the registered trajectory ``name`` for ``arm`` (see :mod:`robust_drake.registry`)."""
    from robust_drake.registry import resolve

    return resolve("trajectory", name)(arm, **params)


def task_space_path(q, link_lengths):
    """Convenience alias of :func:`planar_forward_kinematics` for plots."""
    return planar_forward_kinematics(q, link_lengths)
