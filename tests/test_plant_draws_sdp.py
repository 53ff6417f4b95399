"""The plant-draw SDPs posed with Drake's MathematicalProgram (uncertainty.plant_draws) against
the same problems written independently in cvxpy, and their solver-free certificates."""

import numpy as np
import pytest

from robust_drake.uncertainty.plant_draws import (NearestPhysical, PhysicalBySdp, _weights, physical_certificate,
                                                  plant_setup)
from robust_drake.models import make_plant
from robust_drake.regressor import InverseDynamicsRegressor

cp = pytest.importorskip("cvxpy")


def _cvxpy_problem(reg, pi_nom, margin, nearest=None):
    """PhysicalBySdp (nearest None) or NearestPhysical (nearest = (theta0, P, inside)) in raw
    units: x the entries with W > 0, each body's pseudo-inertia [[tr(I)/2 - I, h], [h^T, m]] >=
    margin diag(s, s, s, m) (s = tr(I_nom)/2), reflected rotor inertias >= 0. Returns (problem,
    theta parameter, x, pi expression)."""
    w = _weights(reg, pi_nom)
    free = w > 0
    x = cp.Variable(int(free.sum()))
    pi = np.where(free, 0.0, pi_nom) + np.eye(len(w))[:, free] @ x
    cons = []
    for k in range(len(reg._nodes)):
        m, hx, hy, hz, ixx, iyy, izz, ixy, ixz, iyz = (pi[10 * k + i] for i in range(10))
        t = 0.5 * (ixx + iyy + izz)
        J = cp.bmat([[t - ixx, -ixy, -ixz, hx], [-ixy, t - iyy, -iyz, hy], [-ixz, -iyz, t - izz, hz],
                     [hx, hy, hz, m]])
        s = np.sum(pi_nom[10 * k + 4:10 * k + 7]) / 2.0
        cons.append(0.5 * (J + J.T) >> margin * np.diag([s, s, s, pi_nom[10 * k]]))
    base = 10 * len(reg._nodes)
    cons += [pi[base + c] >= 0 for c, (_, kind, _) in enumerate(reg._extras) if kind == "Ia"]
    K = np.asarray(reg.K, float)
    theta = cp.Parameter(K.shape[0])
    reg_term = cp.sum_squares(cp.multiply(1.0 / np.sqrt(w[free]), x - pi_nom[free]))
    if nearest is None:
        cons.append(K @ pi == theta)
        return cp.Problem(cp.Minimize(reg_term), cons), theta, x, pi
    theta0, P, inside = nearest
    Linv = np.linalg.cholesky(np.linalg.inv(P)).T  # ||Linv d||^2 = d^T P^-1 d
    cons.append(cp.norm(Linv @ (K @ pi - theta0)) <= inside)
    cost = cp.sum_squares(Linv @ (K @ pi - theta)) + 1e-6 * reg_term
    return cp.Problem(cp.Minimize(cost), cons), theta, x, pi


def _moved_arm(pi_nom, n_bodies, rng):
    """A physically valid arm near the URDF's: every body's mass moved rigidly by d (|d| ~ 2 cm)
    and its central inertia scaled by 0.8..1.2 (parallel axis theorem), masses kept."""
    pi = pi_nom.copy()
    for k in range(n_bodies):
        m, h, Iv = pi[10 * k], pi[10 * k + 1:10 * k + 4], pi[10 * k + 4:10 * k + 10]
        if m <= 0:
            continue
        I = np.array([[Iv[0], Iv[3], Iv[4]], [Iv[3], Iv[1], Iv[5]], [Iv[4], Iv[5], Iv[2]]])
        c = h / m
        Ic = I - m * (c @ c * np.eye(3) - np.outer(c, c))
        c2 = c + 0.02 * rng.standard_normal(3)
        I2 = rng.uniform(0.8, 1.2) * Ic + m * (c2 @ c2 * np.eye(3) - np.outer(c2, c2))
        pi[10 * k + 1:10 * k + 4] = m * c2
        pi[10 * k + 4:10 * k + 10] = [I2[0, 0], I2[1, 1], I2[2, 2], I2[0, 1], I2[0, 2], I2[1, 2]]
    return pi


@pytest.mark.parametrize("robot", ["puma560_3link", "serial7"])
def test_drake_and_cvxpy_find_the_same_nearest_physical_arm(robot):
    """PhysicalBySdp on base parameters of rigidly moved arms: Drake/Clarabel and cvxpy/Clarabel
    reach the same optimum (cost 1e-5 relative, pi 1e-4 of its largest entry), and the returned
    plant has the asked base parameters when Drake recomputes them (1e-8)."""
    reg = InverseDynamicsRegressor.from_robot(robot)
    pi_nom = reg.standard_parameters()
    K = np.asarray(reg.K, float)
    sdp = PhysicalBySdp(reg, pi_nom)
    prob, theta_p, x, pi_expr = _cvxpy_problem(reg, pi_nom, 1e-4)
    plant = make_plant(robot)
    rng = np.random.default_rng(1)
    for _ in range(3):
        theta = K @ _moved_arm(pi_nom, len(reg._nodes), rng)
        theta_p.value = theta
        prob.solve(solver="CLARABEL")
        assert prob.status == "optimal"
        pi_d, cost_d = sdp.solve(theta)
        assert np.isclose(cost_d, prob.value, rtol=1e-5, atol=1e-9)
        assert np.max(np.abs(pi_d - pi_expr.value)) <= 1e-4 * np.abs(pi_d).max()
        pi = sdp(theta)
        assert pi is not None
        ctx = plant.CreateDefaultContext()
        plant_setup(reg, pi)(plant, ctx)
        assert np.allclose(reg.base_parameters(plant, ctx), theta, rtol=1e-8, atol=1e-10 * np.abs(theta).max())


@pytest.mark.parametrize("robot", ["puma560_3link", "serial7"])
def test_drake_and_cvxpy_agree_on_the_nearest_valid_point_of_the_set(robot):
    """NearestPhysical for draws on the boundary of a +-20 % set (the serial7's are no rigid-body
    arm): same optimum as cvxpy (cost 1e-5 relative or 1e-8, Clarabel's absolute gap), same base parameters K pi (1e-4 in the set's
    Mahalanobis metric), and the returned point lies in the set at radius <= 0.999 (+1e-5)."""
    reg = InverseDynamicsRegressor.from_robot(robot)
    pi_nom = reg.standard_parameters()
    K = np.asarray(reg.K, float)
    th0 = reg.base_parameters()
    P = np.diag((0.2 * np.abs(th0) + 1e-3) ** 2)
    near = NearestPhysical(reg, pi_nom, th0, P)
    prob, theta_p, x, pi_expr = _cvxpy_problem(reg, pi_nom, 1e-4, (th0, P, 0.999))
    rng = np.random.default_rng(2)
    for _ in range(3):
        z = rng.standard_normal(len(th0))
        theta = th0 + np.sqrt(np.diag(P)) * z / np.linalg.norm(z)
        theta_p.value = theta
        prob.solve(solver="CLARABEL")
        assert prob.status == "optimal"
        pi_d, cost_d = near.solve(theta)
        assert np.isclose(cost_d, prob.value, rtol=1e-5, atol=1e-8)
        d = K @ (pi_d - pi_expr.value)
        assert np.sqrt(d @ np.linalg.solve(P, d)) <= 1e-4
        pi = near(theta)
        assert pi is not None
        r = K @ pi - th0
        assert np.sqrt(r @ np.linalg.solve(P, r)) <= 0.999 + 1e-5


def _with_central_inertia(pi_nom, k, Ic_diag):
    """pi_nom with body k's central inertia replaced by diag(Ic_diag) (centre of mass kept)."""
    pi = pi_nom.copy()
    m, c = pi[10 * k], pi[10 * k + 1:10 * k + 4] / pi[10 * k]
    I = np.diag(Ic_diag) + m * (c @ c * np.eye(3) - np.outer(c, c))
    pi[10 * k + 4:10 * k + 10] = [I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]
    return pi


def _puma_with_margin(reg):
    """The URDF's PUMA with link 1 (a flat disc in the URDF: pseudo-inertia singular, no margin)
    given central moments (0.18, 0.18, 0.35) kg m^2."""
    return _with_central_inertia(reg.standard_parameters(), 0, [0.18, 0.18, 0.35])


def test_the_certificate_refuses_bodies_no_mass_density_realises():
    """The URDF's PUMA link 1 is a flat disc (Izz = Ixx + Iyy): no margin, refused. With link 1
    thickened, PUMA link 2 with central principal moments (0.019, 0.01, 0.01) kg m^2 is a rigid body
    (0.019 < 0.02): certified; (0.021, 0.01, 0.01) breaks the triangle inequality (no mass density
    has it, although the matrix is positive definite): refused; so are a changed mass and a
    negative reflected rotor inertia."""
    reg = InverseDynamicsRegressor.from_robot("puma560_3link")
    pi_nom = reg.standard_parameters()
    assert not physical_certificate(reg, pi_nom, pi_nom, 1e-4)
    base = _puma_with_margin(reg)
    assert physical_certificate(reg, base, pi_nom, 1e-4)
    assert physical_certificate(reg, _with_central_inertia(base, 1, [0.019, 0.01, 0.01]), pi_nom, 1e-4)
    assert not physical_certificate(reg, _with_central_inertia(base, 1, [0.021, 0.01, 0.01]), pi_nom, 1e-4)
    heavier = base.copy()
    heavier[10] *= 1.01
    assert not physical_certificate(reg, heavier, pi_nom, 1e-4)
    ia = [10 * len(reg._nodes) + c for c, (_, kind, _) in enumerate(reg._extras) if kind == "Ia"]
    assert ia
    neg = base.copy()
    neg[ia[0]] = -1e-9
    assert not physical_certificate(reg, neg, pi_nom, 1e-4)


def test_a_solver_point_outside_the_set_or_no_rigid_body_is_never_returned(monkeypatch):
    """NearestPhysical returns only certified points: a rigidly moved PUMA (a valid arm) that the
    solver would return is refused when it lies outside a tight set around the URDF's parameters,
    kept when the set holds it; a point whose link 2 breaks the triangle inequality is refused."""
    reg = InverseDynamicsRegressor.from_robot("puma560_3link")
    pi_nom = reg.standard_parameters()
    K = np.asarray(reg.K, float)
    th0 = K @ pi_nom
    moved = _moved_arm(_puma_with_margin(reg), len(reg._nodes), np.random.default_rng(4))
    d = K @ moved - th0
    for scale, kept in ((0.5, False), (2.0, True)):  # radius of the moved arm 2 and 0.5
        n = np.count_nonzero(d)
        P = np.diag(n * (scale * d) ** 2 + (1e-6 * np.abs(th0)) ** 2 + 1e-30)
        assert np.isclose(np.sqrt(d @ np.linalg.solve(P, d)), 1.0 / scale, rtol=1e-3)
        near = NearestPhysical(reg, pi_nom, th0, P)
        monkeypatch.setattr(near, "solve", lambda theta: (moved, 0.0))
        assert (near(th0) is not None) == kept
    bad = _with_central_inertia(moved, 1, [0.021, 0.01, 0.01])
    monkeypatch.setattr(near, "solve", lambda theta: (bad, 0.0))
    assert near(th0) is None


def test_draws_whose_projection_fails_its_certificate_are_not_used(monkeypatch):
    """PUMA, a +-60 % set (most of it no rigid-body arm), two tries per draw: when every projection
    fails (solver or certificate), draw_plants refuses with a one-line error instead of a plant."""
    from robust_drake.errors import RobustDrakeError
    from robust_drake.uncertainty import plant_draws

    reg = InverseDynamicsRegressor.from_robot("puma560_3link")
    th0 = reg.base_parameters()
    P = np.diag((0.6 * np.abs(th0) + 1e-3) ** 2)
    monkeypatch.setattr(plant_draws.NearestPhysical, "__call__", lambda self, theta: None)
    with pytest.raises(RobustDrakeError, match="no physically valid plant"):
        plant_draws.draw_plants(reg, th0, P, 3, np.random.default_rng(0), tries=2)
