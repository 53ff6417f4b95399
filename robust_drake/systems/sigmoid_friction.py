"""Sigmoid joint friction of Gaz et al. (IEEE RA-L 2019, the Franka Emika Panda identification):

    tau_f,i(qd_i) = phi1_i / (1 + exp(-phi2_i (qd_i + phi3_i))) - phi1_i / (1 + exp(-phi2_i phi3_i))

[N m], phi1 [N m], phi2 [s/rad], phi3 [rad/s]; tau_f(0) = 0, smooth (no sgn), saturating at
phi1 (1 - s0) for qd -> +inf and -phi1 s0 for qd -> -inf, s0 = 1 / (1 + exp(-phi2 phi3)).
The plant-side block applies -tau_f (friction opposes motion) on ``generalized_force``.
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.systems.framework import LeafSystem

from robust_drake.errors import RobustDrakeError
from robust_drake.systems.compiled import SymbolicBlock

#: Gaz et al. 2019, Panda joints 1-7 (also in the authors' published dynamic model code).
PANDA_PHI1 = (0.54615, 0.87224, 0.64068, 1.2794, 0.83904, 0.30301, 0.56489)
PANDA_PHI2 = (5.1181, 9.0657, 10.136, 5.5903, 8.3469, 17.133, 10.336)
PANDA_PHI3 = (0.039533, 0.025882, -0.04607, 0.036194, 0.026226, -0.021047, 0.0035526)


def sigmoid_friction(qd, phi1, phi2, phi3) -> np.ndarray:
    """tau_f(qd) of the module docstring (the torque friction takes from the joint) [N m]."""
    qd, phi1, phi2, phi3 = (np.asarray(x, dtype=float) for x in (qd, phi1, phi2, phi3))
    return phi1 / (1.0 + np.exp(-phi2 * (qd + phi3))) - phi1 / (1.0 + np.exp(-phi2 * phi3))


class SigmoidFriction(LeafSystem):
    """Plant-side effect block: input ``state`` (2n), output ``generalized_force`` = -tau_f(qd)."""

    def __init__(self, n, phi1, phi2, phi3):
        super().__init__()
        self.n = int(n)
        self.phi = [np.broadcast_to(np.asarray(p, float), (self.n,)).copy() for p in (phi1, phi2, phi3)]
        if np.any(self.phi[0] < 0) or np.any(self.phi[1] <= 0):
            raise RobustDrakeError("sigmoid friction needs phi1 >= 0 and phi2 > 0")
        self._state = self.DeclareVectorInputPort("state", 2 * self.n)
        self.DeclareVectorOutputPort("generalized_force", self.n, self._calc)

    def _calc(self, context, out):
        qd = self._state.Eval(context)[self.n:]
        out.SetFromVector(-sigmoid_friction(qd, *self.phi))


class CompiledSigmoidFriction(SymbolicBlock):
    """:class:`SigmoidFriction` evaluated by Drake in C++ (a ``SymbolicVectorSystem``, see
    :mod:`robust_drake.systems.compiled`): same ports and law, tested equal to the Python block."""

    def __init__(self, n, phi1, phi2, phi3):
        from pydrake.symbolic import MakeVectorVariable, exp

        ref = SigmoidFriction(n, phi1, phi2, phi3)  # checks the parameters
        self.n, self.phi = ref.n, ref.phi
        x = MakeVectorVariable(2 * self.n, "x")
        out = []
        for i in range(self.n):
            p1, p2, p3 = (float(p[i]) for p in self.phi)
            out.append(-(p1 / (1.0 + exp(-p2 * (x[self.n + i] + p3))) - p1 / (1.0 + math.exp(-p2 * p3))))
        super().__init__(x, out, "state", "generalized_force", "SigmoidFriction(C++)")


def make_sigmoid_friction(ctx, phi1=None, phi2=None, phi3=None, python=False):
    """Registry factory ``sigmoid_friction``: the Panda values of Gaz et al. unless given; run in
    C++ (:class:`CompiledSigmoidFriction`) unless ``python=True``."""
    if phi1 is None and phi2 is None and phi3 is None:
        if ctx.n != 7:
            raise RobustDrakeError("sigmoid_friction has the Panda's (7-joint) values built in; give phi1, phi2, phi3")
        phi1, phi2, phi3 = PANDA_PHI1, PANDA_PHI2, PANDA_PHI3
    return (SigmoidFriction if python else CompiledSigmoidFriction)(ctx.n, phi1, phi2, phi3)
