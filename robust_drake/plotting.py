"""Plots a person would rather look at than read (matplotlib, written to files).

No function here touches pyplot or the matplotlib backend: figures are bare
``matplotlib.figure.Figure`` objects saved with ``fig.savefig``, so they work under any backend
(a notebook's inline backend stays as it was; only the command line selects Agg, in
``robust_drake.cli.main``) and open no window.
"""

from __future__ import annotations

import pathlib

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

    from robust_drake.diagram import SimulationResult


#: The shared look of every figure of the package (matplotlib rcParams, applied with
#: :func:`style` while a figure is built; a notebook's own settings are left alone): fonts
#: legible at the saved size (legends >= 8.5 pt), light grids, no top/right spines.
STYLE = {
    "font.size": 10.0, "axes.titlesize": 10.5, "axes.labelsize": 10.0, "xtick.labelsize": 9.0,
    "ytick.labelsize": 9.0, "legend.fontsize": 9.0, "figure.titlesize": 11.5, "axes.grid": True,
    "grid.alpha": 0.3, "axes.spines.top": False, "axes.spines.right": False, "legend.frameon": False,
    "lines.linewidth": 1.2, "savefig.dpi": 110, "savefig.bbox": "tight", "figure.dpi": 100,
    "axes.prop_cycle": None,  # filled below: matplotlib's tab10, in the same order
}


def _style() -> dict:
    from cycler import cycler

    out = dict(STYLE)
    out["axes.prop_cycle"] = cycler(color=["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
                                           "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf"])
    return out


def style():
    """Context manager: build figures in the package's shared style (:data:`STYLE`)."""
    import matplotlib

    return matplotlib.rc_context(_style())


def styled(func):
    """Decorator: run a figure function inside :func:`style`."""
    import functools

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with style():
            return func(*args, **kwargs)

    return wrapper


def subplots(nrows: int = 1, ncols: int = 1, *, figsize=None, **kwargs):
    """``(fig, axes)`` like ``pyplot.subplots`` but outside pyplot: a detached ``Figure`` (no
    backend switch, no GUI window, nothing to close; it is freed with its last reference).
    ``kwargs`` go to ``Figure.subplots`` (``squeeze``, ``sharex``, ...)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    return fig, fig.subplots(nrows, ncols, **kwargs)


#: points per drawn time series in repair figures (an envelope of 1000 buckets; a 0.8 s
#: savefig of 20k-sample, 7-joint torque panels becomes ~0.2 s, the picture at 80 dpi the same)
PLOT_POINTS = 2000


def envelope(x: np.ndarray, y: np.ndarray, max_points: int = PLOT_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """``(x, y)`` thinned to at most ``max_points`` samples for drawing: the samples are cut into
    ``max_points // 2`` consecutive buckets and each bucket keeps its smallest and its largest
    ``y`` (in time order), so every peak and spike a full-resolution line shows is still drawn.
    Series of at most ``max_points`` samples are returned as they are."""
    x, y = np.asarray(x), np.asarray(y)
    N = len(y)
    buckets = max(max_points // 2, 1)
    if N <= max_points:
        return x, y
    size = -(-N // buckets)
    pad = np.concatenate([y, np.full(buckets * size - N, y[-1])]).reshape(buckets, size)
    start = np.arange(buckets) * size
    i_lo = np.minimum(start + np.argmin(pad, axis=1), N - 1)
    i_hi = np.minimum(start + np.argmax(pad, axis=1), N - 1)
    idx = np.stack([np.minimum(i_lo, i_hi), np.maximum(i_lo, i_hi)], axis=1).reshape(-1)
    idx = idx[start.repeat(2) < N]  # buckets that are all padding (none unless N is tiny)
    return x[idx], y[idx]


def _prepare(path) -> pathlib.Path:
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


def _describe(result) -> str:
    """'sp2 on d2r2 (load none), circle, 2500 Hz, 2 s, friction compensation off' from the config."""
    c = result.config or {}
    fc = "on" if c.get("friction_compensation") else "off"
    return (f"{c.get('controller', '?')} on {c.get('robot', '?')} (load {c.get('load', '?')}), "
            f"{c.get('trajectory', '?')}, {c.get('rate', float('nan')):g} Hz, "
            f"{result.sim_seconds:.3g} s, friction compensation {fc}")


def tracking_figure(result: "SimulationResult", title: str | None = None) -> "Figure":
    """Tracking errors per joint [rad], task-space error [mm] and torques [N m] against time,
    the layout of JS figures 4-11, as a matplotlib ``Figure``.

    The interval the metrics skip (``metrics_skip``, 1 s for the circle, JS section 10) is
    shaded; the torque limit (D2R2: 31.2 N m) is drawn dashed; legends sit outside the data.

    Parameters
    ----------
    result : SimulationResult
        A run of :func:`robust_drake.simulate`.
    title : str, optional
        Figure title; None describes the run (controller, robot, load, trajectory, rate,
        duration, friction compensation).

    Returns
    -------
    matplotlib.figure.Figure
        Detached from pyplot: display it in a notebook or ``fig.savefig(path)``.
    """
    t = result.t
    e = result.q - result.q_d
    n = e.shape[1]
    rows = n + 2 if result.link_lengths else n + 1
    fig, axes = subplots(rows, 1, figsize=(9, 1.9 * rows + 0.6), sharex=True, squeeze=False)
    axes = axes[:, 0]
    skip = float((result.config or {}).get("metrics_skip") or 0.0)
    for j in range(n):
        axes[j].plot(t, e[:, j], lw=0.8, color=f"C{j}")
        axes[j].set_ylabel(f"e{j + 1} = q{j + 1} - q{j + 1},d [rad]", fontsize=8)
    k = n
    if result.link_lengths:
        from robust_drake.kinematics import planar_forward_kinematics

        d = np.linalg.norm(planar_forward_kinematics(result.q, result.link_lengths)
                           - planar_forward_kinematics(result.q_d, result.link_lengths), axis=1)
        axes[k].plot(t, d * 1e3, lw=0.8, color="C2")
        axes[k].set_ylabel("task-space error [mm]", fontsize=8)
        k += 1
    for j in range(n):
        axes[k].plot(t, result.tau[:, j], lw=0.6, color=f"C{j}", label=f"tau{j + 1}")
    limit = (result.config or {}).get("torque_limit")
    if limit is not None:
        lims = np.broadcast_to(np.asarray(limit, float), (n,))
        same = bool(np.all(lims == lims[0]))
        for j, lim in enumerate(lims[:1] if same else lims):
            for sign in (1, -1):
                axes[k].axhline(sign * lim, color="k" if same else f"C{j}", ls="--", lw=0.7,
                                label=(f"limit +-{lim:g} N m" + ("" if same else f" (tau{j + 1})"))
                                if sign > 0 else None)
    axes[k].set_ylabel("applied torque [N m]", fontsize=8)
    axes[k].set_xlabel("t [s]")
    axes[k].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, frameon=False)
    for ax in axes:
        ax.grid(alpha=0.3)
        if skip > 0:
            ax.axvspan(t[0], t[0] + skip, color="0.93", zorder=0,
                       label="not in the metrics" if ax is axes[0] else None)
    if skip > 0:
        axes[0].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, frameon=False)
    fig.suptitle(title or _describe(result), fontsize=10)
    fig.tight_layout()
    return fig


def task_path_figure(result: "SimulationResult", title: str | None = None) -> "Figure":
    """The end effector's path in the plane, desired and actual [m] (planar 2-link arms).

    Parameters
    ----------
    result : SimulationResult
        A run of a planar 2-link arm (``result.link_lengths`` set).
    title : str, optional
        Figure title (None: describes the run).

    Returns
    -------
    matplotlib.figure.Figure
        Equal axes in m; the desired path dashed, the start marked.
    """
    from robust_drake.errors import RobustDrakeError
    from robust_drake.kinematics import planar_forward_kinematics

    if not result.link_lengths:
        raise RobustDrakeError("task_path_figure needs a planar 2-link arm (result.link_lengths)")
    p = planar_forward_kinematics(result.q, result.link_lengths)
    p_d = planar_forward_kinematics(result.q_d, result.link_lengths)
    fig, ax = subplots(figsize=(6, 5.5))
    ax.plot(p_d[:, 0], p_d[:, 1], "k--", lw=1.0, label="desired")
    ax.plot(p[:, 0], p[:, 1], color="C3", lw=0.9, label="actual")
    ax.plot(p_d[0, 0], p_d[0, 1], "ko", ms=4, label="start")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set(xlabel="x [m]", ylabel="y [m]")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    ax.set_title(title or "task-space path\n" + _describe(result), fontsize=9)
    fig.tight_layout()
    return fig


def plot_tracking(result: "SimulationResult", path: "str | pathlib.Path", title: str | None = None) -> pathlib.Path:
    """Write :func:`tracking_figure` to ``path`` (PNG; the folder is created).

    Parameters
    ----------
    result : SimulationResult
        A closed-loop run.
    path : str or pathlib.Path
        Output file.
    title : str, optional
        Figure title (None: describes the run).

    Returns
    -------
    pathlib.Path
        The file written.
    """
    path = _prepare(path)
    tracking_figure(result, title).savefig(path, dpi=110)
    return path


def _load_report(report_or_dir) -> dict:
    """The repair report: a dict as is, else ``report.json`` (or a folder holding it)."""
    import json
    import os

    from robust_drake.errors import RobustDrakeError

    if isinstance(report_or_dir, dict):
        return report_or_dir
    path = pathlib.Path(os.fspath(report_or_dir))
    if path.is_dir():
        path = path / "report.json"
    if not path.is_file():
        raise RobustDrakeError(f"no repair report at {path} (give the report dict, report.json or its folder)")
    with open(path) as fh:
        return json.load(fh)


def repair_figure(report_or_dir: "dict | str | pathlib.Path") -> "Figure":
    """RMS torque residual per joint [N m] of the baseline and the repaired model, on the fit
    and the validation data, from a repair report (what :func:`robust_drake.repair` returns).

    The time-series figures of a repair (``residual_fit.png``, ``residual_validate.png``,
    ``torque_validate.png``) need the data and are written by ``repair --out``; this one needs
    only the report.

    Parameters
    ----------
    report_or_dir : dict or str or pathlib.Path
        The report dict, a ``report.json`` file or the folder holding it.

    Returns
    -------
    matplotlib.figure.Figure
        One panel per data set (fit, validate), grouped bars per joint (numbered from 0 with the
        URDF's joint names, as in the report); detached from pyplot.
    """
    from robust_drake.errors import RobustDrakeError

    rep = _load_report(report_or_dir)
    try:
        base, fin = rep["baseline"], rep["final"]
    except (KeyError, TypeError):
        raise RobustDrakeError("not a repair report: 'baseline' and 'final' are missing") from None
    names = rep.get("joint_names") or [str(j) for j in range(len(base["rms_fit"]))]
    fig, axes = subplots(1, 2, figsize=(10, 4), sharey=True, squeeze=False)
    x = np.arange(len(names))
    for ax, key, what in zip(axes[0], ("rms_fit", "rms_validate"), ("fit data", "validation data")):
        b = np.array([np.nan if v is None else v for v in base[key]], float)
        f = np.array([np.nan if v is None else v for v in fin[key]], float)
        ax.bar(x - 0.2, b, 0.4, color="tab:red", label="baseline model")
        ax.bar(x + 0.2, f, 0.4, color="tab:blue", label="repaired model")
        ax.set_xticks(x, [f"joint {j} ({n})" for j, n in enumerate(names)])
        ax.set_title(what)
        ax.grid(axis="y", alpha=0.3)
    axes[0, 0].set_ylabel("RMS torque residual [N m]")
    axes[0, 1].legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, frameon=False)
    fig.suptitle(f"repair of {rep.get('robot', '?')}: {rep.get('verdict', '')}", fontsize=10)
    fig.tight_layout()
    return fig
