"""Forward selection over the effect library, judged on held-out error the search never fitted.

Model structure: rigid-body base columns + Coulomb/viscous friction (the baseline) + the chosen
effects' columns (``Effect.columns``). All columns are parallel-filtered like the torque.

Rows (per gap-free segment of every file, :func:`selection_split`)::

    | search rows (blocked K-fold CV)              | gap | confirmation block (last 20 %) |
    | block 0 | gap | block 1 | ... | block K-1    |

* **Gap** (:func:`gap_samples`): training rows within ``g`` samples of a held-out block (same
  segment) are dropped from that fold's training set, and the confirmation block is separated from
  the search rows by ``g``. g = filter settling time + residual correlation time:
  - the zero-phase Butterworth low-pass (order m, cut-off f_c) spreads every sample over its
    impulse response; its slowest pole has real part sigma = 2 pi f_c sin(pi / (2 m)), so it
    settles to 1 % after t_f = ln(100) / sigma (8 Hz, order 4: 0.24 s) -- per side (filtfilt
    spreads it both ways, and the gap is applied on both sides);
  - the baseline residual's correlation time t_r: the first lag where its autocorrelation (mean
    over the segments, largest over the joints) falls below 1/e;
  - g = round((t_f + t_r) / dt), capped at ``GAP_CAP`` of a CV block (so that training rows
    remain). The issue's measurement: with no gap two accepted gains of 14.9 % and 14.7 % were
    -1.4 % and 0.8 % with a 0.5 s gap -- the held-out block was predicted from its own
    filtered, correlated neighbours.
* **Confirmation block** (guard against the best of many, :func:`confirm_rows`): the last
  ``CONFIRM_FRACTION`` of every segment is never used by the search (no CV fold trains or tests on
  it). A candidate picked on the CV (its score biased low by the pick itself among ~50) is judged
  on the one set of rows no candidate was picked on. A confirmation block was chosen over a null
  distribution of the best gain because it costs one fit per candidate tested (a permutation null
  would refit every candidate many times on correlated data) and because it also guards against
  structure that lives only in the early part of the runs.
* **Fold fits** (:func:`heldout_residuals`): every fold is solved on the identifiable subspace of
  the whole data's Gram matrix at the same ``RANK_TOL`` as every other fit
  (:func:`identifiable_basis`): a fold cannot fit a direction the whole data cannot see. (Issue 21:
  with the earlier fold tolerance 1e-10 the baseline's held-out error on a simulated 6-axis arm
  was 646 instead of 1.18, and any added column looked like an 80-99 % gain.)
* **Physical admissibility**: every kind's fitted parameters must satisfy its own rule
  (``Effect.admissible``, with :class:`~robust_drake.effects.PhysicalContext`: the
  fit's Coulomb/viscous levels, torque range, duration, analysis band, the delay bound from the
  robot description); an inadmissible fit is rejected before its CV score is computed.

Step rule (greedy forward, one effect per step; issue 21). Each effect is **judged on the error of
its own joint** (an effect without a joint: all joints pooled, rows weighted by 1/sigma_j), so a
single-joint effect is not diluted by the other joints. Every remaining candidate is fitted and
ranked by its CV gain on that error; then, from the top of the ranking:

    1. screen: CV gain >= ``min_gain / 2`` (a cheap pre-filter; below it the step stops);
    2. degenerate rivals (:func:`_degenerate`): a candidate of another kind or joint judged on the
       same error, passing the screen, significantly better than the current model but not
       significantly worse than the candidate (paired block tests of the CV errors on the search
       rows) -- "degenerate: the data cannot rank these", none of them is accepted (they leave
       the pool);
    3. noise floor: the effect's explained RMS (its filtered columns x coefficients, on its joint;
       pooled: the RMS over joints of the ratios) must reach the residual's white-noise level
       (:func:`white_noise_level`, reported per joint in ``rows``);
    4. confirmation: a paired block test (``decisions.paired_test``) of the candidate vs the
       current model's squared errors on the confirmation rows (both fitted on the search rows;
       the current model's errors computed once per step), blocks of ``decisions.block_length``
       (3 residual correlation times + the filter's settling time; a shorter segment is one block;
       cut to a quarter of the shortest segment only when fewer than ``decisions.MIN_BLOCKS``
       blocks remain). Accepted when p_better < alpha_k.
    Multiple-comparison guard: up to 1 + ``next_tries`` (``NEXT_TRIES`` = 3) candidates of a step
    reach test 4, tried in ranking order when the ones above fail (a candidate refused by 2 or 3
    spends no test: it never reaches one; at most 4 (1 + ``next_tries``) candidates are looked at); weighted Bonferroni, the winner
    at alpha / 2 and each next-ranked at alpha / (2 next_tries), alpha = (1 - ``level``) / 2 one-sided
    (``level`` default ``decisions.LEVEL``), so the step's false-acceptance rate is at most alpha.
    A step that accepts nothing ends the search; so on data with no effect the whole search
    accepts something with probability at most alpha. ``confirm_gain`` (a number) adds an
    effect-size bar on the confirmation gain. Without a confirmation block (every segment too
    short) the CV gain must reach ``min_gain`` (not a calibrated test: said in the reason).
At the end (:func:`_recheck`) every accepted effect is re-checked on the confirmation block: its
marginal contribution (all accepted vs all but it, Holm over the accepted at alpha), the weakest
that no longer holds removed and the rest re-tested; then all together vs the baseline (per joint
they act on, Holm).
The score of a model = mean held-out weighted squared output error, normalised by the baseline's
(``Step.gain`` pooled as before, ``Step.joint_gain`` on the judged error). The BIC is reported per
step for information (``bic_before`` / ``bic_after``), not a rule.
A shared candidate (one parameter for all joints: a command delay) is ranked just above the
best single-joint candidate of its kind that it explains as well (:func:`_shared_first`).
Shape-parameter variants (a Stribeck velocity, a delay) are separate candidates; once an effect of
a kind/joint is chosen the other variants of the same kind and joint leave the pool.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from robust_drake.identification.data import IdentData, n_effective
from robust_drake.identification.fitting import (  # noqa: F401  (re-exported)
    ColumnCache, effect_label, fit_model, implicit_mask, predict, predict_tau,
)
from robust_drake.identification.instruments import fit_iv_blocks, solve_iv  # noqa: F401
from robust_drake.identification.least_squares import RANK_TOL, _gram_eig, identifiability, solve_ls  # noqa: F401

MIN_GAIN = 0.05
CV_FOLDS = 4
#: last share of every segment held out from the search (the confirmation block)
CONFIRM_FRACTION = 0.2
#: the gap is at most this share of a CV block (training rows must remain)
GAP_CAP = 0.25
#: the residual's correlation time is the first lag where its autocorrelation falls below this
CORRELATION_THRESHOLD = math.exp(-1.0)
#: settling of the filter's slowest mode to this fraction of its start
SETTLE_TO = 0.01


def implausible(effect, coef, context=None) -> str:
    """Empty string if the effect's fitted parameters are admissible (``Effect.admissible`` with
    ``context``, a :class:`~robust_drake.effects.PhysicalContext`), else the reason."""
    try:
        params = effect.parameters(coef)
    except Exception as exc:  # noqa: BLE001
        return f"parameters failed: {exc}"
    return effect.admissible(params, context)


# ------------------------------------------------------------------------------------ the gap
def filter_settling_time(cutoff_hz: float | None, order: int) -> float:
    """Time [s] for the slowest mode of an order-``order`` Butterworth low-pass at ``cutoff_hz``
    to decay to ``SETTLE_TO``: its poles lie on the circle of radius w_c = 2 pi f_c at angles
    pi (2k + 1) / (2 m) from the imaginary axis, the slowest with real part w_c sin(pi / (2 m)),
    so t_f = ln(1 / SETTLE_TO) / (w_c sin(pi / (2 m))). 0 without a filter."""
    if not cutoff_hz:
        return 0.0
    sigma = 2.0 * math.pi * float(cutoff_hz) * math.sin(math.pi / (2.0 * int(order)))
    return math.log(1.0 / SETTLE_TO) / sigma


def correlation_time(data: IdentData, residual: np.ndarray, threshold: float = CORRELATION_THRESHOLD) -> float:
    """Correlation time [s] of ``residual`` (N, n): the first lag at which its autocorrelation,
    pooled over the gap-free segments (sum of lagged products over the sum of squares), falls
    below ``threshold``; the largest over the joints. Lags up to half the shortest segment."""
    from robust_drake.identification.data import pooled_autocorrelation

    rho = pooled_autocorrelation(residual, data.segment)
    max_lag = rho.shape[0]
    lags = []
    for j in range(rho.shape[1]):
        below = np.nonzero(rho[:, j] < threshold)[0]
        lags.append(int(below[0]) if len(below) else max_lag)
    return float(max(lags)) * float(data.dt)


def gap_samples(data: IdentData, residual: np.ndarray, folds: int = CV_FOLDS,
                confirm_fraction: float = CONFIRM_FRACTION) -> tuple[int, dict]:
    """The gap g [samples] between training and held-out rows (module docstring): filter
    settling time + residual correlation time, capped at ``GAP_CAP`` of the shortest CV block."""
    t_f = filter_settling_time(data.filter.cutoff_hz, data.filter.order)
    t_r = correlation_time(data, residual)
    L = min(int(np.sum(data.segment == s)) for s in np.unique(data.segment))
    cap = int(GAP_CAP * L * (1.0 - confirm_fraction) / folds)
    want = int(round((t_f + t_r) / data.dt))
    g = min(want, cap)
    info = {"gap_samples": g, "gap_s": g * float(data.dt), "filter_settling_s": t_f,
            "correlation_time_s": t_r, "capped": want > cap}
    return g, info


# ------------------------------------------------------------------------------------ noise floor
#: the white-noise level is read from the residual's spectrum on this share of the band below the
#: filter's cut-off f_c: [NOISE_BAND[0] f_c, NOISE_BAND[1] f_c] (no filter: of the Nyquist frequency)
NOISE_BAND = (0.5, 1.0)


def white_noise_level(data: IdentData, residual: np.ndarray, keep: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
    """Per-joint white-noise level sigma_j [N m] of the residual (N, n) of the filtered torque: the
    RMS that white noise of the residual's own level keeps after the zero-phase filter -- the
    floor an effect's explained RMS (of filtered columns) is compared with, like with like.

    Method: the residual's one-sided power spectral density P_j(f) (Welch, per segment, averaged
    with the segments' lengths as weights) divided by the zero-phase filter's power gain
    |H(f)|^4 (Butterworth applied forward and backward) is the white level N0_j where the residual
    is noise; it is averaged over the upper part of the filter's passband ``NOISE_BAND`` x f_c
    (there the motion's structure is weakest and the filter still passes the noise: |H|^4 >= 1/4),
    and sigma_j^2 = N0_j int_0^{f_s/2} |H(f)|^4 df. The per-sample equivalent sqrt(N0_j f_s / 2)
    (white noise of variance s^2 has density 2 s^2 / f_s) is reported as ``noise_sample_std``:
    it grows with the sampling rate and is not a floor (the filter averages it down).
    Why not the first-difference variance: the torque is filtered, so neighbouring residual
    samples are correlated by the filter and a difference mostly cancels the noise too. What the
    band holds besides the torque sensor's noise (twice-differentiated encoder noise in the
    regressor, broadband friction errors at reversals) raises the estimate: the floor errs towards
    refusing. ``keep`` (N, n): rows in use (excluded rows hold zeros: power divided by the share)."""
    from scipy import signal

    r = np.asarray(residual, float)
    fs = 1.0 / float(data.dt)
    fc = data.filter.cutoff_hz if getattr(data.filter, "derivatives", "computed") != "given" else None
    fc = float(fc) if fc and fc < fs / 2 else None
    top = fc if fc else fs / 2
    lo, hi = NOISE_BAND[0] * top, NOISE_BAND[1] * top
    grid = np.linspace(0.0, fs / 2, 4097)
    gain_of = (lambda f: np.ones_like(f)) if fc is None else (
        lambda f: np.abs(signal.freqz(*signal.butter(int(data.filter.order), fc / (fs / 2)), worN=f, fs=fs)[1]) ** 4)
    band_width = float(np.trapezoid(gain_of(grid), grid))  # int |H|^4 df [Hz]
    num, den = np.zeros(r.shape[1]), 0.0
    for s in np.unique(data.segment):
        idx = np.nonzero(data.segment == s)[0]
        nper = int(min(len(idx), max(64, 2 ** math.ceil(math.log2(16.0 * fs / max(hi - lo, 1e-9))))))
        f, P = signal.welch(r[idx], fs=fs, nperseg=nper, axis=0)
        gain = gain_of(f)
        band = (f >= lo) & (f <= hi) & (gain > 1e-3)
        if band.any():
            num += len(idx) * np.mean(P[band] / gain[band, None], axis=0)
            den += len(idx)
    share = np.ones(r.shape[1]) if keep is None else np.maximum(np.mean(np.asarray(keep, float), axis=0), 1e-9)
    n0 = np.maximum(num / max(den, 1e-300) / share, 0.0)
    sigma = np.sqrt(n0 * band_width)
    return sigma, {"noise_floor": [float(x) for x in sigma], "noise_band_hz": [lo, hi],
                   "noise_sample_std": [float(x) for x in np.sqrt(n0 * fs / 2.0)],
                   "noise_method": "white level = mean residual PSD / filter power gain on the upper half of the "
                                   "filter passband; floor = that white noise's RMS after the filter"}


# ------------------------------------------------------------------------------------ rows
@dataclass
class Split:
    """Row masks of the selection: ``folds`` = [(test, train)] of the blocked CV on the search
    rows, ``confirm`` the confirmation block, ``search`` the rows the search may use."""

    folds: list
    search: np.ndarray
    confirm: np.ndarray
    gap: int


def blocked_folds(data: IdentData, k: int = CV_FOLDS, gap: int = 0, rows: np.ndarray | None = None) -> list:
    """[(test, train)] masks: the ``rows`` (default all) of every segment cut into ``k``
    contiguous blocks; fold i tests on block i of each segment and trains on the other rows of
    ``rows`` except those within ``gap`` samples of block i in the same segment."""
    rows = np.ones(data.N, bool) if rows is None else np.asarray(rows, bool)
    fold = np.full(data.N, -1)
    near = [np.zeros(data.N, bool) for _ in range(k)]
    for s in np.unique(data.segment):
        idx = np.nonzero((data.segment == s) & rows)[0]
        if not len(idx):
            continue
        f = np.minimum((np.arange(len(idx)) * k) // len(idx), k - 1)
        fold[idx] = f
        for i in range(k):
            pos = np.nonzero(f == i)[0]
            if len(pos):
                near[i][idx[max(0, pos[0] - gap):pos[-1] + gap + 1]] = True
    return [(fold == i, rows & ~near[i]) for i in range(k)]


def confirm_rows(data: IdentData, fraction: float = CONFIRM_FRACTION, gap: int = 0,
                 k: int = CV_FOLDS) -> tuple[np.ndarray, np.ndarray]:
    """(search, confirm) masks: the last ``fraction`` of every segment is the confirmation block,
    the rows more than ``gap`` before it are the search rows. A segment too short to keep k
    blocks of at least 2 gap + 10 rows before it gives no confirmation rows (all search)."""
    search, confirm = np.zeros(data.N, bool), np.zeros(data.N, bool)
    for s in np.unique(data.segment):
        idx = np.nonzero(data.segment == s)[0]
        nc = int(len(idx) * fraction)
        ns = len(idx) - nc - gap
        if nc < 1 or ns < k * (2 * gap + 10):
            search[idx] = True
            continue
        search[idx[:ns]] = True
        confirm[idx[len(idx) - nc:]] = True
    return search, confirm


def selection_split(data: IdentData, residual: np.ndarray, k: int = CV_FOLDS,
                    confirm_fraction: float = CONFIRM_FRACTION, gap: int | None = None) -> tuple[Split, dict]:
    """The selection's rows (module docstring); ``gap`` None = :func:`gap_samples`."""
    info = {}
    if gap is None:
        gap, info = gap_samples(data, residual, k, confirm_fraction)
    search, confirm = confirm_rows(data, confirm_fraction, gap, k)
    info.update(gap_samples=int(gap), confirm_fraction=confirm_fraction, confirm_rows=int(confirm.sum()),
                search_rows=int(search.sum()))
    return Split(blocked_folds(data, k, gap, search), search, confirm, int(gap)), info


# ------------------------------------------------------------------------------------ scores
def identifiable_basis(G: np.ndarray, tol: float = RANK_TOL) -> np.ndarray:
    """B (p, r): the directions of parameter space the Gram matrix ``G`` identifies, theta = B z.

    With the column-normalised Gram matrix G_s = D^-1 G D^-1 = V diag(s^2) V^T
    (``least_squares._gram_eig``), B = D^-1 V_keep over the eigen-directions whose singular value
    is at least ``tol`` s_max (the same ``RANK_TOL`` as every other fit). A fold fitted as
    z = argmin on B cannot move along a direction the whole data cannot see."""
    scale, _, V, keep, _ = _gram_eig(G, tol)
    return V[:, keep] / scale[:, None]


def _fold_theta(G_all, g_all, B) -> np.ndarray:
    """Least squares from normal equations G_all, g_all restricted to theta = B z (the whole
    data's identifiable subspace, :func:`identifiable_basis`), solved at ``RANK_TOL``."""
    from robust_drake.identification.least_squares import solve_gram

    z = solve_gram(B.T @ G_all @ B, B.T @ g_all, tol=RANK_TOL)[0]
    return B @ z


def _fold_thetas(cache: "ColumnCache", effects, weights, folds, icache=None) -> list:
    """theta of every fold = [(test, train)], fitted on its training rows (:func:`heldout_residuals`)."""
    used = np.zeros(cache.data.N, bool)
    for test, train in folds:
        used |= test | train
    # Z^T W Y, Z^T W tau over the used rows, the other rows, and each fold's left-out rows, from the
    # memoised block products (fitting.ColumnCache.gram: shared by every candidate of a step)
    Gs, gs = cache.gram(effects, weights, [used, ~used] + [used & ~train for _, train in folds], icache)
    G_all, g_all = Gs[0], gs[0]
    if icache is not None:
        return [np.linalg.lstsq(G_all - Gx, g_all - gx, rcond=None)[0] for Gx, gx in zip(Gs[2:], gs[2:])]
    B = identifiable_basis(Gs[0] + Gs[1])
    return [_fold_theta(G_all - Gx, g_all - gx, B) for Gx, gx in zip(Gs[2:], gs[2:])]


def heldout_residuals(cache: "ColumnCache", effects, weights, folds, icache=None) -> tuple[np.ndarray, np.ndarray]:
    """(R, test): weighted held-out output errors R (N, n) -- row i of fold k's block predicted by
    the model fitted on fold k's training rows -- and the mask of rows held out by some fold
    (R is 0 elsewhere; the folds' test blocks are disjoint).

    Least squares: every fold is solved on the identifiable subspace of the **whole data's**
    Gram matrix (all N rows, :func:`identifiable_basis` at ``RANK_TOL``), so a fold cannot fit a
    direction the whole data do not identify. Measured (issue 21): on a simulated 6-axis arm with
    no extra effect the baseline's mean held-out error was 646 with the earlier fold tolerance
    1e-10 and 1.18 with ``RANK_TOL``. With ``icache`` (instrument columns on the same rows,
    ``instruments.py``) every fold is fitted by instrumental variables, (Z^T W Y)^-1 Z^T W tau."""
    tau = cache.data.tau
    R, held = np.zeros(tau.shape), np.zeros(len(tau), bool)
    for (test, _), theta in zip(folds, _fold_thetas(cache, effects, weights, folds, icache)):
        R[test] = (tau[test] - predict_tau(cache, effects, theta, test)) * weights[None, :]
        held |= test
    return R, held


def _predicted_joints(cache: "ColumnCache", effects) -> list | None:
    """Joints whose held-out error needs an output-error prediction: those of the implicit
    effects (torque in the columns, ``fitting.implicit_mask``); the other joints' errors follow
    from the Gram products. None when an implicit effect may read other joints' torques
    (``Effect.own_joint_tau`` False): then every joint is predicted."""
    n, out = cache.data.n, set()
    for e in effects:
        if getattr(e, "needs_tau", False) and not getattr(e, "uses_taud", False):
            if not getattr(e, "own_joint_tau", False):
                return None
            out.update(int(j) for j in e.joints(n))
    return sorted(out)


def heldout_sse(cache: "ColumnCache", effects, weights, folds, icache=None) -> tuple[np.ndarray, int]:
    """(sse (n,), rows): per joint the weighted held-out squared output error summed over the
    folds' test rows (disjoint), and the count of those rows: ``np.sum(R**2, axis=0)`` and
    ``held.sum()`` of :func:`heldout_residuals`, without the (N, n) residual.

    Joint j of an explicit model: w_j^2 sum_k (tt_kj - 2 theta_k^T g_kj + theta_k^T G_kj theta_k)
    from the per-joint products of the test rows (``ColumnCache.joint_gram``, memoised per
    block: a candidate adds only its own block's); the joints of implicit effects
    (:func:`_predicted_joints`) are predicted on the test rows (``predict_tau``'s ``joints``).
    Equal to the residual path up to round-off (``tests/test_fast_repair.py``)."""
    w2 = np.asarray(weights, float) ** 2
    n = cache.data.n
    thetas = _fold_thetas(cache, effects, weights, folds, icache)
    tests = [test for test, _ in folds]
    rows = int(np.sum(np.any(tests, axis=0))) if tests else 0
    pj = _predicted_joints(cache, effects)
    if pj is None or len(pj) == n:
        tau, sse = cache.data.tau, np.zeros(n)
        for test, theta in zip(tests, thetas):
            sse += np.sum((tau[test] - predict_tau(cache, effects, theta, test)) ** 2, axis=0)
        return sse * w2, rows
    G, g, tt = cache.joint_gram(effects, tests)
    sse = np.zeros(n)
    for k, (test, theta) in enumerate(zip(tests, thetas)):
        err = np.maximum(tt[k] - 2.0 * (g[k] @ theta) + np.einsum("jpq,p,q->j", G[k], theta, theta), 0.0)
        if pj:
            pred = predict_tau(cache, effects, theta, test, joints=pj)
            err[pj] = np.sum((cache.data.tau[test][:, pj] - pred[:, pj]) ** 2, axis=0)
        sse += err
    return sse * w2, rows


def heldout_error(cache: "ColumnCache", effects, weights, folds, icache=None) -> float:
    """Mean held-out weighted squared output error over ``folds`` = [(test, train)]
    (:func:`heldout_sse`)."""
    sse, rows = heldout_sse(cache, effects, weights, folds, icache)
    return float(np.sum(sse)) / max(rows * len(sse), 1)


def cv_score(cache: "ColumnCache", effects, weights, folds, icache=None) -> float:
    """Blocked-CV held-out error (:func:`heldout_error`); ``folds`` = [(test, train)] or, as
    before, test masks alone (train = the complement, no gap)."""
    folds = [f if isinstance(f, tuple) else (f, ~f) for f in folds]
    return heldout_error(cache, effects, weights, folds, icache)


def bic(rss_w: float, rows: int, p: int, n_eff_rows: float) -> float:
    """BIC with the likelihood scaled to the effective sample count (reported, not a rule)."""
    if rss_w <= 0:
        return -np.inf
    return n_eff_rows * np.log(rss_w / rows) + p * np.log(n_eff_rows)


@dataclass
class Step:
    step: int
    label: str
    kind: str
    joint: int | None
    score_before: float
    score_after: float
    gain: float  # pooled held-out (CV) gain over all joints (as before)
    confirm_before: float  # confirmation-block error, relative to the baseline's
    confirm_after: float
    confirm_gain: float
    bic_before: float  # informational (module docstring)
    bic_after: float
    accepted: bool
    reason: str
    tried: int
    #: held-out (CV) gain on the error the effect is judged on (its joint's; all joints pooled for
    #: an effect without a joint) -- what ranks the candidates and screens the winner
    joint_gain: float = float("nan")
    #: the candidate's place in the step's ranking (1 = winner) and the count of candidates tested
    #: on the confirmation block in the step so far (the multiple-comparison guard's m)
    rank: int = 1
    attempt: int = 1
    #: paired block test of the confirmation block, candidate vs current model, on the judged
    #: error (``decisions.PairedTest.as_dict()``); None when it was not run
    confirm_test: dict | None = None
    alpha: float = float("nan")  # one-sided level of that test after the guard
    #: RMS [N m] of the effect's explained torque per joint and the joint's white-noise level
    explained_rms: list | None = None
    noise_floor: list | None = None

    def as_dict(self):
        return dict(self.__dict__)


@dataclass
class SelectionResult:
    chosen: list
    steps: list[Step]
    baseline_score: float
    final_score: float
    weights: np.ndarray
    ranking: list[dict] = field(default_factory=list)  # last step's candidate table
    rows: dict = field(default_factory=dict)  # gap, confirmation block (selection_split's info)


#: candidates of a step tested on the confirmation block when the ones ranked above them fail
#: (all counted in the multiple-comparison guard: each test at alpha / (1 + NEXT_TRIES))
NEXT_TRIES = 3
#: rivals of a different kind or joint, on the same error, the winner is compared with
#: (:func:`_degenerate`)
RIVALS = 3


def _target(effect):
    """The joint an effect is judged on (None: all joints pooled)."""
    return getattr(effect, "joint", None)


def _series(R: np.ndarray, joint) -> np.ndarray:
    """Per-row squared (weighted) error of ``joint`` (None: summed over the joints)."""
    return R[:, joint] ** 2 if joint is not None else np.sum(R**2, axis=1)


@dataclass
class _Search:
    """What every step of :func:`forward_select` shares (rows, weights, rules, noise levels)."""

    cache: object
    icache: object
    weights: np.ndarray
    split: Split
    context: object
    min_gain: float
    confirm_gain: float | None
    level: float
    tries: int
    noise: np.ndarray
    ids_search: np.ndarray
    ids_confirm: np.ndarray
    rows: int
    n_eff_rows: float

    @property
    def has_confirm(self) -> bool:
        return bool(self.split.confirm.any())

    @property
    def alpha(self) -> float:
        """The step's one-sided family-wise level (1 - level) / 2 (module docstring)."""
        return (1.0 - self.level) / 2.0

    def alpha_of(self, attempt: int) -> float:
        """One-sided level of the ``attempt``-th confirmation test of a step (1 = the winner):
        weighted Bonferroni, the winner at alpha / 2 and each of the ``tries - 1`` next-ranked at
        alpha / (2 (tries - 1)), so the levels of all tries of a step sum to alpha (one try: alpha)."""
        if self.tries <= 1:
            return self.alpha
        return self.alpha / 2.0 if attempt <= 1 else self.alpha / (2.0 * (self.tries - 1))

    @property
    def screen(self) -> float:
        return self.min_gain / 2.0 if self.has_confirm else self.min_gain

    def fit(self, effects):
        parts = [self.split.search, ~self.split.search]  # all rows (a partition), memoised block Grams
        if self.icache is None:  # coefficients only: no (N, n) residual (a step holds
            # every candidate's fit: ~1.1 GB of residuals at 99.5k rows x 7 joints)
            return self.cache.fit_ls(effects, self.weights, parts=parts, warn=False, residual=False)
        return fit_iv_blocks(self.cache, self.icache, effects, self.weights, parts=parts, residual=False)

    def cv(self, effects) -> np.ndarray:
        """Weighted held-out residuals (N, n) of the blocked CV on the search rows."""
        return heldout_residuals(self.cache, effects, self.weights, self.split.folds, self.icache)[0]

    def confirm(self, effects) -> np.ndarray:
        """Weighted confirmation-block residuals (N, n), the model fitted on the search rows."""
        return heldout_residuals(self.cache, effects, self.weights, [(self.split.confirm, self.split.search)],
                                 self.icache)[0]

    def evaluate(self, effects):
        """(pooled CV score, per-joint CV scores (n,), BIC, fit, names, slices, why-inadmissible)."""
        names, slices = self.cache.names(effects), self.cache.blocks(effects)[2]
        fit = self.fit(effects)
        ctx = self.context.with_friction(fit.theta, names)
        for e, sl in zip(effects, slices):
            why = implausible(e, fit.theta[sl], ctx)
            if why:  # checked before the (costlier) cross validation
                return np.inf, None, np.inf, fit, names, slices, why
        sse, _ = heldout_sse(self.cache, effects, self.weights, self.split.folds, self.icache)
        per = sse / max(sum(int(t.sum()) for t, _ in self.split.folds), 1)
        return float(np.mean(per)), per, _LazyBIC(self, list(effects), fit.theta, fit.rank), fit, names, slices, ""

    def explained(self, effects, fit) -> np.ndarray:
        """RMS per joint [N m] of the last effect's columns x its coefficients (rows in use)."""
        slices = self.cache.blocks(effects)[2]
        mask = np.zeros(slices[-1].stop, bool)
        mask[slices[-1]] = True
        return np.asarray(self.cache.rms(self.cache.explicit_prediction(effects, fit.theta, mask)), float)


class _LazyBIC:
    """The BIC of a fitted candidate (:func:`bic` of its weighted output error on all rows),
    computed when first read (``float(...)``): it is informational (module docstring) and read only
    for the candidates a step records, so the other candidates skip one all-rows output-error
    prediction each (the torque-dependent fixed point of ``predict_tau`` when the model has one)."""

    def __init__(self, search, effects, theta, rank):
        self._args, self._value = (search, effects, theta, rank), None

    def __float__(self) -> float:
        if self._value is None:
            search, effects, theta, rank = self._args
            r = (search.cache.data.tau - predict_tau(search.cache, effects, theta)) * search.weights[None, :]
            self._value, self._args = float(bic(float(np.sum(r**2)), search.rows, rank, search.n_eff_rows)), None
        return self._value


def _decide(gain, c_gain, min_gain, confirm_gain, has_confirm, b_best, b):
    """The earlier rule (fixed gains), kept for callers; :func:`forward_select` uses :func:`_judge`."""
    screen = min_gain / 2.0 if has_confirm else min_gain
    if gain < screen:
        return False, f"held-out gain {gain:.1%} < {screen:.1%}: stop"
    if has_confirm and not c_gain >= confirm_gain:
        return False, (f"held-out gain {gain:.1%} not confirmed: confirmation-block gain {c_gain:.1%} "
                       f"< {confirm_gain:.1%}: stop")
    conf = f", confirmation block -{c_gain:.1%}" if has_confirm else " (no confirmation block: segments too short)"
    return True, f"held-out error -{gain:.1%}{conf} (BIC {b:.1f} -> {b_best:.1f}, not a rule)"


def forward_select(cache: ColumnCache, candidates: list, min_gain: float = MIN_GAIN,
                   max_effects: int = 4, folds: int = CV_FOLDS, progress=None, weights=None,
                   icache=None, confirm_fraction: float = CONFIRM_FRACTION, confirm_gain: float | None = None,
                   gap: int | None = None, context=None, level: float | None = None,
                   next_tries: int = NEXT_TRIES) -> SelectionResult:
    """Greedy forward selection (see module docstring). ``progress(msg)`` is called per step.

    ``weights`` (n,): per-joint row weights (default 1 / baseline residual RMS of each joint).
    ``icache``: instrument columns; every fit and held-out score then uses instrumental variables.
    ``gap`` [samples]: None = :func:`gap_samples`; ``confirm_gain`` None = no effect-size bar on
    the confirmation block beyond the paired test (a number: the confirmation gain must reach it
    too); ``context``: :class:`~robust_drake.effects.PhysicalContext` (default from
    the data, no robot: a ``time_delay`` is then not admissible); ``level``: confidence level of
    the decisions (default ``decisions.LEVEL``; one-sided (1 - level) / 2 for a step, shared by
    the up to 1 + ``next_tries`` candidates tested on the confirmation block in it)."""
    search, rows_info = _setup(cache, min_gain, folds, weights, icache, confirm_fraction, confirm_gain, gap,
                               context, level, next_tries)
    sc0, per0, b0, _, _, _, _ = search.evaluate([])
    baseline_score = sc0
    cur = {"effects": [], "score": sc0, "per": per0, "bic": b0,
           "confirm": search.confirm([]) if search.has_confirm else None}
    base_confirm = cur["confirm"]
    c_base = float(np.sum(base_confirm[search.split.confirm] ** 2)) if search.has_confirm else float("nan")
    steps, pool, ranking = [], list(candidates), []
    while pool and len(cur["effects"]) < max_effects:
        trials = _shared_first(search, cur, sorted((_trial(search, cur, e) for e in pool),
                                                   key=lambda t: -t["joint_gain"]))
        ranking = [{"label": effect_label(t["effect"]), "kind": t["effect"].kind, "joint": t["effect"].joint,
                    "score": t["score"] / baseline_score if np.isfinite(t["score"]) else None,
                    "joint_gain": t["joint_gain"] if np.isfinite(t["joint_gain"]) else None, "note": t["why"]}
                   for t in trials]
        new_steps, winner, drop = _step(search, cur, trials, baseline_score, c_base, len(steps))
        for st in new_steps:
            steps.append(st)
            if progress:
                progress(f"step {st.step}: {st.label}: {st.reason}")
        if winner is None:  # a step that accepts nothing ends the search (its alpha is spent)
            break
        pool = [e for e in pool if effect_label(e) not in drop]
        e_best = winner["effect"]
        cur = {"effects": cur["effects"] + [e_best], "score": winner["score"], "per": winner["per"],
               "bic": winner["bic"], "confirm": winner.get("confirm")}
        pool = [e for e in pool if not (e.kind == e_best.kind and e.joint == e_best.joint)]
    chosen, removed = _recheck(search, cur["effects"], base_confirm)
    for label, why in removed:
        steps.append(Step(len(steps) + 1, label, "", None, *([float("nan")] * 8), False, why, 0))
        if progress:
            progress(f"re-check: {label}: {why}")
    final = cur["score"] if len(chosen) == len(cur["effects"]) else search.evaluate(chosen)[0]
    rows_info.update(level=search.level, alpha_per_step=search.alpha, tries_per_step=search.tries,
                     alpha_per_try=[search.alpha_of(k + 1) for k in range(search.tries)])
    return SelectionResult(chosen=chosen, steps=steps, baseline_score=baseline_score, final_score=final,
                           weights=search.weights, ranking=ranking, rows=rows_info)


def _setup(cache, min_gain, folds, weights, icache, confirm_fraction, confirm_gain, gap, context, level, next_tries):
    """The :class:`_Search` of a selection (baseline fit and weights, rows, blocks, noise levels)
    and the rows' info (``SelectionResult.rows``)."""
    from robust_drake.model_repair.decisions import LEVEL, MIN_BLOCKS, block_ids, block_length
    from robust_drake.effects import PhysicalContext

    data = cache.data
    Y0, names0, _ = cache.model([])
    base = solve_ls(Y0, data.tau, names0, warn=False)
    weights = 1.0 / np.maximum(base.rms, 1e-12) if weights is None else np.asarray(weights, float)
    context = PhysicalContext.from_data(data) if context is None else context
    split, rows_info = selection_split(data, base.residual, folds, confirm_fraction, gap)
    t_r = rows_info.get("correlation_time_s", correlation_time(data, base.residual))
    t_f = filter_settling_time(data.filter.cutoff_hz, data.filter.order)

    def ids(mask):
        """Blocks of the paired tests: 3 correlation times + the filter's settling
        (``decisions.block_length``); a segment shorter than that is one block of its own (blocks
        never cross segments); only when that leaves fewer than ``MIN_BLOCKS`` blocks are they cut
        shorter (at most a quarter of the shortest segment's rows), which the test then needs."""
        out = block_ids(data.segment, data.N, block_length(data.dt, t_r, t_f), mask)
        if out.max(initial=-1) + 1 >= MIN_BLOCKS:
            return out
        lens = [int(np.sum(mask & (data.segment == s))) for s in np.unique(data.segment)]
        lens = [L for L in lens if L] or [1]
        return block_ids(data.segment, data.N, block_length(data.dt, t_r, t_f, rows=min(lens)), mask)

    noise, noise_info = white_noise_level(data, base.residual, cache.keep)
    search = _Search(cache, icache, weights, split, context, float(min_gain), confirm_gain,
                     LEVEL if level is None else float(level), 1 + max(int(next_tries), 0), noise,
                     ids(split.search), ids(split.confirm), data.N * data.n, n_effective(data) * data.n)
    cids = search.ids_confirm[search.ids_confirm >= 0]
    rows_info.update(noise_info, confirm_blocks=int(cids.max()) + 1 if len(cids) else 0,
                     block_samples=int(np.bincount(cids).min()) if len(cids) else None)
    return search, rows_info


def _trial(search: _Search, cur: dict, e) -> dict:
    """One candidate next to the current model: scores, BIC, the judged joint's CV gain, or why not."""
    out = {"effect": e, "score": np.inf, "per": None, "bic": np.inf, "joint_gain": -np.inf, "why": ""}
    effects = cur["effects"] + [e]
    try:
        sc, per, b, fit, names, slices, why = search.evaluate(effects)
    except Exception as exc:  # noqa: BLE001  (an effect that cannot build columns on these data)
        return dict(out, why=f"columns failed: {exc}")
    if any(nm in fit.unidentifiable for nm in names[slices[-1]]):
        return dict(out, bic=b, why="not identifiable next to the current model")
    if why:
        return dict(out, bic=b, why=f"inadmissible fit: {why}")
    j = _target(e)
    before, after = (cur["per"][j], per[j]) if j is not None else (cur["score"], sc)
    return dict(out, score=sc, per=per, bic=b, fit=fit, joint_gain=float((before - after) / before))


def _shared_first(search: _Search, cur: dict, trials: list) -> list:
    """The ranking with each shared candidate (a kind with one parameter for all joints,
    ``Effect.shared``, e.g. one command delay) moved just above the highest-ranked single-joint
    candidate of the same kind that it explains as well: pooled CV score lower (better on all
    joints together) and, on that candidate's joint, its held-out error not significantly above
    the single-joint one's (paired block test on the search rows, one-sided (1 - level) / 2).
    Same number of parameters, one explanation for every joint: the single-joint version wins
    only where the data prefer it (it then validates on its own joint)."""
    from robust_drake.model_repair.decisions import paired_test

    alpha = (1.0 - search.level) / 2.0
    out = list(trials)
    for S in [t for t in trials if getattr(t["effect"], "shared", False) and _target(t["effect"]) is None
              and np.isfinite(t["score"])]:
        i_s = next(i for i, t in enumerate(out) if t is S)
        R_shared = None  # the shared candidate's held-out residuals, computed once when first needed
        for i, t in enumerate(out[:i_s]):
            e = t["effect"]
            if e.kind != S["effect"].kind or _target(e) is None or not np.isfinite(t["score"]):
                continue
            if S["score"] >= t["score"]:
                continue
            j = _target(e)
            single = _series(search.cv(cur["effects"] + [e]), j)
            R_shared = search.cv(cur["effects"] + [S["effect"]]) if R_shared is None else R_shared
            shared = _series(R_shared, j)
            if paired_test(shared, single, search.ids_search, search.level).p_better < alpha:
                continue  # the single-joint version explains its joint significantly better
            out.insert(i, out.pop(i_s))
            break
    return out


def _step(search: _Search, cur: dict, trials: list, baseline_score: float, c_base: float, done: int):
    """One step: the winner and, when it fails, the next-ranked candidates, up to ``search.tries``
    tested on the confirmation block (module docstring). Returns (steps, accepted trial or None,
    labels leaving the pool: the degenerate ones)."""
    steps, drop, attempt = [], set(), 0
    for k, t in enumerate(trials):
        if attempt >= search.tries or len(steps) >= 4 * search.tries:
            break
        if not np.isfinite(t["score"]) or t["joint_gain"] < search.screen:
            if not steps:
                why = ("no identifiable, admissible candidate left" if not np.isfinite(t["score"]) else
                       f"held-out gain {t['joint_gain']:.1%} < {search.screen:.1%}: stop")
                steps.append(_record(search, cur, t, done + 1, k, 0, why, baseline_score, c_base, len(trials)))
            break
        st = _record(search, cur, t, done + len(steps) + 1, k, attempt, "", baseline_score, c_base, len(trials))
        steps.append(st)
        if effect_label(t["effect"]) in drop:
            st.reason = "degenerate with a candidate ranked above it (see there): none accepted"
            continue
        rivals = _degenerate(search, cur, t, trials[k + 1:])
        if rivals:
            st.reason = ("degenerate: the data cannot rank these: " + ", ".join([effect_label(t["effect"])] + rivals)
                         + " (held-out errors within each other's spread): none accepted")
            drop.update([effect_label(t["effect"])] + rivals)
            continue
        if _below_floor(search, cur, t, st):  # refused before any test: spends no share of alpha
            continue
        attempt += 1
        st.attempt = attempt
        if _judge(search, cur, t, st):
            st.accepted = True
            return steps, t, drop
    if steps and not steps[-1].reason.endswith("stop"):
        steps[-1].reason += ": stop"
    return steps, None, drop


def _record(search, cur, t, number, k, attempt, why, baseline_score, c_base, tried) -> Step:
    """The Step of candidate ``t`` (rank k + 1) before its decision."""
    e = t["effect"]
    s_after = t["score"] / baseline_score if np.isfinite(t["score"]) else float("nan")
    gain = (cur["score"] - t["score"]) / cur["score"] if np.isfinite(t["score"]) else 0.0
    c_before = (float(np.sum(cur["confirm"][search.split.confirm] ** 2)) / c_base if search.has_confirm
                else float("nan"))
    return Step(number, effect_label(e), e.kind, e.joint, cur["score"] / baseline_score, s_after, float(gain),
                c_before, float("nan"), float("nan"), float(cur["bic"]), float(t["bic"]), False, why, tried,
                joint_gain=float(t["joint_gain"]) if np.isfinite(t["joint_gain"]) else float("nan"),
                rank=k + 1, attempt=attempt)


def _degenerate(search: _Search, cur: dict, t: dict, below: list) -> list:
    """Labels of the next-ranked rivals (a different kind or joint, judged on the same error,
    passing the screen; up to ``RIVALS``) that explain that error themselves (significantly
    better than the current model on the search rows' held-out errors) and that the candidate
    ``t`` is not significantly better than (paired block tests at the one-sided (1 - level) / 2):
    then the data cannot rank them."""
    from robust_drake.model_repair.decisions import paired_test

    e, j = t["effect"], _target(t["effect"])
    same = [r for r in below if np.isfinite(r["score"]) and r["joint_gain"] >= search.screen
            and _target(r["effect"]) == j and (r["effect"].kind, r["effect"].joint) != (e.kind, e.joint)][:RIVALS]
    if not same:
        return []
    alpha = (1.0 - search.level) / 2.0
    now = _series(search.cv(cur["effects"]), j)
    mine = _series(search.cv(cur["effects"] + [e]), j)
    out = []
    for r in same:
        theirs = _series(search.cv(cur["effects"] + [r["effect"]]), j)
        if not paired_test(now, theirs, search.ids_search, search.level).p_better < alpha:
            continue  # the rival does not explain the error either: not a competing explanation
        if not paired_test(theirs, mine, search.ids_search, search.level).p_better < alpha:
            out.append(effect_label(r["effect"]))
    return out


def _below_floor(search: _Search, cur: dict, t: dict, st: Step) -> bool:
    """True (and ``st.reason`` set) when the candidate's explained RMS on its joint is below the
    residual's white-noise level (module docstring): refused before the confirmation test, so it
    does not count among the step's ``search.tries`` tests."""
    e, effects = t["effect"], cur["effects"] + [t["effect"]]
    j = _target(e)
    expl = search.explained(effects, t["fit"])
    st.explained_rms, st.noise_floor = [float(x) for x in expl], [float(x) for x in search.noise]
    ratio = expl[j] / search.noise[j] if j is not None else float(np.sqrt(np.mean((expl / search.noise) ** 2)))
    if ratio >= 1.0:
        return False
    where = f"joint {j + 1}" if j is not None else "all joints"
    st.reason = (f"held-out gain {t['joint_gain']:.1%} on {where}, but below the noise floor: explained RMS "
                 f"{ratio:.2f} x the white-noise level")
    return True


def _judge(search: _Search, cur: dict, t: dict, st: Step) -> bool:
    """The confirmation block's paired test (module docstring), after :func:`_below_floor`; fills ``st``."""
    from robust_drake.model_repair.decisions import paired_test

    e, effects = t["effect"], cur["effects"] + [t["effect"]]
    j = _target(e)
    where = f"joint {j + 1}" if j is not None else "all joints"
    if not search.has_confirm:
        st.reason = (f"held-out error on {where} -{t['joint_gain']:.1%} (no confirmation block: segments too "
                     f"short; rule: >= {search.min_gain:.0%})")
        return bool(t["joint_gain"] >= search.min_gain)
    Rc = search.confirm(effects)
    test = paired_test(_series(cur["confirm"], j), _series(Rc, j), search.ids_confirm, search.level)
    t["confirm"] = Rc
    c_cur = float(np.sum(cur["confirm"][search.split.confirm] ** 2))
    c_new = float(np.sum(Rc[search.split.confirm] ** 2))
    st.confirm_after = st.confirm_before * c_new / max(c_cur, 1e-300)
    st.confirm_gain = float((c_cur - c_new) / c_cur) if c_cur > 0 else float("nan")
    alpha = search.alpha_of(st.attempt)
    st.confirm_test, st.alpha = test.as_dict(), alpha
    ok = test.p_better < alpha and (search.confirm_gain is None or st.confirm_gain >= search.confirm_gain)
    st.reason = (f"held-out error on {where} -{t['joint_gain']:.1%}; confirmation block {test.text()}, "
                 f"p = {test.p_better:.2g} {'<' if test.p_better < alpha else '>='} {alpha:.3g} "
                 f"(one-sided, try {st.attempt} of {search.tries})" + ("" if ok else ": not confirmed"))
    if ok:
        st.reason += f" (BIC {st.bic_before:.1f} -> {st.bic_after:.1f}, not a rule)"
    return bool(ok)


def _recheck(search: _Search, chosen: list, base_confirm) -> tuple[list, list]:
    """Every accepted effect re-checked on the confirmation block at the end: its marginal
    contribution (all chosen vs all but it, on its judged error; Holm over the chosen at the
    one-sided (1 - level) / 2) -- the weakest that no longer holds is removed, repeatedly -- then
    all together vs the baseline: removed unless some joint they act on is significantly better
    (``decisions.compare_joints``, Holm over those joints). Returns (kept effects, [(label, why removed)])."""
    from robust_drake.model_repair.decisions import compare_joints, holm, paired_test

    if not chosen or not search.has_confirm:
        return list(chosen), []
    alpha = (1.0 - search.level) / 2.0
    kept, removed = list(chosen), []
    while kept:
        R_all = search.confirm(kept)
        tests = [paired_test(_series(search.confirm([x for x in kept if x is not e]), _target(e)),
                             _series(R_all, _target(e)), search.ids_confirm, search.level) for e in kept]
        holds = holm([tt.p_better for tt in tests], alpha)
        if all(holds):
            break
        k = int(np.argmax([-1.0 if h else tt.p_better for tt, h in zip(tests, holds)]))
        removed.append((effect_label(kept[k]), f"removed at the final re-check: its marginal contribution on the "
                        f"confirmation block {tests[k].text()} (p = {tests[k].p_better:.2g}, Holm over {len(kept)}) "
                        "no longer holds"))
        kept.pop(k)
    if kept:
        joints = sorted({_target(e) for e in kept} - {None})
        joints = None if any(_target(e) is None for e in kept) else joints
        R_all = search.confirm(kept)
        tests = compare_joints(base_confirm**2, R_all**2, search.ids_confirm, search.level, joints=joints)
        if not any(tt.better for tt in tests):
            best = min(tests, key=lambda tt: tt.p_better)
            removed += [(effect_label(e), f"removed at the final re-check: all kept effects together vs the "
                         f"baseline on the confirmation block, no joint they act on significantly better "
                         f"(Holm; best {best.text()})") for e in kept]
            kept = []
    return kept, removed


__all__ = ["ColumnCache", "forward_select", "fit_model", "predict", "predict_tau", "implausible", "blocked_folds",
           "confirm_rows", "selection_split", "gap_samples", "filter_settling_time", "correlation_time",
           "heldout_error", "heldout_residuals", "heldout_sse", "identifiable_basis", "white_noise_level", "cv_score", "effect_label", "identifiability", "bic", "Step", "SelectionResult", "Split",
           "Blocks", "validation_blocks"]


@dataclass(frozen=True)
class Blocks:
    """The validation rows cut into the paired tests' blocks (``decisions.block_ids``), once per
    repair from the least-squares baseline's validation residual: ``ids`` block number per row,
    ``block`` [samples] = round((BLOCK_CORRELATIONS t_r + t_f) / dt) (``decisions.block_length``),
    ``correlation_time_s`` t_r [s] (``selection.correlation_time``), ``settling_time_s`` t_f [s]
    (``selection.filter_settling_time``)."""

    ids: np.ndarray
    block: int
    correlation_time_s: float
    settling_time_s: float

    def as_dict(self) -> dict:
        return {"blocks": int(self.ids.max()) + 1 if len(self.ids) else 0, "block_samples": int(self.block),
                "correlation_time_s": float(self.correlation_time_s), "settling_time_s": float(self.settling_time_s)}


def validation_blocks(val: IdentData, residual: np.ndarray) -> Blocks:
    """:class:`Blocks` of ``val`` from the reference model's validation ``residual`` (N, n)."""
    from robust_drake.model_repair import decisions as D

    t_r = correlation_time(val, residual)
    t_f = filter_settling_time(val.filter.cutoff_hz, val.filter.order)
    shortest = min(int(np.sum(val.segment == s)) for s in np.unique(val.segment))
    L = D.block_length(val.dt, t_r, t_f, rows=shortest)
    return Blocks(D.block_ids(val.segment, val.N, L), L, t_r, t_f)
