"""The nominal-model comparison (model_repair/nominal.py) on its own: span detection,
shift projection, and the torque_scale joint choice, without the repair pipeline."""

import numpy as np
import pytest

from robust_drake.model_repair import nominal as NM
from robust_drake.effects import equivalent_gain_error, make_effect
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


def test_fixed_rigid_fit_holds_effect_coefficients_inside_their_bounds():
    """With the rigid body fixed at the URDF's, a torque_scale coefficient that the free fit puts
    outside (-0.5, 0.5) is held at the bound and the other columns refitted: the output-error
    prediction tau_hat = m / (1 + c) must not be evaluated near c = -1 (the jittered A.0 case read
    22.7 N m)."""
    from types import SimpleNamespace

    rng = np.random.default_rng(1)
    N = 400
    x, v = rng.normal(size=N), rng.normal(size=N)
    tau = np.column_stack([0.3 * x + 0.05 * v + 0.01 * rng.normal(size=N), 0.2 * rng.normal(size=N)])
    Y = np.zeros((N, 2, 3))
    Y[:, 0, 0], Y[:, 1, 0] = x, 0.5 * x          # rigid-body column, fixed at theta0 = 2
    Y[:, 0, 1] = v                                # a free (friction-like) column
    Y[:, 0, 2] = -tau[:, 0]                       # torque_scale[0]: column -tau_0
    ts = make_effect("torque_scale", 0)
    # a ColumnCache stand-in: base block = columns 0-1, the effect's block = column 2
    cache = SimpleNamespace(blocks=lambda effects: ([Y[:, :, :2], Y[:, :, 2:]], None, [slice(2, 3)]),
                            explicit_prediction=lambda effects, th, mask: Y[:, :, mask] @ th[mask],
                            data=SimpleNamespace(tau=tau))
    w = np.array([1.0, 1.0])
    rhs = tau - Y[:, :, 0] * 2.0
    free = np.linalg.lstsq(Y[:, 0, 1:], rhs[:, 0], rcond=None)[0]
    assert free[1] > 0.5  # the unconstrained fit leaves the bound (the case the rule is for)
    th = NM.fit_with_fixed_rigid(cache, [ts], np.array([2.0]), w)
    assert th[0] == 2.0 and th[2] == 0.5
    want = np.linalg.lstsq(Y[:, 0, 1:2], rhs[:, 0] - Y[:, 0, 2] * 0.5, rcond=None)[0][0]
    assert th[1] == pytest.approx(want, rel=1e-10)
    inside = NM.fit_with_fixed_rigid(cache, [ts], np.array([0.3]), w)
    assert abs(inside[2]) < 0.5  # nothing clipped when the fit is admissible


def test_warning_when_the_urdf_model_validates_better_on_every_joint():
    """The repair's verdict compares with the free baseline; when the URDF's rigid body validates
    better than the repaired model on every joint (beyond the never-worse tolerance) a warning says
    so, and not when the repaired model wins on any joint."""
    from robust_drake.model_repair.pipeline import urdf_model_validates_better

    rng = np.random.default_rng(0)
    r = rng.normal(size=(5000, 2)) * np.array([0.3, 0.12])  # repaired model's validation residual
    rms = np.sqrt(np.mean(r ** 2, axis=0))
    nominal = {"rms_validate": (0.8 * rms).tolist(), "chi2": 38.7}
    msg = urdf_model_validates_better(nominal, r, 0.01)
    assert msg and "validate better than the repaired model on every joint" in msg and "38.7" in msg
    assert urdf_model_validates_better({"rms_validate": [0.8 * rms[0], 1.2 * rms[1]], "chi2": 1.0}, r, 0.01) is None
    assert urdf_model_validates_better({"rms_validate": (0.995 * rms).tolist(), "chi2": 1.0}, r, 0.01) is None
    assert urdf_model_validates_better(None, r, 0.01) is None
