"""Plots a person would rather look at than read (matplotlib, written to files).

No function here touches pyplot or the matplotlib backend: figures are bare
``matplotlib.figure.Figure`` objects saved with ``fig.savefig``, so they work under any backend
(a notebook's inline backend stays as it was; only the command line selects Agg, in
``robust_drake.cli.main``) and open no window.
"""

from __future__ import annotations

import pathlib

from typing import TYPE_CHECKING, Protocol

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure


class TrackedRun(Protocol):
    """What the tracking figures read of a run (``robust_drake.diagram.SimulationResult`` has it):
    this module stays below the closed-loop builder and imports nothing of it."""

    t: np.ndarray  # [s]
    q: np.ndarray  # [rad]
    q_d: np.ndarray  # [rad]
    tau: np.ndarray  # [N m]
    config: dict
    link_lengths: tuple | None


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
    """'SP2 on d2r2 (load none), circle, 2500 Hz, 2 s, friction compensation off' from the config."""
    from robust_drake.registry import paper_name

    c = result.config or {}
    fc = "on" if c.get("friction_compensation") else "off"
    return (f"{paper_name(c.get('controller', '?'))} on {c.get('robot', '?')} (load {c.get('load', '?')}), "
            f"{paper_name(c.get('trajectory', '?'))}, {c.get('rate', float('nan')):g} Hz, "
            f"{result.sim_seconds:.3g} s, friction compensation {fc}")


def torque_limits(result) -> tuple[np.ndarray | None, bool]:
    """(per-joint torque limits [N m], enforced): the loop's saturation, else the actuator limits of
    the robot's description (drawn, not enforced: e.g. the Panda's 87/12 N m); (None, False) if neither."""
    n = np.shape(result.tau)[1]
    limit = (result.config or {}).get("torque_limit")
    if limit is not None:
        return np.broadcast_to(np.asarray(limit, float), (n,)).copy(), True
    try:
        from robust_drake.description import describe

        lims = describe((result.config or {}).get("robot", "")).torque_limits
    except Exception:  # noqa: BLE001 - a URDF without a description
        lims = None
    if lims is None or len(lims) != n:
        return None, False
    return np.asarray(lims, float), False


def draw_torque_limits(ax, result, joints=None) -> None:
    """Dashed +-limit lines on a torque axis, one legend entry per distinct value ("+-87 N m,
    joints 1-4"); solid-black lines are the saturation the loop applies, grey ones the actuator
    limits of the description that the loop does not enforce."""
    lims, enforced = torque_limits(result)
    if lims is None:
        return
    shown = range(len(lims)) if joints is None else joints
    values = list(dict.fromkeys(np.round(lims[list(shown)], 6)))
    every = len(set(np.round(lims, 6))) == 1
    for v in values:
        js = [j + 1 for j in shown if np.round(lims[j], 6) == v]
        which = "" if every else (f", joint {js[0]}" if len(js) == 1 else f", joints {_ranges(js)}")
        label = f"{'saturation' if enforced else 'actuator limit (not enforced)'} +-{v:g} N m{which}"
        color = "k" if enforced else "0.45"
        for sign in (1, -1):
            ax.axhline(sign * v, color=color, ls="--", lw=0.9, label=label if sign > 0 else None, zorder=1)


def _ranges(js: list[int]) -> str:
    """[1, 2, 3, 5] -> '1-3, 5'."""
    out, start = [], js[0]
    for a, b in zip(js, js[1:] + [None]):
        if b != a + 1:
            out.append(f"{start}" if start == a else f"{start}-{a}")
            start = b
    return ", ".join(out)


def window_limits(t, y, skip: float, pad: float = 0.08):
    """(low, high) y-limits over the samples the metrics measure (t >= t0 + skip): a transient
    inside the skipped interval does not set the scale of the figure."""
    t, y = np.asarray(t), np.asarray(y)
    keep = t >= t[0] + skip
    if not np.any(keep):
        keep = np.ones_like(t, bool)
    lo, hi = float(np.nanmin(y[keep])), float(np.nanmax(y[keep]))
    span = hi - lo if hi > lo else max(abs(hi), 1e-12)
    return lo - pad * span, hi + pad * span


@styled
def tracking_figure(result: "TrackedRun", title: str | None = None) -> "Figure":
    """Tracking errors per joint [rad], task-space error [mm] and torques [N m] against time,
    the layout of JS figures 4-11, as a matplotlib ``Figure``.

    The interval the metrics skip (``metrics_skip``, 1 s for the circle, JS section 10) is
    shaded and the y-limits are set on the samples after it (a start-up transient there is
    clipped, not the scale of the figure); the torque limits are drawn dashed: the loop's
    saturation (D2R2: 31.2 N m) in black, or else the robot's actuator limits (Panda: 87/12 N m)
    in grey; legends sit outside the data.

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
    err_panels = [[j] for j in range(n)] if n <= 3 else [list(range(n))]  # many joints: one panel
    lims, _ = torque_limits(result)
    if lims is not None and len(set(np.round(lims, 6))) > 1:  # a panel per limit (Panda: 87 | 12 N m)
        groups = {}
        for j, v in enumerate(np.round(lims, 6)):
            groups.setdefault(v, []).append(j)
        tau_panels = list(groups.values())
    else:
        tau_panels = [list(range(n))]
    rows = len(err_panels) + (1 if result.link_lengths else 0) + len(tau_panels)
    fig, axes = subplots(rows, 1, figsize=(9, 1.8 * rows + 0.9), sharex=True, squeeze=False)
    axes = axes[:, 0]
    skip = float((result.config or {}).get("metrics_skip") or 0.0)
    for ax, joints in zip(axes, err_panels):
        for j in joints:
            ax.plot(t, e[:, j], lw=0.9, color=f"C{j}", label=f"e{j + 1}")
        ax.set_ylabel(f"e{joints[0] + 1} [rad]" if len(joints) == 1 else "e = q - q_d [rad]")
        if skip > 0:
            ax.set_ylim(*window_limits(t, e[:, joints], skip))
        if len(joints) > 1:
            ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), ncol=1 if n <= 8 else 2)
    k = len(err_panels)
    if result.link_lengths:
        from robust_drake.kinematics import planar_forward_kinematics

        d = np.linalg.norm(planar_forward_kinematics(result.q, result.link_lengths)
                           - planar_forward_kinematics(result.q_d, result.link_lengths), axis=1)
        axes[k].plot(t, d * 1e3, lw=0.9, color="k")
        axes[k].set_ylabel("task error [mm]")
        if skip > 0:
            axes[k].set_ylim(0.0, window_limits(t, d * 1e3, skip)[1])
        k += 1
    for ax, joints in zip(axes[k:], tau_panels):
        for j in joints:
            ax.plot(t, result.tau[:, j], lw=0.8, color=f"C{j}", label=f"tau{j + 1}")
        draw_torque_limits(ax, result, joints=joints)
        ax.set_ylabel("torque [N m]" if len(tau_panels) == 1 else f"tau{_ranges([j + 1 for j in joints])} [N m]")
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0))
    axes[-1].set_xlabel("t [s]")
    for ax in axes:
        if skip > 0:
            ax.axvspan(t[0], t[0] + skip, color="0.92", zorder=0,
                       label="not in the metrics (clipped)" if ax is axes[0] else None)
    if skip > 0:
        axes[0].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.suptitle(title or _describe(result))
    fig.align_ylabels(axes)
    fig.tight_layout()
    return fig


@styled
def task_path_figure(result: "TrackedRun", title: str | None = None) -> "Figure":
    """The end effector's path in the plane, desired and actual [m] (planar 2-link arms), with an
    inset of the distance between them [mm] against time (the paths themselves lie within a line
    width of each other).

    Parameters
    ----------
    result : SimulationResult
        A run of a planar 2-link arm (``result.link_lengths`` set).
    title : str, optional
        Figure title (None: describes the run).

    Returns
    -------
    matplotlib.figure.Figure
        Equal axes in m; the desired path thick and light, the actual thin on top, the start
        marked; inset: |p - p_d| [mm] over t [s] (the interval the metrics skip shaded).
    """
    from robust_drake.errors import RobustDrakeError
    from robust_drake.kinematics import planar_forward_kinematics

    if not result.link_lengths:
        raise RobustDrakeError("task_path_figure needs a planar 2-link arm (result.link_lengths)")
    p = planar_forward_kinematics(result.q, result.link_lengths)
    p_d = planar_forward_kinematics(result.q_d, result.link_lengths)
    fig, ax = subplots(figsize=(7.5, 5.8))
    ax.plot(p_d[:, 0], p_d[:, 1], color="0.7", lw=4.0, solid_capstyle="round", label="desired")
    ax.plot(p[:, 0], p[:, 1], color="C3", lw=1.0, label="actual")
    ax.plot(p_d[0, 0], p_d[0, 1], "ko", ms=5, label="start")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set(xlabel="x [m]", ylabel="y [m]")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0))
    inset = ax.inset_axes([1.05, 0.05, 0.55, 0.42])
    err = 1e3 * np.linalg.norm(p - p_d, axis=1)
    skip = float((result.config or {}).get("metrics_skip") or 0.0)
    inset.plot(result.t, err, color="C3", lw=0.8)
    if skip > 0:
        inset.axvspan(result.t[0], result.t[0] + skip, color="0.92", zorder=0)
        inset.set_ylim(0.0, window_limits(result.t, err, skip)[1])
    inset.set_xlabel("t [s]", fontsize=8.5)
    inset.set_ylabel("|p - p_d| [mm]", fontsize=8.5)
    inset.tick_params(labelsize=8)
    inset.set_title("task-space error", fontsize=9)
    ax.set_title(title or "task-space path\n" + _describe(result))
    fig.tight_layout()
    fig.subplots_adjust(right=0.62)
    return fig


def plot_tracking(result: "TrackedRun", path: "str | pathlib.Path", title: str | None = None) -> pathlib.Path:
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
    tracking_figure(result, title).savefig(path, dpi=110, bbox_inches="tight")
    return path


def _load_report(report_or_dir) -> dict:
    """The repair report: a dict as is, else ``report.json`` (or a folder holding it)."""
    import json
    import os

    from robust_drake.errors import RobustDrakeError

    if isinstance(report_or_dir, dict):
        return report_or_dir
    if isinstance(getattr(report_or_dir, "report", None), dict):  # rd.repair's RepairResult
        return report_or_dir.report
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
        One panel per data set (fit, validate), grouped bars per joint (numbered from 1 with the
        URDF's joint names, as in the report); detached from pyplot.
    """
    from robust_drake.errors import RobustDrakeError

    rep = _load_report(report_or_dir)
    try:
        base, fin = rep["baseline"], rep["final"]
    except (KeyError, TypeError):
        raise RobustDrakeError("not a repair report: 'baseline' and 'final' are missing") from None
    names = rep.get("joint_names") or [f"joint{j + 1}" for j in range(len(base["rms_fit"]))]
    fig, axes = subplots(1, 2, figsize=(10, 4), sharey=True, squeeze=False)
    x = np.arange(len(names))
    for ax, key, what in zip(axes[0], ("rms_fit", "rms_validate"), ("fit data", "validation data")):
        b = np.array([np.nan if v is None else v for v in base[key]], float)
        f = np.array([np.nan if v is None else v for v in fin[key]], float)
        ax.bar(x - 0.2, b, 0.4, color="tab:red", label="baseline model")
        ax.bar(x + 0.2, f, 0.4, color="tab:blue", label="repaired model")
        ax.set_xticks(x, [f"joint {j + 1} ({n})" for j, n in enumerate(names)])  # joints from 1 (README)
        ax.set_title(what)
        ax.grid(axis="y", alpha=0.3)
    axes[0, 0].set_ylabel("RMS torque residual [N m]")
    axes[0, 1].legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, frameon=False)
    fig.suptitle(f"repair of {rep.get('robot', '?')}: {rep.get('verdict', '')}", fontsize=10)
    fig.tight_layout()
    return fig
