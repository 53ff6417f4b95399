"""Velocity estimators of Jaritz & Spong section 6 on known signals.

Each estimator sees a quantised encoder signal (theta_m = 2 pi / 655360 rad, JS eq. 70) of a
known smooth motion; its output is compared with the exact derivative by fitting
``v_hat - v = bias + (gain - 1) v - lag a`` (:func:`estimator_quality`). The expectations are
the filters' own theory (DC gain, DC group delay, quantisation noise through the filter), not
numbers read off the code.
"""

import math

import numpy as np
import pytest
import scipy.linalg

from robust_drake.systems.estimators import (
    THETA_M,
    estimator_quality,
    quantize,
    run_estimator,
)
from robust_drake.systems.kalman_observer import kalman_velocity_design, run_kalman
from robust_drake.systems.nonlinear_observer import (
    THETA0_TABLE11,
    d2r2_inertia,
    discrete_error_poles,
    nonlinear_observer_step,
    observer_eigenvalues,
)

T = 1.0 / 2500.0
SKIP = 250  # 0.1 s of start-up transient


def _signal(duration=2.0):
    """q = 0.5 sin(2 pi t) + 0.3 t on one joint (rad), its exact velocity and acceleration."""
    t = np.arange(0.0, duration, T)
    w = 2 * math.pi
    q = 0.5 * np.sin(w * t) + 0.3 * t
    v = 0.5 * w * np.cos(w * t) + 0.3
    a = -0.5 * w * w * np.sin(w * t)
    return t, q, v, a


def _quality(kind, **params):
    t, q, v, a = _signal()
    qm = quantize(q)[:, None]
    V, _ = run_estimator(kind, qm, np.zeros_like(qm), T, **params)
    return estimator_quality(V[:, 0], v, a, T, skip=SKIP)


# quantisation error of an encoder on a moving joint is ~uniform on [0, theta_m): std theta_m/sqrt(12),
# white from sample to sample, so the Euler difference carries noise theta_m / T * sqrt(2/12).
EULER_NOISE = THETA_M / T * math.sqrt(2.0 / 12.0)


def test_euler_difference_is_unbiased_half_sample_late_and_carries_the_quantisation_noise():
    m = _quality("euler")
    assert abs(m["gain"] - 1.0) < 1e-3, m
    assert abs(m["bias"]) < 2e-4, m
    assert m["lag_samples"] == pytest.approx(0.5, abs=0.02), m  # a central difference of the previous half step
    assert m["noise_rms"] == pytest.approx(EULER_NOISE, rel=0.1), (m, EULER_NOISE)


@pytest.mark.parametrize("nu", [0.3, 0.5, 0.8])
def test_filtered_derivative_trades_lag_for_noise(nu):
    """Unit-gain eq. 61: the pole at nu adds nu/(1-nu) samples of delay. The quantisation
    noise e_k (white) reaches v through (1 - nu)(1 - z^-1) / (T (1 - nu z^-1)), whose squared
    impulse response sums to 2 (1 - nu)^2 / (1 + nu), against 2 for the Euler difference."""
    m = _quality("filtered", nu=nu)
    assert abs(m["gain"] - 1.0) < 1e-3, m
    assert m["lag_samples"] == pytest.approx(0.5 + nu / (1 - nu), abs=0.05), m
    expected_noise = EULER_NOISE * (1 - nu) / math.sqrt(1 + nu)
    assert m["noise_rms"] == pytest.approx(expected_noise, rel=0.25), (m, expected_noise)


def test_literal_eq61_has_dc_gain_one_over_one_minus_nu():
    """The printed eq. 61 (no (1 - nu) factor) overestimates a ramp's slope by 1/(1 - nu):
    why the default is the normalised form (BUILD_NOTES)."""
    m = _quality("filtered", nu=0.5, normalize=False)
    assert m["gain"] == pytest.approx(2.0, rel=1e-3), m


def test_averaging67_is_unbiased_with_three_and_a_half_samples_lag():
    """Eq. 67, n = 3: denominator 1 - (z^-1 + z^-2)/3 has DC delay (1/3 + 2/3)/(1/3) = 3 samples,
    plus the Euler half sample; it is quieter than the Euler difference."""
    m = _quality("averaging67", window=3)
    assert abs(m["gain"] - 1.0) < 1e-3, m
    assert m["lag_samples"] == pytest.approx(3.5, abs=0.05), m
    assert m["noise_rms"] < 0.5 * EULER_NOISE, m


def test_velocity_error_output_estimates_the_error_derivative():
    """v_error = d/dt (q - q_d) with q_d a different motion: same gain and lag as v."""
    t, q, v, a = _signal()
    q_d = 0.2 * np.sin(3 * t)
    ve_true = v - 0.6 * np.cos(3 * t)
    ae_true = a + 1.8 * np.sin(3 * t)
    qm = quantize(q)[:, None]
    for kind, lag in (("euler", 0.5), ("filtered", 1.5), ("averaging67", 3.5)):
        _, E = run_estimator(kind, qm, q_d[:, None], T)
        m = estimator_quality(E[:, 0], ve_true, ae_true, T, skip=SKIP)
        assert abs(m["gain"] - 1) < 1e-3 and m["lag_samples"] == pytest.approx(lag, abs=0.05), (kind, m)
    _, E = run_kalman(qm, q_d[:, None], T)
    m = estimator_quality(E[:, 0], ve_true, ae_true, T, skip=SKIP)
    assert abs(m["gain"] - 1) < 1e-3, m


# ------------------------------------------------------------------------- Kalman (section 6.1)
def test_kalman_design_solves_the_riccati_equation_of_the_zoh_model():
    d = kalman_velocity_design(T, c=1000.0)
    Ad, C, Qd, R, P = d["Ad"], d["C"], d["Qd"], d["R"], d["P"]
    # ZOH of the double integrator: exp(A T) and int_0^T exp(A s) ds Gamma
    assert np.allclose(Ad, [[1.0, T], [0.0, 1.0]])
    assert np.allclose(d["Gd"].ravel(), [T * T / 2, T])
    assert R[0, 0] == pytest.approx(THETA_M ** 2 / 3)  # eq. 70
    # discrete Riccati residual of the prior covariance
    S = C @ P @ C.T + R
    resid = Ad @ P @ Ad.T - Ad @ P @ C.T @ np.linalg.solve(S, C @ P @ Ad.T) + Qd - P
    assert np.max(np.abs(resid)) < 1e-9 * np.max(np.abs(P))
    assert np.all(np.abs(d["poles"]) < 1.0)
    # same predictor gain as Drake's steady-state discrete Kalman filter
    from pydrake.systems.estimators import DiscreteTimeSteadyStateKalmanFilter

    L = DiscreteTimeSteadyStateKalmanFilter(Ad, C, Qd, R)
    assert np.allclose(L, d["L"], rtol=1e-6)


def test_kalman_filter_tracks_a_ramp_without_bias_and_is_quieter_than_euler():
    """A double-integrator model follows constant velocity with zero steady-state error (a type-2
    loop); on the test signal it lags by about a sample and removes most quantisation noise."""
    t = np.arange(0.0, 1.0, T)
    qm = quantize(0.7 * t)[:, None]
    V, _ = run_kalman(qm, np.zeros_like(qm), T)
    assert np.mean(V[SKIP:, 0]) == pytest.approx(0.7, rel=1e-3)

    t, q, v, a = _signal()
    V, _ = run_kalman(quantize(q)[:, None], np.zeros((len(t), 1)), T)
    m = estimator_quality(V[:, 0], v, a, T, skip=SKIP)
    assert abs(m["gain"] - 1.0) < 1e-3, m
    assert 0.5 < m["lag_samples"] < 3.0, m
    assert m["noise_rms"] < 0.5 * EULER_NOISE, m


def test_kalman_gain_grows_with_process_covariance():
    """More assumed acceleration noise c -> trust the encoder more -> larger gains, faster poles."""
    lo = kalman_velocity_design(T, c=10.0)
    hi = kalman_velocity_design(T, c=1e5)
    assert hi["M"][1, 0] > lo["M"][1, 0] and hi["M"][0, 0] > lo["M"][0, 0]
    assert np.max(np.abs(hi["poles"])) < np.max(np.abs(lo["poles"]))


# ------------------------------------------------------------------------- nonlinear observer (6.2)
def test_observer_gains_are_critically_damped_and_stable_after_euler_discretisation():
    l1, l2 = observer_eigenvalues(3000.0, 2.25e6)  # eq. 84
    assert l1 == pytest.approx(-1500.0) and l2 == pytest.approx(-1500.0)
    z = discrete_error_poles(T, 3000.0, 2.25e6)  # I + T (A - L G) at 2500 Hz: (1 - 1500 T) twice
    assert np.allclose(z, [0.4, 0.4], atol=1e-6)
    assert np.max(np.abs(discrete_error_poles(1 / 500.0, 3000.0, 2.25e6))) > 1.0  # too slow a rate


def _d2r2_motion(duration=1.0):
    """Exact D2R2 motion q_i = A_i sin(w_i t) and the torque producing it (nominal parameters),
    JS eqs. 1-5 in the parameters of eq. 14: tau = M(q) q'' + C(q, q') q'."""
    t = np.arange(0.0, duration, T)
    A = np.array([0.8, 0.6])
    w = np.array([2 * math.pi * 1.5, 2 * math.pi * 2.0])
    q = A * np.sin(np.outer(t, w))
    qd = A * w * np.cos(np.outer(t, w))
    qdd = -A * w * w * np.sin(np.outer(t, w))
    th = THETA0_TABLE11
    tau = np.empty_like(q)
    for k in range(len(t)):
        d11, d12, d22 = d2r2_inertia(q[k, 1], th)
        h = -th[2] * math.sin(q[k, 1])
        cq = np.array([h * qd[k, 1] * qd[k, 0] + h * (qd[k, 0] + qd[k, 1]) * qd[k, 1], -h * qd[k, 0] * qd[k, 0]])
        tau[k] = np.array([[d11, d12], [d12, d22]]) @ qdd[k] + cq
    return t, q, qd, qdd, tau


def _run_observer(q_meas, tau, use_tau):
    x = [q_meas[0, 0], q_meas[0, 1], 0.0, 0.0]
    V = np.empty_like(q_meas)
    for k in range(len(q_meas)):
        V[k] = x[2:]
        # the torque applied over [t_k, t_k+1] is the zero-order-held sample tau_k
        x = nonlinear_observer_step(x, q_meas[k], tau[k] if use_tau else None, T)
    return V


def test_nonlinear_observer_feedforward_of_the_torque_removes_most_of_the_lag():
    """Without M^-1 tau the observer is a linear filter: from eq. 85, v_k = T^2 L2 z / (z - p)^2
    times the Euler difference (1 - z^-1)/T, p = 1 - T L1 / 2 = 0.4 (the double pole), so its DC
    delay is 1/2 + 1 + 2 p / (1 - p) samples (the discrete form of L1/L2 = 2/1500 s). With the torque (exact nominal M) it predicts the acceleration and the remaining
    error comes from the ignored Coriolis terms (eq. 83) and the quantisation."""
    t, q, qd, qdd, tau = _d2r2_motion()
    qm = quantize(q)
    with_tau = _run_observer(qm, tau, True)
    without = _run_observer(qm, tau, False)
    for j in range(2):
        mw = estimator_quality(with_tau[:, j], qd[:, j], qdd[:, j], T, skip=SKIP)
        mo = estimator_quality(without[:, j], qd[:, j], qdd[:, j], T, skip=SKIP)
        assert abs(mo["gain"] - 1) < 0.02, mo
        p = 1 - T * 3000.0 / 2
        assert mo["lag_samples"] == pytest.approx(1.5 + 2 * p / (1 - p), abs=0.05), mo
        assert abs(mw["lag"]) < 0.25 * mo["lag"], (mw, mo)
        rms_w = float(np.sqrt(np.mean((with_tau[SKIP:, j] - qd[SKIP:, j]) ** 2)))
        rms_o = float(np.sqrt(np.mean((without[SKIP:, j] - qd[SKIP:, j]) ** 2)))
        assert rms_w < 0.5 * rms_o, (j, rms_w, rms_o)


# ------------------------------------------------------------------------------- JS eq. 65
@pytest.mark.parametrize("window", [1, 3, 5])
def test_eq65_secant_is_exact_on_ramps_and_midpoint_exact_on_parabolas(window):
    """Eq. 65 is a secant over N samples of q~ = q - q^d: exact for an error linear in t, and for a
    parabola the slope at the window's midpoint t_k - N T / 2 (property of the signal, not the code)."""
    t = np.arange(0.0, 0.05, T)
    q = np.column_stack([0.2 + 1.5 * t + 4.0 * t ** 2, -0.1 - 0.7 * t])
    q_d = np.column_stack([0.2 + 0.5 * t + 1.0 * t ** 2, 0.3 * t])
    v, ve = run_estimator("averaging65", q, q_d, T, window=window)
    k = np.arange(window, len(t))
    tm = t[k] - window * T / 2
    np.testing.assert_allclose(ve[k, 0], 1.0 + 2 * 3.0 * tm, rtol=0, atol=1e-8)      # d/dt (1.0 t + 3 t^2)
    np.testing.assert_allclose(ve[k, 1], np.full(len(k), -1.0), rtol=0, atol=1e-8)   # d/dt (-1.0 t)
    np.testing.assert_allclose(v[k, 0], 1.5 + 8.0 * tm, rtol=0, atol=1e-8)           # eq. 64 on q
    # Euler (window 1) lags half a sample, the N-sample secant N/2 samples: the lag grows with N
    q1 = np.column_stack([np.sin(3 * t), np.zeros_like(t)])
    assert estimator_quality(run_estimator("averaging65", q1, 0 * q1, T, window=window)[1][:, 0],
                             3 * np.cos(3 * t), -9 * np.sin(3 * t), T, skip=window)["lag_samples"] == \
        pytest.approx(window / 2, abs=0.05)


def test_eq65_observer_matches_the_pure_law_from_a_moving_start():
    """The LeafSystem's start-up history assumes rest at q0 while q^d moves at qd_d0: the first
    v_error is then -qd_d0 exactly (no start-up kick)."""
    from types import SimpleNamespace

    from robust_drake.systems.estimators import make_averaging65

    obs = make_averaging65(SimpleNamespace(n=2, period=T), window=3)
    ctx = obs.CreateDefaultContext()
    q0, qd0 = np.array([0.1, -0.2]), np.array([0.4, 1.2])
    obs.set_initial(ctx, q0, q0, qd0)
    obs.GetInputPort("q").FixValue(ctx, q0)
    obs.GetInputPort("x_d").FixValue(ctx, np.concatenate([q0, qd0, np.zeros(2)]))
    np.testing.assert_allclose(obs.GetOutputPort("v_error").Eval(ctx), -qd0, atol=1e-9)
    np.testing.assert_allclose(obs.GetOutputPort("v").Eval(ctx), 0.0, atol=1e-12)
