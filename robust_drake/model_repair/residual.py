"""Residual analysis: r = tau_measured - Y theta_hat against the state, time and frequency.

Tests (all on the parallel-filtered residual, whose samples are correlated over 1 / (2 f_c);
every significance level uses the effective sample count N_eff = N * 2 f_c dt):

- **state dependence** (correlation ratio): for each joint's residual r_j and each explanatory
  variable x in {q_i, qd_i, sign(qd_i), qdd_i, tau_i, t}, bin x into quantile bins and compute
  eta^2 = var(bin means of r_j) / var(r_j), the share of the residual variance that a
  (nonlinear, arbitrary) function of x explains. F = eta^2/(k-1) / ((1-eta^2)/(N_eff-k)).
  Significant structure: eta^2 >= ``ETA_MIN`` and p < ``ALPHA``, for x a state variable or t.
  The measured torque tau_i is reported but does not raise the flag: noise e in the measured
  torque makes r correlate with tau = tau_true + e by construction (eta^2 ~ var e / var tau),
  so dependence on tau alone is not evidence of a missing effect.
- **whiteness**: Ljung-Box Q on the residual decimated to the filter's Nyquist rate
  (step = 1 / (2 f_c dt)), ``LAGS`` lags. Reported; strong colour (lag-1 autocorrelation above
  ``RHO_MAX`` at that rate and p < ALPHA) also counts as structure.
- **velocity reversals**: the mean residual in a +-``REVERSAL_WINDOW`` window around every zero
  crossing of qd_i (where stiction, backlash and Stribeck effects live), for plots and reports.
- **spectrum**: Welch PSD of each joint's residual, with its largest peak.

``unexplained_structure`` is true when any of these flags remains after selection; ``where``
names the joint and variable(s) that carry it.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

import numpy as np

from robust_drake.identification.data import IdentData, decimation
from robust_drake.model_repair.diagnostics import ALPHA, diagnose

ETA_MIN = 0.05
BINS = 12
LAGS = 10
RHO_MAX = 0.5
REVERSAL_WINDOW = 0.1  # s


def signal_name(kind: str, j: int) -> str:
    """The name of joint index ``j``'s (0-based) signal ``kind``: the joint NUMBER from 1, as the
    CSV columns and ``SimulationResult.to_pandas`` (``signal_name("q", 0) == "q1"``)."""
    return f"{kind}{j + 1}"


_SIGNAL = re.compile(r"^(q|qd|sign_qd|qdd|tau)(\d+)$")


def signal_joint(name: str) -> tuple[str, int] | None:
    """(kind, 0-based joint index) of a :func:`signal_name` (``"qd2"`` -> ("qd", 1)), else None."""
    m = _SIGNAL.match(str(name))
    return (m.group(1), int(m.group(2)) - 1) if m else None


def explanatory_variables(data: IdentData) -> dict[str, np.ndarray]:
    out = {}
    for i in range(data.n):
        out[signal_name("q", i)] = data.q[:, i]  # q1, qd1, ...: joints numbered from 1
        out[signal_name("qd", i)] = data.qd[:, i]
        out[signal_name("sign_qd", i)] = np.sign(data.qd[:, i])
        out[signal_name("qdd", i)] = data.qdd[:, i]
        out[signal_name("tau", i)] = data.tau[:, i]
    out["t"] = data.t
    return out


def correlation_ratio(x: np.ndarray, r: np.ndarray, bins: int = BINS) -> tuple[float, int]:
    """eta^2 of ``r`` given quantile bins of ``x`` (and the number of non-empty bins)."""
    uniq = np.unique(x)
    if len(uniq) <= bins:
        labels = np.searchsorted(uniq, x)
    else:
        edges = np.quantile(x, np.linspace(0, 1, bins + 1)[1:-1])
        labels = np.searchsorted(edges, x, side="right")
    counts = np.bincount(labels)
    sums = np.bincount(labels, weights=r)
    nz = counts > 0
    means = sums[nz] / counts[nz]
    total = float(np.sum((r - r.mean()) ** 2))
    if total <= 0:
        return 0.0, int(nz.sum())
    between = float(np.sum(counts[nz] * (means - r.mean()) ** 2))
    return between / total, int(nz.sum())


def state_dependence(data: IdentData, residual: np.ndarray, bins: int = BINS) -> list[dict]:
    """eta^2 and its p-value for every (residual joint, variable) pair, strongest first."""
    from scipy.stats import f as fdist

    n_eff = max(float(data.N) / decimation(data), bins + 2.0)
    rows = []
    for j in range(residual.shape[1]):
        for name, x in explanatory_variables(data).items():
            eta2, k = correlation_ratio(x, residual[:, j], bins)
            if k < 2:
                continue
            F = (eta2 / (k - 1)) / max((1 - eta2) / (n_eff - k), 1e-300)
            rows.append({"joint": j, "variable": name, "eta2": eta2, "p": float(fdist.sf(F, k - 1, n_eff - k))})
    rows.sort(key=lambda d: -d["eta2"])
    return rows


def configuration_dependence(dependence: list[dict], n: int, alpha: float = ALPHA) -> list[dict]:
    """Rows ``test = "configuration_dependence"`` (joint j, variable q<k>, eta2, p, level) where
    the residual of joint j depends on the angle of another joint k != j: the F test of
    :func:`state_dependence` (N_eff samples) at level ``alpha`` / (n (n - 1)) (Bonferroni over
    the ordered joint pairs). What offers ``configuration_dependent[j]`` to the selection (which
    then decides on held-out error); it does not set ``unexplained_structure``."""
    level = alpha / max(n * (n - 1), 1)
    out = []
    for d in dependence:
        v = d["variable"]
        sj = signal_joint(v)
        if sj is None or sj[0] != "q" or sj[1] == d["joint"] or not d["p"] < level:
            continue
        out.append({"test": "configuration_dependence", "joint": d["joint"], "variable": v,
                    "eta2": round(d["eta2"], 4), "p": float(d["p"]), "level": level})
    return out


def ljung_box(x: np.ndarray, lags: int = LAGS) -> tuple[float, float, float]:
    """(Q, p, rho_1) of the Ljung-Box test."""
    from scipy.stats import chi2

    x = x - x.mean()
    n = len(x)
    denom = float(x @ x)
    if denom <= 0 or n <= lags + 1:
        return 0.0, 1.0, 0.0
    rho = np.array([float(x[:-k] @ x[k:]) / denom for k in range(1, lags + 1)])
    Q = n * (n + 2) * float(np.sum(rho**2 / (n - np.arange(1, lags + 1))))
    return Q, float(chi2.sf(Q, lags)), float(rho[0])


def whiteness(data: IdentData, residual: np.ndarray) -> list[dict]:
    step = decimation(data)
    out = []
    for j in range(residual.shape[1]):
        parts = [residual[data.segment == s, j][::step] for s in np.unique(data.segment)]
        # Ljung-Box per segment, combined by summing Q (independent files)
        Qs, rhos, dof = 0.0, [], 0
        for p in parts:
            Q, _, r1 = ljung_box(p)
            Qs += Q
            rhos.append(r1)
            dof += LAGS
        from scipy.stats import chi2

        out.append({"joint": j, "Q": Qs, "p": float(chi2.sf(Qs, dof)), "rho1": float(np.mean(rhos)),
                    "decimation": step})
    return out


def reversal_profile(data: IdentData, residual: np.ndarray, joint: int, window: float = REVERSAL_WINDOW):
    """Mean residual of every joint vs time from each zero crossing of qd_joint: (tau_axis, mean (K, n))."""
    half = max(1, int(round(window / data.dt)))
    qd = data.qd[:, joint]
    idx = np.nonzero((np.sign(qd[:-1]) != np.sign(qd[1:])) & (data.segment[:-1] == data.segment[1:]))[0]
    idx = idx[(idx >= half) & (idx < data.N - half)]
    lag = np.arange(-half, half + 1)
    if len(idx) == 0:
        return lag * data.dt, np.full((len(lag), residual.shape[1]), np.nan), 0
    sgn = np.sign(qd[idx + 1])[:, None, None]  # align: positive after the crossing
    stack = residual[idx[:, None] + lag[None, :]] * sgn
    return lag * data.dt, stack.mean(axis=0), len(idx)


def spectrum(residual: np.ndarray, dt: float):
    from scipy.signal import welch

    nper = min(1024, residual.shape[0])
    f, P = welch(residual, fs=1.0 / dt, nperseg=nper, axis=0)
    return f, P


def analyse(data: IdentData, residual: np.ndarray, eta_min: float = ETA_MIN, alpha: float = ALPHA,
            validate_residual: np.ndarray | None = None, validation=None) -> dict:
    """All tests; ``unexplained_structure`` and ``where`` if flagged.

    ``where`` lists first the rows of :func:`diagnostics.diagnose` (``test`` = ``periodic`` with
    ``frequency_hz``, ``drift`` with the coefficients of the first / last third and their times,
    ``dead_band`` with the torque range, ``generalization`` when ``validate_residual`` is given),
    then the state-dependence rows (``test`` = ``state_dependence``: joint, variable, eta2).
    ``validation`` = (IdentData, residual) of the validation data: the reversal test runs there
    too (``test`` = ``reversal`` with ``data`` = ``validation``). ``configuration_dependence``:
    the rows of :func:`configuration_dependence` (a joint's residual against other joints'
    angles), which offer the ``configuration_dependent`` kind."""
    diag = diagnose(data, residual, validate_residual, validation=validation)
    dep = state_dependence(data, residual)
    white = whiteness(data, residual)
    where = [d for d in dep if d["eta2"] >= eta_min and d["p"] < alpha and not d["variable"].startswith("tau")]
    coloured = [w for w in white if w["p"] < alpha and w["rho1"] > RHO_MAX]
    f, P = spectrum(residual, data.dt)
    peaks = [float(f[1:][np.argmax(P[1:, j])]) for j in range(residual.shape[1])]
    rms = np.sqrt(np.mean(residual**2, axis=0))
    return {
        "unexplained_structure": bool(where or coloured or diag),
        "where": diag + [{"test": "state_dependence", "joint": d["joint"], "variable": d["variable"],
                          "eta2": round(d["eta2"], 4)} for d in where[:6]],
        "diagnostics": diag,
        "configuration_dependence": configuration_dependence(dep, data.n, alpha),
        "coloured": [{"joint": w["joint"], "rho1": round(w["rho1"], 3)} for w in coloured],
        "state_dependence_top": [{k: (round(v, 5) if isinstance(v, float) else v) for k, v in d.items()} for d in dep[:8]],
        "whiteness": white,
        "spectrum_peak_hz": peaks,
        "rms": [float(x) for x in rms],
    }


if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

#: the state variables the residual is plotted against, with their SI units
RESIDUAL_AXES = (("q", "rad"), ("qd", "rad/s"), ("qdd", "rad/s^2"), ("tau", "N m"))
#: spectra are drawn down to this fraction of their largest value (Welch floors reach 1e-20)
SPECTRUM_FLOOR = 1e-6


def _binned_mean(x: np.ndarray, r: np.ndarray, bins: int = 16, min_count: int = 20):
    """Mean of ``r`` in ``bins`` equal-width bins of ``x`` over its 1-99 % range (bins with fewer
    than ``min_count`` samples dropped): (bin centres, means)."""
    from scipy.stats import binned_statistic

    lo, hi = np.quantile(x, [0.01, 0.99])
    if not hi > lo:
        return np.array([lo]), np.array([r.mean()])
    inside = (x >= lo) & (x <= hi)
    mean, edges, _ = binned_statistic(x[inside], r[inside], "mean", bins=bins, range=(lo, hi))
    count = binned_statistic(x[inside], r[inside], "count", bins=bins, range=(lo, hi))[0]
    ok = count >= min_count
    return 0.5 * (edges[:-1] + edges[1:])[ok], mean[ok]


def _spectrum_panel(ax, data: IdentData, series) -> None:
    """Welch PSD of each joint's residual [(N m)^2/Hz], clipped at SPECTRUM_FLOOR of the max."""
    top = 0.0
    for r, lab, colr in series:
        f, P = spectrum(r, data.dt)
        for j in range(data.n):
            ax.semilogy(f[1:], P[1:, j], color=colr, ls=("-", "--", ":", "-.")[j % 4], lw=1.2)
            top = max(top, float(np.nanmax(P[1:, j])) if len(f) > 1 else 0.0)
    if top > 0:
        ax.set_ylim(top * SPECTRUM_FLOOR, top * 2)
    ax.set_xlim(0, min(0.5 / data.dt, 4 * (data.filter.cutoff_hz or 25)))
    ax.set(xlabel="frequency [Hz]", ylabel="residual PSD [(N m)^2/Hz]", title="spectrum")


def _reversal_panel(ax, data: IdentData, series) -> None:
    """Mean residual of joint j around the zero crossings of qd_j [N m] vs time [s]."""
    for r, lab, colr in series:
        for j in range(data.n):
            lag, prof, k = reversal_profile(data, r, j)
            ax.plot(lag, prof[:, j], color=colr, ls=("-", "--", ":", "-.")[j % 4], lw=1.2,
                    label=f"{lab}, joint {j + 1}: {k} reversals")
    ax.axvline(0, color="0.5", lw=0.6)
    ax.set(xlabel="time from qd_j reversal [s]", ylabel="mean residual r_j [N m]",
           title="around velocity reversals")
    ax.legend(fontsize=8.5, loc="upper left", bbox_to_anchor=(1.02, 1.0), frameon=False)


def residual_figure(data: IdentData, residual: np.ndarray, title: str = "residual",
                    other: np.ndarray | None = None, labels=("baseline", "repaired")) -> "Figure":
    """The torque residual r = tau_meas - tau_model [N m] against the state, its spectrum and
    its mean around velocity reversals, as one matplotlib ``Figure`` of six panels.

    Every panel holds all joints (numbered from 1 as in the report; line style: joint 1 solid,
    joint 2 dashed, ...) and both
    models (colour: ``residual`` red, ``other`` blue); the state panels show the mean residual
    in 16 equal bins (1-99 % range) of q_j [rad], qd_j [rad/s], qdd_j [rad/s^2] and tau_j [N m].

    Parameters
    ----------
    data : IdentData
        The samples the residual belongs to.
    residual : numpy.ndarray
        (N, n) residual of the first model [N m].
    title : str
        Figure title.
    other : numpy.ndarray, optional
        (N, n) residual of a second model (e.g. after repair) [N m].
    labels : tuple of str
        Legend names of ``residual`` and ``other``.

    Returns
    -------
    matplotlib.figure.Figure
        Detached from pyplot.
    """
    from robust_drake.plotting import style

    with style():
        return _residual_figure(data, residual, title, other, labels)


def _residual_figure(data, residual, title, other, labels):
    from robust_drake.plotting import subplots

    series = [(residual, labels[0], "tab:red")] + ([(other, labels[1], "tab:blue")] if other is not None else [])
    fig, axes = subplots(2, 3, figsize=(14, 8.5), squeeze=False)
    for ax, (name, unit) in zip(axes.flat, RESIDUAL_AXES):
        for r, lab, colr in series:
            for j in range(data.n):
                mid, mean = _binned_mean(getattr(data, name)[:, j], r[:, j])
                ax.plot(mid, mean, color=colr, ls=("-", "--", ":", "-.")[j % 4], lw=1.4, marker=".", ms=4)
        ax.axhline(0, color="0.5", lw=0.6)
        ax.set(xlabel=f"{name}_j [{unit}]", ylabel="mean residual r_j [N m]", title=f"vs {name}")
    _spectrum_panel(axes[1, 1], data, series)
    _reversal_panel(axes[1, 2], data, series)
    for ax in axes.flat:
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def plot_residuals(data: IdentData, residual: np.ndarray, path: str, title: str = "residual",
                   other: np.ndarray | None = None, labels=("baseline", "repaired")) -> str:
    """Write :func:`residual_figure` to ``path`` (PNG); returns ``path``."""
    residual_figure(data, residual, title, other, labels).savefig(path, dpi=80)
    return path
