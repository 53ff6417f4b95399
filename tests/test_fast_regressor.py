"""The per-tick Slotine-Li regressor (Pinocchio, ``regressor.PinocchioSlotineLi``) against the numpy/
symbolic Drake-derived regressor it replaces in the controllers, on every URDF shipped in models/ and
on trees written here (joint damping, a prismatic joint, a branched tree whose Pinocchio joint order
differs from Drake's velocity order), and against Drake's own inverse dynamics.

The reference side (``slotine_li_single_reference``, ``slotine_li``) is the project's numpy Newton-
Euler / symbolic route; the physics side is Drake's ``CalcInverseDynamics`` with gravity and force
elements (``drake_inverse_dynamics``), neither of which calls Pinocchio.
"""

import math
import pathlib

import numpy as np
import pytest

from dynamics_reference import damped_siciliano_urdf

from robust_drake.models import make_plant
from robust_drake.regressor import InverseDynamicsRegressor, PinocchioSlotineLi, drake_inverse_dynamics

MODELS = sorted(str(p) for p in (pathlib.Path(__file__).resolve().parents[1] / "robust_drake" / "robots").glob("*.urdf"))

BRANCHED = """<?xml version="1.0"?>
<robot name="branched">
  <link name="base"/>
  <link name="b1"><inertial><origin xyz="0 0.15 0"/><mass value="0.9"/>
    <inertia ixx="0.011" ixy="0" ixz="0" iyy="0.009" iyz="0" izz="0.013"/></inertial></link>
  <link name="a1"><inertial><origin xyz="0.1 0.02 0" rpy="0.1 0 0.2"/><mass value="1.3"/>
    <inertia ixx="0.02" ixy="0.001" ixz="0" iyy="0.03" iyz="0.002" izz="0.025"/></inertial></link>
  <link name="a2"><inertial><origin xyz="0.2 0 0.01"/><mass value="0.8"/>
    <inertia ixx="0.01" ixy="0" ixz="0.001" iyy="0.012" iyz="0" izz="0.011"/></inertial></link>
  <link name="tool"><inertial><origin xyz="0.02 0 0"/><mass value="0.3"/>
    <inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/></inertial></link>
  <link name="b2"><inertial><origin xyz="0 0 0.1"/><mass value="0.5"/>
    <inertia ixx="0.004" ixy="0" ixz="0" iyy="0.004" iyz="0" izz="0.002"/></inertial></link>
  <joint name="ja1" type="revolute"><parent link="base"/><child link="a1"/>
    <origin xyz="0 0 0.3" rpy="0.3 0 0"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="10" velocity="5"/></joint>
  <joint name="ja2" type="revolute"><parent link="a1"/><child link="a2"/>
    <origin xyz="0.4 0 0" rpy="0 0.2 0.1"/><axis xyz="0.6 0 0.8"/><limit lower="-3" upper="3" effort="10" velocity="5"/>
    <dynamics damping="0.4"/></joint>
  <joint name="jtool" type="fixed"><parent link="a2"/><child link="tool"/><origin xyz="0.3 0 0" rpy="0 0 0.5"/></joint>
  <joint name="jb1" type="prismatic"><parent link="base"/><child link="b1"/>
    <origin xyz="0.1 0 0.2" rpy="0 0.4 0"/><axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="10" velocity="5"/></joint>
  <joint name="jb2" type="revolute"><parent link="b1"/><child link="b2"/>
    <origin xyz="0 0.2 0"/><axis xyz="1 0 0"/><limit lower="-3" upper="3" effort="10" velocity="5"/></joint>
</robot>
"""


def _samples(n, N, seed):
    rng = np.random.default_rng(seed)
    return (rng.uniform(-math.pi, math.pi, (N, n)), rng.normal(0, 2, (N, n)), rng.normal(0, 2, (N, n)),
            rng.normal(0, 5, (N, n)))


def _check(reg, N=6, seed=0):
    q, qd, v, a = _samples(reg.n, N, seed)
    Y_vec = reg.slotine_li(q, qd, v, a)
    fast = reg.slotine_li_fast()
    for k in range(N):
        Y_ref = reg.slotine_li_single_reference(q[k], qd[k], v[k], a[k])
        scale = np.abs(Y_ref).max()
        for Y in (reg.slotine_li_single(q[k], qd[k], v[k], a[k]), fast(q[k], qd[k], v[k], a[k]),
                  fast(q[k].tolist(), qd[k].tolist(), v[k].tolist(), a[k].tolist())):
            assert Y.shape == (reg.n, reg.p_base)
            np.testing.assert_allclose(Y, Y_ref, rtol=0, atol=1e-13 * scale)
        np.testing.assert_allclose(Y_vec[k], Y_ref, rtol=0, atol=1e-13 * scale)
    # with v = qd: Drake's inverse dynamics (gravity, damping, reflected inertia) for the URDF's theta
    theta = reg.base_parameters()
    tau = drake_inverse_dynamics(reg.plant, reg.plant.CreateDefaultContext(), q, qd, a)
    for k in range(N):
        got = fast(q[k], qd[k], qd[k], a[k]) @ theta
        assert np.abs(got - tau[k]).max() <= 1e-10 * max(np.abs(tau[k]).max(), 1.0)


@pytest.mark.parametrize("urdf", MODELS, ids=[pathlib.Path(p).stem for p in MODELS])
def test_pinocchio_slotine_li_equals_the_drake_derived_one_on_every_model(urdf):
    _check(InverseDynamicsRegressor.from_robot(urdf, method="numeric"))


@pytest.mark.parametrize("urdf", [p for p in MODELS if make_plant(p).num_velocities() <= 2],
                         ids=lambda p: pathlib.Path(p).stem)
def test_pinocchio_slotine_li_equals_the_symbolic_route(urdf):
    """2-joint arms: the compiled symbolic regressor (DecomposeLumpedParameters) as the reference."""
    _check(InverseDynamicsRegressor.from_robot(urdf, method="symbolic"), seed=1)


def test_damping_prismatic_and_a_branched_tree(tmp_path):
    """Damping columns (b_j qd_j), a prismatic joint, a tool welded to a moving link, tilted frames and
    an unaligned axis; the tree's Pinocchio joint order (depth first) is not Drake's velocity order,
    so the rows and inputs are permuted."""
    _check(InverseDynamicsRegressor.from_robot(str(damped_siciliano_urdf(tmp_path, 0.7)), method="numeric"))
    path = tmp_path / "branched.urdf"
    path.write_text(BRANCHED)
    reg = InverseDynamicsRegressor.from_robot(str(path), method="numeric")
    assert any(name.startswith("b_") for name in reg.standard_names)
    _, joint_q, _ = reg.pinocchio_model()
    assert sorted(joint_q.tolist()) == list(range(reg.n))
    assert joint_q.tolist() != list(range(reg.n)), "the test tree should need the permutation"
    _check(reg, seed=2)


def test_one_instance_per_thread_and_its_own_data():
    import threading

    reg = InverseDynamicsRegressor.from_robot("serial7")
    q, qd, v, a = _samples(7, 2, 5)
    want = [reg.slotine_li_single_reference(q[k], qd[k], v[k], a[k]) for k in range(2)]
    got, seen = {}, {}

    def work(k):
        got[k] = reg.slotine_li_single(q[k], qd[k], v[k], a[k])
        seen[k] = reg._fast_local.f

    threads = [threading.Thread(target=work, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert isinstance(seen[0], PinocchioSlotineLi) and seen[0] is not seen[1]
    for k in range(2):
        np.testing.assert_allclose(got[k], want[k], rtol=0, atol=1e-13 * np.abs(want[k]).max())
