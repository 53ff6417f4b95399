"""Error criteria of Jaritz & Spong, section 4 (eqs. 55, 56, 58, 59).

The paper sums squared errors over the samples sent back to the PC (eq. 53-55) without
saying how often those were sent, so |error_n| depends on the logging interval. We
resample the logs on a uniform grid of ``dt`` seconds (default 0.01 s, i.e. 100 Hz; a
choice recorded in BUILD_NOTES.md) before summing. Max errors do not depend on ``dt``.
"""

from __future__ import annotations

import numpy as np

from robust_drake.errors import RobustDrakeError
from robust_drake.kinematics import planar_forward_kinematics

METRIC_KEYS = ("error1", "maxerr1", "error2", "maxerr2", "error_task", "maxerr_task")


def _resample(t, x, grid):
    return np.stack([np.interp(grid, t, x[:, j]) for j in range(x.shape[1])], axis=1)


def error_criteria(t, q, q_d, link_lengths=None, skip: float = 0.0, dt: float | None = 0.01) -> dict:
    """JS eqs. 55 (|error_n|), 56 (maxerr_n), 58 (|error_task|), 59 (maxerr_task).

    Parameters
    ----------
    t : (K,) sample times [s]; q, q_d : (K, n) joint angles [rad].
    link_lengths : (l1, l2) [m] for the task-space criteria (2-link planar arms); None skips them.
    skip : ignore samples with t < t[0] + skip (the circle runs use the last 6 of 7 s).
    dt : resampling interval for the sums of squares; None sums the raw samples.

    Returns a dict with keys ``error{i}``, ``maxerr{i}`` per joint (1-based) and
    ``error_task``, ``maxerr_task`` (NaN without link lengths).
    """
    t = np.asarray(t, dtype=float)
    q = np.asarray(q, dtype=float)
    q_d = np.asarray(q_d, dtype=float)
    if q.shape != q_d.shape or q.ndim != 2 or q.shape[0] != t.shape[0]:
        raise RobustDrakeError(f"error_criteria: shapes t{t.shape}, q{q.shape}, q_d{q_d.shape} do not match")
    if not (np.isfinite(skip) and skip >= 0):
        raise RobustDrakeError(f"error_criteria: skip must be a finite number of seconds >= 0 (got {skip!r})")
    if dt is not None and not (np.isfinite(dt) and dt > 0):
        raise RobustDrakeError(f"error_criteria: dt must be a positive resampling interval [s] or None (got {dt!r})")
    keep = t >= t[0] + skip - 1e-12
    if keep.sum() < 2:
        raise RobustDrakeError(f"error_criteria: nothing left after skipping {skip} s of a {t[-1] - t[0]:.3f} s log")
    t, q, q_d = t[keep], q[keep], q_d[keep]
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(q_d))):
        raise RobustDrakeError("error_criteria: the log contains NaN/inf (the simulation diverged)")
    e = q - q_d
    if dt is not None:
        grid = np.arange(t[0], t[-1] + 1e-12, dt)
        e_sum = _resample(t, e, grid)
    else:
        grid, e_sum = t, e
    out = {}
    for j in range(q.shape[1]):
        out[f"error{j + 1}"] = float(np.sqrt(np.sum(e_sum[:, j] ** 2)))
        out[f"maxerr{j + 1}"] = float(np.max(np.abs(e[:, j])))
    if link_lengths is not None and q.shape[1] == 2:
        p = planar_forward_kinematics(q, link_lengths)
        p_d = planar_forward_kinematics(q_d, link_lengths)
        dist = np.linalg.norm(p - p_d, axis=1)
        dist_sum = np.interp(grid, t, dist) if dt is not None else dist
        out["error_task"] = float(np.sqrt(np.sum(dist_sum**2)))
        out["maxerr_task"] = float(np.max(dist))
    else:
        out["error_task"] = float("nan")
        out["maxerr_task"] = float("nan")
    return out


def torque_statistics(t, tau) -> dict:
    """Peak |tau|, RMS and total variation per second of each joint torque (chattering measure)."""
    t = np.asarray(t, dtype=float)
    tau = np.asarray(tau, dtype=float)
    span = max(t[-1] - t[0], 1e-12)
    return {
        "tau_peak": np.max(np.abs(tau), axis=0).tolist(),
        "tau_rms": np.sqrt(np.mean(tau**2, axis=0)).tolist(),
        "tau_tv_per_s": (np.sum(np.abs(np.diff(tau, axis=0)), axis=0) / span).tolist(),
    }
