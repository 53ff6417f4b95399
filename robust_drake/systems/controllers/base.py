"""Base class for discrete-time controllers that hold their torque between samples.

A controller samples its inputs at every tick t_k = k T, computes u_k from them and
holds it until t_{k+1} (zero-order hold): the held torque is the controller's discrete
state, exposed with ``DeclareStateOutputPort`` so reading it never re-runs Python code.

Ports (n joints):
- inputs ``x_d`` = [q_d, qd_d, qdd_d] (3n), ``q`` (n, measured/quantised positions [rad]),
  ``v`` (n, velocity estimate [rad/s]), ``v_error`` (n, estimate of d/dt (q - q_d) [rad/s]);
- output ``u`` (n, joint torque command [N m]).

Because the observers compute their outputs from the current ``q`` input and their own
history, the torque applied from t_k uses the measurement taken at t_k: there is no
extra one-sample delay (the paper's DSP also computed within the sample).
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import LeafSystem


class DiscreteController(LeafSystem):
    """Sampled controller skeleton; subclasses implement :meth:`compute` (pure math).

    Ports ``x_d`` (3n: q_d, qd_d, qdd_d), ``q``, ``v``, ``v_error`` (n each) -> ``u`` (n) [N m],
    a discrete state updated every ``period`` s and held between samples (zero-order hold), as
    the closed loop expects (BUILD_NOTES "Architecture contract").

    Parameters
    ----------
    n : int
        Number of joints.
    period : float
        Sample period [s] (``ctx.period`` in a factory; 1/2500 s at 2500 Hz).
    name : str, optional
        The block's name in the diagram.
    """

    def __init__(self, n: int, period: float, name: str | None = None):
        super().__init__()
        if period <= 0:
            raise ValueError(f"sample period must be positive, got {period}")
        self.n = int(n)
        self.period = float(period)
        if name:
            self.set_name(name)
        self._x_d_port = self.DeclareVectorInputPort("x_d", 3 * self.n)
        self._q_port = self.DeclareVectorInputPort("q", self.n)
        self._v_port = self.DeclareVectorInputPort("v", self.n)
        self._v_error_port = self.DeclareVectorInputPort("v_error", self.n)
        self._u_index = self.DeclareDiscreteState(self.n)
        self.DeclarePeriodicDiscreteUpdateEvent(self.period, 0.0, self._update)
        self.DeclareStateOutputPort("u", self._u_index)
        self._feedforward = []
        self._inputs_port = None  # [x_d, q, v, v_error] in one port (enable_fused_input)

    def enable_fused_input(self):
        """Declare input ``inputs`` = [x_d, q, v, v_error] (6n), read by the per-tick update instead
        of the four contract ports: one ``Eval`` per tick (``spong.FusedInputController`` feeds it
        from a C++ Multiplexer and exports the four contract ports)."""
        self._inputs_port = self.DeclareVectorInputPort("inputs", 6 * self.n)

    def add_feedforward(self, f) -> None:
        """Add ``f(q, v) -> n torques`` [N m] to every sample's command, computed in the same tick
        from the measured position and the velocity estimate (model-based compensation, e.g. of
        friction or of effects found by identification). No extra delay, held like the rest of u."""
        self._feedforward.append(f)

    def compute(self, t, q_d, qd_d, qdd_d, q, v, v_error):  # pragma: no cover - abstract
        """Return the n joint torques for this sample (override)."""
        raise NotImplementedError

    def _update(self, context, discrete_state):
        n = self.n
        if self._inputs_port is not None:  # one Eval of [x_d, q, v, v_error]
            x = self._inputs_port.Eval(context)
            q, v = x[3 * n:4 * n], x[4 * n:5 * n]
            u = self.compute(context.get_time(), x[:n], x[n:2 * n], x[2 * n:3 * n], q, v, x[5 * n:])
            if self._feedforward:
                u = np.asarray(u, dtype=float) + sum(np.asarray(f(q, v), dtype=float) for f in self._feedforward)
            self.write_u(discrete_state, u)
            return
        x_d = self._x_d_port.Eval(context)
        u = self.compute(
            context.get_time(),
            x_d[:n], x_d[n:2 * n], x_d[2 * n:],
            self._q_port.Eval(context),
            self._v_port.Eval(context),
            self._v_error_port.Eval(context),
        )
        self.write_u(discrete_state, self.with_feedforward(context, u))

    def write_u(self, discrete_state, u) -> None:
        """Store this tick's torque ``u`` (n floats [N m], list or array) as the held command.  When
        u is the block's only discrete group (every controller here but Bascetta-Rocco's), by the
        one-group ``DiscreteValues.set_value(array)``: 8.3k instructions against 16.9k for
        ``set_value(index, list)`` (callgrind per call, pydrake 1.51; a third of the per-tick
        Python update of the D2R2 SP1 loop, BUILD_NOTES "Speed of the 2500 Hz loop")."""
        only = self.__dict__.get("_u_only")
        if only is None:
            only = self._u_only = self.num_discrete_state_groups() == 1
        if only:
            discrete_state.set_value(np.array(u, float))
        else:
            discrete_state.set_value(self._u_index, np.array(u, float))

    def with_feedforward(self, context, u):
        """``u`` plus every feedforward term evaluated at this tick's inputs (subclasses that
        override ``_update`` call this on their command)."""
        if not self._feedforward:
            return u
        q, v = self._q_port.Eval(context), self._v_port.Eval(context)
        return np.asarray(u, dtype=float) + sum(np.asarray(f(q, v), dtype=float) for f in self._feedforward)


def diag_gain(x, n: int, name: str) -> np.ndarray:
    """A diagonal gain given as a scalar, a length-n sequence or an n x n diagonal matrix."""
    a = np.asarray(x, dtype=float)
    if a.ndim == 0:
        d = np.full(n, float(a))
    elif a.ndim == 1 and a.shape[0] == n:
        d = a.copy()
    elif a.shape == (n, n) and np.allclose(a, np.diag(np.diag(a))):
        d = np.diag(a).copy()
    else:
        raise ValueError(f"{name} must be a scalar, {n} numbers or an {n}x{n} diagonal matrix; got shape {a.shape}")
    if np.any(d <= 0):
        raise ValueError(f"{name} must be positive definite (got diagonal {d.tolist()})")
    return d
