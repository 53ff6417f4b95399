"""``robust-drake calafiore``: nominal (CI eq. 6) vs robust (eq. 15) control on the IMI SCARA (section 5.2)."""

from __future__ import annotations

import os

import numpy as np

from robust_drake.cli import add_output_flags, format_table, print_json


def register(subparsers):
    p = subparsers.add_parser(
        "calafiore", help="Calafiore & Indri section 5.2: nominal vs ellipsoid-robust control",
        description="Control the IMI SCARA with the nominal computed-torque law (CI eq. 6) and the robust "
                    "law built on the confidence ellipsoid (CI eq. 15), each on 'true' arms drawn on the "
                    "ellipsoid's boundary, and print peak, RMS and settling time of the tracking errors. "
                    "--plot DIR writes analogs of CI figures 4-6 and the torques.")
    p.add_argument("--ellipsoid", default=None, help="JSON with theta0 and P (default: the published section 5.1 values)")
    p.add_argument("--n-true", type=int, default=3, help="true parameter vectors drawn on the ellipsoid boundary (default 3)")
    p.add_argument("--duration", type=float, default=None,
                   help="simulated time [s] (default 3, 1 with ROBUST_DRAKE_SHORT=1)")
    p.add_argument("--epsilon", type=float, default=1.0,
                   help="epsilon of CI eq. 15, u = -E w / max(||w||, epsilon): smooths the robust term near w = 0 "
                        "(default 1.0)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the drawn true parameters (default 0)")
    p.add_argument("--settle-rel", type=float, default=0.1,
                   help="relative settling band: fraction of each error's peak (default 0.1)")
    add_output_flags(p, plot="DIR", files="fig3_torque_reconstruction.png, fig4_reference.png, fig5_nominal_errors.png, "
                                          "fig6_robust_errors.png, torques.png")
    p.set_defaults(func=run)


def plot_study(out, directory):
    """Analogs of CI figs. 3-6 in the package's figure style (:func:`_plot_study`)."""
    from robust_drake.plotting import style

    with style():
        return _plot_study(out, directory)


def _plot_study(out, directory):
    """Analogs of CI figs. 3-6: torque reconstruction, reference, nominal and robust tracking
    errors (same y-scale, so the two laws compare at a glance), torques; returns the paths written."""
    import numpy as np

    from robust_drake.experiments.calafiore import torque_reconstruction
    from robust_drake.plotting import subplots

    os.makedirs(directory, exist_ok=True)
    rec = out.get("_reconstruction") or torque_reconstruction()
    fig, axes = subplots(2, 1, sharex=True, figsize=(9, 5))
    for j, ax in enumerate(axes):
        ax.plot(rec["t"], rec["tau_meas"][:, j], ".", ms=3, label="measured")
        ax.plot(rec["t"], rec["tau_rec"][:, j], "-", label="reconstructed (theta0)")
        ax.plot(rec["t_samples"], rec["tau_samples"][:, j], "o", mfc="none", label="n_m samples used")
        ax.set(ylabel=f"tau{j + 1} [N m]")
    axes[0].set_title("CI fig. 3: measured vs reconstructed torque (theta0 from 5 samples)")
    axes[1].set(xlabel="t [s]")
    axes[0].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.align_ylabels(axes)
    fig.tight_layout()
    fig3 = os.path.join(str(directory), "fig3_torque_reconstruction.png")
    fig.savefig(fig3, bbox_inches="tight")
    logs = out["runs"][0]["_logs"]
    t = logs["nominal"]["t"]
    joints = ["joint 1", "joint 2"]
    legend = dict(loc="upper left", bbox_to_anchor=(1.01, 1.0))
    paths = [os.path.join(str(directory), f) for f in
             ("fig4_reference.png", "fig5_nominal_errors.png", "fig6_robust_errors.png", "torques.png")]
    fig, ax = subplots(figsize=(7.5, 3.5))
    ax.plot(t, logs["nominal"]["q_d"], label=joints)
    ax.set(xlabel="t [s]", ylabel="q_d [rad]", title="joint reference (CI fig. 4)")
    ax.grid(alpha=0.3)
    ax.legend(**legend)
    fig.tight_layout()
    fig.savefig(paths[0])
    e_max = max(float(np.max(np.abs(logs[law]["e"]))) for law in ("nominal", "robust")) * 1.05 or 1.0
    for law, num, path in (("nominal", 5, paths[1]), ("robust", 6, paths[2])):
        fig, ax = subplots(figsize=(7.5, 3.5))
        ax.plot(logs[law]["t"], logs[law]["e"], label=joints)
        ax.set(xlabel="t [s]", ylabel="e = q - q_d [rad]", ylim=(-e_max, e_max),
               title=f"tracking errors, {law} control (CI fig. {num}; same scale as fig. {11 - num})")
        ax.grid(alpha=0.3)
        ax.legend(**legend)
        fig.tight_layout()
        fig.savefig(path)
    fig, axes = subplots(2, 1, figsize=(7.5, 5), sharex=True)
    for j, ax in enumerate(axes):
        for law, style in (("nominal", "-"), ("robust", "--")):
            ax.plot(logs[law]["t"], np.asarray(logs[law]["u"])[:, j], style, lw=0.9, label=f"{law} law")
        ax.set_ylabel(f"u{j + 1} [N m]")
        ax.grid(alpha=0.3)
    axes[0].legend(**legend)
    axes[0].set_title("commanded torques, first drawn true arm")
    axes[-1].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(paths[3])
    return [fig3, *paths]


def run(args) -> int:
    from robust_drake.experiments.calafiore import run_study
    from robust_drake.uncertainty.ellipsoid import Ellipsoid

    theta0 = P = None
    if args.ellipsoid:
        ell = Ellipsoid.load(args.ellipsoid)
        theta0, P = ell.theta0, ell.P
    from robust_drake.cli import plot_dir
    from robust_drake.errors import RobustDrakeError
    from robust_drake.experiments.calafiore import torque_reconstruction
    from robust_drake.log import slow_step

    if not 0.0 < args.settle_rel < 1.0:
        raise RobustDrakeError(f"--settle-rel must be in (0, 1) (got {args.settle_rel})")
    plots = plot_dir(args)
    with slow_step(f"calafiore: nominal and robust control on {args.n_true} drawn true arm(s) ..."):
        out = run_study(theta0, P, n_true=args.n_true, duration=args.duration, seed=args.seed,
                        epsilon=args.epsilon, settle_rel=args.settle_rel)
    rec = torque_reconstruction(seed=args.seed)
    out["torque_reconstruction"] = {k: rec[k] for k in ("theta0", "rms_vs_measured", "rms_vs_true", "rms_noise")}
    if plots is not None:
        out["_reconstruction"] = rec
        out["plots"] = plot_study(out, plots)
        out.pop("_reconstruction")
    for r in out["runs"]:
        r.pop("_logs", None)
    if args.json:
        print_json(out)
        return 0
    paper = {"nominal": "larger transient errors, shorter settling (fig. 5)",
             "robust": "errors much reduced, longer settling (fig. 6)"}
    rows = []
    for law in ("nominal", "robust"):
        s = out["summary"][law]
        rows.append([law, *s["peak"], *s["rms"], *s["settling_time"], *s["settling_time_rel"], paper[law]])
    rel = f"{100 * args.settle_rel:g}%pk"
    print(format_table(rows, ["law", "peak e1", "peak e2", "rms e1", "rms e2", "settle1 0.01rad", "settle2 0.01rad",
                              f"settle1 {rel}", f"settle2 {rel}", "paper (CI sec. 5.2)"]))
    print(f"robust law settles later on both joints ({rel} band): "
          f"{'yes' if out['summary']['settling_order_reproduced'] else 'no'} (paper: yes)")
    r = out["torque_reconstruction"]
    print("fig. 3 torque reconstruction, RMS [N m] vs measured / vs noise-free / noise alone: "
          + "; ".join(f"joint {j + 1}: {r['rms_vs_measured'][j]:.3f} / {r['rms_vs_true'][j]:.3f} / "
                      f"{r['rms_noise'][j]:.3f}" for j in range(2)) + " (paper: 'satisfactory', no number)")
    return 0
