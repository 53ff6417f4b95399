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
    """Write the analogs of CI figs. 3-6 (:func:`robust_drake.experiments.calafiore.study_figures`)
    into ``directory``; returns the paths written."""
    from robust_drake.experiments.calafiore import study_figures

    os.makedirs(directory, exist_ok=True)
    paths = []
    for name, fig in study_figures(out).items():
        path = os.path.join(str(directory), name)
        fig.savefig(path, bbox_inches="tight")
        paths.append(path)
    return paths


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
