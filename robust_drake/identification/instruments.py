"""Errors in variables: a regressor that carries what the torque does not biases least squares.

The regressor is built from *measured* positions differentiated twice (zero-phase low-pass at
``f_c``, then central differences). Whatever in those columns the torque does not cause (motion
on the encoder's side of a gear that the link does not make, e.g. through backlash at reversals;
vibration; differentiated encoder noise, though quantisation alone is negligible at 14 bits, see
BUILD_NOTES) acts as an error in the variables, and least squares on such columns is biased
towards smaller parameters ("attenuation"). When the error sits at high
frequency the bias grows with the cut-off. It is worst on rows where large inertial and gravity
torques cancel, e.g. a joint left unpowered (torque ~ 0) that swings by reaction, or motion near
a resonance.

Remedy (the instrumental-variable idea of IDIM-IV, Gautier, Janot & Vandanjon, IEEE TCST 2013,
with a simpler instrument): instruments Z = the same columns built from the same files
low-passed at ``ratio x f_c`` (default 0.5). Z is strongly correlated with the error-free
regressor and uncorrelated with the error *above* ``ratio x f_c``, so theta_IV =
(Z^T W Y)^-1 Z^T W tau is free of that part of the bias; error inside the instrument band is not
removed (tests/test_instruments.py shows both). Decision: a Durbin-Wu-Hausman test of theta_IV
against theta_LS (covariances inflated by N / N_eff for the filtered, correlated rows); IV is used
only when the difference is significant at 1 %. The IV estimate predicts the *fit* data's torque
a little worse (LS is the best equation-error predictor given the same noisy columns) but the
physics better, which is what a different experiment and a replay of the motion see.

Covariance of theta_IV (what the repair's IV model carries into ``uncertainty.confidence``):
:func:`iv_sandwich`, A^-1 Cov(Z^T W e) A^-T with the equation error modelled as the data's own
zero-phase filter applied to an error that is independent between samples but whose size (and
correlation between joints) follows the motion, as noise in the regressor's does. It replaces
sigma^2 (Z^T Y)^-1 Z^T Z (Y^T Z)^-1 x N / N_eff, which assumes one constant error level: with
regressor noise that set under-covers (72.7 % at a nominal 90 % in tests/test_iv_covariance.py,
90.0 % with the sandwich; IMI SCARA independent rows 77 % -> 89 %, tests/test_confidence_eiv.py;
the repair on the simulated C.1, truth = URDF, 71.4 % -> 85.7 %, benchmarks/iv_coverage.py).
A Bartlett (Newey-West) long-run covariance of the row scores was measured worse on the repair's
5 s logs (40 % at 90 % on the simulated C.1 with windows of N / N_eff rows, 10-20 % with longer
windows): its kernel down-weights the correlation inside the filter's span, and longer windows
have too few independent blocks. The Hausman test keeps the homoscedastic pair (LS and IV
covariances of the same form, the classical test), so the estimator choice is unchanged.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from robust_drake.identification.fitting import ColumnCache, fit_model, predict_tau
from robust_drake.identification.least_squares import (
    LS_ROWS, LSResult, RANK_TOL, _gram_eig, identifiability, rss_from_gram,
)

#: instrument cut-off as a fraction of the data cut-off
INSTRUMENT_RATIO = 0.5
#: significance of the Hausman test
ALPHA = 0.01
#: rows over which the IV covariance averages the squared equation error (the local noise level),
#: in units of N / N_eff (the filter's samples per independent sample). Measured at a nominal 90 %:
#: 2 -> 90.0 %, 8 -> 87.0 % in tests/test_iv_covariance.py (a noise level that changes with the
#: motion); 2 -> 89 %, 8 -> 92 % on the simulated C.1's columns with torque noise only
LEVEL_WINDOW = 2.0


def solve_iv(Y: np.ndarray, Z: np.ndarray, tau: np.ndarray, names: list[str], weights=None,
             n_eff_factor: float = 1.0, data=None, robust: bool = True) -> LSResult:
    """Instrumental-variable estimate ``(Z^T W Y)^-1 Z^T W tau`` (rows of joint j weighted w_j).

    ``Y``, ``Z``: (N, n, p) regressor and instruments on the same rows. ``cov``: the sandwich of
    :func:`iv_sandwich` (``data``: the :class:`~robust_drake.identification.data.IdentData` whose
    zero-phase filter made the rows; None = independent rows); ``cov_homoscedastic``: sigma^2
    (Z^T Y)^-1 Z^T Z (Y^T Z)^-1 inflated by 1 / ``n_eff_factor`` (N_eff / N of filtered data), what
    the Hausman test uses (``robust`` False: ``cov`` is that one too, for callers that need theta
    or the Hausman pair only: the sandwich costs about 4x the solve). The residual is the equation
    error ``tau - Y theta``."""
    Y, Z, tau = (np.asarray(a, float) for a in (Y, Z, tau))
    if Y.shape != Z.shape:
        raise ValueError(f"regressor {Y.shape} and instruments {Z.shape} differ")
    N, n, p = Y.shape
    w = np.ones(n) if weights is None else np.asarray(weights, float)
    # the weighted products by 4096-sample row blocks (least_squares.LS_ROWS), not from weighted
    # copies of all (N, n, p) columns (2 x 325 MB at 99.5k rows x 7 joints x 62 columns)
    YY, ZY, ZZ, Zb = np.zeros((p, p)), np.zeros((p, p)), np.zeros((p, p)), np.zeros(p)
    for r0 in range(0, N, LS_ROWS):
        r = slice(r0, r0 + LS_ROWS)
        Yw = (Y[r] * w[None, :, None]).reshape(-1, p)
        Zw = (Z[r] * w[None, :, None]).reshape(-1, p)
        YY += Yw.T @ Yw
        ZY += Zw.T @ Yw
        ZZ += Zw.T @ Zw
        Zb += Zw.T @ (tau[r] * w[None, :]).reshape(-1)
    Yw = Zw = None
    sandwich = None
    if robust:  # with the HC3 leverages h_k = tr(Y_k A^-1 Z_k^T W) of the rows
        YA = (Y.reshape(-1, p) @ np.linalg.pinv(ZY)).reshape(Y.shape)  # one 2-D product (a 3-D one is 5x slower)
        sandwich = ([Z], data, np.einsum("kjp,kjp->k", YA, Z * (w**2)[None, :, None]))
    return solve_iv_normal(YY, ZY, ZZ, Zb, lambda theta: tau - Y @ theta,
                           names, w, N, n_eff_factor, sandwich=sandwich)


def solve_iv_normal(YY, ZY, ZZ, Zb, residual_of, names: list[str], w: np.ndarray, N: int,
                    n_eff_factor: float = 1.0, sandwich=None) -> LSResult:
    """:func:`solve_iv` from the weighted products Y^T W Y, Z^T W Y, Z^T W Z, Z^T W tau (p x p,
    p) and ``residual_of(theta)`` = tau - Y theta (N, n): for callers that hold them already
    (``fitting.ColumnCache.gram``). Columns are scaled by d = sqrt(diag(Y^T W Y)).
    ``sandwich``: (instrument column blocks, IdentData or None[, leverages]) for :func:`iv_sandwich`; with it
    ``cov`` is that sandwich, without it the homoscedastic covariance (``covariance`` says which).
    ``residual_of`` may instead be (tau^T W tau, Y^T W tau): no (N, n) residual is formed
    (``residual`` None, ``rms`` NaN; not with ``sandwich``)."""
    n, p = len(w), len(Zb)
    # rank as least squares has it (least_squares.solve_gram): the identifiable subspace of the
    # column-normalised Y^T W Y; the IV equations are solved on that subspace (theta has no component
    # along a null direction, e.g. a URDF's joint-damping column equal to the viscous one, a joint
    # that barely moves), and the parameters in a null direction are named with se = inf
    d, _, V, keep, _ = _gram_eig(YY, RANK_TOL)  # column scaling and the identifiable directions
    dd = np.outer(d, d)
    ZYs = ZY / dd
    Vk = V[:, keep]
    reduced = Vk.T @ ZYs @ Vk
    try:
        if np.linalg.cond(reduced) > 1.0 / (RANK_TOL * np.finfo(float).eps ** 0.5):
            raise np.linalg.LinAlgError("instruments nearly singular")
        ZYi = Vk @ np.linalg.solve(reduced, Vk.T)
    except np.linalg.LinAlgError:  # instruments weak along some identifiable direction
        ZYi = Vk @ np.linalg.pinv(reduced, rcond=RANK_TOL) @ Vk.T
    theta = ZYi @ (Zb / d) / d
    if callable(residual_of):
        resid = residual_of(theta)
        rss = float(np.sum((resid * w[None, :]) ** 2))
    else:  # (tau^T W tau, Y^T W tau): no (N, n) residual (least_squares.solve_normal)
        resid, rss = None, rss_from_gram(YY, residual_of[1], float(residual_of[0]), theta)
    cond, rank, unident, _ = identifiability(None, names, RANK_TOL, G=YY)
    sigma2 = rss / max(N * n - rank, 1)
    cov0 = sigma2 * ZYi @ (ZZ / dd) @ ZYi.T / dd / max(n_eff_factor, 1e-12)
    cov, kind = cov0, "homoscedastic x N / N_eff"
    if sandwich is not None:
        cov = iv_sandwich(ZYi / dd, sandwich[0], resid, w, sandwich[1], n_eff_factor, *sandwich[2:])
        kind = "filter-aware sandwich" if n_eff_factor < 1 and sandwich[1] is not None else \
            "HC3 sandwich" if sandwich[2:] and sandwich[2] is not None else "HC1 sandwich"
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    for u in unident:
        se[names.index(u)] = np.inf
    rms = np.full(n, np.nan) if resid is None else np.sqrt(np.mean(resid**2, axis=0))
    res = LSResult(theta=theta, names=list(names), se=se, sigma=rms, weights=w, cond=cond, rank=rank,
                   unidentifiable=unident, residual=resid, rms=rms, N=N, rss_weighted=rss)
    res.cov, res.cov_homoscedastic, res.covariance = cov, cov0, kind
    return res


def noise_gain(data) -> np.ndarray:
    """(N,) sum_k h_k^2 of the impulse response h of the data's zero-phase filter at each row's
    segment period: white noise of variance s^2 filtered by it has variance s^2 sum h^2 (sum h = 1;
    ~ 2 f_c dt for the 4th-order Butterworth filtfilt). Ones without a filter."""
    from robust_drake.identification.data import zero_phase_lowpass

    N = len(data.tau)
    fc = data.filter.cutoff_hz
    if fc is None or data.filter.derivatives == "given":
        return np.ones(N)
    segment = np.zeros(N, int) if data.segment is None else np.asarray(data.segment)
    out = np.ones(N)
    for s in np.unique(segment):
        dt = data.segment_period(s)
        m = int(min(max(20.0 / (fc * dt), 50), 200000))  # the response has decayed by then
        impulse = np.zeros((2 * m + 1, 1))
        impulse[m] = 1.0
        h = zero_phase_lowpass(impulse, dt, fc, data.filter.order)[:, 0]
        out[segment == s] = float(h @ h)
    return out


def local_mean(x: np.ndarray, window: int) -> np.ndarray:
    """Centred moving average of ``x`` along axis 0 over ``window`` rows (shifted inside at the ends)."""
    N = x.shape[0]
    L = int(min(max(window, 1), N))
    c = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)])
    lo = np.clip(np.arange(N) - L // 2, 0, N - L)
    return (c[lo + L] - c[lo]) / L


def iv_sandwich(Ainv, Z_blocks, residual, weights, data=None, n_eff_factor: float = 1.0,
                leverage=None) -> np.ndarray:
    """Covariance A^-1 Omega A^-T of theta_IV (A = Z^T W Y, W = diag(w_j^2)) for an equation error
    e_k = (F xi)_k (n,): the data's zero-phase filter F (symmetric) applied to a zero-mean error
    xi independent between samples, with a covariance Sigma_k (n x n) that varies along the log
    and between joints (noise in the regressor enters as Delta Y theta: its size follows the
    motion and it is shared by the joints through M(q)). Then
    Omega = Cov(sum_k Z_k^T W e_k) = sum_k (F Z)_k^T W Sigma_k W (F Z)_k, estimated with
    Sigma_k = local mean of e_k e_k^T over L = ``LEVEL_WINDOW`` x N / N_eff rows / sum h^2
    (:func:`noise_gain`) / (1 - h_k)^2, h_k = the ``leverage`` (tr(Y_k A^-1 Z_k^T W)) summed over
    the N / N_eff rows of one independent sample (local mean over L rows x N / N_eff): the fit
    absorbs that share of the error where the parameters' information lies (HC3). The row's
    total leverage is applied to every joint's equation, conservative for n > 1 by design: on the
    simulated C.1's columns with fresh torque noise only, the 90 % set held the truth in 89 %
    with it, 78 % with each equation's own leverage h_kj (also with the full n x n block), 71 %
    without any (homoscedastic covariance: 77.5 %). No ``leverage``: n_i / (n_i - p) instead (HC1; n_i = N_eff x joints independent
    equations). ``data`` None or unfiltered: F = identity, Sigma_k = e_k e_k^T (the HC3 / HC1
    sandwich of independent rows). Z_blocks: instrument columns (N, n, p_b) side by side
    (``ColumnCache.blocks`` or one joined array). Cost O(N n p^2) and one filter pass of Z."""
    from robust_drake.identification.least_squares import parallel_filter

    e = np.asarray(residual, float)
    w2 = np.asarray(weights, float) ** 2
    N, n = e.shape
    p = Ainv.shape[0]
    n_ind = N * n * min(n_eff_factor, 1.0)
    factor = n_ind / max(n_ind - p, 1.0)
    Z = Z_blocks[0] if len(Z_blocks) == 1 else np.concatenate(Z_blocks, axis=2)
    if data is not None and data.filter.cutoff_hz is not None and n_eff_factor < 1.0 \
            and data.filter.derivatives != "given":
        L = int(np.ceil(LEVEL_WINDOW / n_eff_factor))
        S = local_mean(e[:, :, None] * e[:, None, :], L) / noise_gain(data)[:, None, None]
        if leverage is not None:  # a block of N / N_eff rows is one independent row
            h = np.clip(local_mean(np.asarray(leverage, float), L) / n_eff_factor, 0.0, 0.9)
            S, factor = S / ((1.0 - h) ** 2)[:, None, None], 1.0
        lam, V = np.linalg.eigh(S)
        C = V * np.sqrt(np.maximum(lam, 0.0))[:, None, :]  # Sigma_k = C_k C_k^T
        Z = parallel_filter(data, Z)
    elif leverage is not None:
        C, factor = (e / (1.0 - np.clip(leverage, -0.9, 0.9))[:, None])[:, :, None], 1.0
    else:
        C = e[:, :, None]
    omega = np.zeros((p, p))
    for c in range(C.shape[2]):
        u = np.einsum("kjp,kj->kp", Z, C[:, :, c] * w2[None, :])
        omega += u.T @ u
    cov = Ainv @ (omega * factor) @ Ainv.T
    return 0.5 * (cov + cov.T)


def fit_iv_blocks(cache: ColumnCache, icache: ColumnCache, effects, weights, parts=None,
                  n_eff_factor: float = 1.0, robust: bool = False, residual: bool = True) -> LSResult:
    """``solve_iv(cache.model(effects), icache.model(effects), ...)`` from the memoised block
    products of :meth:`ColumnCache.gram` (``parts``: row masks partitioning the rows, e.g. the
    cross-validation folds whose products the held-out score reuses; default all rows).
    ``robust``: ``cov`` is the sandwich of :func:`iv_sandwich` from the instrument blocks (as
    :func:`solve_iv` with ``data=cache.data``; the selection does not need it), else homoscedastic.
    ``residual`` False: no (N, n) residual (``solve_iv_normal``; the selection's candidate fits)."""
    w = np.asarray(weights, float)
    parts = [np.ones(cache.data.N, bool)] if parts is None else parts
    if not np.array_equal(np.sum(parts, axis=0), np.ones(cache.data.N)):
        raise ValueError("parts must partition the rows")
    YY, Yb = cache.gram(effects, w, parts)
    ZY, Zb = cache.gram(effects, w, parts, left=icache)
    ZZ, _ = icache.gram(effects, w, parts)
    sandwich = None
    if robust:
        Zb_, Yb_ = icache.blocks(effects)[0], cache.blocks(effects)[0]
        spans = np.cumsum([0] + [b.shape[2] for b in Yb_])
        A = sum(ZY)
        Ai = np.linalg.pinv(A)
        U = sum((Y.reshape(-1, Y.shape[2]) @ Ai[spans[a]:spans[a + 1]]).reshape(Y.shape[:2] + (-1,))
                for a, Y in enumerate(Yb_))  # Y A^-1, (N, n, p)
        w2 = (w**2)[None, :, None]
        lev = sum(np.einsum("kjp,kjp->k", U[:, :, spans[b]:spans[b + 1]], Z * w2) for b, Z in enumerate(Zb_))
        sandwich = (Zb_, cache.data, lev)
    resid = ((lambda th: cache.data.tau - cache.explicit_prediction(effects, th)) if residual or robust
             else (cache.tau_sq(w), sum(Yb)))
    return solve_iv_normal(sum(YY), sum(ZY), sum(ZZ), sum(Zb), resid, cache.names(effects), w, cache.data.N,
                           n_eff_factor, sandwich)


def ls_covariance(Y: np.ndarray, tau: np.ndarray, theta: np.ndarray, weights, n_eff_factor: float = 1.0):
    """sigma^2 (Y^T W Y)^-1 for a least-squares estimate, inflated by 1 / n_eff_factor."""
    N, n, p = Y.shape
    w = np.asarray(weights, float)
    Yw = (Y * w[None, :, None]).reshape(-1, p)
    r = ((tau - Y @ theta) * w[None, :]).reshape(-1)
    sigma2 = float(r @ r) / max(N * n - p, 1)
    return sigma2 * np.linalg.pinv(Yw.T @ Yw) / max(n_eff_factor, 1e-12)


def hausman(theta_ls, cov_ls, theta_iv, cov_iv, alpha: float = ALPHA) -> dict:
    """Durbin-Wu-Hausman statistic H = d^T (V_IV - V_LS)^+ d, d = theta_IV - theta_LS, on the
    positive part of V_IV - V_LS (dof = its rank). ``significant``: H > chi2 quantile 1 - alpha."""
    dlt = np.asarray(theta_iv, float) - np.asarray(theta_ls, float)
    D = np.asarray(cov_iv, float) - np.asarray(cov_ls, float)
    D = 0.5 * (D + D.T)
    lam, V = np.linalg.eigh(D)
    keep = lam > 1e-9 * max(lam.max(), 1e-300)
    proj = V[:, keep].T @ dlt
    H = float(np.sum(proj**2 / lam[keep]))
    dof = int(keep.sum())
    limit = float(stats.chi2.ppf(1 - alpha, max(dof, 1)))
    return {"statistic": H, "dof": dof, "limit": limit, "alpha": alpha, "significant": bool(H > limit)}


def fit_model_iv(cache, icache, effects, weights, n_eff_factor: float = 1.0, robust: bool = True):
    """IV counterpart of ``selection.fit_model``: columns from ``cache``, instruments from
    ``icache`` (same rows, lower cut-off). ``residual``/``rms`` are output errors; ``robust``:
    as :func:`solve_iv`."""
    Y, names, slices = cache.model(effects)
    Z, _, _ = icache.model(effects)
    if Y.shape != Z.shape:
        raise ValueError(f"instrument rows {Z.shape} do not match the data {Y.shape}")
    res = solve_iv(Y, Z, cache.data.tau, names, weights, n_eff_factor, data=cache.data, robust=robust)
    res.residual = cache.data.tau - predict_tau(cache, effects, res.theta)
    res.rms = cache.rms(res.residual)  # over the rows in use (stiction rows left out)
    return res, slices


def cutoff_sweep(paths, robot, regressor, cutoffs, torque: str = "tau_meas", weights=None,
                 ratio: float = INSTRUMENT_RATIO, n_joints=None, reuse=None) -> dict:
    """The attenuation signature: rigid-body base parameters fitted by LS and by IV (instruments at
    ``ratio`` x the cut-off) on the same files at several cut-offs [Hz]. Errors in the variables
    show as LS parameters that shrink as the cut-off rises while IV's move much less.

    Returns ``{"cutoff_hz": [...], "names": base names, "least_squares": [[...] per cut-off],
    "instrumental_variables": [[...]], "nominal": URDF base parameters}``.

    ``reuse``: ``(cache, icache)`` already built from these files at one of the cut-offs (the
    repair's fit columns and its instruments at ``ratio`` x that cut-off): used for that
    cut-off instead of loading and building them again."""
    from robust_drake.identification.data import friction_exclusion, load, load_companion

    p0 = len(regressor.base_names)
    out = {"cutoff_hz": [float(c) for c in cutoffs], "names": list(regressor.base_names),
           "least_squares": [], "instrumental_variables": [],
           "nominal": [float(x) for x in regressor.base_parameters()]}
    for fc in cutoffs:
        if reuse is not None and np.isclose(reuse[0].data.filter.cutoff_hz, fc, rtol=1e-12, atol=0) \
                and np.isclose(reuse[1].data.filter.cutoff_hz, fc * ratio, rtol=1e-12, atol=0):
            c, cz = reuse  # built by the repair with the same stiction rule
        else:
            d = load(paths, robot=robot, n_joints=n_joints, torque=torque, cutoff_hz=fc, quiet=True)  # reported once
            z = load_companion(paths, d, cutoff_hz=fc * ratio, torque=torque)
            ex = friction_exclusion(d)  # the repair's stiction rule
            c, cz = ColumnCache(d, regressor, exclude=ex), ColumnCache(z, regressor, exclude=ex)
        w = np.ones(c.data.n) if weights is None else np.asarray(weights, float)
        out["least_squares"].append([float(x) for x in fit_model(c, [], w)[0].theta[:p0]])
        iv = fit_model_iv(c, cz, [], w, robust=False)[0]  # theta only
        out["instrumental_variables"].append([float(x) for x in iv.theta[:p0]])
        del c, cz  # before the next cut-off's columns are built
    return out


def plot_cutoff_sweep(sweep: dict, path: str, top: int = 4) -> str:
    """Write :func:`cutoff_sweep_figure` to ``path``; returns ``path``."""
    cutoff_sweep_figure(sweep, top).savefig(path, dpi=80)
    return path


def cutoff_sweep_figure(sweep: dict, top: int = 4):
    """LS and IV parameters / URDF value against the cut-off [Hz], for the ``top`` largest nominal
    parameters (one panel each), as a matplotlib ``Figure``."""
    from robust_drake.plotting import style

    with style():
        return _cutoff_sweep_figure(sweep, top)


def _cutoff_sweep_figure(sweep: dict, top: int):
    from robust_drake.plotting import subplots

    nom = np.asarray(sweep["nominal"])
    idx = [k for k in np.argsort(-np.abs(nom)) if abs(nom[k]) > 1e-9 * max(np.abs(nom).max(), 1e-300)][:top]
    if not idx:
        raise ValueError("no non-zero nominal parameter to normalise by")
    ls, iv, fc = np.asarray(sweep["least_squares"]), np.asarray(sweep["instrumental_variables"]), sweep["cutoff_hz"]
    fig, axes = subplots(1, len(idx), figsize=(3.2 * len(idx), 2.8), squeeze=False)
    for ax, k in zip(axes[0], idx):
        ax.plot(fc, ls[:, k] / nom[k], "o-", label="least squares")
        ax.plot(fc, iv[:, k] / nom[k], "s-", label="instrumental variables")
        ax.axhline(1.0, color="k", ls=":", lw=1, label="URDF")
        ax.set_title(sweep["names"][k], fontsize=9)
        ax.set_xlabel("cut-off [Hz]")
    axes[0, 0].set_ylabel("fitted / URDF")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle("LS and IV base parameters against the cut-off (errors in variables: LS shrinks as the "
                 "cut-off lets more of them through)", fontsize=10)
    fig.tight_layout()
    return fig


__all__ = ["solve_iv", "solve_iv_normal", "fit_iv_blocks", "iv_sandwich", "noise_gain", "local_mean", "hausman",
           "ls_covariance", "fit_model_iv", "cutoff_sweep", "plot_cutoff_sweep", "cutoff_sweep_figure",
           "INSTRUMENT_RATIO"]
