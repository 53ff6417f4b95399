"""Residual diagnostics that look where the effect library cannot (issue 13).

Pure functions on an :class:`~robust_drake.identification.data.IdentData` and its residual
r = tau_measured - Y theta_hat (N, n) [N m]. Each test returns the rows that fired, each a dict
with ``test``, ``joint`` (0-based) and where the structure sits (frequency [Hz], time [s] or
torque range [N m]), plus ``variable`` (a readable description) and ``eta2`` (the share of the
residual variance the structure explains) so the rows read like the state-dependence rows of
:mod:`residual` in reports; :func:`diagnose` runs them all. Samples of the filtered residual are
correlated over 1 / (2 f_c) (f_c the data's low-pass cut-off), so standard errors use the
effective count N_eff = N * 2 f_c dt (``data.decimation``).

1. **periodic** (:func:`periodic_peaks`): Hann-windowed, zero-padded periodogram of each file's
   residual, averaged over files. A peak is a local maximum whose power is at least
   ``PEAK_RATIO`` times the spectral floor (median of the band 2/T .. f_c) and which is not a
   harmonic of the motion: at that frequency every joint's velocity spectrum lies below
   ``MOTION_REL`` of its own maximum (a model error driven by the motion sits where the motion
   has power; a disturbance of the environment need not), or the peak lies above twice the
   motion's band (the frequency below which ``MOTION_BAND`` of the velocity power lies, the line
   itself left out) and the velocity there is below ``MOTION_REL_ABOVE`` of its maximum (a light
   arm moves visibly at the disturbance's own frequency: 0.10 on A.0 at 3.1 Hz; peaks at motion
   lines measured >= 0.2, mostly 0.4-1). The frequency is refined by a local
   parabola on log power. Reported: frequency [Hz], amplitude of the sinusoid [N m].
2. **drift** (:func:`friction_drift`): per joint and file, the residual regressed on
   [1, qd_j, sign(qd_j)] on the first and on the last third of the file; the viscous / Coulomb
   coefficients of the two thirds differ by more than ``DRIFT_Z`` standard errors (N_eff-scaled)
   and the implied torque change (|d b| rms(qd) or |d F_c|) is at least ``DRIFT_SHARE`` of the
   residual's RMS. Reported: the coefficients per third, the times of the thirds.
3. **dead-band** (:func:`dead_band`): per joint, the residual regressed on
   [1, tau_j, qd_j, sign(qd_j)] (null: the linear torque term absorbs scale errors and torque
   noise, the velocity terms friction mismatches) and additionally on the saturation
   clip(tau_j, -d, d), d over a grid (quantiles 2-50 % of |tau_j|, and 1/2, 3/4 of the 2 %
   one: a joint that carries a static load seldom enters the band) refined by a bounded 1-D
   search on the residual sum of squares (the fit is nonlinear in d only). Fires when the best d explains at
   least ``DEADBAND_SHARE`` of the residual variance with an F-test p < ``ALPHA`` (N_eff) and its
   coefficient (the share of the torque below d that is lost) lies in ``SAT_SHARE`` (a dead-zone
   loses all of it; other missing effects that correlate with a saturated torque fit shares near
   0: measured |c| <= 0.16 on the twelve library cases of ``simulated.HIDDEN_CASES``, 1.23 on
   a 0.15 N m dead-zone).
   Reported: d [N m], the fitted share c of the saturation (1 = torque below d is lost).
4. **generalization** (:func:`generalization`): validation RMS above ``GEN_RATIO`` times the fit
   RMS on a joint: the model does not generalise (a structure fitted that is not there, or one
   that changes between runs).
5. **reversal** (:func:`reversal`): bursts of residual after the joint's torque reversals -- the
   signature of backlash (:mod:`backlash`): while the gap is crossed the link gets no drive
   torque, then the teeth hit and the contact mode rings, so the burst oscillates and its sign is
   not locked to the reversal's direction (a reversal-locked mean, e.g. signed indicator windows,
   explained only 8 % of the Siciliano elbow's validation residual; its energy 74 %). The
   residual is first cleaned of [1, tau_j, qd_j, sign(qd_j)] and clip(tau_j, -d, d) at six
   quantiles of |tau_j| (friction, scale and any odd function of the torque near zero); then the
   share of its energy within windows from 1 / (2 f_c) before to w in ``REVERSAL_WIDTHS`` after
   each sign change of tau_j (the torque, not the velocity: a Coulomb mismatch steps at velocity
   reversals and sign(qd_j) carries it) is compared with the time the windows take. Fires when
   the excess share >= ``REVERSAL_SHARE``, the mean energy inside / outside >= ``REVERSAL_RATIO``
   with a Goldfeld-Quandt F-test p < ``ALPHA`` (N_eff counts, Bonferroni over widths), and the
   share is at least ``REVERSAL_OVER_VELOCITY`` times the same share after velocity reversals.
   Runs on the fit data and, when given, on the validation data (another motion reverses the
   torque elsewhere: the Siciliano elbow's fit run reverses its torque 3 times, slowly, with no
   visible burst). Measured (8 s battery runs, baseline residual, excess share / energy ratio on
   the backlash joint, fit / validation): Siciliano elbow 0.00 / 0.74 (ratio 114), PUMA waist
   0.25 (3.3) / 0.47 (13.4), serial7 joint 1 0.74 (72) / 0.75 (49). Largest shares elsewhere:
   the twelve ``simulated.HIDDEN_CASES`` on the default, Siciliano and PUMA arms <= 0.26
   (ratio <= 3.3); the no-effect cases <= 0.12 except serial7's last joint (0.41, ratio 6.2, but
   0.40 after velocity reversals too); the outside cases on A.0, Siciliano and PUMA <= 0.26
   (ratio <= 6.2) except the A.0 dead-zone (0.40, ratio 6.7: a driver dead-zone is crossed at
   every torque reversal too; a reversal row on a joint where the dead-band test fired is
   dropped, the dead-band names it); DFKI A.0 <= 0.14 (ratio 1.8) and C.1 0.11-0.15 (ratio
   <= 2.1, p 3e-10 on the fit runs: a real but small concentration; the C.1 motors' ~0.15 deg
   backlash may be part of it, too little to call).
   Reported: the window [s], the share (``eta2``), the energy ratio, which data.
"""

from __future__ import annotations

import numpy as np

from robust_drake.identification.data import decimation

ALPHA = 1e-3  # significance level of every residual test (here and in :mod:`residual`)

PEAK_RATIO = 300.0  # peak power / median spectral floor
MOTION_REL = 1e-2  # velocity power at the peak / its maximum, below which a peak is not the motion's
MOTION_BAND = 0.99  # share of the velocity power below the motion band's upper edge
MOTION_REL_ABOVE = 0.3  # above twice the motion band, a line is the motion's only if this strong
DRIFT_Z = 8.0
DRIFT_SHARE = 0.15
DEADBAND_SHARE = 0.05
SAT_SHARE = (0.5, 1.5)  # fitted share of the saturation term: ~1 for a dead-zone
GEN_RATIO = 1.5
REVERSAL_WIDTHS = (0.1, 0.2, 0.4)  # s after each torque reversal (window starts 1 / (2 f_c) before it)
REVERSAL_SHARE = 0.3  # excess share of the residual energy inside the windows
REVERSAL_RATIO = 5.0  # mean r^2 inside / outside the windows
REVERSAL_OVER_VELOCITY = 2.0  # torque-locked share / the same share locked to velocity reversals


def _segments(data):
    return [np.nonzero(data.segment == s)[0] for s in np.unique(data.segment)]


def averaged_spectrum(data, x: np.ndarray, nfft: int | None = None):
    """(f [Hz], P (F, k)): Hann-windowed periodogram of each file's columns of x (N, k),
    zero-padded to a common ``nfft`` and averaged over files (weighted by length). Amplitude
    normalised: a sinusoid of amplitude A gives a peak of height A^2 / 4 * (sum w)^2 / ... so
    that :func:`sinusoid_amplitude` inverts it."""
    segs = [s for s in _segments(data) if len(s) >= 16]
    L = max(len(s) for s in segs)
    nfft = nfft or int(2 ** np.ceil(np.log2(4 * L)))
    P = 0.0
    wsum = 0
    for s in segs:
        w = np.hanning(len(s))
        y = x[s] - x[s].mean(axis=0)
        F = np.fft.rfft(y * w[:, None], n=nfft, axis=0)
        P = P + len(s) * (np.abs(F) * 2.0 / w.sum()) ** 2  # |.|: amplitude of a sinusoid at a bin
        wsum += len(s)
    f = np.fft.rfftfreq(nfft, d=data.dt)
    return f, P / wsum


def periodic_peaks(data, residual: np.ndarray, peak_ratio: float = PEAK_RATIO,
                   motion_rel: float = MOTION_REL) -> list[dict]:
    """Narrow peaks of the residual's spectrum not explained by the motion's harmonics."""
    f, P = averaged_spectrum(data, residual)
    _, V = averaged_spectrum(data, data.qd)
    Vrel = V / np.maximum(V.max(axis=0), 1e-300)
    lobe = 4.0 / (min(len(s) for s in _segments(data)) * data.dt)  # Hann main-lobe half width [Hz]
    T = min(len(s) for s in _segments(data)) * data.dt
    fc = data.filter.cutoff_hz or 0.5 / data.dt
    band = (f >= 2.0 / T) & (f <= fc)
    out = []
    for j in range(residual.shape[1]):
        p = P[:, j]
        floor = float(np.median(p[band]))
        if floor <= 0:
            continue
        idx = np.nonzero(band)[0]
        k = idx[np.argmax(p[idx])]
        ratio = p[k] / floor
        motion = float(Vrel[k].max())
        # parabolic refinement on log power
        fk = f[k]
        if 0 < k < len(p) - 1 and min(p[k - 1], p[k + 1]) > 0:
            a, b, c = np.log(p[k - 1]), np.log(p[k]), np.log(p[k + 1])
            den = a - 2 * b + c
            if den < 0:
                fk = f[k] + 0.5 * (a - c) / den * (f[1] - f[0])
        # the motion's band, without the line itself (a disturbance moves the joint at its own
        # frequency too)
        Vs = V.sum(axis=1).copy()
        if motion < MOTION_REL_ABOVE:  # a weak line: leave it out of the motion's band
            Vs[np.abs(f - fk) <= lobe] = 0.0
        cum = np.cumsum(Vs)
        f_band = float(f[min(np.searchsorted(cum, MOTION_BAND * cum[-1]), len(f) - 1)])
        amp = float(np.sqrt(p[k]))
        row = {"test": "periodic", "joint": j, "frequency_hz": float(fk),
               "amplitude": amp, "peak_ratio": float(ratio),
               "variable": f"t (periodic {fk:.3f} Hz)",
               "eta2": float(min(1.0, 0.5 * amp ** 2 / max(np.mean(residual[:, j] ** 2), 1e-300))),
               "motion_power_rel": motion, "motion_band_hz": f_band}
        if ratio >= peak_ratio and (motion < motion_rel or (fk > 2.0 * f_band and motion < MOTION_REL_ABOVE)):
            out.append(row)
    return out


def _ols(X, y, n_eff):
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    e = y - X @ coef
    dof = max(n_eff - X.shape[1], 1.0)
    s2 = float(e @ e) / max(len(y) - X.shape[1], 1) * len(y) / max(n_eff, X.shape[1] + 1)
    cov = s2 * np.linalg.pinv(X.T @ X)
    del dof
    return coef, np.sqrt(np.maximum(np.diag(cov), 0.0)), float(e @ e)


def friction_drift(data, residual: np.ndarray, z_min: float = DRIFT_Z, share: float = DRIFT_SHARE) -> list[dict]:
    """Viscous / Coulomb coefficients on the first vs last third of each file (see module doc)."""
    dec = decimation(data)
    out = []
    for j in range(residual.shape[1]):
        best = None
        for s in _segments(data):
            if len(s) < 60:
                continue
            thirds = np.array_split(s, 3)
            fits = []
            for part in (thirds[0], thirds[-1]):
                qd = data.qd[part, j]
                X = np.column_stack([np.ones(len(part)), qd, np.sign(qd)])
                c, se, _ = _ols(X, residual[part, j], len(part) / dec)
                fits.append((c, se, float(np.sqrt(np.mean(qd ** 2)))))
            (c1, s1, v1), (c2, s2, v2) = fits
            rms_r = float(np.sqrt(np.mean(residual[s, j] ** 2))) or 1e-300
            for i, name, size in ((1, "viscous", 0.5 * (v1 + v2)), (2, "coulomb", 1.0)):
                d = c2[i] - c1[i]
                z = abs(d) / max(np.hypot(s1[i], s2[i]), 1e-300)
                eff = abs(d) * size / rms_r
                row = {"test": "drift", "joint": j, "coefficient": name,
                       "first_third": float(c1[i]), "last_third": float(c2[i]), "z": float(z),
                       "torque_share": float(eff),
                       "time_s": [float(data.t[thirds[0][0]]), float(data.t[thirds[-1][-1]])]}
                if z >= z_min and eff >= share and (best is None or z > best["z"]):
                    best = row
        if best is not None:
            best["variable"] = f"t ({best['coefficient']} drift)"
            best["eta2"] = _drift_share(data, residual[:, j], j)
            out.append(best)
    return out


def _drift_share(data, r, j) -> float:
    """Share of r's variance that [t qd_j, t sign qd_j] explain beyond [1, qd_j, sign qd_j]
    (t from each file's start)."""
    t = data.t.copy()
    for s in _segments(data):
        t[s] = t[s] - t[s[0]]
    qd = data.qd[:, j]
    X0 = np.column_stack([np.ones(len(r)), qd, np.sign(qd)])
    X1 = np.column_stack([X0, t * qd, t * np.sign(qd)])
    rss = [float(np.sum((r - X @ np.linalg.lstsq(X, r, rcond=None)[0]) ** 2)) for X in (X0, X1)]
    tot = float(np.sum((r - r.mean()) ** 2)) or 1e-300
    return float((rss[0] - rss[1]) / tot)


def dead_band(data, residual: np.ndarray, share: float = DEADBAND_SHARE, alpha: float = ALPHA) -> list[dict]:
    """Residual vs commanded torque near zero: a saturation clip(tau, -d, d) term (module doc)."""
    from scipy.optimize import minimize_scalar
    from scipy.stats import f as fdist

    n_eff = data.N / decimation(data)
    out = []
    for j in range(residual.shape[1]):
        tau, qd, r = data.tau[:, j], data.qd[:, j], residual[:, j]
        X0 = np.column_stack([np.ones(data.N), tau, qd, np.sign(qd)])
        c0, *_ = np.linalg.lstsq(X0, r, rcond=None)
        rss0 = float(np.sum((r - X0 @ c0) ** 2))
        tot = float(np.sum((r - r.mean()) ** 2)) or 1e-300
        def fit(d):
            X = np.column_stack([X0, np.clip(tau, -d, d)])
            c, *_ = np.linalg.lstsq(X, r, rcond=None)
            return float(np.sum((r - X @ c) ** 2)), float(c[-1])

        qs = np.quantile(np.abs(tau), np.linspace(0.02, 0.5, 12))
        grid = sorted({float(d) for d in np.concatenate([[0.5 * qs[0], 0.75 * qs[0]], qs]) if d > 0})
        if not grid:
            continue
        rss_grid = [fit(d)[0] for d in grid]
        k = int(np.argmin(rss_grid))
        # refine between the neighbouring grid points (bounded 1-D search on the RSS)
        lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
        d = grid[k]
        if hi > lo:
            d = float(minimize_scalar(lambda x: fit(x)[0], bounds=(lo, hi), method="bounded",
                                      options={"xatol": 1e-3 * hi}).x)
        rss, c = fit(d)
        gain = (rss0 - rss) / tot
        F = (rss0 - rss) / max(rss / max(n_eff - 5, 1.0), 1e-300)
        p = float(fdist.sf(F * 1.0, 1, max(n_eff - 5, 1.0)))
        if gain >= share and p < alpha and SAT_SHARE[0] <= c <= SAT_SHARE[1]:
            out.append({"test": "dead_band", "joint": j, "threshold": d, "torque_range": [-d, d],
                        "variable": f"tau{j + 1} (dead band |tau| < {d:.3g})", "eta2": float(gain),
                        "saturation_share": c, "variance_explained": float(gain), "p": p})
    return out


def generalization(fit_residual: np.ndarray, validate_residual: np.ndarray, ratio: float = GEN_RATIO) -> list[dict]:
    """Joints whose validation RMS exceeds ``ratio`` times the fit RMS."""
    rf = np.sqrt(np.mean(np.asarray(fit_residual) ** 2, axis=0))
    rv = np.sqrt(np.mean(np.asarray(validate_residual) ** 2, axis=0))
    return [{"test": "generalization", "joint": j, "rms_fit": float(a), "rms_validate": float(b),
             "ratio": float(b / a), "variable": f"validation (rms x{b / a:.2f} the fit's)",
             "eta2": float(1.0 - (a / b) ** 2)} for j, (a, b) in enumerate(zip(rf, rv)) if a > 0 and b > ratio * a]


def reversals(x: np.ndarray, segment: np.ndarray) -> np.ndarray:
    """Indices k where sign(x) changes between samples k-1 and k of the same file (both nonzero)."""
    s = np.sign(x)
    return np.nonzero((s[:-1] != s[1:]) & (s[:-1] != 0) & (s[1:] != 0) & (segment[:-1] == segment[1:]))[0] + 1


def _near(idx, segment, before: int, after: int) -> np.ndarray:
    """Mask of the samples from ``before`` samples ahead of to ``after`` samples past each index
    in ``idx``, within the index's file."""
    m = np.zeros(len(segment), bool)
    for i in idx:
        sl = slice(max(i - before, 0), min(i + after, len(segment)))
        m[sl] |= segment[sl] == segment[i]
    return m


def reversal_energy(data, e: np.ndarray, x: np.ndarray, widths=REVERSAL_WIDTHS):
    """Concentration of the residual energy e^2 (e (N,) [N m]) after the sign reversals of x.

    For each width w the window mask M runs from 1 / (2 f_c) before each reversal (the
    zero-phase filter smears a burst both ways) to w after it. Returns the best width's dict:
    ``share`` = sum_M e^2 / sum e^2 - |M| / N (the energy's excess over the time the windows
    take), ``ratio`` = mean_M e^2 / mean_~M e^2 and its p-value under a residual of constant
    variance (Goldfeld-Quandt: F(|M| / dec, |~M| / dec), N_eff-scaled, Bonferroni over widths),
    ``width`` [s], ``reversals``."""
    from scipy.stats import f as fdist

    dec = decimation(data)
    idx = reversals(x, data.segment)
    e2 = e ** 2
    tot = float(e2.sum()) or 1e-300
    pre = int(round(0.5 / ((data.filter.cutoff_hz or 0.25 / data.dt) * data.dt)))
    best = {"share": 0.0, "ratio": 1.0, "p": 1.0, "width": None, "reversals": int(len(idx))}
    for w in widths:
        m = _near(idx, data.segment, pre, int(round(w / data.dt)))
        nn, nf = int(m.sum()), int((~m).sum())
        if nn < 2 * dec or nf < 2 * dec:
            continue
        ratio = float(e2[m].mean() / max(e2[~m].mean(), 1e-300))
        share = float(e2[m].sum() / tot - nn / len(e))
        if share > best["share"]:
            p = min(1.0, float(fdist.sf(ratio, nn / dec, nf / dec)) * len(widths))
            best = {"share": share, "ratio": ratio, "p": p, "width": float(w), "reversals": int(len(idx))}
    return best


def reversal_null(tau: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """The columns the residual is cleaned of before :func:`reversal`: [1, tau, qd, sign(qd)]
    (scale errors and friction, as :func:`dead_band`) and clip(tau, -d, d) at d = the 5, 10, 20
    and 40 % quantiles of |tau| (any odd function of the torque near zero, a dead-zone's
    signature: a dead-zone is a function of tau, backlash rings)."""
    d = np.quantile(np.abs(tau), (0.01, 0.02, 0.05, 0.1, 0.2, 0.4))
    return np.column_stack([np.ones(len(tau)), tau, qd, np.sign(qd)] + [np.clip(tau, -x, x) for x in d if x > 0])


def reversal(data, residual: np.ndarray, alpha: float = ALPHA, label: str = "fit") -> list[dict]:
    """Residual bursts after the joint's torque reversals (backlash, module doc 5)."""
    out = []
    for j in range(residual.shape[1]):
        tau, qd, r = data.tau[:, j], data.qd[:, j], residual[:, j]
        X0 = reversal_null(tau, qd)
        e = r - X0 @ np.linalg.lstsq(X0, r, rcond=None)[0]
        T = reversal_energy(data, e, tau)
        V = reversal_energy(data, e, qd)
        if (T["p"] < alpha and T["share"] >= REVERSAL_SHARE and T["ratio"] >= REVERSAL_RATIO
                and T["share"] >= REVERSAL_OVER_VELOCITY * V["share"]):
            ms = 1e3 * T["width"]
            out.append({"test": "reversal", "joint": j, "data": label, "window_s": T["width"],
                        "where": f"within {ms:.0f} ms after torque reversals ({label} data)",
                        "variable": f"tau{j + 1} reversals (residual bursts within {ms:.0f} ms after, {label} data)",
                        "eta2": T["share"], "energy_ratio": T["ratio"], "p": T["p"],
                        "reversals": T["reversals"], "velocity_share": V["share"]})
    return out


def diagnose(data, residual: np.ndarray, validate_residual: np.ndarray | None = None,
             validation=None) -> list[dict]:
    """Every test's rows that fired (empty list: nothing found outside the state-dependence
    tests of :mod:`residual`). ``validation`` = (IdentData, residual) of the validation data:
    the reversal test runs there too (another motion reverses the torque elsewhere)."""
    rows = periodic_peaks(data, residual) + friction_drift(data, residual) + dead_band(data, residual)
    rev = reversal(data, residual) + (reversal(*validation, label="validation") if validation is not None else [])
    dead = {d["joint"] for d in rows if d["test"] == "dead_band"}  # a dead-zone is crossed at each reversal
    rows += [d for d in rev if d["joint"] not in dead]
    if validate_residual is not None:
        rows += generalization(residual, validate_residual)
    return rows


# ------------------------------------------------------------------------------------ moving / stuck rows
def moving_rows(data) -> np.ndarray:
    """(N, n) bool: the rows where joint j MOVES: outside the stuck runs widened by the filter's
    settling (``data.friction_exclusion``, the rows a fit leaves out of joint j's equation) and
    with |qd_j| above the stiction band ``conditioning.STICK_SPEED`` [rad/s]. The complement
    ("still") holds the rows where friction balances whatever torque is applied, which no
    velocity-friction model predicts (sign(qd_j) flips on a standing joint)."""
    from robust_drake.identification.conditioning import STICK_SPEED
    from robust_drake.identification.data import friction_exclusion

    excl = friction_exclusion(data)
    moving = np.abs(np.asarray(data.qd)) > STICK_SPEED
    return moving if excl is None else moving & ~excl


def stuck_rows_split(data, residual: np.ndarray) -> dict:
    """Per-joint RMS of ``residual`` (N, n) [N m] on the moving rows and on the still ones
    (:func:`moving_rows`), and the still rows' share of the samples: ``{"rms_validate_moving",
    "rms_validate_stuck", "stuck_share"}`` (lists per joint; an RMS over no rows is NaN)."""
    r2 = np.asarray(residual, float) ** 2
    mov = moving_rows(data)
    def rms_on(mask):
        cnt = mask.sum(axis=0)
        return [float(np.sqrt(s / c)) if c else float("nan") for s, c in zip((r2 * mask).sum(axis=0), cnt)]
    return {"rms_validate_moving": rms_on(mov), "rms_validate_stuck": rms_on(~mov),
            "stuck_share": [float(x) for x in (~mov).mean(axis=0)]}


# ------------------------------------------------------------------------------------ setup change
def setup_change(e_fit: np.ndarray, rows_fit: np.ndarray, seg_fit: np.ndarray, block_fit: int,
                 e_val: np.ndarray, rows_val: np.ndarray, seg_val: np.ndarray, block_val: int,
                 level: float | None = None) -> dict:
    """Does the validation run match the fit run? Per joint j, the validation error's mean square
    on its moving rows against the fit model's OUT-OF-SAMPLE mean square on the fit run's own
    held-out moving rows (both (N, n) squared-error arrays ``e_*``, the rows ``rows_*`` (N, n)
    bool, segments ``seg_*``, block lengths ``block_*`` [samples]), by
    :func:`decisions.unpaired_test` (two different row sets: each side's block-mean spread), with
    Holm's correction over the joints at family-wise (1 - level) / 2 one-sided. Flagged joints:
    validation error beyond what the fit run's own held-out error and its spread explain (a
    payload mounted, a sensor re-zeroed, another arm between the runs).

    Returns ``{"flagged", "joints", "level", "tests": [{"joint", "ratio" (validation / held-out
    RMS), "ratio_low", "ratio_high", ...PairedTest.as_dict()}], "rule"}``."""
    from robust_drake.model_repair.decisions import LEVEL, block_ids, holm, unpaired_test

    level = LEVEL if level is None else level
    n = e_fit.shape[1]
    tests = []
    for j in range(n):
        ia = block_ids(seg_fit, len(seg_fit), block_fit, rows_fit[:, j])
        ic = block_ids(seg_val, len(seg_val), block_val, rows_val[:, j])
        tests.append(unpaired_test(e_fit[:, j], ia, e_val[:, j], ic, level))
    flags = holm([t.p_worse for t in tests], (1.0 - level) / 2.0)
    rows = [{"joint": j, "ratio": t.estimate + 1.0, "ratio_low": t.low + 1.0, "ratio_high": t.high + 1.0,
             **t.as_dict(), "worse": bool(f)} for j, (t, f) in enumerate(zip(tests, flags))]
    joints = [r["joint"] for r in rows if r["worse"]]
    return {"flagged": bool(joints), "joints": joints, "level": level, "tests": rows,
            "rule": "per joint, the validation RMS torque error on the moving rows (|qd| above the stiction band, "
                    "outside stuck runs) against the baseline's out-of-sample error on the fit run's held-out "
                    "(confirmation) rows, unpaired block test (each side's block-mean spread), Holm over joints, "
                    f"one-sided at {(1.0 - level) / 2.0:.1%}"}


def setup_change_text(sc: dict, joint_names) -> str:
    """The warning of a flagged :func:`setup_change`: the joints, each with its RMS ratio and
    interval."""
    parts = [f"joint {r['joint'] + 1} ({joint_names[r['joint']]}) x{r['ratio']:.2g} "
             f"[{r['ratio_low']:.2g}, {r['ratio_high']:.2g}]" for r in sc["tests"] if r["worse"]]
    return ("setup changed between fit and validation: the validation RMS torque error on moving rows is above the "
            "fit run's own held-out error beyond its spread on " + ", ".join(parts)
            + f" ({sc['level']:.0%} intervals of the RMS ratio): a payload, a re-zeroed sensor or another arm? "
            "no effect is claimed on the strength of this validation")


def setup_explained(sc: dict, fit_cache, weights, fit_residual, val_data, val_residual, effects,
                    level: float | None = None) -> dict:
    """The baseline's :func:`setup_change_of` ``sc`` re-judged with the repair's kept ``effects``:
    an effect missing from the baseline can make the validation run's error differ from the fit
    run's (the two motions excite it differently), but a setup change (a payload mounted or a
    sensor re-zeroed between the runs) cannot be explained by effects fitted on the fit run alone.
    If no joint is flagged any more with the effects in both sides (the fit run's held-out error
    of the model with them, and ``val_residual``, that model's validation error), ``sc`` is
    returned unflagged with ``explained_by_effects`` (the test with the effects) and the baseline's
    flags under ``baseline_joints``; otherwise ``sc`` with the repaired model's test beside it
    (``with_effects``)."""
    if not sc.get("flagged") or not effects:
        return sc
    again = setup_change_of(fit_cache, weights, fit_residual, val_data, val_residual, level=level, effects=effects)
    out = dict(sc)
    if again["flagged"]:
        out["with_effects"] = again
        return out
    out.update(flagged=False, joints=[], baseline_joints=list(sc["joints"]), explained_by_effects=again)
    return out


def heldout_residual(cache, weights, train: np.ndarray, test: np.ndarray, effects=()) -> np.ndarray:
    """(N, n) [N m]: the baseline (rigid body + Coulomb + viscous) with ``effects`` fitted by
    weighted least squares on the ``train`` rows of ``cache`` (a ``fitting.ColumnCache``) and its
    output error on the ``test`` rows (0 elsewhere): the fit run's own out-of-sample error."""
    from robust_drake.identification.fitting import predict_tau
    from robust_drake.identification.least_squares import RANK_TOL, solve_gram

    effects = list(effects)
    Gs, gs = cache.gram(effects, np.asarray(weights, float), [np.asarray(train, bool)])
    theta = solve_gram(Gs[0], gs[0], tol=RANK_TOL)[0]
    r = np.zeros_like(cache.data.tau)
    r[test] = cache.data.tau[test] - predict_tau(cache, effects, theta, test)
    return r


def setup_change_of(fit_cache, weights, fit_residual: np.ndarray, val_data, val_residual: np.ndarray,
                    level: float | None = None, effects=()) -> dict:
    """:func:`setup_change` of a repair: the fit side is the baseline refitted on the selection's
    search rows and scored on its confirmation block (``selection.selection_split``: the last
    ``CONFIRM_FRACTION`` of every fit segment, behind a gap of filter settling + residual
    correlation time), the validation side the baseline (fitted on all fit rows) on the
    validation data, ``val_residual``; both on their moving rows (:func:`moving_rows`). Blocks:
    ``decisions.block_length`` of the baseline residual's correlation time and the filter's
    settling time, in each side's own sample period. Computed once from the baseline (no effect
    in the reference); with ``effects`` (and ``val_residual`` the model with them) the same test
    of the repaired model, :func:`setup_explained`."""
    from robust_drake.model_repair.decisions import block_length
    from robust_drake.model_repair.selection import correlation_time, filter_settling_time, selection_split

    fit = fit_cache.source
    split, _ = selection_split(fit, fit_residual)
    confirm = split.confirm if split.confirm.any() else np.ones(fit.N, bool)
    train = split.search if split.confirm.any() else np.ones(fit.N, bool)
    r_fit = heldout_residual(fit_cache, weights, train, confirm, effects)
    rows_fit = moving_rows(fit) & confirm[:, None]
    if fit_cache.exclude is not None:
        rows_fit &= ~fit_cache.exclude
    rows_val = moving_rows(val_data)
    t_r = correlation_time(fit, fit_residual)
    t_f = filter_settling_time(fit.filter.cutoff_hz, fit.filter.order or 1)
    shortest = lambda d, m: min(int(np.sum((d.segment == s) & m)) for s in np.unique(d.segment[m]))  # noqa: E731
    b_fit = block_length(fit.dt, t_r, t_f, rows=shortest(fit, confirm))
    b_val = block_length(val_data.dt, t_r, t_f, rows=shortest(val_data, np.ones(val_data.N, bool)))
    out = setup_change(r_fit ** 2, rows_fit, fit.segment, b_fit, np.asarray(val_residual) ** 2, rows_val,
                       val_data.segment, b_val, level)
    out.update(block_fit=int(b_fit), block_validate=int(b_val), correlation_time_s=float(t_r),
               filter_settling_s=float(t_f))
    return out
