"""Confidence ellipsoid of an identified model's base parameters, in seconds at any data size.

An :class:`~robust_drake.model_repair.model.IdentifiedModel` carries the least-squares (or IV)
estimate theta_hat of the base parameters and its covariance Sigma. Asymptotically (many
independent rows, zero-mean residual independent of the regressor) theta_hat ~ N(theta, Sigma),
so

    E = {theta : (theta - theta_hat)^T Sigma^-1 (theta - theta_hat) <= chi2_{p, 1-alpha}}

contains the true theta with probability 1 - alpha. In the convention of CI eq. 10
(E(P, theta0) = {theta0 + E z : ||z|| <= 1}, E^T E = P) this is theta0 = theta_hat,
P = chi2_{p, 1-alpha} Sigma.

The rows of a low-passed log are correlated: only N_eff = N min(1, 2 f_c dt) of the N samples per
joint are independent (``identification.data.n_effective``). The IV estimate's covariance already
carries the factor N / N_eff (``instruments.solve_iv``); the least-squares covariance of the
repair's fit (``least_squares.solve_ls``: sigma^2 (Y^T W Y)^-1 with sigma^2 from the residual) does
not, so it is inflated here by N / N_eff. Cost: one eigen-decomposition of a p x p matrix, against
minutes for the LFR SDP (``uncertainty.ellipsoid``) at 1000 samples.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from robust_drake.errors import RobustDrakeError


def n_eff_factor(model) -> float:
    """N / N_eff of the model's fit data (1 when no low-pass cutoff is recorded)."""
    data = model.data or {}
    fc = (data.get("filter") or {}).get("cutoff_hz")
    dt = data.get("dt")
    if fc is None or dt is None:
        return 1.0
    return 1.0 / min(1.0, 2.0 * float(fc) * float(dt))


def confidence_ellipsoid(model, alpha: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """(theta0, P) of the 1 - alpha confidence ellipsoid (CI eq. 10 convention, E^T E = P) of the
    base parameters of ``model`` (SI units of the base parameters: kg m^2, kg m, ...)."""
    if not 0.0 < alpha < 1.0:
        raise RobustDrakeError(f"alpha must lie in (0, 1), got {alpha}")
    if model.base_covariance is None:
        raise RobustDrakeError("the identified model carries no base-parameter covariance")
    theta0 = np.asarray(model.base_values, float).reshape(-1)
    S = np.asarray(model.base_covariance, float)
    p = theta0.size
    if S.shape != (p, p) or not np.all(np.isfinite(S)):
        raise RobustDrakeError(f"base covariance must be a finite {p}x{p} matrix")
    S = 0.5 * (S + S.T)
    if str(model.estimator).startswith("least"):
        S = S * n_eff_factor(model)
    if np.linalg.eigvalsh(S)[0] <= 0:
        raise RobustDrakeError("base covariance is not positive definite (unidentifiable parameters)")
    return theta0, float(chi2.ppf(1.0 - alpha, p)) * S


def mahalanobis_radius(theta0, P, theta) -> float:
    """sqrt((theta - theta0)^T P^-1 (theta - theta0)); <= 1 inside E(P, theta0)."""
    d = np.asarray(theta, float) - np.asarray(theta0, float)
    return float(np.sqrt(d @ np.linalg.solve(P, d)))
