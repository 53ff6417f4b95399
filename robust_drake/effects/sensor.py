"""Effects between the commanded and the applied torque: a constant offset, a gain error of the
torque channel (``torque_scale``) and a transport delay of the command (``time_delay``, with its
discrete delay line).
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.systems.framework import LeafSystem

from robust_drake.effects.base import Effect, _limit_by, check_bounds, delay_bound
from robust_drake.errors import RobustDrakeError


class TorqueOffset(Effect):
    """Constant torque bias (sensor / current offset, unmodelled static load): ``offset`` [N m]."""

    kind = "torque_offset"
    coef_names = ("offset",)
    shape_grid = [{}]

    def _features(self, j, q, qd, qdd, tau, taud):
        return np.ones((q.shape[0], 1))

    def admissible(self, parameters, context=None):
        """Either sign; |offset| <= the largest torque the joint carried in the data."""
        return _limit_by(self, parameters, "offset", context, "tau_max", "max |tau|")


class TorqueScale(Effect):
    """Motor-constant error: the joint receives ``(1 + gain_error) tau`` for a commanded tau.
    Columns ``-tau_j`` with coefficient ``gain_error`` (dimensionless).

    Identifiability: scaling every joint's torque by the same factor only rescales theta, so
    only the gains *relative to each other* are identifiable from free rigid-body fits, and
    candidates are per joint. On a 2-joint arm, gain (1 + e) on joint 1 is indistinguishable from
    gain 1 / (1 + e) on joint 0 (see :func:`equivalent_gain_error`); which joint is "wrong"
    needs an absolute reference (a known mass or a torque sensor)."""

    kind = "torque_scale"
    own_joint_tau = True  # _features reads tau[:, j]
    coef_names = ("gain_error",)
    #: a motor constant wrong by more than 50 %, or -> -1 (the trivial "model = 0" solution of an
    #: errors-in-variables column), is no motor-constant error
    bounds = {"gain_error": (-0.5, 0.5)}
    needs_tau = True
    shape_grid = [{}]

    def _features(self, j, q, qd, qdd, tau, taud):
        return -tau[:, j:j + 1]


def equivalent_gain_error(gain_error: float) -> float:
    """On a 2-joint arm: the gain error on the *other* joint that explains the same data,
    (1 + e') = 1 / (1 + e) (a common factor is absorbed by theta)."""
    return 1.0 / (1.0 + gain_error) - 1.0


class TimeDelay(Effect):
    """Delay ``delay`` d [s] between the recorded command and the torque the plant receives.
    Columns: d tau_j/dt (first-order expansion, see module docstring); joint=None means one delay
    shared by all joints. Block: :class:`TorqueDelayLine`."""

    kind = "time_delay"
    coef_names = ("delay",)
    needs_tau = True
    shared = True
    uses_taud = True
    shape_grid = [{}]
    bounds = {"delay": (0.0, math.inf)}  # causal

    def _features(self, j, q, qd, qdd, tau, taud):
        if taud is None:
            raise RobustDrakeError("time_delay columns need d tau/dt")
        return taud[:, j:j + 1]

    @classmethod
    def candidates(cls, n_joints, robot=None, **context):
        """Offered only when the robot description declares a physical source (:func:`delay_bound`):
        the column d tau/dt correlates with any residual that leads the torque, and would absorb
        it as a 'delay' on an arm that has none."""
        if robot is None or delay_bound(robot)[0] is None:
            return []
        return [cls(joint=None)] + [cls(joint=j) for j in range(n_joints)]

    def admissible(self, parameters, context=None):
        """0 <= d <= the description's bound (``context.max_delay``; None: no source, rejected)."""
        why = check_bounds(parameters, self.bounds)
        if why or context is None:
            return why
        if context.max_delay is None:
            return "no physical source of a delay in the robot description (bus / bus_latency)"
        return check_bounds(parameters, {"delay": (0.0, context.max_delay)})

    def block(self, n, parameters, sample_period=None, **kw):
        d = parameters["delay"]
        delays = np.zeros(n)
        js = self.joints(n)
        delays[js] = d if np.isscalar(d) else np.asarray(d, dtype=float)
        return TorqueDelayLine(n, delays, sample_period or 1e-3)


class TorqueDelayLine(LeafSystem):
    """Discrete delay line on the commanded torque (per-joint delays ``delays`` [s]).

    Samples input ``tau`` every ``period`` into a history buffer; output ``generalized_force`` =
    tau(t - d) - tau(t), tau(t - d) linearly interpolated between the current input and the
    stored samples. Before the first samples exist the history holds zeros."""

    def __init__(self, n, delays, period):
        super().__init__()
        self.n = n
        self.delays = np.asarray(delays, dtype=float)
        if np.any(self.delays < 0):
            raise RobustDrakeError("time_delay: delay must be >= 0")
        self.period = float(period)
        self.K = int(math.ceil(self.delays.max() / self.period)) + 2
        self.set_name("effect_time_delay")
        self._tau = self.DeclareVectorInputPort("tau", n)
        self.DeclareVectorInputPort("state", 2 * n)  # unused; keeps the common port layout
        # state: [t_last, buffer (K x n) newest first]
        self._x = self.DeclareDiscreteState(1 + self.K * n)
        self.DeclarePeriodicDiscreteUpdateEvent(self.period, 0.0, self._update)
        self.DeclareVectorOutputPort("generalized_force", n, self._calc,
                                     prerequisites_of_calc={self.all_sources_ticket()})

    def _update(self, context, discrete_state):
        x = context.get_discrete_state(self._x).get_value()
        new = discrete_state.get_mutable_vector(self._x).get_mutable_value()
        n, K = self.n, self.K
        new[0] = context.get_time()
        new[1 + n:] = x[1:1 + (K - 1) * n]
        new[1:1 + n] = self._tau.Eval(context)

    def _calc(self, context, output):
        x = context.get_discrete_state(self._x).get_value()
        t = context.get_time()
        tau = self._tau.Eval(context)
        n, K = self.n, self.K
        buf = x[1:].reshape(K, n)
        ts = x[0] - self.period * np.arange(K)
        out = np.zeros(n)
        for j in range(n):
            d = self.delays[j]
            if d <= 0:
                continue
            target = t - d
            times = np.concatenate(([t], ts))[::-1]
            vals = np.concatenate(([tau[j]], buf[:, j]))[::-1]
            out[j] = np.interp(target, times, vals, left=vals[0]) - tau[j]
        output.SetFromVector(out)
