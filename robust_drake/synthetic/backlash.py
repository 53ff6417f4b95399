"""Backlash in a joint's drive: a gap between the motor side and the link (generator side).

Model (the "dead-zone" backlash model with its physical correction, Nordin & Gutman,
"Controlling mechanical systems with backlash -- a survey", Automatica 38 (2002), section 2):
the motor side of joint j is an inertia J_m [kg m^2, referred to the joint] at angle theta_m,
driven by the commanded torque tau_j; the link (the Drake plant) receives only the torque the
gear teeth transmit. With the gap position delta = theta_m - q_j [rad] and half-width b [rad]::

    tau_t = k D_b(delta) + c delta_dot        while the teeth touch (|delta| > b), else 0,
    D_b(delta) = delta - b sign(delta) for |delta| > b, else 0,
    tau_t is clipped to the sign of D_b (contact pushes, never pulls),
    J_m theta_m'' = tau_j - tau_t ,           M(q) q'' + ... = tau + f_e with f_e_j = tau_t - tau_j

k [N m/rad] and c [N m s/rad] are the contact stiffness and damping of the teeth. Inside the
gap the link receives no drive torque and the motor accelerates alone; at the end of the gap
the teeth hit. For the rigid model the fitter holds, the motor inertia J_m sits on the link
(reflected rotor inertia), so a simulated arm with backlash takes J_m off the link side
(:func:`robust_drake.synthetic.simulated_cases.backlash_case`).

Why backlash is NOT a library kind (issue 13): its effect on a log of motor torque and link
position is a burst of residual at every reversal of the transmitted torque whose timing depends
on the unobserved state delta and whose size depends on J_m, b and k jointly; no column linear
in a coefficient represents it, and in the battery's logs (250 Hz, encoder 2 pi / 2^14) the burst
lasts a few samples. It is simulated here to check that the repair flags it (or at least
claims nothing it cannot back) and is never worse.

:func:`transmitted_torque` is the pure map; :class:`BacklashDrive` the Drake block (continuous
state (delta, omega_m) per joint with backlash, set at ``Initialize`` to teeth touching on the
side the initial torque pushes, motor moving with the link).
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.systems.framework import LeafSystem

from robust_drake.errors import RobustDrakeError

__all__ = ["dead_zone", "transmitted_torque", "contact_parameters", "BacklashDrive"]


def dead_zone(delta, b):
    """D_b(delta) [rad]: delta - b sign(delta) outside the gap |delta| <= b, 0 inside (pure)."""
    delta = np.asarray(delta, dtype=float)
    return np.where(np.abs(delta) > b, delta - b * np.sign(delta), 0.0)


def transmitted_torque(delta, delta_dot, b, k, c):
    """Torque [N m] the teeth transmit to the link at gap position delta [rad] and rate
    delta_dot [rad/s]: k D_b(delta) + c delta_dot in contact, 0 in the gap, and never of the
    opposite sign to D_b (Nordin & Gutman 2002, physical dead-zone model). Pure, vectorised."""
    d = dead_zone(delta, b)
    t = np.where(d != 0.0, k * d + c * np.asarray(delta_dot, dtype=float), 0.0)
    return np.where(t * d > 0.0, t, 0.0)


def contact_parameters(J_m: float, frequency_hz: float, damping_ratio: float) -> tuple[float, float]:
    """(k, c) giving the motor inertia J_m [kg m^2] on stiff teeth a contact mode at
    ``frequency_hz`` with ``damping_ratio``: k = J_m (2 pi f)^2, c = 2 zeta sqrt(k J_m)."""
    k = J_m * (2.0 * math.pi * frequency_hz) ** 2
    return k, 2.0 * damping_ratio * math.sqrt(k * J_m)


class BacklashDrive(LeafSystem):
    """Backlash on joint ``joint`` of an n-joint plant (see the module docstring).

    Inputs ``state`` (2n, the plant's) and ``tau`` (n, commanded). Outputs
    ``generalized_force`` (n): tau_t - tau_j on the joint, 0 elsewhere (summed with tau the
    link receives tau_t), and ``gap`` (1): the dead-band position delta [rad].
    Continuous state [delta, omega_m]; parameters gap half-width ``b`` [rad], motor-side
    inertia ``J_m`` [kg m^2], contact ``stiffness`` k [N m/rad] and ``damping`` c [N m s/rad]."""

    def __init__(self, n: int, joint: int, b: float, J_m: float, stiffness: float, damping: float):
        super().__init__()
        if not 0 <= joint < n:
            raise RobustDrakeError(f"backlash: joint index {joint} (0-based) out of range for {n} joints")
        if b < 0 or J_m <= 0 or stiffness <= 0 or damping < 0:
            raise RobustDrakeError("backlash: needs b >= 0, J_m > 0, stiffness > 0, damping >= 0")
        self.n, self.j = n, int(joint)
        self.b, self.J_m, self.k, self.c = float(b), float(J_m), float(stiffness), float(damping)
        self.set_name(f"backlash_{joint}")
        self._state = self.DeclareVectorInputPort("state", 2 * n)
        self._tau = self.DeclareVectorInputPort("tau", n)
        self.DeclareContinuousState(2)
        self.DeclareVectorOutputPort("generalized_force", n, self._calc_force)
        self.DeclareVectorOutputPort("gap", 1, self._calc_gap, prerequisites_of_calc={self.xc_ticket()})
        self.DeclareInitializationUnrestrictedUpdateEvent(self._initialize)

    def _delta_dot(self, context, x):
        return x[1] - self._state.Eval(context)[self.n + self.j]

    def _tau_t(self, context):
        x = context.get_continuous_state_vector().CopyToVector()
        return float(transmitted_torque(x[0], self._delta_dot(context, x), self.b, self.k, self.c))

    def _initialize(self, context, state):
        tau = self._tau.Eval(context)[self.j]
        qd = self._state.Eval(context)[self.n + self.j]
        state.get_mutable_continuous_state().SetFromVector([self.b * np.sign(tau), qd])

    def DoCalcTimeDerivatives(self, context, derivatives):
        x = context.get_continuous_state_vector().CopyToVector()
        tau = self._tau.Eval(context)[self.j]
        derivatives.get_mutable_vector().SetFromVector(
            [self._delta_dot(context, x), (tau - self._tau_t(context)) / self.J_m])

    def _calc_force(self, context, output):
        out = np.zeros(self.n)
        out[self.j] = self._tau_t(context) - self._tau.Eval(context)[self.j]
        output.SetFromVector(out)

    def _calc_gap(self, context, output):
        output.SetFromVector([context.get_continuous_state_vector()[0]])
