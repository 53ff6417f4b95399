"""Velocity estimation from quantised encoder positions (JS section 6).

Base class :class:`DiscreteObserver` fixes the ports every estimator shares:

- inputs ``q`` (n, measured positions [rad]) and ``x_d`` (3n, [q_d, qd_d, qdd_d]);
- outputs ``v`` (n, velocity estimate [rad/s]) and ``v_error`` (n, estimate of
  d/dt (q - q_d) [rad/s]), plus ``v_sampled`` (the estimate computed at the last tick,
  held, for logging).

The outputs ``v`` and ``v_error`` are computed from the stored history and the *current*
input, so a controller that updates at the same tick uses this tick's estimate (as the
paper's DSP did). At each tick the observer's discrete update pushes the new sample into
its history. Subclasses implement :meth:`estimate` (pure function of history and input)
and :meth:`advance` (new history).

:class:`AveragingVelocityObserver` is JS eq. 64 for v and eq. 66 for the velocity error
(n = 3 at 2500 Hz).
"""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem, ValueProducer

from robust_drake.errors import RobustDrakeError


class DiscreteObserver(LeafSystem):
    """Sampled velocity estimator with history ``h`` (a flat vector of ``history_size``)."""

    def __init__(self, n: int, period: float, history_size: int, name: str | None = None):
        super().__init__()
        if period <= 0:
            raise RobustDrakeError(f"observer sample period must be positive, got {period}")
        self.n = int(n)
        self.period = float(period)
        self.history_size = int(history_size)
        if name:
            self.set_name(name)
        self._q_port = self.DeclareVectorInputPort("q", self.n)
        self._x_d_port = self.DeclareVectorInputPort("x_d", 3 * self.n)
        self._h_index = self.DeclareDiscreteState(int(history_size))
        self._vs_index = self.DeclareDiscreteState(2 * self.n)
        self.DeclarePeriodicDiscreteUpdateEvent(self.period, 0.0, self._update)
        # (v, v_error) computed once per context change and shared by both outputs and the update
        self._estimate_cache = self.DeclareCacheEntry(
            "velocity estimate", ValueProducer(
                allocate=lambda: AbstractValue.Make(np.zeros(2 * self.n)), calc=self._calc_estimate))
        self.DeclareVectorOutputPort("v", self.n, self._calc_v)
        self.DeclareVectorOutputPort("v_error", self.n, self._calc_v_error)
        self.DeclareStateOutputPort("v_sampled", self._vs_index)

    # -- to override ------------------------------------------------------------------
    def estimate(self, h, q, q_d, qd_d, t):  # pragma: no cover - abstract
        """Return (v, v_error) from history ``h`` and this tick's inputs."""
        raise NotImplementedError

    def advance(self, h, q, q_d, qd_d, v, v_error, t):  # pragma: no cover - abstract
        """Return the next history after the sample (q, q_d) with estimates (v, v_error)."""
        raise NotImplementedError

    def initial_history(self, q0, q_d0, qd_d0) -> np.ndarray:  # pragma: no cover - abstract
        """History consistent with the arm at rest at ``q0`` before t = 0."""
        raise NotImplementedError

    # -- plumbing ---------------------------------------------------------------------
    def _inputs(self, context):
        x_d = self._x_d_port.Eval(context)
        n = self.n
        return self._q_port.Eval(context), x_d[:n], x_d[n:2 * n]

    def _calc_estimate(self, context, abstract_value):
        q, q_d, qd_d = self._inputs(context)
        h = context.get_discrete_state(self._h_index).get_value()
        v, ve = self.estimate(h, q, q_d, qd_d, context.get_time())
        out = abstract_value.get_mutable_value()
        out[:self.n] = v
        out[self.n:] = ve

    def _calc_v(self, context, output):
        output.get_mutable_value()[:] = self._estimate_cache.Eval(context)[:self.n]

    def _calc_v_error(self, context, output):
        output.get_mutable_value()[:] = self._estimate_cache.Eval(context)[self.n:]

    def _update(self, context, discrete_state):
        q, q_d, qd_d = self._inputs(context)
        t = context.get_time()
        h = context.get_discrete_state(self._h_index).get_value()
        est = self._estimate_cache.Eval(context)
        v, ve = est[:self.n].copy(), est[self.n:].copy()
        discrete_state.get_mutable_vector(self._h_index).get_mutable_value()[:] = self.advance(
            h, q, q_d, qd_d, v, ve, t)
        vs = discrete_state.get_mutable_vector(self._vs_index).get_mutable_value()
        vs[:self.n] = v
        vs[self.n:] = ve

    def set_initial(self, context, q0, q_d0, qd_d0=None) -> None:
        """Fill the history as if the arm had rested at ``q0`` (measured) before t = 0."""
        qd_d0 = np.zeros(self.n) if qd_d0 is None else qd_d0
        context.get_mutable_discrete_state(self._h_index).SetFromVector(
            self.initial_history(np.asarray(q0, float), np.asarray(q_d0, float), np.asarray(qd_d0, float)))


class AveragingVelocityObserver(DiscreteObserver):
    """JS eq. 64 (velocity) and eq. 66 (velocity error), window ``n_avg`` (paper: 3).

    v_k = (q_k - q_{k-N}) / (N T)                                     (eq. 64)
    e'_k = (1/N) [ (q~_k - q~_{k-1}) / T + sum_{i=1}^{N-1} e'_{k-i} ]  (eq. 66, q~ = q - q_d)

    Eq. 66 as printed puts the Euler term outside the 1/N, which has a DC gain of N
    (a constant slope would be estimated N times too large); we use the unity-gain
    reading above and record it in BUILD_NOTES.md.

    History layout: [q_{k-1}, ..., q_{k-N}] (N n), q~_{k-1} (n), [e'_{k-1}, ..., e'_{k-N+1}] ((N-1) n).
    """

    def __init__(self, n, period, n_avg: int = 3):
        if int(n_avg) < 1:
            raise RobustDrakeError(f"averaging window must be >= 1, got {n_avg}")
        self.N = int(n_avg)
        super().__init__(n, period, history_size=(2 * self.N) * n, name="AveragingVelocityObserver")

    def estimate(self, h, q, q_d, qd_d, t):
        # scalar loops: this runs at every tick (numpy on 2-vectors costs more than it saves)
        n, N, T = self.n, self.N, self.period
        h, q, q_d = h.tolist(), q.tolist(), q_d.tolist()
        base_qt = N * n
        base_e = (N + 1) * n
        v = [0.0] * n
        ve = [0.0] * n
        for j in range(n):
            qj = q[j]
            v[j] = (qj - h[(N - 1) * n + j]) / (N * T)
            acc = (qj - q_d[j] - h[base_qt + j]) / T
            for i in range(N - 1):
                acc += h[base_e + i * n + j]
            ve[j] = acc / N
        return v, ve

    def advance(self, h, q, q_d, qd_d, v, v_error, t):
        n, N = self.n, self.N
        out = np.empty_like(h)
        out[n:N * n] = h[:(N - 1) * n]  # shift positions
        out[:n] = q
        out[N * n:(N + 1) * n] = np.asarray(q) - np.asarray(q_d)
        if N > 1:
            base = (N + 1) * n
            out[base + n:] = h[base:base + (N - 2) * n]
            out[base:base + n] = v_error
        return out

    def initial_history(self, q0, q_d0, qd_d0):
        n, N = self.n, self.N
        return np.concatenate([np.tile(q0, N), q0 - q_d0, np.tile(-qd_d0, N - 1)])


class ExactVelocityObserver(LeafSystem):
    """Ideal measurement for tests and studies: v = true velocity, v_error = v - qd_d.

    Extra input ``state`` (2n plant state); the builder connects it when present.
    """

    def __init__(self, n):
        super().__init__()
        self.n = n
        self.DeclareVectorInputPort("q", n)
        self._x_d = self.DeclareVectorInputPort("x_d", 3 * n)
        self._state = self.DeclareVectorInputPort("state", 2 * n)
        self.DeclareVectorOutputPort("v", n, self._calc_v)
        self.DeclareVectorOutputPort("v_error", n, self._calc_ve)

    def _calc_v(self, context, out):
        out.get_mutable_value()[:] = self._state.Eval(context)[self.n:]

    def _calc_ve(self, context, out):
        n = self.n
        out.get_mutable_value()[:] = self._state.Eval(context)[n:] - self._x_d.Eval(context)[n:2 * n]

    def set_initial(self, context, *args, **kwargs):
        pass


def make_averaging(ctx, n_avg: int = 3, python: bool = False):
    """Registry factory ``averaging`` (JS eqs. 64/66): run by Drake's C++ LinearSystem
    (:class:`~robust_drake.systems.linear_observer.LinearObserver`, tested equal to this module's
    Python block); ``python=True`` gives the Python :class:`AveragingVelocityObserver` itself."""
    from robust_drake.systems.linear_observer import compiled

    return compiled(AveragingVelocityObserver(ctx.n, ctx.period, n_avg), python)


def make_exact(ctx):
    return ExactVelocityObserver(ctx.n)
