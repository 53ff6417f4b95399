"""Robust laws of the three papers on arms other than their own (issue 14): Calafiore & Indri
eq. 15 with an ellipsoid on the Drake-derived base parameters, Bascetta & Rocco Case A/B,
and the LG/ZC refusals, on serial7 and the Siciliano 2-link arm."""

import numpy as np
import pytest

from robust_drake.diagram import ClosedLoopConfig, _arm_for, simulate
from robust_drake.errors import RobustDrakeError
from robust_drake.models import ROBOTS, make_plant
from robust_drake.registry import BuildContext
from robust_drake.regressor import InverseDynamicsRegressor

ROBOTS_UNDER_TEST = ["siciliano_2link", "serial7"]


def _ctx(robot, period=1e-3, **cfg):
    c = ClosedLoopConfig(robot=robot, trajectory=cfg.pop("trajectory", "sine"), **cfg).resolved()
    n = ROBOTS[robot].n
    return BuildContext(robot=robot, arm=_arm_for(robot, n), load=c.load, n=n, period=period, config=c)


def _heavier(plant, ctx, factor=1.15):
    """Every link 15 % heavier (centre of mass and unit inertia kept, so inertias scale too)."""
    for k in range(1, 8):
        if plant.HasBodyNamed(f"link{k}"):
            b = plant.GetBodyByName(f"link{k}")
            b.SetMass(ctx, factor * b.default_mass())


def _true_base_parameters(robot):
    reg = InverseDynamicsRegressor.from_robot(robot)
    plant = make_plant(robot)
    ctx = plant.CreateDefaultContext()
    _heavier(plant, ctx)
    return reg.base_parameters(), reg.base_parameters(plant, ctx)


# ----------------------------------------------------------------- Calafiore & Indri eq. 15
def test_calafiore_with_a_sphere_is_sp1_on_serial7():
    """CI section 4: with P = rho^2 I, eq. 15 is Spong's SP1 (eq. 18) with epsilon_CI =
    rho epsilon_SP1: same torques from the Drake-derived regressor, inside and outside the layer."""
    from robust_drake.systems.controllers.calafiore_indri import make_calafiore
    from robust_drake.systems.controllers.spong import make_sp1

    ctx = _ctx("serial7")
    reg = InverseDynamicsRegressor.from_robot("serial7")
    rho, eps = 3.0, 0.5
    ci = make_calafiore(ctx, P=rho ** 2 * np.eye(reg.p_base), epsilon=rho * eps)
    sp = make_sp1(ctx, rho=rho, epsilon=eps)
    rng = np.random.default_rng(1)
    for scale in (1.0, 1e-3, 1e-5):  # outside, and (small r) inside the boundary layer
        q_d, qd_d, qdd_d, q, v = rng.normal(size=(5, 7))
        v_err = v - qd_d
        q = q_d + scale * (q - q_d)
        v_err = scale * v_err
        args = (0.0, q_d, qd_d, qdd_d, q, qd_d + v_err, v_err)
        np.testing.assert_allclose(ci.compute(*args), sp.compute(*args), rtol=1e-10, atol=1e-10)
    assert ci.uncertainty["kind"] == "ellipsoid" and ci.rho == pytest.approx(rho)


def test_default_ellipsoid_contains_the_box():
    """The default P (k diag(b^2)) contains every vertex of the box |theta~_i| <= b_i, with
    vertices on the boundary; a point 10 % outside a face along one axis stays inside (k > 1)."""
    from robust_drake.systems.controllers.calafiore_indri import ellipsoid_from_box

    th0 = InverseDynamicsRegressor.from_robot("siciliano_2link").base_parameters()
    P = ellipsoid_from_box(th0, 0.2)
    b = 0.2 * np.abs(th0)
    keep = b > 0
    Pk = P[np.ix_(keep, keep)]
    rng = np.random.default_rng(0)
    verts = b[keep] * rng.choice([-1.0, 1.0], size=(200, keep.sum()))
    r2 = np.einsum("ki,ij,kj->k", verts, np.linalg.inv(Pk), verts)
    assert r2.max() <= 1 + 1e-12 and r2.min() >= 1 - 1e-12
    assert np.allclose(P[~keep], 0) and np.allclose(P[:, ~keep], 0)  # zero parameters stay fixed


@pytest.fixture(scope="module")
def ci_runs():
    runs = {}
    for robot in ROBOTS_UNDER_TEST:
        for ctrl in ("pd", "calafiore_nominal", "calafiore"):
            runs[(robot, ctrl)] = simulate(ClosedLoopConfig(
                robot=robot, controller=ctrl, trajectory="sine", rate=1000.0, duration=1.0,
                observer="exact", plant_setup=[_heavier]))
    return runs


@pytest.mark.parametrize("robot", ROBOTS_UNDER_TEST)
def test_calafiore_tracks_a_plant_inside_its_ellipsoid_better_than_pd(ci_runs, robot):
    """True arm 15 % heavier, inside the default ellipsoid (checked on Drake's parameters): eq. 15
    keeps the error bounded, beats PD with the same K, Lambda after the transient by 5x, and beats
    its own nominal law (eq. 6, same theta0) in RMS error."""
    th0, th = _true_base_parameters(robot)
    b = 0.2 * np.abs(th0)
    assert np.all(np.abs(th - th0) <= b + 1e-12)  # inside the box, so inside the ellipsoid
    ci, nom, pd = (ci_runs[(robot, c)] for c in ("calafiore", "calafiore_nominal", "pd"))
    assert not ci.diverged and not pd.diverged
    e = {k: np.abs(r.q - r.q_d) for k, r in (("ci", ci), ("nom", nom), ("pd", pd))}
    rms = {k: float(np.sqrt((x ** 2).mean())) for k, x in e.items()}
    late = ci.t > 0.5
    assert e["ci"].max() < 0.05
    assert e["ci"][late].max() < 0.2 * e["pd"][late].max(), (e["ci"][late].max(), e["pd"][late].max())
    assert rms["ci"] < 0.7 * rms["pd"], rms
    assert rms["ci"] < rms["nom"], rms


def test_calafiore_reports_its_ellipsoid_and_refuses_a_wrong_size():
    from robust_drake.systems.controllers.calafiore_indri import make_calafiore

    c = make_calafiore(_ctx("siciliano_2link"), rel_bound=0.1)
    unc = c.uncertainty
    P = np.asarray(unc["P"])
    assert unc["kind"] == "ellipsoid" and P.shape == (len(unc["theta0"]),) * 2
    assert c.rho == pytest.approx(np.sqrt(np.linalg.eigvalsh(P)[-1]))
    with pytest.raises(RobustDrakeError, match="base parameters"):
        make_calafiore(_ctx("siciliano_2link"), P=np.eye(3))
