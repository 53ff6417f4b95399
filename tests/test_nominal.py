"""The nominal-model comparison (model_repair/nominal.py) on its own: span detection,
shift projection, and the torque_scale joint choice, without the repair pipeline."""

import numpy as np
import pytest

from robust_drake.model_repair import nominal as NM
from robust_drake.model_repair.effects import equivalent_gain_error, make_effect
from robust_drake.identification.least_squares import load_regressor

ROBOT = "dfki_double_pendulum_c1"


@pytest.fixture(scope="module")
def states():
    rng = np.random.default_rng(3)
    N = 120
    q = rng.uniform(-np.pi, np.pi, (N, 2))
    qd = rng.normal(0, 3, (N, 2))
    qdd = rng.normal(0, 20, (N, 2))
    return q, qd, qdd


def test_payload_columns_lie_in_the_rigid_body_span_and_friction_does_not(states):
    q, qd, qdd = states
    reg = load_regressor(ROBOT)
    Yb = np.asarray(reg.evaluate(q, qd, qdd), float)
    phi = make_effect("payload", robot=ROBOT).evaluate_columns(q, qd, qdd)
    d, rel = NM.span_direction(Yb, phi)
    assert rel < NM.SPAN_TOL
    # d is the base-parameter change of a 1 kg tool mass: it moves link 2's parameters only
    assert np.linalg.norm(d[:, 0]) > 0.1
    strib = make_effect("stribeck", 1).evaluate_columns(q, qd, qdd)
    _, rel_s = NM.span_direction(Yb, strib)
    assert rel_s > 1e-2


def test_shift_projection_recovers_the_coefficient():
    rng = np.random.default_rng(0)
    theta0 = np.array([0.23, 0.0, 0.059, 0.16, 0.0, 0.051, 0.0023])
    d = rng.normal(size=(7, 1))
    W = NM.shift_weights(theta0, np.zeros(7))
    delta = d[:, 0] * 0.2
    c, c2 = NM.project_shift(delta, d, W)
    assert c[0] == pytest.approx(0.2, rel=1e-12) and c2 == pytest.approx(0.0, abs=1e-12)
    # a shift along another direction is not explained: the remainder keeps most of the chi^2
    other = rng.normal(size=7)
    other -= d[:, 0] * (d[:, 0] @ (W * other)) / (d[:, 0] @ (W * d[:, 0]))
    _, c2o = NM.project_shift(other, d, W)
    assert c2o == pytest.approx(NM.chi2(other, W), rel=1e-9)


def test_shift_weights_floor_and_standard_errors():
    theta0 = np.array([1.0, 0.0, -0.5])
    W = NM.shift_weights(theta0, np.array([0.0, 0.0, np.inf]), sigma_rel=0.1)
    assert W[0] == pytest.approx(1 / 0.1**2)
    assert W[1] == pytest.approx(1 / (0.1 * NM.FLOOR) ** 2)  # floored scale
    assert W[2] == pytest.approx(1 / (0.1 * 0.5) ** 2)  # an infinite se counts as unknown (0)
    W2 = NM.shift_weights(theta0, np.array([0.1, 0.0, 0.0]), sigma_rel=0.1)
    assert W2[0] < W[0]


@pytest.mark.parametrize("e_true", [-0.2, 0.15])
def test_torque_scale_joint_is_chosen_against_the_urdf(e_true):
    theta0 = np.array([0.23, 0.0, 0.059, 0.16, 0.0, 0.051, 0.0023])
    se = np.full(7, 1e-4)
    # truth: gain (1 + e_true) on joint 1. A free fit may report the equivalent on joint 0,
    # e0 = 1/(1+e_true) - 1, with base parameters theta0 * (1 + e0)^-1 ... see nominal.py:
    e0 = equivalent_gain_error(e_true)
    theta_fitted_on_0 = theta0 * (1.0 + e0)
    res = NM.resolve_torque_scale(theta_fitted_on_0, se, theta0, joint=0, gain_error=e0, n=2)
    assert res["swapped"] and res["joint"] == 1
    assert res["gain_error"] == pytest.approx(e_true, rel=1e-12)
    # fitted on the right joint already: kept
    res = NM.resolve_torque_scale(theta0, se, theta0, joint=1, gain_error=e_true, n=2)
    assert not res["swapped"] and res["joint"] == 1
