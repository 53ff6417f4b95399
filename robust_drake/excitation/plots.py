"""Figures of a designed excitation (``robust-drake excite --plot DIR``)."""

from __future__ import annotations

import os

import numpy as np


def excitation_figure(res):
    """One period of the motion: positions with the position box, velocities, accelerations
    and model torques as fractions of their limits, one line per joint (numbered from 1, URDF names)."""
    from robust_drake.plotting import subplots

    traj, rep = res.trajectory, res.report
    rate = rep["rate"]
    t = np.arange(int(np.ceil(traj.period * rate)) + 1) / rate
    q, qd, qdd = traj(t)
    tau = res.tau[:len(t)] if len(res.tau) >= len(t) else None
    lim = rep["limits"]
    fig, axes = subplots(4, 1, figsize=(9, 9.5), sharex=True)
    lo, hi = np.asarray(lim["position"]["lower"]), np.asarray(lim["position"]["upper"])
    for j, name in enumerate(res.joint_names):
        line, = axes[0].plot(t, q[:, j], lw=1.1, label=f"{j + 1} {name}")
        axes[0].axhline(lo[j], color=line.get_color(), ls=":", lw=0.7)
        axes[0].axhline(hi[j], color=line.get_color(), ls=":", lw=0.7)
    axes[0].set_ylabel("q [rad]\n(dotted: allowed box)")
    for ax, val, key, unit in ((axes[1], qd, "velocity", "rad/s"), (axes[2], qdd, "acceleration", "rad/s^2"),
                               (axes[3], tau, "torque", "N m")):
        limv = lim.get(key)
        limv = None if limv is None else np.asarray(limv, float)
        if val is None:
            continue
        if limv is not None and np.all(np.isfinite(limv)):
            ax.plot(t, val / limv, lw=1.0)
            ax.axhline(1.0, color="k", ls="--", lw=0.8)
            ax.axhline(-1.0, color="k", ls="--", lw=0.8)
            ax.set_ylabel(f"{key} / limit")
        else:
            ax.plot(t, val, lw=1.0)
            ax.set_ylabel(f"{key} [{unit}]\n(no limit)")
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, ncol=4, loc="upper right")
    axes[-1].set_xlabel(f"t [s] (one period of {traj.period:g} s; the log repeats it {rep['periods']}x)")
    fig.suptitle(f"excitation for {rep['robot']}: {traj.harmonics} harmonics up to {traj.max_frequency:.3g} Hz, "
                 f"log det {rep['log_det']:.1f} (default {rep['default']['log_det']:.1f})", fontsize=10)
    fig.tight_layout()
    return fig


def information_figure(res):
    """Predicted standard deviation of every parameter (Cramer-Rao, torque noise
    ``noise_std``): designed excitation against the default one of the same duration."""
    from robust_drake.plotting import subplots

    rep = res.report
    names = rep["parameters"]
    sd, sd0 = np.asarray(rep["predicted_std"]), np.asarray(rep["default"]["predicted_std"])
    fig, ax = subplots(1, 1, figsize=(min(18, 3 + 0.22 * len(names)), 4.5))
    x = np.arange(len(names))
    ax.bar(x - 0.2, sd0, 0.4, label="default excitation", color="tab:red")
    ax.bar(x + 0.2, sd, 0.4, label="designed excitation", color="tab:blue")
    ax.set_yscale("log")
    ax.set_xticks(x)
    ax.set_xticklabels([nm if len(nm) <= 18 else nm[:16] + ".." for nm in names], rotation=90, fontsize=6)
    ax.set_ylabel("predicted std (SI units of each parameter)")
    ax.set_title(f"{rep['robot']}, {rep['duration']:g} s at {rep['rate']:g} Hz, torque noise {rep['noise_std']:.3g} N m: "
                 f"median std ratio default/designed {rep['median_std_ratio']:.3g}", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    return fig


def write_plots(res, folder) -> list[str]:
    os.makedirs(folder, exist_ok=True)
    out = []
    for name, make in (("excitation.png", excitation_figure), ("information.png", information_figure)):
        fig = make(res)
        path = os.path.join(str(folder), name)
        fig.savefig(path, dpi=110)
        out.append(path)
    return out
