"""Unit tests of the core pure functions: trajectories, kinematics, metrics, Spong laws,
encoder, friction, averaging estimator (no simulator)."""

import math

import numpy as np
import pytest

from robust_drake.errors import RobustDrakeError
from robust_drake.kinematics import planar_forward_kinematics, planar_inverse_kinematics, planar_jacobian
from robust_drake.metrics import error_criteria
from robust_drake.models import get_arm
from robust_drake.systems.controllers.spong import (
    d2r2_regressor_single,
    sp1_robust_input,
    sp2_robust_input,
    spong_error_terms,
)
from robust_drake.systems.friction import coulomb_viscous_force
from robust_drake.systems.sensors import D2R2_THETA_M, quantize
from robust_drake.trajectories import (
    circle_task_space,
    cubic_cpt,
    make_circle,
    make_line,
    second_order_step,
    sinusoid,
    trapezoidal_profile,
)


def _numeric_derivative(f, t, h=1e-6):
    return (f(t + h) - f(t - h)) / (2 * h)


@pytest.mark.parametrize("name", ["cpt", "step_crit", "step_under", "step_over", "sine", "circle", "line"])
def test_reference_derivatives_are_consistent(name):
    """qd and qdd of every reference equal numerical derivatives of q and qd."""
    arm = get_arm("d2r2")
    L = arm.link_lengths
    funcs = {
        "cpt": lambda t: cubic_cpt(t),
        "step_crit": lambda t: second_order_step(t, [0.3, -0.2], 8.0, 1.0),
        "step_under": lambda t: second_order_step(t, [0.3, -0.2], 8.0, 0.4),
        "step_over": lambda t: second_order_step(t, [0.3, -0.2], 8.0, 2.5),
        "sine": lambda t: sinusoid(t, [0.5, 0.2], 3.0),
        "circle": lambda t: circle_task_space(t, L),
        "line": lambda t: make_line(get_arm("siciliano_2link"))(t),
    }
    f = funcs[name]
    for t in [0.13, 0.37, 0.71, 1.43, 1.77]:
        q, qd, qdd = f(t)
        assert np.allclose(qd, _numeric_derivative(lambda s: f(s)[0], t), atol=1e-5)
        assert np.allclose(qdd, _numeric_derivative(lambda s: f(s)[1], t), atol=1e-4)


def test_cpt_endpoints():
    q0, qd0, _ = cubic_cpt(0.0)
    q1, qd1, _ = cubic_cpt(1.0)
    q2, qd2, _ = cubic_cpt(2.0)
    assert np.allclose(q0, 0) and np.allclose(q2, 0) and np.allclose(q1, math.pi / 2)
    assert np.allclose([qd0, qd1, qd2], 0)


def test_circle_is_the_circle():
    L = get_arm("d2r2").link_lengths
    t = np.linspace(0, 2, 50)
    q, _, _ = circle_task_space(t, L)
    p = planar_forward_kinematics(q, L)
    assert np.allclose(np.linalg.norm(p - [0.4, 0.0], axis=1), 0.1, atol=1e-12)


def test_unreachable_circle_is_a_clear_error():
    with pytest.raises(RobustDrakeError, match="unreachable"):
        make_circle(get_arm("d2r2"), center=(1.0, 0.0), radius=0.1)


def test_ik_inverts_fk_and_jacobian_matches():
    rng = np.random.default_rng(0)
    L = (0.3, 0.25)
    q = np.column_stack([rng.uniform(-3, 3, 20), rng.uniform(0.2, 2.8, 20)])
    q_back = planar_inverse_kinematics(planar_forward_kinematics(q, L), L)
    wrapped = np.angle(np.exp(1j * (q_back - q)))  # equal modulo 2 pi
    assert np.allclose(wrapped, 0.0, atol=1e-10)
    h = 1e-7
    for qi in q[:5]:
        J = planar_jacobian(qi, L)
        Jn = np.column_stack([(planar_forward_kinematics(qi + h * e, L) - planar_forward_kinematics(qi - h * e, L)) / (2 * h)
                              for e in np.eye(2)])
        assert np.allclose(J, Jn, atol=1e-6)


def test_trapezoid_velocity_profile():
    s, sd, sdd = trapezoidal_profile(np.linspace(0, 2, 2001), 2.0, 0.5)
    assert s[0] == 0 and abs(s[-1] - 1) < 1e-12
    assert np.all(np.diff(s) >= 0) and abs(sd.max() - 1 / 1.5) < 1e-9


def test_metrics_definitions():
    """eq. 55 sums squares on the dt grid, eq. 56 is the max, eqs. 58/59 use the tool distance."""
    t = np.linspace(0, 1, 1001)
    q_d = np.zeros((t.size, 2))
    q = np.column_stack([np.full(t.size, 0.01), np.zeros(t.size)])
    m = error_criteria(t, q, q_d, (0.3, 0.3), dt=0.01)
    assert m["maxerr1"] == pytest.approx(0.01)
    assert m["error1"] == pytest.approx(0.01 * math.sqrt(101))
    assert m["maxerr2"] == 0.0
    # joint-1 offset of 0.01 rad moves the tool (at distance 0.6 m with q2 = 0) by 2*0.6*sin(0.005)
    assert m["maxerr_task"] == pytest.approx(2 * 0.6 * math.sin(0.005), rel=1e-9)
    m_skip = error_criteria(t, q, q_d, (0.3, 0.3), skip=0.5, dt=0.01)
    assert m_skip["error1"] == pytest.approx(0.01 * math.sqrt(51))


def test_metrics_reject_nan():
    t = np.linspace(0, 1, 11)
    q = np.zeros((11, 2))
    q[3, 0] = np.nan
    with pytest.raises(RobustDrakeError):
        error_criteria(t, q, np.zeros((11, 2)))


def test_d2r2_regressor_is_the_model():
    """Y(q, qd, v, a) theta = M(q) a + C(q, qd) v with JS eqs. 2-5."""
    rng = np.random.default_rng(1)
    th = np.array([0.678, 0.033, 0.029])
    for _ in range(20):
        q, qd, v, a = rng.normal(size=(4, 2))
        c2, s2 = math.cos(q[1]), math.sin(q[1])
        M = np.array([[th[0] + th[1] + 2 * th[2] * c2, th[1] + th[2] * c2], [th[1] + th[2] * c2, th[1]]])
        h = -th[2] * s2
        C = np.array([[h * qd[1], h * (qd[0] + qd[1])], [-h * qd[0], 0.0]])
        assert np.allclose(np.asarray(d2r2_regressor_single(q, qd, v, a)) @ th, M @ a + C @ v, atol=1e-12)


def test_spong_robust_inputs():
    xi = np.array([3.0, -4.0, 0.0])
    u = sp1_robust_input(xi, 0.1, 1.0)
    assert np.allclose(u, -0.1 * xi / 5.0)  # outside the boundary layer: norm rho
    u_in = sp1_robust_input(xi * 0.1, 0.1, 1.0)
    assert np.allclose(u_in, -0.1 * xi * 0.1)  # inside: linear, continuous at ||xi|| = eps
    assert np.allclose(sp1_robust_input(xi / 5.0, 0.1, 1.0), -0.1 * xi / 5.0)
    u2 = sp2_robust_input([1.0, -0.2, 0.0], [0.05, 0.07, 0.05], [0.5, 0.5, 0.5])
    assert np.allclose(u2, [-0.05, 0.07 * 0.2 / 0.5, 0.0])


def test_spong_error_terms():
    Lam = np.array([50.0, 20.0])
    qt, r, v, a = spong_error_terms([0.1, 0.2], [1.0, 2.0], [3.0, 4.0], [0.11, 0.19], [0.5, -0.5], Lam)
    assert np.allclose(qt, [0.01, -0.01])
    assert np.allclose(r, [0.5 + 0.5, -0.5 - 0.2])
    assert np.allclose(v, [1.0 - 0.5, 2.0 + 0.2])
    assert np.allclose(a, [3.0 - 25.0, 4.0 + 10.0])


def test_encoder_quantisation():
    q = np.array([0.123456789, -0.987654321])
    qq = quantize(q, D2R2_THETA_M)
    assert np.all(qq <= q) and np.all(q - qq < D2R2_THETA_M)
    counts = qq / D2R2_THETA_M
    assert np.allclose(counts, np.round(counts), atol=1e-6)


def test_friction_is_dissipative():
    rng = np.random.default_rng(2)
    qd = rng.normal(size=(100, 2))
    F = coulomb_viscous_force(qd, [1.2, 2.3], [0.15, 0.08])
    assert np.all(np.sum(F * qd, axis=1) >= 0)  # friction power is never negative
    assert np.allclose(coulomb_viscous_force([0.0, 0.0], [1, 2], [1, 1]), 0.0)
