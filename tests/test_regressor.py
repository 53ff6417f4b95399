"""Regressors against Drake's inverse dynamics and the robot-dynamics identities (JS eqs. 6, 7)."""

import math

import numpy as np
import pytest

from dynamics_reference import christoffel_C, damped_siciliano_urdf, mass_matrix_and_derivative

from robust_drake.errors import RobustDrakeError
from robust_drake.models import (
    D2R2_THETA_LOADED,
    D2R2_THETA_UNLOADED,
    ROBOTS,
    d2r2_theta_from_plant,
    make_plant,
    resolve_urdf,
    set_d2r2_theta,
)
from robust_drake.regressor import (
    IMI_L1,
    InverseDynamicsRegressor,
    d2r2_regressor,
    drake_inverse_dynamics,
    imi_scara_regressor,
    imi_theta_from_plant,
)

ALL = [(r, load) for r in ROBOTS for load in ROBOTS[r].loads]
TWO_LINK = [(r, load) for r, load in ALL if ROBOTS[r].n == 2]
CASES = [(r, load, "numeric") for r, load in ALL] + [(r, load, "symbolic") for r, load in TWO_LINK]


def _states(n, N, seed):
    rng = np.random.default_rng(seed)
    return rng.uniform(-math.pi, math.pi, (N, n)), rng.normal(0, 2, (N, n)), rng.normal(0, 5, (N, n))


@pytest.mark.parametrize("robot,load,method", CASES)
def test_regressor_equals_drake_inverse_dynamics_with_gravity(robot, load, method):
    reg = InverseDynamicsRegressor.from_robot(robot, load, method=method)
    assert reg.method == method and reg.n == ROBOTS[robot].n
    plant = make_plant(robot, load)
    ctx = plant.CreateDefaultContext()
    q, v, vd = _states(reg.n, 25, seed=11)
    tau = drake_inverse_dynamics(plant, ctx, q, v, vd)
    Y = reg.evaluate(q, v, vd)
    assert Y.shape == (25, reg.n, reg.p_base)
    tau_r = Y @ reg.base_parameters()
    assert np.abs(tau_r - tau).max() <= 1e-9 * np.abs(tau).max()
    # gravity really is in there for vertical arms: zero velocity/acceleration still needs torque
    tau_static = reg.evaluate(q, 0 * v, 0 * vd) @ reg.base_parameters()
    if ROBOTS[robot].gravity:
        np.testing.assert_allclose(tau_static, -np.array(
            [_gravity(plant, ctx, qi) for qi in q]), rtol=1e-9, atol=1e-9 * np.abs(tau_static).max())
    else:
        assert np.abs(tau_static).max() < 1e-12
    # a single state (n,) gives (1, n, p_base)
    assert reg.evaluate(q[0], v[0], vd[0]).shape == (1, reg.n, reg.p_base)


def _gravity(plant, ctx, q):
    plant.SetPositions(ctx, q)
    return plant.CalcGravityGeneralizedForces(ctx)


def test_symbolic_and_numeric_routes_agree():
    for robot in ("siciliano_2link", "d2r2"):
        a = InverseDynamicsRegressor.from_robot(robot, method="symbolic")
        b = InverseDynamicsRegressor.from_robot(robot, method="numeric")
        assert a.base_names == b.base_names
        q, v, vd = _states(2, 50, seed=5)
        Ya, Yb = a.evaluate(q, v, vd), b.evaluate(q, v, vd)
        np.testing.assert_allclose(Ya, Yb, rtol=1e-10, atol=1e-10 * np.abs(Yb).max())


def test_base_parameters_follow_the_context():
    """Parameters changed in a context (Monte Carlo 'truth') are read back correctly."""
    reg = InverseDynamicsRegressor.from_robot("d2r2", "max")
    plant = make_plant("d2r2", "max")
    ctx = plant.CreateDefaultContext()
    set_d2r2_theta(plant, ctx, (0.70, 0.10, 0.07))
    q, v, vd = _states(2, 10, seed=3)
    tau = drake_inverse_dynamics(plant, ctx, q, v, vd)
    np.testing.assert_allclose(reg.evaluate(q, v, vd) @ reg.base_parameters(plant, ctx), tau, rtol=1e-9, atol=1e-12)
    reg7 = InverseDynamicsRegressor.from_robot("serial7")
    p7 = make_plant("serial7")
    c7 = p7.CreateDefaultContext()
    p7.GetBodyByName("link4").SetMass(c7, 5.0)
    p7.GetBodyByName("link6").SetCenterOfMassInBodyFrame(c7, np.array([0.01, 0.02, 0.05]))
    q, v, vd = _states(7, 10, seed=4)
    tau = drake_inverse_dynamics(p7, c7, q, v, vd)
    tau_r = reg7.evaluate(q, v, vd) @ reg7.base_parameters(p7, c7)
    assert np.abs(tau_r - tau).max() <= 1e-9 * np.abs(tau).max()
    # base_from_standard is the linear map K
    pi = reg7.standard_parameters(p7, c7)
    np.testing.assert_allclose(reg7.base_from_standard(pi), reg7.K @ pi)


@pytest.mark.parametrize("load,table", [("none", D2R2_THETA_UNLOADED), ("max", D2R2_THETA_LOADED)])
def test_d2r2_closed_form_regressor(load, table):
    plant = make_plant("d2r2", load)
    ctx = plant.CreateDefaultContext()
    ad = plant.ToAutoDiffXd()
    ad_ctx = ad.CreateDefaultContext()
    theta = d2r2_theta_from_plant(plant, ctx)
    np.testing.assert_allclose(theta, table, atol=1e-3)
    q, qd, qdd = _states(2, 20, seed=8)
    # JS eq. 7 with v = qd, a = qdd: Drake's inverse dynamics
    tau = drake_inverse_dynamics(plant, ctx, q, qd, qdd)
    np.testing.assert_allclose(d2r2_regressor(q, qd, qd, qdd) @ theta, tau, rtol=1e-12, atol=1e-12)
    # eq. 15 with v != qd: M(q) a + C(q, qd) v, C the Christoffel matrix of Drake's M(q)
    rng = np.random.default_rng(9)
    for k in range(5):
        v, a = rng.normal(size=2), rng.normal(size=2)
        M, dM = mass_matrix_and_derivative(ad, ad_ctx, q[k])
        C = christoffel_C(dM, qd[k])
        plant.SetPositions(ctx, q[k])
        plant.SetVelocities(ctx, qd[k])
        np.testing.assert_allclose(C @ qd[k], plant.CalcBiasTerm(ctx), atol=1e-12)
        np.testing.assert_allclose(d2r2_regressor(q[k], qd[k], v, a) @ theta, M @ a + C @ v, atol=1e-12)
    # vectorised over leading axes
    assert d2r2_regressor(q.reshape(4, 5, 2), qd.reshape(4, 5, 2), qd.reshape(4, 5, 2),
                          qdd.reshape(4, 5, 2)).shape == (4, 5, 2, 3)
    # the Drake-derived base parameters map onto eq. 14: theta = [b0, b3, l1 b1]
    reg = InverseDynamicsRegressor.from_robot("d2r2", load)
    b = reg.base_parameters()
    l1 = ROBOTS["d2r2"].link_lengths[0]
    names = reg.base_names
    assert names[0].startswith("Izz_link1") and names[1].startswith("mx_link2")
    np.testing.assert_allclose([b[0], b[3], l1 * b[1]], theta, rtol=1e-12)
    assert abs(b[2]) < 1e-12  # centre of mass on the link axis: my_link2 = 0


def test_imi_closed_form_regressor_and_printed_typo():
    plant = make_plant("imi_scara")
    ctx = plant.CreateDefaultContext()
    th = imi_theta_from_plant(plant, ctx)
    q, qd, qdd = _states(2, 30, seed=12)
    tau = drake_inverse_dynamics(plant, ctx, q, qd, qdd)
    D = imi_scara_regressor(q, qd, qdd)
    assert D.shape == (30, 2, 8)
    np.testing.assert_allclose(D[..., :4] @ th, tau, rtol=1e-12, atol=1e-12)
    # the printed D_{1,2} (qdd2 instead of qd2 in the Coriolis product) does not match Drake
    s2, c2 = np.sin(q[:, 1]), np.cos(q[:, 1])
    printed = IMI_L1 * (c2 * (2 * qdd[:, 0] + qdd[:, 1]) - s2 * qdd[:, 1] * (2 * qd[:, 0] + qd[:, 1]))
    Dp = D.copy()
    Dp[:, 0, 1] = printed
    err = np.abs(Dp[..., :4] @ th - tau).max() / np.abs(tau).max()
    assert err > 1e-3
    # friction columns: eq. 16, tau_f,i = sigma_s,i sgn(qd_i) + sigma_v,i qd_i
    sig = np.array([1.4, 12.12, 1.9, 0.24])
    tf = D[..., 4:] @ sig
    np.testing.assert_allclose(tf[:, 0], 1.4 * np.sign(qd[:, 0]) + 12.12 * qd[:, 0])
    np.testing.assert_allclose(tf[:, 1], 1.9 * np.sign(qd[:, 1]) + 0.24 * qd[:, 1])
    # Drake-derived base set = CI's 4 inertial parameters
    reg = InverseDynamicsRegressor.from_robot("imi_scara")
    np.testing.assert_allclose(reg.base_parameters()[[0, 1, 2, 3]], [th[0], th[1], th[2], th[3]], rtol=1e-12)


@pytest.mark.parametrize("robot,load", TWO_LINK)
def test_skew_symmetry_of_Mdot_minus_2C(robot, load):
    """JS eq. 6 along random states; C from Drake's M (Christoffel), checked against Drake's bias."""
    plant = make_plant(robot, load)
    ctx = plant.CreateDefaultContext()
    ad = plant.ToAutoDiffXd()
    ad_ctx = ad.CreateDefaultContext()
    q, qd, _ = _states(2, 8, seed=21)
    for k in range(8):
        M, dM = mass_matrix_and_derivative(ad, ad_ctx, q[k])
        Mdot = dM @ qd[k]
        C = christoffel_C(dM, qd[k])
        plant.SetPositions(ctx, q[k])
        plant.SetVelocities(ctx, qd[k])
        np.testing.assert_allclose(C @ qd[k], plant.CalcBiasTerm(ctx), atol=1e-10 * max(1.0, np.abs(M).max()))
        N = Mdot - 2 * C
        np.testing.assert_allclose(N, -N.T, atol=1e-10 * max(1.0, np.abs(M).max()))
        if robot == "d2r2":  # JS eq. 4-5 directly
            theta = d2r2_theta_from_plant(plant, ctx)
            h = -theta[2] * math.sin(q[k, 1])
            C_js = np.array([[h * qd[k, 1], h * (qd[k, 0] + qd[k, 1])], [-h * qd[k, 0], 0.0]])
            Njs = Mdot - 2 * C_js
            np.testing.assert_allclose(Njs, -Njs.T, atol=1e-12)
            np.testing.assert_allclose(C_js @ qd[k], plant.CalcBiasTerm(ctx), atol=1e-12)


def test_base_set_sizes_and_rank_report():
    # classical counts: planar 2R horizontal 4 (ZZ1R, MX2, MY2, ZZ2); vertical adds MX1R, MY1R;
    # a reflected rotor inertia on joint 2 is one more, on joint 1 it merges with ZZ1R
    assert InverseDynamicsRegressor.from_robot("d2r2").p_base == 4
    assert InverseDynamicsRegressor.from_robot("imi_scara").p_base == 4
    assert InverseDynamicsRegressor.from_robot("siciliano_2link").p_base == 7
    assert InverseDynamicsRegressor.from_robot("dfki_double_pendulum_c1").p_base == 7
    reg = InverseDynamicsRegressor.from_robot("d2r2")
    q, v, vd = _states(2, 40, seed=2)
    full = reg.rank_report(q, v, vd)
    assert full == {**full, "rank": 4, "p_base": 4, "deficient": False, "unidentified": []}
    # elbow locked at a fixed angle: m2 s2x and m2 s2y, Gamma2z are no longer separable
    q[:, 1] = 0.4
    v[:, 1] = 0.0
    vd[:, 1] = 0.0
    bad = reg.rank_report(q, v, vd)
    assert bad["deficient"] and bad["rank"] < 4 and bad["unidentified"]
    # serial7: base regressor has full column rank on random samples, rank < standard count
    reg7 = InverseDynamicsRegressor.from_robot("serial7")
    q, v, vd = _states(7, 60, seed=6)
    rep = reg7.rank_report(q, v, vd)
    assert not rep["deficient"] and reg7.p_base < reg7.p_standard
    assert len(reg7.base_names) == reg7.p_base == reg7.K.shape[0]


def test_inputs_cache_and_errors():
    a = InverseDynamicsRegressor.from_robot("d2r2")
    assert InverseDynamicsRegressor.from_robot("d2r2") is a
    b = InverseDynamicsRegressor.from_robot(str(resolve_urdf("d2r2")))
    np.testing.assert_allclose(b.base_parameters(), a.base_parameters())
    import pickle

    c = pickle.loads(pickle.dumps(a))  # rebuilt from the URDF (plants do not pickle)
    assert c.base_names == a.base_names and c.method == a.method
    # another plant of the same URDF inside a diagram: parameters matched by body name
    from pydrake.systems.framework import DiagramBuilder

    from robust_drake.models import add_arm

    plant, _ = add_arm(DiagramBuilder(), "d2r2")
    np.testing.assert_allclose(a.base_parameters(plant), a.base_parameters())
    with pytest.raises(RobustDrakeError):
        InverseDynamicsRegressor.from_robot("d2r2", method="magic")
    with pytest.raises(RobustDrakeError):
        a.evaluate(np.zeros((3, 2)), np.zeros((3, 2)), np.zeros((4, 2)))
    with pytest.raises(RobustDrakeError):
        d2r2_regressor(np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))


def test_joint_damping_becomes_a_parameter(tmp_path):
    """A URDF with joint damping: Drake adds it through CalcForceElementsContribution; the
    regressor carries it as a base parameter b_<joint> (viscous column v_j)."""
    path = damped_siciliano_urdf(tmp_path, 0.7)
    plant = make_plant(str(path))
    ctx = plant.CreateDefaultContext()
    q, v, vd = _states(2, 10, seed=30)
    tau = drake_inverse_dynamics(plant, ctx, q, v, vd)
    for method in ("numeric", "symbolic"):
        reg = InverseDynamicsRegressor.from_robot(str(path), method=method)
        assert "b_joint2" in reg.base_names
        assert reg.base_parameters()[reg.base_names.index("b_joint2")] == pytest.approx(0.7)
        tau_r = reg.evaluate(q, v, vd) @ reg.base_parameters()
        assert np.abs(tau_r - tau).max() <= 1e-9 * np.abs(tau).max()


@pytest.mark.parametrize("robot,load", ALL)
def test_batched_world_frame_regressor_equals_the_recursive_one(robot, load):
    """The numeric route's batched world-frame evaluation against the body-frame recursive
    Newton-Euler regressor (two different algorithms, same standard columns)."""
    reg = InverseDynamicsRegressor.from_robot(robot, load, method="numeric")
    q, v, vd = _states(reg.n, 12, seed=44)
    Yw = reg._standard_world(q, v, vd)
    Yr = reg._standard_numeric_recursive(q, v, vd)
    np.testing.assert_allclose(Yw, Yr, rtol=0, atol=1e-12 * np.abs(Yr).max())
