"""Plots a person would rather look at than read (matplotlib, written to files).

No function here touches pyplot or the matplotlib backend: figures are bare
``matplotlib.figure.Figure`` objects saved with ``fig.savefig``, so they work under any backend
(a notebook's inline backend stays as it was; only the command line selects Agg, in
``robust_drake.cli.main``) and open no window.
"""

from __future__ import annotations

import pathlib

import numpy as np


def subplots(nrows: int = 1, ncols: int = 1, *, figsize=None, **kwargs):
    """``(fig, axes)`` like ``pyplot.subplots`` but outside pyplot: a detached ``Figure`` (no
    backend switch, no GUI window, nothing to close; it is freed with its last reference).
    ``kwargs`` go to ``Figure.subplots`` (``squeeze``, ``sharex``, ...)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    return fig, fig.subplots(nrows, ncols, **kwargs)


def _prepare(path) -> pathlib.Path:
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


def plot_tracking(result, path, title: str | None = None):
    """Tracking errors per joint [rad], task-space error [m] and torques [N m] against time,
    the layout of JS figures 4-11. Returns the path written."""
    path = _prepare(path)
    t = result.t
    e = result.q - result.q_d
    n = e.shape[1]
    rows = n + 2 if result.link_lengths else n + 1
    fig, axes = subplots(rows, 1, figsize=(8, 1.9 * rows), sharex=True)
    for j in range(n):
        axes[j].plot(t, e[:, j], lw=0.8)
        axes[j].set_ylabel(f"e{j + 1} [rad]")
        axes[j].grid(alpha=0.3)
    k = n
    if result.link_lengths:
        from robust_drake.kinematics import planar_forward_kinematics

        d = np.linalg.norm(planar_forward_kinematics(result.q, result.link_lengths)
                           - planar_forward_kinematics(result.q_d, result.link_lengths), axis=1)
        axes[k].plot(t, d * 1e3, lw=0.8, color="C2")
        axes[k].set_ylabel("task err [mm]")
        axes[k].grid(alpha=0.3)
        k += 1
    for j in range(n):
        axes[k].plot(t, result.tau[:, j], lw=0.6, label=f"tau{j + 1}")
    axes[k].set_ylabel("torque [N m]")
    axes[k].set_xlabel("t [s]")
    axes[k].legend(loc="upper right", fontsize=8)
    axes[k].grid(alpha=0.3)
    if title:
        axes[0].set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path
