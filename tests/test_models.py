"""Arm models: the URDFs against the papers' and labs' equations (not against our own code)."""

import math

import numpy as np
import pytest

from robust_drake.errors import RobustDrakeError
from robust_drake.models import (
    D2R2_LOAD_INTERVALS,
    D2R2_THETA0,
    D2R2_THETA_LOADED,
    D2R2_THETA_UNLOADED,
    ROBOTS,
    add_arm,
    d2r2_theta,
    d2r2_theta_from_plant,
    get_arm,
    make_plant,
    resolve_urdf,
    set_d2r2_theta,
)

G = 9.81
ALL = [(r, load) for r in ROBOTS for load in ROBOTS[r].loads]


@pytest.fixture(scope="module")
def plants():
    return {(r, load): make_plant(r, load) for r, load in ALL}


def _link_params(plant, ctx, link, welded=()):
    """(m, lc along x, central izz) of a link (plus bodies welded to it), from Drake's bodies."""
    frame = plant.GetBodyByName(link).body_frame()
    idx = [plant.GetBodyByName(b).index() for b in (link, *welded)]
    M = plant.CalcSpatialInertia(ctx, frame, idx)
    m, c = M.get_mass(), M.get_com()
    assert abs(c[1]) < 1e-12 and abs(c[2]) < 1e-12
    Izz_c = M.Shift(c).CalcRotationalInertia().CopyToFullMatrix3()[2, 2]
    return m, c[0], Izz_c


@pytest.mark.parametrize("robot,load", ALL)
def test_every_model_loads_with_conventions(plants, robot, load):
    spec = get_arm(robot)
    plant = plants[(robot, load)]
    assert plant.num_positions() == spec.n == plant.num_actuators()
    for i in range(1, spec.n + 1):
        j = plant.GetJointByName(f"joint{i}")
        assert j.num_velocities() == 1 and j.velocity_start() == i - 1
    ctx = plant.CreateDefaultContext()
    # tool frame at the tip: stretched arm (q = 0) of a planar model reaches l1 + l2 from joint 1
    tool = plant.GetFrameByName("tool")
    X = tool.CalcPoseInWorld(ctx)
    if spec.plane is not None:
        j1 = plant.GetJointByName("joint1").frame_on_child().CalcPoseInWorld(ctx)
        assert np.linalg.norm(X.translation() - j1.translation()) == pytest.approx(sum(spec.link_lengths), abs=1e-12)
    # mass matrix symmetric positive definite at random configurations
    rng = np.random.default_rng(3)
    for _ in range(5):
        plant.SetPositions(ctx, rng.uniform(-math.pi, math.pi, spec.n))
        M = plant.CalcMassMatrix(ctx)
        assert np.allclose(M, M.T, atol=1e-12) and np.linalg.eigvalsh(M).min() > 0
        g = plant.CalcGravityGeneralizedForces(ctx)
        if spec.gravity:
            assert np.abs(g).max() > 1e-3
        else:  # horizontal plane: joint axes along world z, gravity -z gives no joint torque
            assert np.abs(g).max() < 1e-12


def test_lookup_errors(tmp_path, monkeypatch):
    with pytest.raises(RobustDrakeError, match="known robots: .*d2r2"):
        get_arm("puma560")
    with pytest.raises(RobustDrakeError, match="no load"):
        resolve_urdf("d2r2", "heavy")
    with pytest.raises(RobustDrakeError, match="does not exist"):
        resolve_urdf(str(tmp_path / "nothing.urdf"))
    with pytest.raises(RobustDrakeError):
        make_plant("not_a_robot")
    path = resolve_urdf("d2r2", "max")
    assert path.name == "d2r2_loaded.urdf"
    assert resolve_urdf(str(path)) == path  # a path works too
    monkeypatch.setenv("ROBUST_DRAKE_MODELS", str(tmp_path))
    with pytest.raises(RobustDrakeError, match="not found"):
        resolve_urdf("d2r2")


def test_add_arm_and_discrete_plant():
    from pydrake.systems.framework import DiagramBuilder

    builder = DiagramBuilder()
    plant, sg = add_arm(builder, "siciliano_2link", time_step=1e-3)
    assert plant.is_finalized() and plant.time_step() == 1e-3
    assert plant.get_actuation_input_port().size() == 2
    builder.Build()


# ----------------------------------------------------------------------------- D2R2


@pytest.mark.parametrize("load,table", [("none", D2R2_THETA_UNLOADED), ("max", D2R2_THETA_LOADED)])
def test_d2r2_theta_equals_tables(plants, load, table):
    plant = plants[("d2r2", load)]
    ctx = plant.CreateDefaultContext()
    np.testing.assert_allclose(d2r2_theta_from_plant(plant, ctx), table, atol=1e-3)
    # from the bodies themselves, via eq. 14
    l1 = ROBOTS["d2r2"].link_lengths[0]
    m1, lc1, I1 = _link_params(plant, ctx, "link1")
    m2, lc2, I2 = _link_params(plant, ctx, "link2", ("payload",) if load == "max" else ())
    np.testing.assert_allclose(d2r2_theta(m1, lc1, I1, m2, lc2, I2, l1), table, atol=1e-3)
    # JS eqs. 2-3 against Drake's mass matrix
    rng = np.random.default_rng(0)
    for q in rng.uniform(-math.pi, math.pi, (10, 2)):
        c2 = math.cos(q[1])
        M_js = np.array([
            [m1 * lc1**2 + m2 * (l1**2 + lc2**2 + 2 * l1 * lc2 * c2) + I1 + I2, m2 * (lc2**2 + l1 * lc2 * c2) + I2],
            [m2 * (lc2**2 + l1 * lc2 * c2) + I2, m2 * lc2**2 + I2],
        ])
        plant.SetPositions(ctx, q)
        np.testing.assert_allclose(plant.CalcMassMatrix(ctx), M_js, rtol=1e-12, atol=1e-14)


def test_d2r2_load_increments_match_eq93(plants):
    c0 = plants[("d2r2", "none")].CreateDefaultContext()
    c1 = plants[("d2r2", "max")].CreateDefaultContext()
    m2, lc2, I2 = _link_params(plants[("d2r2", "none")], c0, "link2")
    M2, LC2, II2 = _link_params(plants[("d2r2", "max")], c1, "link2", ("payload",))
    dm, dl, dI = M2 - m2, LC2 - lc2, II2 - I2
    assert dm == pytest.approx(D2R2_LOAD_INTERVALS["dm2"][1], abs=1e-9)
    assert dl == pytest.approx(D2R2_LOAD_INTERVALS["dlc2"][1], abs=1e-9)
    assert dI == pytest.approx(D2R2_LOAD_INTERVALS["dI2"][1], abs=1e-3)
    # table 11 is the mean of tables 8 and 9 (eq. 16's "1/2 (max - unloaded)" is a typo)
    np.testing.assert_allclose(D2R2_THETA0, 0.5 * (np.array(D2R2_THETA_UNLOADED) + D2R2_THETA_LOADED), atol=6e-4)
    # l1^2 = dtheta1 / dm2 within the rounding of the tables
    l1 = ROBOTS["d2r2"].link_lengths[0]
    lo, hi = 0.105 / 1.1841, 0.107 / 1.1841
    assert lo <= l1**2 <= hi


def test_d2r2_reaches_section10_circle(plants):
    """Every point of the circle r = 0.1 m about (0.4, 0) m: analytic IK, Drake FK of 'tool'."""
    plant = plants[("d2r2", "none")]
    ctx = plant.CreateDefaultContext()
    l1, l2 = ROBOTS["d2r2"].link_lengths
    tool = plant.GetFrameByName("tool")
    for phi in np.linspace(0, 2 * math.pi, 37):
        x, y = 0.4 + 0.1 * math.cos(phi), 0.1 * math.sin(phi)
        c2 = (x * x + y * y - l1 * l1 - l2 * l2) / (2 * l1 * l2)
        assert abs(c2) < 0.9  # well away from the singularities q2 = 0, pi
        q2 = math.acos(c2)
        q1 = math.atan2(y, x) - math.atan2(l2 * math.sin(q2), l1 + l2 * c2)
        plant.SetPositions(ctx, [q1, q2])
        np.testing.assert_allclose(tool.CalcPoseInWorld(ctx).translation()[:2], [x, y], atol=1e-12)


def test_set_d2r2_theta_roundtrip_and_errors():
    rng = np.random.default_rng(7)
    for load in ("none", "max"):
        plant = make_plant("d2r2", load)
        ctx = plant.CreateDefaultContext()
        lo, hi = np.array(D2R2_THETA_UNLOADED), np.array(D2R2_THETA_LOADED)
        for _ in range(5):
            theta = lo + rng.random(3) * (hi - lo)
            set_d2r2_theta(plant, ctx, theta)
            np.testing.assert_allclose(d2r2_theta_from_plant(plant, ctx), theta, rtol=1e-12)
            # the realised bodies satisfy eq. 14 and give JS eq. 3 at q2 = pi/2
            plant.SetPositions(ctx, [0.3, math.pi / 2])
            M = plant.CalcMassMatrix(ctx)
            np.testing.assert_allclose(M, [[theta[0] + theta[1], theta[1]], [theta[1], theta[1]]], rtol=1e-12)
        with pytest.raises(RobustDrakeError, match="not physically realisable"):
            set_d2r2_theta(plant, ctx, (0.1, 0.01, 0.05))  # theta3^2 > theta1 theta2
        with pytest.raises(RobustDrakeError):
            set_d2r2_theta(plant, ctx, (0.7, -0.01, 0.0))


# ----------------------------------------------------------------------------- other arms


def test_imi_scara_inside_published_ellipsoid(plants):
    from robust_drake.regressor import IMI_P, IMI_THETA0, imi_theta_from_plant

    plant = plants[("imi_scara", "none")]
    th = imi_theta_from_plant(plant, plant.CreateDefaultContext())
    d = th - IMI_THETA0[:4]
    # inside the projection of E(P, theta0) on the inertial coordinates
    assert d @ np.linalg.solve(IMI_P[:4, :4], d) < 1.0
    # entries that are physically realisable are kept close (in the ellipsoid's own metric)
    assert th[3] > 0  # Gamma2z > 0 although theta0 prints -0.09
    assert np.linalg.eigvalsh(IMI_P).min() > 0


def test_siciliano_matches_textbook(plants):
    """Sciavicco-Siciliano B(q), g(q) with motors; Drake's reflected inertia is diagonal, so
    b12 lacks kr2 Im2 (documented)."""
    plant = plants[("siciliano_2link", "none")]
    ctx = plant.CreateDefaultContext()
    a1 = 1.0
    l1 = l2 = 0.5
    ml, Il, mm, Im, kr = 50.0, 10.0, 5.0, 0.01, 100.0
    rng = np.random.default_rng(1)
    for q in rng.uniform(-math.pi, math.pi, (5, 2)):
        c2 = math.cos(q[1])
        b11 = Il + ml * l1**2 + kr**2 * Im + Il + ml * (a1**2 + l2**2 + 2 * a1 * l2 * c2) + Im + mm * a1**2
        b12 = Il + ml * (l2**2 + a1 * l2 * c2) + kr * Im
        b22 = Il + ml * l2**2 + kr**2 * Im
        plant.SetPositions(ctx, q)
        B = plant.CalcMassMatrix(ctx)
        np.testing.assert_allclose([B[0, 0], B[1, 1]], [b11, b22], rtol=1e-12)
        assert B[0, 1] == pytest.approx(b12 - kr * Im, rel=1e-12)
        c1, c12 = math.cos(q[0]), math.cos(q[0] + q[1])
        g1 = (ml * l1 + mm * a1 + ml * a1) * G * c1 + ml * l2 * G * c12
        g2 = ml * l2 * G * c12
        # Drake's generalized gravity force is -g(q) of the textbook's B qdd + C qd + g = tau
        np.testing.assert_allclose(-plant.CalcGravityGeneralizedForces(ctx), [g1, g2], rtol=1e-9)


def test_dfki_c1_matches_lab_model(plants):
    """The lab's M and G (data README) with dfki_model_1.0.yml, except M12's -gr Ir term."""
    import yaml

    import pathlib

    yml = pathlib.Path(__file__).resolve().parents[1] / "../shared/data/dfki_double_pendulum/design_C1/dfki_model_1.0.yml"
    if not yml.is_file():
        pytest.skip("lab data folder not present")
    p = yaml.safe_load(yml.read_text())
    plant = plants[("dfki_double_pendulum_c1", "none")]
    ctx = plant.CreateDefaultContext()
    gr2Ir = p["gr"] ** 2 * p["Ir"]
    rng = np.random.default_rng(2)
    for q in rng.uniform(-math.pi, math.pi, (5, 2)):
        c2 = math.cos(q[1])
        M11 = p["I1"] + p["I2"] + p["l1"] ** 2 * p["m2"] + 2 * p["l1"] * p["m2"] * p["r2"] * c2 + gr2Ir + p["Ir"]
        M12 = p["I2"] + p["l1"] * p["m2"] * p["r2"] * c2 - p["gr"] * p["Ir"]
        M22 = p["I2"] + gr2Ir
        plant.SetPositions(ctx, q)
        M = plant.CalcMassMatrix(ctx)
        np.testing.assert_allclose([M[0, 0], M[1, 1]], [M11, M22], rtol=1e-12)
        assert M[0, 1] == pytest.approx(M12 + p["gr"] * p["Ir"], rel=1e-12)
        s1, s12 = math.sin(q[0]), math.sin(q[0] + q[1])
        Gl = [-p["g"] * p["m1"] * p["r1"] * s1 - p["g"] * p["m2"] * (p["l1"] * s1 + p["r2"] * s12),
              -p["g"] * p["m2"] * p["r2"] * s12]
        np.testing.assert_allclose(plant.CalcGravityGeneralizedForces(ctx), Gl, rtol=1e-9, atol=1e-12)
    # q = 0 hangs straight down: the tool is below joint 1 by l1 + l2
    plant.SetPositions(ctx, [0.0, 0.0])
    p_tool = plant.GetFrameByName("tool").CalcPoseInWorld(ctx).translation()
    np.testing.assert_allclose(p_tool, [0, 0, -0.5], atol=1e-12)


def test_dfki_a0_geometry(plants):
    plant = plants[("dfki_double_pendulum_a0", "none")]
    ctx = plant.CreateDefaultContext()
    plant.SetPositions(ctx, [math.pi / 2, 0.0])  # horizontal: full lever arms
    l1, l2 = ROBOTS["dfki_double_pendulum_a0"].link_lengths
    elbow = plant.GetJointByName("joint2").frame_on_child().CalcPoseInWorld(ctx).translation()
    assert np.linalg.norm(elbow) == pytest.approx(l1, abs=1e-12) and abs(elbow[2]) < 1e-12
    # potential energy minimum at q = 0 (hanging down)
    plant.SetPositions(ctx, [0.0, 0.0])
    V0 = plant.CalcPotentialEnergy(ctx)
    for q in np.random.default_rng(0).uniform(-3, 3, (5, 2)):
        plant.SetPositions(ctx, q)
        assert plant.CalcPotentialEnergy(ctx) > V0


def test_set_d2r2_theta_on_arm_with_joint1_rotor_inertia():
    """IMI SCARA: joint-1 reflected inertia stays and counts in theta1; joint-2 rotor refused."""
    plant = make_plant("imi_scara")
    ctx = plant.CreateDefaultContext()
    theta = (4.8, 0.03, -0.04)  # theta3 < 0: centre of mass behind the elbow
    set_d2r2_theta(plant, ctx, theta)
    np.testing.assert_allclose(d2r2_theta_from_plant(plant, ctx), theta, rtol=1e-12)
    dfki = make_plant("dfki_double_pendulum_c1")
    with pytest.raises(RobustDrakeError, match="joint 2 has a reflected rotor inertia"):
        set_d2r2_theta(dfki, dfki.CreateDefaultContext(), (0.1, 0.05, 0.03))
