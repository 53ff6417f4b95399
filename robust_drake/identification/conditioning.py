"""Conditioning of real logs: time stamps, gaps, stiction and derivative checks (pure functions).

Every function here works on one file's arrays and returns new arrays plus one-line messages;
:mod:`robust_drake.identification.data` turns the messages into :class:`DataWarning`.

Time stamps (:func:`classify_stamps`)
    Within a gap-free stretch, fit ``t_k = t0 + k T`` by least squares and look at the residual
    ``r_k = t_k - t0 - k T``:

    * stamps that *scatter around a fixed rate* (a real-time loop logged by a non-real-time
      thread: the samples are evenly spaced, each stamp is the true time plus an independent
      error ``e_k``) give ``std(dt) = sqrt(2) std(e)`` and ``std(r) = std(e)``, so the drift ratio
      ``D = std(r) / (std(dt) / sqrt(2))`` is about 1 and does not grow with N;
    * truly irregular sampling (independent or slowly varying intervals) makes ``t_k`` a random
      walk about the line: ``std(r)`` grows like ``std(dt) sqrt(N / 15)``, so ``D`` is about
      ``sqrt(2 N / 15)`` (5 at N = 200, 26 at N = 5000) or larger for a slowly varying rate.

    Rule: ``std(dt) / T <= UNIFORM_TOL`` -> ``uniform``; else ``D <= JITTER_DRIFT_MAX`` and
    ``std(r) <= JITTER_RESIDUAL_MAX * T`` -> ``jittered``: the samples are kept and put on the
    fitted grid ``t0 + k T`` (the stamps are discarded, with a warning); otherwise ``irregular``:
    positions, torques (and logged velocities) are resampled onto a uniform grid with the
    segment's *mean* step ``(t_last - t_first) / (N - 1)`` (same span and sample count) by a
    not-a-knot cubic spline through the logged stamps (warning when ``std(dt) / T`` exceeds
    ``IRREGULAR_WARN``). Derivatives are then taken on that uniform grid only.

Gaps (:func:`split_at_gaps`)
    A step ``dt > GAP_FACTOR x median(dt)`` is a logging gap (at least two samples missing): the
    file is split there into segments; filtering, differentiation, trimming, instruments and
    folds all work per segment.

Stiction (:func:`stuck_mask`)
    A joint sticks where its filtered speed stays below ``STICK_SPEED`` [rad/s] for at least
    ``STICK_MIN_S`` seconds while its torque changes by more than ``STICK_TORQUE_FRAC`` of the
    joint's torque range: there friction balances whatever torque is applied and is not a
    function of velocity. Those samples are marked (``IdentData.stuck``) and reported.

Derivative check (:func:`derivative_consistency`)
    After a zero-phase low-pass at ``f_c`` (an effective order-8 roll-off) a signal carries
    essentially nothing above ``BAND_MARGIN x f_c``, so ``rms(qdd) <= 2 pi BAND_MARGIN f_c rms(qd)``
    (Bernstein's inequality for band-limited signals, applied to the RMS through Parseval);
    an acceleration beyond that bound comes from differentiating something that is not the
    motion (jittered stamps, logged velocities out of step with the positions).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: a step longer than this many median steps is a logging gap (the file is split there)
GAP_FACTOR = 3.0
#: std(dt) / T at or below which stamps are taken as uniform (timer rounding)
UNIFORM_TOL = 1e-3
#: drift ratio D = std(r) / (std(dt)/sqrt(2)) at or below which stamps scatter around one rate
JITTER_DRIFT_MAX = 2.0
#: and the stamp residual must stay below this fraction of the period (else samples may be out of order)
JITTER_RESIDUAL_MAX = 0.25
#: std(dt) / T above which resampling an irregular stretch is announced as a warning
IRREGULAR_WARN = 0.05
#: stiction: speed threshold [rad/s], minimum duration [s], torque change as a fraction of the range
STICK_SPEED = 0.01
STICK_MIN_S = 0.1
STICK_TORQUE_FRAC = 0.05
#: warn when a joint is stuck on more than this fraction of its samples
STICK_WARN_FRAC = 0.10
#: band margin of the acceleration check (content above BAND_MARGIN x cut-off is negligible)
BAND_MARGIN = 1.5
#: logged velocity vs derivative of the positions: relative RMS disagreement that warns
VELOCITY_MISMATCH = 0.2


@dataclass
class StampDiagnosis:
    """What :func:`classify_stamps` found for one gap-free stretch (SI: seconds)."""

    kind: str  # "uniform", "jittered" or "irregular"
    period: float  # T of the uniform grid used
    relative_jitter: float  # std(dt) / T
    drift_ratio: float  # D = std(r) / (std(dt) / sqrt(2))
    residual_rel: float  # std(r) / T
    samples: int

    def to_dict(self) -> dict:
        return {"kind": self.kind, "period": self.period, "relative_jitter": self.relative_jitter,
                "drift_ratio": self.drift_ratio, "residual_rel": self.residual_rel,
                "samples": self.samples}


def split_at_gaps(t: np.ndarray, factor: float = GAP_FACTOR) -> list[slice]:
    """Slices of ``t`` between logging gaps (``dt > factor x median(dt)``), in order."""
    t = np.asarray(t, float)
    dt = np.diff(t)
    if dt.size == 0:
        return [slice(0, len(t))]
    cut = np.nonzero(dt > factor * float(np.median(dt)))[0]
    bounds = [0, *(cut + 1).tolist(), len(t)]
    return [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]


def classify_stamps(t: np.ndarray) -> StampDiagnosis:
    """Uniform, jittered around one rate, or irregular (module docstring for the statistic)."""
    t = np.asarray(t, float)
    N = len(t)
    k = np.arange(N, dtype=float)
    kc = k - k.mean()
    T = float(np.dot(kc, t - t.mean()) / np.dot(kc, kc))
    r = t - t.mean() - T * kc
    dt = np.diff(t)
    sd_dt = float(np.std(dt))
    rel = sd_dt / T
    sd_r = float(np.std(r))
    D = sd_r / max(sd_dt / math.sqrt(2.0), 1e-300)
    if rel <= UNIFORM_TOL:
        kind = "uniform"
    elif D <= JITTER_DRIFT_MAX and sd_r <= JITTER_RESIDUAL_MAX * T:
        kind = "jittered"
    else:
        kind = "irregular"
        T = float((t[-1] - t[0]) / (N - 1))
    return StampDiagnosis(kind=kind, period=T, relative_jitter=rel, drift_ratio=float(D),
                          residual_rel=sd_r / T, samples=N)


def uniform_grid(t: np.ndarray, diag: StampDiagnosis) -> np.ndarray:
    """The grid the samples are placed on: the fitted line (uniform/jittered) or ``t0 + k T_mean``."""
    t = np.asarray(t, float)
    k = np.arange(len(t), dtype=float)
    if diag.kind == "irregular":
        return t[0] + k * diag.period
    kc = k - k.mean()
    return t.mean() + diag.period * kc


def resample_cubic(t: np.ndarray, x: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Not-a-knot cubic spline through ``(t, x)`` evaluated on ``grid`` (along axis 0)."""
    from scipy.interpolate import CubicSpline

    return CubicSpline(np.asarray(t, float), np.asarray(x, float), axis=0)(grid)


def condition_stretch(t, arrays: dict, name: str = "") -> tuple[np.ndarray, dict, StampDiagnosis, list[str]]:
    """Put one gap-free stretch on a uniform grid. ``arrays``: {"q": (N, n), "tau": ..., ...}
    sampled at ``t``. Returns (grid, arrays on the grid, diagnosis, one-line messages)."""
    diag = classify_stamps(t)
    grid = uniform_grid(t, diag)
    msgs = []
    if diag.kind == "jittered":
        msgs.append(
            f"{name}: time stamps scatter around a fixed rate ({1 / diag.period:.4g} Hz; jitter "
            f"std(dt)/T = {diag.relative_jitter:.3f}, drift ratio {diag.drift_ratio:.2f} <= "
            f"{JITTER_DRIFT_MAX:g}): samples kept, placed on the uniform grid t0 + k T "
            "(stamps discarded)")
        out = {k: (None if v is None else np.array(v, float)) for k, v in arrays.items()}
    elif diag.kind == "irregular":
        if diag.relative_jitter > IRREGULAR_WARN:
            msgs.append(
                f"{name}: irregular sampling (jitter std(dt)/T = {diag.relative_jitter:.3f}, stamp "
                f"drift ratio {diag.drift_ratio:.1f} > {JITTER_DRIFT_MAX:g}): positions and torques "
                f"resampled onto a uniform {1 / diag.period:.4g} Hz grid by cubic-spline interpolation")
        out = {k: (None if v is None else resample_cubic(t, v, grid)) for k, v in arrays.items()}
    else:
        out = {k: (None if v is None else np.array(v, float)) for k, v in arrays.items()}
    return grid, out, diag, msgs


def stuck_mask(qd: np.ndarray, tau: np.ndarray, dt: float, speed: float = STICK_SPEED,
               min_s: float = STICK_MIN_S, torque_frac: float = STICK_TORQUE_FRAC) -> np.ndarray:
    """(N, n) bool: samples where a joint sticks (|qd| < ``speed`` [rad/s] for a run of at least
    ``min_s`` seconds during which its torque changes by more than ``torque_frac`` of its range)."""
    qd = np.asarray(qd, float).reshape(len(qd), -1)
    tau = np.asarray(tau, float).reshape(len(tau), -1)
    N, n = qd.shape
    out = np.zeros((N, n), bool)
    min_len = max(2, int(math.ceil(min_s / dt)))
    for j in range(n):
        span = float(np.ptp(tau[:, j]))
        if span <= 0:
            continue
        slow = np.abs(qd[:, j]) < speed
        edges = np.diff(np.concatenate([[0], slow.astype(np.int8), [0]]))
        starts, stops = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]
        for a, b in zip(starts, stops):
            if b - a >= min_len and np.ptp(tau[a:b, j]) > torque_frac * span:
                out[a:b, j] = True
    return out


def derivative_consistency(qd: np.ndarray, qdd: np.ndarray, cutoff_hz: float | None, dt: float,
                           name: str = "") -> list[str]:
    """Messages for joints whose RMS acceleration exceeds the band limit
    ``2 pi f_b rms(qd)``, ``f_b = BAND_MARGIN x cut-off`` (Nyquist without a filter)."""
    fb = min(BAND_MARGIN * cutoff_hz, 0.5 / dt) if cutoff_hz else 0.5 / dt
    rv = np.sqrt(np.mean(np.asarray(qd) ** 2, axis=0))
    ra = np.sqrt(np.mean(np.asarray(qdd) ** 2, axis=0))
    msgs = []
    for j in range(len(rv)):
        bound = 2 * math.pi * fb * rv[j]
        if ra[j] > bound and ra[j] > 0:
            msgs.append(
                f"{name}: joint {j + 1} (q{j + 1}) RMS acceleration {ra[j]:.3g} rad/s^2 exceeds what "
                f"the motion allows (2 pi x {fb:.3g} Hz x RMS velocity {rv[j]:.3g} = {bound:.3g}): "
                "derivatives are not consistent with the positions (time stamps? logged velocities?)")
    return msgs


def agreement(given: np.ndarray, reference: np.ndarray, given_name: str, reference_name: str,
              name: str = "", tol: float = VELOCITY_MISMATCH) -> list[str]:
    """Messages for joints whose ``given`` signal (a logged velocity, a given acceleration)
    differs from ``reference`` (the derivative of the positions / velocities on the same grid and
    in the same band) by more than ``tol`` relative RMS."""
    msgs = []
    for j in range(given.shape[1]):
        ref = float(np.sqrt(np.mean(reference[:, j] ** 2)))
        err = float(np.sqrt(np.mean((given[:, j] - reference[:, j]) ** 2)))
        if ref > 0 and err > tol * ref:
            msgs.append(f"{name}: {given_name}{j + 1} differs from {reference_name}{j + 1} by "
                        f"{err / ref:.0%} RMS (sign, units, delay, noise or a different sensor?)")
    return msgs


def velocity_agreement(qd_logged: np.ndarray, qd_from_q: np.ndarray, name: str = "") -> list[str]:
    """Logged velocity against the derivative of the positions (:func:`agreement`)."""
    return agreement(qd_logged, qd_from_q, "logged velocity qd", "the derivative of q", name)


__all__ = ["GAP_FACTOR", "StampDiagnosis", "split_at_gaps", "classify_stamps", "uniform_grid",
           "resample_cubic", "condition_stretch", "stuck_mask", "derivative_consistency",
           "velocity_agreement", "agreement"]


#: family-wise level of the position-jump test (:func:`position_jumps`) over every step and joint
#: of a file (Bonferroni): a file of smooth motion is flagged with at most this probability
JUMP_ALPHA = 1e-4
#: a jump within this fraction of a whole number of turns (2 pi k) is a wrapped angle
WRAP_TOL = 0.05


def position_jumps(q: np.ndarray, alpha: float = JUMP_ALPHA) -> list[tuple[int, int, float, float]]:
    """Steps ``k -> k+1`` in which a joint's position moves far more than in both neighbouring
    steps: ``(k, joint, step [rad], z)``, sorted.

    A motion sampled above its band changes its step only by acceleration x dt^2 (plus encoder
    noise) from one sample to the next, so ``e_k = |dq_k| - max(|dq_{k-1}|, |dq_{k+1}|)`` is of the
    size of the second differences. ``z = e_k / s`` with ``s`` = 1.4826 MAD of the second
    differences + one encoder quantum (the smallest non-zero step); a step with ``z`` above the
    normal quantile at ``alpha`` / (number of steps x joints) is one no motion of this log makes:
    two logs joined with shifted stamps, an encoder glitch, a wrapped angle. Measured on the DFKI
    logs (9 files, both joints): largest z 4.8, limit 5.7; a joined simulated log 169 and 4142."""
    from scipy.stats import norm

    q = np.asarray(q, float).reshape(len(q), -1)
    N, n = q.shape
    if N < 8:
        return []
    dq = np.diff(q, axis=0)
    d2 = np.diff(dq, axis=0)
    zlim = float(norm.isf(alpha / (2 * dq.size)))
    out = []
    for j in range(n):
        a = np.abs(dq[:, j])
        steps = a[a > 0]
        quantum = float(steps.min()) if steps.size else 0.0
        scale = 1.4826 * float(np.median(np.abs(d2[:, j] - np.median(d2[:, j])))) + quantum
        if scale <= 0:
            continue
        neighbours = np.maximum(np.r_[0.0, a[:-1]], np.r_[a[1:], 0.0])
        z = (a - neighbours) / scale
        # the first and last steps have one neighbour: e_k is then only a second difference (a
        # run that starts or stops accelerating hard), not a jump; a cut there would leave one
        # sample, which the filter trim drops anyway
        z[0] = z[-1] = 0.0
        out += [(int(k), j, float(dq[k, j]), float(z[k])) for k in np.nonzero(z > zlim)[0]]
    return sorted(out)


def is_wrap(step: float, tol: float = WRAP_TOL) -> bool:
    """True when ``step`` [rad] is within ``tol`` of a non-zero whole number of turns."""
    turns = step / (2 * np.pi)
    return round(turns) != 0 and abs(turns - round(turns)) <= tol
