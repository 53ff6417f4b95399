"""The fitted model against the nominal (URDF) one: effects that live inside the rigid-body span.

Some effects cannot show up in the residual of a free rigid-body fit, because their regressor
columns are linear combinations of the rigid-body base columns: a payload fixed to the last link
(it only changes that link's inertial parameters), and a reflected rotor inertia on a joint whose
diagonal inertia is already a base parameter. A free fit absorbs them exactly; what is left is a
*shift of the base parameters away from the URDF's*, theta_hat = theta0 + d c, where ``d`` solves
Phi = Y_b d for the effect's columns Phi. This module reads that shift:

1. which candidate effects are in the span (numerically: ||Phi - Y_b d|| <= SPAN_TOL ||Phi||);
2. is the shift significant? chi^2 = Delta^T W Delta with Delta = theta_hat - theta0 and
   W = diag(1 / (sigma_rel^2 s_k^2 + se_k^2)): the URDF is trusted to a relative
   ``sigma_rel`` of each parameter's scale s_k (floored at FLOOR x the largest), the estimate to
   its standard error; computed over the directions the data identify only
   (:class:`IdentifiableShift`: the information matrix's base block, friction and effects
   profiled out, kept at the fit's ``RANK_TOL``; on a 6-axis arm the exact URDF read chi^2
   954.2 over all 36 parameters, 808.8 of it from the nine the fit lists as unidentifiable,
   issue 21), with their full covariance (fit + URDF trust) instead of the diagonal W;
3. does one span effect explain it? c by weighted projection, chi^2 of the remainder; accepted if
   the effect is physically admissible (``selection.implausible``) and the remainder is within
   the 99 % chi^2 quantile (the shift is then "the URDF plus this effect"). The omnibus test
   of 2. spreads a shift along one effect's direction over all p0 degrees of freedom; the
   directed test along a candidate (explained part chi^2 - chi^2_after against the chi^2
   quantile of its k coefficients, Bonferroni over the candidates offered) also counts as
   significant (a 0.4 kg m^2 rotor inertia on the PUMA's shoulder: omnibus 28.1 < 30.6 at 15
   degrees of freedom, explained part 28.06 against 14.7);
4. the named effect is then fitted the direct way: rigid-body part fixed at theta0, the effect's
   coefficient and the friction/effect columns by least squares, and that model's validation
   error is compared with the URDF-only model's (both with fitted friction).

The same reference fixes the joint of a ``torque_scale`` effect, which a free fit cannot: on a
2-joint arm gain (1+e) on joint j and 1/(1+e) on the other joint explain the same data with base
parameters that differ by the factor (1+e) (``effects.equivalent_gain_error``); the variant whose
rigid-body parameters are closer to the URDF's (same chi^2) is reported.

This is the "prior / nominal model" that ``effects.Payload`` says the payload needs; it is a
test against the nominal model, not a Bayesian fit: the least-squares estimate is not pulled
towards the URDF.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from robust_drake.identification.fitting import nonzero_joints
from robust_drake.model_repair.selection import effect_label, implausible, predict_tau

#: relative trust in the URDF's base parameters (5 % of each parameter's scale)
SIGMA_REL = 0.05
#: parameter scale floor, as a fraction of the largest nominal base parameter
FLOOR = 0.05
#: relative projection residual below which an effect's columns count as in the rigid-body span
SPAN_TOL = 1e-6
#: chi^2 quantile used for "significant shift" and "remainder consistent with the URDF"
QUANTILE = 0.99


def shift_weights(theta0: np.ndarray, se: np.ndarray, sigma_rel: float = SIGMA_REL) -> np.ndarray:
    """W_kk = 1 / (sigma_rel^2 s_k^2 + se_k^2), s_k = max(|theta0_k|, FLOOR max|theta0|)."""
    theta0 = np.asarray(theta0, float)
    s = np.maximum(np.abs(theta0), FLOOR * max(np.max(np.abs(theta0)), 1e-12))
    se = np.where(np.isfinite(se), se, 0.0)
    return 1.0 / ((sigma_rel * s) ** 2 + se**2)


class SpanBasis:
    """The stacked rigid-body columns Yb (rows x p0) prepared once for many span projections.

    Computed by row blocks, without the stacked copy or its thin SVD's (rows x p0) U (at 99.5k rows
    x 7 joints the copy, U and the SVD's workspace were ~0.9 GB): R of Yb = Q R (incremental QR),
    then the SVD of the small R = U_r diag(s) V^T, which has Yb's singular values and right vectors.
    Singular values below ``eps * max(rows, p0) * s_max`` are dropped, the rank rule of
    ``numpy.linalg.lstsq``'s default ``rcond``. A projection solves the semi-normal equations
    d = V diag(s)^-2 V^T Yb^T Phi with one step of refinement on the residual (the accuracy of the
    QR route for the conditioning of base columns), so ``d`` is the same minimum-norm solution, and
    the residual ||Phi - Yb d|| is the first solve's, computed block by block, corrected for the
    refinement step (two passes over Yb per projection)."""

    BLOCK_ROWS = 4096

    def __init__(self, Yb: np.ndarray):
        Yb = np.asarray(Yb, float)
        self.Yb = Yb if Yb.ndim == 3 else Yb[:, None, :]
        p0 = self.Yb.shape[2]
        R = np.zeros((0, p0))
        for r in self._runs():
            R = np.linalg.qr(np.vstack([R, self.Yb[r].reshape(-1, p0)]), mode="r")
        _, s, Vt = np.linalg.svd(R) if R.size else (None, np.zeros(0), np.zeros((0, p0)))
        rows = self.Yb.shape[0] * self.Yb.shape[1]
        keep = s > np.finfo(float).eps * max(rows, p0) * (s[0] if s.size else 0.0)
        self.s, self.Vt = s[keep], Vt[keep]
        self.G = R.T @ R  # = Yb^T Yb

    def _runs(self):
        N = self.Yb.shape[0]
        return [slice(a, min(N, a + self.BLOCK_ROWS)) for a in range(0, N, self.BLOCK_ROWS)]

    def _solve(self, g):
        return self.Vt.T @ ((self.Vt @ g) / (self.s ** 2)[:, None])

    def _at(self, B, d=None):
        """Yb^T (B - Yb d) (d None: Yb^T B) and ||B - Yb d||^2, by row blocks (d None and B zero on
        all joints but some, a single-joint effect's columns: the products of those joints only)."""
        p0, k = self.Yb.shape[2], B.shape[2]
        g, ss = np.zeros((p0, k)), 0.0
        joints = nonzero_joints(B) if d is None else None
        if joints is not None:
            for j in joints:
                for r in self._runs():
                    Br = B[r, j, :]
                    g += self.Yb[r, j, :].T @ Br
                    ss += float(np.sum(Br * Br))
            return g, ss
        for r in self._runs():
            A, Br = self.Yb[r].reshape(-1, p0), B[r].reshape(-1, k)
            res = Br if d is None else Br - A @ d
            g += A.T @ res
            ss += float(np.sum(res * res))
        return g, ss

    def direction(self, Phi: np.ndarray) -> tuple[np.ndarray, float]:
        B = np.asarray(Phi, float)
        B = B.reshape(self.Yb.shape[0], self.Yb.shape[1], -1)
        g, nb2 = self._at(B)
        d = self._solve(g)
        g, res2 = self._at(B, d)  # Yb^T r and ||r||^2 of the first solve
        delta = self._solve(g)
        d = d + delta  # one refinement step on the residual
        # ||r - Yb delta||^2 = ||r||^2 - 2 delta^T Yb^T r + delta^T (R^T R) delta: no third pass
        res2 = max(res2 - 2.0 * float(np.sum(delta * g)) + float(np.sum(delta * (self.G @ delta))), 0.0)
        nb = np.sqrt(nb2)
        rel = float(np.sqrt(res2) / nb) if nb > 0 else np.inf
        return d, rel


def span_direction(Yb, Phi: np.ndarray) -> tuple[np.ndarray, float]:
    """d with Phi ~= Yb d (stacked rows, minimum-norm least squares) and the relative residual
    ||Phi - Yb d|| / ||Phi||. ``Yb``: the (N, n, p0) base columns or their :class:`SpanBasis`
    (pass the basis when projecting many candidates on the same columns)."""
    basis = Yb if isinstance(Yb, SpanBasis) else SpanBasis(Yb)
    return basis.direction(Phi)


class IdentifiableShift:
    """The shift test restricted to the directions the data identify (issue 21 item 7).

    A free fit determines only the functions u^T theta_b of the base parameters with u in the
    range of the information matrix's base block once the friction and effect coefficients are
    profiled out, the Schur complement S = G_bb - G_bn G_nn^+ G_nb of G = Y^T W Y (the fit's
    weighted columns). Along its null directions the minimum-norm solution sets the estimate by
    convention (``least_squares.solve_gram``), not from data, so a shift there says nothing about
    the URDF. With D = diag(sqrt(G_bb)) (the fit's column normalisation), the eigenvectors B
    (p0, r) of D^-1 S D^-1 whose singular value sqrt(lambda) >= ``RANK_TOL`` x the largest singular value of
    the normalised G (the fit's own rank rule, ``least_squares._gram_eig``) span the identifiable
    coordinates z = B^T D Delta. Their covariance C = B^T D (Sigma_fit + Sigma_URDF) D B, Sigma_fit
    the fit's covariance of theta_b, Sigma_URDF = diag(sigma_rel^2 s_k^2) (:func:`shift_weights`);
    whitened x = L^-1 z (C = L L^T), chi^2 = ||x||^2 over r degrees of freedom."""

    def __init__(self, G: np.ndarray, p0: int, cov_b: np.ndarray, theta0: np.ndarray, sigma_rel: float):
        from robust_drake.identification.least_squares import RANK_TOL, _gram_eig

        _, s_full, _, _, _ = _gram_eig(G, RANK_TOL)
        Gbb, Gbn, Gnn = G[:p0, :p0], G[:p0, p0:], G[p0:, p0:]
        S = Gbb - (Gbn @ np.linalg.pinv(Gnn, rcond=1e-12, hermitian=True) @ Gbn.T if Gnn.size else 0.0)
        d = np.sqrt(np.maximum(np.diag(Gbb), 0.0))
        D = np.where(d > 0, d, 1.0)
        lam, V = np.linalg.eigh(0.5 * (S + S.T) / np.outer(D, D))
        keep = np.sqrt(np.maximum(lam, 0.0)) >= RANK_TOL * max(float(s_full[0]) if s_full.size else 0.0, 1e-300)
        self.T = (V[:, keep].T * D[None, :])  # z = T Delta, (r, p0)
        prior = 1.0 / shift_weights(theta0, np.zeros(p0), sigma_rel)
        C = self.T @ (np.asarray(cov_b, float) + np.diag(prior)) @ self.T.T
        self.L = np.linalg.cholesky(0.5 * (C + C.T)) if C.size else np.zeros((0, 0))
        self.dof = int(keep.sum())
        self.unidentified = int(p0 - self.dof)

    def whiten(self, x: np.ndarray) -> np.ndarray:
        """L^-1 T x for a shift (p0,) or shift directions (p0, k)."""
        from scipy.linalg import solve_triangular

        return solve_triangular(self.L, self.T @ x, lower=True) if self.dof else np.zeros((0,) + x.shape[1:])

    def chi2(self, delta: np.ndarray) -> float:
        x = self.whiten(delta)
        return float(x @ x)

    def project(self, delta: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, float]:
        """Coefficient c of delta ~ d c in the whitened identifiable coordinates and the chi^2 of
        the remainder (:func:`project_shift` in this metric)."""
        x, X = self.whiten(delta), self.whiten(d)
        c = np.linalg.lstsq(X, x, rcond=None)[0] if self.dof else np.zeros(d.shape[1])
        r = x - X @ c
        return c, float(r @ r)


def chi2(delta: np.ndarray, W: np.ndarray) -> float:
    return float(np.sum(W * delta**2))


def project_shift(delta: np.ndarray, d: np.ndarray, W: np.ndarray) -> tuple[np.ndarray, float]:
    """Weighted LS coefficient c of delta ~ d c and the chi^2 of the remainder."""
    DW = d * W[:, None]
    c = np.linalg.lstsq(d.T @ DW, DW.T @ delta, rcond=None)[0]
    return c, chi2(delta - d @ c, W)


def fit_with_fixed_rigid(cache, effects, theta0: np.ndarray, weights) -> np.ndarray:
    """Coefficients of ``cache.model(effects)`` with the rigid-body part fixed at theta0 and the
    rest (friction, effect columns) fitted by weighted least squares; an effect coefficient outside
    its kind's ``bounds`` is fixed at the nearest bound and the rest refitted (:func:`_bounded_columns`).
    Without that, a torque_scale fitted against the URDF's rigid body can come out at -1 or below,
    where the output-error prediction's fixed point tau_hat = m / (1 + c) diverges (measured: 22.7 N m
    RMS on jittered, gapped DFKI A.0 logs whose repaired model validates at 0.29 N m)."""
    blocks, _, slices = cache.blocks(effects)
    spans = [slice(0, blocks[0].shape[2])] + slices
    p, p0 = spans[-1].stop, len(theta0)
    w = np.asarray(weights, float)
    fixed = np.zeros(p, bool)
    th = np.concatenate([theta0, np.zeros(p - p0)])
    for _ in range(2):  # fit; if a bound binds, fix those columns and refit the others once
        free = ~fixed
        free[:p0] = False
        # from the column blocks (no joined (N, n, p) copy): the fixed columns' prediction block
        # by block, the few free columns (friction, effects) gathered
        rhs = (cache.data.tau - cache.explicit_prediction(effects, th, mask=~free)) * w[None, :]
        A = np.concatenate([Y[:, :, free[sl]] for Y, sl in zip(blocks, spans) if free[sl].any()], axis=2)
        A = (A * w[None, :, None]).reshape(-1, int(free.sum()))
        th[free] = np.linalg.lstsq(A, rhs.reshape(-1), rcond=None)[0]
        clip = _bounded_columns(effects, slices, th)
        if not clip:
            break
        for col, value in clip.items():
            th[col], fixed[col] = value, True
    return th


def _bounded_columns(effects, slices, theta) -> dict:
    """{column: nearest bound} for each effect coefficient of ``theta`` outside its kind's
    ``bounds`` (effects whose columns are one per coefficient name)."""
    out = {}
    for e, sl in zip(effects, slices):
        cols = range(sl.start, sl.stop)
        if len(cols) != len(e.coef_names):
            continue
        for name, col in zip(e.coef_names, cols):
            lo, hi = e.bounds.get(name, (-np.inf, np.inf))
            if not lo <= theta[col] <= hi:
                out[col] = float(np.clip(theta[col], lo, hi))
    return out


def _weighted_sq(r, weights) -> np.ndarray:
    """(N, n) [1]: (w_j r_j)^2, the fit's weighted squared output error per row and joint."""
    return (np.asarray(r, float) * np.asarray(weights, float)[None, :]) ** 2


def _on_joints(sq: np.ndarray, a, b) -> np.ndarray:
    """(N,): the squared errors ``sq`` (N, n) on the joint two effects ``a``, ``b`` share, else
    summed over the joints (an effect on joint j judged on joint j's error, not diluted)."""
    return sq[:, a.joint] if a.joint is not None and a.joint == b.joint else sq.sum(axis=1)


def _ranked(cf, fits, theta_nom, chosen, weights, level, out):
    """The effect to name among ``fits`` = [(fit error, effect, theta, per-row squared errors,
    entry)] of the candidates that explain the shift (step 3), or None. The one with the smallest
    fit-run error of URDF + effect is named only if every rival of another kind or joint fits the
    fit run significantly worse (paired block test at ``level``, one-sided at (1 - level) / 2,
    Holm over the rivals, blocks from the URDF-only model's fit residual; on the joint both
    act on, else pooled over the joints, :func:`_on_joints`); otherwise the data
    cannot tell them apart and none is named (``out["degenerate"]``: the labels). A spring on a
    shoulder and a harmonic-1 position torque (a centre-of-mass offset) both explain the shift its
    stiffness makes; only their fit errors differ."""
    from robust_drake.model_repair import decisions as D
    from robust_drake.model_repair.selection import validation_blocks

    if not fits:
        return None
    fits.sort(key=lambda f: f[0])
    top = fits[0]
    rivals = [f for f in fits[1:] if (f[1].kind, f[1].joint) != (top[1].kind, top[1].joint)]
    if rivals:
        lv = D.LEVEL if level is None else float(level)
        ids = validation_blocks(cf.data, cf.data.tau - predict_tau(cf, chosen, theta_nom)).ids
        tests = [D.paired_test(_on_joints(top[3], top[1], f[1]), _on_joints(f[3], top[1], f[1]), ids, lv)
                 for f in rivals]
        worse = D.holm([t.p_worse for t in tests], (1.0 - lv) / 2.0)
        tied = []
        for f, t, w in zip(rivals, tests, worse):
            f[4]["against_named"] = t.as_dict()
            if not w:
                tied.append(f[4]["label"])
        if tied:
            out["degenerate"] = [top[4]["label"]] + tied
            return None
    return top[1], top[2]


def _rms(r):
    return [float(x) for x in np.sqrt(np.mean(np.asarray(r) ** 2, axis=0))]


def compare_with_nominal(cf, cv, regressor, final_fit, chosen, candidates, weights,
                         sigma_rel: float = SIGMA_REL, level: float | None = None) -> dict:
    """The nominal-model analysis (module docstring). Returns a JSON-able dict:

    ``{"sigma_rel", "chi2", "dof", "significant", "rms_validate": URDF-only model,
    "span_candidates": [{label, kind, joint, parameters, chi2_after, accepted, reason}],
    "named": effect entry or None, "unexplained_shift": bool}``; ``named`` carries ``kind``,
    ``joint``, ``parameters``, ``rms_fit_after`` and ``rms_validate_after`` of URDF + effect.
    """
    theta0 = np.asarray(regressor.base_parameters(), float)
    p0 = len(theta0)
    delta = final_fit.theta[:p0] - theta0
    ident = identifiable_shift(cf, chosen, weights, final_fit, theta0, sigma_rel)
    c2_all = chi2(delta, shift_weights(theta0, final_fit.se[:p0], sigma_rel))  # all p0 (before issue 21)
    c2 = ident.chi2(delta)
    dof = ident.dof
    limit = float(stats.chi2.ppf(QUANTILE, max(dof, 1)))
    significant = bool(dof > 0 and c2 > limit)

    theta_nom = fit_with_fixed_rigid(cf, chosen, theta0, weights)
    rv_nom = cv.data.tau - predict_tau(cv, chosen, theta_nom)
    out = {"sigma_rel": sigma_rel, "chi2": c2, "dof": dof, "chi2_limit": limit,
           "unidentified_directions": ident.unidentified, "chi2_all_parameters": c2_all,
           "significant": significant, "rms_fit": _rms(cf.data.tau - predict_tau(cf, chosen, theta_nom)),
           "rms_validate": _rms(rv_nom), "span_candidates": [], "named": None,
           "unexplained_shift": False}
    basis = SpanBasis(cf.base[:, :, :p0])  # one SVD for all candidates
    chosen_kinds = {(e.kind, e.joint) for e in chosen}
    fits = []
    for e in candidates:
        if (e.kind, e.joint) in chosen_kinds:
            continue
        try:
            Phi, _ = cf.effect(e)
        except Exception:  # noqa: BLE001 - an effect that cannot build columns on these data
            continue
        d, rel = span_direction(basis, Phi)
        c, c2_after = ident.project(delta, d)
        why = implausible(e, c)
        limit_after = float(stats.chi2.ppf(QUANTILE, max(dof - len(c), 1)))
        directed = c2 - c2_after > stats.chi2.ppf(1 - (1 - QUANTILE) / max(len(candidates), 1), len(c))
        ok = (significant or directed) and not why and c2_after <= limit_after
        reason = ("shift not significant" if not (significant or directed) else why if why else
                  f"remainder chi2 {c2_after:.1f} > {limit_after:.1f}" if c2_after > limit_after else
                  f"explains the shift: chi2 {c2:.1f} -> {c2_after:.1f}")
        entry = {"label": effect_label(e), "kind": e.kind, "joint": e.joint,
                 "parameters": {k: float(v) for k, v in e.parameters(c).items()
                                if isinstance(v, (int, float, np.floating))},
                 "chi2_after": c2_after, "span_residual": float(rel), "accepted": ok, "reason": reason}
        if rel > SPAN_TOL and not ok:  # outside the span and not explaining the shift: not listed
            continue
        if ok:  # ranked by the fit run's error of URDF + effect (step 4's fit)
            th = fit_with_fixed_rigid(cf, chosen + [e], theta0, weights)
            sq = _weighted_sq(cf.data.tau - predict_tau(cf, chosen + [e], th), weights)  # (N, n)
            entry["fit_error_after"] = float(sq.sum())
            fits.append((entry["fit_error_after"], e, th, sq, entry))
        out["span_candidates"].append(entry)
    out["span_candidates"].sort(key=lambda x: (x.get("fit_error_after", np.inf), x["chi2_after"]))
    best = _ranked(cf, fits, theta_nom, chosen, weights, level, out)
    if best is not None:
        e, th = best
        _, _, slices = cf.model(chosen + [e])
        coef = th[slices[-1]]
        params = {k: float(v) for k, v in e.parameters(coef).items() if isinstance(v, (int, float, np.floating))}
        out["named"] = {
            "kind": e.kind, "joint": e.joint, "label": effect_label(e), "parameters": params,
            "coefficients": [float(x) for x in coef],
            "rms_fit_after": _rms(cf.data.tau - predict_tau(cf, chosen + [e], th)),
            "rms_validate_after": _rms(cv.data.tau - predict_tau(cv, chosen + [e], th)),
            "effect": e,
            # (N_val, n) [N m] validation residuals of URDF + effect and URDF alone, for the
            # caller's paired test (not JSON: popped with "effect")
            "residual_validate_after": cv.data.tau - predict_tau(cv, chosen + [e], th),
            "residual_validate_before": rv_nom,
        }
    else:
        out["unexplained_shift"] = significant
    return out


def identifiable_shift(cf, chosen, weights, final_fit, theta0: np.ndarray, sigma_rel: float) -> IdentifiableShift:
    """:class:`IdentifiableShift` of a fit of ``cf.model(chosen)`` with row weights ``weights``:
    G from the column cache's weighted Gram matrix over all rows, Sigma_fit the fit's covariance
    of the base block (its ``cov``; else diag(se^2) with unidentifiable se taken as 0), times
    N / N_eff (``data.n_effective``) when it is the homoscedastic least-squares one (which counts
    every filtered row as independent; the IV covariances carry that factor already)."""
    p0 = len(theta0)
    Gs, _ = cf.gram(chosen, np.asarray(weights, float), [np.ones(cf.data.N, bool)])
    cov = getattr(final_fit, "cov", None)
    kind = str(getattr(final_fit, "covariance", "homoscedastic"))
    if cov is None:
        se = np.where(np.isfinite(final_fit.se[:p0]), final_fit.se[:p0], 0.0)
        cov_b = np.diag(se ** 2)
    else:
        cov_b = np.asarray(cov, float)[:p0, :p0]
    if "N_eff" not in kind and "sandwich" not in kind:
        # homoscedastic least squares counts every filtered row as independent: x N / N_eff
        from robust_drake.identification.data import n_effective

        cov_b = cov_b * cf.data.N / max(n_effective(cf.data), 1.0)
    return IdentifiableShift(Gs[0], p0, cov_b, theta0, sigma_rel)


def resolve_torque_scale(theta_rigid: np.ndarray, se_rigid: np.ndarray, theta0: np.ndarray, joint: int,
                         gain_error: float, n: int, sigma_rel: float = SIGMA_REL) -> dict:
    """Pick the joint of a torque_scale effect against the URDF (module docstring).

    Returns ``{"joint", "gain_error", "swapped", "chi2_as_fitted", "chi2_swapped"}``; only 2-joint
    arms have the single-equivalent ambiguity, other arms return the fitted variant."""
    W = shift_weights(theta0, se_rigid, sigma_rel)
    c_fit = chi2(np.asarray(theta_rigid) - theta0, W)
    if n != 2:
        return {"joint": joint, "gain_error": gain_error, "swapped": False,
                "chi2_as_fitted": c_fit, "chi2_swapped": None}
    from robust_drake.effects import equivalent_gain_error

    alt = np.asarray(theta_rigid) / (1.0 + gain_error)
    c_alt = chi2(alt - theta0, W)
    swap = c_alt < c_fit
    return {"joint": (1 - joint) if swap else joint,
            "gain_error": equivalent_gain_error(gain_error) if swap else gain_error,
            "swapped": bool(swap), "chi2_as_fitted": c_fit, "chi2_swapped": c_alt}


__all__ = ["compare_with_nominal", "resolve_torque_scale", "span_direction", "SpanBasis", "shift_weights",
           "fit_with_fixed_rigid", "SIGMA_REL"]
