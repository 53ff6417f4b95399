"""The Slotine-Li regressor Y(q, qd, v, a) for any URDF arm (JS eqs. 6, 10, 15) against Drake.

References are computed from Drake independently of the regressor: M(q) from CalcMassMatrix,
C(q, qd) from the Christoffel symbols of dM/dq (AutoDiff through Drake's mass matrix), g(q)
from CalcGravityGeneralizedForces, C(q, qd) qd from CalcBiasTerm, eq. 15's theta from Drake's
mass matrix (d2r2_theta_from_plant).
"""

import math

import numpy as np
import pytest

from dynamics_reference import christoffel_C, damped_siciliano_urdf, mass_matrix_and_derivative

from robust_drake.errors import RobustDrakeError
from robust_drake.models import ROBOTS, d2r2_theta_from_plant, make_plant, set_d2r2_theta
from robust_drake.regressor import InverseDynamicsRegressor, d2r2_regressor

ALL = [(r, load) for r in ROBOTS for load in ROBOTS[r].loads]


def _states(n, N, seed):
    rng = np.random.default_rng(seed)
    return (rng.uniform(-math.pi, math.pi, (N, n)), rng.normal(0, 2, (N, n)), rng.normal(0, 2, (N, n)),
            rng.normal(0, 5, (N, n)))


@pytest.mark.parametrize("robot,load", ALL)
def test_slotine_li_equals_drake_M_a_plus_C_v_plus_g(robot, load):
    reg = InverseDynamicsRegressor.from_robot(robot, load)
    plant = make_plant(robot, load)
    ctx = plant.CreateDefaultContext()
    ad = plant.ToAutoDiffXd()
    ad_ctx = ad.CreateDefaultContext()
    theta = reg.base_parameters()
    q, qd, v, a = _states(reg.n, 8, seed=3)
    Y = reg.slotine_li(q, qd, v, a)
    assert Y.shape == (8, reg.n, reg.p_base)
    Yq = reg.slotine_li(q, qd, qd, a)
    for k in range(8):
        M, dM = mass_matrix_and_derivative(ad, ad_ctx, q[k])
        plant.SetPositions(ctx, q[k])
        plant.SetVelocities(ctx, qd[k])
        np.testing.assert_allclose(M, plant.CalcMassMatrix(ctx), rtol=1e-12, atol=1e-12)
        g = -plant.CalcGravityGeneralizedForces(ctx)
        C = christoffel_C(dM, qd[k])
        ref = M @ a[k] + C @ v[k] + g
        scale = np.abs(M @ a[k]).max() + np.abs(C @ v[k]).max() + np.abs(g).max()
        assert np.abs(Y[k] @ theta - ref).max() <= 1e-9 * scale, (robot, k)
        # v = qd: Drake's own bias term C(q, qd) qd
        ref_q = M @ a[k] + plant.CalcBiasTerm(ctx) + g
        assert np.abs(Yq[k] @ theta - ref_q).max() <= 1e-9 * scale, (robot, k)
    # with v = qd it is the ordinary inverse-dynamics regressor, column by column
    Y_id = reg.evaluate(q, qd, a)
    np.testing.assert_allclose(Yq, Y_id, rtol=1e-9, atol=1e-9 * np.abs(Y_id).max())
    # the per-tick path gives the same matrix
    np.testing.assert_allclose(reg.slotine_li_single(q[0], qd[0], v[0], a[0]), Y[0], rtol=0, atol=1e-12 * np.abs(Y).max())


@pytest.mark.parametrize("robot,load", ALL)
def test_skew_symmetry_with_the_bilinear_C(robot, load):
    """JS eq. 6: x^T (M' - 2 C) x = 0 with C(q, qd) read column by column from the regressor
    (C e_j = Y(q, qd, e_j, 0) theta - g) and M' from central finite differences of Drake's M."""
    reg = InverseDynamicsRegressor.from_robot(robot, load)
    plant = make_plant(robot, load)
    ctx = plant.CreateDefaultContext()
    theta = reg.base_parameters()
    n = reg.n
    q, qd, _, _ = _states(n, 4, seed=17)
    rng = np.random.default_rng(5)
    h = 1e-6
    for k in range(4):
        E = np.eye(n)
        Yc = reg.slotine_li(np.tile(q[k], (n + 1, 1)), np.tile(qd[k], (n + 1, 1)),
                            np.vstack([E, np.zeros(n)]), np.zeros((n + 1, n)))
        g = Yc[n] @ theta
        C = np.stack([Yc[j] @ theta - g for j in range(n)], axis=1)

        def M_at(x):
            plant.SetPositions(ctx, x)
            return plant.CalcMassMatrix(ctx)

        Mdot = (M_at(q[k] + h * qd[k]) - M_at(q[k] - h * qd[k])) / (2 * h)
        N = Mdot - 2 * C
        scale = np.abs(Mdot).max() + 2 * np.abs(C).max()
        np.testing.assert_allclose(N + N.T, 0.0, atol=1e-6 * scale)
        for _ in range(3):
            x = rng.normal(size=n)
            assert abs(x @ N @ x) <= 1e-6 * scale * (x @ x)
        # and the same C is Drake's bias term on v = qd
        plant.SetPositions(ctx, q[k])
        plant.SetVelocities(ctx, qd[k])
        np.testing.assert_allclose(C @ qd[k], plant.CalcBiasTerm(ctx), rtol=0,
                                   atol=1e-9 * max(1.0, np.abs(C @ qd[k]).max()))


@pytest.mark.parametrize("load", ["none", "max"])
def test_d2r2_reproduces_js_eq15(load):
    """On the D2R2 (horizontal, no gravity) the Drake-derived Slotine-Li regressor gives the
    torques of JS eq. 15 with eq. 14's theta read from Drake's mass matrix, also for plants
    whose parameters were changed (Monte Carlo arms)."""
    reg = InverseDynamicsRegressor.from_robot("d2r2", load)
    plant = make_plant("d2r2", load)
    ctx = plant.CreateDefaultContext()
    rng = np.random.default_rng(8)
    q, qd, v, a = _states(2, 30, seed=9)
    for trial in range(3):
        if trial:
            set_d2r2_theta(plant, ctx, np.array([0.678, 0.033, 0.029]) * rng.uniform(0.7, 1.4, 3))
        th_js = d2r2_theta_from_plant(plant, ctx)
        th_b = reg.base_parameters(plant, ctx)
        tau_sl = reg.slotine_li(q, qd, v, a) @ th_b
        tau_js = np.einsum("nij,j->ni", d2r2_regressor(q, qd, v, a), th_js)
        assert np.abs(tau_sl - tau_js).max() <= 1e-9 * np.abs(tau_js).max(), trial


def test_symbolic_and_numeric_routes_agree_and_damping_acts_on_qd(tmp_path):
    """A URDF with joint damping: b_j multiplies the true velocity qd_j, not the reference v_j."""
    path = damped_siciliano_urdf(tmp_path, 0.7)
    plant = make_plant(str(path))
    ctx = plant.CreateDefaultContext()
    ad = plant.ToAutoDiffXd()
    ad_ctx = ad.CreateDefaultContext()
    q, qd, v, a = _states(2, 6, seed=4)
    Ys = {}
    for method in ("numeric", "symbolic"):
        reg = InverseDynamicsRegressor.from_robot(str(path), method=method)
        theta = reg.base_parameters()
        Ys[method] = reg.slotine_li(q, qd, v, a)
        for k in range(6):
            M, dM = mass_matrix_and_derivative(ad, ad_ctx, q[k])
            plant.SetPositions(ctx, q[k])
            ref = M @ a[k] + christoffel_C(dM, qd[k]) @ v[k] - plant.CalcGravityGeneralizedForces(ctx)
            ref[1] += 0.7 * qd[k, 1]
            assert np.abs(Ys[method][k] @ theta - ref).max() <= 1e-9 * np.abs(ref).max()
            np.testing.assert_allclose(reg.slotine_li_single(q[k], qd[k], v[k], a[k]), Ys[method][k],
                                       rtol=0, atol=1e-12 * np.abs(Ys[method][k]).max())
    np.testing.assert_allclose(Ys["numeric"], Ys["symbolic"], rtol=1e-9, atol=1e-9)


def test_inputs_are_checked():
    reg = InverseDynamicsRegressor.from_robot("serial7")
    with pytest.raises(RobustDrakeError, match=r"\(N, 7\)"):
        reg.slotine_li(np.zeros(7), np.zeros(7), np.zeros(6), np.zeros(7))
    with pytest.raises(RobustDrakeError):
        reg.slotine_li(np.zeros((3, 7)), np.zeros((2, 7)), np.zeros((3, 7)), np.zeros((3, 7)))


# ----------------------------------------------------------------------------- SP1 / SP2 for n joints
def _ctx(robot, period=1e-3, **cfg):
    from robust_drake.diagram import ClosedLoopConfig, _arm_for
    from robust_drake.registry import BuildContext

    c = ClosedLoopConfig(robot=robot, trajectory=cfg.pop("trajectory", "sine"), **cfg).resolved()
    n = ROBOTS[robot].n
    return BuildContext(robot=robot, arm=_arm_for(robot, n), load=c.load, n=n, period=period, config=c)


@pytest.mark.parametrize("factory", ["make_sp1", "make_sp2"])
def test_d2r2_scalar_fast_path_equals_the_pure_law(factory):
    """The D2R2 controllers run eqs. 11-12 in scalar math; that path must equal spong_law
    (spong_error_terms -> Y -> Y^T r -> robust input -> spong_torque) on random samples, inside and
    outside the boundary layer."""
    from robust_drake.systems.controllers import spong, spong_friction

    rng = np.random.default_rng(2)
    ctrls = [getattr(spong, factory)(_ctx("d2r2", 4e-4, trajectory="cpt")),
             getattr(spong_friction, factory + "_robust_friction")(_ctx("d2r2", 4e-4, trajectory="cpt"))]
    for c in ctrls:
        assert c.scalar_fast_path
        for scale in (1e-3, 1.0, 30.0):
            for _ in range(20):
                q_d, qd_d, qdd_d, q, v, v_err = (scale * rng.normal(size=2) for _ in range(6))
                fast = c.compute_scalar(q_d, qd_d, qdd_d, q, v, v_err)
                pure = spong.spong_law(c.regressor, c.robust_input, c.theta0, c.K, c.Lambda,
                                       q_d, qd_d, qdd_d, q, v, v_err)
                np.testing.assert_allclose(fast, pure, rtol=1e-12, atol=1e-12 * max(1.0, np.abs(pure).max()))


def test_factories_pick_closed_form_or_drake_regressor_and_state_the_set():
    from robust_drake.systems.controllers.spong import D2R2_RHO_SP1, make_sp1, make_sp2

    c = make_sp1(_ctx("d2r2", 4e-4, trajectory="cpt"))
    assert c.rho == D2R2_RHO_SP1 and c.uncertainty["kind"] == "box"
    reg = InverseDynamicsRegressor.from_robot("serial7")
    th0 = reg.base_parameters()
    c1 = make_sp1(_ctx("serial7"), rel_bound=0.3)
    c2 = make_sp2(_ctx("serial7"), rel_bound=0.3)
    assert not c1.scalar_fast_path
    np.testing.assert_allclose(c1.theta0, th0)
    # the box |theta_i - theta0_i| <= 0.3 |theta0_i|: SP1's rho is max ||theta~|| over it, SP2's the b_i
    assert c1.rho == pytest.approx(0.3 * np.linalg.norm(th0), rel=1e-12)
    np.testing.assert_allclose(c2.rho, 0.3 * np.abs(th0), rtol=1e-12)
    vert = 0.3 * np.abs(th0) * np.random.default_rng(0).choice([-1.0, 1.0], size=(50, th0.size))
    assert np.linalg.norm(vert, axis=1).max() <= c1.rho * (1 + 1e-12)
    # the controller really evaluates the Drake-derived Slotine-Li regressor
    rng = np.random.default_rng(3)
    q, qd, v, a = rng.normal(size=(4, 7))
    Y_ref = reg.slotine_li(q, qd, v, a)[0]  # the numpy route; the controller's is Pinocchio's (rounding)
    np.testing.assert_allclose(np.asarray(c1.regressor(q, qd, v, a)), Y_ref, rtol=0, atol=1e-13 * np.abs(Y_ref).max())
    with pytest.raises(RobustDrakeError, match="base parameters"):
        make_sp1(_ctx("serial7"), theta0=[1.0, 2.0])
    with pytest.raises(RobustDrakeError, match="rel_bound"):
        make_sp1(_ctx("serial7"), rel_bound=-0.1)


@pytest.fixture(scope="module")
def n_joint_runs():
    from robust_drake.diagram import ClosedLoopConfig, simulate

    runs = {}
    for robot in ("siciliano_2link", "serial7"):
        for ctrl in ("pd", "sp1", "sp2"):
            runs[(robot, ctrl)] = simulate(ClosedLoopConfig(robot=robot, controller=ctrl, trajectory="sine",
                                                            rate=1000.0, duration=1.0))
    return runs


@pytest.mark.parametrize("robot", ["siciliano_2link", "serial7"])
@pytest.mark.parametrize("ctrl", ["sp1", "sp2"])
def test_spong_tracks_and_beats_pd_with_the_same_gains(n_joint_runs, robot, ctrl):
    """Sine on every joint from rest (initial velocity error pi/2 rad/s): bounded tracking, and
    after the transient SP1/SP2 hold the error 100x below PD with the same K, Lambda (PD has no
    gravity or inertia model)."""
    sp, pd = n_joint_runs[(robot, ctrl)], n_joint_runs[(robot, "pd")]
    assert not sp.diverged and not pd.diverged
    e_sp, e_pd = np.abs(sp.q - sp.q_d), np.abs(pd.q - pd.q_d)
    late = sp.t > 0.5
    assert e_sp.max() < 0.05, e_sp.max()
    assert e_sp[late].max() < 1e-3, e_sp[late].max()
    assert e_sp[late].max() < 0.01 * e_pd[late].max(), (e_sp[late].max(), e_pd[late].max())
    assert np.sqrt((e_sp ** 2).mean()) < 0.6 * np.sqrt((e_pd ** 2).mean())


def test_simulate_json_reports_uncertainty_and_rho(capsys):
    import json

    from robust_drake.cli import main as cli_main

    assert cli_main(["simulate", "--robot", "siciliano_2link", "--controller", "sp1", "--trajectory", "sine",
                     "--duration", "0.05", "--rate", "1000", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    unc = out["uncertainty"]
    assert unc["kind"] == "box" and unc["rel_bound"] == 0.2
    assert out["rho"] == pytest.approx(np.linalg.norm(unc["bounds"]))
    np.testing.assert_allclose(unc["theta0"], InverseDynamicsRegressor.from_robot("siciliano_2link").base_parameters())
    assert cli_main(["simulate", "--controller", "pd", "--duration", "0.02", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["uncertainty"] is None and out["rho"] is None


def _heavier(plant, ctx, factor=1.15):
    """Every link 15 % heavier (centre of mass and unit inertia kept, so inertias scale too)."""
    for k in range(1, 8):
        if plant.HasBodyNamed(f"link{k}"):
            b = plant.GetBodyByName(f"link{k}")
            b.SetMass(ctx, factor * b.default_mass())


@pytest.mark.parametrize("robot", ["siciliano_2link", "serial7"])
def test_sp1_is_robust_to_a_plant_inside_its_uncertainty_box(robot):
    """The true arm (links 15 % heavier) lies in the stated box (checked from Drake's parameters);
    SP1 with theta0 = the URDF keeps tracking bounded and beats both the nominal law (rho = 0,
    same K, Lambda, theta0) and PD."""
    from robust_drake.diagram import ClosedLoopConfig, simulate

    reg = InverseDynamicsRegressor.from_robot(robot)
    plant = make_plant(robot)
    ctx = plant.CreateDefaultContext()
    _heavier(plant, ctx)
    th0, th = reg.base_parameters(), reg.base_parameters(plant, ctx)
    assert np.linalg.norm(th - th0) > 0.05 * np.linalg.norm(th0)  # a real mismatch ...
    assert np.all(np.abs(th - th0) <= 0.2 * np.abs(th0) + 1e-12)  # ... inside the default box
    runs = {}
    for name, ctrl, params in (("pd", "pd", {}), ("nominal", "sp1", {"rho": 0.0}), ("sp1", "sp1", {})):
        res = simulate(ClosedLoopConfig(robot=robot, controller=ctrl, controller_params=params, trajectory="sine",
                                        rate=1000.0, duration=1.0, plant_setup=[_heavier]))
        assert not res.diverged
        e = np.abs(res.q - res.q_d)
        runs[name] = (np.sqrt((e ** 2).mean()), e[res.t > 0.5].max())
    assert runs["sp1"][1] < 5e-3 and runs["sp1"][1] < 0.2 * runs["pd"][1], runs
    assert runs["sp1"][0] < 0.9 * runs["nominal"][0] and runs["sp1"][0] < 0.5 * runs["pd"][0], runs
