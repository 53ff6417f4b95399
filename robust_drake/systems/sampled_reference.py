"""The reference x_d = [q_d, qd_d, qdd_d] as seen by a sampled loop, served by Drake in C++.

Every reader of x_d in the closed loop (observer, controller, logger) samples it at the ticks
t_k = k T, where :class:`robust_drake.trajectories.ReferenceTrajectory` (the Python reference block)
returns its table row k.  :class:`SampledReference` returns the same rows from a C++
``TrajectorySource`` over a zero-order-hold ``PiecewisePolynomial`` whose breaks sit half a period
before each tick, so the value at t_k is row k exactly (tested equal to the Python block) and the
output costs no Python callback per tick.  Between ticks it holds the nearest tick's row (the Python
block computes the exact reference there), and beyond the tabulated horizon it holds the last row
(:meth:`SampledReference.tabulate` sets the horizon; ``ClosedLoop.simulate`` calls it with the run's
duration).  A reader of x_d between ticks (a continuous-time custom block) should use
``ReferenceTrajectory`` (``ClosedLoop.reference_block``).  Port: output ``x_d`` (3n).
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.systems.framework import Diagram, DiagramBuilder
from pydrake.systems.primitives import TrajectorySource
from pydrake.trajectories import PiecewisePolynomial


class SampledReference(Diagram):
    """x_d of ``reference`` (a :class:`robust_drake.trajectories.Reference`) at the ticks k ``period``,
    tabulated for ``duration`` (default: the reference's); :meth:`tabulate` re-tabulates."""

    def __init__(self, reference, period: float, duration: float | None = None):
        super().__init__()
        self.reference, self._period, self._n = reference, float(period), reference.n
        b = DiagramBuilder()
        self.source = b.AddSystem(TrajectorySource(self._table(duration or reference.duration)))
        self.source.set_name("reference_table")
        b.ExportOutput(self.source.get_output_port(0), "x_d")
        b.BuildInto(self)
        self.set_name("SampledReference")

    def _table(self, duration: float) -> PiecewisePolynomial:
        """Rows k = 0..ceil(duration/T)+1 (as ReferenceTrajectory.tabulate), held on
        [(k - 1/2) T, (k + 1/2) T); the last row repeated once more (a ZOH drops its last sample)."""
        T = self._period
        k = np.arange(int(math.ceil(duration / T)) + 2)
        q, qd, qdd = self.reference(k * T)
        table = np.hstack([np.reshape(q, (k.size, -1)), np.reshape(qd, (k.size, -1)), np.reshape(qdd, (k.size, -1))])
        table = np.vstack([table, table[-1:]])
        breaks = (np.arange(table.shape[0]) - 0.5) * T
        return PiecewisePolynomial.ZeroOrderHold(breaks, table.T)

    def tabulate(self, duration: float) -> None:
        """Tabulate the ticks up to ``duration`` [s] (called by ``ClosedLoop.simulate``)."""
        self.source.UpdateTrajectory(self._table(duration))
