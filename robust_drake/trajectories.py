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

Joint limits.  The joint-space references (``sine``, ``step``, ``cpt``, ``refmodel``) take an
``offset`` [rad per joint] added to q_d.  Its default (None) is the rule of :func:`fit_in_limits`:
a joint whose motion about q = 0 stays inside the arm's position limits
(``ArmSpec.position_limits()``, read from the URDF) keeps offset 0 (the papers' references,
unchanged); any other joint is centred in its range, and its amplitude shrunk (logged warning,
recorded in ``Reference.params["limits"]``) only if the motion is wider than
``1 - 2 LIMIT_MARGIN`` of the range.  An explicit ``offset`` is used as given.  The closed loop
checks the reference it runs against the plant's limits (:func:`check_within_limits`).
"""

from __future__ import annotations

import logging
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


# --------------------------------------------------------------------------- joint limits
#: fraction of a joint's range left free at each end when a reference must be shrunk to fit
LIMIT_MARGIN = 0.05

_log = logging.getLogger("robust_drake.trajectories")


def fit_in_limits(lo, hi, lower, upper, margin=LIMIT_MARGIN):
    """Offset and amplitude scale per joint that put a motion inside the joint limits.

    The motion without offset spans [lo_j, hi_j] (lo_j <= 0 <= hi_j for the references here,
    e.g. [-a, a] for JS eq. 49's sine) and scales linearly with its amplitude, so
    q = offset + s * (motion) spans offset + s [lo, hi].  Per joint:

    - [lo, hi] inside [lower, upper] (or no finite limit): offset 0, s = 1 (unchanged);
    - else, both limits finite: s = min(1, (1 - 2 margin)(upper - lower)/(hi - lo)) and the
      motion centred, offset = (lower + upper)/2 - s (lo + hi)/2;
    - one finite limit: s = 1, the motion shifted to ``margin (hi - lo)`` inside it.

    Returns (offset (n,), s (n,), moved (n,) bool).  Units those of the limits (rad or m).
    """
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    lower, upper = np.broadcast_to(np.asarray(lower, float), lo.shape), np.broadcast_to(np.asarray(upper, float), lo.shape)
    moved = (lo < lower) | (hi > upper)
    width = hi - lo
    both = np.isfinite(lower) & np.isfinite(upper)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(moved & both & (width > 0),
                     np.minimum(1.0, (1.0 - 2.0 * margin) * (upper - lower) / np.where(width > 0, width, 1.0)), 1.0)
    lf, uf = np.where(np.isfinite(lower), lower, 0.0), np.where(np.isfinite(upper), upper, 0.0)
    offset = np.where(both, 0.5 * (lf + uf) - s * 0.5 * (lo + hi),
                      np.where(np.isfinite(lower), lf + margin * width - lo,
                               np.where(np.isfinite(upper), uf - margin * width - hi, 0.0)))
    return np.where(moved, offset, 0.0), s, moved


def _arm_limits(arm):
    """The arm's :class:`robust_drake.models.JointLimits`, or None (an arm-like object without)."""
    get = getattr(arm, "position_limits", None)
    return get() if get is not None else None


def _placed(arm, what, lo, hi, offset):
    """(offset (n,), amplitude scale (n,), params entries) for a reference spanning [lo, hi]
    about q = 0: ``offset`` as given, or :func:`fit_in_limits` on the arm's limits (None)."""
    n = len(lo)
    if offset is not None:
        off = _vec(offset, n)
        if off.shape != (n,) or not np.all(np.isfinite(off)):
            raise RobustDrakeError(f"{what} offset must be a finite number or {n} finite numbers (got {offset!r})")
        return off, np.ones(n), {"offset": off.tolist()}
    limits = _arm_limits(arm)
    if limits is None or limits.n != n or not limits.any_finite():
        return np.zeros(n), np.ones(n), {"offset": [0.0] * n}
    lower, upper = limits.arrays()
    off, s, moved = fit_in_limits(lo, hi, lower, upper)
    info = {"offset": off.tolist()}
    if moved.any():
        idx = np.flatnonzero(moved)
        info["limits"] = (f"joints {(idx + 1).tolist()} centred in their position limits"
                          + ("" if np.all(s == 1.0) else f"; amplitude scaled by {np.round(s, 4).tolist()}"))
        _log_once(logging.INFO, f"{what} reference: joint(s) {(idx + 1).tolist()} "
                  f"({', '.join(limits.names[j] for j in idx)}) centred in their position limits, "
                  f"offset {np.round(off[idx], 4).tolist()} rad")
        if np.any(s < 1.0):
            shrunk = np.flatnonzero(s < 1.0)
            _log_once(logging.WARNING, f"{what} reference: amplitude of joint(s) {(shrunk + 1).tolist()} "
                      f"({', '.join(limits.names[j] for j in shrunk)}) scaled by {np.round(s[shrunk], 4).tolist()} "
                      "to fit inside the joint limits")
    return off, s, info


_LOGGED: set = set()


def _log_once(level: int, message: str) -> None:
    """Log ``message`` the first time only (a reference is rebuilt by controllers and per run)."""
    if message not in _LOGGED:
        _LOGGED.add(message)
        _log.log(level, message)


def _with_offset(f, off):
    """``f`` with ``off`` added to q_d; ``f`` itself when the offset is zero (same floats)."""
    if not np.any(off):
        return f

    def g(t):
        q, qd, qdd = f(t)
        return q + off, qd, qdd

    return g


def check_within_limits(reference, limits, duration: float, period: float, name: str | None = None,
                        hint: str | None = None) -> None:
    """RobustDrakeError (one line) if q_d of ``reference`` at the ticks k ``period``,
    0 <= k <= ceil(duration/period) + 1 (what a sampled loop reads), leaves a finite limit of
    ``limits`` (:class:`robust_drake.models.JointLimits`).  Names the first offending joint
    (its number from 1 and URDF name), its limits, the reference's range on it, and the trajectory
    parameters that move it (``hint`` replaces that advice).  ``reference(t)`` returns
    (q (K, n), ...) for t of shape (K,)."""
    if limits is None or not limits.any_finite():
        return
    lower, upper = limits.arrays()
    k = np.arange(int(math.ceil(duration / period)) + 2)
    q = np.asarray(reference(k * period)[0], float).reshape(k.size, -1)
    qmin, qmax = q.min(axis=0), q.max(axis=0)
    bad = np.flatnonzero((qmin < lower) | (qmax > upper))
    if bad.size == 0:
        return
    j = int(bad[0])
    u = limits.units[j]
    keys = [p for p in ("offset", "amplitude", "amplitude_deg") if p in getattr(reference, "params", {})]
    hint = (f"set the trajectory parameters {' / '.join(keys)} (e.g. offset {0.5 * (lower[j] + upper[j]):.4g} "
            f"{u} on this joint, the middle of its range)" if "offset" in keys and np.isfinite(lower[j] + upper[j])
            else "choose a reference inside the limits") if hint is None else hint
    more = f"; also joints {(bad[1:] + 1).tolist()}" if bad.size > 1 else ""
    raise RobustDrakeError(
        f"reference {name or getattr(reference, 'name', 'reference')!r} leaves the position limits of joint {j + 1} "
        f"({limits.names[j]}): q_d spans [{qmin[j]:.4g}, {qmax[j]:.4g}] {u} over {duration:g} s, limits "
        f"[{lower[j]:.4g}, {upper[j]:.4g}] {u}{more}; {hint}")


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


def make_cpt(arm, amplitude_deg=90.0, segment=1.0, offset=None):
    """JS eq. 48 CPT: 0 -> ``amplitude_deg`` -> 0 on every joint, two ``segment``-s cubics, plus
    ``offset`` [rad] (default: the joint-limit rule of :func:`fit_in_limits`, module docstring)."""
    amp = np.deg2rad(_vec(amplitude_deg, arm.n))
    off, scale, info = _placed(arm, "cpt", np.minimum(amp, 0.0), np.maximum(amp, 0.0), offset)
    amp = amp * scale
    return Reference(_with_offset(lambda t: cubic_cpt(t, amp, segment), off), arm.n, 2.0 * segment, "cpt",
                     {"amplitude_deg": amplitude_deg, "segment": segment, **info})


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


def make_refmodel(arm, amplitude_deg=90.0, omega=3.5, duration=3.0, offset=None):
    """JS eq. 47: critically damped second-order reference model driven by a 0 -> 90 deg step,
    plus ``offset`` [rad] (default: the joint-limit rule of :func:`fit_in_limits`)."""
    amp = np.deg2rad(_vec(amplitude_deg, arm.n))
    off, scale, info = _placed(arm, "refmodel", np.minimum(amp, 0.0), np.maximum(amp, 0.0), offset)
    amp = amp * scale
    return Reference(_with_offset(lambda t: second_order_step(t, amp, omega, 1.0), off), arm.n, duration,
                     "refmodel", {"amplitude_deg": amplitude_deg, "omega": omega, **info})


def step_peak(zeta: float) -> float:
    """Largest value over t >= 0 of the unit step response of omega^2/(s^2 + 2 zeta omega s +
    omega^2): 1 for zeta >= 1, 1 + exp(-zeta pi / sqrt(1 - zeta^2)) (first overshoot) for
    0 < zeta < 1.  Its smallest value is 0 (at t = 0)."""
    z = float(zeta)
    return 1.0 if z >= 1.0 else 1.0 + math.exp(-z * math.pi / math.sqrt(1.0 - z * z))


def make_step(arm, amplitude=0.5, omega=10.0, zeta=1.0, t0=0.0, duration=3.0, offset=None):
    """A step of ``amplitude`` rad per joint smoothed by a second-order filter (CI section 5.2),
    from q_d = ``offset``.  Default offset (None): 0 on each joint whose motion (0 to amplitude
    times :func:`step_peak`) is inside its position limits, else the rule of :func:`fit_in_limits`
    (motion centred in the range, amplitude shrunk only if it must)."""
    amp = _vec(amplitude, arm.n)
    if not (float(omega) > 0 and float(zeta) > 0):
        raise RobustDrakeError(f"second-order step needs omega > 0 and zeta > 0 (got {omega}, {zeta})")
    peak = amp * step_peak(zeta)
    off, scale, info = _placed(arm, "step", np.minimum(peak, 0.0), np.maximum(peak, 0.0), offset)
    amp = amp * scale

    def f(t):
        q, qd, qdd = second_order_step(t, amp, omega, zeta, t0)
        return q + off, qd, qdd

    return Reference(f, arm.n, duration, "step",
                     {"amplitude": amp.tolist(), "omega": omega, "zeta": zeta, "t0": t0, **info})


def make_sine(arm, amplitude=0.5, omega=math.pi, duration=4.0, offset=None):
    """JS eq. 49 about an offset: q_d = offset + a sin(omega t) on every joint [rad, rad/s].

    Default offset (None): 0 (JS eq. 49 as printed) on each joint where [-|a|, |a|] lies inside
    its position limits; any other joint is centred in its range, offset = (lower + upper)/2, and
    its amplitude shrunk to (1 - 2 LIMIT_MARGIN)(upper - lower)/2 only if it is wider
    (:func:`fit_in_limits`; logged, and described in ``params["limits"]``)."""
    amp = _vec(amplitude, arm.n)
    off, scale, info = _placed(arm, "sine", -np.abs(amp), np.abs(amp), offset)
    amp = amp * scale
    return Reference(_with_offset(lambda t: sinusoid(t, amp, omega), off), arm.n, duration, "sine",
                     {"amplitude": amp.tolist(), "omega": omega, **info})


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
    """Build the registered trajectory ``name`` for ``arm`` (see :mod:`robust_drake.registry`);
    a name ending in ``.csv`` is a trajectory file (:func:`make_file`, ``path=name``)."""
    from robust_drake.registry import resolve

    if str(name).lower().endswith(".csv"):
        return make_file(arm, path=name, **params)
    return resolve("trajectory", name)(arm, **params)


# --------------------------------------------------------------------------- trajectory files
def write_trajectory_csv(path, t, q, qd, qdd) -> str:
    """Write a joint reference as CSV: columns ``t, q1..qn, qd1..qdn, qdd1..qddn`` (s, rad,
    rad/s, rad/s^2; joints numbered from 1 as in the canonical log CSV of
    ``identification.data``), one row per sample, each number as the shortest text that reads
    back the same double.  Returns the path."""
    import os

    import pandas as pd

    q, qd, qdd = (np.atleast_2d(np.asarray(a, float)) for a in (q, qd, qdd))
    n = q.shape[1]
    cols = {"t": np.asarray(t, float)}
    for name, arr in (("q", q), ("qd", qd), ("qdd", qdd)):
        for j in range(n):
            cols[f"{name}{j + 1}"] = arr[:, j]
    os.makedirs(os.path.dirname(os.path.abspath(str(path))) or ".", exist_ok=True)
    pd.DataFrame(cols).to_csv(path, index=False)  # shortest repr that reads back the same doubles
    return str(path)


def read_trajectory_csv(path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(t, q, qd, qdd) of a file written by :func:`write_trajectory_csv` (t (N,), others (N, n)).

    One-line :class:`RobustDrakeError` for a missing file, missing or extra joint columns,
    non-finite values, or time that does not increase."""
    import os

    import pandas as pd

    if not os.path.isfile(str(path)):
        raise RobustDrakeError(f"trajectory file {path} not found")
    try:
        df = pd.read_csv(path)
    except (ValueError, OSError) as exc:
        raise RobustDrakeError(f"trajectory file {path}: not a CSV ({str(exc).splitlines()[0]})") from None
    cols = list(df.columns)
    n = sum(1 for c in cols if c.startswith("q") and c[1:].isdigit())
    need = ["t"] + [f"{k}{j + 1}" for k in ("q", "qd", "qdd") for j in range(n)]
    missing = [c for c in need if c not in cols]
    if n == 0 or missing:
        raise RobustDrakeError(f"trajectory file {path}: needs columns t, q1..qn, qd1..qdn, qdd1..qddn "
                               f"(missing {missing[:4] or ['q1']})")
    arr = df[need].to_numpy(float)
    if len(arr) < 2 or not np.all(np.isfinite(arr)):
        raise RobustDrakeError(f"trajectory file {path}: needs at least 2 rows of finite numbers")
    t = arr[:, 0]
    if np.any(np.diff(t) <= 0):
        raise RobustDrakeError(f"trajectory file {path}: time t must increase from row to row")
    return t, arr[:, 1:1 + n], arr[:, 1 + n:1 + 2 * n], arr[:, 1 + 2 * n:]


def quintic_hermite(t, T, Q, QD, QDD):
    """(q, qd, qdd) at t of the piecewise quintic through the samples (T (N,), Q/QD/QDD (N, n)):
    on each interval the quintic matching position, velocity and acceleration at both ends
    (exact for a piecewise quintic; C2 everywhere).  Before the first / after the last sample
    it holds the end sample's position with zero velocity and acceleration (the file's motion
    starts and ends at rest)."""
    t = np.asarray(t, float)
    scalar = t.ndim == 0
    tt = np.atleast_1d(t)
    i = np.clip(np.searchsorted(T, tt, side="right") - 1, 0, len(T) - 2)
    h = (T[i + 1] - T[i])[:, None]
    s = np.clip((tt - T[i])[:, None] / h, 0.0, 1.0)
    p0, v0, a0 = Q[i], QD[i] * h, QDD[i] * h * h
    p1, v1, a1 = Q[i + 1], QD[i + 1] * h, QDD[i + 1] * h * h
    # quintic in s: c0 + c1 s + ... + c5 s^5 with the six end conditions
    c0, c1, c2 = p0, v0, 0.5 * a0
    c3 = 10 * (p1 - p0) - 6 * v0 - 4 * v1 - 1.5 * a0 + 0.5 * a1
    c4 = -15 * (p1 - p0) + 8 * v0 + 7 * v1 + 1.5 * a0 - a1
    c5 = 6 * (p1 - p0) - 3 * v0 - 3 * v1 - 0.5 * a0 + 0.5 * a1
    q = c0 + s * (c1 + s * (c2 + s * (c3 + s * (c4 + s * c5))))
    qd = (c1 + s * (2 * c2 + s * (3 * c3 + s * (4 * c4 + s * 5 * c5)))) / h
    qdd = (2 * c2 + s * (6 * c3 + s * (12 * c4 + s * 20 * c5))) / (h * h)
    out = np.vstack([tt < T[0], tt > T[-1]]).any(axis=0)
    if out.any():
        end = np.where(tt[out] < T[0], 0, len(T) - 1)
        q[out], qd[out], qdd[out] = Q[end], 0.0, 0.0
    return (q[0], qd[0], qdd[0]) if scalar else (q, qd, qdd)


def make_file(arm, path: str, time_offset: float = 0.0):
    """A reference read from a trajectory CSV (``t, q1.., qd1.., qdd1..``: what ``robust-drake
    excite`` writes), interpolated between its rows by :func:`quintic_hermite` (at the file's own
    stamps the rows exactly); its duration is the file's last stamp minus ``time_offset`` [s]
    (the file's time ``t = time_offset`` is the loop's t = 0).  The closed loop refuses it
    like any other reference if it leaves a joint limit (:func:`check_within_limits`)."""
    T, Q, QD, QDD = read_trajectory_csv(path)
    if Q.shape[1] != arm.n:
        raise RobustDrakeError(f"trajectory file {path} has {Q.shape[1]} joints, robot {arm.name} has {arm.n}")
    T = T - float(time_offset)
    if T[-1] <= 0:
        raise RobustDrakeError(f"trajectory file {path}: no samples after time_offset {time_offset:g} s")
    return Reference(lambda t: quintic_hermite(t, T, Q, QD, QDD), arm.n, float(T[-1]), "file",
                     {"path": str(path), "rows": int(len(T)), "time_offset": float(time_offset)})


def task_space_path(q, link_lengths):
    """Convenience alias of :func:`planar_forward_kinematics` for plots."""
    return planar_forward_kinematics(q, link_lengths)
