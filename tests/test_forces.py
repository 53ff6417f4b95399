"""The one force path and the one friction block.

The closed loop (``diagram.ClosedLoop``), the replay (``replay.build_replay_diagram``) and the
simulated experiment (``simulated.build_experiment``) build their plant-side forces through
``forces``; for the same model (Coulomb + viscous friction and a cogging torque) and the
same plant state they must apply the same generalized force besides the torque command, equal to
the model written out by hand here.  The three use different friction sign laws (sharp sign in
the closed loop, tanh with v_eps = 0.01 rad/s in the simulated experiment, 0.05 rad/s in the
replay); at |qd| >= 1.5 rad/s tanh(qd / v_eps) is 1 to double precision, so the state chosen
below makes them agree exactly.
"""

import math

import numpy as np
import pytest

from robust_drake.errors import RobustDrakeError
from robust_drake.systems.friction import CoulombViscousFriction, coulomb_viscous_force

ROBOT = "dfki_double_pendulum_c1"
FC, FV = (0.3, 0.2), (0.05, 0.02)  # N m, N m s/rad
COG = {"amplitude": 0.06, "phase": 0.5}  # N m, rad; harmonic 4 on joint index 1
Q, QD = np.array([0.4, -0.7]), np.array([1.6, -2.1])


def _expected():
    friction = -(np.array(FV) * QD + np.array(FC) * np.sign(QD))
    cogging = np.array([0.0, COG["amplitude"] * math.sin(4 * Q[1] + COG["phase"])])
    return friction, cogging


def _effects():
    from robust_drake.effects import make_effect

    return [(make_effect("position_dependent", 1, harmonic=4), dict(COG))]


def _applied_minus_tau(diagram, plant, tau_port, t=0.0):
    ctx = diagram.CreateDefaultContext()
    ctx.SetTime(t)
    pctx = plant.GetMyMutableContextFromRoot(ctx)
    plant.SetPositions(pctx, Q)
    plant.SetVelocities(pctx, QD)
    F = plant.get_applied_generalized_force_input_port().Eval(pctx)
    tau = tau_port.Eval(tau_port.get_system().GetMyContextFromRoot(ctx))
    return F - tau


def _closed_loop():
    from robust_drake.diagram import ClosedLoop, ClosedLoopConfig
    from robust_drake.effects import effect_hooks

    loop = ClosedLoop(ClosedLoopConfig(
        robot=ROBOT, controller="pd", trajectory="sine", observer="exact", rate=500.0,
        plant_friction={"coulomb": list(FC), "viscous": list(FV)}, encoder_resolution=None,
        torque_limit=None, **effect_hooks(_effects())))
    loop._finish()
    return _applied_minus_tau(loop.diagram, loop.plant, loop.tau_port)


def _replay():
    from robust_drake.identification.data import IdentData
    from robust_drake.model_repair.replay import build_replay_diagram

    t = np.array([0.0, 0.01])
    tau = np.array([[0.7, -0.3], [0.7, -0.3]])
    data = IdentData(t=t, q=np.tile(Q, (2, 1)), qd=np.tile(QD, (2, 1)), qdd=np.zeros((2, 2)),
                     tau=tau, dt=0.01)
    diagram, plant = build_replay_diagram(ROBOT, data, FC, FV, _effects())
    src = next(s for s in diagram.GetSystems() if s.get_name() == "measured_tau")
    return _applied_minus_tau(diagram, plant, src.get_output_port(0))


def _simulated():
    from robust_drake.synthetic.simulated import build_experiment

    exc = dict(amplitude=(1.0, 1.3), base_frequency=0.1, harmonics=5, bandwidth_hz=4.0,
               offset=None, torque_limit=12.0)
    exp = build_experiment(ROBOT, _effects(), exc, np.random.default_rng(0), FC, FV, 250.0)
    return _applied_minus_tau(exp.diagram, exp.plant, exp.controller.get_output_port(0))


def test_closed_loop_replay_and_experiment_apply_the_same_force():
    friction, cogging = _expected()
    forces = {"closed_loop": _closed_loop(), "replay": _replay(), "simulated": _simulated()}
    for name, F in forces.items():
        # cogging is a torque the motor must supply: it enters the plant with a minus sign
        assert np.allclose(F, friction - cogging, rtol=0, atol=1e-14), (name, F, friction - cogging)


@pytest.mark.parametrize("v_eps", [None, 0.01, 0.05])
def test_friction_block_is_the_law(v_eps):
    """The block's output (the sharp law through its scalar fast path) equals
    -coulomb_viscous_force, bit for bit, at velocities including 0 and inside the transition."""
    blk = CoulombViscousFriction(2, FC, FV, v_eps)
    ctx = blk.CreateDefaultContext()
    for qd in ([0.0, -0.0], [0.003, -0.02], [0.5, -1e-9], [-2.0, 7.0]):
        blk.get_input_port(0).FixValue(ctx, np.r_[0.0, 0.0, qd])
        out = blk.get_output_port(0).Eval(ctx)
        assert np.array_equal(out, -coulomb_viscous_force(qd, FC, FV, v_eps))


def test_friction_law_sign_laws():
    qd = np.array([0.0, 0.01, -0.05, 3.0])
    sharp = coulomb_viscous_force(qd, 1.0, 0.0)
    assert list(sharp) == [0.0, 1.0, -1.0, 1.0]
    smooth = coulomb_viscous_force(qd, 1.0, 0.0, v_eps=0.01)
    # tanh(1) at qd = v_eps: 76 % of the Coulomb level; the transition is odd and saturates
    assert math.isclose(smooth[1], 0.7615941559557649, rel_tol=1e-15)
    assert smooth[0] == 0.0 and math.isclose(smooth[2], -math.tanh(5.0)) and smooth[3] == 1.0
    assert list(coulomb_viscous_force(qd, 0.0, 2.0)) == [0.0, 0.02, -0.1, 6.0]


def test_friction_block_refuses_bad_coefficients():
    with pytest.raises(RobustDrakeError, match="Coulomb"):
        CoulombViscousFriction(2, (-0.1, 0.2), FV)
    CoulombViscousFriction(2, (-0.1, 0.2), FV, 0.05, nonnegative=False)  # an identified fit
    with pytest.raises(RobustDrakeError, match="v_eps"):
        CoulombViscousFriction(2, FC, FV, 0.0)


def test_sum_into_plant_single_source_is_connected_directly():
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource

    from robust_drake.models import add_arm
    from robust_drake.forces import sum_into_plant

    b = DiagramBuilder()
    plant, _ = add_arm(b, ROBOT)
    src = b.AddSystem(ConstantVectorSource(np.array([0.1, -0.2])))
    zero = b.AddSystem(ConstantVectorSource(np.zeros(2)))
    b.Connect(zero.get_output_port(0), plant.get_actuation_input_port())
    assert sum_into_plant(b, plant, [src.get_output_port(0)]) is None
    d = b.Build()
    ctx = d.CreateDefaultContext()
    F = plant.get_applied_generalized_force_input_port().Eval(plant.GetMyContextFromRoot(ctx))
    assert list(F) == [0.1, -0.2]
