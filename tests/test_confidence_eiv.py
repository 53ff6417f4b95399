"""A sound confidence set with noise in the regressor (issue 14): bias-compensated least squares
with an HC3 sandwich covariance (uncertainty.confidence.corrected_least_squares), Monte Carlo
coverage on a 2-link arm (CI's IMI SCARA regressor) with CI's acceleration and torque noise."""

import numpy as np
import pytest

from robust_drake.errors import RobustDrakeError
from robust_drake.experiments.calafiore import IMI_THETA_TRUE, exciting_trajectory
from robust_drake.identification.least_squares import solve_ls
from robust_drake.identification.model import IdentifiedModel
from robust_drake.regressor import imi_scara_regressor
from robust_drake.uncertainty.confidence import (acceleration_noise_directions, confidence_ellipsoid,
                                                 corrected_least_squares, eiv_confidence_ellipsoid,
                                                 mahalanobis_radius)
from robust_drake.uncertainty.regression import CI_BOUNDS

DRAWS, ROWS, ALPHA = 300, 100, 0.1
#: 3 binomial standard deviations of a 90 % coverage estimated from 300 draws (sqrt(.09/300) = 1.7 %)
MARGIN = 3.0 * np.sqrt(ALPHA * (1 - ALPHA) / DRAWS)


def _experiment(rng):
    """ROWS independent samples of CI's multi-sine at random times; uniform noise within CI's
    bounds on the torque and on the *measured acceleration* (which enters the regressor)."""
    q, qd, qdd = exciting_trajectory(rng.uniform(0.0, 20.0, ROWS))
    tau = imi_scara_regressor(q, qd, qdd) @ IMI_THETA_TRUE + rng.uniform(-1, 1, (ROWS, 2)) * CI_BOUNDS["tau"]
    return q, qd, qdd + rng.uniform(-1, 1, (ROWS, 2)) * CI_BOUNDS["qdd"], tau


def _model(fit):
    return IdentifiedModel(robot="imi_scara", joint_names=["j1", "j2"], base_names=list(fit.names),
                           base_values=fit.theta, base_covariance=fit.cov, coulomb=np.zeros(2), viscous=np.zeros(2))


@pytest.fixture(scope="module")
def coverage():
    rng = np.random.default_rng(7)
    var = np.asarray(CI_BOUNDS["qdd"]) ** 2 / 3.0  # variance of U(-d, d)
    hits = {"corrected": 0, "least_squares": 0}
    names = [f"t{i}" for i in range(8)]
    for _ in range(DRAWS):
        q, qd, qdd_m, tau = _experiment(rng)
        Y = imi_scara_regressor(q, qd, qdd_m)
        fit = corrected_least_squares(Y, tau, acceleration_noise_directions(imi_scara_regressor, q, qd, qdd_m), var)
        hits["corrected"] += mahalanobis_radius(*eiv_confidence_ellipsoid(fit, ALPHA), IMI_THETA_TRUE) <= 1.0
        th0, P = confidence_ellipsoid(_model(solve_ls(Y, tau, names)), ALPHA)
        hits["least_squares"] += mahalanobis_radius(th0, P, IMI_THETA_TRUE) <= 1.0
    return {k: v / DRAWS for k, v in hits.items()}


def test_corrected_set_covers_the_truth_at_its_level(coverage):
    """300 experiments of 100 rows: the 90 % corrected set holds the truth in >= 90 % - 3 sd
    (5.2 %) of them (measured 89 % here; 88.5-92 % at 50-200 rows in other seeds, see the module docstring)."""
    assert coverage["corrected"] >= 1 - ALPHA - MARGIN, coverage


def test_least_squares_set_is_not_sound_with_noise_in_the_regressor(coverage):
    """Same draws: the chi2 set of plain least squares misses the truth far more often than 10 %
    (measured 73 %): the attenuation bias, which the correction removes."""
    assert coverage["least_squares"] < 1 - ALPHA - 2 * MARGIN, coverage


def test_noise_directions_are_the_acceleration_columns():
    """B_j = dY/dqdd_j does not depend on qdd (Y affine in qdd): the same at two accelerations,
    and Y(qdd + d) = Y(qdd) + sum_j d_j B_j exactly."""
    rng = np.random.default_rng(0)
    q, qd, a = (rng.normal(size=(5, 2)) for _ in range(3))
    d = rng.normal(size=(5, 2))
    B = acceleration_noise_directions(imi_scara_regressor, q, qd, a)
    B2 = acceleration_noise_directions(imi_scara_regressor, q, qd, a + 3.0)
    assert all(np.allclose(x, y) for x, y in zip(B, B2))
    lhs = imi_scara_regressor(q, qd, a + d)
    assert np.allclose(lhs, imi_scara_regressor(q, qd, a) + sum(d[:, j, None, None] * B[j] for j in range(2)))


def test_least_squares_model_flagged_with_errors_in_variables_is_refused():
    m = IdentifiedModel(robot="x", joint_names=["j1"], base_names=["b0"], base_values=np.zeros(1),
                        base_covariance=np.eye(1), coulomb=np.zeros(1), viscous=np.zeros(1),
                        data={"errors_in_variables": {"significant": True, "statistic": 40.0, "limit": 11.3}})
    with pytest.raises(RobustDrakeError, match="errors in variables"):
        confidence_ellipsoid(m)
    m.estimator = "instrumental_variables"
    assert confidence_ellipsoid(m)[1].shape == (1, 1)
    m.estimator, m.data = "least_squares", {"errors_in_variables": {"significant": False}}
    assert confidence_ellipsoid(m)[1].shape == (1, 1)


@pytest.fixture(scope="module")
def iv_coverage():
    """IV with the excitation's reference as instruments: the arm tracks the reference with a
    deviation (the motion the torque causes), the acceleration is measured with CI's noise."""
    from robust_drake.identification.instruments import solve_iv
    from robust_drake.uncertainty.confidence import instrumental_variables

    rng = np.random.default_rng(11)
    hits = {"sandwich": 0, "solve_iv": 0, "homoscedastic": 0}
    for _ in range(DRAWS):
        q_r, qd_r, qdd_r = exciting_trajectory(rng.uniform(0.0, 20.0, ROWS))
        q, qd = q_r + 0.02 * rng.standard_normal((ROWS, 2)), qd_r + 0.05 * rng.standard_normal((ROWS, 2))
        qdd = qdd_r + 0.3 * rng.standard_normal((ROWS, 2))
        tau = imi_scara_regressor(q, qd, qdd) @ IMI_THETA_TRUE + rng.uniform(-1, 1, (ROWS, 2)) * CI_BOUNDS["tau"]
        Y = imi_scara_regressor(q, qd, qdd + rng.uniform(-1, 1, (ROWS, 2)) * CI_BOUNDS["qdd"])
        Z = imi_scara_regressor(q_r, qd_r, qdd_r)
        fit = instrumental_variables(Y, Z, tau)
        hits["sandwich"] += mahalanobis_radius(*eiv_confidence_ellipsoid(fit, ALPHA), IMI_THETA_TRUE) <= 1.0
        iv = solve_iv(Y, Z, tau, fit.names)  # independent rows: HC3 sandwich in ``cov``
        for key, cov in (("solve_iv", iv.cov), ("homoscedastic", iv.cov_homoscedastic)):
            model = _model(iv)
            model.base_covariance, model.estimator = cov, "instrumental_variables"
            th0, P = confidence_ellipsoid(model, ALPHA)
            hits[key] += mahalanobis_radius(th0, P, IMI_THETA_TRUE) <= 1.0
    return {k: v / DRAWS for k, v in hits.items()}


def test_iv_sandwich_set_covers_the_truth_without_knowing_the_noise_level(iv_coverage):
    """Same size and noise as above, no noise level given: the 90 % set of IV with an HC3 sandwich
    holds the truth in >= 90 % - 3 sd of 300 experiments (measured 91 %; ``solve_iv``'s ``cov``
    on independent rows, the same sandwich with the chi2 quantile: 89 %); IV's homoscedastic
    covariance (``cov_homoscedastic``, what the repair's IV model carried before) does not (77 %)."""
    assert iv_coverage["sandwich"] >= 1 - ALPHA - MARGIN, iv_coverage
    assert iv_coverage["solve_iv"] >= 1 - ALPHA - MARGIN, iv_coverage
    assert iv_coverage["homoscedastic"] < 1 - ALPHA - 2 * MARGIN, iv_coverage
