"""The one definition of a diverged closed-loop run, shared by simulate, compare, batch and
Monte Carlo.

A run has diverged when any of these holds on its logs (sampled at the controller rate):

1. a non-finite joint position q, velocity v or reference q_d (NaN/inf: the integrator blew
   up, or the controller produced a non-finite torque);
2. |q| > ``state_limit`` [rad] or |v| > ``state_limit`` [rad/s] (default
   :data:`STATE_LIMIT` = 1e3: no arm of this package turns 160 revolutions or spins at
   1e3 rad/s while tracking);
3. a joint tracking error |q - q_d| > ``error_limit`` [rad] (default
   :data:`TRACKING_ERROR_LIMIT` = pi rad: the arm is on the wrong side of its reference,
   the loop has lost it).

Pure function, no Drake: :func:`is_diverged` returns ``(diverged, reason)`` with the reason
naming the criterion, the time of its first violation and the bound.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["STATE_LIMIT", "TRACKING_ERROR_LIMIT", "is_diverged"]

#: |q| [rad] or |v| [rad/s] beyond this marks a run as diverged.
STATE_LIMIT = 1e3
#: |q_i - q_d,i| [rad] beyond this (half a turn) marks a run as diverged ("tracking lost").
TRACKING_ERROR_LIMIT = math.pi


def _first_time(t, mask_rows) -> str:
    idx = np.flatnonzero(mask_rows)
    if idx.size == 0 or t is None or len(t) <= idx[0]:
        return ""
    return f" at t = {float(t[idx[0]]):.4g} s"


def is_diverged(t, q, v, q_d, *, state_limit: float = STATE_LIMIT,
                error_limit: float | None = TRACKING_ERROR_LIMIT) -> tuple[bool, str | None]:
    """Has the run with logs ``t`` (K,) [s], ``q``, ``v``, ``q_d`` (K, n) diverged?

    Returns ``(False, None)`` or ``(True, reason)``; the checks run in the order of the
    module docstring and the first one that fails gives the reason. ``error_limit=None``
    skips the tracking-error check.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    v = np.atleast_2d(np.asarray(v, dtype=float))
    q_d = np.atleast_2d(np.asarray(q_d, dtype=float))
    bad = ~(np.all(np.isfinite(q), axis=1) & np.all(np.isfinite(v), axis=1)
            & np.all(np.isfinite(q_d), axis=1))
    if bad.any():
        return True, "non-finite state or reference (NaN/inf)" + _first_time(t, bad)
    over_q = np.any(np.abs(q) > state_limit, axis=1)
    if over_q.any():
        return True, (f"|q| = {float(np.max(np.abs(q))):.3g} rad beyond the limit of "
                      f"{state_limit:.3g} rad" + _first_time(t, over_q))
    over_v = np.any(np.abs(v) > state_limit, axis=1)
    if over_v.any():
        return True, (f"|v| = {float(np.max(np.abs(v))):.3g} rad/s beyond the limit of "
                      f"{state_limit:.3g} rad/s" + _first_time(t, over_v))
    if error_limit is not None and q.size:
        e = np.abs(q - q_d)
        lost = np.any(e > error_limit, axis=1)
        if lost.any():
            return True, (f"tracking lost: max joint error {float(e.max()):.3g} rad > "
                          f"{error_limit:.3g} rad" + _first_time(t, lost))
    return False, None
