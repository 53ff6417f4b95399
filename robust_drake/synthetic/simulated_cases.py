"""Simulated experiments with effects OUTSIDE the original effect library (issue 13).

Builds on :func:`robust_drake.synthetic.simulated.simulate_experiment` (its ``extra_blocks``
hook): each case adds one true-plant block that no kind of the original library represents,
on an arm other than the D2R2 / default C.1 arm. Every block has input ``state`` (2n) [and
``tau`` (n)] and output ``generalized_force`` (n), summed into the plant's applied force like
the library's blocks (sign convention of :mod:`effects`: the output is the torque the effect
adds to the joint).

Cases (:data:`OUTSIDE_CASES`):

- ``periodic_fast``: a torque periodic in time, 3.1 Hz, on one joint (a pump, a vibrating base);
- ``periodic_slow``: the same at 0.73 Hz (below 1 Hz, inside the band of the motion's harmonics);
- ``dead_zone``: a driver dead-zone, commanded torque below ``threshold`` [N m] in magnitude does
  not reach the joint: applied = tau - clip(tau, -threshold, threshold);
- ``drift``: viscous friction growing linearly over each run (warming up):
  b(t) = b_0 + rate * t, the block adds -rate * t * qd [N m];
- ``none``: the baseline arm only.
"""

from __future__ import annotations

import math
import os
import tempfile

import numpy as np
from pydrake.systems.framework import LeafSystem

from robust_drake.description import packaged_description
from robust_drake.errors import RobustDrakeError
from robust_drake.synthetic.simulated import PeriodicDisturbance, simulate_experiment


class DeadZoneDriver(LeafSystem):
    """Driver dead-zone on joint ``joint``: generalized_force = -clip(tau_j, -d, d) (so the joint
    receives tau_j - clip(tau_j, -d, d)); inputs ``state`` (2n), ``tau`` (n)."""

    def __init__(self, n, joint, threshold):
        super().__init__()
        self.n, self.j, self.d = n, int(joint), float(threshold)
        self.DeclareVectorInputPort("state", 2 * n)
        self._tau = self.DeclareVectorInputPort("tau", n)
        self.DeclareVectorOutputPort("generalized_force", n, self._calc)

    def _calc(self, context, output):
        tau = self._tau.Eval(context)
        out = np.zeros(self.n)
        out[self.j] = -min(max(tau[self.j], -self.d), self.d)
        output.SetFromVector(out)


class ViscousDrift(LeafSystem):
    """Viscous coefficient growing linearly in time on joint ``joint``:
    generalized_force_j = -rate * t * qd_j  (rate [N m s / rad per s])."""

    def __init__(self, n, joint, rate):
        super().__init__()
        self.n, self.j, self.rate = n, int(joint), float(rate)
        self._state = self.DeclareVectorInputPort("state", 2 * n)
        self.DeclareVectorOutputPort("generalized_force", n, self._calc)

    def _calc(self, context, output):
        qd = self._state.Eval(context)[self.n:]
        out = np.zeros(self.n)
        out[self.j] = -self.rate * context.get_time() * qd[self.j]
        output.SetFromVector(out)


#: robot -> simulation settings (excitation, friction, noise) that suit its size
ARMS = {
    "dfki_double_pendulum_a0": dict(coulomb=(0.02, 0.01), viscous=(0.004, 0.002), torque_noise_std=0.005,
                                    excitation=dict(amplitude=(1.0, 1.3), torque_limit=12.0)),
    "siciliano_2link": dict(effect_scale=400.0, coulomb=(2.0, 1.0), viscous=(0.4, 0.2), torque_noise_std=0.5,
                            excitation=dict(amplitude=(0.8, 1.0), torque_limit=3000.0)),
    "serial7": dict(effect_scale=20.0, drift_scale=100.0, coulomb=0.2, viscous=0.04, torque_noise_std=0.05,
                    excitation=dict(amplitude=0.6, torque_limit=300.0)),
}

#: case -> (kind of the hidden block, joint, parameters relative to the arm's torque scale)
OUTSIDE_CASES = ("none", "periodic_fast", "periodic_slow", "dead_zone", "drift")


def _scale(robot) -> float:
    """Size of the hidden effects relative to the A.0 cases. Siciliano: 400 (not the torque-noise
    ratio 100): with 50 kg links the encoder quantisation differentiated twice and multiplied by
    the ~100 kg m^2 inertia leaves a ~4 N m baseline residual (measured, no-effect case), so the
    effects are sized against that, ~3-15 % of the torques. serial7: 20 (drift 100: its shoulder
    joint moves slowly, a 20x drift stayed at z = 2.8 in the drift test)."""
    return ARMS[robot].get("effect_scale", 1.0)


def outside_case(case: str, robot: str = "dfki_double_pendulum_a0", seed: int = 0, out_dir=None,
                 duration: float = 12.0, rate_hz: float = 250.0):
    """Fit and validation CSVs of ``robot`` with one effect outside the library.

    Returns (fit_csv, validate_csv, truth) with truth = {"case", "kind", "joint", "parameters",
    "robot"}; fit and validation use different reference seeds (different motions)."""
    if robot not in ARMS:
        raise RobustDrakeError(f"no simulation settings for {robot!r}; known: {', '.join(ARMS)}")
    if case not in OUTSIDE_CASES:
        raise RobustDrakeError(f"unknown case {case!r}; known: {', '.join(OUTSIDE_CASES)}")
    out_dir = out_dir or tempfile.mkdtemp(prefix=f"outside_{case}_")
    os.makedirs(out_dir, exist_ok=True)
    s = _scale(robot)
    j = 1
    if case == "none":
        extra, truth = (), {"kind": None, "joint": None, "parameters": {}}
    elif case in ("periodic_fast", "periodic_slow"):
        f = 3.1 if case == "periodic_fast" else 0.73
        amp = 0.08 * s
        extra = (lambda n: PeriodicDisturbance(n, [amp if i == j else 0.0 for i in range(n)], f, 0.3),)
        truth = {"kind": "periodic_disturbance", "joint": j,
                 "parameters": {"amplitude": amp, "frequency": f}}
    elif case == "dead_zone":
        d = 0.15 * s
        extra = (lambda n: DeadZoneDriver(n, j, d),)
        truth = {"kind": "dead_zone", "joint": j, "parameters": {"threshold": d}}
    else:  # drift
        rate = 0.004 * ARMS[robot].get("drift_scale", s)  # b grows by rate * duration over the run (0.048 N m s/rad in 12 s on A.0)
        extra = (lambda n: ViscousDrift(n, j, rate),)
        truth = {"kind": "friction_drift", "joint": j, "parameters": {"viscous_rate": rate}}
    truth.update(case=case, robot=robot)
    kw = {k: v for k, v in ARMS[robot].items() if k not in ("effect_scale", "drift_scale")}
    paths = []
    for role, sd in (("fit", seed), ("validate", seed + 1)):
        path = os.path.join(out_dir, f"{case}_{role}.csv")
        simulate_experiment(robot, (), duration=duration, rate_hz=rate_hz, seed=sd, out_csv=path,
                            extra_blocks=extra, **kw)
        paths.append(path)
    return paths[0], paths[1], truth


# ---------------------------------------------------------------------------------------------
# The issue-13 battery's additions (appended; see tests/test_battery.py)
# ---------------------------------------------------------------------------------------------
#: the PUMA 560's first three joints (robots/puma560_3link.*): small Coulomb levels (the real
#: 26/11/6 N m make the joints stick at every reversal, which no velocity-friction column fits),
#: torque noise 0.05 N m; shoulder and elbow swing +-1 rad about -0.8 / +0.8 rad (inside the joint
#: limits): a swing of +-0.5 rad about q = 0 left the shoulder's gravity column cos q ~ 1 - q^2/2
#: nearly constant, and a torque offset or a spring on it was absorbed by the gravity parameters
ARMS["puma560_3link"] = dict(effect_scale=40.0, coulomb=(0.5, 0.3, 0.2), viscous=(0.2, 0.2, 0.1),
                             torque_noise_std=0.05,
                             excitation=dict(amplitude=(1.0, 1.0, 1.0), offset=(0.0, -0.8, 0.8),
                                             torque_limit=packaged_description("puma560_3link").torque_limits))


def _reflected_inertias(robot) -> list[float]:
    """Reflected rotor inertia G^2 J_m [kg m^2] of every joint of ``robot``'s URDF (0 without one)."""
    from robust_drake.models import make_plant

    plant = make_plant(robot)
    ctx = plant.CreateDefaultContext()
    out = [0.0] * plant.num_velocities()
    for ai in plant.GetJointActuatorIndices():
        a = plant.get_joint_actuator(ai)
        out[a.joint().velocity_start()] = a.rotor_inertia(ctx) * a.gear_ratio(ctx) ** 2
    return out


#: backlash per arm: joint, gap half-width b [rad], contact-mode frequency [Hz] and damping ratio
#: (the DFKI C.1 motor's 0.15 deg is b = 0.075 deg; the battery uses a worn gear's 0.5 deg gap)
BACKLASH = dict(joint=1, b=math.radians(0.25), frequency_hz=25.0, damping_ratio=0.3)


def backlash_case(robot: str = "siciliano_2link", seed: int = 0, out_dir=None, duration: float = 12.0,
                  rate_hz: float = 250.0, **backlash):
    """Fit and validation CSVs of ``robot`` with backlash in one joint's drive (outside the
    library, :mod:`robust_drake.synthetic.backlash`).

    The true plant is ``robot``'s URDF with the motors' reflected inertia taken off the links
    (``simulated.strip_rotor_inertia``) and put back on the far side of the gap: on the backlash
    joint as the drive's motor inertia J_m, on the others (rigid drives) as the library's
    ``rotor_inertia`` plant change. The fitter is given ``robot`` (rigid, inertia on the links),
    which is exact except while the gap is crossed. Returns (fit_csv, validate_csv, truth)."""
    from robust_drake.synthetic.backlash import BacklashDrive, contact_parameters
    from robust_drake.synthetic.simulated import strip_rotor_inertia

    if robot not in ARMS:
        raise RobustDrakeError(f"no simulation settings for {robot!r}; known: {', '.join(ARMS)}")
    p = {**BACKLASH, **backlash}
    j = int(p["joint"])
    out_dir = out_dir or tempfile.mkdtemp(prefix="outside_backlash_")
    os.makedirs(out_dir, exist_ok=True)
    J = _reflected_inertias(robot)
    if J[j] <= 0:
        raise RobustDrakeError(f"backlash_case: joint {j + 1} of {robot} has no reflected rotor inertia")
    k, c = contact_parameters(J[j], p["frequency_hz"], p["damping_ratio"])
    stripped = strip_rotor_inertia(robot, os.path.join(out_dir, f"{robot}_no_rotor.urdf"))
    rigid = [("rotor_inertia", i, {"reflected_inertia": J[i]}) for i in range(len(J)) if i != j and J[i] > 0]
    extra = (lambda n: BacklashDrive(n, j, p["b"], J[j], k, c),)
    kw = {key: v for key, v in ARMS[robot].items() if key not in ("effect_scale", "drift_scale")}
    paths = []
    for role, sd in (("fit", seed), ("validate", seed + 1)):
        path = os.path.join(out_dir, f"backlash_{role}.csv")
        simulate_experiment(stripped, rigid, duration=duration, rate_hz=rate_hz, seed=sd, out_csv=path,
                            extra_blocks=extra, **kw)
        paths.append(path)
    truth = {"case": "backlash", "kind": "backlash", "joint": j, "robot": robot,
             "parameters": {"b": p["b"], "J_m": J[j], "stiffness": k, "damping": c}}
    return paths[0], paths[1], truth
