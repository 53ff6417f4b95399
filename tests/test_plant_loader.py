"""The one plant loader (``robust_drake.models.make_plant`` / ``add_arm``): a URDF written the
ROS/Pinocchio way (root link without a joint to the world) is welded to the world and then
loads, simulates in the closed loop and goes through ``repair``; unsupported joints are refused
by name; the ``before_finalize`` hook runs before ``Finalize``."""

import logging
import math

import numpy as np
import pytest

from robust_drake.errors import RobustDrakeError
from robust_drake.models import make_plant

L1, L2, M1, M2 = 0.3, 0.2, 0.6, 0.5


def _link(name, m, length):
    izz = m * length**2 / 12
    return (f'<link name="{name}"><inertial><origin xyz="{length / 2} 0 0"/><mass value="{m}"/>'
            f'<inertia ixx="{izz / 10}" iyy="{izz}" izz="{izz}" ixy="0" ixz="0" iyz="0"/>'
            f'</inertial></link>')


def _urdf(tmp_path, joint1="revolute", extra="", axis="0 1 0"):
    """Two links swinging about ``axis`` (default y: vertical plane, gravity acts), no world link
    or joint."""
    text = f"""<?xml version="1.0"?>
<robot name="ros_two_link">
  <link name="base_link"/>
  {_link("link1", M1, L1)}
  {_link("link2", M2, L2)}
  <joint name="joint1" type="{joint1}"><parent link="base_link"/><child link="link1"/>
    <axis xyz="{axis}"/><limit lower="-10" upper="10" effort="20" velocity="20"/></joint>
  <joint name="joint2" type="continuous"><parent link="link1"/><child link="link2"/>
    <origin xyz="{L1} 0 0"/><axis xyz="{axis}"/></joint>
  {extra}
</robot>"""
    path = tmp_path / f"two_link_{joint1}_{axis.replace(' ', '')}.urdf"
    path.write_text(text)
    return str(path)


def test_root_without_world_joint_is_welded_with_a_message(tmp_path, caplog):
    path = _urdf(tmp_path)
    with caplog.at_level(logging.INFO, logger="robust_drake.models"):
        plant = make_plant(path)
    assert plant.num_positions() == 2 and plant.num_velocities() == 2
    assert any("base_link" in r.getMessage() and "welded" in r.getMessage() for r in caplog.records)
    # welded, not floating: gravity torque at q = 0 (links horizontal) is the static moment
    ctx = plant.CreateDefaultContext()
    g = plant.CalcGravityGeneralizedForces(ctx)
    g_expected = 9.81 * np.array([M1 * L1 / 2 + M2 * (L1 + L2 / 2), M2 * L2 / 2])
    assert np.allclose(np.abs(g), g_expected, rtol=1e-12)


def test_floating_base_only_when_asked(tmp_path):
    plant = make_plant(_urdf(tmp_path), floating_base=True)
    assert plant.num_velocities() == 6 + 2  # a free base plus the two joints
    assert plant.num_positions() == 7 + 2  # quaternion floating joint


@pytest.mark.parametrize("jtype", ["planar", "floating"])
def test_unsupported_joint_is_named(tmp_path, jtype):
    with pytest.raises(RobustDrakeError, match="joint1|link1"):
        make_plant(_urdf(tmp_path, joint1=jtype))


def test_before_finalize_hook_adds_a_payload(tmp_path):
    from pydrake.math import RigidTransform
    from pydrake.multibody.tree import SpatialInertia, UnitInertia

    def payload(plant):
        body = plant.AddRigidBody("payload", plant.GetBodyByName("link2").model_instance(),
                                  SpatialInertia(0.4, np.zeros(3), UnitInertia(0, 0, 0),
                                                 skip_validity_check=True))
        plant.WeldFrames(plant.GetFrameByName("link2"), body.body_frame(),
                         RigidTransform([L2, 0, 0]))

    path = _urdf(tmp_path)
    plant0 = make_plant(path)
    M0 = plant0.CalcMassMatrix(plant0.CreateDefaultContext())
    plant = make_plant(path, before_finalize=payload)
    M = plant.CalcMassMatrix(plant.CreateDefaultContext())
    # a 0.4 kg point at the tip of link 2 (arm stretched): adds m r^2 to d22 with r = L2
    assert math.isclose(M[1, 1] - M0[1, 1], 0.4 * L2**2, rel_tol=1e-12)
    assert math.isclose(M[0, 0] - M0[0, 0], 0.4 * (L1 + L2) ** 2, rel_tol=1e-12)


def test_ros_urdf_simulates_in_the_closed_loop(tmp_path):
    from robust_drake.diagram import ClosedLoopConfig, simulate

    # horizontal plane (axes along z): PD alone tracks without a gravity bias
    res = simulate(ClosedLoopConfig(robot=_urdf(tmp_path, axis="0 0 1"), controller="pd",
                                    trajectory="sine", observer="exact", rate=500.0, duration=1.0))
    assert not res.diverged
    swing = np.ptp(res.q_d, axis=0)
    err = np.abs(res.q - res.q_d).max(axis=0)
    # an arm standing still would be off by half the swing; this one follows the reference
    assert np.all(swing > 0.1) and np.all(err < 0.35 * swing)


def test_ros_urdf_repairs(tmp_path):
    from robust_drake.model_repair import pipeline as repair
    from robust_drake.synthetic.simulated import simulate_experiment

    path = _urdf(tmp_path)
    fit, val = str(tmp_path / "fit.csv"), str(tmp_path / "val.csv")
    for csv, seed in ((fit, 0), (val, 1)):
        simulate_experiment(path, [("torque_offset", 1, {"offset": 0.05})], duration=6.0,
                            seed=seed, out_csv=csv, coulomb=(0.02, 0.01), viscous=(0.004, 0.002))
    rep = repair.run_repair([fit], repair.RepairOptions(robot=path, consistent=False, replay=True,
                                                         plots=False), validate_paths=[val])
    kinds = [(e["kind"], e.get("joint")) for e in rep["effects"]]
    assert ("torque_offset", 1) in kinds
    assert rep["final"]["rms_validate"][1] < 0.5 * rep["baseline"]["rms_validate"][1]
    # the replay ran on the welded plant, and the repaired model follows the motion better
    assert rep["replay"]["after"]["rms_q"][1] < rep["replay"]["before"]["rms_q"][1]
