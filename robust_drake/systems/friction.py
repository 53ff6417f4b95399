"""Friction acting on the plant, and its fixed compensation in the controller.

Plant side: :class:`CoulombViscousFriction`, JS eq. 86 / CI eq. 16,
F(qd) = F_v qd + F_C sgn(qd) (per joint, uncoupled), applied to the plant's generalized
force input with a minus sign (it opposes motion). It is a block separate from the plant,
with its own parameters, so a study can give the "true" plant different friction from
what the controller assumes.

Controller side: :class:`FixedFrictionCompensation`, JS eqs. 89-90: the torque command is
increased by F_C_hat sgn(qd_hat) with F_C_hat = diag(k1_hat, k2_hat) (paper: 1 and 2 N m), and
optionally by the viscous term F_v_hat qd_hat (section 7.1, ``viscous_hat``).
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.systems.framework import LeafSystem

from robust_drake.errors import RobustDrakeError

# Plant friction of the simulated D2R2 (our choice; JS section 7 says only that k2 is about
# twice k1, that the compensation k_hat = (1, 2) N m captures most of it, and that the
# viscous part is small at the speeds used). See BUILD_NOTES.md.
D2R2_COULOMB = (1.2, 2.3)  # N m
D2R2_VISCOUS = (0.15, 0.08)  # N m s / rad
D2R2_K_HAT = (1.0, 2.0)  # JS section 9, eq. 90


def coulomb_viscous_force(qd, coulomb, viscous) -> np.ndarray:
    """JS eq. 86: F(qd) = F_v qd + F_C sgn(qd) (the torque friction takes away) [N m]."""
    qd = np.asarray(qd, dtype=float)
    return np.asarray(viscous) * qd + np.asarray(coulomb) * np.sign(qd)


def _per_joint(x, n, what):
    a = np.asarray(x, dtype=float)
    a = np.full(n, float(a)) if a.ndim == 0 else a
    if a.shape != (n,) or np.any(a < 0):
        raise RobustDrakeError(f"{what} must be {n} non-negative numbers (got {x!r})")
    return a


class CoulombViscousFriction(LeafSystem):
    """Plant-side friction: input ``state`` (2n), output ``generalized_force`` = -F(qd)."""

    def __init__(self, n: int, coulomb, viscous):
        super().__init__()
        self.n = int(n)
        self.coulomb = _per_joint(coulomb, n, "Coulomb friction")
        self.viscous = _per_joint(viscous, n, "viscous friction")
        self._c = self.coulomb.tolist()
        self._b = self.viscous.tolist()
        self._state = self.DeclareVectorInputPort("state", 2 * self.n)
        self.DeclareVectorOutputPort("generalized_force", self.n, self._calc)

    def _calc(self, context, output):
        x = self._state.Eval(context)
        out = output.get_mutable_value()
        n = self.n
        for i in range(n):
            w = x[n + i]
            out[i] = -(self._b[i] * w + (math.copysign(self._c[i], w) if w != 0.0 else 0.0))


class FixedFrictionCompensation(LeafSystem):
    """JS eqs. 89-90: output ``u`` = input ``u`` + F_C_hat sgn(``v``).

    Both inputs are held signals (the controller's torque and the observer's sampled
    velocity estimate), so the output is computed once per sample: its calc depends on
    the input ports only, and their sources are discrete states.
    """

    def __init__(self, n: int, k_hat=D2R2_K_HAT, viscous_hat=None):
        super().__init__()
        self.n = int(n)
        self.k_hat = _per_joint(k_hat, n, "k_hat")
        # optional viscous compensation F_v_hat v (JS section 7.1: "compensating for the viscous
        # friction did not improve performance significantly")
        self.viscous_hat = np.zeros(self.n) if viscous_hat is None else _per_joint(viscous_hat, n, "viscous_hat")
        self._u = self.DeclareVectorInputPort("u", self.n)
        self._v = self.DeclareVectorInputPort("v", self.n)
        self.DeclareVectorOutputPort(
            "u_compensated", self.n, self._calc,
            prerequisites_of_calc={self._u.ticket(), self._v.ticket()},
        )

    def _calc(self, context, output):
        v = self._v.Eval(context)
        output.get_mutable_value()[:] = self._u.Eval(context) + self.k_hat * np.sign(v) + self.viscous_hat * v


def make_coulomb_viscous(ctx, coulomb=D2R2_COULOMB, viscous=D2R2_VISCOUS):
    return CoulombViscousFriction(ctx.n, coulomb, viscous)
