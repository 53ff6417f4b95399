"""``robust-drake calafiore``: nominal (CI eq. 6) vs robust (eq. 15) control on the IMI SCARA (section 5.2)."""

from __future__ import annotations

import os

import numpy as np

from robust_drake.cli import add_output_flags, format_table, print_json


def register(subparsers):
    p = subparsers.add_parser("calafiore", help="Calafiore & Indri section 5.2: nominal vs ellipsoid-robust control")
    p.add_argument("--ellipsoid", default=None, help="JSON with theta0 and P (default: the published section 5.1 values)")
    p.add_argument("--n-true", type=int, default=3, help="true parameter vectors drawn on the ellipsoid boundary")
    p.add_argument("--duration", type=float, default=None, help="s (default 3, 1 with ROBUST_DRAKE_SHORT=1)")
    p.add_argument("--epsilon", type=float, default=1.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--settle-rel", type=float, default=0.1,
                   help="relative settling band: fraction of each error's peak (default 0.1)")
    add_output_flags(p, plot="DIR")
    p.set_defaults(func=run)


def plot_study(out, directory):
    """Analogs of CI figs. 3-6: torque reconstruction, reference, nominal and robust tracking errors,
    torques."""
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
    axes[0].set_title("CI fig. 3: measured vs reconstructed torque (theta0 from 5 samples)", fontsize=10)
    axes[1].set(xlabel="t [s]")
    axes[0].legend()
    fig.savefig(os.path.join(directory, "fig3_torque_reconstruction.png"))
    logs = out["runs"][0]["_logs"]
    t = logs["nominal"]["t"]
    fig, ax = subplots()
    ax.plot(t, logs["nominal"]["q_d"])
    ax.set(xlabel="t [s]", ylabel="q_d [rad]", title="joint reference (CI fig. 4)")
    fig.savefig(os.path.join(directory, "fig4_reference.png"))
    for law, num in (("nominal", 5), ("robust", 6)):
        fig, ax = subplots()
        ax.plot(logs[law]["t"], logs[law]["e"])
        ax.set(xlabel="t [s]", ylabel="e [rad]", title=f"tracking errors, {law} control (CI fig. {num})")
        ax.legend(["joint 1", "joint 2"])
        fig.savefig(os.path.join(directory, f"fig{num}_{law}_errors.png"))
    fig, ax = subplots()
    for law in ("nominal", "robust"):
        ax.plot(logs[law]["t"], logs[law]["u"], label=[f"{law} 1", f"{law} 2"])
    ax.set(xlabel="t [s]", ylabel="u [N m]", title="commanded torques")
    ax.legend()
    fig.savefig(os.path.join(directory, "torques.png"))


def run(args) -> int:
    from robust_drake.experiments.calafiore import run_study
    from robust_drake.identification.ellipsoid import Ellipsoid

    theta0 = P = None
    if args.ellipsoid:
        ell = Ellipsoid.load(args.ellipsoid)
        theta0, P = ell.theta0, ell.P
    from robust_drake.errors import RobustDrakeError
    from robust_drake.experiments.calafiore import torque_reconstruction

    if not 0.0 < args.settle_rel < 1.0:
        raise RobustDrakeError(f"--settle-rel must be in (0, 1) (got {args.settle_rel})")
    out = run_study(theta0, P, n_true=args.n_true, duration=args.duration, seed=args.seed, epsilon=args.epsilon,
                    settle_rel=args.settle_rel)
    rec = torque_reconstruction(seed=args.seed)
    out["torque_reconstruction"] = {k: rec[k] for k in ("theta0", "rms_vs_measured", "rms_vs_true", "rms_noise")}
    if args.plot:
        out["_reconstruction"] = rec
        plot_study(out, args.plot)
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
