"""The closed loop's C++ blocks (issue 14, speed of the 2500 Hz loop) against their Python references.

Each block that Drake now evaluates in C++ (friction and encoder as ``SymbolicVectorSystem``, the
linear velocity estimators as ``LinearSystem``, the reference as a ``TrajectorySource``) must give
what the Python LeafSystem it replaces gives, on random inputs and along random trajectories; the
SP1/SP2 per-tick law (straight-line code) must give what :func:`spong_law` gives; and every block
must still be a named subsystem of the diagram that a user can swap.
"""

import numpy as np
import pytest
from pydrake.systems.framework import LeafSystem

from robust_drake.diagram import ClosedLoop, ClosedLoopConfig, _arm_for, build_closed_loop
from robust_drake.errors import RobustDrakeError
from robust_drake.registry import BuildContext, make_block
from robust_drake.systems.friction import CompiledCoulombViscousFriction, CoulombViscousFriction
from robust_drake.systems.linear_observer import LinearObserver
from robust_drake.systems.observers import AveragingVelocityObserver, DiscreteObserver
from robust_drake.systems.sampled_reference import SampledReference
from robust_drake.systems.sensors import D2R2_THETA_M, CompiledQuantizingEncoder, QuantizingEncoder
from robust_drake.systems.sigmoid_friction import (
    PANDA_PHI1, PANDA_PHI2, PANDA_PHI3, CompiledSigmoidFriction, SigmoidFriction)
from robust_drake.trajectories import ReferenceTrajectory, make_reference

T = 1.0 / 2500.0


def _eval(block, x, port=0):
    ctx = block.CreateDefaultContext()
    block.get_input_port(0).FixValue(ctx, np.asarray(x, float))
    return np.array(block.get_output_port(port).Eval(ctx))


def _states(rng, n, count=300):
    """Random plant states [q, v] at several scales, with exact zeros and negative zeros in v."""
    X = rng.normal(size=(count, 2 * n)) * rng.choice([1e-6, 1e-2, 1.0, 30.0], size=(count, 1))
    X[::7, n] = 0.0
    X[1::7, n] = -0.0
    return X


@pytest.mark.parametrize("v_eps", [None, 0.01, 0.05])
def test_cpp_coulomb_viscous_friction_equals_the_python_block(v_eps):
    rng = np.random.default_rng(0)
    c, b = [1.2, 2.3], [0.15, 0.08]
    py, cpp = CoulombViscousFriction(2, c, b, v_eps), CompiledCoulombViscousFriction(2, c, b, v_eps)
    for x in _states(rng, 2):
        np.testing.assert_allclose(_eval(cpp, x), _eval(py, x), rtol=1e-12, atol=1e-12)
    # a friction law, not a copy of the input: opposes the velocity
    assert _eval(cpp, [0.0, 0.0, 1.0, -1.0]) @ np.array([1.0, -1.0]) < 0


def test_cpp_friction_keeps_the_python_checks():
    with pytest.raises(RobustDrakeError, match="non-negative"):
        CompiledCoulombViscousFriction(2, (-0.1, 0.2), (0.1, 0.1))
    CompiledCoulombViscousFriction(2, (-0.1, 0.2), (0.1, 0.1), 0.05, nonnegative=False)


def test_cpp_sigmoid_friction_equals_the_python_block():
    rng = np.random.default_rng(1)
    py = SigmoidFriction(7, PANDA_PHI1, PANDA_PHI2, PANDA_PHI3)
    cpp = CompiledSigmoidFriction(7, PANDA_PHI1, PANDA_PHI2, PANDA_PHI3)
    for x in _states(rng, 7, 100):
        np.testing.assert_allclose(_eval(cpp, x), _eval(py, x), rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("theta_m", [D2R2_THETA_M, 2 * np.pi / 2 ** 20, None])
def test_cpp_encoder_equals_the_python_block_also_on_count_edges(theta_m):
    rng = np.random.default_rng(2)
    py, cpp = QuantizingEncoder(2, theta_m), CompiledQuantizingEncoder(2, theta_m)
    X = _states(rng, 2)
    if theta_m is not None:  # positions exactly on, and one ulp around, a count boundary
        k = rng.integers(-300000, 300000, size=(60, 2)) * theta_m
        X[:60, :2] = k
        X[60:120, :2] = np.nextafter(k, -np.inf)
        X[120:180, :2] = np.nextafter(k, np.inf)
    for x in X:
        out = _eval(cpp, x)
        assert np.array_equal(out, _eval(py, x))
        ulp = 4 * np.spacing(np.abs(x[:2]))  # theta_m * floor(q / theta_m) rounds, within an ulp or two of q
        assert np.all(out <= x[:2] + ulp) and (theta_m is None or np.all(x[:2] - out < theta_m + ulp))


# ------------------------------------------------------------------ linear estimators
def _step_pair(py, cpp, q_seq, xd_seq):
    """Run the Python observer and its LinearObserver side by side through (q_k, x_d_k); return the
    largest |difference| of v, v_error and v_sampled over the run and the largest |v|."""
    n = py.n
    cp, cc = py.CreateDefaultContext(), cpp.CreateDefaultContext()
    py.set_initial(cp, q_seq[0], xd_seq[0][:n], xd_seq[0][n:2 * n])
    cpp.set_initial(cc, q_seq[0], xd_seq[0][:n], xd_seq[0][n:2 * n])
    worst, scale = 0.0, 0.0
    for q, xd in zip(q_seq, xd_seq):
        for sys_, ctx in ((py, cp), (cpp, cc)):
            sys_.GetInputPort("q").FixValue(ctx, q)
            sys_.GetInputPort("x_d").FixValue(ctx, xd)
        for name in ("v", "v_error", "v_sampled"):
            a, b = py.GetOutputPort(name).Eval(cp), cpp.GetOutputPort(name).Eval(cc)
            worst, scale = max(worst, np.abs(a - b).max()), max(scale, np.abs(a).max())
        cp.SetDiscreteState(py.EvalUniquePeriodicDiscreteUpdate(cp))
        cc.SetDiscreteState(cpp.EvalUniquePeriodicDiscreteUpdate(cc))
    return worst, scale


def _random_trajectory(rng, n, K=400):
    t = np.arange(K) * T
    w = rng.uniform(1.0, 10.0, size=n)
    q = np.sin(np.outer(t, w)) + np.cumsum(rng.normal(scale=1e-4, size=(K, n)), axis=0)
    q = D2R2_THETA_M * np.floor(q / D2R2_THETA_M)  # encoder readings
    xd = np.hstack([np.sin(np.outer(t, w)), np.cos(np.outer(t, w)) * w, -np.sin(np.outer(t, w)) * w * w])
    return q, xd


def _observers(n):
    from robust_drake.systems.estimators import (
        Averaging65Observer, Averaging67Observer, EulerVelocityObserver, FilteredDerivativeObserver)
    from robust_drake.systems.kalman_observer import KalmanVelocityObserver

    return {"averaging": lambda: AveragingVelocityObserver(n, T, 3),
            "averaging5": lambda: AveragingVelocityObserver(n, T, 5),
            "euler": lambda: EulerVelocityObserver(n, T), "filtered": lambda: FilteredDerivativeObserver(n, T, 0.6),
            "averaging67": lambda: Averaging67Observer(n, T, 3), "averaging65": lambda: Averaging65Observer(n, T, 4),
            "kalman": lambda: KalmanVelocityObserver(n, T)}


@pytest.mark.parametrize("kind", list(_observers(2)))
@pytest.mark.parametrize("n", [2, 7])
def test_linear_observer_equals_the_python_observer_along_a_trajectory(kind, n):
    """v, v_error and the held v_sampled agree to 1e-12 of the estimate's size over 400 ticks
    (the matrices sum in another order than the Python law: rounding only)."""
    rng = np.random.default_rng(3)
    q, xd = _random_trajectory(rng, n)
    py = _observers(n)[kind]()
    cpp = LinearObserver(_observers(n)[kind]())
    worst, scale = _step_pair(py, cpp, q, xd)
    assert scale > 1.0  # the run does estimate velocities
    assert worst <= 1e-12 * scale, (worst, scale)


class _SquareObserver(DiscreteObserver):
    """A nonlinear law (v = q^2 / T): must be refused by LinearObserver."""

    def __init__(self):
        super().__init__(1, T, history_size=1)

    def estimate(self, h, q, q_d, qd_d, t):
        return q * q / T, q - q_d

    def advance(self, h, q, q_d, qd_d, v, v_error, t):
        return np.asarray(q, float)


def test_linear_observer_refuses_a_nonlinear_law():
    with pytest.raises(RobustDrakeError, match="not linear"):
        LinearObserver(_SquareObserver())


# ------------------------------------------------------------------ reference
@pytest.mark.parametrize("trajectory", ["cpt", "sine", "circle"])
def test_sampled_reference_equals_the_python_reference_at_every_tick(trajectory):
    ref = make_reference(_arm_for("d2r2", 2), trajectory)
    py, cpp = ReferenceTrajectory(ref, T), SampledReference(ref, T)
    py.tabulate(0.5)
    cpp.tabulate(0.5)
    cp, cc = py.CreateDefaultContext(), cpp.CreateDefaultContext()
    for k in range(0, int(0.5 / T) + 1):
        cp.SetTime(k * T)
        cc.SetTime(k * T)
        assert np.array_equal(py.get_output_port(0).Eval(cp), cpp.get_output_port(0).Eval(cc)), k
    cc.SetTime(0.3 * T + 7 * T)  # between ticks: the nearest tick's row
    cp.SetTime(7 * T)
    assert np.array_equal(cpp.get_output_port(0).Eval(cc), py.get_output_port(0).Eval(cp))


# ------------------------------------------------------------------ SP1 / SP2 per-tick path
def _ctx(robot="d2r2"):
    cfg = ClosedLoopConfig(robot=robot, trajectory="cpt")
    return BuildContext(robot=robot, arm=_arm_for(robot, 2), load="none", n=2, period=T, config=cfg)


@pytest.mark.parametrize("name", ["sp1", "sp2", "sp1_robust_friction", "sp2_robust_friction", "subclass"])
def test_per_tick_update_equals_spong_law(name):
    """The discrete update (ports read as lists, compiled straight-line law) writes the torque of
    spong_law (error terms, Y, Y^T r, robust input, eq. 12) for random inputs inside and outside the
    boundary layer, and a feedforward term is added on top."""
    from robust_drake.systems.controllers import spong

    if name == "subclass":
        class Cubic(spong.SpongSP1Controller):
            def robust_input(self, xi):
                return [-0.01 * x ** 3 for x in xi]
        base = spong.make_sp1(_ctx())
        c = Cubic(2, T, base.regressor, base.theta0, base.rho, base.epsilon, base.K, base.Lambda,
                  scalar_fast_path=True)
    else:
        c = make_block("controller", name, _ctx(), {})
        if name in ("sp1", "sp2"):  # the closed loop's block: four ports gathered by a C++ Multiplexer
            assert isinstance(c, spong.FusedInputController) and c.law.num_input_ports() == 5
    assert c.scalar_fast_path
    rng = np.random.default_rng(4)
    ctx = c.CreateDefaultContext()
    for scale in (1e-3, 1.0, 30.0):
        for _ in range(10):
            x_d, q, v, ve = rng.normal(size=6) * scale, *(rng.normal(size=(3, 2)) * scale)
            for port, val in (("x_d", x_d), ("q", q), ("v", v), ("v_error", ve)):
                c.GetInputPort(port).FixValue(ctx, val)
            got = c.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector(0).CopyToVector()
            want = spong.spong_law(c.regressor, lambda xi: np.asarray(c.robust_input(list(xi))), c.theta0,
                                   c.K, c.Lambda, x_d[:2], x_d[2:4], x_d[4:], q, v, ve)
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * max(1.0, np.abs(want).max()))
    for port, val in (("x_d", np.full(6, 0.1)), ("q", [0.2, 0.3]), ("v", [0.1, 0.1]), ("v_error", [0.0, 0.1])):
        c.GetInputPort(port).FixValue(ctx, val)
    got = c.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector(0).CopyToVector()
    c.add_feedforward(lambda q, v: np.array([1.5, -2.0]))
    c.GetInputPort("q").FixValue(ctx, [0.2, 0.3])  # a new input value: the cached update is recomputed
    got_ff = c.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector(0).CopyToVector()
    np.testing.assert_allclose(got_ff - got, [1.5, -2.0], atol=1e-12)


# ------------------------------------------------------------------ the diagram
def test_every_block_is_a_named_replaceable_subsystem():
    """The C++ blocks are separate, named subsystems; swapping in the Python references (by
    subclass attribute or ``observer_params={"python": True}``) gives the same closed loop."""
    cfg = dict(robot="d2r2", controller="sp1", trajectory="cpt", duration=0.2)
    cl = build_closed_loop(ClosedLoopConfig(**cfg))
    cl._finish()
    names = {s.get_name(): s for s in cl.diagram.GetSystems()}
    for name in ("reference", "encoder", "observer", "controller", "saturation", "plant_friction", "logger"):
        assert name in names, name
    assert isinstance(names["observer"], LinearObserver) and isinstance(names["encoder"], CompiledQuantizingEncoder)
    assert isinstance(names["plant_friction"], CompiledCoulombViscousFriction)
    assert isinstance(names["reference"], SampledReference)

    class PythonBlocks(ClosedLoop):
        reference_block = ReferenceTrajectory
        encoder_block = QuantizingEncoder
        friction_block = CoulombViscousFriction

    old = PythonBlocks(ClosedLoopConfig(observer_params={"python": True}, **cfg))
    old._finish()
    old_names = {s.get_name(): s for s in old.diagram.GetSystems()}
    assert all(isinstance(old_names[k], LeafSystem) for k in ("reference", "encoder", "observer", "plant_friction"))
    a, b = cl.simulate(), old.simulate()
    assert a.t.shape == b.t.shape and len(a.t) == 501
    # same physics; the observer's sums round differently (1e-13 rad/s), which can move one encoder count
    np.testing.assert_allclose(a.q, b.q, atol=1e-7)
    np.testing.assert_allclose(a.tau, b.tau, atol=1e-3 * np.abs(b.tau).max())


def test_logged_columns_are_the_signals_they_are_named_after():
    """The one logger's columns, split by signal: x_d is the reference at the logged instants, tau the
    saturated u, v_hat the held estimate (zero before the first tick's update, then the observer's)."""
    lim = 5.0
    cl = build_closed_loop(ClosedLoopConfig(robot="d2r2", controller="sp1", trajectory="cpt", duration=0.1,
                                            torque_limit=[lim, lim]))
    res = cl.simulate()
    q_d, qd_d, qdd_d = (np.reshape(x, (-1, 2)) for x in cl.reference(res.t))
    np.testing.assert_allclose(res.q_d, q_d, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.qd_d, qd_d, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.qdd_d, qdd_d, rtol=0, atol=1e-12)
    assert np.array_equal(res.tau, np.clip(res.u, -lim, lim)) and np.any(np.abs(res.u) > lim)
    assert res.v_hat.shape == res.q.shape and np.abs(res.v_hat - res.v).max() < 1.0


def test_held_torque_is_written_to_its_own_group_with_one_or_more_groups():
    """DiscreteController.write_u (the per-tick store of u): with u the only discrete group (the
    one-group set_value) and beside another group (by index, the other group left as it was), the
    stored torque is the one compute returned, ints included."""
    from robust_drake.systems.controllers.base import DiscreteController

    class Law(DiscreteController):
        def __init__(self, extra):
            super().__init__(2, T, name="law")
            self.extra = self.DeclareDiscreteState(np.array([7.0, 8.0, 9.0])) if extra else None

        def compute(self, t, q_d, qd_d, qdd_d, q, v, v_error):
            return [int(3), q[0] * 2.0 - v_error[1]]

    for extra in (False, True):
        law = Law(extra)
        ctx = law.CreateDefaultContext()
        for port, val in (("x_d", np.zeros(6)), ("q", [0.25, 0.0]), ("v", [0.0, 0.0]), ("v_error", [0.0, 1.5])):
            law.GetInputPort(port).FixValue(ctx, val)
        new = law.EvalUniquePeriodicDiscreteUpdate(ctx)
        assert new.num_groups() == (2 if extra else 1)
        np.testing.assert_array_equal(new.get_vector(law._u_index).CopyToVector(), [3.0, 0.5 - 1.5])
        if extra:
            np.testing.assert_array_equal(new.get_vector(law.extra).CopyToVector(), [7.0, 8.0, 9.0])


def test_inlined_d2r2_regressor_is_the_function_bit_for_bit():
    """d2r2_regressor_source (JS eq. 15 written into the SP1/SP2 per-tick law) executes to the very
    floats of d2r2_regressor_single, and the law compiled with it gives the law compiled around the call."""
    import math

    from robust_drake.systems.controllers import spong

    rng = np.random.default_rng(11)
    lines, Y = spong.d2r2_regressor_source(["q0", "q1"], ["qd0", "qd1"], ["v0", "v1"], ["a0", "a1"])
    for scale in (1e-6, 1.0, 50.0):
        for _ in range(50):
            q, qd, v, a = rng.normal(size=(4, 2)) * scale
            env = {"_cos": math.cos, "_sin": math.sin, **{f"{s}{j}": float(z[j]) for s, z in
                                                         (("q", q), ("qd", qd), ("v", v), ("a", a)) for j in range(2)}}
            exec("\n".join(lines), env)
            got = [[eval(e, env) for e in row] for row in Y]
            assert got == spong.d2r2_regressor_single(q.tolist(), qd.tolist(), v.tolist(), a.tolist())
    law = make_block("controller", "sp1", _ctx(), {}).law
    inlined = spong.compile_scalar_law(law, packed=True)
    assert "_cos(" in inlined.source and "self.regressor" not in inlined.source
    called = {"_sqrt": math.sqrt, "_copysign": math.copysign}
    exec(spong.scalar_law_source(2, 3, law._Lam, law._K, law._theta0, "sp1", packed=True), called)
    for scale in (1e-3, 1.0, 30.0):
        for _ in range(30):
            x = (rng.normal(size=12) * scale).tolist()
            assert inlined(law, x) == called["_law"](law, x)
