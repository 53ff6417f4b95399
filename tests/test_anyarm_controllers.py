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


# ----------------------------------------------------------------- Bascetta & Rocco Case A / B
CPT30 = dict(trajectory="cpt", trajectory_params={"amplitude_deg": 30.0}, rate=1000.0, observer="exact")


@pytest.fixture(scope="module")
def br_runs():
    from robust_drake.diagram import build_closed_loop

    runs = {}
    for robot in ROBOTS_UNDER_TEST:
        for name, ctrl, params in (("nominal", "bascetta_a", {"beta": [0.0, 0.0, 0.0]}),
                                   ("A", "bascetta_a", {}), ("B", "bascetta_b", {}), ("pd", "pd", None)):
            if params is None:  # PD with the same gains: M_hat(0) (K_P q~ + K_D q~') = K (q~' + Lambda q~)
                c = runs[(robot, "A")][1]
                M0 = c.M_hat_fn(np.zeros(c.n)) if c.M_hat_fn is not None else c.M_hat
                params = {"K": (np.diag(M0) * c.kd).tolist(), "Lambda": (c.kp / c.kd).tolist()}
            cl = build_closed_loop(ClosedLoopConfig(robot=robot, controller=ctrl, controller_params=params, **CPT30))
            if ctrl.startswith("bascetta"):
                cl.add_log("w", cl.controller.GetOutputPort("w"))
                cl.add_log("rho", cl.controller.GetOutputPort("rho"))
            runs[(robot, name)] = (cl.simulate(), cl.controller)
    return runs


@pytest.mark.parametrize("robot", ROBOTS_UNDER_TEST)
def test_bascetta_cases_track_inside_the_tube_and_beat_pd(br_runs, robot):
    """CPT 0 -> 30 deg -> 0 on every joint, K_P = 25, K_D = 5, controller model with 20 % heavier
    links: both cases stay inside the tube the bounds were sampled on (0.1 rad), and beat PD with
    the same gains and the nominal inverse dynamics (w = 0) by 10x in max error."""
    errs = {}
    for name in ("nominal", "A", "B", "pd"):
        res = br_runs[(robot, name)][0]
        assert not res.diverged, name
        errs[name] = float(np.abs(res.q - res.q_d).max())
    tube = br_runs[(robot, "A")][1].design["tube"]
    for case in ("A", "B"):
        assert errs[case] < tube
        assert errs[case] < 0.1 * errs["pd"], errs
        assert errs[case] < 0.1 * errs["nominal"], errs


@pytest.mark.parametrize("robot", ROBOTS_UNDER_TEST)
def test_bascetta_case_b_needs_less_robust_action_than_case_a(br_runs, robot):
    """BR section IV: Case B's beta_1 has no alpha ||K|| term (eq. 20 vs 13), so its rho(||e||) is
    lower along the run, and its robust action w has less energy (paper: 11 % at (25, 5))."""
    (ra, ca), (rb, cb) = br_runs[(robot, "A")], br_runs[(robot, "B")]
    d = ca.design
    assert 0 < d["bounds"].alpha < 1
    assert cb.beta[1] < ca.beta[1] and cb.beta[0] == pytest.approx(ca.beta[0])
    assert rb.extra["rho"].mean() < ra.extra["rho"].mean()
    assert np.sum(rb.extra["w"] ** 2) < np.sum(ra.extra["w"] ** 2)
    unc = ca.uncertainty
    assert unc["kind"] == "bascetta_bounds" and unc["beta"] == ca.beta and ca.rho == ca.beta[0]


def test_bascetta_serial7_uses_a_configuration_dependent_mass_model():
    """A constant diagonal M_hat cannot satisfy BR's alpha < 1 on serial7 (strong coupling): the
    design says so; the default M_hat(q) = model mass matrix gives alpha well below 1."""
    from robust_drake.systems.controllers.bascetta_rocco import case_study_design

    with pytest.raises(RobustDrakeError, match="alpha = .* >= 1.*mass_model='model'"):
        case_study_design("serial7", "cpt", {"amplitude_deg": 30.0}, mass_model="diag_q0")
    d = case_study_design("serial7", "cpt", {"amplitude_deg": 30.0})
    assert d["mass_model"] == "model" and d["bounds"].alpha < 0.5


# ----------------------------------------------------------------- ZC and LG on other arms
def test_zc_bounds_from_drake_match_the_d2r2_closed_form_and_bound_the_scara():
    """With a zero-width box, the Drake-derived beta0, beta1 of JS eqs. 21-22 equal the closed form
    of the D2R2 (zc_bounds on its eq. 14 parameters); on the IMI SCARA every box vertex's M(q)
    and ||C(q, q')|| / ||q'|| (from Drake, random states) lie inside the computed bounds."""
    from robust_drake.models import D2R2_THETA_UNLOADED
    from robust_drake.systems.controllers.zenieh_corless import zc_bounds, zc_bounds_any_arm

    q2 = np.linspace(-np.pi, np.pi, 721)
    d = zc_bounds_any_arm("d2r2", rel_bound=0.0, configs=np.stack([np.zeros_like(q2), q2], axis=1))
    b0, b1, _ = zc_bounds(D2R2_THETA_UNLOADED, D2R2_THETA_UNLOADED)
    assert d["beta0"] == pytest.approx(b0, rel=2e-3) and d["beta1"] == pytest.approx(b1, rel=2e-3)
    s = zc_bounds_any_arm("imi_scara", rel_bound=0.2)
    plant = make_plant("imi_scara")
    ctx = plant.CreateDefaultContext()
    rng = np.random.default_rng(5)
    for _ in range(30):
        q, qd = rng.uniform(-np.pi, np.pi, 2), rng.normal(size=2)
        plant.SetPositions(ctx, q)
        w = np.linalg.eigvalsh(plant.CalcMassMatrix(ctx))
        assert s["beta0"] <= w[0] + 1e-9 and w[-1] <= s["beta1"] + 1e-9
        plant.SetVelocities(ctx, qd)
        assert np.linalg.norm(plant.CalcBiasTerm(ctx)) <= s["beta2"] * np.dot(qd, qd) + 1e-9  # C(q, q') q'


def test_zc_runs_on_a_horizontal_arm_and_refuses_gravity():
    run = dict(trajectory="sine", rate=1000.0, duration=1.0, observer="exact")
    zc = simulate(ClosedLoopConfig(robot="imi_scara", controller="zc", **run))
    pd = simulate(ClosedLoopConfig(robot="imi_scara", controller="pd", **run))
    assert not zc.diverged
    rms = [float(np.sqrt(np.mean((r.q - r.q_d) ** 2))) for r in (zc, pd)]
    assert rms[0] < 0.9 * rms[1], rms
    for robot in ROBOTS_UNDER_TEST:
        with pytest.raises(RobustDrakeError, match="gravity torques up to .* no gravity term"):
            simulate(ClosedLoopConfig(robot=robot, controller="zc", **run))


@pytest.mark.parametrize("robot,match", [("serial7", "n = 7.*Missing for n joints"),
                                         ("siciliano_2link", "eq. 14's parameters")])
@pytest.mark.parametrize("ctrl", ["lg", "lgplus"])
def test_lg_says_what_is_missing(robot, match, ctrl):
    with pytest.raises(RobustDrakeError, match=match):
        simulate(ClosedLoopConfig(robot=robot, controller=ctrl, trajectory="sine", rate=1000.0, duration=0.01))


# ----------------------------------------------------------------- Franka Emika Panda (Gaz et al. 2019)
PANDA_READY = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]
PANDA_LIMITS = [87.0] * 4 + [12.0] * 3


def test_panda_model_and_friction_are_physical():
    """The Panda URDF parses to a 7-joint arm of 16.06 kg (sum of Gaz et al.'s link masses) with
    gravity at the ready pose; the sigmoid friction is dissipative (sign of qd) and bounded by phi1."""
    from robust_drake.systems.sigmoid_friction import PANDA_PHI1, PANDA_PHI2, PANDA_PHI3, sigmoid_friction

    plant = make_plant("panda")
    assert plant.num_velocities() == 7
    ctx = plant.CreateDefaultContext()
    total = sum(plant.GetBodyByName(f"link{k}").default_mass() for k in range(1, 8))
    assert total == pytest.approx(16.062132, abs=1e-6)
    plant.SetPositions(ctx, PANDA_READY)
    assert np.min(np.linalg.eigvalsh(plant.CalcMassMatrix(ctx))) > 0
    assert np.abs(plant.CalcGravityGeneralizedForces(ctx)[3]) > 10.0  # elbow holds the forearm
    qd = np.linspace(-3, 3, 601)[:, None] * np.ones(7)
    tf = sigmoid_friction(qd, PANDA_PHI1, PANDA_PHI2, PANDA_PHI3)
    assert np.all(tf * qd >= 0) and np.all(np.abs(tf) <= np.asarray(PANDA_PHI1))


@pytest.fixture(scope="module")
def panda_runs():
    """1 kHz, 20-bit encoder (our assumption), Gaz et al. sigmoid friction in the plant, torque
    saturation at Franka's limits; filtered 0.3 rad step on every joint from the ready pose."""
    plant = make_plant("panda")
    ctx = plant.CreateDefaultContext()
    plant.SetPositions(ctx, PANDA_READY)
    K = (50.0 * np.diag(plant.CalcMassMatrix(ctx))).tolist()  # same gains for both
    common = dict(robot="panda", trajectory="step", rate=1000.0, duration=1.2,
                  trajectory_params={"amplitude": 0.3, "omega": 8.0, "offset": PANDA_READY, "duration": 1.2},
                  encoder_resolution=2 * np.pi / 2 ** 20, torque_limit=PANDA_LIMITS,
                  effects=[("sigmoid_friction", {})])
    return {name: simulate(ClosedLoopConfig(controller=ctrl, controller_params=dict(params, K=K, Lambda=20.0), **common))
            for name, ctrl, params in (("pd", "pd", {}), ("sp1", "sp1", {"epsilon": 1.0}))}


def test_sp1_on_the_panda_beats_pd_with_friction_encoder_and_saturation(panda_runs):
    """SP1 (Drake-derived Slotine-Li regressor, 43 base parameters, box of +-20 %, epsilon = 1 as JS
    table 1) keeps the error bounded and 10x below PD with the same K, Lambda; the robust term also
    absorbs most of the unmodelled friction (the regressor has no friction columns)."""
    sp, pd = panda_runs["sp1"], panda_runs["pd"]
    assert not sp.diverged and not pd.diverged
    assert np.all(np.abs(sp.tau) <= np.asarray(PANDA_LIMITS) + 1e-9)
    e_sp, e_pd = np.abs(sp.q - sp.q_d), np.abs(pd.q - pd.q_d)
    late = sp.t > 0.8
    assert e_sp.max() < 0.02 and e_sp[late].max() < 5e-3, (e_sp.max(), e_sp[late].max())
    assert np.sqrt(np.mean(e_sp ** 2)) < 0.1 * np.sqrt(np.mean(e_pd ** 2))


def test_calafiore_takes_an_identified_ellipsoid_file(tmp_path):
    """An ellipsoid JSON (theta0, P) on the URDF's base parameters is used as is: the controller's
    theta0 and E E^T are the file's; giving both a file and P is refused."""
    from robust_drake.uncertainty.ellipsoid import Ellipsoid
    from robust_drake.systems.controllers.calafiore_indri import make_calafiore

    reg = InverseDynamicsRegressor.from_robot("siciliano_2link")
    th = reg.base_parameters() * 1.05
    A = np.random.default_rng(2).normal(size=(reg.p_base, reg.p_base))
    P = A @ A.T + np.eye(reg.p_base)
    path = tmp_path / "ell.json"
    Ellipsoid(th, P).save(path)
    c = make_calafiore(_ctx("siciliano_2link"), ellipsoid=str(path))
    np.testing.assert_allclose(c.theta0, th)
    np.testing.assert_allclose(c.E @ c.E.T, P, rtol=1e-10, atol=1e-10)
    assert c.uncertainty["source"].startswith("identified")
    with pytest.raises(RobustDrakeError, match="either 'ellipsoid' or 'theta0'/'P'"):
        make_calafiore(_ctx("siciliano_2link"), ellipsoid=str(path), P=P)
