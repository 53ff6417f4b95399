"""The pieces of logs-to-control's n-joint bound: M(q) from the regressor, which joints change M,
where M is taken, physically valid realisations of base parameters (pseudo-inertia SDP), and the
sampled-loop boundary layer against chattering."""

import numpy as np
import pytest

from robust_drake.uncertainty.plant_draws import NearestPhysical, PhysicalBySdp, plant_setup
from robust_drake.experiments.ultimate_bound import bound_region, mass_joints, mass_matrices
from robust_drake.models import make_plant
from robust_drake.regressor import InverseDynamicsRegressor


@pytest.mark.parametrize("robot", ["siciliano_2link", "puma560_3link", "serial7"])
def test_mass_matrix_from_the_regressor_equals_drakes(robot):
    reg = InverseDynamicsRegressor.from_robot(robot)
    plant = make_plant(robot)
    ctx = plant.CreateDefaultContext()
    q = np.random.default_rng(3).uniform(-2.0, 2.0, (6, reg.n))
    for qk, M in zip(q, mass_matrices(reg, reg.base_parameters(), q)):
        plant.SetPositions(ctx, qk)
        Md = plant.CalcMassMatrix(ctx)
        assert np.allclose(M, Md, rtol=0, atol=1e-10 * np.abs(Md).max())


@pytest.mark.parametrize("robot, joints, kind", [("siciliano_2link", [1], "global"),
                                                  ("puma560_3link", [1, 2], "global"),
                                                  ("serial7", [1, 2, 3, 4, 5], "tube")])
def test_joints_that_change_m_decide_the_region(robot, joints, kind):
    """A planar 2-link arm's M depends on the elbow only; the PUMA's waist turns about the vertical
    (shoulder and elbow change M); a 7-joint arm's M depends on every joint but the first and the
    last (the last link turns about its own symmetry axis in serial7)."""
    plant = make_plant(robot)
    assert mass_joints(plant, plant.CreateDefaultContext(), np.random.default_rng(0)) == joints
    q_ref = np.zeros((5, plant.num_positions()))
    pts, info = bound_region(plant, q_ref, np.random.default_rng(0))
    assert info["kind"] == kind
    if kind == "global":  # every grid angle of the M-joints, the other joints at 0
        assert len(pts) == 73 ** len(joints)
        others = [j for j in range(plant.num_positions()) if j not in joints]
        assert np.all(pts[:, others] == 0.0)
    else:  # the reference and 16 points at +-delta around each sample
        assert len(pts) == 5 * 17 and np.allclose(np.abs(pts[5:]), info["delta"])


def _central_eigs(pi_body):
    m, h, I = pi_body[0], pi_body[1:4], pi_body[4:10]
    J = np.array([[I[0], I[3], I[4]], [I[3], I[1], I[5]], [I[4], I[5], I[2]]])
    c = h / m
    return np.linalg.eigvalsh(J - m * (c @ c * np.eye(3) - np.outer(c, c)))


def test_sdp_realises_base_parameters_the_closed_form_repair_cannot():
    """PUMA: base parameters 20 % off the URDF's in random directions; where the closed-form repair
    (whole unseen columns of K only) gives up, the SDP finds a plant: Drake's base parameters of it
    equal theta, every central inertia is positive definite and satisfies the triangle
    inequality, masses unchanged."""
    from robust_drake.uncertainty.plant_draws import make_physical, standard_for_base

    reg = InverseDynamicsRegressor.from_robot("puma560_3link")
    pi_nom = reg.standard_parameters()
    sdp = PhysicalBySdp(reg, pi_nom)
    rng = np.random.default_rng(0)
    plant = make_plant("puma560_3link")
    found = 0
    for _ in range(30):
        theta = reg.base_parameters() * (1 + 0.2 * rng.standard_normal(reg.p_base))
        if make_physical(reg, standard_for_base(reg, theta, pi_nom)) is not None:
            continue
        pi = sdp(theta)
        if pi is None:
            continue
        found += 1
        ctx = plant.CreateDefaultContext()
        plant_setup(reg, pi)(plant, ctx)
        assert np.allclose(reg.base_parameters(plant, ctx), theta, rtol=1e-8, atol=1e-10)
        for k in range(3):
            lam = _central_eigs(pi[10 * k:10 * k + 10])
            assert lam[0] > 0 and lam[2] <= lam[0] + lam[1]
            assert pi[10 * k] == pi_nom[10 * k]
    assert found >= 3, found


def test_no_rigid_body_has_a_negative_link_inertia_and_the_nearest_valid_point_is_in_the_set():
    """Izz and Ixy of the PUMA's link 3 are base parameters alone: Izz < 0 is no rigid body, nor is
    Izz = 0.02 with Ixy = 0.03 (the xy principal moments differ by >= 2 |Ixy| = 0.06 > Izz: the
    triangle inequality fails): None. The nearest valid point inside a set around the first has
    Izz_link3 > 0 and radius <= 1."""
    from robust_drake.uncertainty.confidence import mahalanobis_radius

    reg = InverseDynamicsRegressor.from_robot("puma560_3link")
    pi_nom = reg.standard_parameters()
    theta = reg.base_parameters().copy()
    i = list(reg.base_names).index("Izz_link3")
    theta[i] = -0.05
    sdp = PhysicalBySdp(reg, pi_nom)
    assert sdp(theta) is None
    th2 = reg.base_parameters().copy()
    th2[i], th2[list(reg.base_names).index("Ixy_link3")] = 0.02, 0.03
    assert sdp(th2) is None
    P = np.diag((0.2 * np.abs(theta) + 0.1) ** 2)
    pi = NearestPhysical(reg, pi_nom, theta, P)(theta)
    th = np.asarray(reg.K, float) @ pi
    assert th[i] > 0 and mahalanobis_radius(theta, P, th) <= 1.0 + 1e-6


def test_verdict_names_every_failed_condition():
    """logs-to-control's verdict: guaranteed only when every draw ran to the end within its bound and,
    for a tube region, every bound lies inside the tube; each failure is named."""
    import math

    from robust_drake.experiments.logs_to_control import verdict

    ok = {"diverged": False, "max_error": 1e-3, "within": True, "bound": 2e-3}
    tube = {"kind": "tube", "delta": 0.05, "consistent": True}
    assert verdict([ok, ok], tube)["guaranteed"] is True
    assert verdict([ok], {"kind": "global"})["guaranteed"] is True
    div = dict(ok, diverged=True, max_error=math.inf, within=False)
    out = dict(ok, within=False, max_error=3e-3)
    v = verdict([ok, div, out], dict(tube, consistent=False))
    assert v["guaranteed"] is False
    assert "[1] diverged" in v["verdict"] and "[2] left their bound" in v["verdict"]
    assert "exceed the +-0.05 rad tube" in v["verdict"]
    assert "[1]" not in v["verdict"].split("left")[1]  # a diverged draw is not also counted as outside


def test_recentred_set_is_a_rigid_body_and_holds_the_whole_identified_set():
    """A set whose centre is no rigid-body arm (the elbow's Izz_link3 and rotor inertia negative, so
    M(q) is not positive definite): eq. 15 is designed on theta_c, the nearest physically valid
    point of the set, with P inflated by (1 + r_c)^2; theta_c's M(q) is positive definite and every
    point of the identified set (boundary samples) lies in the inflated set around theta_c."""
    from robust_drake.experiments.logs_to_control import recentre_on_rigid_body
    from robust_drake.experiments.ultimate_bound import mass_matrices
    from robust_drake.regressor import InverseDynamicsRegressor
    from robust_drake.uncertainty.confidence import mahalanobis_radius

    reg = InverseDynamicsRegressor.from_robot("puma560_3link")
    truth = reg.base_parameters()
    b = 0.3 * np.abs(truth) + 1e-2
    theta0 = truth.copy()
    for k in (11, 15):  # Izz_link3, Ia_joint3: pushed below zero, the truth kept inside the set
        b[k] = 3.0 * abs(truth[k])
        theta0[k] = -0.9 * abs(truth[k])
    P = np.diag(b ** 2)
    assert mahalanobis_radius(theta0, P, truth) <= 1.0
    rng = np.random.default_rng(0)
    q = rng.uniform(-np.pi, np.pi, (50, 3))
    assert np.linalg.eigvalsh(mass_matrices(reg, theta0, q))[:, 0].min() <= 0  # the case
    theta_c, P_c, info = recentre_on_rigid_body(reg, theta0, P)
    assert 0.0 < info["radius"] < 1.0 and np.isclose(info["inflation"], (1 + info["radius"]) ** 2)
    assert np.linalg.eigvalsh(mass_matrices(reg, theta_c, q))[:, 0].min() > 0
    L = np.linalg.cholesky(P)
    for _ in range(200):
        z = rng.normal(size=len(theta0))
        theta = theta0 + L @ (z / np.linalg.norm(z))  # on the identified set's boundary
        assert mahalanobis_radius(theta_c, P_c, theta) <= 1.0 + 1e-9
