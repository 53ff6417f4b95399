"""Confidence ellipsoid of an identified model's base parameters, in seconds at any data size.

An :class:`~robust_drake.identification.model.IdentifiedModel` carries the least-squares (or IV)
estimate theta_hat of the base parameters and its covariance Sigma. Asymptotically (many
independent rows, zero-mean residual independent of the regressor) theta_hat ~ N(theta, Sigma),
so

    E = {theta : (theta - theta_hat)^T Sigma^-1 (theta - theta_hat) <= chi2_{p, 1-alpha}}

contains the true theta with probability 1 - alpha. In the convention of CI eq. 10
(E(P, theta0) = {theta0 + E z : ||z|| <= 1}, E^T E = P) this is theta0 = theta_hat,
P = chi2_{p, 1-alpha} Sigma.

The rows of a low-passed log are correlated: only N_eff = N min(1, 2 f_c dt) of the N samples per
joint are independent (``identification.data.n_effective``). The least-squares covariance of the
repair's fit (``least_squares.solve_ls``: sigma^2 (Y^T W Y)^-1 with sigma^2 from the residual) is
inflated here by N / N_eff. The IV model carries the filter-aware sandwich of
``instruments.iv_sandwich`` (the correlation of the rows is that of the data's own filter), used
with p F_{p, nu}(1 - alpha) instead of chi2 (nu = N_eff x joints - fitted parameters: the
sandwich is estimated from the residual; ``model.data["covariance"]``). Cost: one
eigen-decomposition of a p x p matrix, against minutes for the LFR SDP (``uncertainty.ellipsoid``)
at 1000 samples.

Noise in the regressor (errors in variables). Accelerations differentiated twice from encoder
positions carry noise *inside* Y; least squares is then biased (attenuated) and its chi2 set is
not sound: at a nominal 90 % on the IMI SCARA with CI's acceleration noise it held the truth in
73 % of experiments at 100 rows and 12 % at 3000 (the bias does not shrink with N; measured,
tests/test_confidence_eiv.py). Which set at which size:

- the repair flagged errors in variables (Hausman test, ``model.data["errors_in_variables"]``)
  and kept least squares: :func:`confidence_ellipsoid` refuses (use the IV model, ``stage=
  "final"``, whose estimator is ``instrumental_variables``; the repair's low-passed instruments
  are uncorrelated with the regressor noise above ratio x f_c only, see
  ``identification.instruments``). Its set, measured against the URDF's parameters on simulated
  5 s logs where the repair chose IV (``benchmarks/iv_coverage.py``, the same fits with the
  homoscedastic covariance the model carried before -> the sandwich it carries now, at 90 % /
  99 %): C.1 71.4 / 85.7 -> 85.7 / 97.6 % (42 of 150 seeds), Siciliano arm 95.9 / 100 ->
  98.0 / 100 % (49 of 60); with a 10-bit encoder (more noise in the regressor) C.1 97.2 / 98.6
  -> 98.6 / 100 % (71 of 80), Siciliano 100 / 100 % both (73 of 80). On filtered synthetic rows
  with a noise level that follows the motion and an unbiased IV: 72.7 / 89 -> 90.0 / 99.7 %
  (300 draws, tests/test_iv_covariance.py);
- the level of the acceleration noise is known (CI's setting: bounds delta_qdd; uniform noise has
  variance delta^2 / 3), any size N >= 50 rows: :func:`corrected_least_squares` +
  :func:`eiv_confidence_ellipsoid`, the bias-compensated estimate with an HC3 sandwich covariance
  and an F quantile. Sound because its estimating equation has zero mean at the true theta
  (E[Y^T Y] = Y0^T Y0 + sum Psi_k with Y0 the noise-free regressor), and an M-estimator is
  asymptotically normal with the sandwich covariance; HC3 (scores / (1 - leverage)) and the
  F_{p, N-p} quantile correct the small-sample under-coverage (measured at 90 %: 88.5 % at N = 50,
  92 % at N = 100 and 200 rows, 400 draws each). Cost: O(N p^2), milliseconds at 10^4-10^5 rows;
- the noise level is not known but instruments are (the regressor of the excitation's reference
  motion, noise-free and correlated with the actual motion), N >= 100 rows:
  :func:`instrumental_variables` (IV with an HC3 sandwich, F quantile): 91.7 % / 90 % coverage
  at 100 / 300 rows at 90 % (91 % in the test, another seed); ``solve_iv``'s ``cov`` on
  independent rows is the same HC3 sandwich (89 % with the chi2 quantile in the test), its
  homoscedastic ``cov_homoscedastic`` (what the repair's IV model carried before) 72 % / 78 %;
- fewer rows, or noise known only by bounds and a guarantee wanted for every noise realisation:
  CI's LFR SDP (``uncertainty.ellipsoid``), seconds at 50 rows, minutes at 1000.
  Against it where both can be computed (IMI SCARA, CI_BOUNDS on torque and acceleration, rows
  evenly spaced over CI's excitation, 99 %, seeds 0 and 1; ``experiments.logs_to_control.
  compare_eiv_with_sdp``): trace(P_corrected) / trace(P_SDP) = 0.089-0.11 at 50 rows and
  0.035-0.037 at 100 rows (volume ratio 4e-7 and 1e-8 to 3e-8); both sets held the truth (radius
  0.19-0.72 and 0.09-0.17); < 3 ms against 13-38 s for the SDP (loaded machine). The SDP bounds
  the worst case of bounded noise, which does not average out with N; the corrected set is a
  1 - alpha probability set and shrinks as 1/N. Rows must not be selected on the noisy data
  (D-optimal selection picks the noise too: the truth left the 99 % set at 100 selected rows).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2
from scipy.stats import f as f_dist

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
        raise RobustDrakeError("the identified model carries no base-parameter covariance, so it has no confidence "
                               "set (a URDF export keeps none): use the repair's report.json")
    theta0 = np.asarray(model.base_values, float).reshape(-1)
    S = np.asarray(model.base_covariance, float)
    p = theta0.size
    if S.shape != (p, p) or not np.all(np.isfinite(S)):
        raise RobustDrakeError(f"base covariance must be a finite {p}x{p} matrix")
    S = 0.5 * (S + S.T)
    if str(model.estimator).startswith("least"):
        eiv = (model.data or {}).get("errors_in_variables") or {}
        if eiv.get("significant"):
            raise RobustDrakeError(
                f"errors in variables detected (Hausman {eiv.get('statistic', float('nan')):.3g} > "
                f"{eiv.get('limit', float('nan')):.3g}): the least-squares confidence set is not sound; use the "
                "instrumental-variable model (stage 'final') or corrected_least_squares with the noise level")
        S = S * n_eff_factor(model)
    if np.linalg.eigvalsh(S)[0] <= 0:
        raise RobustDrakeError("base covariance is not positive definite (unidentifiable parameters)")
    return theta0, _quantile(model, alpha, p) * S


def _quantile(model, alpha: float, p: int) -> float:
    """chi2_{p, 1-alpha}; for a sandwich covariance (``data["covariance"]``, estimated from the
    residual of N_eff x joints independent equations with k fitted parameters) p F_{p, nu}(1 - alpha),
    nu = N_eff x joints - k."""
    data = model.data or {}
    cov = data.get("covariance") or {}
    if "sandwich" not in str(cov.get("kind", "")) or not data.get("samples") or not data.get("joints"):
        return float(chi2.ppf(1.0 - alpha, p))
    nu = float(data["samples"]) * int(data["joints"]) / n_eff_factor(model) - int(cov.get("parameters", p))
    if nu < 1:
        raise RobustDrakeError(f"the fit has {nu:.3g} residual degrees of freedom: no confidence set")
    return p * float(f_dist.ppf(1.0 - alpha, p, nu))


def mahalanobis_radius(theta0, P, theta) -> float:
    """sqrt((theta - theta0)^T P^-1 (theta - theta0)); <= 1 inside E(P, theta0)."""
    d = np.asarray(theta, float) - np.asarray(theta0, float)
    return float(np.sqrt(d @ np.linalg.solve(P, d)))


# --------------------------------------------------------------------------- errors in variables
@dataclass
class CorrectedFit:
    """Bias-compensated least squares: estimate ``theta`` and its HC3 sandwich covariance ``cov``
    from ``N`` independent rows (samples of all joints) and ``p`` parameters."""

    theta: np.ndarray
    cov: np.ndarray
    N: int
    names: list


def acceleration_noise_directions(regressor, q, qd, qdd) -> list:
    """B_j = dY/dqdd_j (N, n, p) for a regressor ``regressor(q, qd, qdd)`` affine in qdd (every
    rigid-body regressor is): Y(qdd + delta) = Y(qdd) + sum_j delta_j B_j."""
    Y = np.asarray(regressor(q, qd, qdd), float)
    n = np.shape(qdd)[1]
    return [np.asarray(regressor(q, qd, np.asarray(qdd, float) + np.eye(n)[j]), float) - Y for j in range(n)]


def corrected_least_squares(Y, tau, B, variance, names=None) -> CorrectedFit:
    """theta_c = (sum_k Y_k^T Y_k - Psi_k)^-1 sum_k Y_k^T tau_k with Psi_k = sum_j sigma_j^2
    B_jk^T B_jk, the noise part of E[Y_k^T Y_k] (Y_k = Y0_k + sum_j delta_jk B_jk, delta_jk zero
    mean, variance sigma_j^2 [(rad/s^2)^2], independent between rows and of the torque noise).

    Y (N, n, p) measured regressor, tau (N, n) [N m], B list of n (N, n, p) from
    :func:`acceleration_noise_directions`, variance (n,) of the acceleration noise. Covariance: HC3
    sandwich H^-1 (sum_k s_k s_k^T / (1 - h_k)^2) H^-1, scores s_k = Y_k^T (tau_k - Y_k theta_c) +
    Psi_k theta_c, H = sum_k (Y_k^T Y_k - Psi_k), leverages h_k = tr(Y_k H^-1 Y_k^T)."""
    Y, tau = np.asarray(Y, float), np.asarray(tau, float)
    N, n, p = Y.shape
    var = np.broadcast_to(np.asarray(variance, float), (len(B),))
    if N <= p or np.any(var < 0) or not np.all(np.isfinite(var)):
        raise RobustDrakeError(f"corrected least squares needs N > p rows and finite variances >= 0 (N={N}, p={p})")
    Psi = sum(v * np.einsum("kip,kiq->kpq", Bj, Bj) for v, Bj in zip(var, B))
    H = np.einsum("kip,kiq->pq", Y, Y) - Psi.sum(axis=0)
    if np.linalg.eigvalsh(0.5 * (H + H.T))[0] <= 0:
        raise RobustDrakeError("the noise-corrected information matrix is not positive definite "
                               "(regressor noise as large as the excitation, or too few rows)")
    Hi = np.linalg.inv(H)
    theta = Hi @ np.einsum("kip,ki->p", Y, tau)
    s = np.einsum("kip,ki->kp", Y, tau - Y @ theta) + Psi @ theta
    cov = _hc3_sandwich(Hi, s, np.einsum("kip,pq,kiq->k", Y, Hi, Y))
    return CorrectedFit(theta, cov, int(N), list(names or [f"theta{i}" for i in range(p)]))


def _hc3_sandwich(Ai, s, lev) -> np.ndarray:
    """A^-1 (sum_k s_k s_k^T / (1 - h_k)^2) A^-T, leverages h_k clipped to [-0.9, 0.9]."""
    s = s / (1.0 - np.clip(lev, -0.9, 0.9))[:, None]
    cov = Ai @ (s.T @ s) @ Ai.T
    return 0.5 * (cov + cov.T)


def instrumental_variables(Y, Z, tau, names=None) -> CorrectedFit:
    """theta_IV = (sum_k Z_k^T Y_k)^-1 sum_k Z_k^T tau_k with an HC3 sandwich covariance
    A^-1 (sum_k Z_k^T e_k e_k^T Z_k / (1 - h_k)^2) A^-T (A = sum Z_k^T Y_k, h_k = tr(Y_k A^-1 Z_k^T)).

    Y, Z (N, n, p): measured regressor and instruments (uncorrelated with the regressor and torque
    noise, correlated with the noise-free regressor: e.g. the regressor of the excitation's
    *reference* motion), tau (N, n). No noise level is needed. Rows must be independent. Unlike
    the homoscedastic sigma^2 (Z^T Y)^-1 Z^T Z (Y^T Z)^-1 (``instruments.solve_iv``'s
    ``cov_homoscedastic``), the sandwich does not assume an equation error of constant variance,
    which noise in Y (error Delta Y_k theta) breaks: IMI SCARA, CI's noise, 90 % sets, reference
    instruments: 91.7 % / 90 % coverage at 100 / 300 rows with the sandwich, 72 % / 78 % with the
    homoscedastic covariance (300 draws each). For filtered, correlated rows (the repair's):
    ``instruments.iv_sandwich``."""
    Y, Z, tau = (np.asarray(a, float) for a in (Y, Z, tau))
    if Y.shape != Z.shape or Y.shape[0] <= Y.shape[2]:
        raise RobustDrakeError(f"instrumental variables need Y and Z of the same shape with N > p rows "
                               f"(got {Y.shape}, {Z.shape})")
    A = np.einsum("kip,kiq->pq", Z, Y)
    if np.linalg.cond(A) > 1e12:
        raise RobustDrakeError("the instruments are (nearly) uncorrelated with the regressor")
    Ai = np.linalg.inv(A)
    theta = Ai @ np.einsum("kip,ki->p", Z, tau)
    s = np.einsum("kip,ki->kp", Z, tau - Y @ theta)
    cov = _hc3_sandwich(Ai, s, np.einsum("kip,pq,kiq->k", Y, Ai, Z))
    p = Y.shape[2]
    return CorrectedFit(theta, cov, int(Y.shape[0]), list(names or [f"theta{i}" for i in range(p)]))


def eiv_confidence_ellipsoid(fit: CorrectedFit, alpha: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """(theta0, P) of the 1 - alpha set of a :class:`CorrectedFit` (:func:`corrected_least_squares`
    or :func:`instrumental_variables`; CI eq. 10 convention):
    P = p F_{p, N-p}(1 - alpha) cov (the F quantile, not chi2_p, for a covariance estimated from N
    rows)."""
    if not 0.0 < alpha < 1.0:
        raise RobustDrakeError(f"alpha must lie in (0, 1), got {alpha}")
    p = fit.theta.size
    return np.asarray(fit.theta, float), p * float(f_dist.ppf(1.0 - alpha, p, fit.N - p)) * fit.cov
