"""A linear velocity estimator run by Drake's C++ ``LinearSystem`` instead of Python callbacks.

The finite-difference estimators of JS section 6 (eqs. 60-67, :mod:`robust_drake.systems.estimators`
and :class:`robust_drake.systems.observers.AveragingVelocityObserver`) are linear discrete systems:
with the history ``h`` as state and u = [q, x_d] as input,

    [v, v_error] = C h + D u          (the estimate of this tick, direct feedthrough)
    h+           = A h + B u          (the Python ``advance`` after the estimate)

and the held estimate ``v_sampled`` is a ``ZeroOrderHold`` of [v, v_error] at the same ticks (a
state output, no feedthrough: one LinearSystem output holding it would make the whole port
feedthrough and close an algebraic loop through the friction compensation and a flexible drive).

:class:`LinearObserver` reads A, B, C, D off a Python :class:`~robust_drake.systems.observers.DiscreteObserver`
(the reference: its ``estimate`` and ``advance`` evaluated on unit vectors), checks on random
histories and inputs that the matrices reproduce it, and runs them in a ``LinearSystem`` with period
T inside a small Diagram whose ports are those of the Python block (inputs ``q``, ``x_d``; outputs
``v``, ``v_error``, ``v_sampled``), so it drops into the closed loop under the same name and can be
replaced like any observer.  Same sample timing as the Python block: the outputs use this tick's
input and the stored history; the periodic update (offset 0) pushes the sample.
Cost per 2500 Hz tick: see BUILD_NOTES "Speed of the 2500 Hz loop".
"""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import Demultiplexer, LinearSystem, Multiplexer, ZeroOrderHold

from robust_drake.errors import RobustDrakeError

#: Relative mismatch above which a Python law is declared not linear (checked at construction).
LINEARITY_TOL = 1e-9


def observer_matrices(ref) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(A, B, C, D) of a linear :class:`DiscreteObserver` ``ref``: state h (its history), input
    u = [q, q_d, qd_d, qdd_d], output y = [v, v_error] (see module docstring).

    Column j is the Python law evaluated at the j-th unit vector of (h, u) (exact for a linear law:
    one product with 1.0 per entry).  Raises RobustDrakeError if the law is not linear in (h, u)."""
    n, H = ref.n, ref.history_size
    nx, nu = H, 4 * n

    def law(x, u):
        q, q_d, qd_d = u[:n], u[n:2 * n], u[2 * n:3 * n]
        v, ve = (np.asarray(z, dtype=float) for z in ref.estimate(x, q, q_d, qd_d, 0.0))
        return np.asarray(ref.advance(x, q, q_d, qd_d, v, ve, 0.0), dtype=float), np.concatenate([v, ve])

    cols_x = [law(e, np.zeros(nu)) for e in np.eye(nx)]
    cols_u = [law(np.zeros(nx), e) for e in np.eye(nu)]
    A = np.column_stack([c[0] for c in cols_x])
    C = np.column_stack([c[1] for c in cols_x])
    B = np.column_stack([c[0] for c in cols_u])
    D = np.column_stack([c[1] for c in cols_u])
    rng = np.random.default_rng(0)
    for _ in range(3):
        x, u = rng.normal(size=nx), rng.normal(size=nu)
        x_new, y = law(x, u)
        for got, want in ((A @ x + B @ u, x_new), (C @ x + D @ u, y)):
            if np.max(np.abs(got - want)) > LINEARITY_TOL * max(1.0, np.max(np.abs(want))):
                raise RobustDrakeError(f"observer {ref.get_name() or type(ref).__name__} is not linear in its "
                                       "history and inputs; run it as a Python block")
    return A, B, C, D


class LinearObserver(Diagram):
    """The linear observer ``reference`` (a Python DiscreteObserver, kept as the specification)
    run as a Drake ``LinearSystem`` (and a ``ZeroOrderHold`` for ``v_sampled``) at its period:
    ports ``q`` (n), ``x_d`` (3n) -> ``v``,
    ``v_error`` (n each), ``v_sampled`` (2n, the estimate of the last tick, held)."""

    def __init__(self, reference):
        super().__init__()
        n, T = reference.n, reference.period
        self.reference = reference
        self.n, self.period = n, T
        self.A, self.B, self.C, self.D = observer_matrices(reference)
        b = DiagramBuilder()
        self.linear = b.AddSystem(LinearSystem(self.A, self.B, self.C, self.D, T))
        self.linear.set_name("linear_estimator")
        mux = b.AddSystem(Multiplexer([n, 3 * n]))
        b.Connect(mux.get_output_port(0), self.linear.get_input_port(0))
        b.ExportInput(mux.get_input_port(0), "q")
        b.ExportInput(mux.get_input_port(1), "x_d")
        demux = b.AddSystem(Demultiplexer([n, n]))
        b.Connect(self.linear.get_output_port(0), demux.get_input_port(0))
        b.ExportOutput(demux.get_output_port(0), "v")
        b.ExportOutput(demux.get_output_port(1), "v_error")
        self.hold = b.AddSystem(ZeroOrderHold(T, 2 * n))
        self.hold.set_name("v_sampled_hold")
        b.Connect(self.linear.get_output_port(0), self.hold.get_input_port(0))
        b.ExportOutput(self.hold.get_output_port(0), "v_sampled")
        b.BuildInto(self)
        self.set_name(f"{reference.get_name() or type(reference).__name__}(LinearSystem)")

    def set_initial(self, context, q0, q_d0, qd_d0=None) -> None:
        """As the reference's ``set_initial``: history at rest at ``q0`` before t = 0, held estimate 0."""
        qd_d0 = np.zeros(self.n) if qd_d0 is None else np.asarray(qd_d0, float)
        h0 = self.reference.initial_history(np.asarray(q0, float), np.asarray(q_d0, float), qd_d0)
        sub = self.GetMutableSubsystemContext(self.linear, context)
        sub.get_mutable_discrete_state_vector().SetFromVector(h0)
        self.GetMutableSubsystemContext(self.hold, context).get_mutable_discrete_state_vector().SetZero()


def compiled(observer, python: bool = False):
    """The registry factories' choice: ``observer`` itself (``python=True``, the Python reference)
    or :class:`LinearObserver` around it (the default)."""
    return observer if python else LinearObserver(observer)
