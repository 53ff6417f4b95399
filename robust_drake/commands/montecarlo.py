"""``robust-drake montecarlo``: robustness of controllers over drawn "true" plant parameters."""

from __future__ import annotations

import math
import sys

from robust_drake.cli import add_output_flags, format_table, print_json
from robust_drake.errors import RobustDrakeError


def register(sub):
    p = sub.add_parser(
        "montecarlo", help="Monte Carlo robustness: controllers vs drawn true parameters",
        description=(
            "Draw true plant parameters over an uncertainty set and run every controller on "
            "each draw: --robot d2r2 draws the load increments of Jaritz & Spong eq. 93 "
            "(uniform over the box); --robot imi_scara --ellipsoid FILE.json draws inside and "
            "on the boundary of a Calafiore & Indri confidence ellipsoid (JSON keys theta0, P). "
            "Prints percentiles and the worst case of the task-space error per controller, "
            "writes box plots and a resumable Parquet file of all runs."))
    p.add_argument("--robot", default="d2r2", choices=["d2r2", "imi_scara"],
                   help="d2r2 (JS eq. 93 load box) or imi_scara (CI ellipsoid; needs --ellipsoid); default d2r2")
    p.add_argument("--controllers", default="sp1,sp2",
                   help="comma-separated controller names (default sp1,sp2)")
    p.add_argument("--draws", type=int, default=200, help="parameter draws (default 200)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the draws (default 0)")
    p.add_argument("--corners", action="store_true",
                   help="d2r2: also run the 8 corners of the eq. 93 box")
    p.add_argument("--ellipsoid", default=None, metavar="FILE.json",
                   help="imi_scara: confidence ellipsoid (JSON keys theta0, P)")
    p.add_argument("--boundary-fraction", type=float, default=0.5,
                   help="imi_scara: share of draws on the ellipsoid's boundary (default 0.5)")
    p.add_argument("--trajectory", default="cpt", help="reference trajectory (default cpt)")
    p.add_argument("--rate", type=float, default=2500.0, help="sample rate [Hz] (default 2500)")
    p.add_argument("--observer", default="averaging", help="velocity estimator (default averaging)")
    p.add_argument("--duration", type=float, default=None, help="simulated time [s]")
    p.add_argument("--friction-compensation", action="store_true",
                   help="fixed friction compensation (JS eqs. 89-90)")
    p.add_argument("--metric", default="maxerr_task",
                   help="metric for the percentiles and plots (default maxerr_task)")
    p.add_argument("--out", default=None,
                   help="results Parquet (default out/montecarlo_<robot>.parquet); resumable; the "
                        "box plot <stem>_<metric>.png goes beside it unless --plot DIR is given")
    p.add_argument("--workers", type=int, default=None, help="local worker processes")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS", help="Dask scheduler address")
    p.add_argument("--force", action="store_true", help="overwrite --out of another study")
    p.add_argument("--no-progress", action="store_true", help="no progress bar (as -q)")
    add_output_flags(p, plot="DIR", files="montecarlo_<metric>.png (box plot per controller)")
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    import pathlib

    from robust_drake.batch import METRIC_KEYS
    from robust_drake.montecarlo import (boxplot, draw_d2r2, draw_imi, load_ellipsoid,
                                         montecarlo_scenarios, percentile_table, run_montecarlo)

    if args.metric not in METRIC_KEYS:
        raise RobustDrakeError(f"--metric must be one of {', '.join(METRIC_KEYS)}")
    from robust_drake.cli import plot_dir, show_progress

    if args.out is not None and not args.out.strip():
        raise RobustDrakeError("--out is empty; give a file path")
    plots = plot_dir(args)
    from robust_drake.registry import canonical_or_same

    controllers = [canonical_or_same("controller", c.strip()) for c in args.controllers.split(",") if c.strip()]
    if not controllers:
        raise RobustDrakeError("--controllers is empty")
    if args.draws < 1 and not args.corners:
        raise RobustDrakeError("--draws must be >= 1")
    rejected = 0
    from robust_drake.description import describe

    if describe(args.robot).load_intervals:  # the payload box of the description (D2R2: JS eq. 93)
        if args.ellipsoid:
            raise RobustDrakeError("--ellipsoid is for --robot imi_scara; the D2R2 uses eq. 93")
        thetas, deltas = draw_d2r2(args.draws, seed=args.seed, corners=args.corners)
        tags = [{"dm2": float(d[0]), "dlc2": float(d[1]), "dI2": float(d[2])} for d in deltas]
        set_desc = "JS eq. 93 load box" + (" + 8 corners" if args.corners else "")
    else:
        if not args.ellipsoid:
            raise RobustDrakeError("--robot imi_scara needs --ellipsoid FILE.json (keys theta0, P)")
        if not 0.0 <= args.boundary_fraction <= 1.0:
            raise RobustDrakeError("--boundary-fraction must be in [0, 1]")
        theta0, P = load_ellipsoid(args.ellipsoid)
        thetas, radii, rejected = draw_imi(theta0, P, args.draws, seed=args.seed,
                                           boundary_fraction=args.boundary_fraction)
        tags = [{"radius": float(r)} for r in radii]
        set_desc = (f"ellipsoid {args.ellipsoid} ({args.boundary_fraction:.0%} on the boundary; "
                    f"{rejected} physically unrealisable draws rejected)")
    base = dict(trajectory=args.trajectory, rate=args.rate, observer=args.observer,
                duration=args.duration, friction_compensation=args.friction_compensation,
                seed=args.seed)
    scenarios = montecarlo_scenarios(args.robot, controllers, thetas, base=base, tags=tags)
    out = args.out or f"out/montecarlo_{args.robot}.parquet"
    # Every file goes beside --out (or to --plot): nothing lands in the working directory
    # unless the user's own paths say so.
    out_path = pathlib.Path(out)
    plot = (str(plots / f"montecarlo_{args.metric}.png") if plots is not None
            else str(out_path.with_name(f"{out_path.stem}_{args.metric}.png")))
    if not args.json:
        print(f"{len(controllers)} controllers x {len(thetas)} draws over the {set_desc} "
              f"-> {out}", file=sys.stderr)
    df = run_montecarlo(scenarios, out=out, workers=args.workers, scheduler=args.scheduler,
                        force=args.force, progress=not args.no_progress and show_progress(args),
                        spec={"montecarlo": vars_for_spec(args)})
    table = percentile_table(df, metric=args.metric)
    boxplot(df, plot, metric=args.metric,
            title=f"{args.robot}, {args.trajectory}: {len(thetas)} draws of the {set_desc.split(' (')[0]}, ok runs")
    if args.json:
        print_json({
            "robot": args.robot, "draws": int(len(thetas)), "rejected": int(rejected),
            "metric": args.metric, "out": out, "plot": plot,
            "controllers": [{k: (None if isinstance(v, float) and math.isnan(v) else v)
                             for k, v in r.items()} for r in table.to_dict("records")],
        })
    else:
        cols = ["controller", "runs", "ok", "diverged", "failed", "p50", "p90", "p99", "worst",
                "worst_draw"]
        print(f"{args.metric} over {len(thetas)} draws ({set_desc}):")
        print(format_table([[r[c] for c in cols] for r in table.to_dict("records")], cols))
        for r in table.to_dict("records"):
            if r["worst_theta"] is not None:
                print(f"  worst {r['controller']}: draw {r['worst_draw']}, theta = "
                      f"{np.round(r['worst_theta'], 4).tolist()}")
        print(f"results: {out}\nbox plot: {plot}")
    return 0 if int(table["failed"].sum()) == 0 else 1


def vars_for_spec(args) -> dict:
    """The options that define the study (recorded in the Parquet metadata)."""
    keys = ("robot", "controllers", "draws", "seed", "corners", "ellipsoid", "boundary_fraction",
            "trajectory", "rate", "observer", "duration", "friction_compensation")
    return {k: getattr(args, k) for k in keys}
