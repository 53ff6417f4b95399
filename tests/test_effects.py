"""Effect library: every effect's Drake block (or plant change) agrees with its regressor columns,
and both agree with the physics written out by hand from the named parameters.

Sign convention under test (effects module docstring): the block's ``generalized_force`` f_e is
added to the plant's applied force, so the motor torque the identification model predicts gains
``columns @ coef = -f_e``.
"""

import math
from types import SimpleNamespace

import numpy as np
import pytest
from pydrake.multibody.tree import MultibodyForces
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, LogVectorOutput, Sine

from robust_drake.errors import RobustDrakeError
from robust_drake.effects import (
    EFFECTS, TorqueDelayLine, equivalent_gain_error, load_plant, make_effect,
)

ROBOT = "dfki_double_pendulum_c1"
N = 2
RNG = np.random.default_rng(7)
Q = RNG.uniform(-2, 2, (5, N))
QD = RNG.uniform(-1, 1, (5, N)) * np.array([[0.05], [0.3], [1.0], [2.0], [0.01]])
TAU = RNG.uniform(-2, 2, (5, N))

# Independent physics: torque the motor must supply because of the effect (= -f_e), written from
# the named parameters, one joint j. sgn = tanh(v / 0.01) (the library's smooth sign).
sgn = lambda v, e=0.01: np.tanh(v / e)  # noqa: E731
PHYSICS = {
    "stribeck": ({"stribeck_torque": 0.07, "stribeck_velocity": 0.2},
                 lambda p, q, qd, tau: p["stribeck_torque"] * math.exp(-(qd / 0.2) ** 2) * sgn(qd)),
    "smooth_coulomb": ({"coulomb": 0.1, "transition_velocity": 0.3},
                       lambda p, q, qd, tau: 0.1 * math.tanh(qd / 0.3)),
    "asymmetric_coulomb": ({"asymmetry": 0.03},
                           lambda p, q, qd, tau: 0.03 * abs(sgn(qd, 0.02))),
    "load_dependent_friction": ({"load_coefficient": 0.12},
                                lambda p, q, qd, tau: 0.12 * abs(tau) * sgn(qd)),
    "position_dependent": ({"amplitude": 0.05, "phase": 0.7, "harmonic": 4},
                           lambda p, q, qd, tau: 0.05 * math.sin(4 * q + 0.7)),
    "torque_offset": ({"offset": -0.04}, lambda p, q, qd, tau: -0.04),
    "torque_scale": ({"gain_error": 0.15}, lambda p, q, qd, tau: -0.15 * tau),  # plant gets 1.15 tau
    "spring": ({"stiffness": 0.3}, lambda p, q, qd, tau: 0.3 * q),
}


def _eval_block(block, q, qd, tau):
    """The block's generalized_force for fixed inputs (state = [q, qd], tau)."""
    ctx = block.CreateDefaultContext()
    block.GetInputPort("state").FixValue(ctx, np.concatenate([q, qd]))
    if block.HasInputPort("tau"):
        block.GetInputPort("tau").FixValue(ctx, np.asarray(tau, float))
    return block.GetOutputPort("generalized_force").Eval(ctx)


def test_library_has_the_issue_kinds():
    required = {"stribeck", "smooth_coulomb", "asymmetric_coulomb", "load_dependent_friction",
                "position_dependent", "torque_offset", "torque_scale", "rotor_inertia", "spring",
                "time_delay", "payload"}
    assert required <= set(EFFECTS)
    for kind, cls in EFFECTS.items():
        assert cls.kind == kind
    with pytest.raises(RobustDrakeError, match="known"):
        make_effect("backlash")
    with pytest.raises(RobustDrakeError, match="shape"):
        make_effect("stribeck", 0, bogus=1.0)


@pytest.mark.parametrize("kind", sorted(PHYSICS))
@pytest.mark.parametrize("joint", [0, 1])
def test_block_equals_minus_columns_and_physics(kind, joint):
    params, phys = PHYSICS[kind]
    shape = {k: v for k, v in params.items() if k in EFFECTS[kind].default_shape}
    eff = make_effect(kind, joint, **shape)
    coef = eff.coef_from_parameters(params, N)
    blk = eff.block(N, params)
    data = SimpleNamespace(t=np.arange(len(Q)) * 0.01, q=Q, qd=QD, qdd=np.zeros_like(Q), tau=TAU)
    cols, names = eff.columns(data)
    assert cols.shape == (len(Q), N, eff.num_coef(N)) and len(names) == cols.shape[2]
    for i in range(len(Q)):
        f = _eval_block(blk, Q[i], QD[i], TAU[i])
        expected = np.zeros(N)
        expected[joint] = phys(params, Q[i, joint], QD[i, joint], TAU[i, joint])
        np.testing.assert_allclose(cols[i] @ coef, expected, atol=1e-12)
        np.testing.assert_allclose(f, -expected, atol=1e-12)
    # the fitted coefficients map back to the same named parameters
    back = eff.parameters(coef)
    for k, v in params.items():
        assert back[k] == pytest.approx(v, abs=1e-12)


def test_per_joint_effect_on_all_joints_has_separate_coefficients():
    eff = make_effect("torque_offset", None)
    assert eff.num_coef(N) == 2
    coef = eff.coef_from_parameters({"offset": [0.1, -0.2]}, N)
    f = _eval_block(eff.block(N, {"offset": [0.1, -0.2]}), Q[0], QD[0], TAU[0])
    np.testing.assert_allclose(f, [-0.1, 0.2])
    assert eff.parameters(coef)["offset"] == pytest.approx([0.1, -0.2])


def test_position_dependent_phase_form():
    eff = make_effect("position_dependent", 1, harmonic=3)
    p = eff.parameters([0.03, -0.04])  # 0.03 sin 3q - 0.04 cos 3q = 0.05 sin(3q + phi)
    assert p["amplitude"] == pytest.approx(0.05)
    q = np.linspace(-3, 3, 7)
    np.testing.assert_allclose(0.03 * np.sin(3 * q) - 0.04 * np.cos(3 * q), 0.05 * np.sin(3 * q + p["phase"]))


def _inverse_dynamics(plant, q, qd, qdd):
    ctx = plant.CreateDefaultContext()
    plant.SetPositions(ctx, q)
    plant.SetVelocities(ctx, qd)
    f = MultibodyForces(plant)
    plant.CalcForceElementsContribution(ctx, f)  # gravity
    return plant.CalcInverseDynamics(ctx, qdd, f), plant.CalcMassMatrix(ctx)


@pytest.mark.parametrize("joint", [0, 1])
def test_rotor_inertia_changes_only_the_diagonal_and_matches_columns(joint):
    Ir = 0.004
    eff = make_effect("rotor_inertia", joint)
    assert eff.block(N, {"reflected_inertia": Ir}) is None and eff.modifies_plant
    nominal = load_plant(ROBOT)
    changed = load_plant(ROBOT, [(eff, {"reflected_inertia": Ir})])
    q, qd, qdd = np.array([0.3, -0.7]), np.array([1.0, -2.0]), np.array([3.0, -5.0])
    t0, M0 = _inverse_dynamics(nominal, q, qd, qdd)
    t1, M1 = _inverse_dynamics(changed, q, qd, qdd)
    dM = np.zeros((N, N))
    dM[joint, joint] = Ir
    np.testing.assert_allclose(M1 - M0, dM, atol=1e-12)
    cols = eff.evaluate_columns(q[None], qd[None], qdd[None])[0]
    np.testing.assert_allclose(t1 - t0, cols @ eff.coef_from_parameters({"reflected_inertia": Ir}, N),
                               atol=1e-12)


def test_payload_columns_match_welded_mass_and_statics():
    m = 0.3
    eff = make_effect("payload", robot=ROBOT)
    nominal = load_plant(ROBOT)
    loaded = load_plant(ROBOT, [(eff, {"mass": m})])
    assert loaded.CalcTotalMass(loaded.CreateDefaultContext()) == pytest.approx(
        nominal.CalcTotalMass(nominal.CreateDefaultContext()) + m)
    rng = np.random.default_rng(3)
    for _ in range(4):
        q, qd, qdd = rng.uniform(-2, 2, (3, N))
        t0, _ = _inverse_dynamics(nominal, q, qd, qdd)
        t1, _ = _inverse_dynamics(loaded, q, qd, qdd)
        cols = eff.evaluate_columns(q[None], qd[None], qdd[None])[0]
        np.testing.assert_allclose(t1 - t0, cols @ [m], atol=1e-10)
    # statics by hand: holding a point mass at the tip of a hanging 2-link arm (l1 = 0.2,
    # l2 = 0.3 m, q = 0 down) needs |tau| = m g [l1 sin q1 + l2 sin(q1+q2), l2 sin(q1+q2)]
    q = np.array([0.4, 0.9])
    cols = eff.evaluate_columns(q[None], np.zeros((1, N)), np.zeros((1, N)))[0, :, 0]
    g = 9.81
    by_hand = g * np.array([0.2 * math.sin(q[0]) + 0.3 * math.sin(q.sum()), 0.3 * math.sin(q.sum())])
    np.testing.assert_allclose(np.abs(cols), by_hand, rtol=1e-9)


def test_time_delay_line_delays_the_torque_and_columns_are_first_order():
    d, period = 0.012, 0.004
    w = np.array([3.0, 5.0])
    A = np.array([1.0, 2.0])
    eff = make_effect("time_delay")  # one delay for all joints
    b = DiagramBuilder()
    src = b.AddSystem(Sine(A, w, np.zeros(2)))
    blk = b.AddSystem(eff.block(N, {"delay": d}, sample_period=period))
    assert isinstance(blk, TorqueDelayLine)
    b.Connect(src.get_output_port(0), blk.GetInputPort("tau"))
    x = b.AddSystem(ConstantVectorSource(np.zeros(2 * N)))
    b.Connect(x.get_output_port(0), blk.GetInputPort("state"))
    log = LogVectorOutput(blk.GetOutputPort("generalized_force"), b, 0.001)
    sim = Simulator(b.Build())
    sim.AdvanceTo(1.0)
    L = log.FindLog(sim.get_context())
    t, f = L.sample_times(), L.data().T
    keep = t > 2 * d
    t, f = t[keep], f[keep]
    delayed = A * np.sin(np.outer(t - d, w)) - A * np.sin(np.outer(t, w))
    # exact delay up to linear interpolation between samples: |err| <= A (w period)^2 / 8
    assert np.abs(f - delayed).max() <= (A * (w * period) ** 2 / 8).max() + 1e-9
    # columns: d * dtau/dt = -(block) to first order in w d
    data = SimpleNamespace(t=t, q=np.zeros((len(t), N)), qd=np.zeros((len(t), N)), qdd=np.zeros((len(t), N)),
                           tau=A * np.sin(np.outer(t, w)))
    cols, _ = eff.columns(data)
    pred = cols[:, :, 0] * d
    inner = slice(2, -2)
    second_order = (A * (w * d) ** 2 / 2).max()
    assert np.abs(pred[inner] + f[inner]).max() <= second_order + 1e-3 * A.max()


def test_time_delay_columns_do_not_cross_files():
    """Concatenated files: d tau/dt must not be differenced across the jump between segments."""
    t = np.concatenate([np.arange(50) * 0.01, np.arange(50) * 0.01])
    tau = np.concatenate([np.zeros((50, N)), np.full((50, N), 5.0)])
    data = SimpleNamespace(t=t, q=np.zeros((100, N)), qd=np.zeros((100, N)), qdd=np.zeros((100, N)),
                           tau=tau, segment=np.repeat([0, 1], 50))
    cols, _ = make_effect("time_delay").columns(data)
    assert np.abs(cols).max() < 1e-9  # a jump of 5 N m in 0.01 s would give 250 N m/s


def test_torque_scale_equivalence_on_two_joints():
    # gain 0.8 on joint 1 == gain 1.25 on joint 0 up to a common factor 1.25
    assert equivalent_gain_error(-0.2) == pytest.approx(0.25)


def test_generator_plant_obeys_the_effect_physics():
    """System level: simulate the true arm with a spring on joint 1 (exact encoder, no noise);
    the recorded torque minus Drake inverse dynamics minus the baseline friction equals the
    spring torque k q_2 the motor had to supply."""
    from robust_drake.synthetic.simulated import simulate_experiment

    k = 0.4
    fc, fv = (0.02, 0.01), (0.004, 0.002)
    df, res = simulate_experiment(ROBOT, [("spring", 1, {"stiffness": k})], duration=3.0, rate_hz=500,
                                  seed=2, encoder_resolution=None, torque_noise_std=0.0, coulomb=fc,
                                  viscous=fv, return_result=True)
    t, q, qd, tau = res["t"], res["q"], res["qd"], res["tau"]
    qdd = np.gradient(qd, t, axis=0)
    plant = load_plant(ROBOT)
    inner = range(5, len(t) - 5, 7)
    r = np.array([tau[i] - _inverse_dynamics(plant, q[i], qd[i], qdd[i])[0]
                  - (np.array(fc) * np.tanh(qd[i] / 0.01) + np.array(fv) * qd[i]) for i in inner])
    spring = np.array([[0.0, k * q[i, 1]] for i in inner])
    assert np.abs(spring[:, 1]).max() > 0.1  # the spring matters in this run
    # tolerance: finite-difference acceleration error (M qdd error) and friction transitions
    np.testing.assert_allclose(r, spring, atol=0.01)
    # and the recorded CSV is canonical
    assert list(df.columns) == ["t", "q1", "q2", "tau1", "tau2"]


@pytest.mark.parametrize("kind,params", [("rotor_inertia", {"reflected_inertia": 0.004}),
                                         ("payload", {"mass": 0.3})])
def test_apply_to_context_equals_apply_to_plant(kind, params):
    """The post-Finalize route (plant context) gives the same dynamics as the pre-Finalize one."""
    eff = make_effect(kind, 1 if kind == "rotor_inertia" else None,
                      **({"robot": ROBOT} if kind == "payload" else {}))
    pre = load_plant(ROBOT, [(eff, params)])
    post = load_plant(ROBOT)
    ctx = post.CreateDefaultContext()
    eff.apply_to_context(post, ctx, params)
    q, qd, qdd = np.array([0.5, -1.1]), np.array([0.7, 1.9]), np.array([-2.0, 4.0])
    t_pre, M_pre = _inverse_dynamics(pre, q, qd, qdd)
    post.SetPositions(ctx, q)
    post.SetVelocities(ctx, qd)
    f = MultibodyForces(post)
    post.CalcForceElementsContribution(ctx, f)
    np.testing.assert_allclose(post.CalcInverseDynamics(ctx, qdd, f), t_pre, atol=1e-12)
    np.testing.assert_allclose(post.CalcMassMatrix(ctx), M_pre, atol=1e-12)


def test_effect_blocks_in_the_closed_loop_builder():
    """effect_hooks plugs effects into diagram.ClosedLoopConfig: a PD loop holding the
    hanging arm against a 0.3 N m torque offset on joint 1 settles where its command equals the
    gravity torque at the reached posture plus the offset (static balance u + f_e = g(q))."""
    from robust_drake.diagram import ClosedLoopConfig, simulate
    from robust_drake.effects import effect_hooks

    c = 0.3
    hooks = effect_hooks([(make_effect("torque_offset", 1), {"offset": c})])
    cfg = ClosedLoopConfig(robot=ROBOT, controller="pd", controller_params={"K": [1.0, 0.5], "Lambda": [10, 10]},
                           trajectory="sine", trajectory_params={"amplitude": [0.0, 0.0]}, rate=500.0,
                           duration=3.0, initial_q=[0.2, 0.2], **hooks)
    r = simulate(cfg)
    q_end, u_end = r.q[-1], r.u[-1]
    g_end, _ = _inverse_dynamics(load_plant(ROBOT), q_end, np.zeros(N), np.zeros(N))
    assert abs(q_end[1]) > 0.01  # the offset does push the arm away from the set point
    # 3 s of a lightly damped PD: not fully settled (measured 5 mN m left); 0.01 << c = 0.3
    np.testing.assert_allclose(u_end - g_end, [0.0, c], atol=0.01)


def _q_path(t):
    """A joint-0 path with large and small reversals (rad), and its velocity."""
    q = 0.3 * np.sin(2 * np.pi * t) + 0.02 * np.sin(2 * np.pi * 7 * t)
    qd = 0.6 * np.pi * np.cos(2 * np.pi * t) + 0.28 * np.pi * np.cos(2 * np.pi * 7 * t)
    return q, qd


@pytest.mark.parametrize("joint", [0, 1])
def test_presliding_friction_block_equals_minus_columns(joint):
    """Dahl presliding friction: the block (continuous state z, dz/dt = (qd - |qd| z)/x0) driven
    by a known motion outputs -F_d z, and the columns integrated on the sampled path give the
    same z (exact per monotone step, so they agree up to the sampling of the reversals)."""
    from pydrake.systems.primitives import VectorLogSink
    from pydrake.trajectories import PiecewisePolynomial
    from pydrake.systems.primitives import TrajectorySource

    Fd, x0 = 0.1, 0.01
    params = {"presliding_torque": Fd, "presliding_displacement": x0}
    eff = make_effect("presliding_friction", joint, presliding_displacement=x0)
    t = np.arange(0.0, 2.0 + 1e-9, 5e-4)
    q, qd = _q_path(t)
    X = np.zeros((2 * N, len(t)))
    X[joint], X[N + joint] = q, qd
    builder = DiagramBuilder()
    src = builder.AddSystem(TrajectorySource(PiecewisePolynomial.CubicShapePreserving(t, X, True)))
    blk = builder.AddSystem(eff.block(N, params))
    builder.Connect(src.get_output_port(), blk.GetInputPort("state"))
    log = builder.AddSystem(VectorLogSink(N, publish_period=0.01))
    builder.Connect(blk.GetOutputPort("generalized_force"), log.get_input_port())
    sim = Simulator(builder.Build())
    sim.get_mutable_integrator().set_target_accuracy(1e-7)
    sim.AdvanceTo(2.0)
    lg = log.FindLog(sim.get_context())
    tl, f = lg.sample_times(), lg.data()
    cols, names = eff.columns(SimpleNamespace(t=t, q=X[:N].T, qd=X[N:].T, qdd=None, tau=None))
    assert names == [f"presliding_friction:presliding_torque{joint + 1}"]
    coef = eff.coef_from_parameters(params, N)
    model = np.array([np.interp(tl, t, (cols @ coef)[:, i]) for i in range(N)])
    np.testing.assert_allclose(f, -model, atol=2e-3 * Fd)
    other = 1 - joint
    assert np.all(f[other] == 0.0) and np.all(cols[:, other] == 0.0)
    # physics: |z| <= 1; after a long run in one direction the friction opposes the motion at
    # full level F_d; the state lags sign(qd) after a reversal (hysteresis, not a switch)
    z = cols[:, joint, 0]
    assert np.all(np.abs(z) <= 1.0 + 1e-12)
    rise = np.argmin(np.abs(t - 0.12))  # qd > 0 on [0, 0.12] s: 0.2 rad = 20 x0 of rise
    assert np.all(qd[:rise] > 0) and z[rise] == pytest.approx(1.0, abs=1e-6)
    k = np.nonzero(np.diff(np.sign(qd)) != 0)[0][0]  # first reversal (+ -> -)
    assert qd[k] > 0 > qd[k + 1]
    assert z[k + 2] > 0.9  # just after the reversal the friction still points the old way
    back = np.nonzero(q[k] - q[k + 1:] > 3 * x0)[0][0] + k + 1  # 3 x0 back: settled
    assert z[back] < -0.85
    assert eff.parameters(coef)["presliding_torque"] == pytest.approx(Fd)


def test_presliding_friction_is_rate_independent_and_resets_per_file():
    """Dahl's state is a function of the displacement history, not of time: the same path run
    twice as fast gives the same z at the same positions; the columns restart (z = 0) at every
    file boundary instead of integrating across the jump between concatenated files."""
    eff = make_effect("presliding_friction", 0, presliding_displacement=0.02)
    t = np.linspace(0.0, 2.0, 4001)
    q, _ = _q_path(t)
    slow = eff.columns(SimpleNamespace(t=t, q=np.c_[q, q], qd=None, qdd=None, tau=None))[0][:, 0, 0]
    fast = eff.columns(SimpleNamespace(t=t / 2, q=np.c_[q, q], qd=None, qdd=None, tau=None))[0][:, 0, 0]
    np.testing.assert_array_equal(slow, fast)
    qq = np.r_[q, q][:, None] * np.ones((1, N))
    seg = np.r_[np.zeros(len(q), int), np.ones(len(q), int)]
    two = eff.columns(SimpleNamespace(t=np.r_[t, t + 3], q=qq, qd=None, qdd=None, tau=None, segment=seg))[0]
    np.testing.assert_array_equal(two[:len(q), 0, 0], two[len(q):, 0, 0])
    assert two[len(q), 0, 0] == 0.0
