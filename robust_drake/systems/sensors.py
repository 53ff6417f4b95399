"""Sensors: the incremental encoder.

The D2R2's encoders give 655360 counts per revolution (JS section 1), an interpulse angle
theta_m = 2 pi / 655360 = 9.5874e-6 rad (JS eq. 70). An incremental encoder reports the
number of whole counts passed, so the measured angle is theta_m * floor(q / theta_m).
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.systems.framework import LeafSystem

from robust_drake.description import packaged_description
from robust_drake.errors import RobustDrakeError
from robust_drake.systems.compiled import SymbolicBlock

# the D2R2's encoder, from robots/d2r2.yaml (simulation.encoder_counts_per_rev)
D2R2_THETA_M = packaged_description("d2r2").encoder_resolution  # 9.5874e-6 rad, JS eq. 70
D2R2_COUNTS_PER_REV = round(2.0 * math.pi / D2R2_THETA_M)


def quantize(q, theta_m: float) -> np.ndarray:
    """theta_m * floor(q / theta_m): what an incremental encoder with resolution theta_m reads."""
    return theta_m * np.floor(np.asarray(q) / theta_m)


class QuantizingEncoder(LeafSystem):
    """Input ``state`` (2n plant state [q, v]); output ``q`` (n) quantised to ``theta_m`` [rad].

    ``theta_m = None`` passes q through unchanged (an ideal sensor).
    """

    def __init__(self, n: int, theta_m: float | None = D2R2_THETA_M):
        super().__init__()
        if theta_m is not None and not theta_m > 0:
            raise RobustDrakeError(f"encoder resolution must be positive (got {theta_m})")
        self.n = int(n)
        self.theta_m = theta_m
        self._state = self.DeclareVectorInputPort("state", 2 * self.n)
        self.DeclareVectorOutputPort("q", self.n, self._calc)

    def _calc(self, context, output):
        q = self._state.Eval(context)[: self.n]
        if self.theta_m is None:
            output.get_mutable_value()[:] = q
        else:
            output.get_mutable_value()[:] = self.theta_m * np.floor(q / self.theta_m)


class CompiledQuantizingEncoder(SymbolicBlock):
    """:class:`QuantizingEncoder` evaluated by Drake in C++ (a ``SymbolicVectorSystem``, see
    :mod:`robust_drake.systems.compiled`): input ``state`` (2n), output ``q`` (n) =
    theta_m floor(q / theta_m) (q itself for ``theta_m`` None); tested equal to the Python block."""

    def __init__(self, n: int, theta_m: float | None = D2R2_THETA_M):
        from pydrake.symbolic import MakeVectorVariable, floor

        if theta_m is not None and not theta_m > 0:
            raise RobustDrakeError(f"encoder resolution must be positive (got {theta_m})")
        self.n, self.theta_m = int(n), theta_m
        x = MakeVectorVariable(2 * self.n, "x")
        q = [x[i] for i in range(self.n)]
        out = q if theta_m is None else [float(theta_m) * floor(qi / float(theta_m)) for qi in q]
        super().__init__(x, out, "state", "q", "QuantizingEncoder(C++)")
