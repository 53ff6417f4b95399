"""Friction acting on the plant, and its fixed compensation in the controller.

Plant side: :class:`CoulombViscousFriction`, JS eq. 86 / CI eq. 16,
F(qd) = F_v qd + F_C s(qd) (per joint, uncoupled) with a sharp (sgn) or smooth (tanh) sign law
(:func:`coulomb_viscous_force`, the one friction law of the package), applied to the plant's
generalized force input with a minus sign (it opposes motion). It is a block separate from the plant,
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

from pydrake.symbolic import MakeVectorVariable

from robust_drake.description import packaged_description
from robust_drake.errors import RobustDrakeError
from robust_drake.systems.compiled import SymbolicBlock

# Plant friction of the simulated D2R2 (our choice, reasons in robots/d2r2.yaml and
# BUILD_NOTES.md) and the fixed compensation of JS section 9, eq. 90: read from the description.
_D2R2 = packaged_description("d2r2")
D2R2_COULOMB = tuple(_D2R2.plant_friction["coulomb"])  # N m
D2R2_VISCOUS = tuple(_D2R2.plant_friction["viscous"])  # N m s / rad
D2R2_K_HAT = _D2R2.friction_compensation_k_hat  # N m


def coulomb_viscous_force(qd, coulomb, viscous, v_eps=None) -> np.ndarray:
    """JS eq. 86 / CI eq. 16: F(qd) = F_v qd + F_C s(qd), the torque friction takes away [N m].

    The sign law s is sharp, s = sgn(qd) (``v_eps`` None), or smooth, s = tanh(qd / v_eps) with
    v_eps [rad/s] the width of the transition (what an error-controlled integrator can step
    through).  Broadcasts over the last axis (joints)."""
    qd = np.asarray(qd, dtype=float)
    s = np.sign(qd) if v_eps is None else np.tanh(qd / v_eps)
    return np.asarray(viscous) * qd + np.asarray(coulomb) * s


def _per_joint(x, n, what, nonnegative=True):
    a = np.asarray(x, dtype=float)
    a = np.full(n, float(a)) if a.ndim == 0 else a
    if a.shape != (n,) or not np.all(np.isfinite(a)) or (nonnegative and np.any(a < 0)):
        kind = "non-negative" if nonnegative else "finite"
        raise RobustDrakeError(f"{what} must be {n} {kind} numbers (got {x!r})")
    return a


class CoulombViscousFriction(LeafSystem):
    """Plant-side friction, the project's one friction block: input ``state`` (2n), output
    ``generalized_force`` = -:func:`coulomb_viscous_force` (qd; coulomb, viscous, v_eps).

    ``v_eps`` None: sharp sign (the closed loop's plant, JS eq. 86).  ``v_eps`` > 0: smooth
    sign tanh(qd / v_eps); the simulated experiments use 0.01 rad/s
    (``synthetic.simulated.TRUE_FRICTION_V_EPS``), the replays 0.05 rad/s
    (``model_repair.replay.REPLAY_V_EPS``).  ``nonnegative=False`` accepts identified
    coefficients of either sign (a replay of whatever the fit returned)."""

    def __init__(self, n: int, coulomb, viscous, v_eps: float | None = None, *,
                 nonnegative: bool = True):
        super().__init__()
        self.n = int(n)
        self.coulomb = _per_joint(coulomb, n, "Coulomb friction", nonnegative)
        self.viscous = _per_joint(viscous, n, "viscous friction", nonnegative)
        if v_eps is not None and not (math.isfinite(v_eps) and v_eps > 0):
            raise RobustDrakeError(f"v_eps must be a positive number of rad/s or None (got {v_eps!r})")
        self.v_eps = None if v_eps is None else float(v_eps)
        self._c = self.coulomb.tolist()
        self._b = self.viscous.tolist()
        self._state = self.DeclareVectorInputPort("state", 2 * self.n)
        self.DeclareVectorOutputPort("generalized_force", self.n,
                                     self._calc_sharp if self.v_eps is None else self._calc)

    def _calc(self, context, output):
        qd = self._state.Eval(context)[self.n:]
        output.SetFromVector(-coulomb_viscous_force(qd, self.coulomb, self.viscous, self.v_eps))

    def _calc_sharp(self, context, output):
        """Scalar fast path of the sharp law (evaluated at every integrator stage of the 2500 Hz
        loop); tests/test_forces.py checks it equal to :func:`coulomb_viscous_force`."""
        x = self._state.Eval(context)
        out = output.get_mutable_value()
        n = self.n
        for i in range(n):
            w = x[n + i]
            out[i] = -(self._b[i] * w + (math.copysign(self._c[i], w) if w != 0.0 else 0.0))


class CompiledCoulombViscousFriction(SymbolicBlock):
    """:class:`CoulombViscousFriction` evaluated by Drake in C++ (a ``SymbolicVectorSystem``, see
    :mod:`robust_drake.systems.compiled`): same ports (``state`` -> ``generalized_force``), same
    parameters and law, tested equal to the Python block; the closed loop's plant friction.  The
    sharp sign is ``if_then_else`` (sgn 0 = 0, as the Python block), the smooth one tanh."""

    def __init__(self, n: int, coulomb, viscous, v_eps: float | None = None, *, nonnegative: bool = True):
        from pydrake.symbolic import Expression, if_then_else, tanh

        ref = CoulombViscousFriction(n, coulomb, viscous, v_eps, nonnegative=nonnegative)  # checks the inputs
        self.n, self.coulomb, self.viscous, self.v_eps = ref.n, ref.coulomb, ref.viscous, ref.v_eps
        x = MakeVectorVariable(2 * self.n, "x")
        out = []
        for i in range(self.n):
            w, c, b = x[self.n + i], float(self.coulomb[i]), float(self.viscous[i])
            if self.v_eps is None:
                s = if_then_else(w > 0.0, Expression(c), if_then_else(w < 0.0, Expression(-c), Expression(0.0)))
            else:
                s = c * tanh(w / self.v_eps)
            out.append(-(b * w + s))
        super().__init__(x, out, "state", "generalized_force", "CoulombViscousFriction(C++)")


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
