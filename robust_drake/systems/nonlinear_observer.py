"""Nonlinear velocity observer of Jaritz & Spong, section 6.2 (eqs. 74-85).

Full-order observer for ``x1 = q``, ``x2 = q'`` of the D2R2 without gravity (eqs. 74-80):

    xhat' = A xhat + L (y - G xhat) + [0; M^-1(y) tau]                     (eq. 81)

with ``A = [[0, I], [0, 0]]`` (eq. 79), ``G = [I, 0]`` (eq. 80), ``L = [L1 I; L2 I]`` and ``M`` the
inertia matrix (eq. 3) at the *nominal* parameters (middle of the uncertainty range, table 11).
The linear part has the double eigenvalue ``-L1/2 +- sqrt(L1^2/4 - L2)`` (eq. 84); the paper's
``L1 = 3000``, ``L2 = 2.25e6`` make it critically damped at -1500 rad/s. Discretised with the
Euler step of eq. 85 (the printed ``x_k`` on the right-hand side is read as ``xhat_k``):

    xhat_k+1 = xhat_k + T (A xhat_k + L (y_k - G xhat_k) + [0; M^-1(y_k) tau_k])

Timing in the loop: the stored state is ``(xhat_k-1, y_k-1)``; at tick k the output is the
Euler step from it driven by the torque held over ``[t_k-1, t_k]`` (the ``tau`` input, i.e.
the applied torque, which is a held value so there is no algebraic loop). The velocity-error
output is ``xhat_2 - q'_d`` (the reference velocity is known exactly).
"""

from __future__ import annotations

import math

import numpy as np

from robust_drake.description import packaged_description
from robust_drake.errors import RobustDrakeError

#: JS table 11, nominal D2R2 parameter vector (eq. 14), from robots/d2r2.yaml.
THETA0_TABLE11 = packaged_description("d2r2").parameter_sets["theta0"]


def d2r2_inertia(q2: float, theta) -> tuple[float, float, float]:
    """(d11, d12, d22) of JS eq. 3 in the parameters of eq. 14:
    ``d11 = th1 + th2 + 2 th3 cos q2``, ``d12 = th2 + th3 cos q2``, ``d22 = th2``."""
    c2 = math.cos(q2)
    t1, t2, t3 = theta[0], theta[1], theta[2]
    return t1 + t2 + 2.0 * t3 * c2, t2 + t3 * c2, t2


def d2r2_inverse_inertia_times(q2: float, tau, theta) -> tuple[float, float]:
    """``M(q)^-1 tau`` for the D2R2 (2x2 closed form)."""
    d11, d12, d22 = d2r2_inertia(q2, theta)
    det = d11 * d22 - d12 * d12
    return (d22 * tau[0] - d12 * tau[1]) / det, (-d12 * tau[0] + d11 * tau[1]) / det


def observer_eigenvalues(L1: float, L2: float):
    """JS eq. 84: eigenvalues of ``A - L G`` per joint."""
    disc = complex(L1 * L1 / 4.0 - L2)
    root = disc ** 0.5
    return (-L1 / 2.0 + root, -L1 / 2.0 - root)


def nonlinear_observer_step(xhat, y, tau, T, L1=3000.0, L2=2.25e6, theta=THETA0_TABLE11):
    """One Euler step of JS eq. 85 for the 2-joint D2R2.

    ``xhat = [q1, q2, v1, v2]`` at tick k, ``y`` the measured q_k, ``tau`` the torque applied over
    ``[t_k, t_k+1]`` (or ``None``: no torque feed-forward, a linear observer). Returns the new
    list ``xhat_k+1``.
    """
    q1, q2, v1, v2 = xhat
    e1 = y[0] - q1
    e2 = y[1] - q2
    if tau is None:
        a1 = a2 = 0.0
    else:
        a1, a2 = d2r2_inverse_inertia_times(y[1], tau, theta)
    return [q1 + T * (v1 + L1 * e1), q2 + T * (v2 + L1 * e2),
            v1 + T * (L2 * e1 + a1), v2 + T * (L2 * e2 + a2)]


def discrete_error_poles(T: float, L1: float = 3000.0, L2: float = 2.25e6):
    """Poles of the Euler-discretised error dynamics ``I + T (A - L G)`` per joint
    (the paper's gains at 2500 Hz: a double pole at z = 0.4)."""
    Phi = np.array([[1.0 - T * L1, T], [-T * L2, 1.0]])
    return np.linalg.eigvals(Phi)


def check_observer_gains(T: float, L1: float, L2: float) -> None:
    """Raise a clear error when the Euler-discretised observer is unstable at this rate."""
    poles = discrete_error_poles(T, L1, L2)
    if np.max(np.abs(poles)) >= 1.0:
        raise RobustDrakeError(
            f"nonlinear observer with L1={L1}, L2={L2} is unstable at T={T} s (Euler poles "
            f"{np.round(poles, 3)}); lower the gains or raise the rate (JS eq. 84-85)")


# ---------------------------------------------------------------------------------------------
# LeafSystem on the observer port convention, plus the optional input ``tau``
# ---------------------------------------------------------------------------------------------
from robust_drake.systems.observers import DiscreteObserver  # noqa: E402


class NonlinearVelocityObserver(DiscreteObserver):
    """JS eqs. 81-85 for the D2R2. Extra optional input ``tau`` (n, the torque applied to the
    arm); left unconnected, the observer is the linear part only (M^-1 tau = 0).

    History: ``[qhat_k-1 (n), vhat_k-1 (n), y_k-1 (n)]``."""

    def __init__(self, n, period, L1=3000.0, L2=2.25e6, theta=THETA0_TABLE11):
        if n != 2:
            raise RobustDrakeError(f"the nonlinear observer uses the D2R2 inertia (JS eq. 3); got n = {n}")
        check_observer_gains(period, L1, L2)
        self.L1 = float(L1)
        self.L2 = float(L2)
        self.theta = tuple(float(x) for x in theta)
        super().__init__(n, period, history_size=3 * n, name="NonlinearVelocityObserver")
        self._tau_port = self.DeclareVectorInputPort("tau", n)
        self._tau = None

    def _inputs(self, context):
        self._tau = self._tau_port.Eval(context) if self._tau_port.HasValue(context) else None
        return super()._inputs(context)

    def _xhat(self, h):
        return nonlinear_observer_step(h[0:4], h[4:6], self._tau, self.period, self.L1, self.L2, self.theta)

    def estimate(self, h, q, q_d, qd_d, t):
        x = self._xhat(h)
        v = np.array(x[2:4])
        return v, v - qd_d

    def advance(self, h, q, q_d, qd_d, v, v_error, t):
        x = self._xhat(h)
        return np.array([x[0], x[1], x[2], x[3], q[0], q[1]])

    def initial_history(self, q0, q_d0, qd_d0):
        return np.array([q0[0], q0[1], 0.0, 0.0, q0[0], q0[1]])


def make_nonlinear(ctx, L1=3000.0, L2=2.25e6, theta=None):
    """Registry factory ``nonlinear``; ``M`` from the robot's nominal parameters of JS eq. 14
    (its description's ``theta0``; the D2R2's is table 11, the centre of the uncertainty
    interval) unless ``theta`` is given."""
    if theta is None:
        from robust_drake.description import describe

        d = describe(ctx.robot)
        if d.closed_form_regressor != "d2r2" or "theta0" not in d.parameter_sets:
            raise RobustDrakeError(f"the nonlinear observer needs the arm's theta of JS eq. 14; robot {ctx.robot!r} "
                                   "has none in its description: pass observer_params theta=(th1, th2, th3)")
        theta = d.parameter_sets["theta0"]
    return NonlinearVelocityObserver(ctx.n, ctx.period, L1=L1, L2=L2, theta=theta)
