"""Errors in variables on synthetic data (identification/instruments.py): least squares on a
noisy regressor is attenuated, the low-pass instrument removes the bias, and the Hausman test
tells the two cases apart."""

import numpy as np
import pytest

from robust_drake.identification.data import zero_phase_lowpass
from robust_drake.identification.instruments import hausman, ls_covariance, solve_iv

DT = 0.002


def _case(noise: float, seed: int = 0, N: int = 20000):
    """tau = 2 x1 - 0.5 x2 + small torque noise; x measured with an error confined to the band
    above the instrument's (white noise band-passed to 6-12 Hz: differentiated encoder noise, or
    motion the torque does not cause), low-passed at 8 Hz (regressor) and 4 Hz (instrument).
    The IV removes what lies above the instrument band, not what lies inside it."""
    rng = np.random.default_rng(seed)
    t = np.arange(N) * DT
    x = np.column_stack([np.sin(2 * np.pi * 0.7 * t) + 0.5 * np.sin(2 * np.pi * 1.9 * t + 1),
                         np.cos(2 * np.pi * 1.3 * t) + 0.3 * np.sin(2 * np.pi * 3.1 * t)])
    theta = np.array([2.0, -0.5])
    tau = x @ theta + 0.01 * rng.standard_normal(N)
    from scipy.signal import butter, sosfiltfilt

    band = sosfiltfilt(butter(4, [6.0, 12.0], btype="band", fs=1 / DT, output="sos"),
                       rng.standard_normal((N, 2)), axis=0)
    xm = x + noise * band / band.std(axis=0)
    Y = zero_phase_lowpass(xm, DT, 8.0, 4)[:, None, :]
    Z = zero_phase_lowpass(xm, DT, 4.0, 4)[:, None, :]
    tau_f = zero_phase_lowpass(tau[:, None], DT, 8.0, 4)
    return Y, Z, tau_f, theta


def test_iv_removes_the_attenuation_of_least_squares():
    Y, Z, tau, theta = _case(noise=1.0)
    A = Y.reshape(-1, 2)
    th_ls = np.linalg.lstsq(A, tau.reshape(-1), rcond=None)[0]
    iv = solve_iv(Y, Z, tau, ["a", "b"], n_eff_factor=2 * 8.0 * DT)
    # LS shrinks towards zero; IV is within a few per cent of the truth
    assert abs(th_ls[0]) < 0.9 * abs(theta[0])
    assert iv.theta == pytest.approx(theta, rel=0.03)
    assert np.all(np.abs(iv.theta - theta) < np.abs(th_ls - theta))
    cov_ls = ls_covariance(Y, tau, th_ls, np.ones(1), 2 * 8.0 * DT)
    assert hausman(th_ls, cov_ls, iv.theta, iv.cov_homoscedastic)["significant"]


def test_hausman_does_not_fire_on_a_clean_regressor():
    Y, Z, tau, theta = _case(noise=0.0)
    A = Y.reshape(-1, 2)
    th_ls = np.linalg.lstsq(A, tau.reshape(-1), rcond=None)[0]
    iv = solve_iv(Y, Z, tau, ["a", "b"], n_eff_factor=2 * 8.0 * DT)
    cov_ls = ls_covariance(Y, tau, th_ls, np.ones(1), 2 * 8.0 * DT)
    h = hausman(th_ls, cov_ls, iv.theta, iv.cov_homoscedastic)
    assert not h["significant"], h
    assert th_ls == pytest.approx(theta, rel=1e-2) and iv.theta == pytest.approx(theta, rel=1e-2)


def test_solve_iv_rejects_mismatched_instruments():
    Y, Z, tau, _ = _case(noise=0.1, N=2000)
    with pytest.raises(ValueError):
        solve_iv(Y, Z[:-1], tau, ["a", "b"])
