"""The UR5-class arm and the issue-21 battery generator (robust_drake.synthetic.arm_battery).

Truth here is computed independently of the code under test: UR's DH table gives the tool
position (standard DH forward kinematics in numpy), Drake's mass matrix / bias / gravity give
the inverse dynamics the library regressor must reproduce, and the payload / sensor offset the
generator hides are recovered from its logs with Drake's Jacobian of the tool point.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from robust_drake.description import describe
from robust_drake.models import make_plant
from robust_drake.synthetic import arm_battery as AB

#: UR5 (CB3) DH table and masses as published (UR's DH article; ur_description)
DH_D = (0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823)
DH_A = (0.0, -0.425, -0.39225, 0.0, 0.0, 0.0)
DH_ALPHA = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)
MASSES = (3.7, 8.393, 2.275, 1.219, 1.219, 0.1879)
G = 9.81


def _dh_tool(q):
    """Tool (flange) position of the standard-DH chain at joint angles q."""
    T = np.eye(4)
    for th, d, a, al in zip(q, DH_D, DH_A, DH_ALPHA):
        ct, st, ca, sa = math.cos(th), math.sin(th), math.cos(al), math.sin(al)
        T = T @ np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st],
                          [0, sa, ca, d], [0, 0, 0, 1]])
    return T[:3, 3]


def test_ur5_description_masses_kinematics_and_drive():
    d = describe("ur5")
    assert d.n == 6 and d.drive == "geared" and d.gear_ratio == pytest.approx(101.0)
    assert d.torque_limits == (150.0, 150.0, 150.0, 28.0, 28.0, 28.0)
    plant = make_plant("ur5")
    ctx = plant.CreateDefaultContext()
    masses = [plant.GetBodyByName(b).default_mass() for b in
              ("shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link", "wrist_2_link", "wrist_3_link")]
    np.testing.assert_allclose(masses, MASSES, rtol=1e-12)
    assert plant.CalcTotalMass(ctx) == pytest.approx(sum(MASSES), rel=1e-12)
    np.testing.assert_allclose(plant.GetEffortUpperLimits(), d.torque_limits)
    np.testing.assert_allclose(plant.GetVelocityUpperLimits(), math.pi, rtol=1e-9)  # 180 deg/s
    tool = plant.GetFrameByName("tool")
    for q in np.random.default_rng(3).uniform(-math.pi, math.pi, (5, 6)):
        plant.SetPositions(ctx, q)
        p = plant.CalcRelativeTransform(ctx, plant.world_frame(), tool).translation()
        np.testing.assert_allclose(p, _dh_tool(q), atol=1e-9)
    # reflected rotor inertia = rotor x ratio^2 sits on the mass matrix's diagonal
    plant.SetPositions(ctx, np.zeros(6))
    M = plant.CalcMassMatrix(ctx)
    for a in plant.GetJointActuatorIndices():
        plant.get_joint_actuator(a).SetRotorInertia(ctx, 0.0)
    M0 = plant.CalcMassMatrix(ctx)
    np.testing.assert_allclose(np.diag(M - M0), d.rotor_inertia * d.gear_ratio ** 2, rtol=1e-9)


def test_regressor_times_base_parameters_is_drakes_inverse_dynamics():
    from robust_drake.regressor import InverseDynamicsRegressor

    reg = InverseDynamicsRegressor.from_robot("ur5")
    plant = make_plant("ur5")
    ctx = plant.CreateDefaultContext()
    rng = np.random.default_rng(21)
    q, v, a = rng.uniform(-math.pi, math.pi, (20, 6)), rng.normal(0, 2, (20, 6)), rng.normal(0, 5, (20, 6))
    tau = np.empty((20, 6))
    for i in range(20):  # M(q) a + C(q, v) v - g(q), Drake's own terms
        plant.SetPositions(ctx, q[i])
        plant.SetVelocities(ctx, v[i])
        tau[i] = plant.CalcMassMatrix(ctx) @ a[i] + plant.CalcBiasTerm(ctx) - plant.CalcGravityGeneralizedForces(ctx)
    tau_r = reg.evaluate(q, v, a) @ reg.base_parameters()
    assert np.abs(tau_r - tau).max() <= 1e-9 * np.abs(tau).max()


def test_current_noise_is_proportional_to_torque_plus_floor():
    tau = np.column_stack([np.full(200_000, 40.0), np.zeros(200_000)])
    e, sigma = AB.current_noise(tau, 0.02, (0.15, 0.03), np.random.default_rng(0))
    np.testing.assert_allclose(e.std(axis=0), [0.02 * 40 + 0.15, 0.03], rtol=0.01)
    np.testing.assert_allclose(sigma[0], [0.95, 0.03])


def _residual(path, joint_names=None):
    """Log torque minus the fit plant's model (Drake inverse dynamics of the UR5 + the
    simulator's baseline friction) on the filtered log, and the per-kg torque of a point mass at
    the tool frame (J^T (a_tool - g), Drake's Jacobian)."""
    from robust_drake.identification.data import load

    d = load([path], robot="ur5", n_joints=6, quiet=True)
    plant = make_plant("ur5")
    ctx = plant.CreateDefaultContext()
    tool, W = plant.GetFrameByName("tool"), plant.world_frame()
    cfg = AB.ARM_SIM["ur5"]
    fc, fv = np.asarray(cfg["coulomb"]), np.asarray(cfg["viscous"])
    r, u = np.empty_like(d.tau), np.empty_like(d.tau)
    from pydrake.multibody.tree import JacobianWrtVariable
    for i in range(d.N):
        plant.SetPositions(ctx, d.q[i])
        plant.SetVelocities(ctx, d.qd[i])
        tau = plant.CalcMassMatrix(ctx) @ d.qdd[i] + plant.CalcBiasTerm(ctx) - plant.CalcGravityGeneralizedForces(ctx)
        r[i] = d.tau[i] - tau - fc * np.tanh(d.qd[i] / 0.01) - fv * d.qd[i]
        J = plant.CalcJacobianTranslationalVelocity(ctx, JacobianWrtVariable.kV, tool, np.zeros(3), W, W)
        Jd = plant.CalcBiasTranslationalAcceleration(ctx, JacobianWrtVariable.kV, tool, np.zeros(3), W, W)
        u[i] = J.T @ (J @ d.qdd[i] + np.ravel(Jd) + np.array([0.0, 0.0, G]))
    return r, u


@pytest.fixture(scope="module")
def setup_logs(tmp_path_factory):
    out = {}
    for case in AB.SETUP_CHANGES:
        out[case] = AB.generate("ur5", case, str(tmp_path_factory.mktemp(case)), rate_hz=100.0, duration=4.0)
    return out


def test_payload_is_in_the_validation_run_only(setup_logs):
    fits, vals, truth = setup_logs["payload_validation_only"]
    assert truth["kind"] is None and truth["setup_change"] == "payload"
    m_true = AB.ARM_SIM["ur5"]["payload"]
    for path, expected in ((fits[0], 0.0), (vals[0], m_true)):
        r, u = _residual(path)
        rows = slice(30, -30)  # away from the filter's ends
        m_hat = float(np.sum(r[rows, :3] * u[rows, :3]) / np.sum(u[rows, :3] ** 2))
        assert abs(m_hat - expected) <= 0.1 * m_true, (path, m_hat)


def test_sensor_offset_changes_between_the_runs(setup_logs):
    fits, vals, truth = setup_logs["sensor_offset_change"]
    j = truth["joint"]
    shift = truth["offset_fit"] - truth["offset_validate"]
    assert abs(shift) > 0.5  # N m: a re-zeroing the repair must see
    means = [float(np.mean(_residual(p[0])[0][30:-30, j])) for p in (fits, vals)]
    assert means[0] - means[1] == pytest.approx(shift, rel=0.1)


def test_library_case_sets_the_effect_at_the_asked_multiple_of_the_noise(tmp_path):
    fits, vals, truth = AB.library_case("ur5", "position_dependent", 3.0, joint=4, out_dir=str(tmp_path),
                                        rate_hz=100.0, duration=4.0)
    amp, h, phase = (truth["parameters"][k] for k in ("amplitude", "harmonic", "phase"))
    tr = AB._none_run("ur5", AB.SCALE_SEED, 100.0, 4.0)
    rms_effect = np.sqrt(np.mean((amp * np.sin(h * tr["q"][:, 4] + phase)) ** 2))
    noise = np.sqrt(np.mean(tr["sigma"][:, 4] ** 2))
    assert rms_effect == pytest.approx(3.0 * noise, rel=1e-6)
    assert truth["noise_rms"] == pytest.approx(noise)


@pytest.fixture(scope="module")
def cogging_repair(tmp_path_factory):
    from robust_drake.model_repair.pipeline import RepairOptions, run_repair

    fits, vals, truth = AB.generate("ur5", "cogging_10x", str(tmp_path_factory.mktemp("cog")), rate_hz=500.0,
                                    duration=6.0)
    rep = run_repair(fits, RepairOptions(robot=truth["fit_robot"], consistent=False, replay=False, plots=False),
                     validate_paths=vals)
    return rep, truth


def test_ur5_repair_is_never_worse_on_cogging(cogging_repair):
    rep, _ = cogging_repair
    # never worse = no joint's validation error above the baseline's beyond the paired block
    # test's spread (the rule the repair applies, issue 21); on main b5838a6, before issue 21, the
    # search stopped at a wrong-joint winner and this case kept nothing
    tests = rep["final"]["validate_change"]
    assert len(tests) == 6 and not any(t["worse"] for t in tests), tests


def test_ur5_repair_names_a_10x_cogging_within_10_percent(cogging_repair):
    rep, truth = cogging_repair
    m = AB.matches(rep, truth)
    assert m["effects"][0]["found"] and m["effects"][0]["rel_error"] <= 0.10
    assert not m["others"]


def test_rotor_case_removes_exactly_the_shoulders_reflected_inertia(tmp_path):
    d = describe("ur5")
    plant, stripped = make_plant("ur5"), make_plant(AB.without_rotor("ur5", 1, str(tmp_path / "nr.urdf")))
    a, b = plant.CreateDefaultContext(), stripped.CreateDefaultContext()
    dM = np.diag(plant.CalcMassMatrix(a) - stripped.CalcMassMatrix(b))
    np.testing.assert_allclose(dM, [0, d.rotor_inertia * d.gear_ratio ** 2, 0, 0, 0, 0], atol=1e-12)


def _delay_repair(tmp_path, joint):
    """Repair of the UR5 with a 12 ms command delay on ``joint`` (None: every joint), 500 Hz,
    against a copy of the URDF that declares a bus (so a delay is admissible)."""
    from robust_drake.model_repair.pipeline import RepairOptions, run_repair
    from robust_drake.synthetic.battery import described_copy

    effs = [("time_delay", joint, {"delay": 0.012})]
    fits, vals = AB._pair("ur5", "ur5", effs, effs, "ur5", str(tmp_path), "delay", 500.0, AB.DURATION, 0)
    robot = described_copy("ur5", str(tmp_path), **AB.BUS)
    return run_repair(fits, RepairOptions(robot=robot, consistent=False, replay=False, plots=False),
                      validate_paths=vals)


@pytest.mark.slow
def test_a_delay_of_every_joint_is_named_once_for_all_joints(tmp_path):
    # one command delay on all six joints: before the shared candidate was ranked beside its
    # single-joint versions (selection._shared_first) the search named time_delay on joint 1 only
    # (14.3 ms) and the other joints' delay error flagged the validation run as a changed setup
    rep = _delay_repair(tmp_path, None)
    delays = [c for c in AB.claimed(rep) if c[0] == "time_delay"]
    assert delays == [("time_delay", None, "high")], AB.claimed(rep)
    est = next(e["parameters"]["delay"] for e in rep["effects"] if e["kind"] == "time_delay")
    # +20 % here (IV estimate; least squares 12.8 ms; 0.9-1.5 ms on no-delay logs): BUILD_NOTES
    assert est == pytest.approx(0.012, rel=0.4)
    assert not rep["setup_change"]["flagged"]


@pytest.mark.slow
def test_a_delay_of_one_joint_is_not_spread_over_all_joints(tmp_path):
    rep = _delay_repair(tmp_path, 1)
    delays = [c[:2] for c in AB.claimed(rep) if c[0] == "time_delay"]
    assert delays == [("time_delay", 1)], AB.claimed(rep)
