"""Least squares, consistency SDP, residual tests, selection and replay (no shared data)."""

import warnings

import numpy as np
import pytest

from fourier_motion import fourier_motion
from robust_drake.model_repair import residual as R
from robust_drake.identification.consistency import consistent_identification, pseudo_inertia
from robust_drake.identification.data import DataWarning, FilterSettings, IdentData
from robust_drake.effects import make_effect
from robust_drake.identification.least_squares import (
    COND_WARN, friction_columns, load_regressor, solve_ls, solve_wls,
)
from robust_drake.model_repair.selection import ColumnCache, fit_model, forward_select, predict_tau

ROBOT = "dfki_double_pendulum_c1"


@pytest.fixture(scope="module")
def reg():
    return load_regressor(ROBOT)


def _trajectory(N=4000, dt=0.004, seed=0, freeze_joint2=False):
    rng = np.random.default_rng(seed)
    t = np.arange(N) * dt
    q, qd, qdd = fourier_motion(t, rng, 0.2)
    if freeze_joint2:
        q[:, 1], qd[:, 1], qdd[:, 1] = 0.3, 0.0, 0.0
    return t, q, qd, qdd


def _data(t, q, qd, qdd, tau):
    return IdentData(t=t, q=q, qd=qd, qdd=qdd, tau=tau, dt=t[1] - t[0], robot=ROBOT,
                     filter=FilterSettings(cutoff_hz=None, order=0, derivatives="given"))


def _truth_tau(reg, q, qd, qdd, fc=(0.1, 0.05), fv=(0.01, 0.005)):
    th = reg.base_parameters()
    return reg.evaluate(q, qd, qdd) @ th + np.asarray(fc) * np.sign(qd) + np.asarray(fv) * qd, th


def test_ls_recovers_parameters_and_standard_errors_are_calibrated(reg):
    """Over 40 noise draws the estimates scatter as the reported standard errors say."""
    t, q, qd, qdd = _trajectory()
    tau0, th = _truth_tau(reg, q, qd, qdd)
    Y = np.concatenate([reg.evaluate(q, qd, qdd), friction_columns(_data(t, q, qd, qdd, tau0))[0]], axis=2)
    names = list(reg.base_names) + ["fc1", "fv1", "fc2", "fv2"]
    truth = np.concatenate([th, [0.1, 0.01, 0.05, 0.005]])
    rng = np.random.default_rng(1)
    est, ses = [], []
    for _ in range(40):
        res = solve_ls(Y, tau0 + 0.02 * rng.standard_normal(tau0.shape), names, warn=False)
        est.append(res.theta)
        ses.append(res.se)
    est, se = np.array(est), np.mean(ses, axis=0)
    ident = np.isfinite(se) & (se > 0)
    # unbiased: the mean error is within 4 standard errors of the mean
    assert np.all(np.abs(est.mean(0) - truth)[ident] < 4 * se[ident] / np.sqrt(40) + 1e-12)
    # calibrated: empirical scatter / reported se within 0.6 .. 1.6 for every parameter
    ratio = est.std(0)[ident] / se[ident]
    assert np.all((ratio > 0.6) & (ratio < 1.6)), ratio


def test_poor_excitation_names_unidentifiable_parameters(reg):
    t, q, qd, qdd = _trajectory(freeze_joint2=True)
    tau, _ = _truth_tau(reg, q, qd, qdd)
    d = _data(t, q, qd, qdd, tau)
    Y = np.concatenate([reg.evaluate(q, qd, qdd), friction_columns(d)[0]], axis=2)
    names = list(reg.base_names) + ["fc1", "fv1", "fc2", "fv2"]
    with pytest.warns(DataWarning, match="unidentifiable"):
        res = solve_ls(Y, tau, names)
    assert res.cond > COND_WARN and res.rank < len(names)
    # a frozen elbow (qd2 = qdd2 = 0) cannot reveal its friction or its rotor inertia, whose
    # columns vanish; the link-2 inertia still shows in the elbow torque through M21 qdd1
    assert set(res.unidentifiable) == {"fc2", "fv2", "Ia_joint2"}
    assert np.all(np.isinf(res.se[[names.index(u) for u in res.unidentifiable]]))
    # the torque is still reproduced (what is identifiable is fitted)
    assert np.max(res.rms) < 1e-8


def test_wls_weights_follow_noise_levels(reg):
    t, q, qd, qdd = _trajectory()
    tau, _ = _truth_tau(reg, q, qd, qdd)
    rng = np.random.default_rng(2)
    noisy = tau + rng.standard_normal(tau.shape) * np.array([0.01, 0.1])
    Y = reg.evaluate(q, qd, qdd)
    Yf = np.concatenate([Y, friction_columns(_data(t, q, qd, qdd, tau))[0]], axis=2)
    res = solve_wls(Yf, noisy, list(reg.base_names) + ["a", "b", "c", "d"], warn=False)
    assert res.weights[0] / res.weights[1] == pytest.approx(10.0, rel=0.15)


def test_pseudo_inertia_is_psd_exactly_for_physical_bodies():
    # a uniform rod (m = 1, length 0.3, about its end): physical
    m, L = 1.0, 0.3
    rod = np.array([m, m * L / 2, 0, 0, 1e-6, m * L**2 / 3, m * L**2 / 3, 0, 0, 0])
    assert np.linalg.eigvalsh(pseudo_inertia(rod)).min() >= -1e-12
    # violates the triangle inequality Izz <= Ixx + Iyy (about the COM): not physical
    bad = np.array([1.0, 0, 0, 0, 0.01, 0.01, 0.05, 0, 0, 0])
    assert np.linalg.eigvalsh(pseudo_inertia(bad)).min() < 0


def test_consistent_estimate_is_feasible_and_matches_ls_on_good_data(reg):
    t, q, qd, qdd = _trajectory(N=20000, dt=0.002)
    tau, th = _truth_tau(reg, q, qd, qdd)
    tau = tau + 0.005 * np.random.default_rng(3).standard_normal(tau.shape)
    d = _data(t, q, qd, qdd, tau)
    Y = np.concatenate([reg.evaluate(q, qd, qdd), friction_columns(d)[0]], axis=2)
    A, b = Y.reshape(-1, Y.shape[2]), tau.reshape(-1)
    res = consistent_identification(reg, ROBOT, A, b, n_extra=4)
    assert min(res.min_eig) >= -1e-8
    ls = solve_ls(Y, tau, list(reg.base_names) + ["a", "b", "c", "d"], warn=False)
    r_c = np.sqrt(np.mean((b - A @ res.theta) ** 2))
    r_l = np.sqrt(np.mean((b - A @ ls.theta) ** 2))
    assert r_c <= 1.02 * r_l  # the truth is consistent, so the constraint costs (almost) nothing
    np.testing.assert_allclose(res.theta[:len(th)], th, rtol=0.02, atol=2e-4)


def test_consistent_estimate_repairs_an_unphysical_ls_fit(reg):
    """Very noisy, short data push LS to an unphysical point; the SDP stays feasible."""
    t, q, qd, qdd = _trajectory(N=300, dt=0.004, seed=5)
    tau, _ = _truth_tau(reg, q, qd, qdd)
    tau = tau + 0.5 * np.random.default_rng(4).standard_normal(tau.shape)
    Y = reg.evaluate(q, qd, qdd)
    res = consistent_identification(reg, ROBOT, Y.reshape(-1, Y.shape[2]), tau.reshape(-1), 0)
    assert min(res.min_eig) >= -1e-8
    assert all(v >= -1e-9 for v in res.extras.values())  # reflected inertias non-negative


def test_correlation_ratio_and_whiteness_tests():
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, 5000)
    noise = rng.standard_normal(5000)
    assert R.correlation_ratio(x, noise)[0] < 0.01
    assert R.correlation_ratio(x, np.sin(3 * x) + 0.05 * noise)[0] > 0.95
    Q, p, _ = R.ljung_box(noise)
    assert p > 1e-3
    ar = np.zeros(5000)
    for k in range(1, 5000):
        ar[k] = 0.9 * ar[k - 1] + noise[k]
    Q, p, rho1 = R.ljung_box(ar)
    assert p < 1e-10 and rho1 == pytest.approx(0.9, abs=0.03)


def test_selection_finds_a_planted_offset_and_nothing_when_absent(reg):
    t, q, qd, qdd = _trajectory(N=3000)
    tau, _ = _truth_tau(reg, q, qd, qdd)
    rng = np.random.default_rng(6)
    cands = [make_effect("torque_offset", 0), make_effect("torque_offset", 1), make_effect("spring", 0),
             make_effect("spring", 1), make_effect("stribeck", 0, stribeck_velocity=0.2)]
    planted = tau + np.array([0.0, 0.07]) + 0.01 * rng.standard_normal(tau.shape)
    sel = forward_select(ColumnCache(_data(t, q, qd, qdd, planted), reg), cands)
    assert [(e.kind, e.joint) for e in sel.chosen] == [("torque_offset", 1)]
    fit, sl = fit_model(ColumnCache(_data(t, q, qd, qdd, planted), reg), sel.chosen)
    assert fit.theta[sl[0]][0] == pytest.approx(0.07, abs=0.003)
    clean = tau + 0.01 * rng.standard_normal(tau.shape)
    sel0 = forward_select(ColumnCache(_data(t, q, qd, qdd, clean), reg), cands)
    assert sel0.chosen == [] and not sel0.steps[-1].accepted


def test_implicit_prediction_of_a_torque_scale(reg):
    """Plant receives (1 + g) tau: the output-error prediction of tau is Y theta / (1 + g)."""
    t, q, qd, qdd = _trajectory(N=500)
    tau_plant, _ = _truth_tau(reg, q, qd, qdd)
    g = -0.2
    tau_meas = tau_plant.copy()
    tau_meas[:, 1] /= 1 + g
    cache = ColumnCache(_data(t, q, qd, qdd, tau_meas), reg)
    eff = make_effect("torque_scale", 1)
    Y, names, sl = cache.model([eff])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        fit = solve_ls(Y, tau_meas, names)
    assert eff.parameters(fit.theta[sl[0]])["gain_error"] == pytest.approx(g, abs=0.02)
    pred = predict_tau(cache, [eff], fit.theta)
    assert np.max(np.abs(pred - tau_meas)) < 0.02 * np.abs(tau_meas).max()


def test_replay_through_drake_plant_matches_simulated_motion():
    """Data from the simulated arm: replaying its torques through a plant with the true friction
    reproduces the motion; leaving the friction out does not."""
    from robust_drake.identification.data import load
    from robust_drake.model_repair.replay import replay
    import tempfile, os

    from robust_drake.synthetic.simulated import simulate_experiment

    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "x.csv")
        simulate_experiment(ROBOT, duration=4.0, rate_hz=250.0, seed=3, out_csv=path,
                            coulomb=(0.08, 0.05), viscous=(0.004, 0.002), torque_noise_std=0.0)
        d = load(path, robot=ROBOT)
    good = replay(ROBOT, d, [0.08, 0.05], [0.004, 0.002], horizon=0.2, max_windows=8)
    bad = replay(ROBOT, d, [0.0, 0.0], [0.0, 0.0], horizon=0.2, max_windows=8)
    assert max(good["rms_q"]) < 0.5 * max(bad["rms_q"])
    assert max(good["rms_q"]) < 5e-3
